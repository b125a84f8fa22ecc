//! Space tracing (section 7) with mailboxes (section 8): a ray is followed
//! from cell to cell in the projective screen system, and only the subtree
//! of each cell it crosses is evaluated, until a boundary is found inside
//! the cell.
//!
//! Primary rays keep their screen position, so they only move front to back
//! within one super cell (figure 11). Other rays leave cells through side
//! faces and find the next cell by the corner-pointer walk of figure 13:
//! from the pointer at the face's low corner, along the neighbours' corner
//! pointers, until one contains the exit point; then by depth.
//!
//! Exactness: a cell accepts only boundaries with `t` in its own half-open
//! interval `[t_in, t_out)`, where `t_out` of one cell is `t_in` of the
//! next (the same float), so every `t` of the ray belongs to exactly one
//! cell and the first boundary found is the one Roth's brute force finds.

use super::bsp::stitch;
use super::projection::{CamRay, Region, beside_limit, contains, depth_plane_crossing};
use super::share::Hull;
use super::{CellStructure, NOT_HELD, REMOTE, RegionCells, SubtreeLeaf, is_remote};
use crate::csg::{Crossing, EvalCounts, Evaluator, NodeId, PrimHits, PrimId};
use crate::geom::{Aabb, Ray, Vec3};
use crate::render::TraceCounters;
use crate::scene::Scene;
use crate::trace::{Hit, Tracer};

/// The face through which a ray leaves a cell: 0 and 1 the side faces
/// across screen x and y, 2 a depth face, 3 none (the ray does not leave).
type Face = usize;

/// A cell of one region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRef {
    pub region: Region,
    pub cell: u32,
}

/// A ray's move to another node, as the pre-pass walking under a mapping
/// records it (`CellTracer::record_work_for`): the node it left, and the
/// super cell whose owner it moved to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Move {
    pub from: u16,
    pub region: Region,
    pub super_cell: u32,
}

/// Where a ray goes after a cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// Into another cell, at parameter `t`.
    Next(CellRef, f64),
    /// Out of the region.
    Leave,
}

/// The per-ray quantities of the walk in one region.
#[derive(Clone, Copy, Debug)]
pub struct RegionRay {
    pub region: Region,
    pub cam: CamRay,
    /// Motion signs along screen x, screen y and depth.
    pub m: [f64; 3],
    /// `1 / cam.d.z`, for depth crossings (infinite for a zero or
    /// subnormal `d.z`, whose crossings are then not finite: none, as for
    /// `d.z = 0`).
    inv_dz: f64,
}

impl RegionRay {
    pub fn new(region: Region, cam: CamRay) -> Self {
        RegionRay {
            region,
            cam,
            m: [cam.motion(region, 0), cam.motion(region, 1), cam.d.z],
            inv_dz: 1.0 / cam.d.z,
        }
    }
}

impl CellStructure {
    /// The cell containing the ray's point at `t` (the start of its part in
    /// the region), by the BSP and a depth search; ties by direction.
    pub fn locate(&self, rr: &RegionRay, t: f64) -> CellRef {
        let (_, k) = self.region(rr.region).locate(rr, t, u32::MAX);
        CellRef {
            region: rr.region,
            cell: k,
        }
    }

    /// The parameter where the ray leaves cell `c` (never before `t_in`) and
    /// the cell it enters there (section 7, figures 11-13).
    pub fn step(&self, rr: &RegionRay, c: CellRef, t_in: f64) -> (f64, Step) {
        let rc = self.region(rr.region);
        let s = rc.super_cell_of(c.cell);
        let (t_out, next) = rc.exit(rr, s, c.cell, t_in);
        let next = match next {
            Some((_, k)) => Step::Next(
                CellRef {
                    region: c.region,
                    cell: k,
                },
                t_out,
            ),
            None => Step::Leave,
        };
        (t_out, next)
    }
}

/// A side plane's crossing `x = c·z` (front) or `x = c` (back) along
/// `axis`, or infinity for none (parallel, at infinity, or, in front, the
/// plane's mirror half behind the eye).
///
/// In front, the crossing's depth `o.z + t·d.z` is `motion / (d[axis] −
/// c·d.z)`, with `motion = d[axis]·o.z − o[axis]·d.z` (`CamRay::motion`,
/// held in `rr.m`): its sign is taken from that quotient's signs, never
/// from the sum, which cancels for a ray that passes next to the eye.
/// Such a ray keeps its screen coordinate (its motion is rounding noise),
/// and every side plane meets its line at the eye plane, where the sum's
/// sign is noise too: a crossing found there, far behind the ray's start,
/// took the walk out of its cell at once (a random scene's refracted ray,
/// which then missed the cone it was inside). By the quotient, the
/// crossing lies on the face's side of the eye exactly when the motion
/// the walk chose the face by points there.
#[inline(always)]
fn side_crossing<const FRONT: bool>(rr: &RegionRay, axis: usize, c: f64) -> f64 {
    let (o, d) = (rr.cam.o, rr.cam.d);
    let (t, ahead) = if FRONT {
        let den = d[axis] - c * d.z;
        ((c * o.z - o[axis]) / den, rr.m[axis] * den > 0.0)
    } else {
        ((c - o[axis]) / d[axis], true)
    };
    if c.is_finite() && t.is_finite() && ahead {
        t
    } else {
        f64::INFINITY
    }
}

/// A depth plane's crossing (not finite for none).
#[inline(always)]
fn depth_crossing(rr: &RegionRay, z: f64) -> f64 {
    depth_plane_crossing(z, rr.cam.o.z, rr.inv_dz)
}

impl CellStructure {
    /// Where a ray moving as `rr` enters cell `k` of super cell `s` through
    /// its face across `axis` (0, 1: the sides across screen x and y; 2:
    /// depth), computed as the walk computes the previous cell's exit
    /// through that plane: the same plane (neighbours share their
    /// boundary's coordinate) by the same arithmetic, so the same bits,
    /// unless the walk clamped its exit. The wire uses it to leave out a
    /// walk point's entry parameter where it gives back the same bits
    /// (`machine::codec`).
    pub fn entry_crossing(&self, rr: &RegionRay, s: u32, k: u32, axis: usize) -> f64 {
        let rc = self.region(rr.region);
        let m = rr.m[axis.min(2)];
        if axis >= 2 {
            let z = if m > 0.0 {
                rc.zlo[k as usize].into()
            } else {
                rc.zhi(s, k)
            };
            return depth_crossing(rr, z);
        }
        let rect = &rc.supers[s as usize].rect;
        let c = if m > 0.0 {
            rect.lo(axis)
        } else {
            rect.hi(axis)
        };
        match rr.region {
            Region::Front => side_crossing::<true>(rr, axis, c),
            Region::Back => side_crossing::<false>(rr, axis, c),
        }
    }
}

impl RegionCells {
    /// The super cell and cell containing the ray's point at `t`: super
    /// cell `hint` if it contains the point, else by descending the BSP
    /// (same ties: the leaves' half-open rectangles are the BSP's cuts).
    #[inline]
    fn locate(&self, rr: &RegionRay, t: f64, hint: u32) -> (u32, u32) {
        let (sx, sy, z) = rr.cam.screen_at(rr.region, t);
        let s = self.super_cell_at([sx, sy], [rr.m[0], rr.m[1]], hint);
        (s, self.cell_at_depth(s, z, rr.m[2]))
    }

    /// The super cell containing screen point `p` for a ray moving with
    /// signs `m` (ties as `contains` breaks them): `hint` if it does, else
    /// by the BSP, or, in a node's share, which has no BSP, by Ousterhout's
    /// point finding along the corner stitches from `hint`. Both give the
    /// one super cell whose half-open rectangle holds the point: the
    /// leaves' rectangles are the BSP's cuts, with the same ties.
    #[inline]
    pub fn super_cell_at(&self, p: [f64; 2], m: [f64; 2], hint: u32) -> u32 {
        let holds = |s: u32| {
            let r = &self.supers[s as usize].rect;
            contains(r.x0, r.x1, p[0], m[0]) && contains(r.y0, r.y1, p[1], m[1])
        };
        if (hint as usize) < self.supers.len() && holds(hint) {
            return hint;
        }
        if !self.partition.nodes.is_empty() {
            return self.partition.locate(p[0], p[1], m[0], m[1]);
        }
        let start = if (hint as usize) < self.supers.len() {
            hint
        } else {
            0
        };
        self.walk_to(start, p, m)
            // Only a point no rectangle holds (NaN) gets here; the BSP
            // would send it to some leaf, and so does this.
            .or_else(|| (0..self.supers.len() as u32).find(|&s| holds(s)))
            .unwrap_or(0)
    }

    /// Where the ray leaves cell `k` of super cell `s` (never before
    /// `t_in`), and the super cell and cell it enters there, if any.
    #[inline]
    fn exit(&self, rr: &RegionRay, s: u32, k: u32, t_in: f64) -> (f64, Option<(u32, u32)>) {
        let (t_out, face) = self.leave(rr, s, k, t_in);
        (t_out, self.enter_next(rr, s, k, t_out, face))
    }

    /// Where the ray leaves cell `k` of super cell `s` (never before
    /// `t_in`), and through which face (see `exit_in`).
    #[inline]
    fn leave(&self, rr: &RegionRay, s: u32, k: u32, t_in: f64) -> (f64, Face) {
        match rr.region {
            Region::Front => self.exit_in::<true>(rr, s, k, t_in),
            Region::Back => self.exit_in::<false>(rr, s, k, t_in),
        }
    }

    /// The super cell and cell the ray enters when it leaves cell `k` of
    /// super cell `s` at `t_out` through `face`, if any. Apart from
    /// `leave`, so that the walk finds the next cell only when it needs
    /// it: not after the cell where the ray's boundary is.
    #[inline]
    fn enter_next(
        &self,
        rr: &RegionRay,
        s: u32,
        k: u32,
        t_out: f64,
        face: Face,
    ) -> Option<(u32, u32)> {
        match rr.region {
            Region::Front => self.next_in::<true>(rr, s, k, t_out, face),
            Region::Back => self.next_in::<false>(rr, s, k, t_out, face),
        }
    }

    /// `leave` for one region (`FRONT` or not): the ray's crossings of the
    /// cell's side faces (`side_crossing`) and depth faces.
    #[inline(always)]
    fn exit_in<const FRONT: bool>(&self, rr: &RegionRay, s: u32, k: u32, t_in: f64) -> (f64, Face) {
        let rect = &self.supers[s as usize].rect;
        let side = |axis: usize, c: f64| side_crossing::<FRONT>(rr, axis, c);
        let mut t_out = f64::INFINITY;
        // 0, 1: the side faces across x and y; 2: depth; 3: none.
        let mut face = 3usize;
        // Ties between faces: x, then y, then depth (one fixed rule).
        for axis in 0..2 {
            let m = rr.m[axis];
            if m != 0.0 {
                let t = side(
                    axis,
                    if m > 0.0 {
                        rect.hi(axis)
                    } else {
                        rect.lo(axis)
                    },
                );
                if t < t_out {
                    t_out = t;
                    face = axis;
                }
            }
        }
        if rr.m[2] != 0.0 {
            let z = if rr.m[2] > 0.0 {
                self.zhi(s, k)
            } else {
                self.zlo[k as usize].into()
            };
            let t = depth_crossing(rr, z);
            if z.is_finite() && t.is_finite() && t < t_out {
                t_out = t;
                face = 2;
            }
        }
        // The entry t never decreases from cell to cell.
        let t_out = if t_out < t_in { t_in } else { t_out };
        (t_out, face)
    }

    /// `enter_next` for one region.
    #[inline(always)]
    fn next_in<const FRONT: bool>(
        &self,
        rr: &RegionRay,
        s: u32,
        k: u32,
        t_out: f64,
        face: Face,
    ) -> Option<(u32, u32)> {
        let (o, d) = (rr.cam.o, rr.cam.d);
        match face {
            3 => None,
            2 => {
                // Front and back pointers: the neighbours in depth order.
                let n = if rr.m[2] > 0.0 {
                    k + 1
                } else {
                    k.wrapping_sub(1)
                };
                let (first, end) = (self.first_cell[s as usize], self.first_cell[s as usize + 1]);
                (n >= first && n < end).then_some((s, n))
            }
            axis => {
                // The exit point: its coordinate along the face and its depth.
                let other = 1 - axis;
                let z = o.z + t_out * d.z;
                let (q, z) = if !FRONT {
                    (o[other] + t_out * d[other], z.min(0.0))
                } else if z > 0.0 {
                    let q = (o[other] + t_out * d[other]) / z;
                    (beside_limit(q, d[other], rr.m[other], d.z), z)
                } else {
                    let (sx, sy, z) = rr.cam.screen_at(rr.region, t_out);
                    (if other == 0 { sx } else { sy }, z)
                };
                let (zlo, zhi) = (self.zlo[k as usize].into(), self.zhi(s, k));
                self.side_neighbour(rr, s, axis, rr.m[axis] > 0.0, q, z, zlo, zhi)
            }
        }
    }

    /// Figure 13: the neighbour across a side face. Start from the corner
    /// pointer at the face's low end and climb the neighbours' pointers
    /// until one contains the exit point, then find the depth slab.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn side_neighbour(
        &self,
        rr: &RegionRay,
        s: u32,
        axis: usize,
        high: bool,
        q: f64,
        z: f64,
        zlo: f64,
        zhi: f64,
    ) -> Option<(u32, u32)> {
        use stitch::*;
        let supers = &self.supers;
        let rect = supers[s as usize].rect;
        let other = 1 - axis;
        // Clamped to the face, so the walk stays among true neighbours.
        let q = clamp(q, rect.lo(other), rect.hi(other));
        let mq = rr.m[other];
        let (start, climb) = match (axis, high) {
            (0, false) => (LD_LEFT, RU_UP),
            (0, true) => (RD_RIGHT, LU_UP),
            (_, false) => (LD_DOWN, RU_RIGHT),
            (_, true) => (LU_UP, RD_RIGHT),
        };
        let mut n = supers[s as usize].stitches[start];
        let mut guard = supers.len();
        while n != NONE {
            let sc = &supers[n as usize];
            if contains(sc.rect.lo(other), sc.rect.hi(other), q, mq) {
                let z = clamp(z, zlo, zhi);
                return Some((n, self.cell_at_depth(n, z, rr.m[2])));
            }
            n = sc.stitches[climb];
            guard -= 1;
            if guard == 0 {
                break;
            }
        }
        // The exit point is at the face's end and the ray moves past it: it
        // leaves through the corner, toward a diagonal neighbour that no
        // tile along the face contains. Find it from here by Ousterhout's
        // point-finding walk, with the exit coordinate exactly on the face
        // so the walk can never return this super cell.
        let mut p = [0.0; 2];
        p[axis] = if high { rect.hi(axis) } else { rect.lo(axis) };
        p[other] = q;
        let n = self.walk_to(s, p, [rr.m[0], rr.m[1]]);
        debug_assert!(n.is_some(), "corner-stitch point finding left the plane");
        let n = n?;
        Some((n, self.cell_at_depth(n, clamp(z, zlo, zhi), rr.m[2])))
    }

    /// Ousterhout's point finding by corner stitches: from super cell `s`,
    /// move down or up until the tile's y range holds `p.y`, then left or
    /// right until its x range holds `p.x`, and again while needed. Ties go
    /// the way the ray moves (`m`).
    fn walk_to(&self, s: u32, p: [f64; 2], m: [f64; 2]) -> Option<u32> {
        use stitch::*;
        let supers = &self.supers;
        let mut n = s;
        for _ in 0..=supers.len() {
            let r = supers[n as usize].rect;
            let next = if !contains(r.y0, r.y1, p[1], m[1]) {
                if p[1] < r.y0 || (p[1] == r.y0 && m[1] < 0.0) {
                    LD_DOWN
                } else {
                    RU_UP
                }
            } else if !contains(r.x0, r.x1, p[0], m[0]) {
                if p[0] < r.x0 || (p[0] == r.x0 && m[0] < 0.0) {
                    LD_LEFT
                } else {
                    RU_RIGHT
                }
            } else {
                return Some(n);
            };
            n = supers[n as usize].stitches[next];
            if n == NONE {
                break;
            }
        }
        None
    }
}

/// A world ray with its inverse direction, for the culling slab tests of a
/// ray's many cells (one division per axis per ray, not per test).
#[derive(Clone, Copy, Debug)]
struct SlabRay {
    ray: Ray,
    inv: [f64; 3],
    /// Every direction component is normal (not zero, not subnormal): the
    /// products below cannot be NaN, so the test needs no branch per axis.
    plain: bool,
}

impl SlabRay {
    fn new(r: &Ray) -> Self {
        let (o, d) = (r.origin.to_array(), r.dir.to_array());
        let inv = d.map(|v| 1.0 / v);
        let plain = d.iter().all(|v| v.is_normal())
            && inv.iter().all(|v| v.is_finite())
            && o.iter().all(|v| v.is_finite());
        SlabRay {
            ray: *r,
            inv,
            plain,
        }
    }

    /// The slab test's entry and exit parameters for box `b` (entry above
    /// exit where the ray misses it), for a `plain` ray: no direction
    /// component zero or subnormal, so no product is NaN and no axis needs
    /// a branch.
    #[inline(always)]
    fn plain_slabs(&self, b: &Aabb) -> (f64, f64) {
        let o = self.ray.origin;
        let (x0, x1) = ((b.min.x - o.x) * self.inv[0], (b.max.x - o.x) * self.inv[0]);
        let (y0, y1) = ((b.min.y - o.y) * self.inv[1], (b.max.y - o.y) * self.inv[1]);
        let (z0, z1) = ((b.min.z - o.z) * self.inv[2], (b.max.z - o.z) * self.inv[2]);
        let t0 = max(max(min(x0, x1), min(y0, y1)), min(z0, z1));
        let t1 = min(min(max(x0, x1), max(y0, y1)), max(z0, z1));
        (t0, t1)
    }

    /// `Aabb::ray_interval` by the inverse direction (for the scene box
    /// and the clip's boxes).
    #[inline(always)]
    fn interval(&self, b: &Aabb) -> Option<(f64, f64)> {
        if !self.plain {
            return b.ray_interval(&self.ray);
        }
        let (t0, t1) = self.plain_slabs(b);
        (t0 <= t1).then_some((t0, t1))
    }

    /// Whether the ray's part `[t_in, t_end]` surely misses `hull` (as in
    /// `RegionCells::remote_hull`, on the scale of `scene`). The interval
    /// is widened by a relative 1e-9 so that rounding only ever keeps a
    /// cell.
    fn misses_hull(&self, hull: &Hull, scene: &Aabb, t_in: f64, t_end: f64) -> bool {
        let Some(b) = hull.bounds(scene) else {
            return true;
        };
        match self.interval(&b) {
            None => true,
            Some((b0, b1)) => {
                let pad = (t_in.abs() + t_end.abs()) * 1e-9;
                // NaN compares false: the cell is kept.
                b1 < t_in - pad || b0 > t_end + pad
            }
        }
    }

    /// Whether the ray's part `[t_lo, t_hi]` may meet box `b` (a culling
    /// box, inflated): the ray's interval in the box is widened by a
    /// relative 1e-9 of its own ends, so that a point of the box the
    /// rounding of those ends would leave out is kept. False only where
    /// every point of the ray in the box lies outside `[t_lo, t_hi]`.
    #[inline]
    fn meets_range(&self, b: &Aabb, t_lo: f64, t_hi: f64) -> bool {
        match self.interval(b) {
            None => false,
            Some((b0, b1)) => {
                let pad = (b0.abs() + b1.abs()) * 1e-9;
                // NaN compares false: the box is kept.
                !(b1 + pad < t_lo || b0 - pad > t_hi)
            }
        }
    }

    /// Whether the ray meets box `b`: `Aabb::ray_interval(..).is_some()`
    /// with a multiplication by the inverse for the division. Culling boxes
    /// are inflated (`CsgTree::cull_bounds`), so a rounding difference
    /// cannot cull a box the ray reaches.
    #[inline(always)]
    fn meets(&self, b: &Aabb) -> bool {
        if self.plain {
            let (t0, t1) = self.plain_slabs(b);
            // An empty box has min > max: its slabs cross over, t0 > t1.
            return t0 <= t1;
        }
        self.meets_not_plain(b)
    }

    /// `meets` for a ray with a zero or subnormal direction component:
    /// rare, and out of line so that the walk's loop stays small.
    #[cold]
    #[inline(never)]
    fn meets_not_plain(&self, b: &Aabb) -> bool {
        b.ray_interval(&self.ray).is_some()
    }
}

/// Section 8: per primitive, the last ray it was tested against and the
/// extent in `t` of its crossings (`lo > hi` for none), so a primitive
/// spanning several cells is intersected once; the crossings themselves
/// are in `CellTracer::hits`. A primitive whose (minimal) box the ray
/// misses gets no crossings here too, so the culling slab test is also
/// done once per ray, not once per cell. Kept apart from the crossings
/// (24 bytes, not 48): a cell's first look reads only these.
#[derive(Clone, Copy, Debug)]
struct Mailbox {
    ray: u64,
    lo: f64,
    hi: f64,
}

impl Mailbox {
    /// The mailbox of a primitive that ray `ray` does not cross.
    #[inline(always)]
    fn missed(ray: u64) -> Mailbox {
        Mailbox {
            ray,
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }

    fn of(ray: u64, hits: &PrimHits) -> Mailbox {
        let (lo, hi) = match hits {
            PrimHits::Miss => (f64::INFINITY, f64::NEG_INFINITY),
            PrimHits::Solid { enter, exit } => (enter.t, exit.t),
            PrimHits::Sheet { hits, count } => {
                let h = &hits[..*count as usize];
                h.iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| {
                        (a.min(c.t), b.max(c.t))
                    })
            }
        };
        Mailbox { ray, lo, hi }
    }
}

/// The work of entering a cell and of one intersection test, in the units
/// of the pre-pass's profile (`CellTracer::record_work`). Fitted to the
/// machine: the nodes' busy CPU time against their counts, over 192 nodes
/// of eight renders of the sphereflake at 1024x1024 on 16 and 32 nodes,
/// is 142 ns per test, 38 ns per cell and nothing per mailbox hit
/// (R² 0.88; tests alone explain 0.73).
pub const CELL_WORK: u64 = 1;
pub const TEST_WORK: u64 = 4;

/// The cells accelerator on one thread.
pub struct CellTracer<'a> {
    cs: &'a CellStructure,
    scene: &'a Scene,
    eval: Evaluator,
    mailboxes: Vec<Mailbox>,
    /// Per primitive, its crossings with the ray of its mailbox.
    hits: Vec<PrimHits>,
    /// Per scene node, the last ray whose culling test of an operator is
    /// known, and the answer (a mailbox for operators' boxes).
    op_ray: Vec<u64>,
    op_culled: Vec<bool>,
    /// Unique number of the current ray (mailbox key).
    ray_id: u64,
    /// The last ray walked, with the primitive it leaves (`RayJob::leaving`,
    /// whole-scene index): the same again keeps its mailboxes.
    last_ray: Option<(Ray, Option<PrimId>)>,
    slab: SlabRay,
    /// Per region, the super cell where the last walk there started or
    /// found its hit: where the next ray most likely starts (the next
    /// pixel's, or the shadow rays from the hit).
    /// A third for rays from the eye, the primary rays: the next pixel's
    /// is most likely where this pixel's started, not where its last
    /// secondary ray went.
    hint: [u32; 3],
    pub counters: TraceCounters,
    pub eval_counts: EvalCounts,
    /// Work per super cell, when recording (`record_work`).
    profile: Option<Box<[Vec<u64>; 2]>>,
    /// When recording, the work booked so far over all super cells
    /// (`recorded_total`).
    booked: u64,
    /// When recording for a mapping (`record_work_for`), each super cell's
    /// owner, and the structure as a node that owns nothing holds it (every
    /// cell with content remote, with its hull).
    owners: Option<(Box<[Vec<u16>; 2]>, &'a CellStructure)>,
    /// When recording for a mapping with copies (`record_work_with_copies`):
    /// per super cell of each region, the nodes that hold a copy of it.
    copies: Option<Box<Copies>>,
    /// When recording for a mapping, every move of a ray to another node
    /// (the machine's messages of paths between nodes): the node it left
    /// and the super cell it moved to.
    moves: Vec<Move>,
    /// When recording: the super cell where the last hit of a ray other
    /// than a shadow ray was, where the machine shades it and starts the
    /// rays it spawns.
    spawned_at: Option<(Region, u32)>,
    /// Whether the walk is a shadow ray's (`walk_shadow`).
    shadow_walk: bool,
    /// The current walk is a shadow ray's that may stop at the first cell
    /// where the ray passes through the scene's solid (`walk_shadow`).
    occluding: bool,
    /// The light of the current shadow walk, when `occluding`.
    light: usize,
    /// Per light (at most `SHADOW_CACHE_LIGHTS`; empty beyond), the exposed
    /// solid primitive (`ShadowFacts::exposed`), or the small exposed
    /// solid (`ShadowFacts::solids`), that last stopped a shadow ray toward
    /// it: Haines and Greenberg's shadow cache, as neighbouring shadow rays
    /// are mostly stopped by the same object.
    blockers: Vec<Option<Blocker>>,
    /// The node whose cache the current shadow walk asks and fills: 0, or,
    /// when recording for a mapping, the node the ray is on (as each node
    /// of the machine keeps its own cache), with `blockers` holding one
    /// cache per node.
    cache_node: usize,
    /// The primitive the current job's ray leaves (`Tracer::leaving`): its
    /// whole-scene index, and this structure's, if it holds it.
    leaving: Option<PrimId>,
    leaving_here: Option<PrimId>,
    /// A share's recent answers of `CellStructure::local_primitive` for
    /// `leaving`, by whole-scene index modulo `LOCAL_CACHE`: the rays of
    /// neighbouring pixels leave the same few primitives, and the binary
    /// search over a share's thousands of primitives was a third of a
    /// node's own time per path (`--dim 1`, sphereflake).
    local_cache: [(u32, Option<PrimId>); LOCAL_CACHE],
    /// The scene's lights by x, for `light_at_end`.
    lights: LightsByX,
    /// The light of the current job's shadow rays, if told
    /// (`Tracer::toward`): `light_at_end` need not search for it.
    toward: Option<u16>,
}

/// The scene's lights sorted by x, so that the light a shadow ray ends
/// at is found by a binary search, not a scan: a scene of 2,000 lights
/// shoots 2,000 shadow rays per hit, and the scan made its `--dim 0`
/// render take 26 s where Roth took 0.39 s. Up to `SCAN_LIGHTS` lights
/// are scanned still: the search cost the jagged ball (two lights) 2% of
/// its instructions.
struct LightsByX {
    /// `(x, index)` of every light, by x; empty up to `SCAN_LIGHTS`.
    order: Vec<(f64, u32)>,
    /// The largest magnitude of a light's coordinate.
    reach: f64,
}

/// Lights up to which `light_at_end` scans them all.
const SCAN_LIGHTS: usize = 16;

impl LightsByX {
    /// The bytes of the order kept for `lights` lights (none up to
    /// `SCAN_LIGHTS`), which a node counts in its budget.
    fn bytes_for(lights: usize) -> usize {
        if lights > SCAN_LIGHTS {
            lights * std::mem::size_of::<(f64, u32)>()
        } else {
            0
        }
    }

    fn new(scene: &Scene) -> LightsByX {
        let mut order: Vec<(f64, u32)> = Vec::new();
        if scene.lights.len() > SCAN_LIGHTS {
            order = (scene.lights.iter())
                .enumerate()
                .map(|(i, l)| (l.position.x, i as u32))
                .collect();
            order.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        let reach = (scene.lights.iter())
            .map(|l| l.position.abs().max_element())
            .fold(0.0, f64::max);
        LightsByX { order, reach }
    }
}

/// Entries of `CellTracer::local_cache`.
const LOCAL_CACHE: usize = 64;

/// What stopped the last shadow ray toward a light, for the shadow cache
/// (`CellTracer::blockers`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Blocker {
    /// An exposed solid primitive (`ShadowFacts::is_exposed`).
    Primitive(u32),
    /// A small exposed solid: its root in `ShadowFacts::solids`.
    Solid(u32),
}

/// Lights up to which `CellTracer` keeps a shadow cache. Set when finding
/// a shadow ray's light was a scan of them all; that is now a search
/// beyond `SCAN_LIGHTS`, but a cache for more lights did not pay: 2,000
/// lights over a mirror ball on a box (64x48, `--dim 0`) ran 3.57 M
/// intersection tests with it against 1.25 M without, in the same time
/// (0.48 s against 0.49 s).
const SHADOW_CACHE_LIGHTS: usize = 16;

impl<'a> CellTracer<'a> {
    pub fn new(cs: &'a CellStructure, scene: &'a Scene) -> Self {
        CellTracer {
            cs,
            scene,
            eval: Evaluator::new(),
            mailboxes: vec![Mailbox::of(0, &PrimHits::Miss); scene.primitives.len()],
            hits: vec![PrimHits::Miss; scene.primitives.len()],
            op_ray: vec![0; cs.origin_count],
            op_culled: vec![false; cs.origin_count],
            ray_id: 0,
            last_ray: None,
            slab: SlabRay::new(&Ray::new(Vec3::ZERO, Vec3::Z)),
            hint: [u32::MAX; 3],
            counters: TraceCounters::default(),
            eval_counts: EvalCounts::default(),
            profile: None,
            booked: 0,
            owners: None,
            copies: None,
            moves: Vec::new(),
            spawned_at: None,
            shadow_walk: false,
            occluding: false,
            light: 0,
            blockers: if cs.shadows.cache && scene.lights.len() <= SHADOW_CACHE_LIGHTS {
                vec![None; scene.lights.len()]
            } else {
                Vec::new()
            },
            cache_node: 0,
            leaving: None,
            leaving_here: None,
            local_cache: [(u32::MAX, None); LOCAL_CACHE],
            lights: LightsByX::new(scene),
            toward: None,
        }
    }

    /// The first boundary of the subtree rooted at `subtree` with
    /// `t_lo < t < t_end`.
    ///
    /// Only the window `[t_lo, t_end]` matters: whether a point of the ray
    /// is in a CSG solid depends only on which primitives contain it, so a
    /// primitive's span (or surface crossing) that lies wholly outside the
    /// window can be left out of the evaluation without changing any
    /// boundary inside it, nor which of several coincident ends is kept
    /// (ends at the same `t` are all kept or all left out). Most operands
    /// of a cell's subtree are then empty, and the evaluation short-cuts
    /// (empty operands of unions are dropped, an empty first operand of a
    /// difference or any empty operand of an intersection empties it).
    #[inline(always)]
    fn in_cell(&mut self, subtree: u32, ray: &Ray, t_lo: f64, t_end: f64) -> Option<Hit> {
        let cs = self.cs;
        let id = self.ray_id;
        let prims = &self.scene.primitives;
        let slab = &self.slab;
        let counters = &mut self.counters;
        let mailboxes = &mut self.mailboxes;
        let all_hits = &mut self.hits;
        counters.subtree_evaluations += 1;
        // First look: the leaves whose crossings reach into the window, by
        // their mailboxes' extents (section 8), filling the mailboxes of
        // leaves the ray has not met yet: the culling test against the
        // leaf's minimal box, and the intersection if it passes. None: the
        // subtree has no boundary there. One: the subtree is that leaf, or
        // nothing, by the operators above it (see `SubtreeLeaf`). The
        // evaluator runs only for two or more. (A surface's crossings may
        // straddle the window without one inside it: then the lone leaf
        // gives nothing, or the evaluator runs for nothing; both exact.)
        let [a, b] = cs.leaf_span[subtree as usize];
        let mut lone: Option<&SubtreeLeaf> = None;
        let mut several = false;
        // A shadow walk's stop (`walk_shadow`).
        let mut blocked = None;
        // Counted in locals and added once: the intersection call in the
        // loop would otherwise make every count a load and a store.
        let (mut looked, mut met, mut tests, mut culled) = (0u64, 0u64, 0u64, 0u64);
        for l in &cs.subtree_leaves[a as usize..b as usize] {
            let p = l.prim as usize;
            let mb = &mut mailboxes[p];
            looked += 1;
            if mb.ray == id {
                met += 1;
            } else if slab.meets(&l.cull) {
                tests += 1;
                let hits = prims[p].intersect(ray);
                *mb = Mailbox::of(id, &hits);
                if matches!(hits, PrimHits::Miss) {
                    // As a culled leaf (below); its stale crossings stay,
                    // behind an empty extent.
                    continue;
                }
                all_hits[p] = hits;
            } else {
                // No crossings: nothing in the window (the test below
                // would say so, unless `t_lo` is -inf).
                culled += 1;
                *mb = Mailbox::missed(id);
                continue;
            }
            if mb.hi >= t_lo && mb.lo <= t_end {
                if self.occluding && l.exposed {
                    blocked = passes_through(&all_hits[p], PrimId(l.prim), t_lo, t_end);
                    if blocked.is_some() {
                        break;
                    }
                }
                if lone.is_some() {
                    several = true;
                    break;
                }
                lone = Some(l);
            }
        }
        self.eval_counts.nodes_visited += looked;
        self.eval_counts.nodes_culled += culled;
        counters.mailbox_hits += met;
        counters.intersection_tests += tests;
        if blocked.is_some() {
            return blocked;
        }
        if !several {
            let l = lone.filter(|l| l.lone_is_result)?;
            let p = l.prim as usize;
            return first_crossing(&all_hits[p], PrimId(l.prim), t_lo, t_end);
        }
        self.evaluate_cell(subtree, ray, t_lo, t_end)
    }

    /// `in_cell`'s evaluation of a subtree with two or more leaves in the
    /// window. Out of line, so that the walk's loop around the first look
    /// keeps its values in registers.
    #[inline(never)]
    fn evaluate_cell(&mut self, subtree: u32, ray: &Ray, t_lo: f64, t_end: f64) -> Option<Hit> {
        let cs = self.cs;
        let tree = &cs.subtrees;
        let id = self.ray_id;
        let prims = &self.scene.primitives;
        let slab = &self.slab;
        let counters = &mut self.counters;
        let mailboxes = &mut self.mailboxes;
        let all_hits = &mut self.hits;
        // A leaf's crossings in the window, through its mailbox; the
        // culling test against its minimal box only when the mailbox is
        // empty.
        let eval_counts = &mut self.eval_counts;
        let leaf = |n: NodeId, p: PrimId| -> PrimHits {
            let mb = &mut mailboxes[p.index()];
            eval_counts.nodes_visited += 1;
            if mb.ray == id {
                counters.mailbox_hits += 1;
            } else {
                let hits = if slab.meets(&tree.cull_bounds[n.index()]) {
                    counters.intersection_tests += 1;
                    prims[p.index()].intersect(ray)
                } else {
                    eval_counts.nodes_culled += 1;
                    PrimHits::Miss
                };
                *mb = Mailbox::of(id, &hits);
                if !matches!(hits, PrimHits::Miss) {
                    all_hits[p.index()] = hits;
                }
            }
            if mb.hi < t_lo || mb.lo > t_end {
                PrimHits::Miss
            } else {
                window(&all_hits[p.index()], t_lo, t_end)
            }
        };
        let origin = &cs.origin;
        let (op_ray, op_culled) = (&mut self.op_ray, &mut self.op_culled);
        self.eval
            .evaluate_with(tree, NodeId(subtree), leaf, |n| {
                let o = origin[n.index()] as usize;
                if op_ray[o] != id {
                    op_ray[o] = id;
                    op_culled[o] = !slab.meets(&tree.cull_bounds[n.index()]);
                }
                op_culled[o]
            })
            .first_between(t_lo, t_end)
            .map(Hit::from)
    }
}

/// A primitive's crossings without what lies wholly outside `[t_lo, t_end]`
/// (see `CellTracer::in_cell`).
#[inline]
fn window(hits: &PrimHits, t_lo: f64, t_end: f64) -> PrimHits {
    match *hits {
        PrimHits::Solid { enter, exit } if exit.t < t_lo || enter.t > t_end => PrimHits::Miss,
        PrimHits::Sheet { hits, count } => {
            let mut out = [hits[0]; 2];
            let mut n = 0;
            for c in &hits[..count as usize] {
                if c.t >= t_lo && c.t <= t_end {
                    out[n] = *c;
                    n += 1;
                }
            }
            if n == 0 {
                PrimHits::Miss
            } else {
                PrimHits::Sheet {
                    hits: out,
                    count: n as u8,
                }
            }
        }
        h => h,
    }
}

/// For a shadow walk (`CellTracer::walk_shadow`): a hit standing for the
/// ray's passing through an exposed solid leaf inside the window `[t_lo,
/// t_end]`, over more than rounding can blur (a relative 1e-9 of the
/// window's ends), so the ray surely has points inside the scene's solid
/// there.
#[inline]
fn passes_through(hits: &PrimHits, p: PrimId, t_lo: f64, t_end: f64) -> Option<Hit> {
    let PrimHits::Solid { enter, exit } = hits else {
        return None;
    };
    inside_over(enter.t, exit.t, t_lo, t_end).then_some(Hit {
        t: max(enter.t, t_lo),
        prim: p,
        part: enter.part,
        flip: false,
    })
}

/// Whether a ray inside a solid over `[enter, exit]` is inside it over
/// more than rounding of `[t_lo, t_end]` (`passes_through`).
#[inline]
fn inside_over(enter: f64, exit: f64, t_lo: f64, t_end: f64) -> bool {
    let (a, b) = (max(enter, t_lo), min(exit, t_end));
    b - a > (t_lo.abs() + t_end.abs()) * 1e-9
}

/// Whether one primitive has a crossing with `t_lo <= t <= t_end` (for a
/// surface, `t_lo < t`): a boundary the walk over that range might find.
/// A surface crossed at `t_lo` exactly has no inside to change anything
/// after it, and the walk reports only hits after `t_lo`; a solid entered
/// there may still hold the ray in it (`passes_through`).
#[inline]
fn crosses(hits: &PrimHits, t_lo: f64, t_end: f64) -> bool {
    let on = |c: &Crossing| c.t >= t_lo && c.t <= t_end;
    match hits {
        PrimHits::Miss => false,
        PrimHits::Solid { enter, exit } => on(enter) || on(exit),
        PrimHits::Sheet { hits, count } => hits[..*count as usize]
            .iter()
            .any(|c| c.t > t_lo && c.t <= t_end),
    }
}

/// The first of one primitive's crossings with `t_lo < t < t_end`: what
/// `SpanList::first_between` gives on the list `push_prim_hits` makes.
#[inline]
fn first_crossing(hits: &PrimHits, p: PrimId, t_lo: f64, t_end: f64) -> Option<Hit> {
    let hit = |c: &Crossing| Hit {
        t: c.t,
        prim: p,
        part: c.part,
        flip: false,
    };
    let inside = |c: &Crossing| c.t > t_lo && c.t < t_end;
    match hits {
        PrimHits::Miss => None,
        // enter.t < exit.t: the entry first.
        PrimHits::Solid { enter, exit } => [enter, exit].into_iter().find(|c| inside(c)).map(hit),
        // Sorted by t.
        PrimHits::Sheet { hits, count } => {
            hits[..*count as usize].iter().find(|c| inside(c)).map(hit)
        }
    }
}

/// Minimum and maximum of numbers that are not NaN (one instruction each,
/// where `f64::min` and `f64::max` also handle NaN).
#[inline(always)]
fn min(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}

#[inline(always)]
fn max(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

/// `q` clamped to `[lo, hi]` (`lo <= hi`); NaN stays NaN, as with
/// `f64::clamp`, without its check of the bounds.
#[inline(always)]
fn clamp(q: f64, lo: f64, hi: f64) -> f64 {
    if q < lo {
        lo
    } else if q > hi {
        hi
    } else {
        q
    }
}

/// The largest float below `t`, so that `(prev_float(t), x)` includes `t`.
#[inline(always)]
fn prev_float(t: f64) -> f64 {
    // The common case, a positive normal or subnormal `t`, is one less in
    // its bits; `next_down` handles the rest (zero, negatives).
    if t > 0.0 && t < f64::INFINITY {
        f64::from_bits(t.to_bits() - 1)
    } else if t.is_finite() {
        t.next_down()
    } else {
        t
    }
}

impl CellStructure {
    /// The front super cell a primary ray (from the eye) stays in: the
    /// pixel area its sample belongs to (section 3.2).
    pub fn primary_super_cell(&self, ray: &Ray) -> u32 {
        self.primary_super_cell_from(ray, u32::MAX)
    }

    /// `primary_super_cell`, trying super cell `hint` first (and, in a
    /// share, finding the super cell from it).
    pub fn primary_super_cell_from(&self, ray: &Ray, hint: u32) -> u32 {
        let cam = self.view.ray(ray);
        let rr = RegionRay::new(Region::Front, cam);
        let (sx, sy, _) = cam.screen_at(Region::Front, 0.0);
        self.region(Region::Front)
            .super_cell_at([sx, sy], [rr.m[0], rr.m[1]], hint)
    }
}

impl<'a> CellTracer<'a> {
    /// True when a primary job's super cell holds no primitive, so its
    /// sample is background without tracing (section 3.2's pixel areas).
    pub fn primary_is_background(cs: &CellStructure, ray: &Ray) -> bool {
        cs.region(Region::Front)
            .super_cell_is_empty(cs.primary_super_cell(ray))
    }

    /// `primary_is_background` for this tracer's next primary ray, found
    /// from the super cell where its last primary ray started (most often
    /// the same, the next pixel's), not by descending the BSP; the walk
    /// that traces the ray then starts there at once.
    pub fn skips_primary(&mut self, ray: &Ray) -> bool {
        let s = self.cs.primary_super_cell_from(ray, self.hint[2]);
        self.hint[2] = s;
        self.cs.region(Region::Front).super_cell_is_empty(s)
    }

    /// Bytes a tracer over `cs` and `scene` keeps: a mailbox and the
    /// crossings per primitive, an operator mailbox per scene node, a
    /// shadow cache entry per light, the lights sorted for the search
    /// (`LightsByX`), and the cache of local indices.
    pub fn bytes_for(cs: &CellStructure, scene: &Scene) -> usize {
        scene.primitives.len() * Self::BYTES_PER_PRIMITIVE
            + cs.origin_count * Self::BYTES_PER_ORIGIN
            + scene.lights.len() * std::mem::size_of::<Option<Blocker>>()
            + LightsByX::bytes_for(scene.lights.len())
            + std::mem::size_of::<[(u32, Option<PrimId>); LOCAL_CACHE]>()
    }

    /// A tracer's bytes per primitive of its scene and per operator
    /// mailbox of its structure (`bytes_for`).
    pub const BYTES_PER_PRIMITIVE: usize =
        std::mem::size_of::<Mailbox>() + std::mem::size_of::<PrimHits>();
    pub const BYTES_PER_ORIGIN: usize = std::mem::size_of::<u64>() + std::mem::size_of::<bool>();

    /// Starts recording, per super cell of each region, the work done in
    /// its cells (a cell entered counts `CELL_WORK`, an intersection test
    /// or a mailbox hit `TEST_WORK`): the machine's cost-estimating
    /// pre-pass.
    pub fn record_work(&mut self) {
        self.profile = Some(Box::new(
            Region::BOTH.map(|r| vec![0u64; self.cs.region(r).supers.len()]),
        ));
        self.booked = 0;
    }

    /// `record_work`, walking as the machine would with super cells owned
    /// by `owner` (`machine::mapping`): a ray that reaches a cell another
    /// node owns moves there and resumes with cold mailboxes (a new ray
    /// number), so the primitives it met before count again, as tests,
    /// where the machine will test them again. As on the machine, a ray
    /// whose part in such a cell misses the hull of the cell's content
    /// walks on without moving (`walk`); `skeleton` is the structure as a
    /// node that owns nothing holds it (`restrict`), which has every hull.
    pub fn record_work_for(&mut self, owner: [Vec<u16>; 2], skeleton: &'a CellStructure) {
        self.record_work();
        if !self.blockers.is_empty() {
            let nodes = owner
                .iter()
                .flatten()
                .map(|&o| o as usize + 1)
                .max()
                .unwrap_or(1);
            self.blockers = vec![None; self.scene.lights.len() * nodes];
        }
        self.owners = Some((Box::new(owner), skeleton));
    }

    /// `record_work_for`, where nodes also hold copies of super cells they
    /// do not own (`machine::replicas`): a ray that reaches a cell its node
    /// holds a copy of stays there, and its work there is the node's
    /// (booked to the super cell it was on). Every ray but a primary one
    /// starts on the node where its parent's hit was.
    pub fn record_work_with_copies(
        &mut self,
        owner: [Vec<u16>; 2],
        skeleton: &'a CellStructure,
        copies: Copies,
    ) {
        self.record_work_for(owner, skeleton);
        self.copies = Some(Box::new(copies));
    }

    /// The moves of rays between nodes recorded since `record_work_for`.
    pub fn recorded_moves(&self) -> &[Move] {
        &self.moves
    }

    /// The work recorded since `record_work`.
    pub fn recorded_work(&self) -> Option<&[Vec<u64>; 2]> {
        self.profile.as_deref()
    }

    /// The work recorded since `record_work`, over all super cells: what
    /// the rays traced between two reads of it did, wherever they went.
    pub fn recorded_total(&self) -> u64 {
        self.booked
    }
}

/// Where a walk stands when it reaches a cell held by another node: the
/// cell, and the parameter at which the ray entered it. With the ray and
/// its `t_min`/`t_max`, everything else of the walk is recomputed from it,
/// identically on every node.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WalkPoint {
    pub region: Region,
    pub super_cell: u32,
    pub cell: u32,
    pub t_in: f64,
    /// Whether the walk keeps to the box of all but the widest primitive
    /// (`WideClip`): decided where it started, carried so that no other
    /// node tests again.
    pub clipped: bool,
}

/// How a walk through the cells a tracer holds ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Walk {
    /// The nearest boundary.
    Hit(Hit),
    /// Nothing below `t_max`.
    Miss,
    /// The ray reached a cell whose subtree is on another node
    /// (`CellStructure::restrict`); the walk resumes there.
    Remote(WalkPoint),
}

impl CellTracer<'_> {
    /// `walk` for a shadow ray: whether it meets a surface before `t_max`
    /// (its light), as `Walk::Hit` of some surface it crosses, not always
    /// the nearest. The nearest is what a shadow ray needs only to be
    /// attenuated by glass; where the ray meets no material that lets
    /// light through, any surface stops it. So the walk stops at the first
    /// cell where the ray passes through an exposed leaf
    /// (`SubtreeLeaf::exposed`) of the cell's subtree, which may lie before
    /// the cell of the nearest surface, and saves the evaluation too; and
    /// before walking, it tries the primitive that stopped the last shadow
    /// ray toward the same light (the shadow cache), if that is exposed in
    /// the scene's tree (`ShadowFacts::exposed`).
    ///
    /// Why that is exact: inside an exposed leaf within the cell is inside
    /// the cell's subtree's solid, which within the cell is the scene's
    /// (Algorithm 3 keeps whatever matters there); inside a primitive
    /// exposed in the scene's tree is inside the scene's solid anywhere.
    /// The light lies surely outside the solid (`ShadowFacts::clear_lights`),
    /// so the ray is outside it at `t_max`: between the two it crosses the
    /// solid's boundary, which the walk of `walk` would find (or one before
    /// it), and every surface the ray meets is opaque, since it meets no
    /// box of a primitive that transmits. Otherwise (a light inside or near
    /// the solid, a glass box on the way, more than `MAX_GLASS` such
    /// primitives) this is `walk`.
    ///
    /// Either way, a ray that ends at a light is walked only up to the ball
    /// around the light that no primitive's minimal box reaches
    /// (`ShadowFacts::free_radius`): outside its minimal box a primitive
    /// changes nothing (Algorithm 1), so no boundary lies in that ball,
    /// and the walk over what is left finds what the whole walk would.
    pub fn walk_shadow(
        &mut self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        from: Option<WalkPoint>,
    ) -> Walk {
        self.shadow_walk = true;
        let walk = self.walk_shadow_inner(ray, t_min, t_max, from);
        self.shadow_walk = false;
        walk
    }

    fn walk_shadow_inner(
        &mut self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        from: Option<WalkPoint>,
    ) -> Walk {
        // The stretch next to the light, where no primitive is, is left
        // out of the walk (`ShadowFacts::free_radius`).
        let end = self.light_at_end(ray, t_max);
        let t_walk = end.map_or(t_max, |(i, tol)| self.short_of_light(ray, t_max, i, tol));
        if t_walk.partial_cmp(&t_min) != Some(std::cmp::Ordering::Greater) {
            return Walk::Miss;
        }
        let Some(light) = end
            .map(|(i, _)| i)
            .filter(|&i| self.takes_short(ray, t_min, t_max, i))
        else {
            return self.walk(ray, t_min, t_walk, from);
        };
        self.occluding = true;
        self.light = light;
        if from.is_none()
            && self.profile.is_none()
            && let Some(h) = self.cached_blocker(ray, t_min, t_max)
        {
            self.occluding = false;
            return Walk::Hit(h);
        }
        let walk = self.walk(ray, t_min, t_walk, from);
        self.occluding = false;
        // A stop by a primitive the cache may not keep empties its entry:
        // the rays after this one are likelier stopped by the same.
        if let Walk::Hit(h) = &walk
            && !self.blockers.is_empty()
        {
            let facts = &self.cs.shadows;
            let keep =
                if facts.is_exposed(h.prim.0) && self.scene.primitives[h.prim.index()].is_solid() {
                    Some(Blocker::Primitive(h.prim.0))
                } else if self.profile.is_none() {
                    facts.solid_of(h.prim.0).map(Blocker::Solid)
                } else {
                    // The pre-pass models the primitives' cache alone:
                    // the mapping balances on it, and with the solids'
                    // too it balanced worse (`docs/performance-log.md`,
                    // session 41).
                    None
                };
            let lights = self.scene.lights.len();
            self.blockers[self.cache_node * lights + light] = keep;
        }
        walk
    }

    /// The light a ray over `(.., t_max)` ends at, up to the rounding of
    /// its direction (for a shadow ray, the light's position less the
    /// ray's origin), if it ends at one, with how far from the light its
    /// end may be and still be taken to end there.
    ///
    /// The nearest light, if within its tolerance: of the lights in index
    /// order, the first at the least distance. Where there are many
    /// (`LightsByX`), only those whose x lies within twice the largest
    /// tolerance of the end's are looked at: a light farther off is
    /// farther than its own tolerance, and so are all lights if it is the
    /// nearest, so either way it changes nothing.
    ///
    /// A ray whose light the tracer was told (`toward`) ends at that one
    /// if within its tolerance (where lights coincide, the first of equals
    /// would have the same facts, `ShadowFacts`, by their position: only
    /// the shadow cache's entry differs, which changes no answer).
    fn light_at_end(&self, ray: &Ray, t_max: f64) -> Option<(usize, f64)> {
        if !t_max.is_finite() {
            return None;
        }
        let end = ray.at(t_max);
        let from = ray.origin.abs().max_element();
        let lights = &self.scene.lights;
        let d2 = |i: usize| (lights[i].position - end).length_squared();
        let told = self
            .toward
            .map(usize::from)
            .filter(|&i| i < lights.len())
            .map(|i| (i, d2(i)));
        let (i, d2) = if let Some(told) = told {
            told
        } else if self.lights.order.is_empty() {
            (0..lights.len())
                .map(|i| (i, d2(i)))
                .min_by(|a, b| a.1.total_cmp(&b.1))?
        } else {
            let window = 2e-9 * (self.lights.reach + from);
            let order = &self.lights.order;
            let lo = order.partition_point(|&(x, _)| x < end.x - window);
            order[lo..]
                .iter()
                .take_while(|&&(x, _)| x <= end.x + window)
                .map(|&(_, i)| (i as usize, d2(i as usize)))
                // The least distance, and of equals the first light.
                .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))?
        };
        let at = lights[i].position;
        let tol = 1e-9 * (at.abs().max_element() + from);
        (d2 <= tol * tol).then_some((i, tol))
    }

    /// Where a ray ending at light `i` at `t_max` enters the ball around
    /// the light that no primitive reaches (`ShadowFacts::free_radius`,
    /// less `tol`, the tolerance of its end, `light_at_end`): past that,
    /// it meets nothing.
    fn short_of_light(&self, ray: &Ray, t_max: f64, i: usize, tol: f64) -> f64 {
        let r = self.cs.shadows.free_radius.get(i).copied().unwrap_or(0.0) - tol;
        let cut = t_max - r / ray.dir.length();
        if r > 0.0 && cut.is_finite() && cut < t_max {
            cut
        } else {
            t_max
        }
    }

    /// Whether `walk_shadow` may take a ray over `(t_min, t_max)` that
    /// ends at light `i` short: the light lies surely outside the solid,
    /// and the ray meets no box of a primitive that lets light through.
    fn takes_short(&self, ray: &Ray, t_min: f64, t_max: f64, i: usize) -> bool {
        let facts = &self.cs.shadows;
        let Some(glass) = facts.glass.as_ref() else {
            return false;
        };
        let meets = |g: &Aabb| {
            g.ray_interval(ray)
                .is_some_and(|(a, b)| b >= t_min && a <= t_max)
        };
        facts.clear_lights[i] && !glass.iter().any(meets)
    }

    /// The shadow cache's answer for a shadow walk's ray: a hit if it
    /// passes through the primitive or small solid that stopped the last
    /// shadow ray toward its light (`walk_shadow`). A ray that leaves it
    /// is not asked (`RayJob::leaving`: the walk leaves that primitive
    /// out).
    fn cached_blocker(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        let lights = self.scene.lights.len();
        match (*self.blockers.get(self.cache_node * lights + self.light)?)? {
            Blocker::Primitive(p) => {
                if self.leaving_here == Some(PrimId(p)) {
                    return None;
                }
                self.counters.intersection_tests += 1;
                let hits = self.scene.primitives[p as usize].intersect(ray);
                passes_through(&hits, PrimId(p), t_min, t_max)
            }
            Blocker::Solid(root) => {
                let facts = &self.cs.shadows;
                if self.leaving_here.and_then(|p| facts.solid_of(p.0)) == Some(root) {
                    return None;
                }
                // Its span list by Roth's evaluation of its few leaves.
                let prims = &self.scene.primitives;
                let mut tests = 0;
                let spans = self.eval.evaluate(
                    &facts.solids,
                    NodeId(root),
                    ray,
                    true,
                    &mut self.eval_counts,
                    |p| {
                        tests += 1;
                        prims[p.index()].intersect(ray)
                    },
                );
                self.counters.intersection_tests += tests;
                // Inside it over more than rounding, and reported at an end
                // of that stretch on the ray's range: a boundary there lies
                // in its primitive's minimal box, which no transmitting
                // primitive's meets on a short walk (`takes_short`), so the
                // shader sees an opaque stop. (An end behind the ray's start
                // may be a glass cut face the walk never meets; a solid that
                // holds the whole range is left to the walk.)
                let s = spans
                    .spans
                    .iter()
                    .find(|s| inside_over(s.enter.t, s.exit.t, t_min, t_max))?;
                let end = if s.enter.t > t_min {
                    s.enter
                } else if s.exit.t < t_max {
                    s.exit
                } else {
                    return None;
                };
                Some(Hit::from(end))
            }
        }
    }

    /// The walk of section 7 for the boundaries with `t_min < t < t_max`,
    /// from the ray's start (`from` = None) or resumed at a cell another
    /// node stopped at. On a whole structure it never returns `Remote`, and
    /// a walk split over several nodes visits the same cells with the same
    /// `t` as one walk, so it finds the same boundary.
    pub fn walk(&mut self, ray: &Ray, t_min: f64, t_max: f64, from: Option<WalkPoint>) -> Walk {
        // A new ray number unless this is the same ray again (shadow rays
        // ask repeatedly, past each surface they cross; a mailbox keyed by
        // an equal ray holds that ray's answers, so reuse is exact).
        if self.last_ray != Some((*ray, self.leaving)) {
            self.last_ray = Some((*ray, self.leaving));
            self.slab = SlabRay::new(ray);
            self.next_ray_id();
        }
        // Section 3: the cells partition the space bounding the scene, and
        // nothing lies outside it. The ray is followed only over its part
        // inside that box (padded in t, so rounding cannot cut a boundary
        // off); a ray that misses it meets nothing.
        let Some((mut b0, mut b1)) = self.slab.interval(&self.cs.scene_box) else {
            return Walk::Miss;
        };
        // The shadow cache is asked where a shadow ray starts, on the node
        // that made it, not again where its walk resumes. A plain walk asks
        // in `walk_shadow`; a recording one here, to book the test to the
        // super cell, so the node, where the ray starts.
        let recording = self.profile.is_some();
        let mut ask_cache =
            recording && self.occluding && from.is_none() && !self.blockers.is_empty();
        // And only inside the box of all primitives but the widest, when it
        // crosses none of that one's boundaries over its range (`WideClip`).
        // Decided where the walk starts, by a test outside the mailboxes,
        // and carried to the nodes it resumes on.
        let (mut clipped, mut clip_test) = (false, false);
        if self.cs.clip.is_some() {
            let rest;
            (clipped, clip_test, rest) = self.clip(ray, t_min, t_max, from);
            if clipped {
                let Some((r0, r1)) = rest else {
                    return self.clipped_out(ray, (t_min, t_max), ask_cache, clip_test);
                };
                (b0, b1) = (b0.max(r0), b1.min(r1));
            }
        }
        let pad = (b0.abs() + b1.abs()) * 1e-9;
        let (t_min_box, t_max_box) = (t_min.max(b0 - pad), t_max.min(b1 + pad));
        if t_min_box.partial_cmp(&t_max_box) != Some(std::cmp::Ordering::Less) {
            return self.clipped_out(ray, (t_min, t_max), ask_cache, clip_test);
        }
        let cam = self.cs.view.ray(ray);
        let mut order = [Region::Front, Region::Back];
        if cam.d.z > 0.0 {
            order.swap(0, 1);
        }
        let mut from = from;
        // Recording for a mapping: the node the ray is on. A clipped walk
        // other than a primary ray's starts where its parent's hit was,
        // which need not hold its first cell, far from the ray's origin.
        // (Any other starts in or next to its parent's cell, and is taken
        // to start on its first cell's node; but where nodes hold copies,
        // that cell may be a copy on the parent's node: there it starts.)
        let primary = recording && ray.origin == self.cs.view.eye;
        let mut on = match (&self.owners, self.spawned_at) {
            (Some((owners, _)), Some((r, s))) if (clipped || self.copies.is_some()) && !primary => {
                Some(OnNode {
                    node: owners[r as usize][s as usize],
                    region: r,
                    super_cell: s,
                })
            }
            _ => None,
        };
        let first = from.map_or(0, |p| usize::from(order[0] != p.region));
        for &region in &order[first..] {
            let (lo, hi) = cam.region_interval(region);
            let lo = lo.max(t_min_box);
            let hi = hi.min(t_max_box);
            if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
                continue;
            }
            let rc = self.cs.region(region);
            let rr = RegionRay::new(region, cam);
            let slot = if region == Region::Front && ray.origin == self.cs.view.eye {
                2
            } else {
                region as usize
            };
            let (mut s, mut k, mut t_in) = match from.take_if(|p| p.region == region) {
                Some(p) => (p.super_cell, p.cell, p.t_in),
                None => {
                    let (s, k) = rc.locate(&rr, lo, self.hint[slot]);
                    (s, k, lo)
                }
            };
            self.hint[slot] = s;
            // The machine asks the cache before it walks, so before the
            // clip's test.
            if ask_cache {
                ask_cache = false;
                // On the node the ray starts on: with copies, where its
                // parent's hit was.
                let (r0, s0) = on
                    .filter(|_| self.copies.is_some())
                    .map_or((region, s), |o| (o.region, o.super_cell));
                if let Some(h) = self.recorded_cache_test(ray, (t_min, t_max), r0, s0) {
                    return Walk::Hit(h);
                }
            }
            if recording && clip_test {
                // Made where the ray was made: a primary ray on the owner
                // of its pixel's super cell, any other where its parent's
                // hit was.
                clip_test = false;
                match self.spawned_at.filter(|_| !primary) {
                    Some((r0, s0)) => self.book_test(r0, s0),
                    None => self.book_test(region, s),
                }
            }
            // The walk is monotone in every screen axis and depth, so it
            // ends; the guard only turns a bug into a miss, never a hang.
            let mut guard = rc.cell_count() + 2;
            loop {
                guard -= 1;
                debug_assert!(guard > 0, "cell walk did not end");
                if guard == 0 {
                    break;
                }
                let subtree = rc.subtree[k as usize];
                let (t_out, face) = rc.leave(&rr, s, k, t_in);
                let t_end = t_out.min(hi);
                // A cell held elsewhere is walked through here when the
                // ray's part in it misses the hull of its content: the
                // owner would find nothing, and the ray saves a message.
                // (`meets_remote` tests `is_remote` too; tested here first,
                // the call is skipped for the cells a walk holds, and the
                // walk runs 0.3% fewer instructions than with the test
                // inlined, 1.6% fewer than with only the hull out of line.)
                if is_remote(subtree) && self.meets_remote(rc, k, t_in, t_end) {
                    return Walk::Remote(WalkPoint {
                        region,
                        super_cell: s,
                        cell: k,
                        t_in,
                        clipped,
                    });
                }
                self.counters.cells_visited += 1;
                let t_lo = || t_min.max(prev_float(t_in));
                let hit = if recording {
                    self.recorded_step(&mut on, region, s, k, ray, t_in, (t_lo(), t_end))
                } else if subtree < REMOTE && t_end >= t_in {
                    self.in_cell(subtree, ray, t_lo(), t_end)
                } else {
                    None
                };
                if let Some(h) = hit {
                    // A hit is in a cell searched here (never one walked
                    // through), so booked to its own super cell, or, in a
                    // copy, to the one its node's walk is booked to.
                    if recording && !self.shadow_walk {
                        self.spawned_at =
                            Some(on.map_or((region, s), |o| (o.region, o.super_cell)));
                    }
                    self.hint[slot] = s;
                    if let Some(o) = on {
                        // The node that found it fills its cache.
                        self.cache_node = o.node as usize;
                    }
                    return Walk::Hit(h);
                }
                // Past the end of the ray's part in the region (or NaN).
                if t_out.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
                    break;
                }
                match rc.enter_next(&rr, s, k, t_out, face) {
                    Some((s2, k2)) => {
                        s = s2;
                        k = k2;
                        t_in = t_out;
                    }
                    _ => break,
                }
            }
        }
        if recording {
            return self.clipped_out(ray, (t_min, t_max), ask_cache, clip_test);
        }
        Walk::Miss
    }

    /// Whether a walk is clipped (`WideClip`), whether an intersection test
    /// decided it here (not carried by `from`, nor settled by the box or
    /// the mailbox), and the ray's interval in the box it is clipped to.
    /// Out of line: most scenes have no clip, and their walks run faster
    /// without this code inside.
    #[inline(never)]
    fn clip(
        &mut self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        from: Option<WalkPoint>,
    ) -> (bool, bool, Option<(f64, f64)>) {
        let Some(c) = &self.cs.clip else {
            return (false, false, None);
        };
        let (clipped, tested) = match from {
            Some(p) => (p.clipped, false),
            // The ray leaves it: crosses none of its boundaries.
            None if self.leaving == Some(c.global) => (true, false),
            // A ray whose range misses the primitive's (inflated) box
            // crosses none of its boundaries there, and needs no test:
            // most shadow and reflected rays above a ground.
            None if !self.slab.meets_range(&c.cull, t_min, t_max) => (true, false),
            // The same ray again (a shadow ray past a surface it crossed):
            // its crossings are in the primitive's mailbox.
            // (Crossings are kept only for a primitive the ray meets: a
            // mailbox of a culled one has an empty extent and stale hits.)
            None if c.id != NOT_HELD && self.mailboxes[c.id as usize].ray == self.ray_id => {
                self.counters.mailbox_hits += 1;
                let mb = self.mailboxes[c.id as usize];
                let met = mb.hi >= t_min && mb.lo <= t_max;
                (
                    !(met && crosses(&self.hits[c.id as usize], t_min, t_max)),
                    false,
                )
            }
            // A ray leaving the ground (a shadow or reflected ray from
            // it): what the test would find is behind the ray's start,
            // known from a part of the test (`Primitive::surely_behind`).
            // Its mailbox says so to the cells the walk still finds it in,
            // as its crossings would: none from `t_min` on (a surface's at
            // `t_min` exactly is no hit after it, nor has it an inside).
            None if c.prim.surely_behind(ray, t_min) => {
                if c.id != NOT_HELD {
                    self.mailboxes[c.id as usize] = Mailbox::missed(self.ray_id);
                }
                (true, false)
            }
            None => {
                self.counters.intersection_tests += 1;
                let hits = c.prim.intersect(ray);
                // Into the mailbox (section 8), as a cell's first look
                // would fill it: a ray that crosses the primitive is not
                // clipped, and its walk meets it again.
                if c.id != NOT_HELD {
                    self.mailboxes[c.id as usize] = Mailbox::of(self.ray_id, &hits);
                    self.hits[c.id as usize] = hits;
                }
                (!crosses(&hits, t_min, t_max), true)
            }
        };
        let rest = if clipped {
            self.slab.interval(&c.rest)
        } else {
            None
        };
        (clipped, tested, rest)
    }

    /// The end of a walk that reached no cell (or whose tests are not yet
    /// booked): when recording, the tests the machine makes before it walks
    /// (the cache's, the clip's) are booked where the ray was made.
    #[inline(never)]
    fn clipped_out(
        &mut self,
        ray: &Ray,
        range: (f64, f64),
        ask_cache: bool,
        clip_test: bool,
    ) -> Walk {
        if self.profile.is_some()
            && let Some((r, s)) = self.spawned_at
        {
            if ask_cache && let Some(h) = self.recorded_cache_test(ray, range, r, s) {
                return Walk::Hit(h);
            }
            if clip_test {
                self.book_test(r, s);
            }
        }
        Walk::Miss
    }
}

impl CellTracer<'_> {
    /// Whether cell `k` of `rc` is held elsewhere and the ray's part in it
    /// (`t_in` to `t_end`) meets the hull of its content: where a walk
    /// stops and the ray moves to the owner. The machine's walk and the
    /// mapping's pre-pass (`recorded_step`) decide by this one test.
    #[inline]
    fn meets_remote(&self, rc: &RegionCells, k: u32, t_in: f64, t_end: f64) -> bool {
        let t = rc.subtree[k as usize];
        is_remote(t)
            && !self.slab.misses_hull(
                &rc.remote_hull[(t - REMOTE) as usize],
                &self.cs.scene_box,
                t_in,
                t_end,
            )
    }
}

/// Per super cell of each region, the nodes that hold a copy of it
/// (`CellTracer::record_work_with_copies`).
pub type Copies = [Vec<Vec<u16>>; 2];

/// Where the ray is on the machine, when recording for a mapping: its
/// node, and the super cell whose work the node's walk is booked to.
#[derive(Clone, Copy)]
struct OnNode {
    node: u16,
    region: Region,
    super_cell: u32,
}

impl CellTracer<'_> {
    /// The shadow cache's test when recording work, where a shadow walk
    /// starts (super cell `s`): booked to that super cell, with the cache of
    /// the node that owns it, when recording for a mapping. Out of line: it
    /// is the pre-pass's, and the machine's walks never take it.
    #[inline(never)]
    fn recorded_cache_test(
        &mut self,
        ray: &Ray,
        (t_min, t_max): (f64, f64),
        region: Region,
        s: u32,
    ) -> Option<Hit> {
        if let Some((owners, _)) = &self.owners {
            self.cache_node = owners[region as usize][s as usize] as usize;
        }
        // (Only primitives: recording keeps no solid, `walk_shadow`.)
        let blocker = self.cached_blocker(ray, t_min, t_max);
        self.book_test(region, s);
        blocker
    }

    /// The walk's step in cell `k` of super cell `s` when recording work
    /// (`record_work`): the cell's search, as a plain walk does it, and
    /// the work booked to the super cell where the machine does it. When
    /// recording for a mapping (`record_work_for`), as the machine does it
    /// there: the cell is the ray's node's, or its ray part misses the
    /// cell's content (then the node walks through it, and the work is
    /// booked to the super cell the ray is on), or the ray moves to the
    /// owner, with cold mailboxes.
    #[allow(clippy::too_many_arguments)]
    fn recorded_step(
        &mut self,
        on: &mut Option<OnNode>,
        region: Region,
        s: u32,
        k: u32,
        ray: &Ray,
        t_in: f64,
        (t_lo, t_end): (f64, f64),
    ) -> Option<Hit> {
        let subtree = self.cs.region(region).subtree[k as usize];
        let mut through = None;
        let mut book_to = None;
        if let Some((owners, skeleton)) = &self.owners {
            let node = owners[region as usize][s as usize];
            let here = OnNode {
                node,
                region,
                super_cell: s,
            };
            let copied = |o: &OnNode| {
                self.copies
                    .as_ref()
                    .is_some_and(|c| c[region as usize][s as usize].contains(&o.node))
            };
            match *on {
                // Walked and searched on the ray's node, in its copy.
                Some(o) if o.node != node && copied(&o) => book_to = Some((o.region, o.super_cell)),
                Some(o) if o.node != node => {
                    if self.meets_remote(skeleton.region(region), k, t_in, t_end) {
                        self.next_ray_id();
                        self.moves.push(Move {
                            from: o.node,
                            region,
                            super_cell: s,
                        });
                        *on = Some(here);
                    } else {
                        through = Some((o.region, o.super_cell));
                    }
                }
                _ => *on = Some(here),
            }
        }
        let (tests, met) = (self.counters.intersection_tests, self.counters.mailbox_hits);
        let hit = if subtree < REMOTE && t_end >= t_in && through.is_none() {
            self.in_cell(subtree, ray, t_lo, t_end)
        } else {
            None
        };
        let tests = self.counters.intersection_tests - tests;
        // Walking as the machine does, a mailbox hit is a hit there too,
        // nearly free. Without the owners, it stands for the test that
        // the machine mostly repeats on the node a ray crosses to.
        let met = if self.owners.is_some() {
            0
        } else {
            self.counters.mailbox_hits - met
        };
        let (r, b) = through.or(book_to).unwrap_or((region, s));
        self.book(r, b, CELL_WORK + TEST_WORK * (tests + met));
        hit
    }

    /// Books one intersection test to super cell `s` of `region`, when
    /// recording.
    fn book_test(&mut self, region: Region, s: u32) {
        self.book(region, s, TEST_WORK);
    }

    /// Books `work` to super cell `s` of `region`, when recording.
    fn book(&mut self, region: Region, s: u32, work: u64) {
        if let Some(p) = &mut self.profile {
            p[region as usize][s as usize] += work;
            self.booked += work;
        }
    }
}

impl CellTracer<'_> {
    /// A new ray number (a new key for every mailbox, section 8), and the
    /// mailbox of the primitive the ray leaves filled at once: met, and
    /// crossed nowhere (`RayJob::leaving`), so that no cell tests it.
    fn next_ray_id(&mut self) {
        self.ray_id += 1;
        if let Some(m) = self
            .leaving_here
            .and_then(|p| self.mailboxes.get_mut(p.index()))
        {
            *m = Mailbox::missed(self.ray_id);
        }
    }
}

impl Tracer for CellTracer<'_> {
    fn nearest(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        match self.walk(ray, t_min, t_max, None) {
            Walk::Hit(h) => Some(h),
            Walk::Miss => None,
            // A restricted structure is walked with `walk`, never here.
            Walk::Remote(_) => None,
        }
    }

    fn shadow(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        match self.walk_shadow(ray, t_min, t_max, None) {
            Walk::Hit(h) => Some(h),
            Walk::Miss | Walk::Remote(_) => None,
        }
    }

    fn counters(&self) -> TraceCounters {
        self.counters
    }

    fn toward(&mut self, light: Option<u16>) {
        self.toward = light;
    }

    fn leaving(&mut self, prim: Option<PrimId>) {
        // A node asks again for every walk of a path's ray (a shadow ray
        // past each surface it crosses): the share's lookup once.
        if prim != self.leaving {
            self.leaving = prim;
            self.leaving_here = prim.and_then(|g| {
                // A whole structure's indices are the scene's (no search).
                if self.cs.primitive_ids.is_empty() {
                    return Some(g);
                }
                let slot = &mut self.local_cache[g.index() % LOCAL_CACHE];
                if slot.0 != g.0 {
                    *slot = (g.0, self.cs.local_primitive(g));
                }
                slot.1
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{SceneSyntax, parse_scene_str};

    /// `light_at_end` by its binary search (`LightsByX`) names the light
    /// the scan over all lights named: the nearest, the first of equals,
    /// if within its tolerance. Lights at every scale, repeated, and a
    /// hair apart; ends at lights, near them, and anywhere.
    #[test]
    fn the_light_a_shadow_ray_ends_at_is_the_scans() {
        let mut next = crate::testing::uniform(0x9e37_79b9_7f4a_7c15);
        let mut lights = Vec::new();
        for k in 0..300 {
            let scale = [1.0, 1e-6, 1e6, 1e12][k % 4];
            let p = [next(), next(), next()].map(|c| (c - 0.5) * scale);
            lights.push(p);
            if k % 7 == 0 {
                lights.push(p);
            }
            if k % 11 == 0 {
                lights.push([p[0] * (1.0 + 1e-12), p[1], p[2]]);
            }
        }
        let text = format!(
            "(camera: (eye: (0, -6, 0.5), look_at: (0, 0, 0), fov_y: 40, width: 16, height: 12), \
             lights: [{}], objects: [Sphere(center: (0, 0, 0), radius: 1)])",
            lights
                .iter()
                .map(|p| format!(
                    "(position: ({:e}, {:e}, {:e}), color: (1, 1, 1))",
                    p[0], p[1], p[2]
                ))
                .collect::<Vec<_>>()
                .join(", ")
        );
        let scene = parse_scene_str(&text, SceneSyntax::Ron, "lights.ron".as_ref()).unwrap();
        let cs = CellStructure::build(&scene, 16, 12, Default::default()).unwrap();
        let tracer = CellTracer::new(&cs, &scene);
        let scan = |ray: &Ray, t_max: f64| {
            let end = ray.at(t_max);
            let (i, d2) = (scene.lights.iter())
                .map(|l| (l.position - end).length_squared())
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(&b.1))?;
            let at = scene.lights[i].position;
            let tol = 1e-9 * (at.abs().max_element() + ray.origin.abs().max_element());
            (d2 <= tol * tol).then_some((i, tol))
        };
        let mut found = 0;
        for k in 0..20_000 {
            let origin = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 4.0;
            let target = scene.lights[k % scene.lights.len()].position;
            let aim = match k % 3 {
                0 => target,
                1 => target * (1.0 + (next() - 0.5) * 1e-8),
                _ => Vec3::new(next(), next(), next()) * 10.0,
            };
            let ray = Ray::new(origin, aim - origin);
            let want = scan(&ray, 1.0);
            assert_eq!(tracer.light_at_end(&ray, 1.0), want, "ray {k}: {ray:?}");
            found += usize::from(want.is_some());
        }
        assert!(found > 6_000, "{found} rays end at a light");
    }

    /// Told a shadow ray's light (`Tracer::toward`), the walk takes that
    /// light where the ray ends at it within its tolerance, the one of
    /// coincident lights included, and no light where it does not.
    #[test]
    fn a_shadow_ray_told_its_light_ends_there() {
        let scene = parse_scene_str(
            "(camera: (eye: (0, -6, 0.5), look_at: (0, 0, 0), fov_y: 40, width: 16, height: 12), \
             lights: [(position: (2, 0, 3)), (position: (2, 0, 3)), (position: (-2, 0, 3))], \
             objects: [Sphere(center: (0, 0, 0), radius: 1)])",
            SceneSyntax::Ron,
            "lights.ron".as_ref(),
        )
        .unwrap();
        let cs = CellStructure::build(&scene, 16, 12, Default::default()).unwrap();
        let mut tracer = CellTracer::new(&cs, &scene);
        let origin = Vec3::new(0.1, -1.5, 0.2);
        let to = |i: usize| Ray::new(origin, scene.lights[i].position - origin);
        let tol = |i: usize| {
            1e-9 * (scene.lights[i].position.abs().max_element() + origin.abs().max_element())
        };
        // Not told: the first of equals, as the search finds it.
        assert_eq!(tracer.light_at_end(&to(1), 1.0), Some((0, tol(0))));
        for i in 0..3 {
            tracer.toward(Some(i as u16));
            assert_eq!(tracer.light_at_end(&to(i), 1.0), Some((i, tol(i))));
        }
        // Told a light the ray does not end at.
        tracer.toward(Some(2));
        assert_eq!(tracer.light_at_end(&to(0), 1.0), None);
        // Told a light past the scene's: searched.
        tracer.toward(Some(7));
        assert_eq!(tracer.light_at_end(&to(2), 1.0), Some((2, tol(2))));
    }
}
