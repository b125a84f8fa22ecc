//! The projective screen system of the paper's section 7, made total.
//!
//! Camera coordinates: `x = (p−eye)·right`, `y = (p−eye)·up`,
//! `z = (p−eye)·forward`. Space is cut by the eye plane `z = 0` into two
//! regions, each with its own cell structure:
//!
//! * `Front` (`z > 0`): screen coordinates `(x/z, y/z)`, depth `z`. The
//!   perspective projection becomes parallel: a primary ray has constant
//!   screen coordinates (figure 11), and a cell's side faces `x = c·z` are
//!   planes through the eye.
//! * `Back` (`z ≤ 0`): screen coordinates `(x, y)`, depth `z`, an
//!   orthographic structure for what lies behind the eye plane, where the
//!   perspective map is singular or reversed (`ROBUSTNESS.md` cases 19-20).
//!
//! In both, cells are axis-aligned boxes in (screen x, screen y, depth).
//! Crossing parameters are computed from plane equations in camera space,
//! never by dividing by `z`, so nothing is singular at the eye plane; hits
//! and spans stay in world space.

use crate::geom::{Aabb, Ray, Vec3};
use crate::trace::CameraFrame;

/// Which half of space a structure covers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Region {
    Front,
    Back,
}

impl Region {
    pub const BOTH: [Region; 2] = [Region::Front, Region::Back];

    /// The depth interval of the region.
    pub fn depth_range(self) -> (f64, f64) {
        match self {
            Region::Front => (0.0, f64::INFINITY),
            Region::Back => (f64::NEG_INFINITY, 0.0),
        }
    }
}

/// The span of the finite coordinates of `rects`, per axis (`lo > hi`
/// along an axis where none is finite): where unbounded rectangles (the
/// partition is of the whole plane) are clamped to be measured.
pub fn finite_span<'a>(rects: impl IntoIterator<Item = &'a Rect>) -> ([f64; 2], [f64; 2]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for r in rects {
        for k in 0..2 {
            for v in [r.lo(k), r.hi(k)] {
                if v.is_finite() {
                    lo[k] = lo[k].min(v);
                    hi[k] = hi[k].max(v);
                }
            }
        }
    }
    (lo, hi)
}

/// A 2D half-open rectangle `[x0, x1) × [y0, y1)` of the screen plane;
/// bounds may be infinite (the plane is infinite, section 3.2).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    pub x0: f64,
    pub x1: f64,
    pub y0: f64,
    pub y1: f64,
}

impl Rect {
    pub const PLANE: Rect = Rect {
        x0: f64::NEG_INFINITY,
        x1: f64::INFINITY,
        y0: f64::NEG_INFINITY,
        y1: f64::INFINITY,
    };

    pub fn lo(&self, axis: usize) -> f64 {
        if axis == 0 { self.x0 } else { self.y0 }
    }

    pub fn hi(&self, axis: usize) -> f64 {
        if axis == 0 { self.x1 } else { self.y1 }
    }

    pub fn set_lo(&mut self, axis: usize, v: f64) {
        if axis == 0 { self.x0 = v } else { self.y0 = v }
    }

    pub fn set_hi(&mut self, axis: usize, v: f64) {
        if axis == 0 { self.x1 = v } else { self.y1 = v }
    }

    /// The part of this rectangle inside `o`, if it has area.
    pub fn overlap(&self, o: &Rect) -> Option<Rect> {
        let r = Rect {
            x0: self.x0.max(o.x0),
            x1: self.x1.min(o.x1),
            y0: self.y0.max(o.y0),
            y1: self.y1.min(o.y1),
        };
        (r.x0 < r.x1 && r.y0 < r.y1).then_some(r)
    }
}

/// Is `q` in the half-open `[lo, hi)` for a ray moving with sign `m` along
/// the axis? Ties go to the side the ray moves into (`ROBUSTNESS.md`: cells
/// are half-open, point location breaks ties by the ray's direction); an
/// infinite bound contains the matching infinity.
#[inline]
pub fn contains(lo: f64, hi: f64, q: f64, m: f64) -> bool {
    let above_lo = q > lo || (q == lo && (m >= 0.0 || lo == f64::NEG_INFINITY));
    let below_hi = q < hi || (q == hi && (m < 0.0 || hi == f64::INFINITY));
    above_lo && below_hi
}

/// The camera frame in which cells are axis-aligned.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct View {
    pub eye: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub forward: Vec3,
}

impl View {
    pub fn new(cam: &CameraFrame) -> View {
        View {
            eye: cam.eye,
            right: cam.right,
            up: cam.up,
            forward: cam.forward,
        }
    }

    pub fn point(&self, p: Vec3) -> Vec3 {
        let q = p - self.eye;
        Vec3::new(q.dot(self.right), q.dot(self.up), q.dot(self.forward))
    }

    pub fn vector(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.right), v.dot(self.up), v.dot(self.forward))
    }

    /// A world ray in camera coordinates (same `t`).
    pub fn ray(&self, r: &Ray) -> CamRay {
        CamRay {
            o: self.point(r.origin),
            d: self.vector(r.dir),
        }
    }

    /// The screen rectangle and depth interval covered by `b ∩ region`, or
    /// None when the box misses the region. The box is clipped by the eye
    /// plane before projecting (clip before dividing by w): the projection
    /// of a convex polytope is bounded by its vertices' projections, and a
    /// vertex on the eye plane stands for screen points at infinity. A box
    /// with the eye at its boundary, to rounding and to the padding of `b`
    /// around `core` (the box it was grown from, or `b` itself), covers the
    /// whole plane over its whole depth (`eye_near_boundary`).
    pub fn project_box(&self, b: &Aabb, core: &Aabb, region: Region) -> Option<(Rect, f64, f64)> {
        if b.is_empty() {
            return None;
        }
        let corners = b.corners().map(|c| self.point(c));
        if self.eye_near_boundary(b, core) {
            let (z0, z1) = View::depth_range_whole(&corners, region);
            return Some((Rect::PLANE, z0, z1));
        }
        let keep = |z: f64| match region {
            Region::Front => z >= 0.0,
            Region::Back => z <= 0.0,
        };
        let mut verts: Vec<Vec3> = corners.iter().copied().filter(|c| keep(c.z)).collect();
        // Edges of the box that cross the eye plane contribute a vertex on it.
        const EDGES: [(usize, usize); 12] = [
            (0, 1),
            (2, 3),
            (4, 5),
            (6, 7),
            (0, 2),
            (1, 3),
            (4, 6),
            (5, 7),
            (0, 4),
            (1, 5),
            (2, 6),
            (3, 7),
        ];
        for (i, j) in EDGES {
            let (a, c) = (corners[i], corners[j]);
            if (a.z < 0.0 && c.z > 0.0) || (a.z > 0.0 && c.z < 0.0) {
                let mut p = plane_crossing(a, c, a.z, c.z);
                p.z = 0.0;
                verts.push(p);
            }
        }
        if verts.is_empty() {
            return None;
        }
        let mut r = Rect {
            x0: f64::INFINITY,
            x1: f64::NEG_INFINITY,
            y0: f64::INFINITY,
            y1: f64::NEG_INFINITY,
        };
        let (mut z0, mut z1) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in &verts {
            z0 = z0.min(v.z);
            z1 = z1.max(v.z);
            match region {
                Region::Back => {
                    r.x0 = r.x0.min(v.x);
                    r.x1 = r.x1.max(v.x);
                    r.y0 = r.y0.min(v.y);
                    r.y1 = r.y1.max(v.y);
                }
                Region::Front if v.z > 0.0 => {
                    let (sx, sy) = (v.x / v.z, v.y / v.z);
                    r.x0 = r.x0.min(sx);
                    r.x1 = r.x1.max(sx);
                    r.y0 = r.y0.min(sy);
                    r.y1 = r.y1.max(sy);
                }
                Region::Front => {
                    // A vertex on the eye plane: the projection reaches
                    // infinity on the side of its sign (both sides at 0).
                    if v.x >= 0.0 {
                        r.x1 = f64::INFINITY;
                    }
                    if v.x <= 0.0 {
                        r.x0 = f64::NEG_INFINITY;
                    }
                    if v.y >= 0.0 {
                        r.y1 = f64::INFINITY;
                    }
                    if v.y <= 0.0 {
                        r.y0 = f64::NEG_INFINITY;
                    }
                }
            }
        }
        let (rz0, rz1) = region.depth_range();
        Some((
            inflate_rect(r),
            inflate(z0, z1, 0).0.max(rz0),
            inflate(z0, z1, 0).1.min(rz1),
        ))
    }
}

/// A box in camera coordinates: its eight corners, in `Aabb::corners`
/// order.
pub type CamBox = [Vec3; 8];

/// The six faces of a box as corner indices (`Aabb::corners` order), each
/// a cycle.
const FACES: [[usize; 4]; 6] = [
    [0, 1, 3, 2],
    [4, 5, 7, 6],
    [0, 1, 5, 4],
    [2, 3, 7, 6],
    [0, 2, 6, 4],
    [1, 3, 7, 5],
];

impl View {
    /// The corners of `b` in camera coordinates.
    pub fn cam_box(&self, b: &Aabb) -> CamBox {
        b.corners().map(|c| self.point(c))
    }

    /// Whether the eye lies in the band from within rounding outside `b`
    /// to within rounding inside `core` (the box `b` was padded from, or
    /// `b` itself), rounding being `CLIP_ROUNDING` of the coordinates'
    /// largest: there neither box's coordinates tell on which side of the
    /// boundary the eye is. A mirror box 6 thick reaching from −1e20 to
    /// 1e30, with the camera inside it 0.5 from a face, lost its thickness
    /// to rounding at 1e20 and projected to half the screen: no primary ray
    /// found it. Such a box is taken to cover the whole screen, over its
    /// whole depth in each region (`project_box`, `depth_range_whole`).
    pub fn eye_near_boundary(&self, b: &Aabb, core: &Aabb) -> bool {
        if b.is_empty() {
            return false;
        }
        let reach = (b.min - self.eye)
            .abs()
            .max((b.max - self.eye).abs())
            .max_element();
        let e = reach * CLIP_ROUNDING;
        let inside = |(lo, hi): (Vec3, Vec3)| lo.cmple(self.eye).all() && self.eye.cmple(hi).all();
        let deep = !core.is_empty() && inside((core.min + e, core.max - e));
        inside((b.min - e, b.max + e)) && !deep
    }

    /// The depth interval of a box (`corners`) in `region`, the eye plane
    /// included, padded as `depth_range_in` pads: what it gives when no
    /// side plane clips.
    pub fn depth_range_whole(corners: &CamBox, region: Region) -> (f64, f64) {
        let (z0, z1) = corners
            .iter()
            .fold((0.0f64, 0.0f64), |(a, b), c| (a.min(c.z), b.max(c.z)));
        pad_depth(z0, z1, corner_scale(corners), region)
    }

    /// The depth interval of the part of a box (`corners`, in camera
    /// coordinates) inside the region's prism over the screen rectangle
    /// `r` (the super cell's extension in depth, figure 4), or None when
    /// no part of it is there.
    ///
    /// Deviation from section 3.3, which cuts a super cell at the depth
    /// extents of its primitives' whole boxes: a box seen obliquely (a
    /// wall, a floor) spans a large depth range, but its part over one
    /// super cell spans little of it. Clipping the box by the super cell's
    /// side planes (and the eye plane) before taking the depth extent keeps
    /// such a primitive out of the cells it does not reach. The clipping
    /// planes are pushed outwards by a relative margin, and the interval
    /// is inflated, so the test only errs on the side of keeping a
    /// primitive.
    pub fn depth_range_in(corners: &CamBox, region: Region, r: &Rect) -> Option<(f64, f64)> {
        // Half-spaces a·p ≥ 0 with p = (x, y, z, 1).
        let mut planes: [[f64; 4]; 5] = [[0.0; 4]; 5];
        let mut n = 0;
        let margin = |v: f64| v.abs() * 1e-9 + 1e-12;
        let scale = corner_scale(corners);
        // The side planes only where clipping by them can be trusted: its
        // vertices carry rounding at the scale of the box's corners, which
        // must stay far below the super cell's width where the box is. A
        // box reaching 1e20 across over a depth of 11 (a cylinder of that
        // radius around the camera) came out clipped away entirely from a
        // super cell 0.2 wide that it covers: its crossings with the side
        // planes were some 1e4 off. There the box's whole depth in the
        // region is taken, as section 3.3 does, which errs on the side of
        // keeping it.
        let depth = corners.iter().fold(0.0f64, |m, c| m.max(c.z.abs()));
        let across = |lo: f64, hi: f64| match region {
            Region::Front => (hi - lo) * depth,
            Region::Back => hi - lo,
        };
        let trusted = scale * CLIP_ROUNDING <= across(r.x0, r.x1).min(across(r.y0, r.y1));
        // A plane is used only where its distances stay finite: a super
        // cell bounded at y = −7e307 (next to a box whose front is on the
        // eye plane, projected to −∞) gave −c·z past f64's range at a
        // depth of 5, and its clipping lost a rod it holds. Leaving a
        // plane out only widens the range. (An infinite bound is no plane.)
        let reach = match region {
            Region::Front => depth,
            Region::Back => 1.0,
        };
        let usable = |c: f64| trusted && (4.0 * (c.abs() * reach + scale)).is_finite();
        for (axis, lo, hi) in [(0usize, r.x0, r.x1), (1, r.y0, r.y1)] {
            let mut unit = [0.0; 4];
            unit[axis] = 1.0;
            match region {
                // x − c·z ≥ 0 and c·z − x ≥ 0: planes through the eye.
                Region::Front => {
                    if usable(lo) {
                        let c = lo - margin(lo);
                        planes[n] = [unit[0], unit[1], -c, 0.0];
                        n += 1;
                    }
                    if usable(hi) {
                        let c = hi + margin(hi);
                        planes[n] = [-unit[0], -unit[1], c, 0.0];
                        n += 1;
                    }
                }
                Region::Back => {
                    if usable(lo) {
                        planes[n] = [unit[0], unit[1], 0.0, -(lo - margin(lo))];
                        n += 1;
                    }
                    if usable(hi) {
                        planes[n] = [-unit[0], -unit[1], 0.0, hi + margin(hi)];
                        n += 1;
                    }
                }
            }
        }
        // The region's side of the eye plane.
        planes[n] = match region {
            Region::Front => [0.0, 0.0, 1.0, 0.0],
            Region::Back => [0.0, 0.0, -1.0, 0.0],
        };
        n += 1;
        // Only planes that cut the box clip it: a plane with every corner
        // inside leaves the box whole (skipping it can only widen the range
        // by rounding, the safe side), and one with every corner outside
        // leaves nothing. Most planes of a super cell are of the first kind
        // for most of its primitives. Sphereflake level 4: instructions in
        // this function 198M -> 67M, in the whole build 534M -> 404M.
        let dist = |pl: &[f64; 4], p: &Vec3| pl[0] * p.x + pl[1] * p.y + pl[2] * p.z + pl[3];
        let mut cutting = 0;
        for i in 0..n {
            let inside = corners
                .iter()
                .filter(|c| dist(&planes[i], c) >= 0.0)
                .count();
            if inside == 0 {
                return None;
            }
            if inside < corners.len() {
                planes[cutting] = planes[i];
                cutting += 1;
            }
        }
        let planes = &planes[..cutting];
        let (mut z0, mut z1) = (f64::INFINITY, f64::NEG_INFINITY);
        if planes.is_empty() {
            // No plane cuts the box: its extent is its corners' (which
            // the faces below would give, corner by corner).
            for c in corners {
                z0 = z0.min(c.z);
                z1 = z1.max(c.z);
            }
        } else {
            // Sutherland-Hodgman on each face. The extremes of z over the
            // clipped box are at its vertices: on a face of the box (found
            // here), or where three clipping planes meet, which is on the eye
            // plane (the side planes of the front region all pass through the
            // eye; in the back region they are parallel to z). Those count
            // below, conservatively, whenever the box reaches the eye plane.
            // Two polygon buffers, swapped by reference after each plane.
            let (mut buf_a, mut buf_b) = ([Vec3::ZERO; 12], [Vec3::ZERO; 12]);
            for face in &FACES {
                let (mut a, mut b) = (&mut buf_a, &mut buf_b);
                let mut len = 4;
                for (k, &i) in face.iter().enumerate() {
                    a[k] = corners[i];
                }
                for pl in planes {
                    let mut out = 0;
                    for k in 0..len {
                        let (p, q) = (a[k], a[(k + 1) % len]);
                        let (dp, dq) = (dist(pl, &p), dist(pl, &q));
                        if dp >= 0.0 {
                            b[out] = p;
                            out += 1;
                        }
                        if (dp >= 0.0) != (dq >= 0.0) {
                            b[out] = plane_crossing(p, q, dp, dq);
                            out += 1;
                        }
                    }
                    len = out;
                    std::mem::swap(&mut a, &mut b);
                    if len == 0 {
                        break;
                    }
                }
                for p in &a[..len] {
                    z0 = z0.min(p.z);
                    z1 = z1.max(p.z);
                }
            }
        }
        if z0 > z1 {
            return None;
        }
        if corners.iter().any(|c| c.z <= 0.0) && corners.iter().any(|c| c.z >= 0.0) {
            z0 = z0.min(0.0);
            z1 = z1.max(0.0);
        }
        Some(pad_depth(z0, z1, scale, region))
    }
}

/// The largest camera coordinate of a box's corners.
fn corner_scale(corners: &CamBox) -> f64 {
    corners
        .iter()
        .fold(0.0f64, |m, c| m.max(c.abs().max_element()))
}

/// A box's depth interval `[z0, z1]` padded and clamped to `region`:
/// inflated relative to itself, and also by the box's own distance from
/// the eye (`scale`, its largest camera coordinate): a walk crosses a
/// depth plane at a `t` rounded at the scale of its distance, not of the
/// plane's depth. A wall 1e-7 behind the eye plane, seen from 7 away in
/// a mirror, had its cell end 1.2e-15 past it (padded by its depth
/// alone), within a rounding of the crossing: the walk left the cell
/// before the hit and missed the wall.
fn pad_depth(z0: f64, z1: f64, scale: f64, region: Region) -> (f64, f64) {
    let (z0, z1) = inflate(z0, z1, 0);
    let pad = (z1 - z0) * 1e-9 + scale * INFLATE_REL;
    let (rz0, rz1) = region.depth_range();
    ((z0 - pad).max(rz0), (z1 + pad).min(rz1))
}

/// Where the segment from `p` to `q` crosses a plane, given their signed
/// distances `dp` and `dq` to it (of opposite signs), interpolated from
/// the endpoint nearer the plane. From the far one, the step `(q − p)·s`
/// carries the rounding of the whole segment's length: with one end 1e20
/// away, a crossing next to the camera comes out about 1e4 off. (Together
/// with the build's inflation, which then moved a far-reaching floor's
/// near end 1e8 away, that left the floor out of the cells around the
/// camera; `Aabb::inflated_each`.) From the near one, the error scales
/// with the distance to the crossing, the least the inputs allow.
#[inline]
fn plane_crossing(p: Vec3, q: Vec3, dp: f64, dq: f64) -> Vec3 {
    if dp.abs() <= dq.abs() {
        p + (q - p) * (dp / (dp - dq))
    } else {
        q + (p - q) * (dq / (dq - dp))
    }
}

/// How far the side-plane clipping of `View::depth_range_in` is trusted:
/// its vertices are off by a few ulps of the box's largest coordinate
/// (`plane_crossing`), and this bound (2^-40, some ten thousand ulps)
/// must stay below the super cell's width at the box's depth.
const CLIP_ROUNDING: f64 = 1.0 / (1u64 << 40) as f64;

/// Relative inflation of projected bounds: rounding in the camera transform
/// and in crossing parameters is ~1e-16 relative, so a primitive assigned
/// over bounds grown by 1e-12 is never missed by a ray that rounding puts in
/// a neighbouring cell.
const INFLATE_REL: f64 = 1e-12;

fn inflate(lo: f64, hi: f64, _axis: usize) -> (f64, f64) {
    let pad = (lo.abs().max(hi.abs()) * INFLATE_REL).max(f64::MIN_POSITIVE);
    let pad = if pad.is_finite() { pad } else { 0.0 };
    (lo - pad, hi + pad)
}

fn inflate_rect(r: Rect) -> Rect {
    // Screen coordinates of the front region are slopes, dimensionless:
    // a floor of 1e-15 there is scale-free.
    let (x0, x1) = inflate(r.x0, r.x1, 0);
    let (y0, y1) = inflate(r.y0, r.y1, 1);
    let f = |v: f64, s: f64| if v.is_finite() { v + s } else { v };
    Rect {
        x0: f(x0, -1e-15),
        x1: f(x1, 1e-15),
        y0: f(y0, -1e-15),
        y1: f(y1, 1e-15),
    }
}

/// A ray in camera coordinates.
#[derive(Clone, Copy, Debug)]
pub struct CamRay {
    pub o: Vec3,
    pub d: Vec3,
}

/// A front screen coordinate `q = x/z` of a point of a ray, kept on the
/// side of the ray's limit `dx/dz` (its screen position at infinite depth)
/// where its motion puts every point of it: exactly, `q − dx/dz =
/// −motion / (dz·z)`. Near the eye `x` and `z` are both rounding noise and
/// so is their quotient, which could put the walk on the far side of the
/// limit, from where its motion (which never crosses the limit) cannot
/// bring it back; there it is the limit itself. Elsewhere the quotient is
/// on its side already, and this changes nothing (and costs no division).
/// A `dz` that is zero or subnormal acts as zero (`ROBUSTNESS.md` case
/// 28): the ray runs along the eye plane, has no limit, and `q` is kept.
#[inline]
pub fn beside_limit(q: f64, dx: f64, motion: f64, dz: f64) -> f64 {
    if !dz.is_normal() {
        return q;
    }
    let side = limit_side(motion, dz);
    // The sign of q − dx/dz, as that of (q·dz − dx)·dz.
    let off = q * dz - dx;
    let wrong = side == 0.0 || (off * dz) * side < 0.0;
    if wrong {
        let lim = dx / dz;
        if lim.is_finite() { lim } else { q }
    } else {
        q
    }
}

/// Where a ray at camera depth `oz`, with `inv_dz = 1 / dz`, crosses the
/// depth plane `z`: the one arithmetic of every depth crossing, the
/// walk's (`traverse::depth_crossing`) and the regions' common end
/// (`eye_plane_crossing`), which must be the same `t` to the bit.
#[inline(always)]
pub fn depth_plane_crossing(z: f64, oz: f64, inv_dz: f64) -> f64 {
    (z - oz) * inv_dz
}

/// Where a ray at camera depth `oz`, moving by `dz`, crosses the eye
/// plane: the walk's depth crossing at `z = 0`, so that the regions' end
/// and the walk's exit through the eye plane are the same `t`.
#[inline]
pub fn eye_plane_crossing(oz: f64, dz: f64) -> f64 {
    depth_plane_crossing(0.0, oz, 1.0 / dz)
}

/// The sign (1, −1, or 0) of `−motion·dz`, without the product (which
/// can underflow to zero): which side of a front ray's limit its points
/// lie on (`beside_limit`), and, at the eye plane, the sign of its `x`.
#[inline]
pub fn limit_side(motion: f64, dz: f64) -> f64 {
    if motion == 0.0 || dz == 0.0 || motion.is_nan() || dz.is_nan() {
        0.0
    } else if (motion > 0.0) == (dz > 0.0) {
        -1.0
    } else {
        1.0
    }
}

impl CamRay {
    pub fn at(&self, t: f64) -> Vec3 {
        self.o + self.d * t
    }

    /// The sign of the ray's motion along screen axis `axis` (0: x, 1: y):
    /// `d/dt (x/z) ∝ dx·oz − ox·dz` is constant along a ray in the front
    /// region; in the back region the motion is `d[axis]`.
    pub fn motion(&self, region: Region, axis: usize) -> f64 {
        match region {
            Region::Front => self.d[axis] * self.o.z - self.o[axis] * self.d.z,
            Region::Back => self.d[axis],
        }
    }

    /// Screen coordinates at `t` in `region`. On the eye plane (front region
    /// entered from behind, or a primary ray at the eye) the limit of
    /// `x/z` as the ray moves into `z > 0` is used: ±∞ by the sign of `x`
    /// there, or `dx/dz` where `x` is 0 too.
    ///
    /// That sign is taken from the motion (`motion`): at the eye plane
    /// `x = −motion / dz`, exactly, where the point's own `x` may be
    /// rounding noise (a ray passing next to the eye), and so may its `z`
    /// at the front region's start, `t0 = −oz / dz`, where the division
    /// would give any screen position. The walk then starts at the side
    /// of the screen the motion comes from and follows the motion's sign
    /// through the side faces (`traverse::side_crossing`), as the exact
    /// ray does: seen from the eye's side, a ray through the eye's
    /// neighbourhood sweeps in from infinity to `d/dz`.
    #[inline]
    pub fn screen_at(&self, region: Region, t: f64) -> (f64, f64, f64) {
        let p = self.at(t);
        match region {
            Region::Back => (p.x, p.y, p.z.min(0.0)),
            // At the ray's origin, in front (most walks start there): the
            // quotient of its exact coordinates, correctly rounded, which
            // the side rule (`beside_limit`) could move by an ulp at most.
            Region::Front if t == 0.0 && p.z > 0.0 => (p.x / p.z, p.y / p.z, p.z),
            Region::Front => self.screen_in_front(p, t),
        }
    }

    /// `screen_at` in front, but at a ray's origin off the eye plane.
    #[inline(never)]
    fn screen_in_front(&self, p: Vec3, t: f64) -> (f64, f64, f64) {
        // From the eye itself (primary rays): the limit, at once; it is
        // what the arms below give, the motion being zero.
        if self.o == Vec3::ZERO && self.d.z.is_normal() {
            let (x, y) = (self.d.x / self.d.z, self.d.y / self.d.z);
            if x.is_finite() && y.is_finite() {
                return (x, y, p.z.max(0.0));
            }
        }
        // Off the eye plane, unless at the front region's start (`t0` of
        // `region_interval`, by the same arithmetic) coming from behind.
        if p.z > 0.0
            && !(self.o.z < 0.0 && self.d.z > 0.0 && t <= eye_plane_crossing(self.o.z, self.d.z))
        {
            let at = |axis: usize| {
                let q = p[axis] / p.z;
                beside_limit(q, self.d[axis], self.motion(Region::Front, axis), self.d.z)
            };
            return (at(0), at(1), p.z);
        }
        let lim = |axis: usize| {
            // The sign of x at the eye plane: −motion · dz.
            let x = limit_side(self.motion(Region::Front, axis), self.d.z);
            if x > 0.0 {
                f64::INFINITY
            } else if x < 0.0 {
                f64::NEG_INFINITY
            } else {
                let v = self.d[axis] / self.d.z;
                if v.is_nan() { 0.0 } else { v }
            }
        };
        (lim(0), lim(1), 0.0)
    }

    /// The parameter interval `[lo, hi)` of the ray in `region`, in the
    /// order the ray meets the regions; the eye plane crossing belongs to
    /// the region entered second.
    pub fn region_interval(&self, region: Region) -> (f64, f64) {
        let dz = self.d.z;
        if dz == 0.0 {
            let in_front = self.o.z > 0.0;
            return if in_front == (region == Region::Front) {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                (0.0, 0.0)
            };
        }
        // By the walk's own arithmetic for a depth plane
        // (`traverse::depth_crossing` at z = 0), to the bit: the region's
        // end is where its last cell's exit through the eye plane is. (A
        // division came out an ulp past that exit, and a boundary at that
        // `t`, a face through the eye hit by a ray through the eye,
        // belonged to neither region.)
        let t0 = eye_plane_crossing(self.o.z, dz);
        let front_first = dz < 0.0;
        match (region == Region::Front, front_first) {
            (true, true) | (false, false) => (f64::NEG_INFINITY, t0),
            _ => (t0, f64::INFINITY),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at the origin looking along `dir`, z up.
    fn view(dir: Vec3) -> View {
        let forward = dir.normalize();
        let right = forward.cross(Vec3::Z).normalize();
        View {
            eye: Vec3::ZERO,
            right,
            up: right.cross(forward),
            forward,
        }
    }

    /// A box reaching up to 1e20 behind the camera: its part just in front
    /// of the eye plane projects far out on the screen, on the sides its
    /// edges' crossings with the eye plane give, and the rectangle holds it.
    #[test]
    fn a_box_reaching_far_behind_the_eye_covers_its_part_near_the_eye_plane() {
        for dir in [
            Vec3::new(1.0, 0.3, -0.2),
            Vec3::new(1.0, -0.7, 0.1),
            Vec3::new(0.4, 1.0, -0.5),
        ] {
            let v = view(dir);
            for far in [1e12, 1e16, 1e20] {
                let b = Aabb::new(Vec3::new(-far, 0.5, -0.5), Vec3::new(4.0, 2.0, 0.25));
                let (r, _, _) = v.project_box(&b, &b, Region::Front).expect("in front");
                // Points of the box's x-edges just in front of the eye plane.
                for (y, z) in [(0.5, -0.5), (0.5, 0.25), (2.0, -0.5), (2.0, 0.25)] {
                    for eps in [1e-3, 1e-6] {
                        // forward · (x, y, z) = eps, solved for x.
                        let f = v.forward;
                        let x = (eps - f.y * y - f.z * z) / f.x;
                        if !(-far..=4.0).contains(&x) {
                            continue;
                        }
                        let c = v.point(Vec3::new(x, y, z));
                        let (sx, sy) = (c.x / c.z, c.y / c.z);
                        assert!(
                            r.x0 <= sx && sx <= r.x1 && r.y0 <= sy && sy <= r.y1,
                            "dir {dir}, far {far:e}: ({sx:e}, {sy:e}) outside {r:?}"
                        );
                    }
                }
            }
        }
    }

    /// The depth range of a far-reaching box over a narrow super cell near
    /// the screen's centre holds every point of the box that projects into
    /// it (sampled along the box's edges and across its faces).
    #[test]
    fn depth_ranges_of_a_far_reaching_box_hold_its_points() {
        for dir in [Vec3::new(-1.0, 0.3, -0.2), Vec3::new(-0.774, 0.624, -0.107)] {
            let v = view(dir);
            for far in [1e12, 1e20, 1e30] {
                let b = Aabb::new(Vec3::new(-far, -6.0, -0.1), Vec3::new(4.0, 4.0, 0.0));
                let corners = v.cam_box(&b);
                for (x0, y0) in [(-0.01, -0.35), (0.0, -0.3), (0.2, -0.5), (-0.3, -0.2)] {
                    let r = Rect {
                        x0,
                        x1: x0 + 0.02,
                        y0,
                        y1: y0 + 0.02,
                    };
                    let range = View::depth_range_in(&corners, Region::Front, &r);
                    // Points of the floor's top and sides, near the camera.
                    let mut k = 0u64;
                    for i in 0..400 {
                        for j in 0..400 {
                            k = k
                                .wrapping_mul(6364136223846793005)
                                .wrapping_add(1442695040888963407);
                            let fx = (k >> 11) as f64 / (1u64 << 53) as f64;
                            let x = 4.0 - 60.0 * (i as f64 + fx) / 400.0;
                            let y = -6.0 + 10.0 * (j as f64) / 399.0;
                            for z in [0.0, -0.1] {
                                let c = v.point(Vec3::new(x, y, z));
                                if c.z <= 0.0 {
                                    continue;
                                }
                                let (sx, sy) = (c.x / c.z, c.y / c.z);
                                if sx < r.x0 || sx >= r.x1 || sy < r.y0 || sy >= r.y1 {
                                    continue;
                                }
                                let (z0, z1) = range.unwrap_or_else(|| {
                                    panic!(
                                        "dir {dir}, far {far:e}, {r:?}: no range, but {c} is there"
                                    )
                                });
                                assert!(
                                    z0 <= c.z && c.z <= z1,
                                    "dir {dir}, far {far:e}, {r:?}: depth {} outside [{z0}, {z1}]",
                                    c.z
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
