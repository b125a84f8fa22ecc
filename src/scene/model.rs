//! The serde model of scene files (`SCENE_FORMAT.md`), shared by RON and JSON
//! (and the target of the NFF importer). Owns the field names, which are an
//! interface, and their defaults; nothing here validates or compiles: that is
//! `load`'s job. Plain data with `pub` fields, so generators and converters
//! can build a model and serialize it.
//!
//! Every struct and every node denies unknown fields, so a misspelt field is
//! a syntax error rather than a silently ignored default.
//!
//! **Deep trees.** `Node` is recursive; deserializing, serializing, cloning,
//! comparing and dropping a model all recurse once per tree level. A model
//! 10,000 levels deep needs far more than a default 2 MiB thread stack: do
//! such work on a thread with a large stack, as `load` does.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// A 3-vector or a linear RGB colour: RON `(1.0, 2, 3)`, JSON `[1, 2, 3]`.
pub type Vector = [f64; 3];

/// A scene file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub camera: Camera,
    /// Colour of rays that leave the scene.
    #[serde(default = "black")]
    pub background: Vector,
    /// Global ambient light, scaled by each material's `ambient`.
    #[serde(default = "white")]
    pub ambient: Vector,
    #[serde(default)]
    pub lights: Vec<Light>,
    /// Named materials; a `BTreeMap` so that iteration (and so material
    /// numbering) is by name, whatever the order in the file.
    #[serde(default)]
    pub materials: BTreeMap<String, Material>,
    /// The scene, an implicit `Union` of the list.
    pub objects: Vec<Node>,
    /// Reflection/refraction recursion limit (at most `load::MAX_DEPTH_CAP`).
    #[serde(default = "default_max_depth")]
    pub max_depth: u32,
}

/// A pinhole camera. Pixel (i, j), i to the right and j downwards, is
/// sampled at its centre.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    pub eye: Vector,
    pub look_at: Vector,
    #[serde(default = "z_up")]
    pub up: Vector,
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_y: f64,
    pub width: u32,
    pub height: u32,
}

/// A point light, not attenuated with distance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Light {
    pub position: Vector,
    #[serde(default = "white")]
    pub color: Vector,
}

/// Whitted's material. Every field is optional so that a material with a
/// `base` (an extension of `SCENE_FORMAT.md`) can tell "not set here, take
/// the base's" from "set to the default value"; an unset field without a
/// base takes the default of `SCENE_FORMAT.md`, listed beside each field
/// (and in `scene::Material::default()`).
///
/// In RON the values are written bare (`specular: 0.6`, not
/// `specular: Some(0.6)`): `load` parses RON with the `implicit_some`
/// extension.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Another named material to take unset fields from (an extension).
    /// Chains are allowed; cycles and unknown names are load errors.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base: Option<String>,
    /// Default `[1, 1, 1]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<Vector>,
    /// Default 0.1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ambient: Option<f64>,
    /// Default 0.7.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffuse: Option<f64>,
    /// Default 0.0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular: Option<f64>,
    /// Phong exponent. Default 20.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shininess: Option<f64>,
    /// Default 0.0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reflect: Option<f64>,
    /// Default 0.0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transmit: Option<f64>,
    /// Index of refraction. Default 1.0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ior: Option<f64>,
}

/// A node of the CSG tree: serde's externally tagged enum, RON
/// `Sphere(center: (0, 0, 1), radius: 1)`, JSON
/// `{"Sphere": {"center": [0, 0, 1], "radius": 1}}`. Every node takes an
/// optional `material`, a name from `SceneFile::materials`; a node without
/// one inherits its nearest ancestor's, and with none at all the default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum Node {
    Sphere {
        center: Vector,
        radius: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// Axis-aligned; rotate it with `Transform`. `min == max` on an axis is
    /// accepted (an invisible sheet, with a warning); `min > max` is not.
    Box {
        min: Vector,
        max: Vector,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// A solid when capped, else a surface.
    Cylinder {
        base: Vector,
        top: Vector,
        radius: f64,
        #[serde(default = "yes")]
        capped: bool,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// A solid when capped, else a surface. A radius of 0 makes a point.
    Cone {
        base: Vector,
        base_radius: f64,
        top: Vector,
        top_radius: f64,
        #[serde(default = "yes")]
        capped: bool,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// A surface.
    Triangle {
        a: Vector,
        b: Vector,
        c: Vector,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// A planar surface, convex or not.
    Polygon {
        vertices: Vec<Vector>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    Union {
        children: Vec<Node>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    Intersection {
        children: Vec<Node>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// The first child minus all the others.
    Difference {
        children: Vec<Node>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// Children that do not overlap (the paper's null operator).
    Assembly {
        children: Vec<Node>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
    /// Scale, then rotate (degrees about x, then y, then z), then translate.
    Transform {
        #[serde(default = "zero")]
        translate: Vector,
        #[serde(default = "zero")]
        rotate: Vector,
        #[serde(default = "one")]
        scale: Vector,
        child: Box<Node>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
    },
}

impl Node {
    /// The variant's name as written in files (`"Sphere"`, `"Difference"`…),
    /// which is also the segment that node paths use.
    pub fn kind(&self) -> &'static str {
        match self {
            Node::Sphere { .. } => "Sphere",
            Node::Box { .. } => "Box",
            Node::Cylinder { .. } => "Cylinder",
            Node::Cone { .. } => "Cone",
            Node::Triangle { .. } => "Triangle",
            Node::Polygon { .. } => "Polygon",
            Node::Union { .. } => "Union",
            Node::Intersection { .. } => "Intersection",
            Node::Difference { .. } => "Difference",
            Node::Assembly { .. } => "Assembly",
            Node::Transform { .. } => "Transform",
        }
    }

    /// The node's own `material` field.
    pub fn material(&self) -> Option<&str> {
        match self {
            Node::Sphere { material, .. }
            | Node::Box { material, .. }
            | Node::Cylinder { material, .. }
            | Node::Cone { material, .. }
            | Node::Triangle { material, .. }
            | Node::Polygon { material, .. }
            | Node::Union { material, .. }
            | Node::Intersection { material, .. }
            | Node::Difference { material, .. }
            | Node::Assembly { material, .. }
            | Node::Transform { material, .. } => material.as_deref(),
        }
    }

    /// The node's own `material` field, to change it.
    pub fn material_mut(&mut self) -> &mut Option<String> {
        match self {
            Node::Sphere { material, .. }
            | Node::Box { material, .. }
            | Node::Cylinder { material, .. }
            | Node::Cone { material, .. }
            | Node::Triangle { material, .. }
            | Node::Polygon { material, .. }
            | Node::Union { material, .. }
            | Node::Intersection { material, .. }
            | Node::Difference { material, .. }
            | Node::Assembly { material, .. }
            | Node::Transform { material, .. } => material,
        }
    }

    /// True for nodes that bound no volume (`SCENE_FORMAT.md`: triangles,
    /// polygons, uncapped cylinders and cones), which may appear only under
    /// `Union` and `Assembly`.
    pub fn is_surface(&self) -> bool {
        match self {
            Node::Triangle { .. } | Node::Polygon { .. } => true,
            Node::Cylinder { capped, .. } | Node::Cone { capped, .. } => !capped,
            _ => false,
        }
    }
}

fn black() -> Vector {
    [0.0; 3]
}
fn white() -> Vector {
    [1.0; 3]
}
fn zero() -> Vector {
    [0.0; 3]
}
fn one() -> Vector {
    [1.0; 3]
}
fn z_up() -> Vector {
    [0.0, 0.0, 1.0]
}
fn yes() -> bool {
    true
}
fn default_max_depth() -> u32 {
    5
}
