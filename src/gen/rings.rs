//! Eric Haines' "rings" of the Standard Procedural Databases (SPD, 1987),
//! written from its published description: a pentagonal pattern of rings,
//! each ring a loop of cylinders with a sphere at every joint, over a floor
//! polygon, three lights. At size factor `f` the `k`-th pentagon
//! (`k = 1..=f`) carries `5k` rings, `k` per side, so there are
//! `5·f(f+1)/2` rings of 30 cylinders and 30 spheres: at the SPD's default
//! size, 7, that is 4,200 spheres, 4,200 cylinders and the floor, 8,401
//! primitives. The placement of the rings (spacing, tilt, heights) is ours:
//! every ring leans outwards at 45°, and rings are spaced so that none
//! touches another, which keeps the scene a valid flat list of objects.
//!
//! Like the SPD's output, everything is a flat list NFF can hold (open
//! cylinders, spheres, one polygon) with NFF's materials (`Ks` both Phong
//! and reflection coefficient, ambient 0.1) and NFF's grey lights, so
//! `gen rings -o rings.nff` writes it as NFF.

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_4, PI, TAU};

use crate::geom::Vec3;
use crate::scene::model::{Node, SceneFile, Vector};
use crate::scene::nff;

/// The SPD's default size factor.
pub const DEFAULT_SIZE: u32 = 7;
/// Cylinders (and spheres) per ring.
pub const SEGMENTS: usize = 30;
/// Radius of a ring's centre line.
const RING: f64 = 1.0;
/// Radius of its tube (cylinders and joint spheres).
const TUBE: f64 = 0.15;
/// Distance between the corners of consecutive pentagons. Rings on one side
/// are `2·SPACING·sin 36°` apart, pentagons `SPACING·cos 36°`; both exceed
/// `2·(RING + TUBE)`, the diameter of a ring's bounding sphere.
const SPACING: f64 = 3.0;

/// Number of rings at size factor `size`.
pub fn ring_count(size: u32) -> u64 {
    5 * u64::from(size) * (u64::from(size) + 1) / 2
}

/// The rings scene of size factor `size` (`DEFAULT_SIZE` in the SPD), 512×512.
pub fn rings(size: u32) -> SceneFile {
    let mut objects = Vec::with_capacity(ring_count(size) as usize * 2 * SEGMENTS + 1);
    // Lowest point of a ring leaning at 45°: its centre less R·sin 45° and the tube.
    let height = RING * FRAC_PI_4.sin() + TUBE + 0.05;
    for k in 1..=size {
        let corner = |m: u32| {
            let a = PI / 2.0 + f64::from(m) * TAU / 5.0;
            Vec3::new(a.cos(), a.sin(), 0.0) * (f64::from(k) * SPACING)
        };
        let material = ["red", "green", "blue"][(k as usize - 1) % 3];
        for m in 0..5 {
            let (a, b) = (corner(m), corner(m + 1));
            for i in 0..k {
                let c = a + (b - a) * (f64::from(i) / f64::from(k));
                ring(&mut objects, c + Vec3::Z * height, material);
            }
        }
    }
    let extent = (f64::from(size) * SPACING + 2.0 * RING) * 1.5;
    objects.push(Node::Polygon {
        vertices: vec![
            [extent, extent, 0.0],
            [-extent, extent, 0.0],
            [-extent, -extent, 0.0],
            [extent, -extent, 0.0],
        ],
        material: Some("floor".into()),
    });
    // NFF `f` entities: colour, Kd, Ks (also the reflection), Phong exponent.
    let nff =
        |color: Vector, kd: f64, ks: f64, shine: f64| nff::material(color, kd, ks, shine, 0.0, 1.0);
    let materials = BTreeMap::from([
        ("red".into(), nff([0.9, 0.25, 0.2], 0.7, 0.3, 30.0)),
        ("green".into(), nff([0.3, 0.8, 0.35], 0.7, 0.3, 30.0)),
        ("blue".into(), nff([0.3, 0.4, 0.9], 0.7, 0.3, 30.0)),
        ("floor".into(), nff([0.8, 0.75, 0.6], 0.8, 0.0, 0.0)),
    ]);
    let r = f64::from(size) * SPACING + RING;
    let lights = [[1.5, -1.0, 2.5], [-2.0, -1.5, 2.0], [0.5, 2.0, 3.0]].map(|v| v.map(|x| x * r));
    super::spd_scene([0.0, -2.1 * r, 1.6 * r], 42.0, &lights, materials, objects)
}

/// A ring centred at `c`, leaning outwards (away from the z axis) at 45°:
/// `SEGMENTS` open cylinders and a sphere at every joint.
fn ring(out: &mut Vec<Node>, c: Vec3, material: &str) {
    let outward = Vec3::new(c.x, c.y, 0.0).normalize_or(Vec3::X);
    // The ring's plane holds the tangent of its pentagon and the direction
    // half way between outwards and up.
    let u = Vec3::Z.cross(outward);
    let v = (outward + Vec3::Z).normalize();
    let point = |j: usize| {
        let a = TAU * j as f64 / SEGMENTS as f64;
        (c + (u * a.cos() + v * a.sin()) * RING).to_array()
    };
    for j in 0..SEGMENTS {
        out.push(Node::Sphere {
            center: point(j),
            radius: TUBE,
            material: Some(material.into()),
        });
        out.push(Node::Cylinder {
            base: point(j),
            top: point(j + 1),
            radius: TUBE,
            capped: false,
            material: Some(material.into()),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_size_has_the_spds_counts() {
        let m = rings(DEFAULT_SIZE);
        let spheres = m
            .objects
            .iter()
            .filter(|n| matches!(n, Node::Sphere { .. }))
            .count();
        let cylinders = m
            .objects
            .iter()
            .filter(|n| matches!(n, Node::Cylinder { .. }))
            .count();
        assert_eq!((spheres, cylinders, m.objects.len()), (4200, 4200, 8401));
    }

    #[test]
    fn rings_do_not_touch_and_the_scene_compiles() {
        let m = rings(3);
        let centres: Vec<Vec3> = m
            .objects
            .chunks(2 * SEGMENTS)
            .filter(|c| c.len() == 2 * SEGMENTS)
            .map(|c| {
                let sum = c.iter().fold(Vec3::ZERO, |s, n| match n {
                    Node::Sphere { center, .. } => s + Vec3::from_array(*center),
                    _ => s,
                });
                sum / SEGMENTS as f64
            })
            .collect();
        assert_eq!(centres.len() as u64, ring_count(3));
        for (i, a) in centres.iter().enumerate() {
            assert!(
                a.z - RING * FRAC_PI_4.sin() - TUBE > 0.0,
                "ring {i} cuts the floor"
            );
            for b in &centres[i + 1..] {
                assert!((*a - *b).length() > 2.0 * (RING + TUBE), "{a} {b}");
            }
        }
        let (scene, _) =
            crate::scene::load::compile_model(&m, std::path::Path::new("rings")).unwrap();
        assert_eq!(scene.primitives.len(), m.objects.len());
    }
}
