//! Geometry shared by every layer: f64 vectors, rays, axis-aligned boxes and
//! affine transforms. Owns no scene knowledge; everything else builds on it.
//!
//! All geometry is f64 (`ROBUSTNESS.md`: no absolute epsilons). Tolerances
//! that are needed are relative to the magnitudes involved.

pub use glam::{DMat3, DVec3};

/// A 3-vector in world or object space.
pub type Vec3 = DVec3;
/// Linear RGB, each channel nominally in [0, 1].
pub type Color = DVec3;

/// A ray `origin + t·dir`. `dir` need not be unit length; every `t` in the
/// crate is measured in units of `dir`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
}

impl Ray {
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir }
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f64) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// An axis-aligned box, closed on every side. A box with `min > max` on any
/// axis is empty; `Aabb::EMPTY` is the identity of `union`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };
    pub const EVERYTHING: Aabb = Aabb {
        min: DVec3::splat(f64::NEG_INFINITY),
        max: DVec3::splat(f64::INFINITY),
    };

    pub fn new(min: Vec3, max: Vec3) -> Self {
        Aabb { min, max }
    }

    /// True when no point lies in the box (min > max on some axis, or NaN).
    pub fn is_empty(&self) -> bool {
        !(self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z)
    }

    /// The largest side: a primitive's size, on which its rounding scales.
    pub fn largest_side(&self) -> f64 {
        (self.max - self.min).max_element()
    }

    pub fn from_points(points: impl IntoIterator<Item = Vec3>) -> Self {
        points.into_iter().fold(Aabb::EMPTY, |b, p| Aabb {
            min: b.min.min(p),
            max: b.max.max(p),
        })
    }

    pub fn union(&self, o: &Aabb) -> Aabb {
        if self.is_empty() {
            return *o;
        }
        if o.is_empty() {
            return *self;
        }
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// The intersection; empty boxes stay empty (case 14 of `ROBUSTNESS.md`:
    /// an inverted box must never corrupt its parent's bounds).
    pub fn intersect(&self, o: &Aabb) -> Aabb {
        let b = Aabb {
            min: self.min.max(o.min),
            max: self.max.min(o.max),
        };
        if b.is_empty() { Aabb::EMPTY } else { b }
    }

    pub fn overlaps(&self, o: &Aabb) -> bool {
        !self.intersect(o).is_empty()
    }

    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// The eight corners (meaningless for an empty box).
    pub fn corners(&self) -> [Vec3; 8] {
        let (a, b) = (self.min, self.max);
        [
            Vec3::new(a.x, a.y, a.z),
            Vec3::new(b.x, a.y, a.z),
            Vec3::new(a.x, b.y, a.z),
            Vec3::new(b.x, b.y, a.z),
            Vec3::new(a.x, a.y, b.z),
            Vec3::new(b.x, a.y, b.z),
            Vec3::new(a.x, b.y, b.z),
            Vec3::new(b.x, b.y, b.z),
        ]
    }

    /// Each bound moved outwards by `rel` times its own magnitude. Unlike
    /// `inflated`, the near end of a box that reaches very far stays where
    /// it is: a floor box from x = -1e30 to 4, inflated by 1e-12 of its
    /// largest magnitude, reached x = 1e18 as well, and the crossings of
    /// its edges with the eye plane, between corners both 1e18 or more
    /// away, came out some 100 units off (`cells::projection`): the floor
    /// was left out of the cells around the camera.
    pub fn inflated_each(&self, rel: f64) -> Aabb {
        if self.is_empty() {
            return *self;
        }
        let tiny = Vec3::splat(f64::MIN_POSITIVE);
        Aabb {
            min: self.min - self.min.abs() * rel - tiny,
            max: self.max + self.max.abs() * rel + tiny,
        }
    }

    /// Grown on every side by `rel` times the largest magnitude of its
    /// coordinates (a relative, not an absolute, tolerance), so that objects
    /// are assigned to cells over closed, slightly inflated bounds.
    pub fn inflated(&self, rel: f64) -> Aabb {
        if self.is_empty() {
            return *self;
        }
        let mag = self.min.abs().max(self.max.abs());
        let pad = mag * rel + Vec3::splat(f64::MIN_POSITIVE);
        Aabb {
            min: self.min - pad,
            max: self.max + pad,
        }
    }

    /// The parameter interval `[t0, t1]` of `ray` inside the box, if any.
    /// Slab test written so that zero direction components (and -0.0) never
    /// produce NaN: a ray parallel to a slab is inside it or not by its origin.
    #[inline]
    pub fn ray_interval(&self, ray: &Ray) -> Option<(f64, f64)> {
        let mut t0 = f64::NEG_INFINITY;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            let o = ray.origin[a];
            let d = ray.dir[a];
            let (lo, hi) = (self.min[a], self.max[a]);
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d;
            let (mut a0, mut a1) = ((lo - o) * inv, (hi - o) * inv);
            if a0 > a1 {
                std::mem::swap(&mut a0, &mut a1);
            }
            // NaN-safe: (inf - inf) cannot occur with finite box and origin;
            // with infinite boxes the comparisons below skip NaN.
            if a0 > t0 {
                t0 = a0;
            }
            if a1 < t1 {
                t1 = a1;
            }
            if t0 > t1 {
                return None;
            }
        }
        Some((t0, t1))
    }
}

/// The sine and cosine of an angle in degrees, exact for multiples of 90°.
/// `cos(90°)` computed in radians is 6.1e-17, not 0: a primitive turned by a
/// quarter turn would be tilted by that much, so its faces would no longer
/// coincide with another's, and a cylinder's caps would cut a box's faces
/// at slightly different `t` (speckles, `ROBUSTNESS.md` cases 9-10).
fn sin_cos_deg(deg: f64) -> (f64, f64) {
    let quarter = deg.rem_euclid(360.0) / 90.0;
    if quarter.fract() == 0.0 {
        return [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0)][quarter as usize % 4];
    }
    deg.to_radians().sin_cos()
}

/// The Frobenius norm of `m`, an upper bound of how far it stretches any
/// vector (its operator norm).
pub fn frobenius_norm(m: &DMat3) -> f64 {
    (m.x_axis.length_squared() + m.y_axis.length_squared() + m.z_axis.length_squared()).sqrt()
}

/// An affine map `p ↦ M·p + t` with its inverse and the normal matrix
/// (inverse transpose of `M`), so that normals map correctly under
/// non-uniform scale.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Affine {
    pub linear: DMat3,
    pub translation: Vec3,
    pub inv_linear: DMat3,
    pub normal_matrix: DMat3,
}

impl Affine {
    pub const IDENTITY: Affine = Affine {
        linear: DMat3::IDENTITY,
        translation: DVec3::ZERO,
        inv_linear: DMat3::IDENTITY,
        normal_matrix: DMat3::IDENTITY,
    };

    /// `SCENE_FORMAT.md`'s Transform: scale, then rotate about x, then y,
    /// then z (degrees), then translate.
    pub fn from_srt(scale: Vec3, rotate_deg: Vec3, translate: Vec3) -> Affine {
        let (sx, cx) = sin_cos_deg(rotate_deg.x);
        let (sy, cy) = sin_cos_deg(rotate_deg.y);
        let (sz, cz) = sin_cos_deg(rotate_deg.z);
        // glam's `from_rotation_{x,y,z}`, with exact sines and cosines.
        let rx = DMat3::from_cols(Vec3::X, Vec3::new(0.0, cx, sx), Vec3::new(0.0, -sx, cx));
        let ry = DMat3::from_cols(Vec3::new(cy, 0.0, -sy), Vec3::Y, Vec3::new(sy, 0.0, cy));
        let rz = DMat3::from_cols(Vec3::new(cz, sz, 0.0), Vec3::new(-sz, cz, 0.0), Vec3::Z);
        let r = rz * ry * rx;
        let linear = r * DMat3::from_diagonal(scale);
        Affine::from_linear(linear, translate)
    }

    pub fn from_linear(linear: DMat3, translation: Vec3) -> Affine {
        let inv_linear = linear.inverse();
        Affine {
            linear,
            translation,
            inv_linear,
            normal_matrix: inv_linear.transpose(),
        }
    }

    /// `self ∘ inner`: apply `inner` first.
    pub fn then_inner(&self, inner: &Affine) -> Affine {
        Affine::from_linear(
            self.linear * inner.linear,
            self.linear * inner.translation + self.translation,
        )
    }

    pub fn is_identity(&self) -> bool {
        self.linear == DMat3::IDENTITY && self.translation == DVec3::ZERO
    }

    pub fn point(&self, p: Vec3) -> Vec3 {
        self.linear * p + self.translation
    }

    pub fn vector(&self, v: Vec3) -> Vec3 {
        self.linear * v
    }

    pub fn inverse_point(&self, p: Vec3) -> Vec3 {
        self.inv_linear * (p - self.translation)
    }

    pub fn inverse_vector(&self, v: Vec3) -> Vec3 {
        self.inv_linear * v
    }

    /// A world ray expressed in the object space of this transform; `t` is
    /// preserved because the direction is not renormalised.
    pub fn inverse_ray(&self, r: &Ray) -> Ray {
        Ray::new(self.inverse_point(r.origin), self.inverse_vector(r.dir))
    }

    /// An object-space normal mapped to a unit world-space normal.
    pub fn normal(&self, n: Vec3) -> Vec3 {
        (self.normal_matrix * n).normalize()
    }

    /// The world box of an object box (the box of its eight mapped corners).
    pub fn bounds(&self, b: &Aabb) -> Aabb {
        if b.is_empty() {
            return Aabb::EMPTY;
        }
        Aabb::from_points(b.corners().map(|c| self.point(c)))
    }

    /// True when the linear part is a non-negative diagonal scale (no
    /// rotation): axis-aligned boxes stay axis-aligned and can be baked.
    pub fn is_axis_scale(&self) -> bool {
        self.axis_scales()
            .is_some_and(|s| s.cmpgt(Vec3::ZERO).all())
    }

    /// The scales of a linear part that keeps the coordinate axes (a
    /// diagonal matrix, mirrors allowed), if it does.
    pub fn axis_scales(&self) -> Option<Vec3> {
        let m = self.linear;
        let off = [
            m.x_axis.y, m.x_axis.z, m.y_axis.x, m.y_axis.z, m.z_axis.x, m.z_axis.y,
        ];
        off.iter()
            .all(|&x| x == 0.0)
            .then_some(Vec3::new(m.x_axis.x, m.y_axis.y, m.z_axis.z))
    }

    /// The uniform scale factor when the linear part is a rotation times a
    /// uniform positive scale (a similarity), so spheres, cylinders and cones
    /// can be baked into world parameters.
    pub fn similarity_scale(&self) -> Option<f64> {
        let m = self.linear;
        let s = m.x_axis.length();
        let tol = 1e-14 * s;
        let ortho = m.x_axis.dot(m.y_axis).abs() <= tol * s
            && m.x_axis.dot(m.z_axis).abs() <= tol * s
            && m.y_axis.dot(m.z_axis).abs() <= tol * s;
        let same = (m.y_axis.length() - s).abs() <= tol && (m.z_axis.length() - s).abs() <= tol;
        (ortho && same && m.determinant() > 0.0).then_some(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inflating_each_bound_keeps_a_far_reaching_boxs_near_end_near() {
        let b = Aabb::new(Vec3::new(-1e30, -6.0, -0.1), Vec3::new(4.0, 4.0, 0.0));
        let each = b.inflated_each(1e-12);
        assert!(each.contains(b.min) && each.contains(b.max));
        assert!(each.max.x > 4.0 && each.max.x < 4.0 + 1e-10, "{each:?}");
        assert!(each.min.x < -1e30 && each.max.z > 0.0 && each.min.z < -0.1);
        // `inflated` pads by the axis's largest magnitude: 1e18 here.
        assert!(b.inflated(1e-12).max.x >= 1e18);
    }

    #[test]
    fn empty_box_does_not_corrupt_union() {
        let a = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let inverted = Aabb::new(Vec3::splat(5.0), Vec3::splat(-5.0));
        assert!(inverted.is_empty());
        assert_eq!(a.union(&inverted), a);
        assert_eq!(inverted.union(&a), a);
        assert!(a.intersect(&inverted).is_empty());
    }

    #[test]
    fn slab_test_handles_zero_and_negative_zero_directions() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        for dx in [0.0, -0.0] {
            let r = Ray::new(Vec3::new(1.0, 0.5, -5.0), Vec3::new(dx, 0.0, 1.0));
            assert_eq!(b.ray_interval(&r), Some((5.0, 6.0)));
        }
    }

    #[test]
    fn srt_applies_scale_then_rotation_then_translation() {
        let a = Affine::from_srt(
            Vec3::new(2.0, 1.0, 1.0),
            Vec3::new(0.0, 0.0, 90.0),
            Vec3::new(0.0, 0.0, 3.0),
        );
        let p = a.point(Vec3::X);
        assert!((p - Vec3::new(0.0, 2.0, 3.0)).length() < 1e-12);
        assert!((a.inverse_point(p) - Vec3::X).length() < 1e-12);
        assert!(a.similarity_scale().is_none());
        assert!(!a.is_axis_scale());
    }

    #[test]
    fn quarter_turns_are_exact() {
        for (deg, want) in [
            (90.0, Vec3::new(0.0, 0.0, 1.0)),
            (-270.0, Vec3::new(0.0, 0.0, 1.0)),
            (180.0, Vec3::new(0.0, -1.0, 0.0)),
            (450.0, Vec3::new(0.0, 0.0, 1.0)),
            (-90.0, Vec3::new(0.0, 0.0, -1.0)),
        ] {
            let a = Affine::from_srt(Vec3::ONE, Vec3::new(deg, 0.0, 0.0), Vec3::ZERO);
            assert_eq!(a.point(Vec3::Y), want, "{deg}°");
            assert_eq!(a.similarity_scale(), Some(1.0), "{deg}°");
        }
        // Other angles are unchanged: the same as glam's rotation.
        let a = Affine::from_srt(Vec3::ONE, Vec3::new(0.0, 0.0, 30.0), Vec3::ZERO);
        assert_eq!(a.linear, DMat3::from_rotation_z(30f64.to_radians()));
    }
}
