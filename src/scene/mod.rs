//! The scene: the file model (`model`), loading and validation (`load`), and
//! the compiled, validated `Scene` that every later layer reads. Owns file
//! syntax and the meaning of every field of `SCENE_FORMAT.md`; knows nothing
//! of cells, nodes or images.

pub mod flat;
pub mod load;
pub mod model;
pub mod nff;
pub mod pov;

pub use load::{SceneSyntax, load_scene, parse_scene_str};

use crate::csg::{CsgTree, Primitive};
use crate::geom::{Color, Vec3};

/// The largest `max_depth` a scene or `--max-depth` may ask for: enough for
/// any hall of mirrors a Whitted image can show, and a bound on the ray tree.
pub const MAX_DEPTH_LIMIT: u32 = 64;

/// Index into `Scene::materials`. `MaterialId::DEFAULT` is the default
/// material of `SCENE_FORMAT.md`.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
pub struct MaterialId(pub u32);

impl MaterialId {
    pub const DEFAULT: MaterialId = MaterialId(0);
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// A pinhole camera (`SCENE_FORMAT.md`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    pub eye: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_y: f64,
    pub width: u32,
    pub height: u32,
}

/// A point light; not attenuated with distance.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Light {
    pub position: Vec3,
    pub color: Color,
}

/// Whitted's material (`SCENE_FORMAT.md`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Material {
    pub color: Color,
    pub ambient: f64,
    pub diffuse: f64,
    pub specular: f64,
    pub shininess: f64,
    pub reflect: f64,
    pub transmit: f64,
    pub ior: f64,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            color: Color::ONE,
            ambient: 0.1,
            diffuse: 0.7,
            specular: 0.0,
            shininess: 20.0,
            reflect: 0.0,
            transmit: 0.0,
            ior: 1.0,
        }
    }
}

/// A validated scene, ready to render. `tree`'s leaves index `primitives`;
/// primitives index `materials`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Scene {
    pub camera: Camera,
    pub background: Color,
    pub ambient: Color,
    pub lights: Vec<Light>,
    /// `materials[0]` is the default material.
    pub materials: Vec<Material>,
    /// Names of `materials`, `"<default>"` first.
    pub material_names: Vec<String>,
    pub primitives: Vec<Primitive>,
    pub tree: CsgTree,
    pub max_depth: u32,
}

impl Scene {
    pub fn material(&self, id: MaterialId) -> &Material {
        &self.materials[id.index()]
    }
}
