//! The jagged ball of the paper's figure 16 (Priol, Arnaldi & Bouatouch
//! 1987), as `scenes/jagged_ball.ron` models it: a gold ball of radius 1
//! with solids subtracted from it (conical pits, rotated box notches,
//! spherical dimples; their cut faces red) and solids added to it (steel
//! cone spikes, some rotated into place by a `Transform`, small sphere
//! bumps, rotated cube crystals), one per point of a Fibonacci sphere with
//! a pseudo-random choice per point; a conical pedestal over a polished
//! floor box. Tree: a `Union` (steel) of a `Difference` (the sphere first,
//! then the cuts) and the added solids: the CSG-heavy case where a
//! renderer that tests every child of a difference for every ray pays for
//! all 200.
//!
//! `jagged_ball(seed, points)`: the same seed and count give the same
//! scene; `POINTS` makes the bundled scene's 203 primitives. Numbers are
//! rounded to 4 decimals, as in the bundled file.

use std::collections::BTreeMap;

use super::random::SplitMix64;
use crate::geom::Vec3;
use crate::scene::model::{Camera, Light, Material, Node, SceneFile, Vector};

/// Points on the ball in the bundled scene (one cut or added solid each).
pub const POINTS: usize = 200;

/// The jagged ball with `points` cuts and additions (plus the ball, the
/// pedestal and the floor), 640×480.
pub fn jagged_ball(seed: u64, points: usize) -> SceneFile {
    let mut rng = SplitMix64(seed);
    let mut cuts = vec![Node::Sphere {
        center: [0.0; 3],
        radius: 1.0,
        material: Some("gold".into()),
    }];
    let mut adds = Vec::new();
    // The golden angle turns each point from the last, so the points cover
    // the sphere evenly from top (z near 1) to bottom.
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..points {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / points as f64;
        let ring = (1.0 - z * z).sqrt();
        let phi = i as f64 * golden;
        let n = Vec3::new(ring * phi.cos(), ring * phi.sin(), z);
        let kind = rng.unit_f64();
        if rng.chance(0.5) {
            cuts.push(cut(&mut rng, n, kind));
        } else {
            adds.push(addition(&mut rng, n, kind, phi));
        }
    }
    let mut union = vec![Node::Difference {
        children: cuts,
        material: Some("cut".into()),
    }];
    union.extend(adds);
    let material = |color: Vector, specular: f64, shininess: f64, reflect: f64| Material {
        color: Some(color),
        specular: (specular > 0.0).then_some(specular),
        shininess: (specular > 0.0).then_some(shininess),
        reflect: (reflect > 0.0).then_some(reflect),
        ..Material::default()
    };
    SceneFile {
        camera: Camera {
            eye: [3.0, -3.3, 1.2],
            look_at: [0.0, 0.0, -0.15],
            up: [0.0, 0.0, 1.0],
            fov_y: 48.0,
            width: 640,
            height: 480,
        },
        background: [0.04, 0.05, 0.09],
        ambient: [0.6; 3],
        lights: vec![
            Light {
                position: [6.0, -4.0, 8.0],
                color: [0.9; 3],
            },
            Light {
                position: [-5.0, -6.0, 3.0],
                color: [0.3, 0.3, 0.35],
            },
        ],
        materials: BTreeMap::from([
            ("gold".into(), material([0.85, 0.55, 0.18], 0.6, 60.0, 0.15)),
            ("cut".into(), material([0.65, 0.07, 0.05], 0.3, 30.0, 0.0)),
            (
                "steel".into(),
                material([0.7, 0.72, 0.78], 0.8, 120.0, 0.35),
            ),
            ("floor".into(), material([0.3, 0.36, 0.42], 0.0, 0.0, 0.2)),
        ]),
        objects: vec![
            Node::Union {
                children: union,
                material: Some("steel".into()),
            },
            Node::Cone {
                base: [0.0, 0.0, -1.6],
                base_radius: 0.45,
                top: [0.0, 0.0, -0.8],
                top_radius: 0.12,
                capped: true,
                material: Some("steel".into()),
            },
            Node::Box {
                min: [-8.0, -8.0, -1.8],
                max: [8.0, 8.0, -1.6],
                material: Some("floor".into()),
            },
        ],
        max_depth: 5,
    }
}

/// A solid subtracted at the surface point `n`: a conical pit, a rotated
/// box notch or a spherical dimple, by `kind` in [0, 1).
fn cut(rng: &mut SplitMix64, n: Vec3, kind: f64) -> Node {
    if kind < 0.45 {
        Node::Cone {
            base: q3(n * 1.1),
            base_radius: q(rng.range(0.09, 0.14)),
            top: q3(n * rng.range(0.66, 0.74)),
            top_radius: 0.0,
            capped: true,
            material: None,
        }
    } else if kind < 0.75 {
        let half = Vec3::new(
            rng.range(0.08, 0.16),
            rng.range(0.03, 0.07),
            rng.range(0.08, 0.14),
        );
        Node::Transform {
            translate: q3(n * rng.range(0.98, 1.02)),
            rotate: random_rotation(rng),
            scale: [1.0; 3],
            child: Box::new(Node::Box {
                min: q3(-half),
                max: q3(half),
                material: None,
            }),
            material: None,
        }
    } else {
        Node::Sphere {
            center: q3(n * rng.range(1.0, 1.05)),
            radius: q(rng.range(0.09, 0.13)),
            material: None,
        }
    }
}

/// A solid added at the surface point `n` (longitude `phi`): a cone spike
/// (every other one built along z and rotated into place), a sphere bump
/// or a rotated cube crystal, by `kind` in [0, 1).
fn addition(rng: &mut SplitMix64, n: Vec3, kind: f64, phi: f64) -> Node {
    if kind < 0.45 {
        let (length, radius) = (rng.range(1.2, 1.45), q(rng.range(0.05, 0.14)));
        if rng.chance(0.5) {
            Node::Cone {
                base: q3(n * 0.9),
                base_radius: radius,
                top: q3(n * length),
                top_radius: 0.0,
                capped: true,
                material: None,
            }
        } else {
            // About y by the polar angle, then about z by the longitude,
            // takes +z to `n`.
            Node::Transform {
                translate: [0.0; 3],
                rotate: [0.0, q(n.z.acos().to_degrees()), q(phi.to_degrees() % 360.0)],
                scale: [1.0; 3],
                child: Box::new(Node::Cone {
                    base: [0.0, 0.0, 0.9],
                    base_radius: radius,
                    top: [0.0, 0.0, q(length)],
                    top_radius: 0.0,
                    capped: true,
                    material: None,
                }),
                material: None,
            }
        }
    } else if kind < 0.7 {
        Node::Sphere {
            center: q3(n * rng.range(0.95, 1.0)),
            radius: q(rng.range(0.05, 0.08)),
            material: None,
        }
    } else {
        let half = rng.range(0.05, 0.065);
        Node::Transform {
            translate: q3(n * rng.range(0.98, 1.02)),
            rotate: random_rotation(rng),
            scale: [1.0; 3],
            child: Box::new(Node::Box {
                min: [q(-half); 3],
                max: [q(half); 3],
                material: None,
            }),
            material: None,
        }
    }
}

fn random_rotation(rng: &mut SplitMix64) -> Vector {
    [
        q(rng.range(0.0, 180.0)),
        q(rng.range(0.0, 180.0)),
        q(rng.range(0.0, 180.0)),
    ]
}

/// Rounded to 4 decimals, as the bundled scene is written.
fn q(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

fn q3(v: Vec3) -> Vector {
    [q(v.x), q(v.y), q(v.z)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(n: &Node) -> usize {
        match n {
            Node::Union { children, .. } | Node::Difference { children, .. } => {
                children.iter().map(count).sum()
            }
            Node::Transform { child, .. } => count(child),
            _ => 1,
        }
    }

    #[test]
    fn has_the_bundled_scenes_shape_and_compiles() {
        let m = jagged_ball(1, POINTS);
        let prims: usize = m.objects.iter().map(count).sum();
        assert_eq!(prims, POINTS + 3);
        let Node::Union { children, .. } = &m.objects[0] else {
            panic!("a union first")
        };
        let Node::Difference { children: cuts, .. } = &children[0] else {
            panic!("the difference first")
        };
        // About half the points cut, half add.
        assert!((70..130).contains(&(cuts.len() - 1)), "{}", cuts.len());
        let (scene, _) =
            crate::scene::load::compile_model(&m, std::path::Path::new("jagged")).unwrap();
        assert_eq!(scene.primitives.len(), POINTS + 3);
        assert_eq!(jagged_ball(1, POINTS), m);
        assert_ne!(jagged_ball(2, POINTS), m);
    }

    #[test]
    fn rotated_spikes_point_along_their_surface_normal() {
        use crate::geom::Affine;
        let m = jagged_ball(5, POINTS);
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let points: Vec<Vec3> = (0..POINTS)
            .map(|i| {
                let z = 1.0 - (2.0 * i as f64 + 1.0) / POINTS as f64;
                let phi = i as f64 * golden;
                Vec3::new(
                    (1.0 - z * z).sqrt() * phi.cos(),
                    (1.0 - z * z).sqrt() * phi.sin(),
                    z,
                )
            })
            .collect();
        let Node::Union { children, .. } = &m.objects[0] else {
            panic!()
        };
        let mut seen = 0;
        for c in children {
            if let Node::Transform {
                translate: [0.0, 0.0, 0.0],
                rotate,
                ..
            } = c
            {
                let r = Affine::from_srt(Vec3::ONE, Vec3::from_array(*rotate), Vec3::ZERO);
                let axis = r.point(Vec3::Z);
                let nearest = points
                    .iter()
                    .map(|p| (*p - axis).length())
                    .fold(f64::INFINITY, f64::min);
                assert!(nearest < 1e-3, "{rotate:?} points along {axis}");
                seen += 1;
            }
        }
        assert!(seen > 10, "{seen}");
    }
}
