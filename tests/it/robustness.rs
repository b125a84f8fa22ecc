//! `ROBUSTNESS.md`'s stiff and extreme cases at scene level, for the cases
//! no other module holds: the primitives' cases 1-8 and 29 as rays through
//! whole scenes and as pictures (their closed forms are unit tests in
//! `src/csg/shape_tests.rs`), coincident faces and zero-length spans (9-13),
//! and scale (22-24). Cases 14-21, 27 and 28 are in `cells.rs`, 25-27 in
//! `shading.rs`; `docs/robustness.md` lists them all.
//!
//! Every ray is asked of both accelerators (`cells::nearest_both`: equal
//! hits, finite t, unit finite normals), every picture is rendered by both
//! (`cells::assert_renders_equal`: bit-identical, finite pixels). Each case
//! runs over a few variants of its numbers, since the class matters and
//! not the one number in the catalogue.

use hypercast::csg::{PrimHits, PrimId, Primitive, Shape};
use hypercast::geom::{Ray, Vec3};
use hypercast::reference::RothTracer;
use hypercast::scene::Scene;
use hypercast::trace::{
    Film, Hit, RayJob, RayKind, Refraction, Shader, Tracer, offset_origin, refract,
};

use crate::cells::{assert_renders_equal, hits_along, structures};
use crate::csg_props::Rng;
use crate::util;

// ---------------------------------------------------------------------------
// Helpers.

/// A vector in RON, each component printed so that it parses back exactly.
fn v(p: Vec3) -> String {
    format!("({:?}, {:?}, {:?})", p.x, p.y, p.z)
}

/// A camera in RON. Odd sizes put the centre pixel's ray exactly on the
/// line from `eye` to `look_at`.
fn camera(eye: Vec3, look_at: Vec3, up: Vec3, fov: f64, w: u32, h: u32) -> String {
    format!(
        "(eye: {}, look_at: {}, up: {}, fov_y: {fov:?}, width: {w}, height: {h})",
        v(eye),
        v(look_at),
        v(up)
    )
}

/// A lit scene of `objects` seen by `camera`, with a blue background that no
/// surface colour equals.
fn scene_with(camera: &str, objects: &str) -> Scene {
    util::scene(&format!(
        "(camera: {camera}, background: (0.1, 0.2, 0.9), lights: [(position: (-3, -4, 6))],
          objects: [{objects}])"
    ))
}

/// The centre pixel of an odd-sized film.
fn centre(film: &Film, w: u32, h: u32) -> [i64; 3] {
    film.sums()[(h / 2 * w + w / 2) as usize]
}

fn background(scene: &Scene) -> [i64; 3] {
    Film::quantize(scene.background)
}

/// `(primitive, t)` of each hit.
fn pts(hits: &[Hit]) -> Vec<(u32, f64)> {
    hits.iter().map(|h| (h.prim.0, h.t)).collect()
}

/// Every boundary along `ray` from 0, asked of Roth and of the cells of
/// every structure of `scene` (all equal).
fn along(scene: &Scene, ray: &Ray) -> Vec<Hit> {
    let all: Vec<Vec<Hit>> = structures(scene, 33, 33)
        .iter()
        .map(|cs| hits_along(scene, cs, ray, 0.0))
        .collect();
    assert!(all.windows(2).all(|w| w[0] == w[1]), "{all:?}");
    all.into_iter().next().unwrap_or_default()
}

/// Fraction of pixels whose channels differ by more than `tol`.
fn fraction_differing(a: &Film, b: &Film, tol: f32) -> f64 {
    let (a, b) = (a.to_linear(), b.to_linear());
    assert_eq!(a.len(), b.len());
    let bad = a
        .iter()
        .zip(&b)
        .filter(|(p, q)| p.iter().zip(q.iter()).any(|(x, y)| (x - y).abs() > tol))
        .count();
    bad as f64 / a.len() as f64
}

#[track_caller]
fn assert_rel(got: f64, want: f64, rel: f64) {
    assert!(
        (got - want).abs() <= rel * want.abs(),
        "got {got:e}, want {want:e} (±{rel:e} relative)"
    );
}

/// The same pixels, bit for bit.
#[track_caller]
fn assert_same_picture(a: &Film, b: &Film, what: &str) {
    let differ = util::differing(a, b);
    assert_eq!(differ, 0, "{what}: {differ} pixels differ");
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 1: a unit sphere 1e8 away, and a tiny one.

/// The discriminant `b² − ac` of a sphere far away cancels to nothing; the
/// hit must keep full precision (1e-15 relative), whatever the distance and
/// the radius, and the picture shows the sphere.
#[test]
fn case_01_far_and_tiny_spheres_are_hit_at_full_precision() {
    for (dist, r) in [(1e8, 1.0f64), (1e6, 1e-6), (1e12, 1e3), (3e9, 7e-4)] {
        // A field of view four radii wide at that distance.
        let fov = 2.0 * (4.0 * r / dist).atan().to_degrees();
        let scene = scene_with(
            &camera(Vec3::ZERO, Vec3::new(0.0, 0.0, dist), Vec3::Y, fov, 33, 33),
            &format!(
                "Sphere(center: {}, radius: {r:?})",
                v(Vec3::new(0.0, 0.0, dist))
            ),
        );
        let hits = along(&scene, &Ray::new(Vec3::ZERO, Vec3::Z));
        let got = pts(&hits);
        assert_eq!(got.len(), 2, "{dist:e}, {r:e}: {got:?}");
        // 1e-15 relative is a few ulps of the distance.
        assert_rel(got[0].1, dist - r, 1e-15);
        assert_rel(got[1].1, dist + r, 1e-15);
        let film = assert_renders_equal(&scene, 33, 33).0;
        assert_ne!(centre(&film, 33, 33), background(&scene), "{dist:e}, {r:e}");
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 2: grazing rays a few ulps inside and outside a sphere.

/// Rays at height `h` past a unit sphere hit iff `h < 1`, with the chord
/// `2√(1 − h²)`; the tangent ray at `h = 1` sees the background.
#[test]
fn case_02_grazing_rays_hit_iff_inside_with_the_right_chord() {
    let ulp = 2f64.powi(-53);
    let mut heights: Vec<f64> = vec![1.0];
    for k in [1.0, 2.0, 4.0, 16.0, 1024.0] {
        heights.push(1.0 - k * ulp);
        heights.push(1.0 + 2.0 * k * ulp);
    }
    for radius in [1.0, 0.001, 1000.0] {
        for &h in &heights {
            let y = h * radius;
            let eye = Vec3::new(0.0, y, -10.0 * radius);
            let scene = util::scene(&format!(
                "(camera: {}, background: (0, 0, 1), materials: {{ \"red\": (color: (1, 0, 0), ambient: 1) }},
                  objects: [Sphere(center: (0, 0, 0), radius: {radius:?}, material: \"red\")])",
                camera(eye, Vec3::new(0.0, y, 0.0), Vec3::Y, 20.0, 33, 33)
            ));
            let got = pts(&along(&scene, &Ray::new(eye, Vec3::Z)));
            let film = assert_renders_equal(&scene, 33, 33).0;
            let seen = centre(&film, 33, 33) != background(&scene);
            if y < radius {
                assert_eq!(got.len(), 2, "h = {h:?}, r = {radius}: {got:?}");
                // From y, not h: `h · radius` may have rounded. `radius − y`
                // is exact (Sterbenz).
                let chord = 2.0 * ((radius - y) * (radius + y)).sqrt();
                assert_rel(got[1].1 - got[0].1, chord, 1e-6);
                assert!(seen, "h = {h:?}, r = {radius}: the centre pixel misses");
            } else {
                assert!(got.is_empty(), "h = {h:?}, r = {radius}: {got:?}");
                assert!(!seen, "h = {h:?}, r = {radius}: the centre pixel hits");
            }
        }
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 3-5: a cylinder seen along its axis, in its cap planes, and
// through its rim.

const CYLINDER: &str = "Cylinder(base: (0, 0, 0), top: (0, 0, 2), radius: 1)";

/// Rays parallel to the axis (`a = 0` in the quadratic) inside, on and
/// outside the side; a nearly parallel one gives the same span.
#[test]
fn case_03_rays_along_a_cylinders_axis() {
    let scene = scene_with(
        &camera(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 40.0, 33, 33),
        CYLINDER,
    );
    let up = |x: f64, d: Vec3| pts(&along(&scene, &Ray::new(Vec3::new(x, 0.0, -1.0), d)));
    assert_eq!(up(0.5, Vec3::Z), [(0, 1.0), (0, 3.0)]);
    assert_eq!(up(-0.999, Vec3::Z), [(0, 1.0), (0, 3.0)]);
    assert_eq!(up(1.5, Vec3::Z), []);
    let on = up(1.0, Vec3::Z);
    assert!(on.is_empty() || on == [(0, 1.0), (0, 3.0)], "{on:?}");
    // Continuous in the direction: tilted by 1e-20 and by 1e-300.
    for tilt in [1e-20, 1e-300, 5e-324] {
        for d in [Vec3::new(0.0, tilt, 1.0), Vec3::new(-tilt, tilt, 1.0)] {
            assert_eq!(up(0.5, d), [(0, 1.0), (0, 3.0)], "{d:?}");
        }
    }
    assert_renders_equal(&scene, 33, 33);
    // Looking down the side surface itself.
    let scene = scene_with(
        &camera(
            Vec3::new(1.0, 0.0, -5.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::Y,
            40.0,
            33,
            33,
        ),
        CYLINDER,
    );
    assert_renders_equal(&scene, 33, 33);
}

/// Rays perpendicular to the axis (a cap's `t = (h − o)/0`) between the
/// caps and exactly in their planes.
#[test]
fn case_04_rays_in_the_cap_planes() {
    for z in [0.0, 1.0, 2.0, 2.0f64.next_up(), 0.0f64.next_down()] {
        let eye = Vec3::new(-5.0, 0.0, z);
        let scene = scene_with(
            &camera(eye, Vec3::new(0.0, 0.0, z), Vec3::Z, 30.0, 33, 33),
            CYLINDER,
        );
        let got = pts(&along(&scene, &Ray::new(eye, Vec3::X)));
        if z == 1.0 {
            assert_eq!(got, [(0, 4.0), (0, 6.0)]);
        } else if z == 0.0 || z == 2.0 {
            // In a cap's plane: on the closed solid's surface, either is right.
            assert!(got.is_empty() || got == [(0, 4.0), (0, 6.0)], "{got:?}");
        } else {
            assert!(got.is_empty(), "z = {z:?}: {got:?}");
        }
        assert_renders_equal(&scene, 33, 33);
    }
}

/// A ray through the rim: the normal is the cap's or the side's, never a
/// zero or a mixture, and the span inside is not lost.
#[test]
fn case_05_ray_through_the_rim() {
    for (eye, rim, exit) in [
        // The catalogue's ray: in at (−1, 0, 2), out of the side at (1, 0, 1.5).
        (Vec3::new(-5.0, 0.0, 3.0), Vec3::new(-1.0, 0.0, 2.0), 1.5),
        // Through the base rim, upwards.
        (Vec3::new(-5.0, 0.0, -1.0), Vec3::new(-1.0, 0.0, 0.0), 1.5),
    ] {
        let d = rim - eye;
        let scene = scene_with(&camera(eye, rim, Vec3::Z, 30.0, 33, 33), CYLINDER);
        let ray = Ray::new(eye, d);
        let hits = along(&scene, &ray);
        let got = pts(&hits);
        assert_eq!(got.len(), 2, "{got:?}");
        assert_eq!(got[0].1, 1.0);
        assert!((got[1].1 - exit).abs() < 1e-12, "{got:?}");
        let n = crate::cells::checked_normal(&scene, &ray, &hits[0]);
        let cap = Vec3::Z * (rim.z - 1.0).signum();
        assert!(n == cap || n == -Vec3::X, "rim normal {n}");
        assert_renders_equal(&scene, 33, 33);
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 6: a cone through its apex and along a generator.

const CONE: &str = "Cone(base: (0, 0, 0), base_radius: 0, top: (0, 0, 1), top_radius: 1)";

#[test]
fn case_06_cone_apex_and_generator() {
    let eye = Vec3::new(0.0, 0.0, -3.0);
    let scene = scene_with(&camera(eye, Vec3::ZERO, Vec3::Y, 40.0, 33, 33), CONE);
    // Up the axis: in at the apex (a unit normal there), out through the cap.
    let ray = Ray::new(Vec3::new(0.0, 0.0, -1.0), Vec3::Z);
    let hits = along(&scene, &ray);
    assert_eq!(pts(&hits), [(0, 1.0), (0, 2.0)]);
    for h in &hits {
        crate::cells::checked_normal(&scene, &ray, h);
    }
    // Parallel to a generator (a = 0): inside for s in [−0.25, 0.5].
    let ray = Ray::new(Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 1.0, 1.0));
    let spans = RothTracer::new(&scene).spans(&ray).spans;
    assert_eq!(spans.len(), 1, "{spans:?}");
    assert!((spans[0].enter.t + 0.25).abs() <= 1e-12, "{spans:?}");
    assert!((spans[0].exit.t - 0.5).abs() <= 1e-12, "{spans:?}");
    let got = pts(&along(&scene, &ray));
    assert_eq!(got.len(), 1, "{got:?}");
    assert!((got[0].1 - 0.5).abs() <= 1e-12);
    // The mirror nappe below the apex is no part of the cone.
    let below = Ray::new(Vec3::new(0.0, -5.0, -0.5), Vec3::Y);
    assert_eq!(pts(&along(&scene, &below)), []);
    assert_renders_equal(&scene, 33, 33);
    // Looking along a generator, and straight at the apex from the side.
    for (eye, at) in [
        (Vec3::new(0.0, -2.0, -1.5), Vec3::new(0.0, 0.0, 0.5)),
        (Vec3::new(-4.0, 0.0, 0.0), Vec3::ZERO),
    ] {
        let scene = scene_with(&camera(eye, at, Vec3::Z, 40.0, 33, 33), CONE);
        assert_renders_equal(&scene, 33, 33);
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 7 and 8: box edges, corners and signed zeros.

const CUBE: &str = "Box(min: (-1, -1, -1), max: (1, 1, 1))";

#[test]
fn case_07_box_edge_and_corner_hits_are_exact_with_one_face() {
    for (o, d) in [
        (Vec3::new(-5.0, -5.0, 0.0), Vec3::new(1.0, 1.0, 0.0)),
        (Vec3::splat(-5.0), Vec3::ONE),
        (Vec3::splat(5.0), -Vec3::ONE),
        (Vec3::new(0.25, 5.0, 5.0), Vec3::new(0.0, -1.0, -1.0)),
    ] {
        let scene = scene_with(&camera(o, o + d, Vec3::Z, 30.0, 33, 33), CUBE);
        let ray = Ray::new(o, d);
        let hits = along(&scene, &ray);
        assert_eq!(pts(&hits), [(0, 4.0), (0, 6.0)], "{ray:?}");
        for h in &hits {
            let n = crate::cells::checked_normal(&scene, &ray, h);
            // One of the faces meeting there: an axis, signed.
            assert_eq!(n.abs().max_element(), 1.0, "{n}");
            assert_eq!(n.abs().element_sum(), 1.0, "{n}");
        }
        assert_renders_equal(&scene, 33, 33);
    }
}

#[test]
fn case_08_signed_zero_directions_give_the_same_hits() {
    let scene = scene_with(
        &camera(
            Vec3::new(1.0, 0.5, -5.0),
            Vec3::new(1.0, 0.5, 0.0),
            Vec3::Y,
            30.0,
            33,
            33,
        ),
        "Box(min: (0, 0, 0), max: (1, 1, 1))",
    );
    for o in [
        Vec3::new(1.0, 0.5, -5.0),
        Vec3::new(0.0, 0.5, -5.0),
        Vec3::new(1.0, 1.0, -5.0),
    ] {
        let plus = along(&scene, &Ray::new(o, Vec3::new(0.0, 0.0, 1.0)));
        assert_eq!(pts(&plus), [(0, 5.0), (0, 6.0)], "{o}");
        for d in [
            Vec3::new(-0.0, 0.0, 1.0),
            Vec3::new(0.0, -0.0, 1.0),
            Vec3::new(-0.0, -0.0, 1.0),
        ] {
            assert_eq!(along(&scene, &Ray::new(o, d)), plus, "{o} {d:?}");
        }
    }
    let outside = Vec3::new(1.5, 0.5, -5.0);
    for dx in [0.0, -0.0] {
        assert_eq!(
            pts(&along(&scene, &Ray::new(outside, Vec3::new(dx, 0.0, 1.0)))),
            []
        );
    }
    assert_renders_equal(&scene, 33, 33);
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 9-12: coincident faces in CSG.

/// A scene for the coincident-face cases: seen from above and aside, lit
/// so that shadow rays run through the holes too.
fn csg_scene(objects: &str) -> Scene {
    util::scene(&format!(
        "(camera: (eye: (0.3, 0.2, 5), look_at: (0, 0, 0), up: (0, 1, 0), fov_y: 40, width: 48, height: 48),
          background: (0.1, 0.2, 0.9),
          lights: [(position: (0.2, 0.1, 8)), (position: (-4, 3, 2))],
          materials: {{ \"m\": (color: (0.9, 0.6, 0.3), specular: 0.3) }},
          objects: [{objects}])"
    ))
}

/// POV-Ray's speckles: a hole whose cylinder's caps lie exactly in the
/// box's faces renders exactly as one whose cylinder pokes out, whether the
/// cylinder is given directly, scaled from a unit cylinder, turned into
/// place by quarter turns, or the whole object is turned at any angle.
#[test]
fn case_09_hole_with_coincident_caps_has_no_speckles() {
    for (size, r) in [(1.0, 0.5), (3.0, 0.25), (0.1, 0.07)] {
        let boxed = |cyl: &str| {
            format!(
                "Difference(material: \"m\", children: [Box(min: {}, max: {}), {cyl}])",
                v(Vec3::splat(-size)),
                v(Vec3::splat(size))
            )
        };
        let cyl = |h: f64| {
            format!(
                "Cylinder(base: {}, top: {}, radius: {r:?})",
                v(Vec3::new(0.0, 0.0, -h)),
                v(Vec3::new(0.0, 0.0, h))
            )
        };
        let moved = |mut s: Scene| -> Scene {
            s.camera.eye = Vec3::new(0.3, 0.2, 5.0) * size;
            s
        };
        let reference = moved(csg_scene(&boxed(&cyl(size * 1.001))));
        let want = assert_renders_equal(&reference, 48, 48).0;
        let variants = [
            cyl(size),
            // A unit cylinder scaled into place.
            format!(
                "Transform(scale: {}, child: Cylinder(base: (0, 0, -0.5), top: (0, 0, 0.5), radius: 1))",
                v(Vec3::new(r, r, 2.0 * size))
            ),
            // Lying along y, stood up by a quarter turn about x.
            format!(
                "Transform(rotate: (90, 0, 0), child: Cylinder(base: {}, top: {}, radius: {r:?}))",
                v(Vec3::new(0.0, size, 0.0)),
                v(Vec3::new(0.0, -size, 0.0))
            ),
            // Turned half round about y: the caps swap places.
            format!("Transform(rotate: (0, 180, 0), child: {})", cyl(size)),
        ];
        for c in variants {
            let scene = moved(csg_scene(&boxed(&c)));
            let got = assert_renders_equal(&scene, 48, 48).0;
            assert_same_picture(&got, &want, &c);
        }
        // The whole object turned at angles that round: box and cylinder
        // then meet rays in their common object space, so the caps still
        // agree with the faces bit for bit.
        for rotate in ["(30, 40, 50)", "(45, 0, 0)", "(10, 20, 0)"] {
            let turned = |h: f64| {
                moved(csg_scene(&format!(
                    "Transform(rotate: {rotate}, child: {})",
                    boxed(&cyl(h))
                )))
            };
            let want = assert_renders_equal(&turned(size * 1.001), 48, 48).0;
            let got = assert_renders_equal(&turned(size), 48, 48).0;
            assert_same_picture(&got, &want, &format!("turned by {rotate}"));
        }
    }
}

/// A box cut, intersected and joined with a box that shares three of its
/// faces (built from a scaled and translated unit box) gives exactly the
/// box the algebra says: no slivers, no stray faces.
#[test]
fn case_10_boxes_sharing_faces_combine_exactly() {
    let a = "Box(min: (-1, -1, -1), max: (1, 1, 1))";
    let bs = [
        "Transform(scale: (1, 2, 2), translate: (0, -1, -1), child: Box(min: (0, 0, 0), max: (1, 1, 1)))",
        "Transform(scale: (1, 2, 2), translate: (0.5, 0, 0), child: Box(min: (-0.5, -0.5, -0.5), max: (0.5, 0.5, 0.5)))",
        // A quarter turn about x maps [0,1]×[−1,1]² onto itself.
        "Transform(rotate: (90, 0, 0), child: Box(min: (0, -1, -1), max: (1, 1, 1)))",
    ];
    let render = |objects: &str| assert_renders_equal(&csg_scene(objects), 48, 48).0;
    let left = render("Box(min: (-1, -1, -1), max: (0, 1, 1), material: \"m\")");
    let right = render("Box(min: (0, -1, -1), max: (1, 1, 1), material: \"m\")");
    let whole = render(&format!("Union(material: \"m\", children: [{a}])"));
    for b in bs {
        let op = |o: &str| render(&format!("{o}(material: \"m\", children: [{a}, {b}])"));
        assert_same_picture(&op("Difference"), &left, &format!("A − {b}"));
        assert_same_picture(&op("Intersection"), &right, &format!("A ∩ {b}"));
        assert_same_picture(&op("Union"), &whole, &format!("A ∪ {b}"));
    }
    // All of it turned at angles that round: A, B and the references then
    // share the one rotation (B's own scale is folded in first).
    for rotate in ["(30, 40, 50)", "(0, 0, 20)"] {
        let turned = |o: &str| render(&format!("Transform(rotate: {rotate}, child: {o})"));
        let left = turned("Box(min: (-1, -1, -1), max: (0, 1, 1), material: \"m\")");
        let right = turned("Box(min: (0, -1, -1), max: (1, 1, 1), material: \"m\")");
        let whole = turned(&format!("Union(material: \"m\", children: [{a}])"));
        for b in bs {
            let op = |o: &str| turned(&format!("{o}(material: \"m\", children: [{a}, {b}])"));
            let what = |o: &str| format!("{rotate}: A {o} {b}");
            assert_same_picture(&op("Difference"), &left, &what("−"));
            assert_same_picture(&op("Intersection"), &right, &what("∩"));
            assert_same_picture(&op("Union"), &whole, &what("∪"));
        }
    }
}

/// Solids that only touch intersect in nothing: the zero-length span at
/// the contact is never drawn.
#[test]
fn case_11_touching_solids_intersect_in_nothing() {
    for (eye, objects) in [
        (
            Vec3::new(5.0, 0.5, 0.5),
            "Intersection(children: [Box(min: (0, 0, 0), max: (1, 1, 1)), Box(min: (1, 0, 0), max: (2, 1, 1))])",
        ),
        (
            Vec3::new(5.0, 0.5, 0.5),
            "Intersection(children: [Box(min: (1, 0, 0), max: (2, 1, 1)), \
             Transform(translate: (-1, 0, 0), child: Box(min: (1, 0, 0), max: (2, 1, 1)))])",
        ),
        (
            Vec3::new(5.0, 0.0, 0.0),
            "Intersection(children: [Sphere(center: (0, 0, 0), radius: 1), Sphere(center: (2, 0, 0), radius: 1)])",
        ),
        (
            Vec3::new(5.0, 0.5, 0.5),
            "Difference(children: [Box(min: (0, 0, 0), max: (1, 1, 1)), Box(min: (0, 0, 0), max: (1, 1, 1))])",
        ),
    ] {
        let scene = scene_with(&camera(eye, eye - Vec3::X, Vec3::Z, 40.0, 33, 33), objects);
        assert_eq!(
            pts(&along(&scene, &Ray::new(eye, -Vec3::X))),
            [],
            "{objects}"
        );
        let film = assert_renders_equal(&scene, 33, 33).0;
        assert!(
            film.sums().iter().all(|p| *p == background(&scene)),
            "{objects}: something drawn"
        );
    }
}

/// Glass made of two touching boxes refracts as one box: the inner face of
/// a union (or an assembly, which combines as a union) is gone.
#[test]
fn case_12_glass_union_of_touching_boxes_is_one_box() {
    let glass = |objects: &str| {
        util::scene(&format!(
            "(camera: (eye: (1.3, -3, 2.5), look_at: (1, 0.5, 0.5), fov_y: 50, width: 48, height: 36),
              background: (0.1, 0.2, 0.9),
              lights: [(position: (-2, -3, 5))],
              max_depth: 8,
              materials: {{
                \"glass\": (color: (1, 1, 1), ambient: 0, diffuse: 0.1, specular: 0.5, reflect: 0.1, transmit: 0.85, ior: 1.5),
                \"floor\": (color: (0.9, 0.8, 0.2)),
              }},
              objects: [{objects}, Box(min: (-3, -3, -1), max: (5, 5, -0.5), material: \"floor\")])"
        ))
    };
    let one = assert_renders_equal(
        &glass("Box(min: (0, 0, 0), max: (2, 1, 1), material: \"glass\")"),
        48,
        36,
    )
    .0;
    for op in ["Union", "Assembly"] {
        let two = glass(&format!(
            "{op}(material: \"glass\", children: [Box(min: (0, 0, 0), max: (1, 1, 1)), Box(min: (1, 0, 0), max: (2, 1, 1))])"
        ));
        let got = assert_renders_equal(&two, 48, 36).0;
        assert_eq!(fraction_differing(&got, &one, 1e-6), 0.0, "{op}");
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 13: flat, inverted and NaN boxes.

#[test]
fn case_13_flat_boxes_are_invisible_and_bad_ones_refused() {
    let a = "Box(min: (-1, -1, -1), max: (1, 1, 1), material: \"m\")";
    let plain = assert_renders_equal(&csg_scene(a), 48, 48).0;
    for sheet in [
        "Box(min: (0, -2, -2), max: (0, 2, 2))",
        "Box(min: (-2, -2, 1), max: (2, 2, 1))",
        "Box(min: (0.5, 0.5, -3), max: (0.5, 0.5, 3))",
    ] {
        let alone = scene_with(
            &camera(Vec3::new(0.3, 0.2, 5.0), Vec3::ZERO, Vec3::Y, 40.0, 33, 33),
            sheet,
        );
        let film = assert_renders_equal(&alone, 33, 33).0;
        assert!(
            film.sums().iter().all(|p| *p == background(&alone)),
            "{sheet} is visible"
        );
        for op in ["Difference", "Union"] {
            let scene = csg_scene(&format!("{op}(material: \"m\", children: [{a}, {sheet}])"));
            let got = assert_renders_equal(&scene, 48, 48).0;
            assert_same_picture(&got, &plain, &format!("A {op} {sheet}"));
        }
    }
    for (bad, says) in [
        ("Box(min: (1, 0, 0), max: (0, 1, 1))", "min.x"),
        ("Box(min: (0, NaN, 0), max: (1, 1, 1))", "finite"),
        ("Box(min: (0, 0, 0), max: (1, 1, inf))", "finite"),
    ] {
        let text = format!(
            "(camera: (eye: (0, -5, 0), look_at: (0, 0, 0), fov_y: 40, width: 8, height: 8), objects: [{bad}])"
        );
        let err = hypercast::scene::parse_scene_str(
            &text,
            hypercast::scene::SceneSyntax::Ron,
            std::path::Path::new("bad.ron"),
        )
        .err()
        .unwrap_or_else(|| panic!("{bad} loads"));
        assert!(err.to_string().contains(says), "{bad}: {err}");
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 22 and 23: the same scene far away, tiny and huge.

/// A scene with every kind of ray: a diffuse sphere casting a shadow, a
/// mirror cut by a sphere, glass, a cylinder, a floor. `f` maps points and
/// `s` scales lengths, so the same scene can be moved or scaled.
fn shifted_scene(f: impl Fn(Vec3) -> Vec3, s: f64) -> Scene {
    let p = |x: f64, y: f64, z: f64| v(f(Vec3::new(x, y, z)));
    util::scene(&format!(
        "(camera: (eye: {}, look_at: {}, fov_y: 45, width: 100, height: 100),
          background: (0.3, 0.4, 0.6),
          lights: [(position: {}), (position: {}, color: (0.5, 0.5, 0.4))],
          materials: {{
            \"ball\": (color: (0.8, 0.2, 0.1), specular: 0.5, shininess: 30),
            \"mirror\": (color: (0.9, 0.9, 0.9), diffuse: 0.2, reflect: 0.6),
            \"glass\": (color: (1, 1, 1), ambient: 0, diffuse: 0.05, reflect: 0.05, transmit: 0.85, ior: 1.5),
          }},
          objects: [
            Sphere(center: {}, radius: {:?}, material: \"ball\"),
            Difference(material: \"mirror\", children: [
              Box(min: {}, max: {}), Sphere(center: {}, radius: {:?})]),
            Sphere(center: {}, radius: {:?}, material: \"glass\"),
            Cylinder(base: {}, top: {}, radius: {:?}),
            Box(min: {}, max: {}),
          ])",
        p(0.3, -6.1, 3.2),
        p(0.0, 0.0, 0.7),
        p(-3.0, -2.5, 6.3),
        p(4.0, -1.0, 3.0),
        p(0.0, 0.0, 1.2),
        0.8 * s,
        p(1.2, -0.5, 0.0),
        p(2.2, 0.5, 1.0),
        p(1.7, -0.5, 1.0),
        0.45 * s,
        p(-1.6, 0.3, 0.6),
        0.6 * s,
        p(0.5, 1.5, 0.0),
        p(0.5, 1.5, 1.5),
        0.3 * s,
        p(-4.0, -4.0, -0.2),
        p(4.0, 4.0, 0.0),
    ))
}

/// At most one pixel in 10,000 may change by more than 1e-6 (a silhouette
/// or shadow edge that rounding moves across a pixel centre); no acne.
#[test]
fn case_22_translated_far_away_renders_the_same() {
    let home = assert_renders_equal(&shifted_scene(|p| p, 1.0), 100, 100).0;
    for shift in [1e6, 1e8, -3.3e7] {
        let t = Vec3::new(1.0, 1.0, 1.0) * shift;
        let far = assert_renders_equal(&shifted_scene(|p| p + t, 1.0), 100, 100).0;
        let bad = fraction_differing(&far, &home, 1e-6);
        assert!(
            bad <= 1e-4,
            "translated by {shift:e}: {bad} of pixels differ"
        );
    }
}

/// Rays that start far from what they hit: the level-2 sphereflake inside
/// a reflecting sphere of radius 1e6 (the mutant of seed 60955 of
/// `bundled_scenes_with_extreme_numbers_...`). Rays reflected back from
/// its inside cross the floor, seen edge-on behind the eye (its camera
/// looks level), whose super cell of the paper's fewest-splits BSP was
/// 5e-12 wide: a walk from 1e6 away crossed it in no `t` at all, and the
/// cell after it did not hold the floor, so 24 rays of 12x9 pixels went
/// on to the far wall. Cells now hold what lies within the walk's
/// rounding (`cells::walk_rounding`), which scales with the scene's reach.
#[test]
fn rays_from_a_million_away_find_a_floor_seen_edge_on() {
    let scene = bundled_with(
        "scenes/sphereflake2.nff",
        &[
            ("at 0 0 0", "at 1e30 0 0"),
            (
                "s 0.8026084423958546 0.2814712819167448 0.11111111111111113 0.05555555555555555",
                "s 0.8026084423958546 0.2814712819167448 0.11111111111111113 1e6",
            ),
            (
                "s 0.6074872842789857 -0.33532175730307756 -0.11111111111111094 0.05555555555555555",
                "s 0.6074872842789857 -1e6 -0.11111111111111094 0.05555555555555555",
            ),
        ],
    );
    for (w, h) in [(12, 9), (40, 30)] {
        assert_renders_equal(&scene, w, h);
    }
}

/// A sphere of radius 1e30 whose surface passes 3 from the eye, minus a
/// box beside it (`scenes/small/difference.ron` so mutated; seed 98740 of
/// `bundled_scenes_with_extreme_numbers_...`). Its surface there is known
/// to some 1e14 only, and the eye's rays enter it, to rounding, at the
/// eye: Roth then sees the box's face where the rays leave the sphere
/// into the box. The cells cut the box by the sphere's exact box (Algorithm
/// 1), which left it a sliver of zero width, in no cell, and saw the
/// sphere's far side 1e30 away. An ancestor now cuts a child by its box
/// inflated as Roth's culling inflates it (`CsgTree::minimal_boxes`).
#[test]
fn a_difference_cut_by_a_sphere_known_to_1e14_renders_as_roth_does() {
    let scene = bundled_with(
        "scenes/small/difference.ron",
        &[(
            "Sphere(center: (0, 0, 0), radius: 1)",
            "Sphere(center: (-1e30, 0, 0), radius: 1e30)",
        )],
    );
    for (w, h) in [(12, 9), (64, 48)] {
        assert_renders_equal(&scene, w, h);
    }
}

/// A bundled scene file with each `from` (found exactly once) replaced by
/// its `to`, loaded as its extension says.
fn bundled_with(rel: &str, edits: &[(&str, &str)]) -> Scene {
    use hypercast::scene::{SceneSyntax, parse_scene_str};
    let path = util::repo(rel);
    let mut text = std::fs::read_to_string(&path).unwrap();
    for (from, to) in edits {
        assert_eq!(text.matches(from).count(), 1, "{rel}: {from}");
        text = text.replace(from, to);
    }
    let syntax = SceneSyntax::from_path(&path).unwrap();
    parse_scene_str(&text, syntax, &path).unwrap_or_else(|e| panic!("{rel} edited: {e}"))
}

#[test]
fn case_23_scaled_tiny_and_huge_renders_the_same() {
    let home = assert_renders_equal(&shifted_scene(|p| p, 1.0), 100, 100).0;
    for s in [1e-6, 1e6, 3e-9, 7e8] {
        let scaled = assert_renders_equal(&shifted_scene(|p| p * s, s), 100, 100).0;
        let bad = fraction_differing(&scaled, &home, 1e-6);
        assert!(bad <= 1e-4, "scaled by {s:e}: {bad} of pixels differ");
    }
}

/// The stiff scenes on the hypercube: cases 22 and 23 (the scene moved
/// 1e8 away, scaled by 1e-6 and 1e6), the ground reaching 1e50 away, the
/// discs of radius 1e30 (a flat cone and a cylinder) and the wall a hair
/// behind the eye plane (below) give, on 2, 8 and 32
/// nodes, exactly the image the single node gives. The machine's own
/// arithmetic meets these magnitudes too: the cells it walks past by
/// their content's hull (`meets_remote`), the super cells split for
/// balance, a ray's resumption on another node.
#[test]
fn the_stiff_scenes_on_the_machine_give_the_single_node_image() {
    let shift = Vec3::new(1.0, 1.0, 1.0) * 1e8;
    let scenes = [
        ("moved by 1e8", shifted_scene(|p| p + shift, 1.0)),
        ("scaled by 1e-6", shifted_scene(|p| p * 1e-6, 1e-6)),
        ("scaled by 1e6", shifted_scene(|p| p * 1e6, 1e6)),
        ("a ground reaching 1e50", far_ground_scene(1e50)),
        (
            "a tilted flat cone reaching 1e30",
            far_ground_scene_with(
                "Transform(rotate: (4, -3, 0), child: Cone(base: (0, 0, -0.5), \
                 base_radius: 1e30, top: (0, 0, 0), top_radius: 0)),",
            ),
        ),
        (
            "a disc reaching 1e30",
            far_ground_scene_with("Cylinder(base: (0, 0, -0.5), top: (0, 0, 0), radius: 1e30),"),
        ),
        (
            "a wall 1e-12 behind the eye",
            wall_behind_eye_scene("-1e-12"),
        ),
        ("a wall through the eye", wall_behind_eye_scene("-0")),
    ];
    for (what, scene) in &scenes {
        let (one, _) = crate::machine::machine(scene, 0, 80, 60, 16);
        for d in [1, 3, 5] {
            let (film, _) = crate::machine::machine(scene, d, 80, 60, 16);
            assert!(
                film.sums() == one.sums(),
                "{what}, d = {d}: the image differs from d = 0"
            );
        }
    }
}

/// Beyond the catalogue, one object over the whole range of scales: a
/// ground box reaching from under the scene out to 1e20, 1e30 or 1e50
/// (`scene::load::MAX_COORDINATE`) on one side, a user's infinite floor,
/// seen directly and in two mirrors. Found by mutating the bundled scenes'
/// numbers: from about 1e20 the cells lost the floor around the camera
/// (1,191 of 3,072 pixels differed from Roth's at 1e20), because the
/// build inflated the box by its largest magnitude, so that its near end
/// moved 1e8 (at 1e30, 1e18) past the camera, and the crossings of its
/// edges with the eye plane, between two far corners, came out some 100
/// units off (`Aabb::inflated_each`, `projection::plane_crossing`).
///
/// And it shades as a ground reaching 1e4 does, bit for bit (beyond the
/// horizon of a 64x48 picture either way): rays spawned on it start by the
/// rounding of their own hit, not of the box's size, which pushed them 1.4e6
/// up at 1e20, over the ball whose shadow then vanished
/// (`Primitive::rounding_size`).
#[test]
fn a_ground_reaching_1e50_away_is_found_near_the_camera() {
    let (near, _) = assert_renders_equal(&far_ground_scene(1e4), 64, 48);
    for far in [1e20, 1e30, 1e50] {
        let scene = far_ground_scene(far);
        let (film, _) = assert_renders_equal(&scene, 64, 48);
        assert_same_picture(&film, &near, &format!("the ground reaching {far:e}"));
        // The floor fills the bottom row.
        let bottom = &film.sums()[64 * 47..];
        assert!(
            bottom.iter().all(|p| *p != background(&scene)),
            "reaching {far:e}: the floor is missing"
        );
    }
}

/// The same ground as a polygon and as two triangles at `z = 0`, reaching
/// 1e20, 1e30 and 1e50 away in x and y (a polygon that long in one
/// direction alone is refused as of zero area): the same picture as at 1e4, the ball's shadow
/// on it included. The triangle test found such a ground's hits some 1e4
/// off along grazing rays (its vertices' depths, ±1e20, cancel), and its
/// spawned rays started 1.4e6 above it: the shadow was gone. A polygon in
/// a coordinate plane is now met as a box's face is
/// (`shape::on_plane`).
#[test]
fn a_ground_polygon_reaching_1e50_away_shades_as_one_reaching_1e4() {
    let flat = |x: f64, y: f64| format!("({x:?}, {y:?}, 0)");
    for_planar_grounds_reaching_far(&flat, |film, near, what| {
        assert_same_picture(film, near, what);
    });
}

/// For a ground written by `at` as a polygon and as two triangles, reaching
/// 1e4 and then 1e20, 1e30 and 1e50: `check(film, near, what)` of each far
/// picture against the near one, both with the cells as Roth.
fn for_planar_grounds_reaching_far(
    at: &dyn Fn(f64, f64) -> String,
    check: impl Fn(&Film, &Film, &str),
) {
    for (kind, ground) in [
        (
            "polygon",
            polygon_ground as fn(f64, &dyn Fn(f64, f64) -> String) -> String,
        ),
        ("triangles", triangle_ground),
    ] {
        let scene = |far: f64| far_ground_scene_with(&ground(far, at));
        let (near, _) = assert_renders_equal(&scene(1e4), 64, 48);
        for far in [1e20, 1e30, 1e50] {
            let (film, _) = assert_renders_equal(&scene(far), 64, 48);
            check(&film, &near, &format!("the {kind} reaching {far:e}"));
        }
    }
}

/// The same ground tilted out of every coordinate plane, as a polygon and
/// as two triangles on the plane `z = (x + y) / 64` (every vertex on it
/// exactly: the slope is a power of two), reaching 1e20, 1e30 and 1e50
/// away: every pixel within 1e-6 of the picture at 1e4, the ball's shadow
/// on it included, with the cells as Roth. The triangle test's `t` (its
/// vertices' depths, ±1e20 for a grazing ray, weighed by edge functions
/// near ½) was some 1e4 off at 1e20, so spawned rays had to start 64 ε of
/// the extent (1.4e6) off the ground, over the ball: its shadow was gone
/// (`docs/robustness.md`, "A tilted polygon reaching 1e20"). A planar
/// primitive's `t` is now the plane's, from exact arithmetic
/// (`csg::exact`), wherever its reach dwarfs the hit's distances.
#[test]
fn a_tilted_ground_polygon_reaching_1e50_away_shades_as_one_reaching_1e4() {
    let tilted = |x: f64, y: f64| format!("({x:?}, {y:?}, {:?})", (x + y) / 64.0);
    for_planar_grounds_reaching_far(&tilted, |film, near, what| {
        let bad = fraction_differing(film, near, 1e-6);
        assert!(
            bad == 0.0,
            "{what}, tilted: {bad} of pixels differ from one reaching 1e4"
        );
    });
}

/// Discs for a ground, a cone and a cylinder of height 0.5 and radius
/// 1e20 to 1e45, tilted or not: within the scene their surfaces are flat
/// to 1e-20, and each must shade as a slab of the same reach does (every
/// pixel within 1e-6), the ball's shadow on it included, with the cells as
/// Roth. Found by the scene mutants (seed 21729, a spike of the jagged
/// ball made a cone of base radius 1e30): the cone's quadric, set up in
/// the radius's scale, cancelled out of terms of that size, so its hits
/// were far off; and both were offset by their extent, so their spawned
/// rays started some 1e6 (at 1e20) to 1e16 (at 1e30) away. At 1e20, 5.7%
/// of the pixels of the tilted cone and of the tilted cylinder differed
/// from the slab's, 3.8% of the cylinder's untilted. Now a flat cone is set
/// up in the axial scale (`csg::shape::ConeScale`), and both are offset by
/// the distances their hits are computed from (`shape::axial_size`).
#[test]
fn a_disc_reaching_1e30_shades_as_a_slab() {
    let slab = |far: f64| {
        format!(
            "Box(min: ({x:?}, {x:?}, -0.5), max: ({far:?}, {far:?}, 0))",
            x = -far
        )
    };
    let cone = |far: f64| {
        format!("Cone(base: (0, 0, -0.5), base_radius: {far:?}, top: (0, 0, 0), top_radius: 0)")
    };
    let cylinder =
        |far: f64| format!("Cylinder(base: (0, 0, -0.5), top: (0, 0, 0), radius: {far:?})");
    let tilted = |child: String| format!("Transform(rotate: (4, -3, 0), child: {child}),");
    let plain = |child: String| format!("{child},");
    for (how, place) in [
        ("tilted", &tilted as &dyn Fn(String) -> String),
        ("", &plain),
    ] {
        for far in [1e20, 1e30, 1e45] {
            let scene = |ground: String| far_ground_scene_with(&place(ground));
            let (want, _) = assert_renders_equal(&scene(slab(far)), 64, 48);
            for (kind, disc) in [
                ("cone", &cone as &dyn Fn(f64) -> String),
                ("cylinder", &cylinder),
            ] {
                let (got, _) = assert_renders_equal(&scene(disc(far)), 64, 48);
                let bad = fraction_differing(&got, &want, 1e-6);
                assert!(
                    bad == 0.0,
                    "the {how} {kind} reaching {far:e}: {bad} of pixels differ from the slab"
                );
            }
        }
    }
}

/// A sphere of radius 1e12 to 1e45 for a ground, its top at `z = 0` (a
/// "planet" under the scene): within the scene it is flat to 1e-10, and it
/// must shade as a slab does (every pixel within 1e-6), the ball's shadow
/// on it included, with the cells as Roth. In f64 the power of a ray's
/// origin, `|o − centre|² − r²`, cancels from terms of the radius's square
/// (and `o − centre` rounds the origin away), so hits were off by ε·r and
/// spawned rays offset by 64 ε of the extent: at 1e16 and beyond more than
/// half of the pixels differed from the slab's, at 1e12 a third by 1e-6.
/// Such a sphere's power is now exact (`csg::shape::sphere_hits`).
#[test]
fn a_sphere_ground_of_radius_1e45_shades_as_a_slab() {
    assert_far_grounds_shade_as(slab_ground, |far| {
        vec![format!(
            "Sphere(center: (0, 0, {:?}), radius: {far:?}),",
            -far
        )]
    });
}

/// A slab ground from `(-far, -far)` to `(far, far)`, its top at `z = 0`.
fn slab_ground(far: f64) -> String {
    format!(
        "Box(min: ({x:?}, {x:?}, -0.5), max: ({far:?}, {far:?}, 0)),",
        x = -far
    )
}

/// For radii 1e12 to 1e45: every ground `grounds` writes shades as the one
/// `reference` writes, every pixel within 1e-6 (`far_ground_scene_with`),
/// each with the cells equal to Roth.
fn assert_far_grounds_shade_as(reference: fn(f64) -> String, grounds: impl Fn(f64) -> Vec<String>) {
    for far in [1e12, 1e16, 1e20, 1e30, 1e45] {
        let (want, _) = assert_renders_equal(&far_ground_scene_with(&reference(far)), 64, 48);
        for ground in grounds(far) {
            let (got, _) = assert_renders_equal(&far_ground_scene_with(&ground), 64, 48);
            let bad = fraction_differing(&got, &want, 1e-6);
            assert!(
                bad == 0.0,
                "{ground} at {far:e}: {bad} of pixels differ from {}",
                reference(far)
            );
        }
    }
}

/// An ellipsoid of semi-axes 1e12 to 1e45 for a ground (a unit sphere
/// under a scale that is not uniform, kept in its own space), its top at
/// `z = 0`: flat, lying long, and lying across. Each shades as a slab,
/// every pixel, as the sphere does (`csg::shape::ellipsoid_hits`).
/// Before, mapping the ray's origin rounded it by ε of the reach and the
/// power cancelled: 35% to 37% of the pixels differed at 1e12 (0.2% for
/// the flat one), 61% at 1e20, and all but a few from 1e30 on.
#[test]
fn an_ellipsoid_ground_of_semi_axes_1e45_shades_as_a_slab() {
    assert_far_grounds_shade_as(slab_ground, |far| {
        [
            (far, far, far / 64.0),
            (far, far / 4.0, far),
            (far / 8.0, far, far / 2.0),
        ]
        .iter()
        .map(|&(sx, sy, sz)| {
            format!(
                "Transform(translate: (0, 0, {:?}), scale: ({sx:?}, {sy:?}, {sz:?}), \
                     child: Sphere(center: (0, 0, 0), radius: 1)),",
                -sz
            )
        })
        .collect()
    });
}

/// An elliptic drum of semi-axes 1e12 to 1e45 for a ground (a cylinder
/// under a scale that is not uniform, kept in its own space), lying along
/// x or y, its top at `z = 0`: flat and round-ish. Each shades as a slab,
/// every pixel (`csg::shape::elliptic_drum_hits`). Before, mapping the
/// ray's origin rounded it by ε of the reach and the side's power
/// cancelled, as the ellipsoid's did.
#[test]
fn an_elliptic_drum_ground_of_semi_axes_1e45_shades_as_a_slab() {
    assert_far_grounds_shade_as(slab_ground, |far| {
        [
            ("(0, -1, 0)", "(0, 1, 0)", (far, far, far / 64.0)),
            ("(-1, 0, 0)", "(1, 0, 0)", (far, far / 2.0, far / 4.0)),
            ("(0, 1, 0)", "(0, -1, 0)", (far / 8.0, far, far / 2.0)),
        ]
        .iter()
        .map(|&(base, top, (sx, sy, sz))| {
            format!(
                "Transform(translate: (0, 0, {:?}), scale: ({sx:?}, {sy:?}, {sz:?}), \
                     child: Cylinder(base: {base}, top: {top}, radius: 1)),",
                -sz
            )
        })
        .collect()
    });
}

/// A lying drum of radius 1e12 to 1e45 for a ground, its top along a line
/// through the origin at `z = 0`: a cylinder along y, one along a tilted
/// horizontal axis, open or capped, and a cone of equal radii (NFF's open
/// cylinder). Each shades as a slab, every pixel, as the sphere does
/// (`csg::shape::far_cylinder_roots`). Before, its side's power cancelled
/// as the sphere's did and its spawned rays were offset by its extent:
/// along y with caps at ±6, a third of the pixels differed at 1e12 and
/// 62.5% from 1e20 on; the cone of equal radii, met as a cylinder but
/// offset as a cone, still 3.8% once the cylinder was fixed.
#[test]
fn a_cylinder_ground_of_radius_1e45_shades_as_a_slab() {
    assert_far_grounds_shade_as(slab_ground, |far| {
        let x = -far;
        vec![
            format!(
                "Cylinder(base: (0, {x:?}, {x:?}), top: (0, {far:?}, {x:?}), radius: {far:?}),"
            ),
            format!(
                "Cylinder(base: ({x:?}, {:?}, {x:?}), top: ({far:?}, {:?}, {x:?}), radius: {far:?}, capped: false),",
                2.0 * x,
                2.0 * far
            ),
            format!(
                "Cone(base: (0, {x:?}, {x:?}), base_radius: {far:?}, top: (0, {far:?}, {x:?}), top_radius: {far:?}),"
            ),
        ]
    });
}

/// A cone of radius 1e12 to 1e45 for a ground, its side through the origin
/// tangent to the plane `z = y/64` along a generator: lying along y, its
/// radius growing by 1/64 a unit, and standing as a flat mountain (its
/// radius falling by 64 a unit of height, `shape::ConeScale`). Each shades
/// as a polygon in that plane reaching as far, every pixel, as the drum
/// does (`csg::shape::far_cone_roots`). Before, 37% and 0.1% of the
/// pixels differed at 1e12 and 62% from 1e20 on. (At 1e4 the cones are
/// not yet flat enough near the scene to compare: 0.04% of their radius
/// off the plane a few units across.)
#[test]
fn a_cone_ground_of_radius_1e45_shades_as_its_tangent_plane() {
    assert_far_grounds_shade_as(
        |far| {
            let at = |x: f64, y: f64| format!("({x:?}, {y:?}, {:?})", y / 64.0);
            format!(
                "Polygon(vertices: [{}, {}, {}, {}]),",
                at(-far, -far),
                at(far, -far),
                at(far, far),
                at(-far, far)
            )
        },
        |far| {
            let x = -far;
            vec![
                format!(
                    "Cone(base: (0, {x:?}, {x:?}), base_radius: {:?}, top: (0, {far:?}, {x:?}), top_radius: {:?}),",
                    far * 63.0 / 64.0,
                    far * 65.0 / 64.0
                ),
                format!(
                    "Cone(base: (0, {far:?}, {:?}), base_radius: {:?}, top: (0, {far:?}, {:?}), top_radius: 0),",
                    x / 64.0,
                    2.0 * far,
                    far / 64.0
                ),
            ]
        },
    );
}

/// A square ground polygon from `(-far, -far)` to `(4, 4)`, each vertex
/// written by `at(x, y)`.
fn polygon_ground(far: f64, at: &dyn Fn(f64, f64) -> String) -> String {
    let x = -far;
    format!(
        "Polygon(vertices: [{}, {}, {}, {}]),",
        at(x, x),
        at(4.0, x),
        at(4.0, 4.0),
        at(x, 4.0)
    )
}

/// The same ground as two triangles.
fn triangle_ground(far: f64, at: &dyn Fn(f64, f64) -> String) -> String {
    let x = -far;
    format!(
        "Triangle(a: {}, b: {}, c: {}), Triangle(a: {}, b: {}, c: {}),",
        at(x, x),
        at(4.0, x),
        at(4.0, 4.0),
        at(x, x),
        at(4.0, 4.0),
        at(x, 4.0)
    )
}

/// Two mirrors and a ball on a ground box reaching to `-far` in x.
fn far_ground_scene(far: f64) -> Scene {
    far_ground_scene_with(&format!(
        "Box(min: ({x:?}, -6, -0.1), max: (4, 4, 0)),",
        x = -far
    ))
}

/// Two mirrors and a ball on `ground`.
fn far_ground_scene_with(ground: &str) -> Scene {
    util::scene(&format!(
        "(camera: (eye: (1.6, -2.5, 1.3), look_at: (-2, 0.4, 0.8), fov_y: 50, width: 64, height: 48),
          background: (0.2, 0.25, 0.35), max_depth: 10,
          lights: [(position: (0, -3, 4))],
          materials: {{
            \"mirror\": (color: (0.9, 0.9, 0.9), diffuse: 0.05, specular: 0.5, shininess: 200, reflect: 0.85),
            \"red\": (color: (0.85, 0.15, 0.1), specular: 0.4, shininess: 40),
          }},
          objects: [
            Box(min: (-2.1, -3, 0), max: (-2, 3, 3), material: \"mirror\"),
            Box(min: (2, -3, 0), max: (2.1, 3, 3), material: \"mirror\"),
            Sphere(center: (0, 0.5, 0.6), radius: 0.6, material: \"red\"),
            {ground}
          ])"
    ))
}

/// A room's back wall a hair behind the eye plane (1e-7, 1e-12, 0), seen
/// in a mirror across the room and met by shadow rays: the cells find it
/// as Roth does. Found by the mutants below: at 1e-7 the wall's cell ended
/// 1.2e-15 past it, padded by its depth alone, within a rounding of the
/// walk's crossing from 7 away, and 43 of 3,072 pixels missed the wall.
#[test]
fn a_wall_a_hair_behind_the_eye_plane_is_found() {
    for y in ["-1e-7", "-1e-12", "-0"] {
        assert_renders_equal(&wall_behind_eye_scene(y), 64, 48);
    }
}

/// A rod of `behind_eye.ron` made a disc of radius 1e20 or 1e50 (one of
/// them also reaching a million behind the eye), enclosing the room and
/// the camera: the cells keep it wherever it is. Found by the mutants
/// below (seeds 4469 and 2105 of a longer run): clipping its box, a
/// million million times wider than deep, by a super cell's side planes
/// put the crossings some 1e4 off, and the box was clipped out of cells
/// it fills (`projection::CLIP_ROUNDING`).
#[test]
fn a_disc_reaching_1e20_around_the_camera_is_in_every_cell_it_fills() {
    let rod = "Cylinder(base: (1.4, -6, -0.8), top: (1.4, 5, -0.8), radius: 0.2,";
    for disc in [
        "Cylinder(base: (1.4, -6, -0.8), top: (1.4, 5, -0.8), radius: 1e20,",
        "Cylinder(base: (1.4, -6, -0.8), top: (1.4, -1e6, -0.8), radius: 1e50,",
    ] {
        assert_edited_scene_renders_equal("behind_eye.ron", &[(rod, disc)]);
    }
}

/// `behind_eye.ron`'s slab cut off at the eye plane (its far face at
/// y = −0, so that its front part projects to the screen's edge at −∞)
/// and the room open below: the rod next to it is found. Found by the
/// mutants (seed 2821 of a longer run): the screen was split at
/// y = −7e307 beside the slab, and clipping the rod's box by that super
/// cell's side plane took −c·z past f64's range, so the rod was left out
/// of cells it crosses and 4 of 108 pixels saw past it.
#[test]
fn a_box_ending_at_the_eye_plane_leaves_its_neighbours_in_their_cells() {
    assert_edited_scene_renders_equal(
        "behind_eye.ron",
        &[
            (
                "Box(min: (-0.8, -2, -1.6), max: (0.8, 2, -1.3)",
                "Box(min: (-0.8, -2, -1.6), max: (0.8, -0, -1.3)",
            ),
            (
                "Box(min: (-6, -8, -3), max: (6, 7, 5))",
                "Box(min: (-6, -8, -0), max: (6, 7, 5))",
            ),
        ],
    );
}

/// `scenes/small/mirror.ron`'s left mirror stretched from x = −1e20 to
/// 1e30, so that the camera is inside it, half a unit from its face: the
/// cells find its inside as Roth does. Found by the mutants (seed 36595
/// of a longer run): at 1e20 its camera coordinates lost its thickness of
/// 6 to rounding, it projected to half the screen, and 113 rays of a
/// 12x9 render missed it (`View::eye_at_boundary`).
#[test]
fn a_box_around_the_camera_reaching_1e30_is_found_from_inside() {
    let mirror = "Box(min: (-2.1, -3, 0), max: (-2, 3, 3)";
    for reach in [
        "Box(min: (-1e20, -3, 0), max: (1e30, 3, 3)",
        "Box(min: (-1e30, -3, 0), max: (1e20, 3, 3)",
    ] {
        assert_edited_scene_renders_equal("mirror.ron", &[(mirror, reach)]);
    }
}

/// A rotated post reaching 1e30 up, in the ball's shadow, shades exactly as
/// one reaching 1e4 (both beyond the picture's top). Rays spawned on it
/// start by the rounding of mapping their origin into its space, not by
/// its size, which pushed them 1.4e16 off (`Primitive::rounding_size`;
/// mutant seeds 4663 and 18369 of a longer run, a post and a chair's leg
/// of `house.ron`).
#[test]
fn a_rotated_post_reaching_1e30_shades_as_one_reaching_1e4() {
    let floor = "Box(min: (-4, -6, -0.1), max: (4, 4, 0), material: \"floor\"),";
    let post = |top: &str| {
        format!(
            "{floor} Transform(rotate: (0, 0, 30), translate: (0, 1.3, 0), \
             child: Box(min: (-0.07, -0.07, 0), max: (0.07, 0.07, {top}))),"
        )
    };
    let near = edited_small_scene("mirror.ron", &[(floor, &post("1e4"))]);
    let (near, _) = assert_renders_equal(&near, 64, 48);
    for top in ["1e20", "1e30"] {
        let scene = edited_small_scene("mirror.ron", &[(floor, &post(top))]);
        let (film, _) = assert_renders_equal(&scene, 64, 48);
        assert_same_picture(&film, &near, &format!("the post reaching {top}"));
    }
}

/// A light on an edge or at a corner of a box that holds the camera: the
/// shadow rays from inside the box reach it without crossing a surface,
/// and the cells must not take the light for outside the solid and stop
/// them (`cells::leaf_side`). Found by the mutants (seed 24886 of a longer
/// run, the box reaching 1e50): one line through the light touched the box
/// at its edge alone, and 427 shadow rays of a 12x9 render were stopped.
#[test]
fn a_light_on_the_edge_of_a_box_holding_the_camera_is_not_outside_it() {
    let mirror = "Box(min: (-2.1, -3, 0), max: (-2, 3, 3)";
    let around = "Box(min: (-2.1, -3, 0), max: (4, 3, 3)";
    for light in ["(0, -3, 3)", "(4, -3, 3)", "(4, 3, 0)"] {
        assert_edited_scene_renders_equal(
            "mirror.ron",
            &[
                (mirror, around),
                ("(position: (0, -3, 4))", &format!("(position: {light})")),
            ],
        );
    }
}

/// `scenes/small/NAME` with each `(from, to)` edit made (each `from` must
/// be there) renders alike with the cells and Roth at 12x9, the mutants'
/// size, and 64x48.
fn assert_edited_scene_renders_equal(name: &str, edits: &[(&str, &str)]) {
    let scene = edited_small_scene(name, edits);
    for (w, h) in [(12, 9), (64, 48)] {
        assert_renders_equal(&scene, w, h);
    }
}

/// `scenes/small/NAME` with each `(from, to)` edit made; each `from` must
/// be there, or the test would no longer test what it says.
fn edited_small_scene(name: &str, edits: &[(&str, &str)]) -> Scene {
    let text = std::fs::read_to_string(util::repo(&format!("scenes/small/{name}"))).unwrap();
    let mut edited = text.clone();
    for (from, to) in edits {
        assert!(text.contains(from), "{name} changed: no {from}");
        edited = edited.replace(from, to);
    }
    util::scene(&edited)
}

/// `scenes/small/behind_eye.ron` with its back wall's near face at `y`.
fn wall_behind_eye_scene(y: &str) -> Scene {
    edited_small_scene(
        "behind_eye.ron",
        &[(
            "Box(min: (-5.8, -7.8, -2.8), max: (5.8, 6.8, 4.8))",
            &format!("Box(min: (-5.8, {y}, -2.8), max: (5.8, 6.8, 4.8))"),
        )],
    )
}

/// The spans of the numbers in a scene's text (comments included: a
/// mutant there changes nothing, which costs one of the tries).
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && b.get(i + 1).is_some_and(u8::is_ascii_digit));
        let after_word = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if !starts || after_word {
            i += 1;
            continue;
        }
        let start = i;
        i += 1;
        while i < b.len()
            && (b[i].is_ascii_digit()
                || b"._eE".contains(&b[i])
                || (b[i] == b'-' && b"eE".contains(&b[i - 1])))
        {
            i += 1;
        }
        spans.push((start, i));
    }
    spans
}

/// The bundled scenes with one to three of their numbers made extreme, as
/// a fuzzer would: each mutant loads with an error, or renders with the
/// cells exactly as Roth renders it (12x9, both BSP rules; every eighth
/// also on the machine), and never panics. 500 mutants, a seed each;
/// hunts: `HYPERCAST_SEEDS=a..b`, `HYPERCAST_SIZE=WxH`. Such mutants found the far-reaching floor above, the overflow
/// past 1e77 behind `scene::load::MAX_COORDINATE`, and (this test, in the
/// dev profile's debug assertions) a material colour of 1e50 whose
/// shadow rays' weights were infinite (`MAX_INTENSITY`).
#[test]
fn bundled_scenes_with_extreme_numbers_load_with_an_error_or_render_as_roth_does() {
    use hypercast::scene::{SceneSyntax, parse_scene_str};
    const VALUES: [&str; 14] = [
        "1e50", "-1e50", "1e30", "-1e30", "1e20", "-1e20", "1e-30", "0", "-0", "1e6", "-1e6", "3",
        "0.001", "65536",
    ];
    let mut seeds = Vec::new();
    for dir in ["scenes", "scenes/small"] {
        for e in std::fs::read_dir(util::repo(dir)).unwrap().flatten() {
            let path = e.path();
            let syntax = match path.extension().and_then(|x| x.to_str()) {
                Some("ron") => SceneSyntax::Ron,
                // The level-2 sphereflake: 91 spheres; the larger ones
                // take the test's time for the same code.
                Some("nff") if path.ends_with("sphereflake2.nff") => SceneSyntax::Nff,
                _ => continue,
            };
            let text = std::fs::read_to_string(&path).unwrap();
            let spans = number_spans(&text);
            seeds.push((path, syntax, text, spans));
        }
    }
    assert!(seeds.len() >= 8, "{} scenes", seeds.len());
    let (w, h) = crate::cells::hunt_size().unwrap_or((12, 9));
    let mutants = crate::cells::seeds(0..500);
    let count = mutants.clone().count();
    let (mut rendered, mut refused) = (0, 0);
    for seed in mutants {
        // xorshift needs a non-zero state; the odd multiplier keeps seeds apart.
        let mut rng = Rng((0x5EED_F00D_1234_5678 ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)) | 1);
        let (path, syntax, text, spans) = &seeds[rng.below(seeds.len())];
        let mut picked: Vec<(usize, usize)> = (0..1 + rng.below(3))
            .map(|_| spans[rng.below(spans.len())])
            .collect();
        picked.sort_unstable();
        picked.dedup();
        let mut mutant = text.clone();
        let mut what = Vec::new();
        // From the back, so that earlier spans stay where they were.
        for &(a, b) in picked.iter().rev() {
            let value = VALUES[rng.below(VALUES.len())];
            what.push(format!("{} -> {value}", &text[a..b]));
            mutant.replace_range(a..b, value);
        }
        let Ok(scene) = parse_scene_str(&mutant, *syntax, path) else {
            refused += 1;
            continue;
        };
        rendered += 1;
        let result = std::panic::catch_unwind(|| assert_renders_equal(&scene, w, h));
        let Ok((roth, _)) = result else {
            panic!(
                "seed {seed}: {} with {}: the accelerators differ (above); the mutant:\n{mutant}",
                path.display(),
                what.join(", ")
            );
        };
        // Every eighth also on the machine (d = 1 to 3, nodes of 64 MiB so
        // that no mutant is refused for its size): the same picture.
        if seed % 8 == 0 {
            let d = 1 + (seed / 8 % 3) as u32;
            let topo = hypercast::machine::Topology::ipsc_d5()
                .with_overrides(Some(d), Some(64 << 20))
                .unwrap();
            let o = hypercast::machine::MachineOptions::new(w, h, 1);
            let (film, _, _) = hypercast::machine::render(&scene, &topo, &o, &|_| {})
                .unwrap_or_else(|e| {
                    panic!(
                        "seed {seed}: {} with {}: d = {d}: {e}",
                        path.display(),
                        what.join(", ")
                    )
                });
            assert_eq!(
                film.sums(),
                roth.sums(),
                "seed {seed}: {} with {}: d = {d} differs",
                path.display(),
                what.join(", ")
            );
        }
    }
    // Both outcomes occur, or the mutants test nothing.
    assert!(
        count < 500 || rendered >= 40 && refused >= 10,
        "{rendered} rendered, {refused} refused"
    );
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 24: spawned rays never hit the surface they leave.

/// Case 24's scene: the one primitive `shape` of size about `r`, scaled,
/// rotated and translated, in glass or not, seen from 100 r away.
fn placed_alone(
    shape: &str,
    r: f64,
    (scale, rotate, translate): (Vec3, Vec3, Vec3),
    glass: bool,
) -> Scene {
    let (materials, material) = if glass {
        (
            "materials: { \"glass\": (transmit: 1, ior: 1.5) },",
            ", material: \"glass\"",
        )
    } else {
        ("", "")
    };
    util::scene(&format!(
        "(camera: (eye: (0, 0, {:?}), look_at: (0, 0, 0), up: (0, 1, 0), fov_y: 40, width: 8, height: 8),
          {materials}
          objects: [Transform(scale: {}, rotate: {}, translate: {}, child: {shape}{material})])",
        100.0 * r,
        v(scale),
        v(rotate),
        v(translate)
    ))
}

/// pbrt's re-intersection test: spheres and cylinders of radius
/// 10^U(−6, 6), under random rotations, scales and translations; at a hit,
/// 1000 rays leave from the offset origin on the outer side and must not
/// hit the solid again, and 1000 on the inner side must first meet the
/// surface at its far side, never at the point they left. A refracted ray
/// through a sphere leaves it after exactly the chord `2r·cos θt`.
#[test]
fn case_24_spawned_rays_never_hit_the_surface_they_leave() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut self_hits, mut spawned) = (0usize, 0usize);
    for case in 0..80 {
        let r = 10f64.powf(rng.range(-6.0, 6.0));
        let uniform = case % 3 != 2;
        let scale = if uniform {
            Vec3::splat(rng.range(0.5, 2.0))
        } else {
            rng.vec(0.5, 2.0)
        };
        let rotate = rng.vec(0.0, 360.0);
        // Near the origin at the solid's own scale, or up to 1000 away
        // whatever its size (tiny solids far out: only self-hits are
        // checked there, as 1e-9 of a 1e-6 chord is below the ulps of 1000).
        let far = case % 5 == 4;
        let translate = rng.vec(-10.0, 10.0) * if far { 100.0 } else { r };
        let shape = if case % 2 == 0 {
            format!("Sphere(center: (0, 0, 0), radius: {r:?})")
        } else {
            format!(
                "Cylinder(base: {}, top: {}, radius: {r:?})",
                v(Vec3::new(0.0, 0.0, -r)),
                v(Vec3::new(0.0, 0.0, r * 1.5))
            )
        };
        let scene = placed_alone(&shape, r, (scale, rotate, translate), true);
        let prim = &scene.primitives[0];
        let mut roth = RothTracer::new(&scene);
        let centre = (prim.bounds.min + prim.bounds.max) * 0.5;
        let size = (prim.bounds.max - prim.bounds.min).max_element();
        for _ in 0..4 {
            // A ray from outside at the solid's middle, slightly off centre.
            let from = centre + rng.direction() * (10.0 * size);
            let to = centre + rng.direction() * (0.2 * size);
            let ray = Ray::new(from, to - from);
            let Some(hit) = roth.nearest(&ray, 0.0, f64::INFINITY) else {
                continue;
            };
            let p = ray.at(hit.t);
            let n = prim.normal(&ray, hit.t, hit.part);
            assert!(hit.t.is_finite() && n.is_finite(), "{hit:?} {n}");
            let out = offset_origin(&ray, hit.t, p, n, prim.rounding_size(p, hit.part));
            let inside = offset_origin(&ray, hit.t, p, -n, prim.rounding_size(p, hit.part));
            for _ in 0..1000 {
                let d = rng.direction();
                let (o, d) = if d.dot(n) > 0.0 { (out, d) } else { (out, -d) };
                spawned += 1;
                if let Some(h) = roth.nearest(&Ray::new(o, d), 0.0, f64::INFINITY) {
                    assert!(h.t.is_finite());
                    self_hits += 1;
                }
                let d = -d;
                spawned += 1;
                match roth.nearest(&Ray::new(inside, d), 0.0, f64::INFINITY) {
                    // Convex: the far side, at a distance of the solid's
                    // order unless the ray skims along the surface.
                    Some(h) if (h.t * d.length()) > 1e-9 * size || d.dot(n) > -1e-6 => {}
                    other => {
                        self_hits += 1;
                        eprintln!("self-hit {other:?} from {inside} along {d}");
                    }
                }
            }
            // The refracted ray through a sphere: chord 2r·cos θt.
            if case % 2 == 0 && uniform && !far {
                let dn = ray.dir.normalize();
                let Refraction::Transmitted(t) = refract(dn, n, 1.0 / 1.5) else {
                    panic!("entering glass never reflects totally");
                };
                let exit = roth
                    .nearest(&Ray::new(inside, t), 0.0, f64::INFINITY)
                    .expect("the refracted ray leaves the sphere");
                let radius = r * scale.x;
                let cos_t = -t.dot(n);
                assert_rel(exit.t, 2.0 * radius * cos_t, 1e-9);
                assert_eq!(exit.prim, PrimId(0));
            }
        }
        // The surface is no sheet: the scene's only primitive is solid.
        assert!(matches!(
            prim.intersect(&Ray::new(centre, Vec3::Z)),
            PrimHits::Solid { .. }
        ));
        assert!(matches!(
            prim.shape,
            Shape::Sphere { .. } | Shape::Cylinder { .. }
        ));
    }
    assert!(spawned > 100_000, "{spawned} rays spawned");
    assert_eq!(
        self_hits, 0,
        "{self_hits} of {spawned} spawned rays hit their own surface"
    );
}

/// Spawns `per_side` rays in random directions from the hit at `t` of
/// `ray` (normal `n`), offset to each side of the surface as the shader
/// offsets them, the primitive not left out; returns how many it spawned
/// and how many met a surface within 1e-9 of the size of `prim` (the
/// primitive hit on `part`, whose `rounding_size` the offset takes) of
/// their start.
fn spawn_around(
    roth: &mut RothTracer,
    prim: &Primitive,
    ray: &Ray,
    (t, part): (f64, u8),
    n: Vec3,
    per_side: usize,
    rng: &mut Rng,
) -> (usize, usize) {
    let (mut spawned, mut self_hits) = (0, 0);
    let size = (prim.bounds.max - prim.bounds.min).max_element();
    roth.leaving(None);
    for side in [n, -n] {
        let o = offset_origin(ray, t, ray.at(t), side, prim.rounding_size(ray.at(t), part));
        for _ in 0..per_side {
            let mut d = rng.direction();
            if d.dot(side) < 0.0 {
                d = -d;
            }
            spawned += 1;
            if let Some(h) = roth.nearest(&Ray::new(o, d), 0.0, f64::INFINITY)
                && h.t * d.length() < 1e-9 * size
            {
                self_hits += 1;
                eprintln!("self-hit {h:?} from {o} along {d}, {side} off the surface");
            }
        }
    }
    (spawned, self_hits)
}

/// Case 24 for the other shapes, at the same extreme scales: boxes, fat,
/// thin and blunt cones, thin cylinders and triangles, r = 10^U(−6,6),
/// random rotations, scales (a third non-uniform) and translations. Rays
/// spawned from a hit, to either side of the surface, the primitive not
/// left out, never meet it within 1e-9 of its size.
#[test]
fn case_24_spawned_rays_miss_the_surface_they_leave_on_every_shape() {
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);
    for kind in 0..5 {
        let (mut self_hits, mut spawned) = (0usize, 0usize);
        for case in 0..60 {
            let r = 10f64.powf(rng.range(-6.0, 6.0));
            let scale = if case % 3 == 2 {
                rng.vec(0.5, 2.0)
            } else {
                Vec3::splat(rng.range(0.5, 2.0))
            };
            let rotate = rng.vec(0.0, 360.0);
            let translate = rng.vec(-10.0, 10.0) * if case % 5 == 4 { 100.0 } else { r };
            let z = |h: f64| v(Vec3::new(0.0, 0.0, h * r));
            // The shape, and how far off its middle rays are aimed.
            let (shape, aim) = match kind {
                0 => (
                    format!(
                        "Box(min: {}, max: {})",
                        v(Vec3::new(-r, -0.5 * r, -2.0 * r)),
                        v(Vec3::new(r, 0.5 * r, 0.3 * r))
                    ),
                    0.2,
                ),
                1 => (
                    format!(
                        "Cone(base: {}, base_radius: {r:?}, top: {}, top_radius: 0)",
                        z(-1.0),
                        z(3.0)
                    ),
                    0.2,
                ),
                2 => (
                    format!(
                        "Cone(base: {}, base_radius: {:?}, top: {}, top_radius: {:?})",
                        z(-1.0),
                        0.05 * r,
                        z(8.0),
                        0.01 * r
                    ),
                    0.005,
                ),
                3 => (
                    format!(
                        "Cylinder(base: {}, top: {}, radius: {:?})",
                        z(-1.0),
                        z(10.0),
                        0.05 * r
                    ),
                    0.005,
                ),
                _ => (
                    format!(
                        "Triangle(a: {}, b: {}, c: {})",
                        v(Vec3::new(-r, -r, 0.0)),
                        v(Vec3::new(r, -0.3 * r, 0.1 * r)),
                        v(Vec3::new(0.0, r, -0.2 * r))
                    ),
                    0.2,
                ),
            };
            let scene = placed_alone(&shape, r, (scale, rotate, translate), false);
            let prim = &scene.primitives[0];
            let mut roth = RothTracer::new(&scene);
            let centre = (prim.bounds.min + prim.bounds.max) * 0.5;
            let size = (prim.bounds.max - prim.bounds.min).max_element();
            for _ in 0..20 {
                let from = centre + rng.direction() * (10.0 * size);
                let to = centre + rng.vec(-aim, aim) * size;
                let ray = Ray::new(from, to - from);
                let Some(hit) = roth.nearest(&ray, 0.0, f64::INFINITY) else {
                    continue;
                };
                let n = prim.normal(&ray, hit.t, hit.part);
                let (made, met) =
                    spawn_around(&mut roth, prim, &ray, (hit.t, hit.part), n, 50, &mut rng);
                (spawned, self_hits) = (spawned + made, self_hits + met);
            }
        }
        assert!(spawned > 20_000, "shape {kind}: {spawned} rays spawned");
        assert_eq!(
            self_hits, 0,
            "shape {kind}: {self_hits} of {spawned} self-hits"
        );
    }
}

/// Case 24 for thin cones, the jagged ball's spikes (a radius of a tenth of
/// their length or less, seen from a few lengths away). Their crossings
/// were once 5e-14 of `t` off (the discriminant's cancellation,
/// `shape::cone_disc`), more than a spawned ray's offset: 4% of the shadow
/// rays leaving a spike met it again, and 2.3% of the rays spawned into
/// it, at `t` near 1e-14; `jagged_ball.ron` showed dark specks on its
/// spikes. Now: no ray spawned from a spike's surface, outward or inward,
/// meets it within 1e-9 of its size; and with the spike left out
/// (`RayJob::leaving`, which the shader sets for shadow rays leaving it),
/// every shadow ray reaches its light.
#[test]
fn case_24_rays_leaving_a_thin_cone_never_meet_it_at_their_start() {
    let mut rng = Rng(0x5B1C_E0F5_9A17_3C4D);
    let (mut shadow_rays, mut spawned, mut self_hits) = (0usize, 0usize, 0usize);
    // Solid spikes (capped, as the jagged ball's), pointed or blunt.
    for case in 0..40 {
        let tip = rng.direction() * rng.range(0.3, 1.5);
        let scene = util::scene(&format!(
            "(camera: (eye: (0, -4, 1), look_at: (0, 0, 0), fov_y: 40, width: 8, height: 8),
              lights: [(position: {}), (position: {})],
              objects: [Transform(rotate: {}, translate: {}, child: Cone(base: (0, 0, 0), base_radius: {:?}, top: {}, top_radius: {:?}))])",
            v(rng.direction() * 6.0),
            v(rng.direction() * 3.0),
            v(rng.vec(0.0, 360.0)),
            v(rng.vec(-0.5, 0.5)),
            rng.range(0.02, 0.12),
            v(tip),
            if case % 2 == 0 { 0.0 } else { 0.01 },
        ));
        let shader = Shader::new(&scene);
        let mut roth = RothTracer::new(&scene);
        let prim = &scene.primitives[0];
        let centre = (prim.bounds.min + prim.bounds.max) * 0.5;
        let size = (prim.bounds.max - prim.bounds.min).max_element();
        for _ in 0..500 {
            let from = centre + rng.direction() * (5.0 * size);
            let to = centre + rng.vec(-0.3, 0.3) * size;
            let job = RayJob {
                ray: Ray::new(from, to - from),
                kind: RayKind::Reflected,
                pixel: 0,
                depth: 1,
                weight: [1.0; 3],
                t_max: f64::INFINITY,
                leaving: None,
                light: None,
            };
            roth.leaving(None);
            let Some(hit) = roth.nearest(&job.ray, 0.0, f64::INFINITY) else {
                continue;
            };
            // Rays spawned at the hit to either side, the spike not left
            // out: the first crossing ahead is the far side, never the
            // point they start at.
            let n = prim.normal(&job.ray, hit.t, hit.part);
            let (made, met) =
                spawn_around(&mut roth, prim, &job.ray, (hit.t, hit.part), n, 4, &mut rng);
            (spawned, self_hits) = (spawned + made, self_hits + met);
            // The shader's shadow rays, the spike left out.
            let mut jobs = Vec::new();
            shader.shade(&job, &hit, &mut |j| jobs.push(j));
            for j in jobs.iter().filter(|j| j.kind == RayKind::Shadow) {
                shadow_rays += 1;
                assert_eq!(j.leaving, Some(PrimId(0)), "{j:?}");
                roth.leaving(j.leaving);
                let blocked = roth.shadow(&j.ray, 0.0, j.t_max);
                assert!(blocked.is_none(), "{j:?} stopped at {blocked:?}");
            }
        }
    }
    assert!(
        shadow_rays > 3_000 && spawned > 30_000,
        "{shadow_rays} shadow rays, {spawned} spawned"
    );
    assert_eq!(
        self_hits, 0,
        "{self_hits} of {spawned} spawned rays met the spike they leave"
    );
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 29: a closed mesh crossed through its edges and vertices.

/// The cube `[−1, 1]³` as 12 triangles, each face split along a diagonal,
/// or as 6 square polygons (which the loader triangulates).
fn mesh_cube(polygons: bool) -> String {
    let mut s = String::new();
    for axis in 0..3 {
        for side in [-1.0, 1.0] {
            let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |a: f64, b: f64| {
                let mut p = Vec3::ZERO;
                p[axis] = side;
                p[u] = a;
                p[w] = b;
                p
            };
            let q = [
                corner(-1.0, -1.0),
                corner(1.0, -1.0),
                corner(1.0, 1.0),
                corner(-1.0, 1.0),
            ];
            if polygons {
                let vs: Vec<String> = q.iter().map(|p| v(*p)).collect();
                s += &format!("Polygon(vertices: [{}]),", vs.join(", "));
                continue;
            }
            for [i, j, k] in [[0, 1, 2], [0, 2, 3]] {
                s += &format!("Triangle(a: {}, b: {}, c: {}),", v(q[i]), v(q[j]), v(q[k]));
            }
        }
    }
    s
}

/// Rays through the mesh's edges, its vertices and the faces' inner
/// diagonals cross it exactly twice (once in, once out), and its picture
/// covers exactly the pixels the solid box covers; for triangles and for
/// polygons.
#[test]
fn case_29_closed_meshes_are_crossed_once_per_side() {
    for polygons in [false, true] {
        closed_mesh_is_crossed_once_per_side(polygons);
    }
}

fn closed_mesh_is_crossed_once_per_side(polygons: bool) {
    let cam = camera(Vec3::new(4.0, -3.0, 5.0), Vec3::ZERO, Vec3::Z, 50.0, 33, 33);
    let mesh = util::scene(&format!(
        "(camera: {cam}, background: (0, 0, 1), materials: {{ \"flat\": (color: (1, 0, 0), ambient: 1, diffuse: 0) }},
          objects: [Union(material: \"flat\", children: [{}])])",
        mesh_cube(polygons)
    ));
    let mut rays = vec![
        (Vec3::splat(5.0), -Vec3::ONE),
        (Vec3::new(5.0, -5.0, 5.0), Vec3::new(-1.0, 1.0, -1.0)),
        (Vec3::new(5.0, 0.3, 5.0), Vec3::new(-1.0, 0.0, -1.0)),
        (Vec3::new(0.3, -5.0, 5.0), Vec3::new(0.0, 1.0, -1.0)),
    ];
    // On and off the faces' inner diagonals (not in a face's plane: a ray
    // along a face crosses nothing).
    for (a, b) in [
        (0.0, 0.0),
        (0.5, 0.5),
        (-0.5, -0.5),
        (0.5, -0.5),
        (-0.25, 0.25),
    ] {
        for axis in 0..3 {
            let mut o = Vec3::splat(a);
            o[(axis + 1) % 3] = b;
            o[axis] = 5.0;
            let mut d = Vec3::ZERO;
            d[axis] = -1.0;
            rays.push((o, d));
        }
    }
    for (o, d) in rays {
        let got = pts(&along(&mesh, &Ray::new(o, d)));
        assert_eq!(got.len(), 2, "polygons {polygons}, {o} {d}: {got:?}");
        assert!((got[1].1 - got[0].1) > 0.0, "{o} {d}: {got:?}");
    }
    let film = assert_renders_equal(&mesh, 33, 33).0;
    let solid = util::scene(&format!(
        "(camera: {cam}, background: (0, 0, 1), materials: {{ \"flat\": (color: (1, 0, 0), ambient: 1, diffuse: 0) }},
          objects: [Box(min: (-1, -1, -1), max: (1, 1, 1), material: \"flat\")])"
    ));
    let (box_film, _) = util::roth(&solid, 33, 33);
    assert_same_picture(
        &film,
        &box_film,
        &format!("mesh cube (polygons {polygons}) against the box"),
    );
}
