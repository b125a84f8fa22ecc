//! Partitioning in the projection plane (section 3.2): the projected
//! rectangles of the minimal boxes are decomposed into their four segments,
//! and a binary space partition by the segments' lines cuts the infinite
//! screen plane into rectangles, the super cells. Then corner stitching
//! (section 4, figure 6; Ousterhout 1984) links every super cell to its
//! neighbours by the eight corner pointers.

use std::collections::VecDeque;

use super::projection::{Rect, contains, finite_span};

/// How the BSP chooses the segment whose line splits a region (section 3.2
/// discusses the choice).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum SegmentChoice {
    /// The paper's choice: the segment whose line splits the fewest other
    /// segments, until the segment lists are empty. Quadratic in the
    /// segments of a region: slow for thousands of primitives, as the paper
    /// says.
    FewestSplits,
    /// The default: every segment line of a region is a candidate, scored
    /// by a cost model of the rays crossing the region (`Cost`, a
    /// surface-area heuristic in the screen plane), and a region is split
    /// only while the best candidate lowers the cost.
    ///
    /// Deviation from the paper, which splits until the segment lists are
    /// empty: that subdivides empty space and regions whose rectangles
    /// already overlap one another into thousands of thin super cells that
    /// every secondary ray must cross one by one (jagged_ball at 320×240:
    /// 3,317 super cells, 16.1 cells per ray with the fewest-splits rule over
    /// sampled candidates). The cost rule measures and stops; figures in
    /// `CellStructure::build`.
    #[default]
    Sampled,
}

/// A segment of a rectangle's edge: on the line `axis = c` (axis 0: a
/// vertical line x = c), spanning `[a, b]` along the other axis.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Seg {
    axis: u8,
    c: f64,
    a: f64,
    b: f64,
}

/// A node of the BSP, kept for locating points without a hint.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum BspNode {
    /// Points with `screen[axis] < c` (ties by direction) go to `lo`.
    Split {
        axis: u8,
        c: f64,
        lo: u32,
        hi: u32,
    },
    Leaf(u32),
}

/// Indices of the eight corner pointers (figure 6): PTLD.left, PTLD.down,
/// PTLU.left, PTLU.up, PTRU.right, PTRU.up, PTRD.right, PTRD.down.
pub mod stitch {
    pub const LD_LEFT: usize = 0;
    pub const LD_DOWN: usize = 1;
    pub const LU_LEFT: usize = 2;
    pub const LU_UP: usize = 3;
    pub const RU_RIGHT: usize = 4;
    pub const RU_UP: usize = 5;
    pub const RD_RIGHT: usize = 6;
    pub const RD_DOWN: usize = 7;
    /// No neighbour (the edge is at infinity).
    pub const NONE: u32 = u32::MAX;
}

/// A leaf of the partition: a rectangle and the rectangles (primitives)
/// covering it. Every listed rectangle covers the whole leaf unless the
/// subdivision was stopped early.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Leaf {
    pub rect: Rect,
    pub prims: Vec<u32>,
    /// Corner pointers, indexed by `stitch::*`, to other leaves.
    pub stitches: [u32; 8],
}

/// The partition of the screen plane.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Partition {
    pub nodes: Vec<BspNode>,
    pub leaves: Vec<Leaf>,
    /// Segments cut by chosen lines during the build.
    pub splits: u64,
    /// Splits the cost model alone would not have made: for `min_leaves`
    /// or a hot region (`partition_in`). Without any, the partition is
    /// the one a single node builds.
    pub forced: u64,
    /// The span of the rectangles' finite coordinates (`finite_span`):
    /// where the machine's hot spots may cut a super cell that reaches to
    /// infinity, such as the one super cell of a region behind the eye
    /// (`machine::mapping::hot`).
    pub span: ([f64; 2], [f64; 2]),
}

/// Limits that bound the subdivision when rectangles pile up
/// (`ROBUSTNESS.md` case 15: thousands of overlapping primitives end the
/// subdivision in bounded time).
const MAX_DEPTH: u32 = 64;

struct Pending {
    node: u32,
    rect: Rect,
    /// The segments in the region (the fewest-splits rule only).
    segs: Vec<Seg>,
    prims: Vec<u32>,
    /// The sampled rule only: per axis, `prims` sorted by their rectangles'
    /// low and by their high edges along it (then by number). Sorted once
    /// at the root and kept in order as regions split, so that choosing a
    /// split is a sweep, not a sort (Wald and Havran's n log n build).
    sorted: [[Vec<u32>; 2]; 2],
    depth: u32,
}

/// Builds the partition of the plane for `rects` (indexed by primitive
/// number; `None` for primitives not in this region).
pub fn partition(rects: &[Option<Rect>], choice: SegmentChoice) -> Partition {
    partition_in(rects, choice, None, None, 0, &[])
}

/// A part of the plane where the leaves must be small: a region whose
/// overlap with `rect` (finite) is larger than `max_area` is split at the
/// middle of the overlap's longer side. The machine marks so the super
/// cells that its pre-pass found heavier than a node should be
/// (`machine::mapping::hot`), since a super cell is never split over
/// nodes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hot {
    pub rect: Rect,
    pub max_area: f64,
}

impl Hot {
    /// Where to split `region`, if the spot asks for it.
    fn split(&self, region: &Rect) -> Option<(u8, f64)> {
        let lo = |a: usize| region.lo(a).max(self.rect.lo(a));
        let hi = |a: usize| region.hi(a).min(self.rect.hi(a));
        let (w, h) = (hi(0) - lo(0), hi(1) - lo(1));
        if !(w > 0.0 && h > 0.0 && w * h > self.max_area) {
            return None;
        }
        let a = usize::from(h > w);
        let c = (lo(a) + hi(a)) / 2.0;
        (c > region.lo(a) && c < region.hi(a)).then_some((a as u8, c))
    }
}

/// `partition` with the screen window the primary rays sample, which the
/// cost model weights (`None`: the rectangles' extent), and at least
/// `min_leaves` leaves where the regions have candidate lines: while
/// fewer would result, the sampled choice splits by its best line even
/// when the split does not pay (breadth first, so the largest regions
/// first). The machine needs them: a super cell is never split over
/// nodes, so a few large ones cannot keep many nodes equally busy.
pub fn partition_in(
    rects: &[Option<Rect>],
    choice: SegmentChoice,
    window: Option<Rect>,
    weights: Option<&[f64]>,
    min_leaves: usize,
    hot: &[Hot],
) -> Partition {
    let mut segs = Vec::new();
    let mut prims = Vec::new();
    for (i, r) in rects.iter().enumerate() {
        let Some(r) = r else { continue };
        prims.push(i as u32);
        if choice != SegmentChoice::FewestSplits {
            continue;
        }
        for axis in 0..2 {
            let other = 1 - axis;
            for c in [r.lo(axis), r.hi(axis)] {
                if c.is_finite() && r.lo(other) < r.hi(other) {
                    segs.push(Seg {
                        axis: axis as u8,
                        c,
                        a: r.lo(other),
                        b: r.hi(other),
                    });
                }
            }
        }
    }
    let n = prims.len();
    let cost = Cost::new(rects, window, weights);
    // Budget of leaves: beyond it, pending regions become leaves as they
    // are. It leaves room for the super cells the machine asks for and for
    // its splits of heavy ones (`mapping::hot`): held to 16 per primitive,
    // `csg_basics.ron` (11 primitives) stopped at 240 super cells however
    // many nodes, and on 64 and 128 nodes its loads stayed 5 and 18 times
    // uneven (predicted), which made its run 1.5 and 4 times as long in
    // virtual time as on 32.
    let max_leaves = (16 * n + 64).max(4 * min_leaves);
    let mut out = Partition {
        span: finite_span(rects.iter().flatten()),
        ..Partition::default()
    };
    out.nodes.push(BspNode::Leaf(0));
    let mut queue = VecDeque::new();
    let sorted = if choice == SegmentChoice::Sampled {
        [0, 1].map(|axis| {
            [false, true].map(|high| {
                let mut edges: Vec<(f64, u32)> = prims
                    .iter()
                    .filter_map(|&i| {
                        let r = rects[i as usize]?;
                        Some((if high { r.hi(axis) } else { r.lo(axis) }, i))
                    })
                    .collect();
                edges.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                edges.into_iter().map(|e| e.1).collect()
            })
        })
    } else {
        Default::default()
    };
    queue.push_back(Pending {
        node: 0,
        rect: Rect::PLANE,
        segs,
        prims,
        sorted,
        depth: 0,
    });
    let mut scratch = SweepScratch::default();
    // Per primitive, the sides of the last split it was in (bit 0: low,
    // bit 1: high), for the sorted lists.
    let mut sides = vec![0u8; rects.len()];
    // Breadth first, so an exhausted budget stops all regions alike.
    while let Some(p) = queue.pop_front() {
        let leaves_if_stopped = out.leaves.len() + queue.len() + 1;
        let choice_here = if p.depth >= MAX_DEPTH || leaves_if_stopped >= max_leaves {
            None
        } else {
            match choice {
                _ if let Some(c) = hot.iter().find_map(|h| h.split(&p.rect)) => {
                    out.forced += 1;
                    Some(c)
                }
                SegmentChoice::FewestSplits => choose(&p.segs),
                SegmentChoice::Sampled => {
                    let force = leaves_if_stopped < min_leaves;
                    let c = cost.choose(&p.rect, &p.sorted, rects, &mut scratch, force);
                    if c.is_some_and(|(_, pays)| !pays) {
                        out.forced += 1;
                    }
                    c.map(|(line, _)| line)
                }
            }
        };
        let Some((axis, c)) = choice_here else {
            let id = out.leaves.len() as u32;
            out.nodes[p.node as usize] = BspNode::Leaf(id);
            out.leaves.push(Leaf {
                rect: p.rect,
                prims: p.prims,
                stitches: [stitch::NONE; 8],
            });
            continue;
        };
        let a = axis as usize;
        let (mut lo_segs, mut hi_segs) = (Vec::new(), Vec::new());
        for s in &p.segs {
            if s.axis == axis {
                if s.c < c {
                    lo_segs.push(*s);
                } else if s.c > c {
                    hi_segs.push(*s);
                } // on the line: used up by this split
            } else if s.b <= c {
                lo_segs.push(*s);
            } else if s.a >= c {
                hi_segs.push(*s);
            } else {
                out.splits += 1;
                lo_segs.push(Seg { b: c, ..*s });
                hi_segs.push(Seg { a: c, ..*s });
            }
        }
        // Half-open regions: [lo, c) and [c, hi). A rectangle belongs to a
        // side when its interior reaches into it.
        let (mut lo_prims, mut hi_prims) = (Vec::new(), Vec::new());
        for &i in &p.prims {
            let Some(r) = rects[i as usize] else { continue };
            let (to_lo, to_hi) = (r.lo(a) < c, r.hi(a) > c);
            sides[i as usize] = u8::from(to_lo) | u8::from(to_hi) << 1;
            if to_lo {
                lo_prims.push(i);
            }
            if to_hi {
                hi_prims.push(i);
            }
            if to_lo && to_hi && choice != SegmentChoice::FewestSplits {
                // The rectangle's edges across the line, within the region.
                let o = 1 - a;
                out.splits += [r.lo(o), r.hi(o)]
                    .iter()
                    .filter(|&&e| e.is_finite() && e >= p.rect.lo(o) && e <= p.rect.hi(o))
                    .count() as u64;
            }
        }
        // The sorted lists keep their order on both sides.
        let side = |order: &Vec<u32>, bit: u8, len: usize| -> Vec<u32> {
            // (Empty lists under the fewest-splits rule: no room.)
            let mut out = Vec::with_capacity(len.min(order.len()));
            out.extend(
                order
                    .iter()
                    .copied()
                    .filter(|&i| sides[i as usize] & bit != 0),
            );
            out
        };
        let (nl, nh) = (lo_prims.len(), hi_prims.len());
        let lo_sorted = p
            .sorted
            .each_ref()
            .map(|o| o.each_ref().map(|o| side(o, 1, nl)));
        let hi_sorted = p
            .sorted
            .each_ref()
            .map(|o| o.each_ref().map(|o| side(o, 2, nh)));
        let mut lo_rect = p.rect;
        lo_rect.set_hi(a, c);
        let mut hi_rect = p.rect;
        hi_rect.set_lo(a, c);
        let lo = out.nodes.len() as u32;
        out.nodes.push(BspNode::Leaf(0));
        out.nodes.push(BspNode::Leaf(0));
        out.nodes[p.node as usize] = BspNode::Split {
            axis,
            c,
            lo,
            hi: lo + 1,
        };
        queue.push_back(Pending {
            node: lo,
            rect: lo_rect,
            segs: lo_segs,
            prims: lo_prims,
            sorted: lo_sorted,
            depth: p.depth + 1,
        });
        queue.push_back(Pending {
            node: lo + 1,
            rect: hi_rect,
            segs: hi_segs,
            prims: hi_prims,
            sorted: hi_sorted,
            depth: p.depth + 1,
        });
    }
    stitch_all(&mut out);
    out
}

/// Splits caused and balance of the line through `s`.
fn score(segs: &[Seg], axis: u8, c: f64) -> (usize, usize) {
    let (mut splits, mut lo, mut hi) = (0usize, 0usize, 0usize);
    for s in segs {
        if s.axis == axis {
            if s.c < c {
                lo += 1
            } else if s.c > c {
                hi += 1
            }
        } else if s.b <= c {
            lo += 1
        } else if s.a >= c {
            hi += 1
        } else {
            splits += 1
        }
    }
    (splits, lo.abs_diff(hi))
}

/// The paper's rule: the segment whose line splits the fewest others (ties
/// toward balance); None when no segment is left.
fn choose(segs: &[Seg]) -> Option<(u8, f64)> {
    segs.iter()
        .map(|s| (score(segs, s.axis, s.c), s.axis, s.c))
        .min_by(|a, b| a.0.cmp(&b.0))
        .map(|(_, axis, c)| (axis, c))
}

/// The cost model of `SegmentChoice::Sampled`: a surface-area heuristic in
/// the screen plane. A region's weight is the share of rays that cross it:
/// its area (primary rays, one per pixel) plus `PERIMETER` times its
/// perimeter (secondary rays cross a region in proportion to its
/// perimeter, Cauchy-Crofton), both clipped to the rectangle that bounds
/// every projected box (beyond it regions are empty). A leaf costs
/// `weight · n` for its `n` primitives; a split costs `TRAVERSE` plus the
/// weighted costs of both sides. Candidates are the lines of the region's
/// segments (its rectangles' edges inside it), all of them, in one sweep
/// per axis.
struct Cost {
    bounds: Rect,
    perimeter: f64,
    /// Per primitive, what it costs a ray that crosses its region (see
    /// `partition_in`).
    weights: Vec<f64>,
}

/// Cost of crossing one more super cell, against 1 per primitive met.
///
/// The four cost constants (these two, `DEPTH_ALL` and `DEPTH_STEP` in
/// `cells/mod.rs`) were chosen together by the walk's instruction count
/// (callgrind; sphereflake level 4 at 512x512 and jagged_ball at 640x480,
/// one ray in 4 and in 2 per axis; house at 640x480 one in 2): from 1.0,
/// 0.1, 0.1, 1.0 to 0.5, 0.3, 0.05, 0.5 the sphereflake's walk went from
/// 422M to 403M instructions, jagged_ball's from 801M to 763M, house's
/// from 2,586M to 2,558M. The optimum is flat: the fifteen or so settings
/// tried around it moved each scene's count by less than 10%. A primitive met costs less than it did
/// when these were 1.0 and 0.1 (`CellTracer::in_cell`'s first look), so
/// finer cells pay.
const TRAVERSE: f64 = 0.5;
/// Weight of the perimeter against the area, as a fraction of the size of
/// the bounds: secondary rays (four in five on the sphereflake) cross
/// regions in proportion to their perimeter.
const PERIMETER: f64 = 0.3;
/// The weighted part of the screen plane extends this fraction of the
/// window beyond it on every side.
const WINDOW_MARGIN: f64 = 0.25;

#[derive(Default)]
struct SweepScratch {
    los: Vec<(f64, f64)>,
    his: Vec<(f64, f64)>,
}

impl Cost {
    fn new(rects: &[Option<Rect>], window: Option<Rect>, weights: Option<&[f64]>) -> Cost {
        let mut b = Rect {
            x0: f64::INFINITY,
            x1: f64::NEG_INFINITY,
            y0: f64::INFINITY,
            y1: f64::NEG_INFINITY,
        };
        // Finite coordinates only: projections reaching infinity (boxes
        // across the eye plane) are weighted up to the others' extent.
        for r in rects.iter().flatten() {
            for v in [r.x0, r.x1] {
                if v.is_finite() {
                    b.x0 = b.x0.min(v);
                    b.x1 = b.x1.max(v);
                }
            }
            for v in [r.y0, r.y1] {
                if v.is_finite() {
                    b.y0 = b.y0.min(v);
                    b.y1 = b.y1.max(v);
                }
            }
        }
        // Where primary rays go, with a margin for the secondary rays of
        // what lies just outside the view.
        if let Some(w) = window {
            let (mx, my) = ((w.x1 - w.x0) * WINDOW_MARGIN, (w.y1 - w.y0) * WINDOW_MARGIN);
            b.x0 = b.x0.max(w.x0 - mx);
            b.x1 = b.x1.min(w.x1 + mx);
            b.y0 = b.y0.max(w.y0 - my);
            b.y1 = b.y1.min(w.y1 + my);
        }
        let size = (b.x1 - b.x0).max(b.y1 - b.y0);
        let pf: f64 = PERIMETER;
        let perimeter = if size.is_finite() && size > 0.0 {
            pf * size
        } else {
            1.0
        };
        let weights = weights.map_or_else(|| vec![1.0; rects.len()], |w| w.to_vec());
        Cost {
            bounds: b,
            perimeter,
            weights,
        }
    }

    /// The weight of region `r`.
    fn weight(&self, r: &Rect) -> f64 {
        let b = &self.bounds;
        let w = r.x1.min(b.x1) - r.x0.max(b.x0);
        let h = r.y1.min(b.y1) - r.y0.max(b.y0);
        if !(w >= 0.0 && h >= 0.0) {
            return 0.0;
        }
        w * h + self.perimeter * (w + h)
    }

    /// The best split of `region` holding `prims`, if any lowers the cost
    /// (`force`: the best, whether or not it does), and whether it does.
    fn choose(
        &self,
        region: &Rect,
        sorted: &[[Vec<u32>; 2]; 2],
        rects: &[Option<Rect>],
        scratch: &mut SweepScratch,
        force: bool,
    ) -> Option<((u8, f64), bool)> {
        let n = sorted[0][0].len();
        if n == 0 {
            return None;
        }
        let whole = self.weight(region);
        if !(whole > 0.0 && whole.is_finite()) {
            return None;
        }
        let mut best: (f64, Option<(u8, f64)>) = (f64::INFINITY, None);
        let traverse: f64 = TRAVERSE;
        let mut leaf = 0.0;
        for (axis, [by_lo, by_hi]) in sorted.iter().enumerate() {
            let (los, his) = (&mut scratch.los, &mut scratch.his);
            los.clear();
            his.clear();
            for (list, order, high) in [(&mut *los, by_lo, false), (&mut *his, by_hi, true)] {
                list.extend(order.iter().filter_map(|&p| {
                    let r = rects[p as usize].as_ref()?;
                    let edge = if high { r.hi(axis) } else { r.lo(axis) };
                    Some((edge, self.weights[p as usize]))
                }));
            }
            let total: f64 = los.iter().map(|e| e.1).sum();
            if axis == 0 {
                leaf = total;
            }
            let (rlo, rhi) = (region.lo(axis), region.hi(axis));
            // Candidates in increasing order: the merged edge coordinates.
            let (mut i, mut j) = (0usize, 0usize);
            // Rectangles starting before c, and ending at or before c, and
            // their weights.
            let (mut before, mut ended) = (0usize, 0usize);
            let (mut w_before, mut w_ended) = (0.0, 0.0);
            while i < los.len() || j < his.len() {
                let c = match (los.get(i), his.get(j)) {
                    (Some(a), Some(b)) => a.0.min(b.0),
                    (Some(a), None) => a.0,
                    (None, Some(b)) => b.0,
                    (None, None) => break,
                };
                while before < los.len() && los[before].0 < c {
                    w_before += los[before].1;
                    before += 1;
                }
                while ended < his.len() && his[ended].0 <= c {
                    w_ended += his[ended].1;
                    ended += 1;
                }
                while i < los.len() && los[i].0 == c {
                    i += 1;
                }
                while j < his.len() && his[j].0 == c {
                    j += 1;
                }
                if !(c > rlo && c < rhi && c.is_finite()) {
                    continue;
                }
                let (nl, nr) = (w_before, total - w_ended);
                let mut lo_r = *region;
                lo_r.set_hi(axis, c);
                let mut hi_r = *region;
                hi_r.set_lo(axis, c);
                let cost = traverse + (self.weight(&lo_r) * nl + self.weight(&hi_r) * nr) / whole;
                if cost < best.0 && (force || cost < leaf) {
                    best = (cost, Some((axis as u8, c)));
                }
            }
        }
        best.1.map(|line| (line, best.0 < leaf))
    }
}

/// Tiles along the four edges of a subtree's region, in increasing order
/// along the edge.
struct Edges {
    left: Vec<u32>,
    right: Vec<u32>,
    bottom: Vec<u32>,
    top: Vec<u32>,
}

/// Corner stitching built from the BSP in one bottom-up pass: when two
/// halves of a region are joined, the tiles facing each other across the
/// splitting line get their pointers by one merge walk along it. No search
/// over the whole structure (the role of the paper's Algorithm 2).
fn stitch_all(p: &mut Partition) {
    if p.nodes.is_empty() {
        return;
    }
    let nodes = std::mem::take(&mut p.nodes);
    stitch_node(&nodes, 0, &mut p.leaves);
    p.nodes = nodes;
}

fn stitch_node(nodes: &[BspNode], n: u32, leaves: &mut [Leaf]) -> Edges {
    use stitch::*;
    match nodes[n as usize] {
        BspNode::Leaf(l) => Edges {
            left: vec![l],
            right: vec![l],
            bottom: vec![l],
            top: vec![l],
        },
        BspNode::Split { axis, lo, hi, .. } => {
            let a = stitch_node(nodes, lo, leaves);
            let b = stitch_node(nodes, hi, leaves);
            if axis == 0 {
                // Vertical line: `a` on the left, `b` on the right; the
                // facing edges run along y.
                link(
                    leaves,
                    &a.right,
                    &b.left,
                    1,
                    [RD_RIGHT, RU_RIGHT],
                    [LD_LEFT, LU_LEFT],
                );
                Edges {
                    left: a.left,
                    right: b.right,
                    bottom: [a.bottom, b.bottom].concat(),
                    top: [a.top, b.top].concat(),
                }
            } else {
                link(
                    leaves,
                    &a.top,
                    &b.bottom,
                    0,
                    [LU_UP, RU_UP],
                    [LD_DOWN, RD_DOWN],
                );
                Edges {
                    left: [a.left, b.left].concat(),
                    right: [a.right, b.right].concat(),
                    bottom: a.bottom,
                    top: b.top,
                }
            }
        }
    }
}

/// Stitches two facing edge lists sorted along `axis`: for each tile, the
/// pointer at its low corner goes to the facing tile containing that corner
/// (`[lo, hi)`), the one at its high corner to the facing tile containing
/// the point just below it (`(lo, hi]`).
fn link(
    leaves: &mut [Leaf],
    near: &[u32],
    far: &[u32],
    axis: usize,
    near_ptrs: [usize; 2],
    far_ptrs: [usize; 2],
) {
    let find = |leaves: &[Leaf], list: &[u32], q: f64, high_corner: bool| -> u32 {
        // Lists are short on average; a binary search keeps long ones fast.
        let idx = list.partition_point(|&t| {
            let r = &leaves[t as usize].rect;
            if high_corner {
                r.hi(axis) < q
            } else {
                r.hi(axis) <= q
            }
        });
        list.get(idx)
            .copied()
            .filter(|&t| {
                let r = &leaves[t as usize].rect;
                if high_corner {
                    r.lo(axis) < q || q == f64::NEG_INFINITY
                } else {
                    contains(r.lo(axis), r.hi(axis), q, 1.0)
                }
            })
            .unwrap_or(stitch::NONE)
    };
    for &t in near {
        let r = leaves[t as usize].rect;
        let low = find(leaves, far, r.lo(axis), false);
        let high = find(leaves, far, r.hi(axis), true);
        leaves[t as usize].stitches[near_ptrs[0]] = low;
        leaves[t as usize].stitches[near_ptrs[1]] = high;
    }
    for &t in far {
        let r = leaves[t as usize].rect;
        let low = find(leaves, near, r.lo(axis), false);
        let high = find(leaves, near, r.hi(axis), true);
        leaves[t as usize].stitches[far_ptrs[0]] = low;
        leaves[t as usize].stitches[far_ptrs[1]] = high;
    }
}

impl Partition {
    /// The leaf containing screen point `(x, y)` for a ray moving with
    /// signs `(mx, my)`, by descending the BSP.
    pub fn locate(&self, x: f64, y: f64, mx: f64, my: f64) -> u32 {
        let mut n = 0usize;
        loop {
            match self.nodes[n] {
                BspNode::Leaf(l) => return l,
                BspNode::Split { axis, c, lo, hi } => {
                    let (q, m) = if axis == 0 { (x, mx) } else { (y, my) };
                    n = if q > c || (q == c && m >= 0.0) {
                        hi as usize
                    } else {
                        lo as usize
                    };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x0: f64, x1: f64, y0: f64, y1: f64) -> Option<Rect> {
        Some(Rect { x0, x1, y0, y1 })
    }

    /// Brute-force check of every stitch against its definition.
    fn check_stitches(p: &Partition) {
        use stitch::*;
        let find = |x: f64, y: f64, mx: f64, my: f64| -> u32 {
            let hits: Vec<u32> = (0..p.leaves.len() as u32)
                .filter(|&i| {
                    let r = &p.leaves[i as usize].rect;
                    contains(r.x0, r.x1, x, mx) && contains(r.y0, r.y1, y, my)
                })
                .collect();
            assert!(hits.len() <= 1, "tiles overlap at ({x}, {y})");
            hits.first().copied().unwrap_or(NONE)
        };
        for (i, l) in p.leaves.iter().enumerate() {
            let r = l.rect;
            let expect = |ptr: usize| -> u32 {
                match ptr {
                    LD_LEFT => find(r.x0, r.y0, -1.0, 1.0),
                    LD_DOWN => find(r.x0, r.y0, 1.0, -1.0),
                    LU_LEFT => find(r.x0, r.y1, -1.0, -1.0),
                    LU_UP => find(r.x0, r.y1, 1.0, 1.0),
                    RU_RIGHT => find(r.x1, r.y1, 1.0, -1.0),
                    RU_UP => find(r.x1, r.y1, -1.0, 1.0),
                    RD_RIGHT => find(r.x1, r.y0, 1.0, 1.0),
                    _ => find(r.x1, r.y0, -1.0, -1.0),
                }
            };
            for ptr in 0..8 {
                // The coordinate each pointer crosses; none across infinity.
                let across = match ptr {
                    LD_LEFT | LU_LEFT => r.x0,
                    RU_RIGHT | RD_RIGHT => r.x1,
                    LD_DOWN | RD_DOWN => r.y0,
                    _ => r.y1,
                };
                let e = if across.is_finite() {
                    expect(ptr)
                } else {
                    NONE
                };
                assert_eq!(l.stitches[ptr], e, "leaf {i} {r:?} pointer {ptr}");
            }
        }
    }

    #[test]
    fn partition_covers_the_plane_and_stitches_are_exact() {
        let rects = vec![
            rect(0.0, 2.0, 0.0, 1.0),
            rect(1.0, 3.0, 0.5, 2.0),
            rect(-1.0, 0.5, -2.0, -1.0),
            None,
            rect(2.5, 4.0, -1.0, 0.75),
        ];
        for choice in [SegmentChoice::FewestSplits, SegmentChoice::Sampled] {
            let p = partition(&rects, choice);
            check_stitches(&p);
            for l in &p.leaves {
                // Every rectangle reaching into a leaf is listed there.
                for (i, r) in rects.iter().enumerate() {
                    let Some(r) = r else { continue };
                    let reaches = r.x0 < l.rect.x1
                        && l.rect.x0 < r.x1
                        && r.y0 < l.rect.y1
                        && l.rect.y0 < r.y1;
                    assert_eq!(
                        reaches,
                        l.prims.contains(&(i as u32)),
                        "{r:?} in {:?}",
                        l.rect
                    );
                }
                // With the paper's rule, listed rectangles cover the leaf
                // entirely (the segment lists emptied).
                if choice == SegmentChoice::FewestSplits {
                    for &i in &l.prims {
                        let r = rects[i as usize].unwrap();
                        assert!(
                            r.x0 <= l.rect.x0
                                && l.rect.x1 <= r.x1
                                && r.y0 <= l.rect.y0
                                && l.rect.y1 <= r.y1
                        );
                    }
                }
            }
            // Point location agrees with the tiles.
            for &(x, y) in &[
                (0.1, 0.1),
                (1.5, 0.75),
                (-5.0, 7.0),
                (2.0, 0.5),
                (3.9, -0.9),
            ] {
                let l = &p.leaves[p.locate(x, y, 1.0, 1.0) as usize];
                assert!(
                    contains(l.rect.x0, l.rect.x1, x, 1.0)
                        && contains(l.rect.y0, l.rect.y1, y, 1.0)
                );
            }
        }
    }

    #[test]
    fn piled_up_rectangles_end_in_bounded_time() {
        // 2000 nearly identical rectangles (case 15's projection).
        let rects: Vec<Option<Rect>> = (0..2000)
            .map(|i| {
                let e = i as f64 * 1e-5;
                rect(-1.0 + e, 1.0 - e, -1.0 + e * 0.5, 1.0 + e)
            })
            .collect();
        let p = partition(&rects, SegmentChoice::Sampled);
        assert!(p.leaves.len() <= 16 * 2000 + 64);
        check_stitches(&p);
    }

    #[test]
    fn a_hot_spot_splits_the_leaves_over_it_small() {
        let rects = vec![rect(-1.0, 1.0, -1.0, 1.0), rect(-0.2, 0.3, -0.1, 0.4)];
        let plain = partition_in(&rects, SegmentChoice::Sampled, None, None, 0, &[]);
        let spot = Hot {
            rect: Rect {
                x0: -0.2,
                x1: 0.3,
                y0: -0.1,
                y1: 0.4,
            },
            max_area: 0.25 * 0.25 / 4.0,
        };
        let p = partition_in(&rects, SegmentChoice::Sampled, None, None, 0, &[spot]);
        assert!(
            p.leaves.len() > plain.leaves.len() + 4,
            "{} leaves",
            p.leaves.len()
        );
        let overlap = |r: &Rect| {
            let w = r.x1.min(spot.rect.x1) - r.x0.max(spot.rect.x0);
            let h = r.y1.min(spot.rect.y1) - r.y0.max(spot.rect.y0);
            if w > 0.0 && h > 0.0 { w * h } else { 0.0 }
        };
        for l in &p.leaves {
            assert!(overlap(&l.rect) <= spot.max_area, "{:?}", l.rect);
        }
        check_stitches(&p);
    }
}
