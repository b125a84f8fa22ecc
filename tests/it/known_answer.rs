//! Scenes with an exactly known picture (pbrt-v4's `integrators_test` style):
//! a silhouette area, Lambert's cosine, a perfect mirror.

use hypercast::geom::Vec3;

use crate::util::{self, pixel_dir, screen};

/// Silhouette of S(0, 3) minus a box that removes the half-space through
/// the eye and the view axis (rotated 30° about that axis, so the cut is a
/// slanted diameter on screen and the box is a transformed primitive).
/// The sphere's silhouette seen from distance D is a disc of angular
/// radius asin(r/D), on the image plane a disc of radius tan(asin(r/D));
/// the cut keeps exactly half of it.
const HALF_DISC: &str = r#"(
  camera: (eye: (0, -10, 0), look_at: (0, 0, 0), fov_y: 40, width: 400, height: 400),
  background: (0, 0, 0),
  ambient: (1, 1, 1),
  materials: { "flat": (color: (0.5, 0.25, 1), ambient: 1, diffuse: 0) },
  objects: [
    Difference(material: "flat", children: [
      Sphere(center: (0, 0, 0), radius: 3),
      Transform(rotate: (0, 30, 0), child: Box(min: (0, -4, -4), max: (4, 4, 4))),
    ]),
  ],
)"#;

#[test]
fn sphere_minus_box_covers_the_analytic_half_disc() {
    let (w, h, fov) = (400u32, 400u32, 40.0f64);
    let scene = util::scene(HALF_DISC);
    let (film, _) = util::roth(&scene, w, h);
    let colour = hypercast::trace::Film::quantize(Vec3::new(0.5, 0.25, 1.0));
    let mut covered = 0usize;
    for (k, s) in film.sums().iter().enumerate() {
        // With ambient 1 and no lights a covered pixel is the colour, exactly.
        assert!(*s == [0; 3] || *s == colour, "pixel {k} is {s:?}");
        covered += usize::from(*s == colour);
    }
    let rho = (3.0f64 / 10.0).asin().tan();
    let half_h = (fov.to_radians() / 2.0).tan();
    let pixel_area = (2.0 * half_h / w as f64) * (2.0 * half_h / h as f64);
    let expected = std::f64::consts::PI * rho * rho / 2.0 / pixel_area;
    let rel = (covered as f64 - expected).abs() / expected;
    assert!(
        rel < 0.005,
        "covered {covered} pixels, analytic {expected:.1} ({rel:.5} off)"
    );

    // Sharper: count the pixel centres inside the half disc. Kept: the side
    // the rotated box does not reach, x·cos30° − z·sin30° < 0 (screen x is
    // world x, screen y is world z for this camera).
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let mut lattice = 0usize;
    for j in 0..h {
        for i in 0..w {
            let (sx, sy) = screen(fov, w, h, i, j);
            lattice += usize::from(sx * sx + sy * sy < rho * rho && sx * c - sy * s < 0.0);
        }
    }
    assert!(
        covered.abs_diff(lattice) <= 2,
        "covered {covered}, pixel centres in the half disc {lattice}"
    );

    eprintln!("covered {covered}, analytic {expected:.1}, lattice {lattice}");
    // The paper's cells must give the same picture as the brute force, bit for bit.
    let (cells, _) = util::cells(&scene, w, h);
    assert!(cells.sums() == film.sums(), "cells and roth films differ");
}

/// A white-ish Lambert plane (the top face z = 0 of a big box) under one
/// light straight above the origin; ambient 0, diffuse 1. Every pixel is
/// `color · cos θ` with θ between the normal (0, 0, 1) and the light; the
/// centre pixel (odd image size) sees the origin at normal incidence.
#[test]
fn lambert_plane_pixel_is_colour_times_cosine() {
    let (w, h, fov) = (41u32, 31u32, 40.0f64);
    let (eye, look, light) = (
        Vec3::new(0.0, -6.0, 4.0),
        Vec3::ZERO,
        Vec3::new(0.0, 0.0, 5.0),
    );
    let colour = Vec3::new(1.0, 0.5, 0.25);
    let scene = util::scene(
        r#"(
      camera: (eye: (0, -6, 4), look_at: (0, 0, 0), fov_y: 40, width: 41, height: 31),
      background: (0, 0, 0),
      lights: [(position: (0, 0, 5))],
      materials: { "plane": (color: (1, 0.5, 0.25), ambient: 0, diffuse: 1) },
      objects: [Box(min: (-100, -100, -1), max: (100, 100, 0), material: "plane")],
    )"#,
    );
    let (film, _) = util::roth(&scene, w, h);
    let px = film.to_linear();
    for j in 0..h {
        for i in 0..w {
            let d = pixel_dir(eye, look, Vec3::Z, fov, w, h, i, j);
            assert!(d.z < 0.0, "every pixel looks down at the plane");
            let p = eye + d * (-eye.z / d.z);
            let cos = (light - p).normalize().z;
            let want = colour * cos;
            let got = px[(j * w + i) as usize];
            for k in 0..3 {
                assert!(
                    (got[k] as f64 - want[k]).abs() < 1e-6,
                    "pixel ({i}, {j}) is {got:?}, want {want}"
                );
            }
        }
    }
    let centre = px[(h / 2 * w + w / 2) as usize];
    assert!(
        (centre[0] - 1.0).abs() < 1e-6,
        "normal incidence gives the full colour, got {centre:?}"
    );
}

/// What a camera sees directly equals what its mirror image sees in a
/// perfect mirror (reflect 1, nothing else). Camera B looks at the mirror
/// plane y = 0; camera A is B reflected through that plane, and a
/// reflection reverses handedness, so B's pixel (i, j) is A's (w−1−i, j).
#[test]
fn perfect_mirror_shows_the_direct_picture() {
    let (w, h) = (48u32, 36u32);
    let common = r#"
      background: (0, 0, 0),
      lights: [(position: (2, -1, 4))],
      materials: {
        "ball": (color: (0.9, 0.3, 0.2), ambient: 0.1, diffuse: 0.8, specular: 0.5, shininess: 30),
        "mirror": (color: (1, 1, 1), ambient: 0, diffuse: 0, reflect: 1),
      },"#;
    let ball = "Sphere(center: (0, -4, 0), radius: 1, material: \"ball\")";
    let direct = util::scene(&format!(
        "(camera: (eye: (3, 6, 1), look_at: (0, -4, 0), fov_y: 20, width: 48, height: 36), {common}
          objects: [{ball}])"
    ));
    let mirrored = util::scene(&format!(
        "(camera: (eye: (3, -6, 1), look_at: (0, 4, 0), fov_y: 20, width: 48, height: 36), {common}
          objects: [{ball}, Box(min: (-20, 0, -20), max: (20, 0.5, 20), material: \"mirror\")])"
    ));
    let (a, _) = util::roth(&direct, w, h);
    let (b, stats) = util::roth(&mirrored, w, h);
    assert_eq!(
        stats.rays.get(hypercast::trace::RayKind::Reflected),
        (w * h) as u64,
        "every primary ray of B meets the mirror once"
    );
    let (a, b) = (a.to_linear(), b.to_linear());
    let mut ball_pixels = 0;
    for j in 0..h {
        for i in 0..w {
            let pa = a[(j * w + (w - 1 - i)) as usize];
            let pb = b[(j * w + i) as usize];
            ball_pixels += usize::from(pa != [0.0; 3]);
            for k in 0..3 {
                assert!(
                    (pa[k] - pb[k]).abs() < 1e-6,
                    "B pixel ({i}, {j}) {pb:?} != A's mirror pixel {pa:?}"
                );
            }
        }
    }
    assert!(
        ball_pixels > 200,
        "the ball must fill part of the view, got {ball_pixels} pixels"
    );
}
