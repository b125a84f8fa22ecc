//! Scene generators: build `scene::model::SceneFile`s in code, for property
//! tests and for a `gen` command that writes them as RON or JSON (with
//! `scene::load::scene_to_string`). Generators only make models; validation
//! and compilation stay with `scene::load`.

pub mod random;
pub mod sphereflake;
pub mod stress;

pub use random::{CameraPlacement, MAX_TREE_DEPTH, RandomCsgOptions, random_csg};
