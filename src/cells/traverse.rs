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
use super::projection::{contains, CamRay, Region};
use super::{CellStructure, RegionCells, NO_SUBTREE};
use crate::csg::{EvalCounts, Evaluator, NodeId, PrimHits, SpanList};
use crate::geom::Ray;
use crate::render::TraceCounters;
use crate::scene::Scene;
use crate::trace::{Hit, Tracer};

/// A cell of one region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRef {
    pub region: Region,
    pub cell: u32,
}

/// Where a ray goes after a cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// Into another cell, at parameter `t`.
    Next(CellRef, f64),
    /// Out of the region.
    Leave,
}

/// Which face a ray leaves a cell by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Face {
    Side { axis: usize, high: bool },
    Depth { high: bool },
    None,
}

/// The per-ray quantities of the walk in one region.
#[derive(Clone, Copy, Debug)]
pub struct RegionRay {
    pub region: Region,
    pub cam: CamRay,
    /// Motion signs along screen x, screen y and depth.
    pub m: [f64; 3],
}

impl RegionRay {
    pub fn new(region: Region, cam: CamRay) -> Self {
        RegionRay {
            region,
            cam,
            m: [cam.motion(region, 0), cam.motion(region, 1), cam.d.z],
        }
    }
}

impl CellStructure {
    /// The cell containing the ray's point at `t` (the start of its part in
    /// the region), by the BSP and a depth search; ties by direction.
    pub fn locate(&self, rr: &RegionRay, t: f64) -> CellRef {
        let rc = self.region(rr.region);
        let (sx, sy, z) = rr.cam.screen_at(rr.region, t);
        let s = rc.partition.locate(sx, sy, rr.m[0], rr.m[1]);
        CellRef {
            region: rr.region,
            cell: rc.cell_at_depth(s, z, rr.m[2]),
        }
    }

    /// The parameter where the ray leaves cell `c` (never before `t_in`) and
    /// the cell it enters there (section 7, figures 11-13).
    pub fn step(&self, rr: &RegionRay, c: CellRef, t_in: f64) -> (f64, Step) {
        let rc = self.region(rr.region);
        let cell = rc.cells[c.cell as usize];
        let rect = rc.partition.leaves[cell.super_cell as usize].rect;
        let mut t_out = f64::INFINITY;
        let mut face = Face::None;
        // Ties between faces: x, then y, then depth (one fixed rule).
        for axis in 0..2 {
            let m = rr.m[axis];
            if m == 0.0 {
                continue;
            }
            let high = m > 0.0;
            let c = if high { rect.hi(axis) } else { rect.lo(axis) };
            if let Some(t) = rr.cam.cross_side(rr.region, axis, c)
                && t < t_out
            {
                t_out = t;
                face = Face::Side { axis, high };
            }
        }
        if rr.m[2] != 0.0 {
            let high = rr.m[2] > 0.0;
            let z = if high { cell.zhi } else { cell.zlo };
            if let Some(t) = rr.cam.cross_depth(z)
                && t < t_out
            {
                t_out = t;
                face = Face::Depth { high };
            }
        }
        // The entry t never decreases from cell to cell.
        let t_out = t_out.max(t_in);
        let next = match face {
            Face::None => Step::Leave,
            Face::Depth { high } => {
                let range = rc.cells_of(cell.super_cell);
                let k = c.cell as usize;
                let n = if high { k + 1 } else { k.wrapping_sub(1) };
                if range.contains(&n) {
                    Step::Next(CellRef { region: c.region, cell: n as u32 }, t_out)
                } else {
                    Step::Leave
                }
            }
            Face::Side { axis, high } => match self.side_neighbour(rc, rr, cell.super_cell, axis, high, t_out, cell.zlo, cell.zhi) {
                Some(n) => Step::Next(CellRef { region: c.region, cell: n }, t_out),
                None => Step::Leave,
            },
        };
        (t_out, next)
    }

    /// Figure 13: the neighbour across a side face. Start from the corner
    /// pointer at the face's low end and climb the neighbours' pointers
    /// until one contains the exit point, then find the depth slab.
    #[allow(clippy::too_many_arguments)]
    fn side_neighbour(&self, rc: &RegionCells, rr: &RegionRay, s: u32, axis: usize, high: bool, t: f64, zlo: f64, zhi: f64) -> Option<u32> {
        use stitch::*;
        let leaves = &rc.partition.leaves;
        let rect = leaves[s as usize].rect;
        let other = 1 - axis;
        let (sx, sy, z) = rr.cam.screen_at(rr.region, t);
        let q = if other == 0 { sx } else { sy };
        // Clamped to the face, so the walk stays among true neighbours.
        let q = q.clamp(rect.lo(other), rect.hi(other));
        let mq = rr.m[other];
        let (start, climb) = match (axis, high) {
            (0, false) => (LD_LEFT, RU_UP),
            (0, true) => (RD_RIGHT, LU_UP),
            (_, false) => (LD_DOWN, RU_RIGHT),
            (_, true) => (LU_UP, RD_RIGHT),
        };
        let mut n = leaves[s as usize].stitches[start];
        let mut guard = leaves.len();
        while n != NONE {
            let r = leaves[n as usize].rect;
            if contains(r.lo(other), r.hi(other), q, mq) {
                let z = z.clamp(zlo, zhi);
                return Some(rc.cell_at_depth(n, z, rr.m[2]));
            }
            n = leaves[n as usize].stitches[climb];
            guard -= 1;
            if guard == 0 {
                break;
            }
        }
        debug_assert!(false, "corner-stitch walk found no neighbour");
        None
    }
}

/// Section 8: per primitive, the last ray it was tested against and the
/// result, so a primitive spanning several cells is intersected once.
#[derive(Clone, Copy, Debug)]
struct Mailbox {
    ray: u64,
    hits: PrimHits,
}

/// The cells accelerator on one thread.
pub struct CellTracer<'a> {
    cs: &'a CellStructure,
    scene: &'a Scene,
    eval: Evaluator,
    mailboxes: Vec<Mailbox>,
    /// Unique number of the current ray (mailbox key).
    ray_id: u64,
    last_ray: Option<Ray>,
    pub counters: TraceCounters,
    pub eval_counts: EvalCounts,
    /// The span list of the last (ray, subtree) evaluated.
    spans: SpanList,
    last_eval: Option<(u64, u32)>,
}

impl<'a> CellTracer<'a> {
    pub fn new(cs: &'a CellStructure, scene: &'a Scene) -> Self {
        CellTracer {
            cs,
            scene,
            eval: Evaluator::new(),
            mailboxes: vec![
                Mailbox {
                    ray: 0,
                    hits: PrimHits::Miss
                };
                scene.primitives.len()
            ],
            ray_id: 0,
            last_ray: None,
            counters: TraceCounters::default(),
            eval_counts: EvalCounts::default(),
            spans: SpanList::default(),
            last_eval: None,
        }
    }

    /// The first boundary of cell `c`'s subtree with `t_min < t`, `t_in ≤ t`
    /// and `t < t_end`.
    fn in_cell(&mut self, c: CellRef, ray: &Ray, t_min: f64, t_in: f64, t_end: f64) -> Option<Hit> {
        self.counters.cells_visited += 1;
        let cell = self.cs.region(c.region).cells[c.cell as usize];
        if cell.subtree == NO_SUBTREE || t_end < t_in {
            return None;
        }
        // Neighbouring cells often keep the same primitives, and so share
        // one subtree (they are memoised by primitive set): the span list
        // of the same ray is then already known.
        if self.last_eval != Some((self.ray_id, cell.subtree)) {
            let prims = &self.scene.primitives;
            let mailboxes = &mut self.mailboxes;
            let counters = &mut self.counters;
            let id = self.ray_id;
            let spans: &SpanList = self.eval.evaluate(&self.cs.subtrees, NodeId(cell.subtree), ray, true, &mut self.eval_counts, |p| {
                let mb = &mut mailboxes[p.index()];
                if mb.ray == id {
                    counters.mailbox_hits += 1;
                } else {
                    counters.intersection_tests += 1;
                    *mb = Mailbox {
                        ray: id,
                        hits: prims[p.index()].intersect(ray),
                    };
                }
                mb.hits
            });
            self.spans.clone_from(spans);
            self.counters.subtree_evaluations += 1;
            self.last_eval = Some((self.ray_id, cell.subtree));
        }
        self.spans.first_between(t_min.max(prev_float(t_in)), t_end).map(Hit::from)
    }
}

/// The largest float below `t`, so that `(prev_float(t), x)` includes `t`.
fn prev_float(t: f64) -> f64 {
    if t.is_finite() { t.next_down() } else { t }
}

impl CellTracer<'_> {
    /// True when a primary job's super cell holds no primitive, so its
    /// sample is background without tracing (section 3.2's pixel areas).
    pub fn primary_is_background(cs: &CellStructure, ray: &Ray) -> bool {
        let cam = cs.view.ray(ray);
        let rr = RegionRay::new(Region::Front, cam);
        let (sx, sy, _) = cam.screen_at(Region::Front, 0.0);
        let front = cs.region(Region::Front);
        front.super_cell_is_empty(front.partition.locate(sx, sy, rr.m[0], rr.m[1]))
    }
}

impl Tracer for CellTracer<'_> {
    fn nearest(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        // A new ray number unless this is the same ray again (shadow rays
        // ask repeatedly, past each surface they cross).
        if self.last_ray != Some(*ray) {
            self.ray_id += 1;
            self.last_ray = Some(*ray);
        }
        let cam = self.cs.view.ray(ray);
        let mut order = [Region::Front, Region::Back];
        if cam.d.z > 0.0 {
            order.swap(0, 1);
        }
        for region in order {
            let (lo, hi) = cam.region_interval(region);
            let lo = lo.max(t_min);
            let hi = hi.min(t_max);
            if !(lo < hi) {
                continue;
            }
            let rr = RegionRay::new(region, cam);
            let mut c = self.cs.locate(&rr, lo);
            let mut t_in = lo;
            // The walk is monotone in every screen axis and depth, so it
            // ends; the guard only turns a bug into a miss, never a hang.
            let mut guard = self.cs.stats.cells + 2;
            loop {
                guard -= 1;
                debug_assert!(guard > 0, "cell walk did not end");
                if guard == 0 {
                    break;
                }
                let (t_out, next) = self.cs.step(&rr, c, t_in);
                let t_end = t_out.min(hi);
                if let Some(h) = self.in_cell(c, ray, t_min, t_in, t_end) {
                    return Some(h);
                }
                match next {
                    Step::Next(n, t) if t < hi => {
                        c = n;
                        t_in = t;
                    }
                    _ => break,
                }
            }
        }
        None
    }

    fn counters(&self) -> TraceCounters {
        self.counters
    }
}
