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
        self.enter(tree, root, &mut leaf, &mut op_culled);
        while let Some(f) = self.frames.last_mut() {
            let CsgNode::Op { op, first, len } = tree.nodes[f.node.index()] else {
                unreachable!("only operators get frames")
            };
            let children = &tree.children[first as usize..(first + len) as usize];
            if f.next_child > 0 {
                let last_empty = self.results[self.top - 1].is_empty();
                let first = f.next_child == 1;
                if last_empty {
                    // An empty operand empties an intersection, and an empty
                    // first operand empties a difference: skip the rest.
                    if op == Op::Intersection || (op == Op::Difference && first) {
                        let base = f.base;
                        self.frames.pop();
                        self.top = base;
                        self.push_result();
                        continue;
                    }
                    // Empty operands of unions and subtrahends change nothing.
                    self.top -= 1;
                }
            }
            if f.next_child < children.len() {
                let c = children[f.next_child];
                f.next_child += 1;
                self.enter(tree, c, &mut leaf, &mut op_culled);
                continue;
            }
            let base = f.base;
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

    /// The result of the last evaluation (until the next one).
    pub fn last_result(&self) -> &SpanList {
        &self.results[0]
    }

    #[inline]
    fn enter<L, O>(&mut self, tree: &CsgTree, node: NodeId, leaf: &mut L, op_culled: &mut O)
    where
        L: FnMut(NodeId, PrimId) -> PrimHits,
        O: FnMut(NodeId) -> bool,
    {
        match tree.nodes[node.index()] {
            CsgNode::Leaf(p) => {
                let hits = leaf(node, p);
                let out = self.push_result();
                push_prim_hits(out, p, &hits);
            }
            CsgNode::Op { .. } => {
                if op_culled(node) {
                    self.push_result();
                } else {
                    self.frames.push(Frame {
                        node,
                        next_child: 0,
                        base: self.top,
                    })
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
