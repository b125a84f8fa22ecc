//! Reflection, refraction and safe ray origins: the few formulas where naive
//! code produces NaN or self-intersection (`ROBUSTNESS.md` cases 24-25).

use crate::geom::{Ray, Vec3};

/// Mirror direction of `d` about the unit normal `n`.
#[inline]
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - n * (2.0 * d.dot(n))
}

/// The outcome of Snell's law at an interface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Refraction {
    /// The unit transmitted direction; all of the transmitted share passes.
    Transmitted(Vec3),
    /// Total internal reflection: the transmitted share is reflected.
    TotalInternal,
}

impl Refraction {
    /// The shares (reflected, transmitted) of the light that meets the
    /// interface's transmissive part: (0, 1) or, under total internal
    /// reflection, (1, 0). They always sum to exactly 1 (case 25).
    pub fn shares(&self) -> (f64, f64) {
        match self {
            Refraction::Transmitted(_) => (0.0, 1.0),
            Refraction::TotalInternal => (1.0, 0.0),
        }
    }
}

/// Snell's law for a unit direction `d` meeting a unit normal `n` that faces
/// it (`d·n ≤ 0`), with `eta` = n_incident / n_transmitted. `|d·n|` may
/// exceed 1 by rounding; it is clamped so no square root of a negative
/// number is ever taken (`ROBUSTNESS.md` case 25, RayTracing #559).
pub fn refract(d: Vec3, n: Vec3, eta: f64) -> Refraction {
    let cos_i = (-d.dot(n)).clamp(0.0, 1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return Refraction::TotalInternal;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Refraction::Transmitted((d * eta + n * (eta * cos_i - cos_t)).normalize())
}

/// Relative error of rounding a hit point `p = o + d·t` to the nearest
/// floats (two roundings, with a margin): what `p`'s own magnitude costs.
const ROUNDING_ERROR: f64 = 4.0 * f64::EPSILON;

/// Relative error bound of a computed hit distance, as a multiple of the
/// magnitudes the intersection routines subtract and multiply: the distance
/// travelled and the primitive's size (pbrt-v4's γ(n) style, generous enough
/// for transformed primitives).
const DISTANCE_ERROR: f64 = 64.0 * f64::EPSILON;

/// The origin of a ray spawned at `p = ray.at(t)` on a primitive whose world
/// bounds are `extent` wide (their largest side), pushed to the side of the
/// unit vector `side` by the hit point's error bound and rounded away from
/// the surface (pbrt-v4 `OffsetRayOrigin`): the new ray never re-hits the
/// surface it leaves, and the push is far too small to skip a thin wall.
///
/// The bound is relative, never absolute, and each magnitude counts only
/// for the error it causes. Every routine intersects differences such as
/// `o − centre` or `face − o`, which are correctly rounded, so `t` is as
/// accurate as the distance `|d·t|` and the primitive's size, not as the
/// coordinates; only the rounding of `p` itself costs `|p|`. A scene moved
/// 1e8 away is offset by a few ulps of 1e8, not by hundreds
/// (`ROBUSTNESS.md` case 22: hundreds of ulps there are 5e-6, which moved
/// reflections and refractions visibly).
pub fn offset_origin(ray: &Ray, t: f64, p: Vec3, side: Vec3, extent: f64) -> Vec3 {
    let extent = if extent.is_finite() { extent } else { 0.0 };
    let err = p.abs() * ROUNDING_ERROR
        + ((ray.dir * t).abs() + Vec3::splat(extent.abs())) * DISTANCE_ERROR;
    let dist = side.abs().dot(err);
    let mut o = p + side * dist;
    for a in 0..3 {
        if side[a] > 0.0 {
            o[a] = o[a].next_up();
        } else if side[a] < 0.0 {
            o[a] = o[a].next_down();
        }
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn total_internal_reflection_beyond_the_critical_angle() {
        // Inside glass (ior 1.5) toward air: eta = 1.5, critical angle asin(1/1.5).
        let n = Vec3::Z;
        let crit = (1.0f64 / 1.5).asin();
        for angle in [60f64.to_radians(), crit, crit + 1e-12] {
            let d = Vec3::new(angle.sin(), 0.0, -angle.cos());
            let r = refract(d, n, 1.5);
            let (rs, ts) = r.shares();
            assert!((rs + ts - 1.0).abs() <= 1e-12);
            if angle > crit {
                assert_eq!(r, Refraction::TotalInternal);
            }
            if let Refraction::Transmitted(t) = r {
                assert!(t.is_finite());
            }
        }
        // |d·n| slightly above 1 from rounding must not give NaN.
        let d = Vec3::new(0.0, 0.0, -1.0000000000000002);
        match refract(d, n, 1.5) {
            Refraction::Transmitted(t) => assert!(t.is_finite() && (t.z + 1.0).abs() < 1e-12),
            Refraction::TotalInternal => panic!("normal incidence is never TIR"),
        }
    }

    #[test]
    fn snell_law_holds() {
        let n = Vec3::Z;
        let a = 30f64.to_radians();
        let d = Vec3::new(a.sin(), 0.0, -a.cos());
        let Refraction::Transmitted(t) = refract(d, n, 1.0 / 1.5) else {
            panic!("entering glass never reflects totally")
        };
        let sin_t = t.x;
        assert!((a.sin() - 1.5 * sin_t).abs() < 1e-14);
    }

    #[test]
    fn offset_is_relative_to_magnitude() {
        let r = Ray::new(Vec3::ZERO, Vec3::X);
        for scale in [1e-6, 1.0, 1e8] {
            let p = Vec3::new(scale, 0.0, 0.0);
            let o = offset_origin(&r, scale, p, -Vec3::X, scale);
            assert!(o.x < p.x);
            assert!((p.x - o.x) < scale * 1e-12);
        }
        // Far from the origin, a small distance and object are offset by a
        // few ulps of the coordinates, not by the coordinates times 64 ε.
        let p = Vec3::new(1e8, 1e8, 1e8);
        let r = Ray::new(p - Vec3::X, Vec3::X);
        let o = offset_origin(&r, 1.0, p, Vec3::X, 1.0);
        let ulp = 1e8f64.next_up() - 1e8;
        assert!(o.x > p.x && o.x - p.x <= 8.0 * ulp, "{}", o.x - p.x);
    }
}
