//! Eric Haines' sphereflake, the "balls" scene of the Standard Procedural
//! Databases (SPD, 1987): a sphere with nine children of a third of its
//! radius standing on its upper hemisphere (six around its equator, three
//! above), each with nine children of its own, recursively; a beige square
//! floor polygon; three lights; the SPD's camera. Level `n` has
//! `(9^(n+1) − 1)/8` spheres: 10, 91, 820, 7,381 (the SPD default, level 4),
//! 66,430.
//!
//! The model is what the NFF importer (`scene::nff`) makes of the SPD's NFF
//! output, built directly: the spheres are a flat list of top-level objects
//! as the SPD writes them (the implicit union of `SceneFile::objects`),
//! materials map NFF's `f` entity the same way (`Ks` is both the Phong
//! coefficient and the reflection coefficient, ambient 0.1), the lights get
//! NFF's grey `sqrt(n)/(2n)`, and NFF's view angle becomes `fov_y` as there.
//! The geometry is computed in f64 from the SPD's construction, so a
//! generated scene equals the SPD's up to the last printed digit.

use std::collections::BTreeMap;

use crate::geom::Vec3;
use crate::scene::model::{Node, SceneFile, Vector};
use crate::scene::nff;

/// Number of spheres of a sphereflake of `level`.
pub fn sphere_count(level: u32) -> u64 {
    (9u64.pow(level + 1) - 1) / 8
}

/// The SPD "balls" scene of recursion `level` (4 in the SPD, 7,381
/// spheres), 512×512. Spheres come first, parents before children, then
/// the floor polygon.
pub fn sphereflake(level: u32) -> SceneFile {
    let directions = child_directions();
    let mut objects = Vec::with_capacity(sphere_count(level) as usize + 1);
    // The SPD's top sphere: radius 0.5 at the origin, growing along +z;
    // children are a third of their parent's size.
    flake(&mut objects, &directions, level, Vec3::ZERO, 0.5, Vec3::Z);
    objects.push(Node::Polygon {
        vertices: vec![
            [12.0, 12.0, -0.5],
            [-12.0, 12.0, -0.5],
            [-12.0, -12.0, -0.5],
            [12.0, -12.0, -0.5],
        ],
        material: Some("floor".into()),
    });
    // NFF `f` entities: `f 1 0.75 0.33 0.8 0 0 0 1` for the floor and
    // `f 1 0.9 0.7 0.5 0.5 3.0827 0 1` for the spheres (the Phong exponent
    // whose lobe halves at 37 degrees, log 0.5 / log cos 37°).
    let nff =
        |color: Vector, kd: f64, ks: f64, shine: f64| nff::material(color, kd, ks, shine, 0.0, 1.0);
    let shine = 0.5f64.ln() / 37f64.to_radians().cos().ln();
    let materials = BTreeMap::from([
        ("floor".to_string(), nff([1.0, 0.75, 0.33], 0.8, 0.0, 0.0)),
        ("mirror".to_string(), nff([1.0, 0.9, 0.7], 0.5, 0.5, shine)),
    ]);
    // Three lights without colour; NFF's `angle 45` spans the centres of
    // the outer pixel rows, `fov_y` the image's edges.
    let lights = [[4.0, 3.0, 2.0], [1.0, -4.0, 4.0], [-3.0, 1.0, 5.0]];
    let fov_y = nff::fov_y_of_angle(45.0, 512);
    super::spd_scene([2.1, 1.3, 1.7], fov_y, &lights, materials, objects)
}

/// Emits the sphere at `center` of `radius` whose children grow along the
/// unit vector `up`, then its children, `level` generations deep.
fn flake(
    out: &mut Vec<Node>,
    directions: &[Vec3; 9],
    level: u32,
    center: Vec3,
    radius: f64,
    up: Vec3,
) {
    out.push(Node::Sphere {
        center: center.to_array(),
        radius,
        material: Some("mirror".into()),
    });
    if level == 0 {
        return;
    }
    // The rotation taking +z to `up`; children touch their parent.
    let rotate = rotation_from_z(up);
    let distance = radius * (1.0 + 1.0 / 3.0);
    for d in directions {
        let dir = rotate(*d);
        flake(
            out,
            directions,
            level - 1,
            center + dir * distance,
            radius / 3.0,
            dir,
        );
    }
}

/// The nine unit directions of a sphere's children around +z: three trios,
/// 120° apart about z, each trio the directions (1,1,0)/√2, (1,0,−1)/√2,
/// (0,1,−1)/√2 turned by asin(2/√6) about (1,−1,0)/√2. That puts one of each
/// trio at 54.7° from the pole and two on the equator.
fn child_directions() -> [Vec3; 9] {
    let s = 1.0 / 2f64.sqrt();
    let trio = [
        Vec3::new(s, s, 0.0),
        Vec3::new(s, 0.0, -s),
        Vec3::new(0.0, s, -s),
    ];
    let tilt = (2.0 / 6f64.sqrt()).asin();
    let axis = Vec3::new(1.0, -1.0, 0.0).normalize();
    let trio = trio.map(|v| axis_rotate(v, axis, tilt));
    let mut out = [Vec3::ZERO; 9];
    for set in 0..3 {
        let angle = set as f64 * 2.0 * std::f64::consts::PI / 3.0;
        for (k, v) in trio.iter().enumerate() {
            out[set * 3 + k] = axis_rotate(*v, Vec3::Z, angle);
        }
    }
    out
}

/// Rodrigues' rotation of `v` by `angle` (right-handed) about the unit `axis`.
fn axis_rotate(v: Vec3, axis: Vec3, angle: f64) -> Vec3 {
    let (sin, cos) = angle.sin_cos();
    v * cos + axis.cross(v) * sin + axis * axis.dot(v) * (1.0 - cos)
}

/// The rotation taking +z to the unit vector `to`.
fn rotation_from_z(to: Vec3) -> impl Fn(Vec3) -> Vec3 {
    let (axis, angle) = if to.z >= 1.0 {
        (Vec3::Z, 0.0)
    } else if to.z <= -1.0 {
        (Vec3::Y, std::f64::consts::PI)
    } else {
        (Vec3::Z.cross(to).normalize(), to.z.acos())
    };
    move |v| axis_rotate(v, axis, angle)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_four_is_the_spd_default() {
        let m = sphereflake(4);
        assert_eq!(sphere_count(4), 7381);
        assert_eq!(m.objects.len(), 7382);
        assert!(matches!(m.objects.last(), Some(Node::Polygon { .. })));
        assert_eq!(sphereflake(0).objects.len(), 2);
    }

    #[test]
    fn children_touch_their_parent_on_its_upper_half() {
        let dirs = child_directions();
        assert_eq!(dirs.iter().filter(|d| d.z.abs() < 1e-12).count(), 6);
        assert_eq!(dirs.iter().filter(|d| d.z > 0.5).count(), 3);
        for d in dirs {
            assert!((d.length() - 1.0).abs() < 1e-12);
        }
        let m = sphereflake(1);
        let Node::Sphere {
            center: c0,
            radius: r0,
            ..
        } = m.objects[0]
        else {
            panic!()
        };
        for n in &m.objects[1..10] {
            let Node::Sphere { center, radius, .. } = n else {
                panic!()
            };
            let d = (Vec3::from_array(*center) - Vec3::from_array(c0)).length();
            assert!((d - (r0 + radius)).abs() < 1e-12);
        }
    }

    #[test]
    fn compiles() {
        let (scene, _) =
            crate::scene::load::compile_model(&sphereflake(2), std::path::Path::new("sphereflake"))
                .unwrap();
        assert_eq!(scene.primitives.len(), 92);
    }
}
