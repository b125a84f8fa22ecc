//! Scene generators: build `scene::model::SceneFile`s in code, for property
//! tests and for the `gen` command (`cmd::generate`), which writes them as
//! RON, JSON or NFF. Generators only make models; validation and
//! compilation stay with `scene::load`.

pub mod jagged_ball;
pub mod random;
pub mod rings;
pub mod sphereflake;
pub mod stress;

pub use random::{CameraPlacement, MAX_TREE_DEPTH, RandomCsgOptions, random_csg};

use std::collections::BTreeMap;

use crate::scene::model::{Camera, Light, Material, Node, SceneFile, Vector};
use crate::scene::nff;

/// A scene of the Standard Procedural Databases as the SPD writes it: the
/// SPD's 512×512 frame and sky-blue background, looking at the origin with
/// z up, and what NFF implies (white ambient light, recursion depth 5,
/// lights without colour in NFF's grey).
fn spd_scene(
    eye: Vector,
    fov_y: f64,
    lights: &[Vector],
    materials: BTreeMap<String, Material>,
    objects: Vec<Node>,
) -> SceneFile {
    let grey = nff::light_grey(lights.len());
    SceneFile {
        camera: Camera {
            eye,
            look_at: [0.0; 3],
            up: [0.0, 0.0, 1.0],
            fov_y,
            width: 512,
            height: 512,
        },
        background: [0.078, 0.361, 0.753],
        ambient: [1.0; 3],
        lights: lights
            .iter()
            .map(|&position| Light {
                position,
                color: grey,
            })
            .collect(),
        materials,
        objects,
        max_depth: 5,
    }
}
