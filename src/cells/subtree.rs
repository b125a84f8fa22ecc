//! Distributing the CSG tree over the cells (section 6, Algorithm 3): each
//! cell keeps the minimal subtree over the primitives that reach into it.
//!
//! The paper's rules, generalised to n-ary operators, with "empty" for an
//! operand none of whose primitives reach the cell:
//! * union, assembly: the non-empty operands (one left: that operand);
//! * difference: empty if the first operand is; else the first minus the
//!   non-empty others (none left: the first);
//! * intersection: empty if any operand is.
//!
//! Only the ancestors of the cell's primitives are visited, so a cell costs
//! its primitives times the tree depth, never the whole tree.

use crate::csg::{CsgNode, CsgTree, NodeId, Op, PrimId};
use crate::geom::Aabb;

const NONE: u32 = u32::MAX;

/// Builds per-cell subtrees of one scene tree into an arena.
pub struct SubtreeBuilder<'a> {
    tree: &'a CsgTree,
    /// Per node of `tree`, its minimal box (Algorithm 1), for culling.
    minimal: &'a [Aabb],
    parent: Vec<u32>,
    /// Per node, its place among its parent's children.
    place: Vec<u32>,
    /// Per operator, the (place, result) of its children visited for the
    /// current cell, filled bottom-up.
    visited: Vec<Vec<(u32, u32)>>,
    /// Per primitive, its leaf node.
    leaf_of: Vec<u32>,
    stamp: Vec<u32>,
    generation: u32,
    result: Vec<u32>,
    marked: Vec<u32>,
}

impl<'a> SubtreeBuilder<'a> {
    pub fn new(tree: &'a CsgTree, minimal: &'a [Aabb], primitives: usize) -> Self {
        let mut parent = vec![NONE; tree.nodes.len()];
        let mut place = vec![0; tree.nodes.len()];
        let mut leaf_of = vec![NONE; primitives];
        for (i, n) in tree.nodes.iter().enumerate() {
            match n {
                CsgNode::Leaf(p) => leaf_of[p.index()] = i as u32,
                CsgNode::Op { .. } => {
                    for (k, c) in tree.children_of(NodeId(i as u32)).iter().enumerate() {
                        parent[c.index()] = i as u32;
                        place[c.index()] = k as u32;
                    }
                }
            }
        }
        SubtreeBuilder {
            tree,
            minimal,
            parent,
            place,
            visited: vec![Vec::new(); tree.nodes.len()],
            leaf_of,
            stamp: vec![0; tree.nodes.len()],
            generation: 0,
            result: vec![NONE; tree.nodes.len()],
            marked: Vec::new(),
        }
    }

    /// The subtree over `prims` (Algorithm 3), added to `arena`; None when
    /// nothing of the scene can be seen in the cell. `origin` gets, for
    /// every node added to the arena, the scene node it stands for (whose
    /// minimal box is its culling box), so that per-ray caches can be keyed
    /// by scene node across cells.
    pub fn build(
        &mut self,
        prims: &[u32],
        arena: &mut CsgTree,
        origin: &mut Vec<u32>,
    ) -> Option<NodeId> {
        let root = self.tree.root?;
        self.generation += 1;
        let g = self.generation;
        self.marked.clear();
        for &p in prims {
            let mut n = self.leaf_of[p as usize];
            while n != NONE && self.stamp[n as usize] != g {
                self.stamp[n as usize] = g;
                self.marked.push(n);
                n = self.parent[n as usize];
            }
        }
        // Children precede parents in the arena: ascending ids are bottom-up.
        self.marked.sort_unstable();
        let mut kids = Vec::new();
        for k in 0..self.marked.len() {
            let n = self.marked[k];
            let bounds = self.minimal[n as usize];
            let r = match self.tree.nodes[n as usize] {
                CsgNode::Leaf(p) => {
                    origin.push(n);
                    arena.leaf_with_bounds(PrimId(p.0), bounds).0
                }
                CsgNode::Op { op, .. } => {
                    // Only the children visited for this cell can be
                    // present (a flat union of thousands of primitives
                    // would otherwise cost every cell all its children).
                    kids.clear();
                    let visited = &mut self.visited[n as usize];
                    visited.sort_unstable();
                    kids.extend(visited.iter().filter(|v| v.1 != NONE).map(|v| NodeId(v.1)));
                    let first_empty = !visited.first().is_some_and(|v| v.0 == 0 && v.1 != NONE);
                    let any_empty = kids.len() < self.tree.children_of(NodeId(n)).len();
                    visited.clear();
                    let emptied = match op {
                        Op::Intersection => any_empty,
                        Op::Difference => first_empty,
                        Op::Union | Op::Assembly => kids.is_empty(),
                    };
                    if emptied {
                        NONE
                    } else if kids.len() == 1 {
                        kids[0].0
                    } else {
                        origin.push(n);
                        arena.op_with_bounds(op, kids.clone(), bounds).0
                    }
                }
            };
            self.result[n as usize] = r;
            let p = self.parent[n as usize];
            if p != NONE {
                self.visited[p as usize].push((self.place[n as usize], r));
            }
        }
        let r = if self.stamp[root.index()] == g {
            self.result[root.index()]
        } else {
            NONE
        };
        (r != NONE).then_some(NodeId(r))
    }
}
