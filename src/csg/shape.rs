//! The primitives: their parameters, world bounds, ray crossings and normals.
//! Owns the robust root-finding of `ROBUSTNESS.md` (cases 1-8, 29). Knows
//! nothing of trees, cells or shading.
//!
//! Every solid primitive is convex, so a ray is inside it over at most one
//! interval; surfaces (triangles, polygons, open cylinders and cones) are
//! crossed at most twice. `t` is never clipped here: negative values are kept
//! until after CSG combination (Roth 1982; `ROBUSTNESS.md`).

use crate::geom::{Aabb, Affine, Ray, Vec3};
use crate::scene::MaterialId;

/// A primitive's geometry in its own coordinates.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Parts: 0 the surface.
    Sphere { center: Vec3, radius: f64 },
    /// Parts: 0..6 = face `2·axis + side` (side 0 at `min`, 1 at `max`).
    Box { min: Vec3, max: Vec3 },
    /// Parts: 0 side, 1 base cap, 2 top cap. A surface when not capped.
    Cylinder { base: Vec3, top: Vec3, radius: f64, capped: bool },
    /// Parts: 0 side, 1 base cap, 2 top cap, 3 the apex. A surface when not capped.
    Cone { base: Vec3, base_radius: f64, top: Vec3, top_radius: f64, capped: bool },
    /// A surface. Parts: 0.
    Triangle { a: Vec3, b: Vec3, c: Vec3 },
    /// A planar surface, triangulated at load. Parts: 0.
    Polygon(Polygon),
}

/// A planar polygon (convex or not) with its triangulation.
#[derive(Clone, Debug, PartialEq)]
pub struct Polygon {
    pub vertices: Vec<Vec3>,
    /// Indices into `vertices`, three per triangle.
    pub triangles: Vec<[u32; 3]>,
}

/// One place where a ray meets a primitive's surface.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Crossing {
    pub t: f64,
    /// Which part of the surface (see `Shape`), so normals at rims, edges
    /// and apexes are chosen deterministically.
    pub part: u8,
}

/// What one primitive contributes along a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PrimHits {
    Miss,
    /// A solid: the ray is inside over `[enter.t, exit.t]`, `enter.t < exit.t`
    /// (zero-length spans are dropped, `ROBUSTNESS.md` case 2).
    Solid { enter: Crossing, exit: Crossing },
    /// A surface: `count` crossings (0, 1 or 2) sorted by `t`.
    Sheet { hits: [Crossing; 2], count: u8 },
}

/// A primitive placed in the world.
#[derive(Clone, Debug, PartialEq)]
pub struct Primitive {
    pub shape: Shape,
    /// Object-to-world map; `None` when `shape` is already in world
    /// coordinates (transforms are baked into the parameters where that is
    /// exact, see `Primitive::new`).
    pub transform: Option<Affine>,
    pub material: MaterialId,
    /// World bounds, computed once.
    pub bounds: Aabb,
}

impl Primitive {
    /// Places `shape` in the world by `to_world`. Where the map can be folded
    /// into the parameters without loss (boxes under translation and positive
    /// axis scales; spheres, cylinders, cones, triangles and polygons under
    /// similarities; everything under the identity), it is, so that a scaled
    /// and translated unit box meets another box's faces at bit-identical `t`
    /// (`ROBUSTNESS.md` cases 9-10).
    pub fn new(shape: Shape, to_world: &Affine, material: MaterialId) -> Primitive {
        let _ = (shape, to_world, material);
        todo!("shape helper")
    }

    /// True for solids (spheres, boxes, capped cylinders and cones).
    pub fn is_solid(&self) -> bool {
        match &self.shape {
            Shape::Sphere { .. } | Shape::Box { .. } => true,
            Shape::Cylinder { capped, .. } | Shape::Cone { capped, .. } => *capped,
            Shape::Triangle { .. } | Shape::Polygon(_) => false,
        }
    }

    /// The crossings of the (world) ray with this primitive, `t` unclipped.
    pub fn intersect(&self, ray: &Ray) -> PrimHits {
        let _ = ray;
        todo!("shape helper")
    }

    /// The unit world normal at `ray.at(t)` on `part`: outward for solids;
    /// for surfaces the geometric normal of a fixed orientation.
    pub fn normal(&self, ray: &Ray, t: f64, part: u8) -> Vec3 {
        let _ = (ray, t, part);
        todo!("shape helper")
    }
}
