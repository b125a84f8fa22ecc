//! Evaluating a CSG tree along a ray: the span list of the whole tree, from
//! the primitives' crossings, without recursion (trees may be thousands of
//! levels deep, `ROBUSTNESS.md` case 15) and without allocating once warm.

use super::span::{CombineScratch, combine};
use super::{Boundary, CsgNode, CsgTree, NodeId, Op, PrimHits, PrimId, Span, SpanList};
use std::cell::Cell;

use crate::geom::Ray;

#[derive(Debug)]
struct Frame {
    node: NodeId,
    next_child: usize,
    /// Index in `results` of this node's first child's result.
    base: usize,
    /// The last child entered was an operator, whose result is to be
    /// looked at when its frame is done.
    pending: bool,
}

/// Reusable workspace for `evaluate`. One per thread (or node).
#[derive(Default, Debug)]
pub struct Evaluator {
    frames: Vec<Frame>,
    results: Vec<SpanList>,
    top: usize,
    tmp: SpanList,
    scratch: CombineScratch,
}

/// Statistics of one or many evaluations.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EvalCounts {
    /// Tree nodes visited (leaves and operators).
    pub nodes_visited: u64,
    /// Nodes skipped because the ray misses their bounds.
    pub nodes_culled: u64,
}

impl Evaluator {
    pub fn new() -> Self {
        Self::default()
    }

    fn push_result(&mut self) -> &mut SpanList {
        if self.top == self.results.len() {
            self.results.push(SpanList::default());
        }
        let r = &mut self.results[self.top];
        r.clear();
        self.top += 1;
        r
    }

    /// The span list of `tree` (from `root`) along `ray`. `prim_hits` gives a
    /// primitive's crossings (directly, or from a mailbox). With `cull`, a
    /// node whose bounds (slightly inflated, so culling never changes the
    /// result) the ray misses contributes nothing without being visited.
    pub fn evaluate<F>(
        &mut self,
        tree: &CsgTree,
        root: NodeId,
        ray: &Ray,
        cull: bool,
        counts: &mut EvalCounts,
        mut prim_hits: F,
    ) -> &SpanList
    where
        F: FnMut(PrimId) -> PrimHits,
    {
        let culled = |n: NodeId| cull && tree.cull_bounds[n.index()].ray_interval(ray).is_none();
        // Both closures count; they never run at the same time.
        let (visited, skipped) = (Cell::new(0u64), Cell::new(0u64));
        let count = |out: bool| {
            let c = if out { &skipped } else { &visited };
            c.set(c.get() + 1);
            out
        };
        self.evaluate_with(
            tree,
            root,
            |n, p| {
                if count(culled(n)) {
                    PrimHits::Miss
                } else {
                    prim_hits(p)
                }
            },
            |n| count(culled(n)),
        );
        counts.nodes_visited += visited.get();
        counts.nodes_culled += skipped.get();
        &self.results[0]
    }

    /// The span list of `tree` from `root`, with the caller deciding per
    /// node: `leaf(node, prim)` gives a leaf's crossings (`Miss` for a leaf
    /// it culls), and `op_culled(node)` says an operator contributes
    /// nothing. For accelerators that keep per-ray caches of both (the
    /// cells' mailboxes, section 8). Culling must never change the result.
    pub fn evaluate_with<L, O>(
        &mut self,
        tree: &CsgTree,
        root: NodeId,
        mut leaf: L,
        mut op_culled: O,
    ) -> &SpanList
    where
        L: FnMut(NodeId, PrimId) -> PrimHits,
        O: FnMut(NodeId) -> bool,
    {
        self.top = 0;
        self.frames.clear();
        match self.enter(tree, root, &mut leaf, &mut op_culled) {
            Some(true) => {
                self.push_result();
                return &self.results[0];
            }
            Some(false) => return &self.results[0],
            None => {}
        }
        while let Some(&Frame {
            node,
            next_child,
            base,
            pending,
        }) = self.frames.last()
        {
            let CsgNode::Op { op, first, len } = tree.nodes[node.index()] else {
                unreachable!("only operators get frames")
            };
            // An empty operand empties an intersection, and an empty first
            // operand empties a difference: the rest is skipped. Empty
            // operands of unions and subtrahends change nothing and are
            // not kept.
            let empties =
                |child: usize| op == Op::Intersection || (op == Op::Difference && child == 0);
            let fi = self.frames.len() - 1;
            if pending {
                // The last child was an operator: its result is on top.
                self.frames[fi].pending = false;
                if self.results[self.top - 1].is_empty() {
                    if empties(next_child - 1) {
                        self.close_empty(base);
                        continue;
                    }
                    self.top -= 1;
                }
            }
            if next_child < len as usize {
                let c = tree.children[first as usize + next_child];
                self.frames[fi].next_child += 1;
                match self.enter(tree, c, &mut leaf, &mut op_culled) {
                    // A leaf, or a culled operator, with nothing: never kept.
                    Some(true) if empties(next_child) => self.close_empty(base),
                    Some(_) => {}
                    None => {
                        // Its frame is on top now; its result is looked at
                        // when it is done.
                        self.frames[fi].pending = true;
                    }
                }
                continue;
            }
            self.frames.pop();
            let n = self.top - base;
            if n == 0 {
                self.push_result();
            } else if n > 1 {
                combine(
                    op,
                    &self.results[base..self.top],
                    &mut self.tmp,
                    &mut self.scratch,
                );
                std::mem::swap(&mut self.results[base], &mut self.tmp);
                self.top = base + 1;
            }
            // n == 1: the single operand is the result (for an intersection
            // of one child, or a difference left with only its first).
        }
        &self.results[0]
    }

    /// Ends the top frame with an empty result (an operand emptied it).
    fn close_empty(&mut self, base: usize) {
        self.frames.pop();
        self.top = base;
        self.push_result();
    }

    /// The result of the last evaluation (until the next one).
    pub fn last_result(&self) -> &SpanList {
        &self.results[0]
    }

    /// Enters `node`: a leaf's crossings, or nothing for an operator
    /// `op_culled` culls, are its result at once (`Some(empty)`; an empty
    /// result is not pushed); any other operator gets a frame (`None`).
    #[inline]
    fn enter<L, O>(
        &mut self,
        tree: &CsgTree,
        node: NodeId,
        leaf: &mut L,
        op_culled: &mut O,
    ) -> Option<bool>
    where
        L: FnMut(NodeId, PrimId) -> PrimHits,
        O: FnMut(NodeId) -> bool,
    {
        match tree.nodes[node.index()] {
            CsgNode::Leaf(p) => {
                let hits = leaf(node, p);
                if matches!(hits, PrimHits::Miss) {
                    return Some(true);
                }
                let out = self.push_result();
                push_prim_hits(out, p, &hits);
                if out.is_empty() {
                    self.top -= 1;
                    return Some(true);
                }
                Some(false)
            }
            CsgNode::Op { .. } => {
                if op_culled(node) {
                    Some(true)
                } else {
                    self.frames.push(Frame {
                        node,
                        next_child: 0,
                        base: self.top,
                        pending: false,
                    });
                    None
                }
            }
        }
    }
}

/// A primitive's crossings as a span list.
pub fn push_prim_hits(out: &mut SpanList, prim: PrimId, hits: &PrimHits) {
    let b = |c: &super::Crossing| Boundary {
        t: c.t,
        prim,
        part: c.part,
        flip: false,
    };
    match hits {
        PrimHits::Miss => {}
        PrimHits::Solid { enter, exit } => out.spans.push(Span {
            enter: b(enter),
            exit: b(exit),
        }),
        PrimHits::Sheet { hits, count } => {
            out.sheets.extend(hits[..*count as usize].iter().map(b));
        }
    }
}
