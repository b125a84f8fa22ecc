//! The primitives: their parameters, world bounds, ray crossings and normals.
//! Owns the robust root-finding of `ROBUSTNESS.md` (cases 1-8, 29). Knows
//! nothing of trees, cells or shading.
//!
//! Every solid primitive is convex, so a ray is inside it over at most one
//! interval; surfaces (triangles, polygons, open cylinders and cones) are
//! crossed at most twice. `t` is never clipped here: negative values are kept
//! until after CSG combination (Roth 1982; `ROBUSTNESS.md`).
//!
//! Ray directions are never assumed to be unit length, and no absolute
//! epsilon appears: quadratics use the Haines/Günther/Akenine-Möller form
//! (Ray Tracing Gems ch. 7), triangles the watertight test of Woop, Benthin
//! and Wald (JCGT 2013) with a top-left tie rule so that a ray through a
//! shared edge or vertex crosses a closed mesh exactly once per side, and
//! every division by a direction component is guarded (a ray parallel to a
//! slab or cap plane is inside it or not by its origin alone). Ties between
//! faces are broken by fixed rules (lowest box axis; a cap over a side; a
//! zero-radius cap or a ray through the apex is the apex part) so normals at
//! edges, rims and apexes are deterministic, unit and finite. `intersect` allocates nothing.

// Comparisons are written `!(x > 0.0)` on purpose: a NaN lands in the
// "no hit" branch.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::error::fmt_sig;
use crate::geom::{Aabb, Affine, Ray, Vec3, frobenius_norm};
use crate::scene::MaterialId;
use glam::DMat3;

/// A primitive's geometry in its own coordinates.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Shape {
    /// Parts: 0 the surface.
    Sphere { center: Vec3, radius: f64 },
    /// Parts: 0..6 = face `2·axis + side` (side 0 at `min`, 1 at `max`).
    Box { min: Vec3, max: Vec3 },
    /// Parts: 0 side, 1 base cap, 2 top cap. A surface when not capped.
    Cylinder {
        base: Vec3,
        top: Vec3,
        radius: f64,
        capped: bool,
    },
    /// Parts: 0 side, 1 base cap, 2 top cap, 3 the apex. A surface when not capped.
    Cone {
        base: Vec3,
        base_radius: f64,
        top: Vec3,
        top_radius: f64,
        capped: bool,
    },
    /// A surface. Parts: 0.
    Triangle { a: Vec3, b: Vec3, c: Vec3 },
    /// A planar surface, triangulated at load. Parts: 0.
    Polygon(Polygon),
}

/// A planar polygon (convex or not) with its triangulation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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
    Solid {
        enter: Crossing,
        exit: Crossing,
    },
    /// A surface: `count` crossings (0, 1 or 2) sorted by `t`.
    Sheet {
        hits: [Crossing; 2],
        count: u8,
    },
}

/// A primitive placed in the world.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Primitive {
    pub shape: Shape,
    /// Object-to-world map; `None` when `shape` is already in world
    /// coordinates (transforms are baked into the parameters where that is
    /// exact, see `Primitive::new`). Boxed: most primitives have none, and
    /// a map (240 bytes) held inline would more than double every
    /// primitive a node's memory budget pays for.
    pub transform: Option<Box<Affine>>,
    pub material: MaterialId,
    /// World bounds, computed once.
    pub bounds: Aabb,
}

/// Part numbers shared by cylinders and cones.
const SIDE: u8 = 0;
const BASE_CAP: u8 = 1;
const TOP_CAP: u8 = 2;
const APEX: u8 = 3;

impl Primitive {
    /// Places `shape` in the world by `to_world`. Where the map can be folded
    /// into the parameters without loss (boxes under translations, axis
    /// scales and quarter turns; spheres under similarities; cylinders and cones when
    /// their cross-section stays circular and the map takes coordinate axes
    /// to coordinate axes (`keeps_axes`), e.g. an axis-aligned cylinder
    /// scaled equally across its axis or turned by quarter turns; triangles and
    /// polygons under every affine map, since their images are again
    /// triangles and planar polygons; everything under the identity), it is,
    /// so that a scaled and translated unit box meets another box's faces at
    /// bit-identical `t` (`ROBUSTNESS.md` cases 9-10). Otherwise the shape
    /// stays in object space with `transform: Some(*to_world)`.
    pub fn new(shape: Shape, to_world: &Affine, material: MaterialId) -> Primitive {
        let (shape, transform) = if to_world.is_identity() {
            (shape, None)
        } else {
            bake(shape, to_world)
        };
        let bounds = world_bounds(&shape, transform.as_ref());
        Primitive {
            shape,
            transform: transform.map(Box::new),
            material,
            bounds,
        }
    }

    /// True for solids (spheres, boxes, capped cylinders and cones).
    pub fn is_solid(&self) -> bool {
        match &self.shape {
            Shape::Sphere { .. } | Shape::Box { .. } => true,
            Shape::Cylinder { capped, .. } | Shape::Cone { capped, .. } => *capped,
            Shape::Triangle { .. } | Shape::Polygon(_) => false,
        }
    }

    /// The size whose rounding a hit's computed `t` carries, besides the
    /// distance the ray travelled: `optics::offset_origin`'s `extent` for a
    /// hit at `p`, so that a spawned ray starts as near its surface as the
    /// rounding allows.
    ///
    /// A box in world coordinates is met at `(face − o) / d`, a correctly
    /// rounded difference divided once: its `t` is as exact as the distance
    /// itself, however far the box reaches, so its size adds nothing. A box
    /// under a map is met so in its own space, after the ray's origin is
    /// mapped there, `M⁻¹·(o − T)`: that costs its face coordinate some
    /// 4 ε·‖row of M⁻¹‖₁·|o − T|, which is 4√3 ε·|o − T| across the face in
    /// the world, whatever the map's scales; `|o − T|` is at most
    /// `|p − T|` and the distance, so `|p − T|` covers it nine times over.
    /// A triangle or polygon lying in a coordinate plane is met as a box's
    /// face is (`on_plane`): size 0 too. So, reaching 2^21 times beyond
    /// the hit, is a triangle or polygon, met on its exact plane; a sphere,
    /// and an ellipsoid on the coordinate axes, met with their exact power
    /// (`sphere_hits`, `ellipsoid_hits`); and the side (`part`) of a
    /// cylinder or cone (`far_cylinder_roots`, `far_cone_roots`) and of an
    /// elliptic drum along an axis of its map (`mapped_cylinder_hits`). A
    /// cylinder or cone otherwise combines distances along and from its
    /// axis that the hit's distance from its base and its height bound
    /// (`axial_size`), which for a disc of radius 1e20 are far below its
    /// extent. Every other shape subtracts or combines magnitudes of its
    /// own size (a sphere's centre and radius, a tilted polygon's
    /// vertices), which its world extent bounds.
    ///
    /// Before this, a ground box reaching 1e20 pushed every shadow ray from
    /// it 1.4e6 up, over whatever should have shadowed it
    /// (`docs/robustness.md`, "Spawned rays of a box reaching 1e20"), and
    /// so did a ground polygon, tilted or not, a sphere of radius 1e20 and
    /// a lying drum as wide ("A ground polygon reaching 1e20", "A tilted
    /// polygon reaching 1e20", "A sphere of radius 1e12 to 1e45 for a
    /// ground", "A lying drum of radius 1e12 to 1e45 for a ground", "A
    /// cone of radius 1e12 to 1e45 for a ground", "An ellipsoid of
    /// semi-axes 1e12 to 1e45 for a ground").
    pub fn rounding_size(&self, p: Vec3, part: u8) -> f64 {
        let extent = || self.bounds.largest_side();
        match (&self.shape, &self.transform) {
            (Shape::Box { .. }, None) => 0.0,
            (shape, None) if shape.in_coordinate_plane() => 0.0,
            // Met on its exact plane (`on_plane`) or with the exact power
            // of the ray's origin (`sphere_hits`): as accurate as the
            // distance travelled.
            (Shape::Triangle { .. } | Shape::Polygon(_) | Shape::Sphere { .. }, None)
                if extent() > 2.0 * FAR_REACH * p.abs().max_element() =>
            {
                0.0
            }
            // A cylinder's or cone's side as wide against its hit: met
            // with the exact power too (`far_cylinder_roots`,
            // `far_cone_roots`). Its caps keep their size below, as a
            // tilted cap far from its base is met through the rounded axis.
            (shape, None)
                if part == SIDE
                    && shape
                        .side_radius()
                        .is_some_and(|r| r > FAR_REACH * p.abs().max_element()) =>
            {
                0.0
            }
            // An elliptic drum's side as wide against its hit: met with
            // its exact power (`mapped_cylinder_hits`).
            (
                &Shape::Cylinder {
                    base, top, radius, ..
                },
                Some(m),
            ) if part == SIDE
                && elliptic_drum(m, base, top)
                    .is_some_and(|e| radius * e.semi_axis > FAR_REACH * p.abs().max_element()) =>
            {
                0.0
            }
            // An ellipsoid on the coordinate axes as large against its
            // hit: met with its exact power (`ellipsoid_hits`).
            (Shape::Sphere { .. }, Some(m))
                if m.axis_scales().is_some()
                    && extent() > 2.0 * FAR_REACH * p.abs().max_element() =>
            {
                0.0
            }
            (Shape::Box { .. }, Some(m)) => (p - m.translation).abs().max_element(),
            (&Shape::Cylinder { base, top, .. }, m) => {
                axial_size(p, m.as_deref(), base, top, 0.0).min(extent())
            }
            (
                &Shape::Cone {
                    base,
                    base_radius,
                    top,
                    top_radius,
                    ..
                },
                m,
            ) => {
                let k = (top_radius - base_radius) / (top - base).length();
                let apex = ConeScale::new(base_radius, k).apex();
                axial_size(p, m.as_deref(), base, top, apex).min(extent())
            }
            _ => extent(),
        }
    }

    /// Whether a ray that starts on this primitive's surface and moves off
    /// it, to the side its normal points to (`outward`) or to the other,
    /// can never meet it again, so that the ray's queries may leave it out
    /// (`RayJob::leaving`).
    ///
    /// Why: the ray starts a little off the surface on the side it moves
    /// to (`optics::offset_origin`), so it is off the plane across the
    /// normal at its start, on that side, for every `t > 0` (a shadow ray
    /// ends at its light, on that side too). A planar primitive lies in
    /// that plane: either side will do. Every other primitive is convex
    /// or lies on the boundary of its convex hull (an open cylinder or
    /// cone), so the plane across its outward normal leaves it wholly on
    /// the inner side: only a ray leaving outward is sure to miss it. All
    /// of this holds under an affine transform.
    pub fn left_behind(&self, outward: bool) -> bool {
        match &self.shape {
            Shape::Triangle { .. } | Shape::Polygon(_) => true,
            Shape::Sphere { .. }
            | Shape::Box { .. }
            | Shape::Cylinder { .. }
            | Shape::Cone { .. } => outward,
        }
    }

    /// The crossings of the (world) ray with this primitive, `t` unclipped.
    /// A transformed primitive is intersected with the ray mapped into its
    /// object space; `t` is the same in both spaces because the direction is
    /// mapped without renormalising.
    pub fn intersect(&self, ray: &Ray) -> PrimHits {
        match (&self.transform, &self.shape) {
            (None, shape) => intersect_shape(shape, ray),
            (Some(m), &Shape::Sphere { center, radius }) => ellipsoid_hits(ray, m, center, radius),
            (Some(m), shape @ Shape::Cylinder { .. }) => mapped_cylinder_hits(ray, m, shape),
            (Some(m), shape) => mapped_hits(ray, m, shape),
        }
    }

    /// True only when every crossing `intersect` would report lies before
    /// `t_min` (a solid's) or at or before it (a surface's, with `t_min ≥
    /// 0`), decided by a part of the test's own arithmetic, so that the
    /// answer is exact without the whole test. False says nothing. Covers
    /// the grounds of the walk clip (`cells::WideClip`) seen from rays that
    /// leave them: a box whose far face on some axis is behind `t_min`, and
    /// a polygon with every vertex behind the ray's origin.
    pub fn surely_behind(&self, ray: &Ray, t_min: f64) -> bool {
        let local;
        let ray = match &self.transform {
            None => ray,
            Some(m) => {
                local = m.inverse_ray(ray);
                &local
            }
        };
        match &self.shape {
            Shape::Box { min, max } => box_behind(ray, *min, *max, t_min),
            Shape::Polygon(p) => t_min >= 0.0 && polygon_behind(ray, p),
            _ => false,
        }
    }

    /// The unit world normal at `ray.at(t)` on `part`: outward for solids;
    /// for surfaces the geometric normal of a fixed orientation
    /// (`(b − a) × (c − a)` for triangles, the vertex order for polygons).
    /// Never NaN or zero: edges, rims and apexes use their part's normal.
    pub fn normal(&self, ray: &Ray, t: f64, part: u8) -> Vec3 {
        match &self.transform {
            None => shape_normal(&self.shape, ray, t, part),
            Some(m) => {
                let n = m.normal(shape_normal(&self.shape, &m.inverse_ray(ray), t, part));
                if n.is_finite() { n } else { Vec3::Z }
            }
        }
    }

    /// Bytes of heap memory this primitive owns (its map, a polygon's
    /// vertices and triangles), for the nodes' memory budgets.
    pub fn heap_bytes(&self) -> usize {
        let map = self
            .transform
            .as_ref()
            .map_or(0, |_| std::mem::size_of::<Affine>());
        map + match &self.shape {
            Shape::Polygon(p) => p.heap_bytes(),
            _ => 0,
        }
    }
}

impl Polygon {
    /// Checks and triangulates a polygon given by its boundary in order.
    ///
    /// Exact repeats of consecutive vertices (and a closing copy of the
    /// first) are dropped. Rejected: fewer than 3 distinct vertices, NaN or
    /// infinite coordinates, zero area (twice the area ≤ 1e-12 × extent²),
    /// non-planar vertices (farther than 1e-9 × extent from the plane through
    /// the centroid with Newell's normal), and self-intersecting or touching
    /// boundaries (checked pairwise for up to `SIMPLE_CHECK_LIMIT` vertices;
    /// beyond that only when ear clipping gets stuck). The triangulation is
    /// ear clipping in the projection that drops the normal's dominant axis;
    /// every triangle keeps the polygon's orientation.
    pub fn from_vertices(vertices: Vec<Vec3>) -> Result<Polygon, String> {
        if let Some(i) = vertices.iter().position(|v| !v.is_finite()) {
            return Err(format!("polygon vertex {i} is not finite: {}", vertices[i]));
        }
        let mut vs = vertices;
        vs.dedup();
        while vs.len() > 1 && vs.first() == vs.last() {
            vs.pop();
        }
        let n = vs.len();
        if n < 3 {
            return Err(format!(
                "a polygon needs at least 3 distinct vertices, it has {n}"
            ));
        }
        if u32::try_from(n).is_err() {
            return Err(format!("a polygon may have at most {} vertices", u32::MAX));
        }
        let bbox = Aabb::from_points(vs.iter().copied());
        let extent = bbox.largest_side();
        let centre = (bbox.min + bbox.max) * 0.5;
        let newell = newell_normal(&vs, centre);
        let twice_area = newell.length();
        if !(twice_area > 1e-12 * extent * extent) {
            return Err(zero_area(&vs, extent));
        }
        let unit = newell / twice_area;
        let centroid = vs.iter().fold(Vec3::ZERO, |s, v| s + (*v - centre)) / n as f64 + centre;
        let tol = 1e-9 * extent;
        for (i, v) in vs.iter().enumerate() {
            let dist = (*v - centroid).dot(unit).abs();
            if dist > tol {
                return Err(format!(
                    "the polygon is not planar: vertex {i} is {} from its plane \
                     (tolerance {})",
                    fmt_sig(dist),
                    fmt_sig(tol)
                ));
            }
        }
        // Project by dropping the dominant axis; (ix, iy, drop) is a cyclic
        // permutation, so the projection's signed area has the sign of
        // `unit[drop]` and `orient` below is positive at convex corners.
        let drop = unit.abs().max_position();
        let (ix, iy) = ((drop + 1) % 3, (drop + 2) % 3);
        let sign = if unit[drop] > 0.0 { 1.0 } else { -1.0 };
        let pts: Vec<[f64; 2]> = vs
            .iter()
            .map(|v| {
                let q = *v - centre;
                [q[ix] * sign, q[iy]]
            })
            .collect();
        if n <= SIMPLE_CHECK_LIMIT {
            check_simple(&pts)?;
        }
        let triangles = ear_clip(&pts)?;
        vs.shrink_to_fit();
        Ok(Polygon {
            vertices: vs,
            triangles,
        })
    }

    /// The unit normal of the polygon's orientation (Newell's method), the
    /// same for every triangle of its triangulation.
    pub fn normal(&self) -> Vec3 {
        let origin = self.vertices.first().copied().unwrap_or(Vec3::ZERO);
        newell_normal(&self.vertices, origin).normalize_or(Vec3::Z)
    }

    /// Bytes of heap memory owned by the vertex and triangle vectors.
    pub fn heap_bytes(&self) -> usize {
        self.vertices.capacity() * std::mem::size_of::<Vec3>()
            + self.triangles.capacity() * std::mem::size_of::<[u32; 3]>()
    }
}

/// Why a polygon's area is zero: its vertices lie on a line (within the
/// planarity tolerance of `extent`), or its boundary crosses itself so that
/// the signed areas of its parts cancel (a bow tie), which the message must
/// not call collinear.
fn zero_area(vs: &[Vec3], extent: f64) -> String {
    let o = vs[0];
    let far = vs
        .iter()
        .copied()
        .max_by(|a, b| {
            (*a - o)
                .length_squared()
                .total_cmp(&(*b - o).length_squared())
        })
        .unwrap_or(o);
    let along = (far - o).normalize_or_zero();
    let off_line = vs
        .iter()
        .map(|v| (*v - o).cross(along).length())
        .fold(0.0, f64::max);
    if off_line <= 1e-9 * extent {
        "the polygon has zero area (its vertices are collinear)".to_string()
    } else {
        "the polygon has zero area: its boundary crosses itself so that its parts cancel; \
         give each part as a polygon of its own"
            .to_string()
    }
}

/// Polygons with more vertices skip the O(n²) self-intersection check.
const SIMPLE_CHECK_LIMIT: usize = 4096;

/// Newell's normal: twice the vector area, summed relative to `origin` to
/// keep the products small.
fn newell_normal(vs: &[Vec3], origin: Vec3) -> Vec3 {
    let mut n = Vec3::ZERO;
    for (i, v) in vs.iter().enumerate() {
        let w = vs[(i + 1) % vs.len()];
        n += (*v - origin).cross(w - origin);
    }
    n
}

/// Twice the signed area of the 2D triangle `a b c` (positive when
/// counter-clockwise).
fn orient2(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// True when `p` lies on the closed segment `a b`, given that the three are
/// collinear.
fn on_segment(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> bool {
    p[0] >= a[0].min(b[0])
        && p[0] <= a[0].max(b[0])
        && p[1] >= a[1].min(b[1])
        && p[1] <= a[1].max(b[1])
}

/// Rejects a boundary that crosses or touches itself, or doubles back on
/// itself (a zero-width spike).
fn check_simple(pts: &[[f64; 2]]) -> Result<(), String> {
    let n = pts.len();
    let err = |i: usize, j: usize| Err(format!("the polygon's edges {i} and {j} intersect"));
    for i in 0..n {
        let (a, b) = (pts[i], pts[(i + 1) % n]);
        let c = pts[(i + 2) % n];
        if orient2(a, b, c) == 0.0
            && (b[0] - a[0]) * (c[0] - b[0]) + (b[1] - a[1]) * (c[1] - b[1]) < 0.0
        {
            return err(i, (i + 1) % n);
        }
        for j in i + 2..n {
            if i == 0 && j == n - 1 {
                continue; // adjacent through the closing edge
            }
            let (c, d) = (pts[j], pts[(j + 1) % n]);
            let (o1, o2) = (orient2(a, b, c), orient2(a, b, d));
            let (o3, o4) = (orient2(c, d, a), orient2(c, d, b));
            let proper = o1 * o2 < 0.0 && o3 * o4 < 0.0;
            let touch = (o1 == 0.0 && on_segment(a, b, c))
                || (o2 == 0.0 && on_segment(a, b, d))
                || (o3 == 0.0 && on_segment(c, d, a))
                || (o4 == 0.0 && on_segment(c, d, b));
            if proper || touch {
                return err(i, j);
            }
        }
    }
    Ok(())
}

/// Ear clipping of a simple polygon whose projection is counter-clockwise.
/// Zero-area ears are never cut (a vertex between collinear neighbours waits
/// until a neighbour is cut), so no degenerate triangle is produced.
fn ear_clip(pts: &[[f64; 2]]) -> Result<Vec<[u32; 3]>, String> {
    let n = pts.len();
    let mut next: Vec<usize> = (0..n).map(|i| (i + 1) % n).collect();
    let mut prev: Vec<usize> = (0..n).map(|i| (i + n - 1) % n).collect();
    let mut tris = Vec::with_capacity(n - 2);
    let mut remaining = n;
    let mut i = 0;
    let mut misses = 0;
    let as_u32 = |k: usize| k as u32; // n ≤ u32::MAX, checked by the caller
    while remaining > 3 {
        let (p, q) = (prev[i], next[i]);
        let is_ear = orient2(pts[p], pts[i], pts[q]) > 0.0 && {
            let mut k = next[q];
            let mut empty = true;
            while k != p {
                let x = pts[k];
                if orient2(pts[p], pts[i], x) >= 0.0
                    && orient2(pts[i], pts[q], x) >= 0.0
                    && orient2(pts[q], pts[p], x) >= 0.0
                {
                    empty = false;
                    break;
                }
                k = next[k];
            }
            empty
        };
        if is_ear {
            tris.push([as_u32(p), as_u32(i), as_u32(q)]);
            next[p] = q;
            prev[q] = p;
            remaining -= 1;
            misses = 0;
            i = p;
        } else {
            misses += 1;
            if misses > remaining {
                return Err("the polygon is self-intersecting or degenerate \
                            (it cannot be triangulated)"
                    .to_string());
            }
            i = q;
        }
    }
    let (p, q) = (prev[i], next[i]);
    if orient2(pts[p], pts[i], pts[q]) > 0.0 {
        tris.push([as_u32(p), as_u32(i), as_u32(q)]);
    }
    tris.shrink_to_fit();
    Ok(tris)
}

/// Folds `m` into the shape's parameters where that is exact (see
/// `Primitive::new`); otherwise keeps the transform.
fn bake(shape: Shape, m: &Affine) -> (Shape, Option<Affine>) {
    match shape {
        // Under scales and quarter turns a box stays axis-aligned: its
        // corners map to the corners of a box (sorted below).
        Shape::Box { min, max } if keeps_axes(m) => {
            let (p, q) = (m.point(min), m.point(max));
            (
                Shape::Box {
                    min: p.min(q),
                    max: p.max(q),
                },
                None,
            )
        }
        Shape::Sphere { center, radius } => match m.similarity_scale() {
            Some(s) => (
                Shape::Sphere {
                    center: m.point(center),
                    radius: radius * s,
                },
                None,
            ),
            None => (Shape::Sphere { center, radius }, Some(*m)),
        },
        Shape::Cylinder {
            base,
            top,
            radius,
            capped,
        } => match circular_scale(m, base, top).filter(|_| keeps_axes(m)) {
            Some(s) => (
                Shape::Cylinder {
                    base: m.point(base),
                    top: m.point(top),
                    radius: radius * s,
                    capped,
                },
                None,
            ),
            None => (
                Shape::Cylinder {
                    base,
                    top,
                    radius,
                    capped,
                },
                Some(*m),
            ),
        },
        Shape::Cone {
            base,
            base_radius,
            top,
            top_radius,
            capped,
        } => match circular_scale(m, base, top).filter(|_| keeps_axes(m)) {
            Some(s) => (
                Shape::Cone {
                    base: m.point(base),
                    base_radius: base_radius * s,
                    top: m.point(top),
                    top_radius: top_radius * s,
                    capped,
                },
                None,
            ),
            None => (
                Shape::Cone {
                    base,
                    base_radius,
                    top,
                    top_radius,
                    capped,
                },
                Some(*m),
            ),
        },
        Shape::Triangle { a, b, c } => (
            Shape::Triangle {
                a: m.point(a),
                b: m.point(b),
                c: m.point(c),
            },
            None,
        ),
        Shape::Polygon(p) => {
            // An affine map keeps the triangulation valid (it maps triangles
            // to triangles and preserves incidence).
            let vertices = p.vertices.iter().map(|v| m.point(*v)).collect();
            (
                Shape::Polygon(Polygon {
                    vertices,
                    triangles: p.triangles,
                }),
                None,
            )
        }
        other => (other, Some(*m)),
    }
}

/// True when `m`'s linear part maps each coordinate axis onto a coordinate
/// axis (a scale, possibly with quarter turns): then every plane a box
/// under `m` would have in its object space is also a coordinate plane in
/// the world. Cylinders and cones are baked only then. Under any other
/// rotation a box cannot be baked and meets rays in its object space; a
/// cylinder baked into the world would meet them at caps computed another
/// way, so a hole drilled by a cylinder whose caps lie in the box's faces
/// (one transform above both) showed speckles where the two roundings
/// disagree (`ROBUSTNESS.md` case 9 turned by (30°, 40°, 50°): 171 pixels
/// of 9216). Kept in object space, both compute those planes from the same
/// mapped ray, bit for bit.
fn keeps_axes(m: &Affine) -> bool {
    let cols = [m.linear.x_axis, m.linear.y_axis, m.linear.z_axis];
    cols.iter()
        .all(|c| c.to_array().iter().filter(|x| **x != 0.0).count() == 1)
}

/// `shape` with `m` folded into its parameters, when that is exact for it
/// (see `Primitive::new`); `None` otherwise.
pub fn bake_exactly(shape: Shape, m: &Affine) -> Option<Shape> {
    let (shape, transform) = bake(shape, m);
    transform.is_none().then_some(shape)
}

/// The radius scale when `m` maps every circle perpendicular to the axis
/// `base → top` to a circle perpendicular to the image axis (a similarity,
/// or e.g. scale (s, s, z) of a z-aligned cylinder), so that a cylinder or
/// cone stays one. Relative tolerance 1e-14, as `Affine::similarity_scale`.
fn circular_scale(m: &Affine, base: Vec3, top: Vec3) -> Option<f64> {
    if let Some(s) = m.similarity_scale() {
        return Some(s);
    }
    let (a, _) = unit_axis(base, top)?;
    let (u, v) = a.any_orthonormal_pair();
    let (mu, mv, ma) = (m.vector(u), m.vector(v), m.vector(a));
    let (lu, lv, la) = (mu.length(), mv.length(), ma.length());
    let tol = 1e-14;
    let ok = lu > 0.0
        && lu.is_finite()
        && la > 0.0
        && la.is_finite()
        && (lu - lv).abs() <= tol * lu
        && mu.dot(mv).abs() <= tol * lu * lv
        && mu.dot(ma).abs() <= tol * lu * la
        && mv.dot(ma).abs() <= tol * lv * la;
    ok.then_some(lu)
}

/// The unit axis from `base` to `top` and its length; `None` when they
/// coincide (or are not finite).
#[inline]
fn unit_axis(base: Vec3, top: Vec3) -> Option<(Vec3, f64)> {
    let h = top - base;
    let len = h.length();
    // Division rather than multiplication by 1/len: an axis-aligned axis
    // comes out exactly ±1, so cap planes meet box faces at identical t.
    (len > 0.0 && len.is_finite()).then(|| (h / len, len))
}

/// The world bounds of `shape` placed by `m` (`None`: already in world
/// space). Tight for spheres (ellipsoids), cylinders and cones: a disk of
/// radius r around c with unit normal a, mapped by the linear part L,
/// extends r·|row_i(L) − (row_i(L)·a)·a| along world axis i, which is
/// r·sqrt(1 − a_i²) without a transform.
fn world_bounds(shape: &Shape, m: Option<&Affine>) -> Aabb {
    let lin = m.map_or(DMat3::IDENTITY, |m| m.linear);
    let rows = [lin.row(0), lin.row(1), lin.row(2)];
    let point = |p: Vec3| m.map_or(p, |m| m.point(p));
    let disk = |c: Vec3, a: Vec3, r: f64| {
        let ext = |row: Vec3| r * (row - a * row.dot(a)).length();
        let e = Vec3::new(ext(rows[0]), ext(rows[1]), ext(rows[2]));
        let c = point(c);
        Aabb::new(c - e, c + e)
    };
    let b = match shape {
        Shape::Sphere { center, radius } => {
            let e = Vec3::new(rows[0].length(), rows[1].length(), rows[2].length()) * *radius;
            let c = point(*center);
            Aabb::new(c - e, c + e)
        }
        Shape::Box { min, max } => {
            let b = Aabb::new(*min, *max);
            match m {
                _ if b.is_empty() => Aabb::EMPTY,
                Some(m) => m.bounds(&b),
                None => b,
            }
        }
        Shape::Cylinder {
            base, top, radius, ..
        } => match unit_axis(*base, *top) {
            Some((a, _)) => disk(*base, a, *radius).union(&disk(*top, a, *radius)),
            None => Aabb::EMPTY,
        },
        Shape::Cone {
            base,
            base_radius,
            top,
            top_radius,
            ..
        } => match unit_axis(*base, *top) {
            Some((a, _)) => disk(*base, a, *base_radius).union(&disk(*top, a, *top_radius)),
            None => Aabb::EMPTY,
        },
        Shape::Triangle { a, b, c } => Aabb::from_points([*a, *b, *c].map(point)),
        Shape::Polygon(p) => Aabb::from_points(p.vertices.iter().map(|v| point(*v))),
    };
    if b.is_empty() { Aabb::EMPTY } else { b }
}

#[inline]
fn crossing(t: f64, part: u8) -> Crossing {
    Crossing { t, part }
}

/// A solid's span, or `Miss` when it is empty, of zero length (tangent,
/// `ROBUSTNESS.md` case 2) or not finite.
#[inline]
fn solid(enter: Crossing, exit: Crossing) -> PrimHits {
    if enter.t < exit.t && enter.t.is_finite() && exit.t.is_finite() {
        PrimHits::Solid { enter, exit }
    } else {
        PrimHits::Miss
    }
}

/// A surface's crossings, finite ones only, sorted by `t`.
#[inline]
fn sheet(a: Option<Crossing>, b: Option<Crossing>) -> PrimHits {
    let a = a.filter(|c| c.t.is_finite());
    let b = b.filter(|c| c.t.is_finite());
    match (a, b) {
        (Some(x), Some(y)) => {
            let hits = if y.t < x.t { [y, x] } else { [x, y] };
            PrimHits::Sheet { hits, count: 2 }
        }
        (Some(x), None) | (None, Some(x)) => PrimHits::Sheet {
            hits: [x, Crossing::default()],
            count: 1,
        },
        (None, None) => PrimHits::Miss,
    }
}

fn intersect_shape(shape: &Shape, ray: &Ray) -> PrimHits {
    match shape {
        Shape::Sphere { center, radius } => sphere_hits(ray, *center, *radius),
        Shape::Box { min, max } => box_hits(ray, *min, *max),
        Shape::Cylinder {
            base,
            top,
            radius,
            capped,
        } => cylinder_hits(ray, *base, *top, *radius, *capped),
        Shape::Cone {
            base,
            base_radius,
            top,
            top_radius,
            capped,
        } => {
            if base_radius == top_radius {
                cylinder_hits(ray, *base, *top, *base_radius, *capped)
            } else {
                cone_hits(ray, *base, *base_radius, *top, *top_radius, *capped)
            }
        }
        Shape::Triangle { a, b, c } => match Shear::new(ray).and_then(|s| s.triangle(*a, *b, *c)) {
            Some(t) => {
                let t = on_plane(ray, &[*a, *b, *c], [0, 1, 2], t);
                sheet(Some(crossing(t, 0)), None)
            }
            None => PrimHits::Miss,
        },
        Shape::Polygon(p) => polygon_hits(ray, p),
    }
}

impl Shape {
    /// The radius of a cylinder, or the larger of a cone's: how far its
    /// side's power reaches (`reaches_far`).
    fn side_radius(&self) -> Option<f64> {
        match *self {
            Shape::Cylinder { radius, .. } => Some(radius),
            Shape::Cone {
                base_radius,
                top_radius,
                ..
            } => Some(base_radius.max(top_radius)),
            _ => None,
        }
    }

    /// Whether this is a triangle or polygon lying in a coordinate plane,
    /// whose hits are met as a box's face is (`on_plane`).
    fn in_coordinate_plane(&self) -> bool {
        match self {
            Shape::Triangle { a, b, c } => coordinate_plane(&[*a, *b, *c]).is_some(),
            Shape::Polygon(p) => coordinate_plane(&p.vertices).is_some(),
            _ => false,
        }
    }
}

/// The axis and coordinate of the coordinate plane every vertex lies in
/// exactly, if any (a ground polygon at `z = 0`, a wall at `x = 4`).
#[inline]
fn coordinate_plane(vertices: &[Vec3]) -> Option<(usize, f64)> {
    let (first, rest) = vertices.split_first()?;
    (0..3)
        .find(|&k| rest.iter().all(|v| v[k] == first[k]))
        .map(|k| (k, first[k]))
}

/// How far a planar primitive, a sphere, a cylinder or a cone must reach
/// beyond its hit (its extent, or diameter, against the hit point's
/// largest coordinate) for the hit to be taken from exact arithmetic
/// (`on_plane`, `sphere_hits`, `cylinder_hits`, `far_cone_roots`);
/// `Primitive::rounding_size` asks for twice this, so that it counts a hit
/// as exact only where the intersection surely made it so (the f64 point
/// it decided by is off by far less than `|p|` there).
const FAR_REACH: f64 = (1u64 << 20) as f64;

/// The `t` of a planar primitive's hit, which the triangle test found at
/// `t_fan` on triangle `tri` of a primitive with `vertices`: the plane's
/// own `t` where the primitive lies in a coordinate plane or reaches far
/// beyond the hit, else `t_fan`.
///
/// Why: the triangle test weighs the vertices' depths along the ray by
/// barycentric-like edge functions, which cancel to the hit's distance
/// with an error of ε times the vertices' reach. A ground of ±1e20 met by
/// a grazing ray was found some 1e4 off along the ray, and its spawned
/// rays had to start 1.4e6 off the ground (`Primitive::rounding_size`),
/// over the shadows on it (`docs/robustness.md`, "A ground polygon
/// reaching 1e20" and "A tilted polygon reaching 1e20"). In a coordinate
/// plane the hit is met as a box's face is, `(c − o)/d` on that axis: one
/// correctly rounded difference divided once. Tilted, the plane through
/// the triangle's vertices is met at `n·(v₀ − o) / n·d` with `n = (v₁ −
/// v₀) × (v₂ − v₀)`, both products evaluated exactly (`exact`) and
/// rounded once each: as accurate as the distance travelled, whatever the
/// reach, at the cost of about a microsecond, which only the rare
/// primitives reaching 2^20 times beyond their hits pay. The plane's `t`
/// has the exact sign of the line's crossing with that plane; where
/// rounding made the triangle test report a hit that crossing contradicts
/// (`t_fan ≤ 0` but the plane ahead, a ray grazing a polygon wholly behind
/// it, every vertex behind its start), `t_fan` is kept, which keeps
/// `polygon_behind`'s promise (`t ≤ 0`).
/// Whether the ray hits is the triangle test's alone, so edges stay
/// watertight.
#[inline(always)]
fn on_plane(ray: &Ray, vertices: &[Vec3], tri: [usize; 3], t_fan: f64) -> f64 {
    let t = if let Some((k, c)) = coordinate_plane(vertices) {
        (c - ray.origin[k]) / ray.dir[k]
    } else {
        match far_plane_t(ray, vertices, tri, t_fan) {
            Some(t) => t,
            None => return t_fan,
        }
    };
    if !t.is_finite() {
        t_fan
    } else if t <= 0.0 || t_fan > 0.0 {
        t
    } else {
        ahead_of_behind(ray, vertices, t, t_fan)
    }
}

/// `on_plane` where the triangle test's `t_fan ≤ 0` and the plane's `t` is
/// ahead: `t_fan` is kept for a hit rounding made up on a polygon wholly
/// behind the ray's start (every vertex behind it), whose plane the line
/// crosses ahead, outside it; any other such `t_fan` is the triangle
/// test's cancellation (a hit ahead, its `t` off by ε times the reach),
/// and the plane's `t` is taken. Rare, so out of line.
#[cold]
#[inline(never)]
fn ahead_of_behind(ray: &Ray, vertices: &[Vec3], t: f64, t_fan: f64) -> f64 {
    if vertices_behind(ray, vertices) {
        t_fan
    } else {
        t
    }
}

/// `on_plane` for a tilted primitive: the exact plane's `t` where it
/// reaches `FAR_REACH` times beyond the hit. Out of line, so that the
/// triangle tests of meshes and grounds stay small.
#[inline(never)]
fn far_plane_t(ray: &Ray, vertices: &[Vec3], tri: [usize; 3], t_fan: f64) -> Option<f64> {
    if planar_extent(vertices) > FAR_REACH * ray.at(t_fan).abs().max_element() {
        exact_plane_t(ray, tri.map(|i| vertices[i]))
    } else {
        None
    }
}

/// The largest side of the box around `vertices`, as the primitive's world
/// bounds give it (`world_bounds`): triangles and polygons are always in
/// world coordinates (`bake`).
#[inline]
fn planar_extent(vertices: &[Vec3]) -> f64 {
    Aabb::from_points(vertices.iter().copied()).largest_side()
}

/// `t` where the ray meets the plane through `tri`, from exact products
/// (see `on_plane`): `n·(v₀ − o) / n·d` with `n = (v₁ − v₀) × (v₂ − v₀)`,
/// every difference and product exact, each of the two rounded once. None
/// where the plane is parallel to the ray or a product overflowed.
fn exact_plane_t(ray: &Ray, tri: [Vec3; 3]) -> Option<f64> {
    use super::exact::Expansion;
    let less = |p: Vec3, q: Vec3| [0, 1, 2].map(|k| Expansion::diff(p[k], q[k]));
    let (e1, e2) = (less(tri[1], tri[0]), less(tri[2], tri[0]));
    let mut n: [Expansion; 3] = Default::default();
    for (k, n) in n.iter_mut().enumerate() {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        n.add_product(&e1[i], &e2[j], 1.0);
        n.add_product(&e1[j], &e2[i], -1.0);
    }
    let a = less(tri[0], ray.origin);
    let (mut num, mut den) = (Expansion::default(), Expansion::default());
    for k in 0..3 {
        num.add_product(&n[k], &a[k], 1.0);
        den.add_scaled(&n[k], ray.dir[k]);
    }
    let t = num.estimate() / den.estimate();
    t.is_finite().then_some(t)
}

/// The roots of `|f + t·d|² = r²`: the ray (relative to a centre, or its
/// components perpendicular to a cylinder's axis) against a sphere or an
/// infinite cylinder.
enum Roots {
    /// Never strictly inside.
    None,
    /// Inside for every `t` (parallel to a cylinder's axis, within it).
    All,
    /// Inside over `(t0, t1)`, `t0 < t1`.
    Two(f64, f64),
}

/// Robust quadratic (`ROBUSTNESS.md`, Ray Tracing Gems ch. 7, Haines,
/// Günther and Akenine-Möller): with `a = d·d`, `b' = f·d`, `c = f·f − r²`,
/// the discriminant `b'² − a·c` cancels catastrophically when the ray starts
/// far away (case 1: a unit sphere at 1e8). Written instead as
/// `a·(r² − |l|²)` with `l = f − (b'/a)·d` the closest approach, and
/// `r² − |l|²` as `(r + |l|)(r − |l|)`, it keeps its accuracy; the roots are
/// then `q/a` and `c/q` with `q = −(b' + sign(b')·sqrt(a·disc))`, which never
/// subtracts nearly equal numbers. A zero discriminant is a tangent: no span
/// (case 2). `a = 0` (a ray parallel to a cylinder's axis, case 3) is
/// decided by whether the origin is inside, with no division.
#[inline]
fn circle_roots(f: Vec3, d: Vec3, r: f64) -> Roots {
    circle_roots_with(f, d, r, f.dot(f) - r * r)
}

/// `circle_roots` with `c = f·f − r²` given (`sphere_hits` may give it
/// exactly).
#[inline]
fn circle_roots_with(f: Vec3, d: Vec3, r: f64, c: f64) -> Roots {
    let a = d.dot(d);
    // The answer for a ray (nearly) parallel to the axis: the distance to
    // the axis does not change, so the origin decides.
    let parallel = if c < 0.0 { Roots::All } else { Roots::None };
    if !(a > 0.0) {
        return parallel;
    }
    let b = f.dot(d);
    let l = f - d * (b / a);
    let ll = l.length();
    let disc = (r + ll) * (r - ll);
    if disc.is_nan() {
        // b/a overflowed: only for a subnormal perpendicular direction.
        return parallel;
    }
    if !(disc > 0.0) {
        return Roots::None;
    }
    let q = -(b + (a * disc).sqrt().copysign(b));
    if q == 0.0 {
        // a·disc underflowed with b = 0: a nearly parallel ray.
        return parallel;
    }
    let (t0, t1) = (q / a, c / q);
    let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
    if !(t0.is_finite() && t1.is_finite()) {
        // Roots beyond f64's range: nearly parallel again.
        return parallel;
    }
    if t0 < t1 {
        Roots::Two(t0, t1)
    } else {
        Roots::None
    }
}

/// A sphere's span. Where the sphere reaches far beyond the hit nearer the
/// ray's origin (a ground of radius 1e20 under a scene of size 1, its
/// extent `2^20` times the hit point's largest coordinate), the roots are
/// taken again with `c = |o − centre|² − r²` evaluated exactly (`exact`).
///
/// Why: that root is `c/q`, and `c` is the difference of two squares of
/// the radius's size: in f64 it is off by ε·r², so the hit by ε·r, some
/// 1e4 at 1e20 (and the ray's origin is itself rounded away by as much in
/// `o − centre`), and the spawned rays were offset by 64 ε of the extent,
/// over the shadows on it; at 1e16 to 1e30 more than half of the pixels
/// of a test scene differed from a flat ground's. With `c` exact and `q`
/// accurate to a few ulps (its terms `b = f·d` and the discriminant do not
/// cancel unless the ray grazes the sphere), the hit is as accurate as
/// the distance travelled, so it is offset by no size
/// (`Primitive::rounding_size`).
fn sphere_hits(ray: &Ray, center: Vec3, radius: f64) -> PrimHits {
    let f = ray.origin - center;
    let mut roots = circle_roots(f, ray.dir, radius);
    if let Roots::Two(t0, t1) = roots
        && reaches_far(radius, ray, t0, t1)
    {
        roots = far_sphere_roots(ray, f, center, radius);
    }
    match roots {
        Roots::Two(t0, t1) => solid(crossing(t0, 0), crossing(t1, 0)),
        Roots::None | Roots::All => PrimHits::Miss,
    }
}

/// `sphere_hits`' roots with the exact power of the ray's origin. Out of
/// line: rare, and the common sphere test stays small.
#[cold]
#[inline(never)]
fn far_sphere_roots(ray: &Ray, f: Vec3, center: Vec3, radius: f64) -> Roots {
    let c = exact_power(ray.origin, center, radius);
    circle_roots_with(f, ray.dir, radius, c)
}

/// Whether a round surface of `radius` reaches `FAR_REACH` times beyond
/// either of its hits at `t0`, `t1` (its diameter against the hit point's
/// largest coordinate): where its power, and so the hit, cancels in f64.
/// Both hits are asked, as either may be the one shaded
/// (`Primitive::rounding_size` counts it exact).
/// (Axis by axis, so that the common answer, no, is found at the first
/// coordinate of each hit: every sphere and cone test asks.)
#[inline]
fn reaches_far(radius: f64, ray: &Ray, t0: f64, t1: f64) -> bool {
    let s = radius * (2.0 / FAR_REACH);
    let near = |t: f64| (0..3).all(|k| (ray.origin[k] + ray.dir[k] * t).abs() < s);
    near(t0) || near(t1)
}

/// `cylinder_hits`' side roots with the power of the ray's origin,
/// `|f⊥|² − r²`, evaluated exactly from the file's own numbers: with
/// `f = o − base` and `A = top − base`, `|f⊥|² = |f × A|² / |A|²`, so the
/// power is `(|f × A|² − r²·|A|²) / |A|²`, its numerator exact and
/// rounded once, divided once. The unit axis `a` that `f⊥` was taken with
/// is rounded, which moves `f⊥` by ε·|f|, as much as the cancellation
/// itself; this form never uses it. Out of line, as `far_sphere_roots`.
#[cold]
#[inline(never)]
fn far_cylinder_roots(
    ray: &Ray,
    f_perp: Vec3,
    d_perp: Vec3,
    (base, top): (Vec3, Vec3),
    radius: f64,
) -> Roots {
    if let Some(along) = along_one_axis(base, top) {
        // Along a coordinate axis (a drum lying along x or y): `f⊥` is `f`
        // on the other two axes, and the power is the sphere's there.
        let c = exact_power_on(ray.origin, base, radius, !along);
        return circle_roots_with(f_perp, d_perp, radius, c);
    }
    let [mut numerator, axis2, _] = exact_axial_terms(ray.origin, base, top);
    numerator.add_scaled(&axis2.times(radius), -radius);
    let c = numerator.estimate() / axis2.estimate();
    circle_roots_with(f_perp, d_perp, radius, c)
}

/// A sphere under a map (an ellipsoid), met in its own space as every
/// mapped shape is. Where the map keeps the coordinate axes (a scale that
/// is not uniform, and a translation) and the ellipsoid reaches far beyond
/// either hit (a ground of semi-axes 1e20 under a scene of size 1), the
/// roots are taken again with the object-space power
/// `|S⁻¹(o − T) − c|² − r²` exact (`far_ellipsoid_roots`): mapping the
/// origin rounds `o − T` by ε of the reach, and the power then cancels as
/// the sphere's does, which lost 37% of a test scene's pixels at 1e12 and
/// all but a few from 1e30 on (`docs/robustness.md`). Under a rotation the
/// map's entries are themselves rounded, and nothing here takes that back.
/// Out of line, so that `Primitive::intersect` stays small for the
/// shapes in the world (the jagged ball's instructions +0.55% inline).
#[inline(never)]
fn ellipsoid_hits(ray: &Ray, m: &Affine, center: Vec3, radius: f64) -> PrimHits {
    let local = m.inverse_ray(ray);
    let f = local.origin - center;
    let mut roots = circle_roots(f, local.dir, radius);
    if let Roots::Two(t0, t1) = roots
        && let Some(s) = m.axis_scales()
        && reaches_far(radius * s.abs().max_element(), ray, t0, t1)
    {
        roots = far_ellipsoid_roots(ray, m, s, (center, radius), (f, local.dir));
    }
    match roots {
        Roots::Two(t0, t1) => solid(crossing(t0, 0), crossing(t1, 0)),
        Roots::None | Roots::All => PrimHits::Miss,
    }
}

/// `ellipsoid_hits`' roots with the object-space power exact
/// (`exact_mapped_power` over all three axes); where a term overflows,
/// the roots given.
#[cold]
#[inline(never)]
fn far_ellipsoid_roots(
    ray: &Ray,
    m: &Affine,
    s: Vec3,
    (center, radius): (Vec3, f64),
    (f, d): (Vec3, Vec3),
) -> Roots {
    match exact_mapped_power(ray.origin, m, s, (center, radius), 0b111) {
        Some(c) => circle_roots_with(f, d, radius, c),
        None => circle_roots(f, d, radius),
    }
}

/// Any other shape under a map, met in its own space. Out of line, as
/// the map's arithmetic was before `mapped_cylinder_hits` made the
/// compiler take it into `Primitive::intersect`, where it cost the
/// jagged ball's boxes under rotations 0.6% more instructions.
#[inline(never)]
fn mapped_hits(ray: &Ray, m: &Affine, shape: &Shape) -> PrimHits {
    intersect_shape(shape, &m.inverse_ray(ray))
}

/// A cylinder under a map (an elliptic drum, where the map is a scale
/// that is not uniform), met in its own space as every mapped shape is.
/// Where the map keeps the coordinate axes, the cylinder's axis is one of
/// them, and its side reaches far beyond either hit (a ground of
/// semi-axes 1e20 under a scene of size 1), the side's roots are taken
/// again with the object-space power over the other two axes exact
/// (`exact_mapped_power`), as the ellipsoid's are (`ellipsoid_hits`).
/// Out of line, as that is.
#[inline(never)]
fn mapped_cylinder_hits(ray: &Ray, m: &Affine, shape: &Shape) -> PrimHits {
    let &Shape::Cylinder {
        base,
        top,
        radius,
        capped,
    } = shape
    else {
        return mapped_hits(ray, m, shape);
    };
    let local = m.inverse_ray(ray);
    cylinder_hits_with(
        &local,
        (base, top),
        radius,
        capped,
        |t0, t1, f_perp, d_perp| {
            let e = elliptic_drum(m, base, top)?;
            if !reaches_far(radius * e.semi_axis, ray, t0, t1) {
                return None;
            }
            let c = exact_mapped_power(ray.origin, m, e.scales, (base, radius), e.across)?;
            Some(circle_roots_with(f_perp, d_perp, radius, c))
        },
    )
}

/// A cylinder under a map that keeps the coordinate axes, lying along one
/// of them: an elliptic drum whose side `mapped_cylinder_hits` can meet
/// exactly.
struct EllipticDrum {
    /// The map's scales.
    scales: Vec3,
    /// The two axes across the drum, as bits (bit `k` for axis `k`).
    across: u32,
    /// The largest scale across, in magnitude: the side's largest
    /// semi-axis for a radius of 1.
    semi_axis: f64,
}

/// The cylinder from `base` to `top` under `m` as an elliptic drum, if it
/// is one.
fn elliptic_drum(m: &Affine, base: Vec3, top: Vec3) -> Option<EllipticDrum> {
    let across = !along_one_axis(base, top)? & 0b111;
    let scales = m.axis_scales()?;
    let semi_axis = (0..3)
        .filter(|k| across & (1 << k) != 0)
        .map(|k| scales[k].abs())
        .fold(0.0, f64::max);
    Some(EllipticDrum {
        scales,
        across,
        semi_axis,
    })
}

/// The axis (as a bit: bit `k` for axis `k`) a segment from `base` to
/// `top` lies along, where it is a coordinate axis.
fn along_one_axis(base: Vec3, top: Vec3) -> Option<u32> {
    let along = (top - base).cmpne(Vec3::ZERO).bitmask();
    (along.count_ones() == 1).then_some(along)
}

/// `Σ_k ((o_k − T_k)/s_k − c_k)² − r²` over the axes `k` whose bits are
/// set in `axes`: the power, in the space of the map `x ↦ s·x + T`, of
/// the world point `o` with respect to the sphere or circle of centre `c`
/// and radius `r` there. Evaluated exactly from the file's own numbers
/// and rounded once: with `u_k = o_k − T_k − s_k·c_k` (the offset from the
/// centre in the world, exact) and `P` the product of those axes' scales,
/// it is `(Σ_k (u_k·P/s_k)² − (r·P)²) / P²`. Mapping `o` first rounds
/// `o − T` by ε of the reach, and the power then cancels as a sphere's
/// does. None where a term overflows.
fn exact_mapped_power(
    o: Vec3,
    m: &Affine,
    s: Vec3,
    (center, radius): (Vec3, f64),
    axes: u32,
) -> Option<f64> {
    use super::exact::Expansion;
    let on: Vec<usize> = (0..3).filter(|k| axes & (1 << k) != 0).collect();
    let mut numerator = Expansion::default();
    for &k in &on {
        let mut u = Expansion::diff(o[k], m.translation[k]);
        u.add_f64_product(s[k], -center[k]);
        u.compress();
        // u_k times the other axes' scales.
        for &j in on.iter().filter(|&&j| j != k) {
            u = u.times(s[j]);
        }
        u.compress();
        numerator.add_product(&u, &u, 1.0);
    }
    let mut rp = Expansion::default();
    rp.add_f64_product(radius, 1.0);
    for &j in &on {
        rp = rp.times(s[j]);
    }
    rp.compress();
    numerator.add_product(&rp, &rp, -1.0);
    let p: f64 = on.iter().map(|&j| s[j]).product();
    let c = numerator.estimate() / (p * p);
    c.is_finite().then_some(c)
}

/// `|o − centre|² − r²`, the power of `o` with respect to the sphere,
/// evaluated exactly and rounded once (see `sphere_hits`).
fn exact_power(o: Vec3, center: Vec3, r: f64) -> f64 {
    exact_power_on(o, center, r, 0b111)
}

/// `exact_power` over the axes whose bits are set in `axes` (bit `k` for
/// axis `k`): a cylinder along a coordinate axis has the power of a circle
/// in the other two.
fn exact_power_on(o: Vec3, center: Vec3, r: f64, axes: u32) -> f64 {
    use super::exact::Expansion;
    let mut power = Expansion::default();
    power.add_f64_product(r, -r);
    for k in (0..3).filter(|k| axes & (1 << k) != 0) {
        let f = Expansion::diff(o[k], center[k]);
        power.add_product(&f, &f, 1.0);
    }
    power.estimate()
}

/// Slab test. A zero direction component (+0.0 or −0.0 alike, case 8) never
/// divides: the ray is inside that slab or not by its origin (closed). The
/// face `t` is `(plane − o)/d`, one correctly rounded division, so boxes
/// that share a face plane meet a ray there at bit-identical `t` (cases
/// 9-10). Ties in the entry maximum or exit minimum go to the lowest axis
/// (strict comparisons in axis order, case 7), so an edge or corner hit
/// gets one fixed face. A flat box (`min = max` on an axis) is never hit.
#[inline]
fn box_hits(ray: &Ray, min: Vec3, max: Vec3) -> PrimHits {
    let mut enter = crossing(f64::NEG_INFINITY, 0);
    let mut exit = crossing(f64::INFINITY, 1);
    for axis in 0..3 {
        let (o, d) = (ray.origin[axis], ray.dir[axis]);
        let (lo, hi) = (min[axis], max[axis]);
        if d == 0.0 {
            // `lo < hi` too: a flat box (case 13) has no inside, even for a
            // ray lying in its plane.
            if !(lo <= o && o <= hi && lo < hi) {
                return PrimHits::Miss;
            }
            continue;
        }
        let (t_lo, t_hi) = ((lo - o) / d, (hi - o) / d);
        let part = 2 * axis as u8;
        let (near, far) = if d > 0.0 {
            (crossing(t_lo, part), crossing(t_hi, part + 1))
        } else {
            (crossing(t_hi, part + 1), crossing(t_lo, part))
        };
        if near.t > enter.t {
            enter = near;
        }
        if far.t < exit.t {
            exit = far;
        }
    }
    solid(enter, exit)
}

/// `Primitive::surely_behind` for a box: on some axis the ray is not
/// parallel to, the far face's `t`, computed as `box_hits` computes it,
/// is below `t_min`. `box_hits`' exit is at most that `t` and its entry
/// before its exit, so both are below `t_min`.
#[inline]
fn box_behind(ray: &Ray, min: Vec3, max: Vec3, t_min: f64) -> bool {
    (0..3).any(|axis| {
        let (o, d) = (ray.origin[axis], ray.dir[axis]);
        let far = if d > 0.0 {
            (max[axis] - o) / d
        } else if d < 0.0 {
            (min[axis] - o) / d
        } else {
            return false;
        };
        far < t_min
    })
}

/// `Primitive::surely_behind` for a polygon: every vertex's ray-space `z`
/// (`Shear::project`, the value the triangle test weighs) is negative. A
/// hit's `t` is the sum of those `z` weighted by edge functions of one sign
/// (or zero), over their sum: every term is of the sign opposite to the
/// divisor's, and rounding keeps signs, so `t ≤ 0` (it may be `−0.0` or
/// `+0.0` where products underflow: hence "at or before" `t_min ≥ 0`).
#[inline]
fn polygon_behind(ray: &Ray, p: &Polygon) -> bool {
    vertices_behind(ray, &p.vertices)
}

/// Whether every vertex's ray-space `z` is negative (`polygon_behind`).
#[inline]
fn vertices_behind(ray: &Ray, vertices: &[Vec3]) -> bool {
    // `Shear::new`'s axis and scale, and `Shear::project`'s `z`, with the
    // same operations (the rest of the shear is not needed here).
    let Some((kz, dz)) = Shear::depth_axis(ray) else {
        // `polygon_hits` reports nothing.
        return true;
    };
    let (sz, o) = (1.0 / dz, ray.origin.to_array()[kz]);
    vertices.iter().all(|v| sz * (v.to_array()[kz] - o) < 0.0)
}

/// The interval of `t` between the planes through `base` and `top`
/// perpendicular to the unit axis `a`, closed, with the planes' parts.
/// `None` when empty. A ray parallel to the planes (case 4) is between them
/// or not by its origin alone: no `t = (h − o)/0`. The plane distances are
/// `(plane point − o)·a`, so an axis-aligned cap meets a box face at the same
/// `t` as the box's slab test (case 9).
#[inline]
fn cap_slab(
    ray: &Ray,
    base: Vec3,
    top: Vec3,
    a: Vec3,
    base_part: u8,
    top_part: u8,
) -> Option<(Crossing, Crossing)> {
    let da = ray.dir.dot(a);
    let sb = (base - ray.origin).dot(a);
    let st = (top - ray.origin).dot(a);
    if da == 0.0 {
        return (sb <= 0.0 && 0.0 <= st).then_some((
            crossing(f64::NEG_INFINITY, base_part),
            crossing(f64::INFINITY, top_part),
        ));
    }
    let (tb, tt) = (crossing(sb / da, base_part), crossing(st / da, top_part));
    Some(if da > 0.0 { (tb, tt) } else { (tt, tb) })
}

/// Combines the interval inside the infinite side surface with the cap
/// slab. Solid: their intersection, a cap winning a tie with the side (the
/// rim, case 5: either normal is right, one is chosen). Surface: the side's
/// finite ends that lie within the slab; an apex crossing (part 3) is kept
/// when `apex_on_end` (a pointed cone's apex lies on a cap plane, where
/// rounding must not decide).
#[inline]
fn side_and_caps(
    side: (Crossing, Crossing),
    slab: (Crossing, Crossing),
    capped: bool,
    apex_on_end: bool,
) -> PrimHits {
    if capped {
        let enter = if slab.0.t >= side.0.t { slab.0 } else { side.0 };
        let exit = if slab.1.t <= side.1.t { slab.1 } else { side.1 };
        solid(enter, exit)
    } else {
        let within = |c: Crossing| {
            c.t.is_finite()
                && ((slab.0.t <= c.t && c.t <= slab.1.t) || (c.part == APEX && apex_on_end))
        };
        sheet(
            Some(side.0).filter(|c| within(*c)),
            Some(side.1).filter(|c| within(*c)),
        )
    }
}

/// A cylinder with a general axis. The side is `circle_roots` on the
/// components perpendicular to the axis, so `a = 0` (a ray parallel to the
/// axis, case 3) is handled there and a nearly parallel ray gives huge
/// roots that the caps clip: the span is continuous in the direction.
///
/// Where the cylinder is so wide that it reaches far beyond the hit
/// nearer the ray's origin (a lying drum of radius 1e20 for a ground), the
/// roots are taken again with the power `|f⊥|² − r²` exact, as a
/// sphere's are (`sphere_hits`, `far_cylinder_roots`).
fn cylinder_hits(ray: &Ray, base: Vec3, top: Vec3, radius: f64, capped: bool) -> PrimHits {
    cylinder_hits_with(
        ray,
        (base, top),
        radius,
        capped,
        |t0, t1, f_perp, d_perp| {
            reaches_far(radius, ray, t0, t1)
                .then(|| far_cylinder_roots(ray, f_perp, d_perp, (base, top), radius))
        },
    )
}

/// `cylinder_hits`, with `far` asked for the side's roots again where
/// f64 gave two, `t0` and `t1` (with `f⊥` and `d⊥`): `Some` replaces them.
#[inline]
fn cylinder_hits_with(
    ray: &Ray,
    (base, top): (Vec3, Vec3),
    radius: f64,
    capped: bool,
    far: impl FnOnce(f64, f64, Vec3, Vec3) -> Option<Roots>,
) -> PrimHits {
    let Some((a, _)) = unit_axis(base, top) else {
        return PrimHits::Miss;
    };
    let Some(slab) = cap_slab(ray, base, top, a, BASE_CAP, TOP_CAP) else {
        return PrimHits::Miss;
    };
    let f = ray.origin - base;
    let f_perp = f - a * f.dot(a);
    let d_perp = ray.dir - a * ray.dir.dot(a);
    let mut roots = circle_roots(f_perp, d_perp, radius);
    if let Roots::Two(t0, t1) = roots
        && let Some(exact) = far(t0, t1, f_perp, d_perp)
    {
        roots = exact;
    }
    let side = match roots {
        Roots::None => return PrimHits::Miss,
        Roots::All => (
            crossing(f64::NEG_INFINITY, SIDE),
            crossing(f64::INFINITY, SIDE),
        ),
        Roots::Two(t0, t1) => (crossing(t0, SIDE), crossing(t1, SIDE)),
    };
    side_and_caps(side, slab, capped, false)
}

/// The two roots of `A t² + 2B t + C` with `disc = B² − AC > 0`, sorted,
/// without cancellation (`q = −(B + sign(B)·sqrt(disc))`, roots `q/A`,
/// `C/q`).
#[inline]
fn quadratic_roots(qa: f64, qb: f64, qc: f64, disc: f64) -> (f64, f64) {
    let q = -(qb + disc.sqrt().copysign(qb));
    let (t0, t1) = (q / qa, qc / q);
    if t0 <= t1 { (t0, t1) } else { (t1, t0) }
}

/// `Primitive::rounding_size` of a cylinder or cone hit at world point
/// `p`, beside its extent (which also bounds it). Its caps are met at
/// `(end − o)·a / (d·a)`, as exact as the distances from the ray's origin
/// to the ends; its side's quadric combines distances from the base and
/// radii, which at a side hit are at most the hit's distance from the base
/// and the height (a side hit lies as far from the axis as the radius
/// there), and a flat cone's (`ConeScale`) the distance to its apex,
/// `apex`. So the hit's distance from the base, the height and `apex`
/// bound them all, beside the distance travelled (`offset_origin` adds
/// that). Under a map: stretched by its norm, with the rounding of the
/// ray's origin mapped to the primitive's space (`M⁻¹·(o − T)`, as for a
/// box) besides.
///
/// Before, the extent alone: a disc ground (a cylinder or flat cone of
/// radius 1e20, height 0.5) pushed its spawned rays some 1e6 off, over the
/// ball that should have shadowed it (`docs/robustness.md`, "A disc of
/// radius 1e30").
fn axial_size(p: Vec3, m: Option<&Affine>, base: Vec3, top: Vec3, apex: f64) -> f64 {
    let axial = |q: Vec3| (q - base).length() + (top - base).length() + apex;
    match m {
        None => axial(p),
        Some(m) => {
            let (norm, inv_norm) = (frobenius_norm(&m.linear), frobenius_norm(&m.inv_linear));
            norm * axial(m.inverse_point(p)) + norm * inv_norm * (p - m.translation).length()
        }
    }
}

/// The scale in which `cone_hits` sets up a cone's quadric `|p⊥|² = ρ²`,
/// `ρ = rb + k·s`. A cone whose radius changes faster than its axis runs
/// (`|k| > 1`: flat, up to a disc of radius 1e30 and height 0.4, which
/// the scene mutants made) is set up divided by `k²`, as
/// `|p⊥/k|² = (rb/|k| ± s)²`: the signed radius `rb + k·s` cancels to the
/// hit's small distance from the axis out of terms of the size of `rb`
/// (an error of ε·1e30 where the ball it stood over was a unit away), its
/// axial form `rb/|k| ± s` out of terms of the axial distances only. The
/// surface is the same (the axial rate taken as exactly ±1, the slope's
/// rounding, ε); the signs of `ρ` and of `m` are kept, as the scale is
/// positive. Any other cone keeps scale 1, bit for bit.
#[derive(Clone, Copy)]
struct ConeScale {
    /// `rb`, or `rb / |k|`.
    rb: f64,
    /// `k`, or its sign.
    k: f64,
    /// 1, or `1 / |k|`: the factor of the perpendicular parts.
    perp: f64,
}

impl ConeScale {
    #[inline]
    fn new(rb: f64, k: f64) -> ConeScale {
        if k.abs() > 1.0 {
            ConeScale {
                rb: rb / k.abs(),
                k: k.signum(),
                perp: 1.0 / k.abs(),
            }
        } else {
            ConeScale { rb, k, perp: 1.0 }
        }
    }

    /// The distance to the apex that a flat cone's quadric holds
    /// (`rb / |k|`); 0 for any other, whose quadric holds radii instead.
    fn apex(&self) -> f64 {
        if self.perp < 1.0 { self.rb } else { 0.0 }
    }
}

/// A cone or frustum (`base_radius != top_radius`). With `f = o − base`,
/// `s = (f + t·d)·a` the axial coordinate and `ρ(s) = rb + k·s` the signed
/// radius (`k = (rt − rb)/h`), the double cone is `|p⊥|² = ρ²`:
/// `A t² + 2B t + C = 0` with `g = ρ` at the origin and `m = k·(d·a)`,
/// `A = |d⊥|² − m²`, `B = f⊥·d⊥ − g·m`, `C = |f⊥|² − g²`.
///
/// The real nappe is where `ρ > 0`; the mirror nappe (`ρ < 0`, beyond the
/// apex) is rejected by that sign, not by the slab alone (case 6). `A < 0`
/// (steeper than the surface) is inside outside the roots, one piece per
/// nappe; `A = 0` (parallel to a generator, case 6) is linear with no
/// division by `A`; a double root with `A < 0` is the apex (part 3). A
/// cone that reaches far beyond its hits has its roots taken again with
/// `C` exact (`far_cone_roots`).
fn cone_hits(ray: &Ray, base: Vec3, rb: f64, top: Vec3, rt: f64, capped: bool) -> PrimHits {
    let Some((a, len)) = unit_axis(base, top) else {
        return PrimHits::Miss;
    };
    // A zero-radius cap is the apex itself.
    let base_part = if rb == 0.0 { APEX } else { BASE_CAP };
    let top_part = if rt == 0.0 { APEX } else { TOP_CAP };
    let Some(slab) = cap_slab(ray, base, top, a, base_part, top_part) else {
        return PrimHits::Miss;
    };
    // The radius's rate along the axis; a flat cone (|k| > 1) is set up
    // in the axial scale instead (`ConeScale`), the same quadric divided by
    // k², so that no term holds the radius's magnitude.
    let sc = ConeScale::new(rb, (rt - rb) / len);
    let (o, d) = (ray.origin, ray.dir);
    let f = o - base;
    let (fa, da) = (f.dot(a), d.dot(a));
    let f_perp = (f - a * fa) * sc.perp;
    let d_perp = (d - a * da) * sc.perp;
    let g = sc.rb + sc.k * fa;
    let m = sc.k * da;
    let qa = d_perp.dot(d_perp) - m * m;
    let qb = f_perp.dot(d_perp) - g * m;
    let qc = f_perp.dot(f_perp) - g * g;
    let (below, above) = (
        crossing(f64::NEG_INFINITY, SIDE),
        crossing(f64::INFINITY, SIDE),
    );
    let side = if qa == 0.0 {
        // Parallel to a generator: inside where 2B·t + C ≤ 0, a half-line
        // in the nappe the ray runs into (ρ's sign at its infinite end is
        // m's sign there). B = 0 is the generator itself: grazing.
        if qb == 0.0 || m == 0.0 {
            return PrimHits::Miss;
        }
        let t = crossing(-qc / (2.0 * qb), SIDE);
        match (qb > 0.0, m > 0.0) {
            (true, false) => (below, t),
            (false, true) => (t, above),
            _ => return PrimHits::Miss,
        }
    } else if qa > 0.0 {
        // One bounded interval, in one nappe.
        let disc = cone_discriminant(f_perp, d_perp, g, m);
        if !(disc > 0.0) {
            return PrimHits::Miss;
        }
        let (t0, t1) = cone_roots((f, d, a, d_perp), (sc, m), (qa, qb, qc, disc));
        let (t0, t1) = far_cone_roots(ray, (base, rb, top, rt), sc, (qa, qb, disc), (t0, t1));
        // In exact arithmetic the slab already excludes the mirror nappe;
        // this keeps rounding near a pointed end from admitting it.
        let mid = 0.5 * t0 + 0.5 * t1;
        if !(g + m * mid > 0.0) {
            return PrimHits::Miss;
        }
        (crossing(t0, SIDE), crossing(t1, SIDE))
    } else if qa < 0.0 {
        // Inside before t0 (one nappe) and after t1 (the other); m ≠ 0
        // here, and its sign says which end lies in the real nappe.
        let disc = cone_discriminant(f_perp, d_perp, g, m);
        if disc > 0.0 {
            let (t0, t1) = cone_roots((f, d, a, d_perp), (sc, m), (qa, qb, qc, disc));
            let (t0, t1) = far_cone_roots(ray, (base, rb, top, rt), sc, (qa, qb, disc), (t0, t1));
            if m > 0.0 {
                (crossing(t1, SIDE), above)
            } else {
                (below, crossing(t0, SIDE))
            }
        } else {
            // A double root (or one rounded below zero): through the apex.
            let t = crossing(-qb / qa, APEX);
            if m > 0.0 { (t, above) } else { (below, t) }
        }
    } else {
        return PrimHits::Miss; // NaN
    };
    side_and_caps(side, slab, capped, rb == 0.0 || rt == 0.0)
}

/// A cone's roots `(t0, t1)` again, with the quadric's constant term `C`
/// exact, where the cone is so wide that it reaches `FAR_REACH` times
/// beyond either hit (a mountain or a funnel for a ground): `C` is the
/// difference of two squares of the radius's size, off by ε·r² in f64,
/// and the root `C/q` by ε·r, as a sphere's (`sphere_hits`). From the
/// file's own numbers, with `f = o − base`, `A = top − base` and
/// `D = rt − rb`: `|f⊥|² = |f × A|²/|A|²` and the radius at the origin's
/// axial place is `g = (rb·|A|² + D·(f·A))/|A|²`, so
/// `C = (|f × A|²·|A|² − (rb·|A|² + D·(f·A))²) / |A|⁴`, its numerator
/// exact and rounded once (`exact`), then scaled as the quadric is
/// (`ConeScale`). The roots are then `quadratic_roots` of that `C`, the
/// refinement of `cone_roots` (whose constant term at a root cancels as
/// this one did) left out. Otherwise, or where the exact terms overflow,
/// the roots given.
#[inline]
fn far_cone_roots(
    ray: &Ray,
    cone: (Vec3, f64, Vec3, f64),
    sc: ConeScale,
    quadratic: (f64, f64, f64),
    (t0, t1): (f64, f64),
) -> (f64, f64) {
    let (_, rb, _, rt) = cone;
    if reaches_far(rb.max(rt), ray, t0, t1) {
        exact_cone_roots(ray, cone, sc, quadratic).unwrap_or((t0, t1))
    } else {
        (t0, t1)
    }
}

/// The place of `o` against the axis from `base` to `top`, exactly, for
/// `far_cylinder_roots` and `exact_cone_roots`: with `f = o − base` and
/// `A = top − base`, `[|f × A|², |A|², f·A]` (the first is the squared
/// distance from the axis times `|A|²`), each compressed.
fn exact_axial_terms(o: Vec3, base: Vec3, top: Vec3) -> [super::exact::Expansion; 3] {
    use super::exact::Expansion;
    let f: [Expansion; 3] = std::array::from_fn(|k| Expansion::diff(o[k], base[k]));
    let axis: [Expansion; 3] = std::array::from_fn(|k| Expansion::diff(top[k], base[k]));
    let mut terms: [Expansion; 3] = Default::default();
    for k in 0..3 {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        // (f × A)_k = f_i·A_j − f_j·A_i.
        let mut cross = Expansion::default();
        cross.add_product(&f[i], &axis[j], 1.0);
        cross.add_product(&f[j], &axis[i], -1.0);
        cross.compress();
        terms[0].add_product(&cross, &cross, 1.0);
        terms[1].add_product(&axis[k], &axis[k], 1.0);
        terms[2].add_product(&f[k], &axis[k], 1.0);
    }
    for t in &mut terms {
        t.compress();
    }
    terms
}

/// `far_cone_roots`' exact path. Out of line, as `far_sphere_roots`.
#[cold]
#[inline(never)]
fn exact_cone_roots(
    ray: &Ray,
    (base, rb, top, rt): (Vec3, f64, Vec3, f64),
    sc: ConeScale,
    (qa, qb, disc): (f64, f64, f64),
) -> Option<(f64, f64)> {
    use super::exact::Expansion;
    let [cross2, axis2, fa] = exact_axial_terms(ray.origin, base, top);
    // g·|A|² = rb·|A|² + D·(f·A).
    let mut g = axis2.times(rb);
    g.add_product(&Expansion::diff(rt, rb), &fa, 1.0);
    g.compress();
    let mut numerator = Expansion::default();
    numerator.add_product(&cross2, &axis2, 1.0);
    numerator.add_product(&g, &g, -1.0);
    let a2 = axis2.estimate();
    let c = numerator.estimate() / (a2 * a2) * (sc.perp * sc.perp);
    c.is_finite().then(|| quadratic_roots(qa, qb, c, disc))
}

/// `B² − A·C` of the cone's quadratic (`cone_hits`), as
/// `|m·f⊥ − g·d⊥|² − |f⊥ × d⊥|²` (the same polynomial, by Lagrange's
/// identity in the quadric's metric): the form Haines, Günther and
/// Akenine-Möller give spheres (Ray Tracing Gems, ch. 7), for the cone.
/// `B² − A·C` cancels wherever the roots lie close together, and above
/// all for a ray through the apex, where they meet: there it kept only
/// the square root of the precision, and a ray aimed at a cone's apex
/// from 11 units away met it 3.4e-7 short, outside the cone's box, so
/// the cells (whose walk keeps to the boxes) and Roth disagreed. Here
/// both vectors vanish at the apex, each to a rounding of its own
/// terms, so the roots keep full precision.
#[inline]
fn cone_discriminant(f_perp: Vec3, d_perp: Vec3, g: f64, m: f64) -> f64 {
    (f_perp * m - d_perp * g).length_squared() - f_perp.cross(d_perp).length_squared()
}

/// The cone's roots (`cone_hits`), each made accurate. From afar a thin
/// cone has `B² ≈ A·C`, and the roots keep only the digits the difference
/// leaves: a ray from 6 units away at a spike of radius 0.085 found it
/// 5e-14 of `t` inside, more than a spawned ray's offset, and rays spawned
/// there met the cone again (`docs/robustness.md`, case 24). So the
/// quadratic is set up again from the point at each root, where the ray
/// nearly touches the surface and the constant term is exact to a few ulps
/// of the cone's own size, and its root nearest 0 is added (Ray Tracing
/// Gems, ch. 7: move the origin close to the surface), by a Newton step.
/// A correction that is not small against the roots' distance (near a
/// tangent, where the two roots blur; or NaN) is not taken.
#[inline]
fn cone_roots(
    (f, d, a, d_perp): (Vec3, Vec3, Vec3, Vec3),
    (sc, m): (ConeScale, f64),
    (qa, qb, qc, disc): (f64, f64, f64, f64),
) -> (f64, f64) {
    let (t0, t1) = quadratic_roots(qa, qb, qc, disc);
    let room = 0.25 * (t1 - t0).abs();
    let refine = |t: f64| {
        let f1 = f + d * t;
        let fa = f1.dot(a);
        let f_perp = (f1 - a * fa) * sc.perp;
        let g = sc.rb + sc.k * fa;
        let b1 = f_perp.dot(d_perp) - g * m;
        let c1 = f_perp.dot(f_perp) - g * g;
        // A Newton step from 0 on `A x² + 2 b1 x + c1`: the root is some
        // ulps from 0, where the square term is far below rounding.
        let dt = -c1 / (2.0 * b1);
        if dt.abs() < room { t + dt } else { t }
    };
    let (r0, r1) = (refine(t0), refine(t1));
    if r0 <= r1 { (r0, r1) } else { (t0, t1) }
}

/// The ray of the watertight triangle test (Woop, Benthin and Wald, JCGT
/// 2013), computed once per ray: the axes permuted so that the dominant
/// direction component is z (x and y swapped when it is negative, to keep
/// the winding), and the shear that makes the direction +z. Vertices shared
/// by triangles are transformed identically, so their edges agree.
struct Shear {
    o: Vec3,
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f64,
    sy: f64,
    sz: f64,
}

impl Shear {
    /// The dominant axis of the ray's direction and its component, unless
    /// the direction is zero (or NaN).
    #[inline]
    fn depth_axis(ray: &Ray) -> Option<(usize, f64)> {
        let d = ray.dir;
        let kz = d.abs().max_position();
        let dz = d[kz];
        (dz.abs() > 0.0).then_some((kz, dz))
    }

    #[inline]
    fn new(ray: &Ray) -> Option<Shear> {
        let d = ray.dir;
        let (kz, dz) = Shear::depth_axis(ray)?;
        let (mut kx, mut ky) = ((kz + 1) % 3, (kz + 2) % 3);
        if dz < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Some(Shear {
            o: ray.origin,
            kx,
            ky,
            kz,
            sx: d[kx] / dz,
            sy: d[ky] / dz,
            sz: 1.0 / dz,
        })
    }

    /// A vertex in ray space: x, y across the ray (the ray is the origin),
    /// z scaled so that `t` is a weighted sum of the three.
    #[inline]
    fn project(&self, p: Vec3) -> [f64; 3] {
        // An array, not `Vec3`: indexing a `Vec3` by a run-time axis is a
        // match per access.
        let q = (p - self.o).to_array();
        let z = q[self.kz];
        [
            q[self.kx] - self.sx * z,
            q[self.ky] - self.sy * z,
            self.sz * z,
        ]
    }

    /// The ray's `t` at triangle `a b c`, if it hits.
    ///
    /// Edge functions `U, V, W` (the 2D cross products of the projected
    /// vertices) have exact signs: a non-zero rounded `x·y − z·w` has the
    /// sign of the exact value (rounding is monotonic), and when it rounds
    /// to zero the sign is recomputed exactly from the products' rounding
    /// errors (the paper's fallback to higher precision). Mixed signs miss;
    /// all zero is a ray in the triangle's plane (or a degenerate triangle),
    /// which misses. An edge function exactly zero (the ray through an edge
    /// or vertex) is decided by the top-left rule on the edge directed
    /// counter-clockwise in the projection: own it iff `dy < 0`, or `dy = 0`
    /// and `dx > 0`. That is the inside test of the point nudged by
    /// (+x, then +y), so of two triangles sharing an edge (directed
    /// oppositely) exactly one owns it, and of a fan around a vertex exactly
    /// one owns the vertex (`ROBUSTNESS.md` case 29, Embree #188).
    #[inline]
    fn triangle(&self, a: Vec3, b: Vec3, c: Vec3) -> Option<f64> {
        self.projected_triangle(self.project(a), self.project(b), self.project(c))
    }

    /// `triangle` of vertices already in ray space (`project`), so that a
    /// polygon's fan projects each vertex once.
    #[inline]
    fn projected_triangle(&self, pa: [f64; 3], pb: [f64; 3], pc: [f64; 3]) -> Option<f64> {
        let u = edge_function(pc, pb);
        let v = edge_function(pa, pc);
        let w = edge_function(pb, pa);
        let pos = u > 0.0 || v > 0.0 || w > 0.0;
        let neg = u < 0.0 || v < 0.0 || w < 0.0;
        if pos == neg {
            return None;
        }
        // `pos`: a→c→b is counter-clockwise in the projection and the edges
        // of U, V, W run c→b, a→c, b→a; otherwise they run the other way.
        let owns = |value: f64, from: [f64; 3], to: [f64; 3]| {
            value != 0.0
                || if pos {
                    top_left(from, to)
                } else {
                    top_left(to, from)
                }
        };
        if !(owns(u, pc, pb) && owns(v, pa, pc) && owns(w, pb, pa)) {
            return None;
        }
        let det = u + v + w; // same-signed terms: no cancellation, non-zero
        Some((u * pa[2] + v * pb[2] + w * pc[2]) / det)
    }
}

/// `p.x·q.y − p.y·q.x` with an exact sign (see `Shear::triangle`). When the
/// rounded difference is zero the rounded products are equal, so the exact
/// value is the difference of their rounding errors (exact by fused
/// multiply-add); that is only off for products under- or overflowing.
#[inline]
fn edge_function(p: [f64; 3], q: [f64; 3]) -> f64 {
    let (x, y) = (p[0] * q[1], p[1] * q[0]);
    let e = x - y;
    if e != 0.0 {
        return e;
    }
    let ex = p[0].mul_add(q[1], -x);
    let ey = p[1].mul_add(q[0], -y);
    ex - ey
}

/// The top-left rule for the projected edge `from → to` of a
/// counter-clockwise triangle.
#[inline]
fn top_left(from: [f64; 3], to: [f64; 3]) -> bool {
    let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
    dy < 0.0 || (dy == 0.0 && dx > 0.0)
}

/// A polygon is planar, so it is crossed at most once: the first of its
/// triangles that the ray hits (the tie rule makes a ray through an inner
/// diagonal hit exactly one of the two triangles beside it).
fn polygon_hits(ray: &Ray, p: &Polygon) -> PrimHits {
    let Some(shear) = Shear::new(ray) else {
        return PrimHits::Miss;
    };
    // Each vertex projected once for the whole fan (the same arithmetic
    // as per triangle, so the same hits), up to `FAN` vertices.
    const FAN: usize = 8;
    let mut projected = [[0.0; 3]; FAN];
    let few = p.vertices.len() <= FAN;
    if few {
        for (q, v) in projected.iter_mut().zip(&p.vertices) {
            *q = shear.project(*v);
        }
    }
    for tri in &p.triangles {
        let [i, j, k] = tri.map(|i| i as usize);
        let hit = if few {
            let projected = &projected[..p.vertices.len()];
            let (Some(a), Some(b), Some(c)) =
                (projected.get(i), projected.get(j), projected.get(k))
            else {
                continue;
            };
            shear.projected_triangle(*a, *b, *c)
        } else {
            let (Some(a), Some(b), Some(c)) =
                (p.vertices.get(i), p.vertices.get(j), p.vertices.get(k))
            else {
                continue;
            };
            shear.triangle(*a, *b, *c)
        };
        if let Some(t) = hit {
            let t = on_plane(ray, &p.vertices, [i, j, k], t);
            return sheet(Some(crossing(t, 0)), None);
        }
    }
    PrimHits::Miss
}

/// The object-space unit normal (see `Primitive::normal`). Points are taken
/// as `(o − centre) + t·d` rather than `ray.at(t) − centre`, which would
/// cancel far from the origin.
fn shape_normal(shape: &Shape, ray: &Ray, t: f64, part: u8) -> Vec3 {
    match shape {
        Shape::Sphere { center, .. } => {
            ((ray.origin - *center) + ray.dir * t).normalize_or(Vec3::Z)
        }
        Shape::Box { .. } => {
            let mut n = Vec3::ZERO;
            let axis = usize::from(part / 2).min(2);
            n[axis] = if part.is_multiple_of(2) { -1.0 } else { 1.0 };
            n
        }
        Shape::Cylinder { base, top, .. } => cylinder_normal(ray, t, part, *base, *top),
        Shape::Cone {
            base,
            base_radius,
            top,
            top_radius,
            ..
        } => {
            if base_radius == top_radius {
                return cylinder_normal(ray, t, part, *base, *top);
            }
            let Some((a, len)) = unit_axis(*base, *top) else {
                return Vec3::Z;
            };
            let k = (top_radius - base_radius) / len;
            // The apex lies beyond the end whose radius is smaller; its
            // normal is the axis pointing from the body to the apex.
            let apex = if k < 0.0 { a } else { -a };
            match part {
                BASE_CAP => -a,
                TOP_CAP => a,
                APEX => apex,
                _ => {
                    let f = (ray.origin - *base) + ray.dir * t;
                    let radial = (f - a * f.dot(a)).normalize_or_zero();
                    if radial == Vec3::ZERO {
                        return apex; // on the axis: only the apex
                    }
                    // The gradient of |p⊥| − ρ(s): radial minus the slope
                    // along the axis; its length is sqrt(1 + k²) > 0.
                    (radial - a * k).normalize_or(apex)
                }
            }
        }
        Shape::Triangle { a, b, c } => (*b - *a).cross(*c - *a).normalize_or(Vec3::Z),
        Shape::Polygon(p) => p.normal(),
    }
}

fn cylinder_normal(ray: &Ray, t: f64, part: u8, base: Vec3, top: Vec3) -> Vec3 {
    let Some((a, _)) = unit_axis(base, top) else {
        return Vec3::Z;
    };
    match part {
        BASE_CAP => -a,
        TOP_CAP => a,
        _ => {
            let f = (ray.origin - base) + ray.dir * t;
            (f - a * f.dot(a)).normalize_or(a.any_orthonormal_vector())
        }
    }
}

#[cfg(test)]
#[path = "shape_tests.rs"]
mod tests;
