//! Unit tests of the primitives: hit distances and normals against closed
//! forms computed independently here, and `ROBUSTNESS.md` cases 1-8 and 29
//! at the primitive level. Every intersection goes through `hits`, which
//! asserts that no `t` or normal is NaN or infinite and that normals are
//! unit length.

use super::*;
use crate::geom::{Affine, Ray, Vec3};
use crate::testing::uniform;

fn v(x: f64, y: f64, z: f64) -> Vec3 {
    Vec3::new(x, y, z)
}

fn prim(shape: Shape) -> Primitive {
    Primitive::new(shape, &Affine::IDENTITY, MaterialId::DEFAULT)
}

fn placed(shape: Shape, m: &Affine) -> Primitive {
    Primitive::new(shape, m, MaterialId::DEFAULT)
}

fn sphere(center: Vec3, radius: f64) -> Primitive {
    prim(Shape::Sphere { center, radius })
}

fn aabox(min: Vec3, max: Vec3) -> Primitive {
    prim(Shape::Box { min, max })
}

fn cylinder(base: Vec3, top: Vec3, radius: f64, capped: bool) -> Primitive {
    prim(Shape::Cylinder {
        base,
        top,
        radius,
        capped,
    })
}

fn cone(base: Vec3, base_radius: f64, top: Vec3, top_radius: f64, capped: bool) -> Primitive {
    prim(Shape::Cone {
        base,
        base_radius,
        top,
        top_radius,
        capped,
    })
}

fn triangle(a: Vec3, b: Vec3, c: Vec3) -> Primitive {
    prim(Shape::Triangle { a, b, c })
}

/// The crossings of a result, in order.
fn crossings(h: &PrimHits) -> Vec<Crossing> {
    match *h {
        PrimHits::Miss => vec![],
        PrimHits::Solid { enter, exit } => vec![enter, exit],
        PrimHits::Sheet { hits, count } => hits[..usize::from(count)].to_vec(),
    }
}

/// Intersects and checks the invariants: finite `t`, unit finite normals,
/// `enter.t < exit.t`, sheets sorted with at most two crossings, solids
/// never returning sheets and surfaces never returning spans.
fn hits(p: &Primitive, o: Vec3, d: Vec3) -> PrimHits {
    let ray = Ray::new(o, d);
    let h = p.intersect(&ray);
    match h {
        PrimHits::Miss => {}
        PrimHits::Solid { enter, exit } => {
            assert!(p.is_solid(), "a surface returned a span: {h:?}");
            assert!(enter.t < exit.t, "empty span {h:?}");
        }
        PrimHits::Sheet { hits, count } => {
            assert!(!p.is_solid(), "a solid returned a sheet: {h:?}");
            assert!((1..=2).contains(&count), "sheet with {count} crossings");
            if count == 2 {
                assert!(hits[0].t <= hits[1].t, "unsorted sheet {h:?}");
            }
        }
    }
    for c in crossings(&h) {
        assert!(c.t.is_finite(), "non-finite t in {h:?} for {ray:?}");
        let n = p.normal(&ray, c.t, c.part);
        assert!(n.is_finite(), "non-finite normal {n} at {c:?} for {ray:?}");
        assert!(
            (n.length() - 1.0).abs() < 1e-12,
            "normal {n} not unit at {c:?}"
        );
    }
    h
}

/// The span of a solid hit; panics on anything else.
fn span(p: &Primitive, o: Vec3, d: Vec3) -> (Crossing, Crossing) {
    match hits(p, o, d) {
        PrimHits::Solid { enter, exit } => (enter, exit),
        other => panic!("expected a span for o={o} d={d}, got {other:?}"),
    }
}

fn is_miss(p: &Primitive, o: Vec3, d: Vec3) -> bool {
    hits(p, o, d) == PrimHits::Miss
}

fn normal_at(p: &Primitive, o: Vec3, d: Vec3, c: Crossing) -> Vec3 {
    p.normal(&Ray::new(o, d), c.t, c.part)
}

#[track_caller]
fn assert_close(got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "got {got:e}, want {want:e} (±{tol:e})"
    );
}

#[track_caller]
fn assert_vec_close(got: Vec3, want: Vec3, tol: f64) {
    assert!(
        (got - want).abs().max_element() <= tol,
        "got {got}, want {want} (±{tol:e})"
    );
}

// ---------------------------------------------------------------- spheres

#[test]
fn sphere_hits_and_normals_match_closed_form() {
    let c = v(1.0, 2.0, 3.0);
    let s = sphere(c, 2.0);
    let (o, d) = (v(1.0, 2.0, -7.0), v(0.0, 0.0, 1.0));
    let (e, x) = span(&s, o, d);
    assert_eq!((e.t, x.t), (8.0, 12.0));
    assert_eq!(normal_at(&s, o, d, e), v(0.0, 0.0, -1.0));
    assert_eq!(normal_at(&s, o, d, x), v(0.0, 0.0, 1.0));
    // A non-unit direction scales t.
    let (e, x) = span(&s, o, v(0.0, 0.0, 4.0));
    assert_eq!((e.t, x.t), (2.0, 3.0));
    // Off-centre by 1 along y: the chord is at x − 1 = ∓√3.
    let (o, d) = (v(-10.0, 3.0, 3.0), v(3.0, 0.0, 0.0));
    let (e, x) = span(&s, o, d);
    let r3 = 3f64.sqrt();
    assert_close(e.t, (11.0 - r3) / 3.0, 1e-14);
    assert_close(x.t, (11.0 + r3) / 3.0, 1e-14);
    assert_vec_close(normal_at(&s, o, d, e), v(-r3 / 2.0, 0.5, 0.0), 1e-14);
    assert_vec_close(normal_at(&s, o, d, x), v(r3 / 2.0, 0.5, 0.0), 1e-14);
    // From the centre: negative t is kept (never clipped here).
    let (e, x) = span(&s, c, v(0.0, 1.0, 0.0));
    assert_eq!((e.t, x.t), (-2.0, 2.0));
    // Miss, and an exact tangent (zero-length span) is a miss too.
    assert!(is_miss(&s, v(1.0, 4.5, -7.0), v(0.0, 0.0, 1.0)));
    assert!(is_miss(&s, v(1.0, 4.0, -7.0), v(0.0, 0.0, 1.0)));
    assert!(is_miss(&s, v(3.0, 2.0, -7.0), v(0.0, 0.0, 0.5)));
}

#[test]
fn sphere_case1_far_and_tiny_spheres_keep_their_precision() {
    let s = sphere(v(0.0, 0.0, 1e8), 1.0);
    let (e, x) = span(&s, Vec3::ZERO, v(0.0, 0.0, 1.0));
    let want = 1e8 - 1.0;
    assert!((e.t - want).abs() <= 1e-15 * want, "t0 = {}", e.t);
    assert!((x.t - (1e8 + 1.0)).abs() <= 1e-15 * 1e8, "t1 = {}", x.t);
    // Same with a non-unit direction.
    let (e, _) = span(&s, Vec3::ZERO, v(0.0, 0.0, 1e-3));
    assert!(
        (e.t - want * 1e3).abs() <= 1e-15 * want * 1e3,
        "t0 = {}",
        e.t
    );
    let tiny = sphere(v(0.0, 0.0, 1e6), 1e-6);
    let (e, x) = span(&tiny, Vec3::ZERO, v(0.0, 0.0, 1.0));
    assert_close(e.t, 1e6 - 1e-6, 1e-9);
    assert_close(x.t - e.t, 2e-6, 1e-9);
    // Off the axis by half the radius: chord 2·sqrt(1 − 1/4)·r.
    let (e, x) = span(&tiny, v(0.5e-6, 0.0, 0.0), v(0.0, 0.0, 1.0));
    assert_close(x.t - e.t, 3f64.sqrt() * 1e-6, 1e-9);
}

#[test]
fn sphere_case2_grazing_rays_hit_iff_inside() {
    let s = sphere(Vec3::ZERO, 1.0);
    let d = v(0.0, 0.0, 1.0);
    let ulp = 2f64.powi(-53);
    for k in [1.0, 2.0, 4.0, 16.0] {
        for sign in [1.0, -1.0] {
            let h = sign * (1.0 - k * ulp);
            let (e, x) = span(&s, v(0.0, h, -10.0), d);
            // 1 − h² = (1 − |h|)(1 + |h|), both factors exact here.
            let chord = 2.0 * ((1.0 - h.abs()) * (1.0 + h.abs())).sqrt();
            let got = x.t - e.t;
            assert!(
                (got - chord).abs() <= 1e-6 * chord,
                "k={k}: chord {got:e} vs {chord:e}"
            );
            assert!(
                is_miss(&s, v(0.0, sign * (1.0 + k * 2.0 * ulp), -10.0), d),
                "k={k}"
            );
        }
    }
    assert!(is_miss(&s, v(0.0, 1.0, -10.0), d));
    assert!(is_miss(&s, v(0.0, -1.0, -10.0), d));
}

// ------------------------------------------------------------------ boxes

#[test]
fn box_faces_parts_and_normals() {
    let b = aabox(v(0.0, 0.0, 0.0), v(1.0, 2.0, 3.0));
    let (o, d) = (v(-1.0, 0.5, 0.5), v(2.0, 0.0, 0.0));
    let (e, x) = span(&b, o, d);
    assert_eq!(
        (e, x),
        (Crossing { t: 0.5, part: 0 }, Crossing { t: 1.0, part: 1 })
    );
    assert_eq!(normal_at(&b, o, d, e), v(-1.0, 0.0, 0.0));
    assert_eq!(normal_at(&b, o, d, x), v(1.0, 0.0, 0.0));
    let (o, d) = (v(0.5, 1.0, 10.0), v(0.0, 0.0, -0.5));
    let (e, x) = span(&b, o, d);
    assert_eq!(
        (e, x),
        (Crossing { t: 14.0, part: 5 }, Crossing { t: 20.0, part: 4 })
    );
    assert_eq!(normal_at(&b, o, d, e), v(0.0, 0.0, 1.0));
    assert_eq!(normal_at(&b, o, d, x), v(0.0, 0.0, -1.0));
    let (e, x) = span(&b, v(0.5, 1.0, 1.5), v(0.0, 1.0, 0.0));
    assert_eq!(
        (e, x),
        (Crossing { t: -1.0, part: 2 }, Crossing { t: 1.0, part: 3 })
    );
    assert!(is_miss(&b, v(-1.0, 2.5, 0.5), v(1.0, 0.0, 0.0)));
    assert!(is_miss(&b, v(-1.0, 0.5, 0.5), v(0.0, 1.0, 0.0)));
    assert_eq!(b.bounds, Aabb::new(v(0.0, 0.0, 0.0), v(1.0, 2.0, 3.0)));
}

#[test]
fn box_case7_edge_and_corner_ties_pick_the_lowest_axis() {
    let b = aabox(Vec3::splat(-1.0), Vec3::ONE);
    let (o, d) = (v(-5.0, -5.0, 0.0), v(1.0, 1.0, 0.0));
    let (e, x) = span(&b, o, d);
    assert_eq!(
        (e, x),
        (Crossing { t: 4.0, part: 0 }, Crossing { t: 6.0, part: 1 })
    );
    assert_eq!(normal_at(&b, o, d, e), v(-1.0, 0.0, 0.0));
    let (o, d) = (Vec3::splat(-5.0), Vec3::ONE);
    let (e, x) = span(&b, o, d);
    assert_eq!(
        (e, x),
        (Crossing { t: 4.0, part: 0 }, Crossing { t: 6.0, part: 1 })
    );
    let (e, x) = span(&b, Vec3::splat(5.0), Vec3::splat(-1.0));
    assert_eq!(
        (e, x),
        (Crossing { t: 4.0, part: 1 }, Crossing { t: 6.0, part: 0 })
    );
    // An edge in y and z only: the y face wins over z.
    let (e, _) = span(&b, v(0.0, -3.0, -3.0), v(0.0, 0.5, 0.5));
    assert_eq!(e, Crossing { t: 4.0, part: 2 });
}

#[test]
fn box_case8_signed_zero_directions_agree() {
    let b = aabox(Vec3::ZERO, Vec3::ONE);
    let o = v(1.0, 0.5, -5.0);
    let plus = span(&b, o, v(0.0, 0.0, 1.0));
    let minus = span(&b, o, v(-0.0, 0.0, 1.0));
    let both = span(&b, o, v(-0.0, -0.0, 1.0));
    assert_eq!(
        plus,
        (Crossing { t: 5.0, part: 4 }, Crossing { t: 6.0, part: 5 })
    );
    assert_eq!(minus, plus);
    assert_eq!(both, plus);
    // The same on the min face, and outside it a miss for both signs.
    let o = v(0.0, 0.5, -5.0);
    assert_eq!(
        span(&b, o, v(0.0, 0.0, 1.0)),
        span(&b, o, v(-0.0, 0.0, 1.0))
    );
    assert!(is_miss(&b, v(1.5, 0.5, -5.0), v(0.0, 0.0, 1.0)));
    assert!(is_miss(&b, v(1.5, 0.5, -5.0), v(-0.0, 0.0, 1.0)));
    // A subnormal component behaves like zero (case 28 at this level).
    let sub = span(&b, v(0.5, 0.5, -5.0), v(1e-310, 0.0, 1.0));
    assert_eq!(sub, span(&b, v(0.5, 0.5, -5.0), v(0.0, 0.0, 1.0)));
}

#[test]
fn box_case13_flat_box_is_never_hit() {
    let flat = aabox(v(0.5, 0.0, 0.0), v(0.5, 1.0, 1.0));
    assert!(is_miss(&flat, v(-1.0, 0.5, 0.5), v(1.0, 0.0, 0.0)));
    assert!(is_miss(&flat, v(0.5, 0.5, -1.0), v(0.0, 0.0, 1.0)));
    assert!(is_miss(&flat, v(0.5, 0.5, -1.0), v(-0.0, 0.0, 1.0)));
    assert!(is_miss(&flat, v(0.5, -1.0, -1.0), v(0.0, 1.0, 1.0)));
    let inverted = aabox(Vec3::ONE, Vec3::ZERO);
    assert_eq!(inverted.bounds, Aabb::EMPTY);
    assert!(is_miss(&inverted, v(0.5, 0.5, -1.0), v(0.0, 0.0, 1.0)));
    assert!(is_miss(&inverted, v(-1.0, -1.0, -1.0), Vec3::ONE));
}

#[test]
fn box_baked_from_scaled_unit_box_is_bit_identical() {
    let m = Affine::from_srt(v(1.0, 2.0, 2.0), Vec3::ZERO, v(0.0, -1.0, -1.0));
    let baked = placed(
        Shape::Box {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        },
        &m,
    );
    assert_eq!(baked.transform, None);
    assert_eq!(
        baked.shape,
        Shape::Box {
            min: v(0.0, -1.0, -1.0),
            max: v(1.0, 1.0, 1.0)
        }
    );
    let direct = aabox(v(0.0, -1.0, -1.0), v(1.0, 1.0, 1.0));
    assert_eq!(baked.bounds, direct.bounds);
    for (o, d) in [
        (v(0.3, 0.2, 5.0), v(-0.01, 0.03, -1.0)),
        (v(-2.0, 0.1, 0.7), v(1.0, 0.1, -0.2)),
        (v(0.5, 3.0, 0.0), v(0.1, -1.0, 0.3)),
    ] {
        assert_eq!(hits(&baked, o, d), hits(&direct, o, d));
    }
}

#[test]
fn rotated_box_hits_its_slanted_faces() {
    let m = Affine::from_srt(Vec3::ONE, v(0.0, 0.0, 45.0), Vec3::ZERO);
    let b = placed(
        Shape::Box {
            min: Vec3::splat(-1.0),
            max: Vec3::ONE,
        },
        &m,
    );
    assert!(b.transform.is_some());
    let r2 = 2f64.sqrt();
    assert_vec_close(b.bounds.min, v(-r2, -r2, -1.0), 1e-12);
    assert_vec_close(b.bounds.max, v(r2, r2, 1.0), 1e-12);
    // The square's corners are at (±√2, 0), (0, ±√2): at y = 0.3 the ray
    // enters the face −x + y = √2 and leaves the face x + y = √2.
    let (o, d) = (v(-5.0, 0.3, 0.2), v(2.0, 0.0, 0.0));
    let (e, x) = span(&b, o, d);
    assert_close(e.t, (0.3 - r2 + 5.0) / 2.0, 1e-12);
    assert_close(x.t, (r2 - 0.3 + 5.0) / 2.0, 1e-12);
    assert_vec_close(normal_at(&b, o, d, e), v(-1.0, 1.0, 0.0) / r2, 1e-12);
    assert_vec_close(normal_at(&b, o, d, x), v(1.0, 1.0, 0.0) / r2, 1e-12);
    assert!(is_miss(&b, v(-5.0, 1.5, 0.2), d));
}

#[test]
fn nonuniformly_scaled_sphere_is_an_ellipsoid() {
    let m = Affine::from_srt(v(2.0, 1.0, 0.5), Vec3::ZERO, v(1.0, 0.0, 0.0));
    let e = placed(
        Shape::Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
        },
        &m,
    );
    assert!(e.transform.is_some());
    assert_eq!(e.bounds, Aabb::new(v(-1.0, -1.0, -0.5), v(3.0, 1.0, 0.5)));
    // ((x − 1)/2)² + y² + (z/0.5)² = 1 at y = 0.5, z = 0.2.
    let (o, d) = (v(-10.0, 0.5, 0.2), v(3.0, 0.0, 0.0));
    let (en, ex) = span(&e, o, d);
    let half = 2.0 * (1.0f64 - 0.25 - 0.16).sqrt();
    assert_close(en.t, (1.0 - half + 10.0) / 3.0, 1e-13);
    assert_close(ex.t, (1.0 + half + 10.0) / 3.0, 1e-13);
    for (c, x) in [(en, 1.0 - half), (ex, 1.0 + half)] {
        // Gradient of the implicit function: ((x − 1)/4, y, 4z).
        let want = v((x - 1.0) / 4.0, 0.5, 4.0 * 0.2).normalize();
        assert_vec_close(normal_at(&e, o, d, c), want, 1e-13);
    }
    assert!(is_miss(&e, v(-10.0, 0.0, 0.6), d));
    // A similarity is baked instead.
    let m = Affine::from_srt(Vec3::splat(3.0), v(10.0, 20.0, 30.0), v(1.0, 2.0, 3.0));
    let s = placed(
        Shape::Sphere {
            center: v(1.0, 0.0, 0.0),
            radius: 1.0,
        },
        &m,
    );
    assert!(s.transform.is_none());
    let Shape::Sphere { center, radius } = s.shape else {
        panic!("not a sphere")
    };
    assert_close(radius, 3.0, 1e-14);
    assert_vec_close(center, m.point(v(1.0, 0.0, 0.0)), 0.0);
}

// -------------------------------------------------------------- cylinders

#[test]
fn tilted_cylinder_matches_closed_form() {
    let (base, top) = (v(1.0, 1.0, 1.0), v(3.0, 5.0, 5.0));
    let a = v(1.0, 2.0, 2.0) / 3.0;
    let c = cylinder(base, top, 0.5, true);
    let w = v(2.0, -1.0, 0.0) / 5f64.sqrt();
    let u = a.cross(w);
    let p = base + a * 3.0;
    // Across the axis, 0.3 off it: half chord 0.4.
    let (o, d) = (p - w * 5.0 + u * 0.3, w * 2.0);
    let (e, x) = span(&c, o, d);
    assert_eq!((e.part, x.part), (0, 0));
    assert_close(e.t, 2.3, 1e-12);
    assert_close(x.t, 2.7, 1e-12);
    assert_vec_close(normal_at(&c, o, d, e), w * -0.8 + u * 0.6, 1e-12);
    assert_vec_close(normal_at(&c, o, d, x), w * 0.8 + u * 0.6, 1e-12);
    // Along the axis through the caps.
    let (o, d) = (base - a * 2.0 + w * 0.1, a * 1.5);
    let (e, x) = span(&c, o, d);
    assert_eq!((e.part, x.part), (1, 2));
    assert_close(e.t, 2.0 / 1.5, 1e-12);
    assert_close(x.t, 8.0 / 1.5, 1e-12);
    assert_vec_close(normal_at(&c, o, d, e), -a, 1e-15);
    assert_vec_close(normal_at(&c, o, d, x), a, 1e-15);
    assert!(is_miss(&c, base - a * 2.0 + w * 0.6, d));
    // Tight bounds: each disk spans r·sqrt(1 − a_i²) on axis i.
    let ext = v(8.0f64 / 9.0, 5.0 / 9.0, 5.0 / 9.0).map(f64::sqrt) * 0.5;
    assert_vec_close(c.bounds.min, base - ext, 1e-15);
    assert_vec_close(c.bounds.max, top + ext, 1e-15);
}

#[test]
fn cylinder_case3_rays_along_the_axis() {
    let c = cylinder(Vec3::ZERO, v(0.0, 0.0, 2.0), 1.0, true);
    let up = v(0.0, 0.0, 1.0);
    let (e, x) = span(&c, v(0.5, 0.0, -5.0), up);
    assert_eq!(
        (e, x),
        (Crossing { t: 5.0, part: 1 }, Crossing { t: 7.0, part: 2 })
    );
    assert_eq!(normal_at(&c, v(0.5, 0.0, -5.0), up, e), v(0.0, 0.0, -1.0));
    let (e, x) = span(&c, v(0.5, 0.0, -5.0), v(0.0, 0.0, 0.5));
    assert_eq!((e.t, x.t), (10.0, 14.0));
    assert!(is_miss(&c, v(1.5, 0.0, -5.0), up));
    match hits(&c, v(1.0, 0.0, -5.0), up) {
        PrimHits::Miss => {}
        PrimHits::Solid { enter, exit } => assert_eq!((enter.t, exit.t), (5.0, 7.0)),
        other => panic!("{other:?}"),
    }
    // Nearly parallel directions give the same span, continuously.
    for dy in [1e-20, -1e-20, 1e-300, 1e-310, -0.0] {
        let (e, x) = span(&c, v(0.5, 0.0, -5.0), v(0.0, dy, 1.0));
        assert_eq!((e.part, x.part), (1, 2), "dy={dy}");
        assert_close(e.t, 5.0, 1e-12);
        assert_close(x.t, 7.0, 1e-12);
    }
    // Going down, from inside: negative entry.
    let (e, x) = span(&c, v(0.0, 0.5, 1.5), v(0.0, 0.0, -1.0));
    assert_eq!(
        (e, x),
        (Crossing { t: -0.5, part: 2 }, Crossing { t: 1.5, part: 1 })
    );
}

#[test]
fn cylinder_case4_rays_in_the_cap_planes() {
    let c = cylinder(Vec3::ZERO, v(0.0, 0.0, 2.0), 1.0, true);
    let d = v(1.0, 0.0, 0.0);
    let (e, x) = span(&c, v(-5.0, 0.0, 1.0), d);
    assert_eq!(
        (e, x),
        (Crossing { t: 4.0, part: 0 }, Crossing { t: 6.0, part: 0 })
    );
    assert_eq!(normal_at(&c, v(-5.0, 0.0, 1.0), d, e), v(-1.0, 0.0, 0.0));
    for z in [0.0, 2.0, -0.0] {
        for d in [d, v(1.0, 0.0, -0.0), v(2.0, 0.0, 0.0)] {
            match hits(&c, v(-5.0, 0.0, z), d) {
                PrimHits::Miss => {}
                PrimHits::Solid { enter, exit } => {
                    assert_eq!((enter.t * d.x, exit.t * d.x), (4.0, 6.0), "z={z}")
                }
                other => panic!("{other:?}"),
            }
        }
    }
    assert!(is_miss(&c, v(-5.0, 0.0, 2.5), d));
}

#[test]
fn cylinder_case5_ray_through_the_rim() {
    let c = cylinder(Vec3::ZERO, v(0.0, 0.0, 2.0), 1.0, true);
    let (o, d) = (v(-5.0, 0.0, 3.0), v(4.0, 0.0, -1.0));
    let (e, x) = span(&c, o, d);
    assert_eq!(e.t, 1.0);
    let n = normal_at(&c, o, d, e);
    assert!(
        n == v(0.0, 0.0, 1.0) || n == v(-1.0, 0.0, 0.0),
        "rim normal {n}"
    );
    // Either is allowed; the rule is fixed: the cap wins the tie.
    assert_eq!(e.part, 2);
    assert_eq!(x.t, 1.5);
    assert_eq!(normal_at(&c, o, d, x), v(1.0, 0.0, 0.0));
}

#[test]
fn open_cylinder_is_a_sheet_within_its_height() {
    let c = cylinder(Vec3::ZERO, v(0.0, 0.0, 2.0), 1.0, false);
    assert!(!c.is_solid());
    let h = hits(&c, v(-5.0, 0.0, 1.0), v(1.0, 0.0, 0.0));
    assert_eq!(
        crossings(&h),
        vec![Crossing { t: 4.0, part: 0 }, Crossing { t: 6.0, part: 0 }]
    );
    // Through the open ends: nothing.
    assert!(is_miss(&c, v(0.5, 0.0, -5.0), v(0.0, 0.0, 1.0)));
    assert!(is_miss(&c, v(-5.0, 0.0, 3.0), v(1.0, 0.0, 0.0)));
    // In at the side (x = −1 at t = 0.8, z = 1.3), out through the top.
    let (o, d) = (v(-5.0, 0.0, 0.5), v(5.0, 0.0, 1.5));
    let h = hits(&c, o, d);
    let cs = crossings(&h);
    assert_eq!(cs.len(), 1);
    assert_close(cs[0].t, 0.8, 1e-15);
    assert_eq!(normal_at(&c, o, d, cs[0]), v(-1.0, 0.0, 0.0));
    let cs = crossings(&hits(&c, o, v(5.0, 0.0, 1.0)));
    assert_eq!(cs.len(), 2);
    assert_close(cs[0].t, 0.8, 1e-15);
    assert_close(cs[1].t, 1.2, 1e-15);
}

#[test]
fn baking_keeps_circular_cylinders_and_cones_exact() {
    // Case 9's scaled unit cylinder equals the one written directly.
    let m = Affine::from_srt(v(0.5, 0.5, 1.0), Vec3::ZERO, Vec3::ZERO);
    let unit = Shape::Cylinder {
        base: v(0.0, 0.0, -1.0),
        top: v(0.0, 0.0, 1.0),
        radius: 1.0,
        capped: true,
    };
    let scaled = placed(unit.clone(), &m);
    let direct = cylinder(v(0.0, 0.0, -1.0), v(0.0, 0.0, 1.0), 0.5, true);
    assert_eq!(scaled, direct);
    let m = Affine::from_srt(v(2.0, 1.0, 3.0), Vec3::ZERO, v(0.0, 0.0, 1.0));
    let cone_shape = Shape::Cone {
        base: v(0.0, 0.0, 0.0),
        base_radius: 1.0,
        top: v(0.0, 0.0, 1.0),
        top_radius: 0.5,
        capped: true,
    };
    assert!(placed(cone_shape.clone(), &m).transform.is_some());
    let m = Affine::from_srt(v(2.0, 2.0, 3.0), Vec3::ZERO, v(0.0, 0.0, 1.0));
    assert_eq!(
        placed(cone_shape, &m).shape,
        Shape::Cone {
            base: v(0.0, 0.0, 1.0),
            base_radius: 2.0,
            top: v(0.0, 0.0, 4.0),
            top_radius: 1.0,
            capped: true
        }
    );
    // A tilted cylinder stays in object space, as a box under the same
    // transform must (case 9 turned: their planes then agree bit for bit);
    // a quarter turn keeps the axes and bakes.
    let m = Affine::from_srt(Vec3::splat(2.0), v(30.0, 40.0, 50.0), v(1.0, 1.0, 1.0));
    let tilted = placed(unit.clone(), &m);
    assert_eq!(
        (&tilted.shape, tilted.transform),
        (&unit, Some(Box::new(m)))
    );
    let m = Affine::from_srt(Vec3::splat(2.0), v(90.0, 0.0, 0.0), v(1.0, 1.0, 1.0));
    let turned = placed(unit, &m);
    assert!(turned.transform.is_none());
    assert_eq!(
        turned.shape,
        Shape::Cylinder {
            base: v(1.0, 3.0, 1.0),
            top: v(1.0, -1.0, 1.0),
            radius: 2.0,
            capped: true
        }
    );
    // A triangle is baked under any affine map.
    let m = Affine::from_srt(v(2.0, 1.0, 3.0), v(10.0, 0.0, 0.0), Vec3::ZERO);
    let t = placed(
        Shape::Triangle {
            a: Vec3::ZERO,
            b: Vec3::X,
            c: Vec3::Y,
        },
        &m,
    );
    assert!(t.transform.is_none());
    assert_eq!(
        t.shape,
        Shape::Triangle {
            a: Vec3::ZERO,
            b: m.point(Vec3::X),
            c: m.point(Vec3::Y)
        }
    );
}

#[test]
fn elliptic_cylinder_keeps_its_transform() {
    // Scale (2, 1, 1) of a z cylinder: (x/2)² + y² = 1.
    let m = Affine::from_srt(v(2.0, 1.0, 1.0), Vec3::ZERO, Vec3::ZERO);
    let c = placed(
        Shape::Cylinder {
            base: Vec3::ZERO,
            top: v(0.0, 0.0, 2.0),
            radius: 1.0,
            capped: true,
        },
        &m,
    );
    assert!(c.transform.is_some());
    assert_eq!(c.bounds, Aabb::new(v(-2.0, -1.0, 0.0), v(2.0, 1.0, 2.0)));
    let (o, d) = (v(-10.0, 0.5, 1.0), v(1.0, 0.0, 0.0));
    let (e, x) = span(&c, o, d);
    let r3 = 3f64.sqrt();
    assert_close(e.t, 10.0 - r3, 1e-13);
    assert_close(x.t, 10.0 + r3, 1e-13);
    assert_vec_close(
        normal_at(&c, o, d, e),
        v(-r3 / 4.0, 0.5, 0.0).normalize(),
        1e-13,
    );
    let (e, x) = span(&c, v(1.5, 0.0, -1.0), v(0.0, 0.0, 1.0));
    assert_eq!(
        (e, x),
        (Crossing { t: 1.0, part: 1 }, Crossing { t: 3.0, part: 2 })
    );
    assert_eq!(
        normal_at(&c, v(1.5, 0.0, -1.0), v(0.0, 0.0, 1.0), x),
        v(0.0, 0.0, 1.0)
    );
}

// ------------------------------------------------------------------ cones

/// Case 6's cone: apex at 0, axis +z, 45°, height 1.
fn case6_cone(capped: bool) -> Primitive {
    cone(v(0.0, 0.0, 1.0), 1.0, Vec3::ZERO, 0.0, capped)
}

#[test]
fn cone_case6_apex_and_generator() {
    let c = case6_cone(true);
    let (o, d) = (v(0.0, 0.0, -1.0), v(0.0, 0.0, 1.0));
    let (e, x) = span(&c, o, d);
    assert_eq!(
        (e, x),
        (Crossing { t: 1.0, part: 3 }, Crossing { t: 2.0, part: 1 })
    );
    assert_eq!(normal_at(&c, o, d, e), v(0.0, 0.0, -1.0));
    assert_eq!(normal_at(&c, o, d, x), v(0.0, 0.0, 1.0));
    // Parallel to a generator (A = 0): y² ≤ z² on the ray gives t ≥ −1/4,
    // the base plane z = 1 gives t ≤ 1/2.
    let (o, d) = (v(0.0, 0.0, 0.5), v(0.0, 1.0, 1.0));
    let (e, x) = span(&c, o, d);
    assert_close(e.t, -0.25, 1e-12);
    assert_close(x.t, 0.5, 1e-12);
    assert_eq!((e.part, x.part), (0, 1));
    let r2 = 2f64.sqrt();
    assert_vec_close(normal_at(&c, o, d, e), v(0.0, -1.0, -1.0) / r2, 1e-15);
    let (e, x) = span(&c, o, v(0.0, 2.0, 2.0));
    assert_close(e.t, -0.125, 1e-12);
    assert_close(x.t, 0.25, 1e-12);
    let (e, x) = span(&c, o, v(0.0, -1.0, -1.0));
    assert_close(e.t, -0.5, 1e-12);
    assert_close(x.t, 0.25, 1e-12);
    assert_eq!((e.part, x.part), (1, 0));
    // Through the apex from below at a slant inside the cone of directions.
    let (o, d) = (v(-0.5, 0.0, -1.0), v(0.5, 0.0, 1.0));
    let (e, x) = span(&c, o, d);
    assert_eq!(e.part, 3);
    assert_close(e.t, 1.0, 1e-15);
    assert_close(x.t, 2.0, 1e-15);
}

#[test]
fn cone_rejects_the_mirror_nappe() {
    let c = case6_cone(true);
    assert!(is_miss(&c, v(-5.0, 0.0, -0.5), v(1.0, 0.0, 0.0)));
    assert!(is_miss(&c, v(-5.0, 0.0, -0.5), v(1.0, 0.0, 0.1)));
    // Through the mirror nappe's interior (z < 0), then into the cone at
    // z = x = 0.2 and out through the base at z = 1.
    let (o, d) = (v(0.2, 0.0, -2.0), v(0.0, 0.0, 1.0));
    let (e, x) = span(&c, o, d);
    assert_close(e.t, 2.2, 1e-15);
    assert_eq!((e.part, x), (0, Crossing { t: 3.0, part: 1 }));
    assert_vec_close(
        normal_at(&c, o, d, e),
        v(1.0, 0.0, -1.0) / 2f64.sqrt(),
        1e-15,
    );
    // Down the axis: in through the base, out at the apex.
    let (o, d) = (v(0.0, 0.0, 3.0), v(0.0, 0.0, -1.0));
    let (e, x) = span(&c, o, d);
    assert_eq!(
        (e, x),
        (Crossing { t: 2.0, part: 1 }, Crossing { t: 3.0, part: 3 })
    );
    assert_eq!(normal_at(&c, o, d, x), v(0.0, 0.0, -1.0));
    // Horizontal at z = 0.5: radius 0.5.
    let (e, x) = span(&c, v(-5.0, 0.0, 0.5), v(1.0, 0.0, 0.0));
    assert_close(e.t, 4.5, 1e-15);
    assert_close(x.t, 5.5, 1e-15);
}

#[test]
fn frustum_matches_closed_form() {
    // Radius 2 at z = 0, 1 at z = 2 (apex at z = 4, slope k = −1/2).
    let c = cone(Vec3::ZERO, 2.0, v(0.0, 0.0, 2.0), 1.0, true);
    let (o, d) = (v(-5.0, 0.0, 1.0), v(1.0, 0.0, 0.0));
    let (e, x) = span(&c, o, d);
    assert_eq!((e.t, x.t, e.part, x.part), (3.5, 6.5, 0, 0));
    assert_vec_close(
        normal_at(&c, o, d, e),
        v(-2.0, 0.0, 1.0) / 5f64.sqrt(),
        1e-15,
    );
    assert_vec_close(
        normal_at(&c, o, d, x),
        v(2.0, 0.0, 1.0) / 5f64.sqrt(),
        1e-15,
    );
    let (e, x) = span(&c, v(0.3, 0.0, -1.0), v(0.0, 0.0, 2.0));
    assert_eq!(
        (e, x),
        (Crossing { t: 0.5, part: 1 }, Crossing { t: 1.5, part: 2 })
    );
    // Beyond the top, where the extended cone narrows to its apex: nothing.
    assert!(is_miss(&c, v(-5.0, 0.0, 3.0), d));
    assert!(is_miss(&c, v(-5.0, 0.0, 5.0), d));
    // Parallel to the generator from (2,0,0) to (1,0,2) (A = 0): in through
    // the base at t = 0.5, out through the far side at (−1.5, 0, 1).
    let (o, d) = (v(-0.5, 0.0, -1.0), v(-1.0, 0.0, 2.0));
    let (e, x) = span(&c, o, d);
    assert_eq!((e.part, x.part), (1, 0));
    assert_close(e.t, 0.5, 1e-15);
    assert_close(x.t, 1.0, 1e-15);
    assert_vec_close(
        normal_at(&c, o, d, x),
        v(-2.0, 0.0, 1.0) / 5f64.sqrt(),
        1e-15,
    );
    // Bounds: disks of radius 2 and 1.
    assert_eq!(c.bounds, Aabb::new(v(-2.0, -2.0, 0.0), v(2.0, 2.0, 2.0)));
    // Upside down (narrow end first) is the same solid.
    let flipped = cone(v(0.0, 0.0, 2.0), 1.0, Vec3::ZERO, 2.0, true);
    let (e, x) = span(&flipped, v(-5.0, 0.0, 1.0), v(1.0, 0.0, 0.0));
    assert_eq!((e.t, x.t), (3.5, 6.5));
}

#[test]
fn open_cones_are_sheets() {
    let f = cone(Vec3::ZERO, 2.0, v(0.0, 0.0, 2.0), 1.0, false);
    let cs = crossings(&hits(&f, v(-5.0, 0.0, 1.0), v(1.0, 0.0, 0.0)));
    assert_eq!(
        cs,
        vec![Crossing { t: 3.5, part: 0 }, Crossing { t: 6.5, part: 0 }]
    );
    assert!(is_miss(&f, v(0.3, 0.0, -1.0), v(0.0, 0.0, 1.0)));
    // A pointed open cone up its axis: the apex only.
    let c = case6_cone(false);
    let cs = crossings(&hits(&c, v(0.0, 0.0, -1.0), v(0.0, 0.0, 1.0)));
    assert_eq!(cs, vec![Crossing { t: 1.0, part: 3 }]);
    // Across at z = 0.5: two side crossings.
    let cs = crossings(&hits(&c, v(-5.0, 0.0, 0.5), v(1.0, 0.0, 0.0)));
    assert_eq!(cs.len(), 2);
    assert_close(cs[0].t, 4.5, 1e-15);
    assert_close(cs[1].t, 5.5, 1e-15);
    // Along a generator direction: one crossing, the other end is open.
    let cs = crossings(&hits(&c, v(0.0, 0.0, 0.5), v(0.0, 1.0, 1.0)));
    assert_eq!(cs.len(), 1);
    assert_close(cs[0].t, -0.25, 1e-12);
}

#[test]
fn cone_normals_stay_unit_at_the_apex_and_near_it() {
    let c = case6_cone(true);
    let ray = Ray::new(v(0.0, 0.0, -1.0), v(0.0, 0.0, 1.0));
    for part in 0..4 {
        let n = c.normal(&ray, 1.0, part);
        assert!(
            n.is_finite() && (n.length() - 1.0).abs() < 1e-15,
            "part {part}: {n}"
        );
    }
    assert_eq!(c.normal(&ray, 1.0, 0), v(0.0, 0.0, -1.0));
    for eps in [1e-300, 1e-15, 1e-8] {
        let (o, d) = (v(eps, 0.0, -1.0), v(0.0, 0.0, 1.0));
        let (e, _) = span(&c, o, d);
        assert!(e.t >= 1.0 && e.t <= 1.0 + 1e-7, "eps={eps}: {e:?}");
    }
    // A cone transformed non-uniformly maps its apex normal too.
    let m = Affine::from_srt(v(1.0, 2.0, 1.0), v(0.0, 90.0, 0.0), Vec3::ZERO);
    let t = placed(
        Shape::Cone {
            base: v(0.0, 0.0, 1.0),
            base_radius: 1.0,
            top: Vec3::ZERO,
            top_radius: 0.0,
            capped: true,
        },
        &m,
    );
    assert!(t.transform.is_some());
    // The axis now runs along +x (rotated 90° about y: z → x).
    let (o, d) = (v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0));
    let (e, x) = span(&t, o, d);
    assert_eq!(e.part, 3);
    assert_close(e.t, 1.0, 1e-15);
    assert_close(x.t, 2.0, 1e-15);
    assert_vec_close(normal_at(&t, o, d, e), v(-1.0, 0.0, 0.0), 1e-15);
}

#[test]
fn cylinder_and_cone_bounds_are_tight() {
    let (base, top) = (v(0.5, -1.0, 2.0), v(3.0, 1.0, -1.0));
    let a = (top - base).normalize();
    let (u, w) = a.any_orthonormal_pair();
    for (p, r0, r1) in [
        (cylinder(base, top, 0.7, true), 0.7, 0.7),
        (cone(base, 1.3, top, 0.2, true), 1.3, 0.2),
        (cone(base, 0.0, top, 0.9, false), 0.0, 0.9),
    ] {
        let mut lo = Vec3::splat(f64::INFINITY);
        let mut hi = Vec3::splat(f64::NEG_INFINITY);
        for i in 0..3600 {
            let th = (i as f64 / 10.0).to_radians();
            let rim = u * th.cos() + w * th.sin();
            for q in [base + rim * r0, top + rim * r1] {
                lo = lo.min(q);
                hi = hi.max(q);
            }
        }
        let b = p.bounds;
        assert!(
            b.min.cmple(lo + 1e-12).all() && b.max.cmpge(hi - 1e-12).all(),
            "{b:?} vs {lo} {hi}"
        );
        assert_vec_close(b.min, lo, 1e-5);
        assert_vec_close(b.max, hi, 1e-5);
    }
}

/// Rays aimed at a pointed cone's apex from 1 to 20 away, the cone placed
/// by random rotations and unequal scales (as a random scene placed the
/// one a hunt found, `cone_discriminant`): every crossing lies in the
/// cone's box, to a few ulps. The two roots meet at the apex, and `B² −
/// A·C` kept only the square root of the precision there: that cone was
/// met 3.4e-7 short of its apex, outside its box, where the cells (which
/// walk the boxes) could not find what Roth found. Rays at the apex of a
/// pointed cap are counted, to show the case is met.
#[test]
fn rays_at_a_cone_apex_meet_it_within_its_box() {
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut met = 0;
    for k in 0..2000 {
        let mut r = |lo: f64, hi: f64| lo + (hi - lo) * next();
        let base = v(r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0));
        let top = v(r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0));
        let shape = Shape::Cone {
            base,
            base_radius: 0.0,
            top,
            top_radius: r(0.05, 1.5),
            capped: k % 2 == 0,
        };
        let m = Affine::from_srt(
            v(r(0.3, 2.0), r(0.3, 2.0), r(0.3, 2.0)),
            v(r(-180.0, 180.0), r(-180.0, 180.0), r(-180.0, 180.0)),
            v(r(-3.0, 3.0), r(-3.0, 3.0), r(-3.0, 3.0)),
        );
        let p = placed(shape, &m);
        let apex = m.point(base);
        let dir = v(r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0)).normalize();
        let o = apex - dir * r(1.0, 20.0);
        let ray = Ray::new(o, (apex - o) * r(0.1, 10.0));
        let h = p.intersect(&ray);
        let b = p.bounds;
        let reach = b
            .min
            .abs()
            .max(b.max.abs())
            .max_element()
            .max(o.abs().max_element());
        let slack = 64.0 * f64::EPSILON * reach;
        for c in crossings(&h) {
            let q = ray.at(c.t);
            let outside = (b.min - q).max(q - b.max).max_element();
            assert!(
                outside <= slack,
                "crossing {c:?} at {q} lies {outside:e} outside {b:?} (cone {k}, ray {ray:?})"
            );
            met += usize::from((q - apex).length() <= slack);
        }
    }
    assert!(met >= 100, "only {met} crossings at the apex");
}

// -------------------------------------------------------------- triangles

#[test]
fn triangle_hits_match_the_plane_and_barycentrics() {
    let t = triangle(v(0.0, 0.0, 1.0), v(2.0, 0.0, 1.0), v(0.0, 2.0, 1.0));
    let (o, d) = (v(0.25, 0.25, 0.0), v(0.25, 0.25, 1.0));
    let cs = crossings(&hits(&t, o, d));
    assert_eq!(cs, vec![Crossing { t: 1.0, part: 0 }]);
    assert_eq!(normal_at(&t, o, d, cs[0]), v(0.0, 0.0, 1.0));
    assert_eq!(
        crossings(&hits(&t, v(0.5, 0.5, 3.0), v(0.0, 0.0, -4.0))),
        vec![Crossing { t: 0.5, part: 0 }]
    );
    // Behind the origin: negative t is kept.
    assert_eq!(
        crossings(&hits(&t, v(0.5, 0.5, 3.0), v(0.0, 0.0, 1.0))),
        vec![Crossing { t: -2.0, part: 0 }]
    );
    assert!(is_miss(&t, v(1.5, 1.5, 0.0), v(0.0, 0.0, 1.0)));
    // In the triangle's plane: a miss.
    assert!(is_miss(&t, v(-1.0, 0.5, 1.0), v(1.0, 0.0, 0.0)));
    assert!(is_miss(&t, v(-1.0, 0.5, 1.0), v(1.0, 0.3, 0.0)));
    // A tilted triangle against an independently computed plane hit.
    let (a, b, c) = (v(1.0, 0.0, 0.0), v(0.0, 2.0, 0.0), v(0.0, 0.0, 3.0));
    let tri = triangle(a, b, c);
    let n = (b - a).cross(c - a);
    let (o, d) = (v(-1.0, -0.5, -2.0), v(0.7, 0.9, 1.8));
    let want = (a - o).dot(n) / d.dot(n);
    let cs = crossings(&hits(&tri, o, d));
    assert_eq!(cs.len(), 1);
    assert_close(cs[0].t, want, 1e-14);
    let p = o + d * want;
    assert!(p.x > 0.0 && p.y > 0.0 && p.z > 0.0, "hit {p} outside");
    assert_vec_close(normal_at(&tri, o, d, cs[0]), n.normalize(), 1e-15);
}

/// A tilted triangle reaching 1e20 to 1e50 away, on the plane `z = (x +
/// y) / 64` (its vertices on it exactly: sums of `±far` and 0 are exact),
/// met near the origin: `t` as
/// the small plane equation gives it, to 1e-14, and a spawned ray's offset
/// that needs no size (`Primitive::rounding_size`). The triangle test alone
/// was some 1e4 off at 1e20 (`shape::on_plane`).
#[test]
fn a_tilted_triangle_reaching_far_is_met_on_its_exact_plane() {
    let on = |x: f64, y: f64| v(x, y, (x + y) / 64.0);
    let mut unit = uniform(7);
    for far in [1e20, 1e30, 1e50] {
        let tri = triangle(on(-far, -far), on(far, -far), on(0.0, far));
        for _ in 0..200 {
            let o = v(unit() * 4.0 - 2.0, unit() * 4.0 - 2.0, 1.0 + unit() * 3.0);
            let d = v(unit() - 0.5, unit() - 0.5, -0.2 - unit());
            // o + t·d on the plane: 64·z = x + y.
            let want = (o.x + o.y - 64.0 * o.z) / (64.0 * d.z - d.x - d.y);
            let cs = crossings(&hits(&tri, o, d));
            assert_eq!(cs.len(), 1, "reaching {far:e}: {o} + t·{d} misses");
            assert_close(cs[0].t, want, 1e-14);
            assert_eq!(tri.rounding_size(o + d * want, 0), 0.0);
        }
    }
    // Near its own vertices it keeps the triangle test and its size.
    let tri = triangle(on(-1e20, -1e20), on(1e20, -1e20), on(0.0, 1e20));
    assert!(tri.rounding_size(on(-1e20, -1e20), 0) > 1e20);
}

/// A lying drum of radius 1e20 to 1e45 along a tilted horizontal axis, its
/// top along a line through the origin at `z = 0`, met near the origin:
/// `t` as the plane `z = 0` gives it (the drum is flat there to 1e-19), to
/// 1e-14, and its spawned rays offset by no size. The f64 power `|f⊥|² −
/// r²` was some ε·r² off, the hit ε·r (`shape::far_cylinder_roots`). The
/// same of a lying cone as wide (`shape::far_cone_roots`), of a flat
/// ellipsoid (`shape::ellipsoid_hits`) and of a flat elliptic drum
/// (`shape::mapped_cylinder_hits`).
#[test]
fn a_drum_cone_or_ellipsoid_reaching_far_is_met_on_its_exact_surface() {
    let mut unit = uniform(11);
    let sphere = Shape::Sphere {
        center: Vec3::ZERO,
        radius: 1.0,
    };
    for far in [1e20, 1e30, 1e45] {
        let drum = cylinder(
            v(-far, -2.0 * far, -far),
            v(far, 2.0 * far, -far),
            far,
            true,
        );
        // A cone lying along y, its radius growing by 1/64 a unit, its top
        // generator on the plane z = y/64.
        let cone = cone(
            v(0.0, -far, -far),
            far * 63.0 / 64.0,
            v(0.0, far, -far),
            far * 65.0 / 64.0,
            true,
        );
        let flat = Affine::from_srt(
            v(far, far / 4.0, far / 64.0),
            Vec3::ZERO,
            v(0.0, 0.0, -far / 64.0),
        );
        let ellipsoid = placed(sphere.clone(), &flat);
        assert!(ellipsoid.transform.is_some());
        // An elliptic drum lying along x, flat as the ellipsoid.
        let lying = Affine::from_srt(
            v(far, far / 2.0, far / 64.0),
            Vec3::ZERO,
            v(0.0, 0.0, -far / 64.0),
        );
        let unit_drum = Shape::Cylinder {
            base: v(-1.0, 0.0, 0.0),
            top: v(1.0, 0.0, 0.0),
            radius: 1.0,
            capped: true,
        };
        let elliptic = placed(unit_drum, &lying);
        assert!(elliptic.transform.is_some());
        let on_z0 = |o: Vec3, d: Vec3| -o.z / d.z;
        let on_slope = |o: Vec3, d: Vec3| (o.y - 64.0 * o.z) / (64.0 * d.z - d.y);
        // The `t` at which o + t·d meets the plane the ground is flat to.
        type PlaneT = fn(Vec3, Vec3) -> f64;
        let grounds: [(&Primitive, PlaneT); 4] = [
            (&drum, on_z0),
            (&cone, on_slope),
            (&ellipsoid, on_z0),
            (&elliptic, on_z0),
        ];
        for (ground, plane_t) in grounds {
            for _ in 0..200 {
                let o = v(unit() * 4.0 - 2.0, unit() * 4.0 - 2.0, 1.0 + unit() * 3.0);
                let d = v(unit() - 0.5, unit() - 0.5, -0.2 - unit());
                let want = plane_t(o, d);
                let cs = crossings(&hits(ground, o, d));
                assert_eq!(cs.len(), 2, "{:?} at {far:e}: {o} + t·{d}", ground.shape);
                assert_close(cs[0].t, want, 1e-14);
                assert_eq!(ground.rounding_size(o + d * want, cs[0].part), 0.0);
            }
        }
    }
    // On its far side, as wide as its hit is far, it keeps its size.
    let drum = cylinder(v(0.0, -1e20, -1e20), v(0.0, 1e20, -1e20), 1e20, true);
    assert!(drum.rounding_size(v(0.0, 0.0, -2e20), 0) > 1e20);
}

/// The 12 triangles of the cube [0,1]³, outward-facing, with the diagonals
/// of neighbouring faces in different directions.
fn cube_triangles() -> Vec<Primitive> {
    let corner = |i: usize| v((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64);
    // Faces as corner indices counter-clockwise seen from outside.
    let faces = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut out = Vec::new();
    for (k, f) in faces.iter().enumerate() {
        let q = if k % 2 == 0 {
            *f
        } else {
            [f[1], f[2], f[3], f[0]]
        };
        out.push(triangle(corner(q[0]), corner(q[1]), corner(q[2])));
        out.push(triangle(corner(q[0]), corner(q[2]), corner(q[3])));
    }
    out
}

/// All crossings of a ray with the cube's triangles, sorted, with the sign
/// of `normal·d` (negative on entry, the triangles face outwards).
fn cube_crossings(tris: &[Primitive], o: Vec3, d: Vec3) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    for t in tris {
        for c in crossings(&hits(t, o, d)) {
            out.push((c.t, normal_at(t, o, d, c).dot(d)));
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

#[test]
fn triangle_case29_cube_edges_and_vertices_are_crossed_once() {
    let tris = cube_triangles();
    for t in &tris {
        assert!((t.normal(&Ray::new(Vec3::ZERO, Vec3::X), 0.0, 0).length() - 1.0).abs() < 1e-15);
    }
    let centre = Vec3::splat(0.5);
    // Points on every edge, every vertex, and the face diagonals.
    let mut points = Vec::new();
    for i in 0..8 {
        points.push(v(
            (i & 1) as f64,
            ((i >> 1) & 1) as f64,
            ((i >> 2) & 1) as f64,
        ));
    }
    for axis in 0..3 {
        for (p, q) in [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)] {
            for s in [0.5, 0.25, 1.0 / 3.0] {
                let mut e = Vec3::ZERO;
                e[axis] = s;
                e[(axis + 1) % 3] = p;
                e[(axis + 2) % 3] = q;
                points.push(e);
            }
        }
    }
    for axis in 0..3 {
        for side in [0.0, 1.0] {
            for s in [0.5, 0.25, 0.375] {
                for diag in [false, true] {
                    let mut e = Vec3::ZERO;
                    e[axis] = side;
                    e[(axis + 1) % 3] = s;
                    e[(axis + 2) % 3] = if diag { 1.0 - s } else { s };
                    points.push(e);
                }
            }
        }
    }
    // Dyadic rays whose dominant direction component is a power of two:
    // the shear of the watertight test is then exact, so the edge functions
    // are exactly zero on the edges and vertices and the tie rule decides.
    // Then rays with rounding, where it need not.
    let dyadic = [
        Vec3::ZERO,
        v(0.125, 0.25, -0.0625),
        v(-0.25, 0.0625, 0.125),
        v(0.0625, -0.25, -0.125),
    ];
    let rounded = [v(0.1, 0.2, -0.05), v(-0.3, 0.05, 0.2), v(0.02, -0.25, -0.1)];
    let mut rays = Vec::new();
    for p in &points {
        for nudge in dyadic {
            let mut d = centre - *p + nudge;
            let k = d.abs().max_position();
            d[k] = d[k].signum() * 2f64.powi(d[k].abs().log2().ceil() as i32);
            for scale in [1.0, 4.0, 0.25] {
                rays.push((*p, d * scale, 2.0));
            }
        }
        for nudge in rounded {
            for scale in [1.0, 3.0, 0.1] {
                rays.push((*p, (centre - *p + nudge) * scale, 3.0));
            }
        }
    }
    let mut checked = 0;
    for (p, d, t) in rays {
        let o = p - d * t;
        let cs = cube_crossings(&tris, o, d);
        assert_eq!(cs.len(), 2, "through {p} along {d}: {cs:?}");
        assert!(
            cs[0].1 < 0.0 && cs[1].1 > 0.0,
            "entry/exit order through {p}: {cs:?}"
        );
        assert_close(cs[0].0, t, 1e-12);
        checked += 1;
    }
    assert!(checked > 200);
    // Grazing rays that touch the cube only along an edge or at a vertex
    // cross an even number of times (front and back agree).
    for (p, d) in [
        (v(1.0, 1.0, 0.5), v(1.0, -1.0, 0.0)),
        (v(1.0, 1.0, 0.5), v(1.0, -1.0, 0.3)),
        (v(1.0, 1.0, 1.0), v(1.0, -1.0, 0.0)),
        (v(1.0, 1.0, 1.0), v(1.0, -1.0, 0.5)),
        (v(0.0, 0.0, 0.0), v(1.0, -1.0, 0.5)),
    ] {
        let cs = cube_crossings(&tris, p - d * 2.0, d);
        assert!(
            cs.len().is_multiple_of(2),
            "grazing through {p} along {d}: {cs:?}"
        );
    }
}

#[test]
fn edge_function_sign_is_exact_when_the_products_round_equal() {
    // (1 + 2⁻⁵²)² rounds to 1 + 2⁻⁵¹ = (1 + 2⁻⁵¹)·1, but exceeds it by 2⁻¹⁰⁴.
    let e = 2f64.powi(-52);
    let (p, q) = ([1.0 + e, 1.0 + 2.0 * e, 0.0], [1.0, 1.0 + e, 0.0]);
    assert_eq!(p[0] * q[1], p[1] * q[0]);
    assert!(edge_function(p, q) > 0.0);
    assert!(edge_function(q, p) < 0.0);
    assert_eq!(edge_function(p, q), -edge_function(q, p));
    assert_eq!(edge_function([1.0, 2.0, 0.0], [2.0, 4.0, 0.0]), 0.0);
}

// --------------------------------------------------------------- polygons

/// Sum of the triangles' areas, and the minimum of their normals' dot
/// products with the polygon's normal (positive: same orientation).
fn triangulation_area(p: &Polygon) -> (f64, f64) {
    let n = p.normal();
    let mut area = 0.0;
    let mut min_dot = f64::INFINITY;
    for [i, j, k] in &p.triangles {
        let (a, b, c) = (
            p.vertices[*i as usize],
            p.vertices[*j as usize],
            p.vertices[*k as usize],
        );
        let cr = (b - a).cross(c - a);
        area += 0.5 * cr.length();
        min_dot = min_dot.min(cr.normalize().dot(n));
    }
    (area, min_dot)
}

#[test]
fn polygon_from_vertices_rejects_bad_input() {
    let sq = [
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(1.0, 1.0, 0.0),
        v(0.0, 1.0, 0.0),
    ];
    assert!(Polygon::from_vertices(sq[..2].to_vec()).is_err());
    assert!(Polygon::from_vertices(vec![sq[0], sq[1], sq[1], sq[0]]).is_err());
    assert!(Polygon::from_vertices(vec![sq[0], sq[1], v(f64::NAN, 0.0, 0.0)]).is_err());
    assert!(Polygon::from_vertices(vec![sq[0], sq[1], v(f64::INFINITY, 0.0, 0.0)]).is_err());
    let why = |vs: Vec<Vec3>| Polygon::from_vertices(vs).err().unwrap_or_default();
    assert!(
        why(vec![sq[0], sq[1], v(2.0, 0.0, 0.0)]).contains("collinear"),
        "collinear"
    );
    // A bow tie whose lobes' signed areas cancel is not called collinear.
    let cancelling = why(vec![sq[0], sq[2], sq[1], sq[3]]);
    assert!(cancelling.contains("crosses itself"), "{cancelling}");
    let mut bent = sq.to_vec();
    bent[2].z = 1e-6;
    let bent = why(bent);
    assert!(
        bent.contains("is 2.5e-7 from its plane (tolerance 1e-9)"),
        "{bent}"
    );
    let mut slightly = sq.to_vec();
    slightly[2].z = 1e-12;
    assert!(
        Polygon::from_vertices(slightly).is_ok(),
        "planar within the tolerance"
    );
    let bowtie = vec![sq[0], sq[2], sq[1], sq[3]];
    assert!(Polygon::from_vertices(bowtie).is_err(), "self-intersecting");
    let spike = vec![
        sq[0],
        sq[1],
        v(2.0, 0.0, 0.0),
        v(1.5, 0.0, 0.0),
        sq[2],
        sq[3],
    ];
    assert!(Polygon::from_vertices(spike).is_err(), "doubles back");
    let touching = vec![
        v(0.0, 0.0, 0.0),
        v(2.0, 0.0, 0.0),
        v(2.0, 2.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 2.0, 0.0),
    ];
    assert!(
        Polygon::from_vertices(touching).is_err(),
        "vertex on an edge"
    );
    // Repeats are dropped, including a closing copy of the first vertex.
    let p = Polygon::from_vertices(vec![sq[0], sq[1], sq[1], sq[2], sq[3], sq[0]])
        .expect("valid square");
    assert_eq!(p.vertices, sq.to_vec());
    assert_eq!(p.triangles.len(), 2);
    assert_eq!(p.normal(), v(0.0, 0.0, 1.0));
}

#[test]
fn polygon_triangulation_covers_nonconvex_shapes() {
    // An L, a comb and a square with collinear midpoints, in a tilted plane,
    // with their areas.
    let shapes: Vec<(Vec<[f64; 2]>, f64)> = vec![
        (
            vec![
                [0.0, 0.0],
                [2.0, 0.0],
                [2.0, 1.0],
                [1.0, 1.0],
                [1.0, 2.0],
                [0.0, 2.0],
            ],
            3.0,
        ),
        (
            vec![
                [0.0, 0.0],
                [5.0, 0.0],
                [5.0, 3.0],
                [4.0, 3.0],
                [4.0, 1.0],
                [3.0, 1.0],
                [3.0, 3.0],
                [2.0, 3.0],
                [2.0, 1.0],
                [1.0, 1.0],
                [1.0, 3.0],
                [0.0, 3.0],
            ],
            11.0, // a 5×1 back and three 1×2 teeth
        ),
        (
            vec![
                [0.0, 0.0],
                [1.0, 0.0],
                [2.0, 0.0],
                [2.0, 1.0],
                [2.0, 2.0],
                [1.0, 2.0],
                [0.0, 2.0],
                [0.0, 1.0],
            ],
            4.0,
        ),
    ];
    let m = Affine::from_srt(Vec3::ONE, v(20.0, -35.0, 10.0), v(1.0, 2.0, 3.0));
    for (pts, area) in shapes {
        for reversed in [false, true] {
            let mut vs: Vec<Vec3> = pts.iter().map(|p| m.point(v(p[0], p[1], 0.0))).collect();
            if reversed {
                vs.reverse();
            }
            let n = vs.len();
            let poly = Polygon::from_vertices(vs).expect("valid polygon");
            assert_eq!(poly.triangles.len(), n - 2);
            let (sum, min_dot) = triangulation_area(&poly);
            assert_close(sum, area, 1e-12);
            assert!(min_dot > 1.0 - 1e-12, "a triangle is flipped: {min_dot}");
            let want = m.vector(v(0.0, 0.0, if reversed { -1.0 } else { 1.0 }));
            assert_vec_close(poly.normal(), want, 1e-12);
        }
    }
}

#[test]
fn polygon_is_crossed_once_even_on_inner_diagonals() {
    let m = Affine::from_srt(Vec3::ONE, v(20.0, -35.0, 10.0), v(1.0, 2.0, 3.0));
    let hexagon: Vec<Vec3> = (0..6)
        .map(|i| {
            let a = (60.0 * i as f64).to_radians();
            m.point(v(a.cos(), a.sin(), 0.0))
        })
        .collect();
    let poly = Polygon::from_vertices(hexagon).expect("valid hexagon");
    let p = prim(Shape::Polygon(poly.clone()));
    assert!(!p.is_solid());
    let n = poly.normal();
    // Every inner diagonal of the triangulation, at several points, from
    // several directions: exactly one crossing at the plane's t.
    let mut diagonals = 0;
    for (x, tri) in poly.triangles.iter().enumerate() {
        for other in &poly.triangles[x + 1..] {
            let shared: Vec<u32> = tri.iter().copied().filter(|i| other.contains(i)).collect();
            if shared.len() != 2 {
                continue;
            }
            diagonals += 1;
            let (a, b) = (
                poly.vertices[shared[0] as usize],
                poly.vertices[shared[1] as usize],
            );
            for s in [0.5, 0.25, 1.0 / 3.0] {
                let q = a + (b - a) * s;
                for d in [
                    n,
                    -n * 2.0,
                    n + (b - a) * 0.3,
                    n * 0.5 + m.vector(v(0.2, -0.4, 0.0)),
                ] {
                    let o = q - d * 2.0;
                    let cs = crossings(&hits(&p, o, d));
                    assert_eq!(cs.len(), 1, "through {q} along {d}");
                    assert_close(cs[0].t, 2.0, 1e-12);
                    assert_vec_close(normal_at(&p, o, d, cs[0]), n, 1e-15);
                }
            }
        }
    }
    assert_eq!(diagonals, 3);
    // The L's notch is outside.
    let l: Vec<Vec3> = [
        [0.0, 0.0],
        [2.0, 0.0],
        [2.0, 1.0],
        [1.0, 1.0],
        [1.0, 2.0],
        [0.0, 2.0],
    ]
    .iter()
    .map(|q| v(q[0], q[1], 0.0))
    .collect();
    let lp = prim(Shape::Polygon(Polygon::from_vertices(l).expect("valid L")));
    assert!(is_miss(&lp, v(1.5, 1.5, 1.0), v(0.0, 0.0, -1.0)));
    assert_eq!(
        crossings(&hits(&lp, v(0.5, 1.5, 1.0), v(0.0, 0.0, -1.0))),
        vec![Crossing { t: 1.0, part: 0 }]
    );
    assert_eq!(lp.bounds, Aabb::new(Vec3::ZERO, v(2.0, 2.0, 0.0)));
    // In its plane: a miss.
    assert!(is_miss(&lp, v(-1.0, 0.5, 0.0), v(1.0, 0.0, 0.0)));
}

#[test]
fn heap_bytes_counts_polygon_storage() {
    assert_eq!(sphere(Vec3::ZERO, 1.0).heap_bytes(), 0);
    let poly = Polygon::from_vertices(vec![Vec3::ZERO, Vec3::X, Vec3::ONE, Vec3::Y]).err();
    assert!(poly.is_some(), "not planar");
    let poly = Polygon::from_vertices(vec![Vec3::ZERO, Vec3::X, v(1.0, 1.0, 0.0), Vec3::Y])
        .expect("square");
    let p = prim(Shape::Polygon(poly));
    assert!(p.heap_bytes() >= 4 * std::mem::size_of::<Vec3>() + 2 * 12);
}

// ----------------------------------------------- random rays vs membership

/// xorshift64*: a fixed-seed generator, so the test is reproducible.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn vec(&mut self, lo: f64, hi: f64) -> Vec3 {
        v(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }
}

/// A signed measure of the object-space solid, written independently of
/// the intersection code: negative inside, positive outside, roughly a
/// distance near the surface.
fn signed_measure(shape: &Shape, p: Vec3) -> f64 {
    match shape {
        Shape::Sphere { center, radius } => (p - *center).length() - radius,
        Shape::Box { min, max } => (*min - p).max(p - *max).max_element(),
        Shape::Cylinder {
            base, top, radius, ..
        } => {
            let h = *top - *base;
            let a = h.normalize();
            let s = (p - *base).dot(a);
            let perp = ((p - *base) - a * s).length();
            (-s).max(s - h.length()).max(perp - radius)
        }
        Shape::Cone {
            base,
            base_radius,
            top,
            top_radius,
            ..
        } => {
            let h = *top - *base;
            let a = h.normalize();
            let s = (p - *base).dot(a);
            let perp = ((p - *base) - a * s).length();
            let k = (top_radius - base_radius) / h.length();
            let rho = base_radius + k * s;
            (-s).max(s - h.length())
                .max((perp - rho) / (1.0 + k * k).sqrt())
        }
        _ => unreachable!("solids only"),
    }
}

#[test]
fn random_rays_agree_with_point_membership() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut spans, mut normals) = (0, 0);
    for case in 0..4000 {
        let base = rng.vec(-1.0, 1.0);
        let top = base + rng.vec(-2.0, 2.0);
        let shape = match case % 5 {
            0 => Shape::Sphere {
                center: base,
                radius: rng.range(0.1, 2.0),
            },
            1 => Shape::Box {
                min: base,
                max: base + rng.vec(0.1, 2.0),
            },
            2 => Shape::Cylinder {
                base,
                top,
                radius: rng.range(0.1, 1.5),
                capped: true,
            },
            3 => Shape::Cone {
                base,
                base_radius: rng.range(0.1, 1.5),
                top,
                top_radius: rng.range(0.0, 1.5),
                capped: true,
            },
            _ => Shape::Cone {
                base,
                base_radius: 0.0,
                top,
                top_radius: rng.range(0.1, 1.5),
                capped: true,
            },
        };
        // Half of the primitives get a general affine map (kept as a
        // transform); membership is then tested in object space.
        let m = if case % 2 == 0 {
            Affine::IDENTITY
        } else {
            Affine::from_srt(
                rng.vec(0.3, 2.0),
                rng.vec(-180.0, 180.0),
                rng.vec(-1.0, 1.0),
            )
        };
        let p = placed(shape.clone(), &m);
        let (object_shape, to_object) = match &p.transform {
            Some(t) => (&p.shape, **t),
            None => (&p.shape, Affine::IDENTITY),
        };
        // Aim at a random point near the primitive from a random origin.
        let target = m.point(base + rng.vec(-1.0, 1.0));
        let o = target + rng.vec(-6.0, 6.0);
        let d = (target - o) * rng.range(0.05, 20.0);
        let ray = Ray::new(o, d);
        let inside = |t: f64| signed_measure(object_shape, to_object.inverse_point(ray.at(t)));
        let Some((t_lo, t_hi)) = p.bounds.inflated(1e-9).ray_interval(&ray) else {
            assert!(is_miss(&p, o, d), "hit outside its bounds: {p:?} {ray:?}");
            continue;
        };
        let samples =
            |from: f64, to: f64| (0..=64).map(move |i| from + (to - from) * i as f64 / 64.0);
        let tol = 1e-9;
        match hits(&p, o, d) {
            PrimHits::Miss => {
                for t in samples(t_lo, t_hi) {
                    assert!(
                        inside(t) > -tol,
                        "missed an inside point at t={t}: {p:?} {ray:?}"
                    );
                }
            }
            PrimHits::Solid { enter, exit } => {
                spans += 1;
                let scale = d.length();
                for c in [enter, exit] {
                    let m = inside(c.t);
                    assert!(
                        m.abs() < 1e-9,
                        "crossing off the surface by {m:e}: {p:?} {ray:?}"
                    );
                    // The outward normal is the measure's gradient, away
                    // from edges and rims (where the measure has a kink and
                    // two step sizes disagree).
                    let x = ray.at(c.t);
                    let f = |q: Vec3| signed_measure(object_shape, to_object.inverse_point(q));
                    let grad = |h: f64| {
                        v(
                            f(x + Vec3::X * h) - f(x - Vec3::X * h),
                            f(x + Vec3::Y * h) - f(x - Vec3::Y * h),
                            f(x + Vec3::Z * h) - f(x - Vec3::Z * h),
                        )
                        .normalize()
                    };
                    let (g1, g2) = (grad(1e-6), grad(0.5e-6));
                    if g1.dot(g2) > 1.0 - 1e-9 {
                        let n = p.normal(&ray, c.t, c.part);
                        assert!(
                            n.dot(g1) > 1.0 - 1e-6,
                            "normal {n} vs gradient {g1} at {c:?}: {p:?} {ray:?}"
                        );
                        normals += 1;
                    }
                }
                let len = exit.t - enter.t;
                for t in samples(enter.t + 1e-6 * len, exit.t - 1e-6 * len) {
                    assert!(
                        inside(t) < tol * scale.max(1.0),
                        "outside at t={t} in the span: {p:?} {ray:?}"
                    );
                }
                for t in samples(t_lo, enter.t).chain(samples(exit.t, t_hi)) {
                    let between = t > enter.t + 1e-6 * len && t < exit.t - 1e-6 * len;
                    if !between {
                        assert!(
                            inside(t) > -tol,
                            "inside at t={t} beyond the span: {p:?} {ray:?}"
                        );
                    }
                }
            }
            other => panic!("a solid gave {other:?}"),
        }
    }
    assert!(spans > 1000, "only {spans} spans");
    assert!(normals > 2 * spans - 100, "only {normals} normals checked");
}

/// `Primitive::surely_behind` (the walk clip's shortcut) may only answer
/// true where `intersect` finds nothing after `t_min`: boxes and polygons,
/// with and without transforms, seen from rays leaving them (where it
/// should answer true) and from anywhere.
#[test]
fn surely_behind_never_hides_a_crossing() {
    let mut rng = Rng(0x2545_F491_4F6C_DD1D);
    let (mut leaving, mut behind) = (0, 0);
    for case in 0..6000 {
        let base = rng.vec(-1.0, 1.0);
        let size = rng.vec(0.1, 3.0);
        let shape = if case % 2 == 0 {
            Shape::Box {
                min: base,
                max: base + size,
            }
        } else {
            let (sx, sy) = (size.x, size.y);
            let quad = vec![
                base,
                base + v(sx, 0.0, 0.0),
                base + v(sx, sy, 0.0),
                base + v(0.0, sy, 0.0),
            ];
            Shape::Polygon(Polygon::from_vertices(quad).expect("a rectangle"))
        };
        let m = if case % 4 < 2 {
            Affine::IDENTITY
        } else {
            Affine::from_srt(
                rng.vec(0.3, 2.0),
                rng.vec(-180.0, 180.0),
                rng.vec(-1.0, 1.0),
            )
        };
        let p = placed(shape, &m);
        // A ray leaving the top face (z = base.z + size.z for a box, the
        // plane for a polygon) upward, as a shadow or reflected ray leaves
        // a ground, or a ray from anywhere.
        let top = if p.is_solid() {
            base.z + size.z
        } else {
            base.z
        };
        let on = v(
            base.x + size.x * rng.next(),
            base.y + size.y * rng.next(),
            top,
        );
        let (o, d) = if case % 3 == 0 {
            let target = m.point(base + rng.vec(-1.0, 3.0));
            let o = target + rng.vec(-6.0, 6.0);
            (o, (target - o) * rng.range(0.05, 20.0))
        } else {
            leaving += 1;
            let up = v(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(0.05, 1.0),
            );
            (
                m.point(on + v(0.0, 0.0, 1e-9 * (1.0 + top.abs()))),
                m.vector(up),
            )
        };
        let ray = Ray::new(o, d);
        let t_min = if case % 5 == 0 {
            rng.range(0.0, 2.0)
        } else {
            0.0
        };
        if !p.surely_behind(&ray, t_min) {
            continue;
        }
        behind += usize::from(case % 3 != 0);
        for c in crossings(&p.intersect(&ray)) {
            let before = if p.is_solid() {
                c.t < t_min
            } else {
                c.t <= t_min
            };
            assert!(before, "{p:?} hides {c:?} after {t_min} from {ray:?}");
        }
    }
    // Most rays leaving a face are told apart without the test: the
    // shortcut is worth its place.
    assert!(behind * 2 > leaving, "{behind} of {leaving} leaving rays");
}

// ------------------------------------------------ rays leaving a surface

/// `Primitive::left_behind`: a ray that starts on a primitive's surface,
/// offset and moving to the side the rule allows (outward for the convex
/// shapes and the open tubes, either side for planar ones), finds no
/// crossing with it ahead, whatever the primitive, its transform and the
/// ray's direction; and only planar primitives allow the inner side.
#[test]
fn rays_leaving_a_surface_to_the_allowed_side_never_meet_it_again() {
    let m = Affine::from_srt(v(2.0, 0.5, 1.0), v(20.0, 35.0, -10.0), v(1.0, -2.0, 0.5));
    let shapes = [
        Shape::Sphere {
            center: v(0.1, 0.2, 0.3),
            radius: 1.3,
        },
        Shape::Box {
            min: v(-1.0, -0.5, -2.0),
            max: v(1.0, 0.5, 0.0),
        },
        Shape::Cylinder {
            base: v(0.0, 0.0, -1.0),
            top: v(0.5, 0.0, 1.0),
            radius: 0.7,
            capped: true,
        },
        Shape::Cylinder {
            base: v(0.0, 0.0, -1.0),
            top: v(0.0, 0.5, 1.0),
            radius: 0.7,
            capped: false,
        },
        Shape::Cone {
            base: v(0.0, 0.0, -1.0),
            base_radius: 1.0,
            top: v(0.0, 0.0, 1.0),
            top_radius: 0.0,
            capped: true,
        },
        Shape::Cone {
            base: v(0.0, 0.0, -1.0),
            base_radius: 1.0,
            top: v(0.2, 0.0, 1.0),
            top_radius: 0.4,
            capped: false,
        },
        Shape::Triangle {
            a: v(-1.0, -1.0, 0.2),
            b: v(1.5, -0.5, 0.0),
            c: v(0.0, 1.2, -0.3),
        },
    ];
    let mut rng = Rng(0x5EED_1EAF);
    let (mut spawned, mut surfaces) = (0usize, 0usize);
    for shape in shapes {
        let planar = matches!(shape, Shape::Triangle { .. });
        for p in [prim(shape.clone()), placed(shape, &m)] {
            assert!(p.left_behind(true));
            assert_eq!(p.left_behind(false), planar, "{p:?}");
            let centre = (p.bounds.min + p.bounds.max) * 0.5;
            let size = p.bounds.largest_side();
            for _ in 0..60 {
                let from = centre + rng.vec(-1.0, 1.0).normalize_or(Vec3::X) * (4.0 * size);
                let ray = Ray::new(from, centre + rng.vec(-0.3, 0.3) * size - from);
                for c in crossings(&p.intersect(&ray)) {
                    surfaces += 1;
                    let at = ray.at(c.t);
                    let n = p.normal(&ray, c.t, c.part);
                    for side in [n, -n] {
                        if !p.left_behind(side == n) {
                            continue;
                        }
                        let o = crate::trace::offset_origin(
                            &ray,
                            c.t,
                            at,
                            side,
                            p.rounding_size(at, c.part),
                        );
                        for _ in 0..40 {
                            let mut d = rng.vec(-1.0, 1.0).normalize_or(side);
                            if d.dot(side) < 0.0 {
                                d = -d;
                            }
                            spawned += 1;
                            let ahead = crossings(&hits(&p, o, d));
                            assert!(
                                ahead.iter().all(|x| x.t <= 0.0),
                                "{p:?}: from {o} along {d} ({} off the normal) {ahead:?}",
                                d.dot(side)
                            );
                        }
                    }
                }
            }
        }
    }
    assert!(
        surfaces > 500 && spawned > 20_000,
        "{surfaces} surfaces, {spawned} rays"
    );
}
