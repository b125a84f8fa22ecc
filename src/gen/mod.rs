//! Scene generators: build `scene::model::SceneFile`s in code, for property
//! tests and for the `gen` command (`cmd::generate`), which writes them as
//! RON, JSON or NFF. Generators only make models; validation and
//! compilation stay with `scene::load`.

pub mod jagged_ball;
pub mod random;
pub mod rings;
pub mod sphereflake;

pub use random::{CameraPlacement, MAX_TREE_DEPTH, RandomCsgOptions, random_csg};
