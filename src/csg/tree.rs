//! The CSG tree: an arena of n-ary operator nodes over primitive leaves, with
//! the node bounds and minimal primitive boxes of the paper's Algorithm 1.

use super::{PrimId, Primitive};
use crate::geom::Aabb;

/// Index of a node in `CsgTree::nodes`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct NodeId(pub u32);

impl NodeId {
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// The operators of `SCENE_FORMAT.md`, all n-ary.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Op {
    Union,
    Intersection,
    /// The first child minus all the others.
    Difference,
    /// The paper's null operator: children that do not overlap. It combines
    /// exactly as a union (touching children merge, overlapping ones lose
    /// their inner faces), so it is never a source of inconsistency between
    /// the whole tree and a cell's subtree.
    Assembly,
}

/// A node: a primitive leaf, or an operator whose children are
/// `CsgTree::children[first..first + len]` (flat, so that thousands of
/// per-cell subtrees cost no allocation each).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum CsgNode {
    Leaf(PrimId),
    Op { op: Op, first: u32, len: u32 },
}

/// A CSG tree. Nodes are stored children-before-parents, so a forward pass
/// is a post-order traversal (no recursion: trees may be 10,000 levels deep).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CsgTree {
    pub nodes: Vec<CsgNode>,
    /// Operators' children, referenced by `CsgNode::Op::first/len`.
    pub children: Vec<NodeId>,
    pub root: Option<NodeId>,
    /// Per node, the bounds of what it can contain (Algorithm 1's first
    /// step). Empty for nodes that contain nothing (case 14).
    pub bounds: Vec<Aabb>,
    /// `bounds` inflated by a relative 1e-9, for culling: a conservative
    /// test, so culling never changes a span list.
    pub cull_bounds: Vec<Aabb>,
}

impl CsgTree {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn leaf(&mut self, prim: PrimId) -> NodeId {
        self.push(CsgNode::Leaf(prim))
    }

    /// Adds an operator over already-added children.
    pub fn op(&mut self, op: Op, children: Vec<NodeId>) -> NodeId {
        debug_assert!(children.iter().all(|c| c.index() < self.nodes.len()));
        let first = self.children.len() as u32;
        let len = children.len() as u32;
        self.children.extend(children);
        self.push(CsgNode::Op { op, first, len })
    }

    /// The children of `node` (empty for a leaf).
    pub fn children_of(&self, node: NodeId) -> &[NodeId] {
        match self.nodes[node.index()] {
            CsgNode::Leaf(_) => &[],
            CsgNode::Op { first, len, .. } => {
                &self.children[first as usize..(first + len) as usize]
            }
        }
    }

    /// The number of nodes reachable from `root` (the whole tree for the
    /// scene; a subtree for a cell).
    pub fn size_from(&self, root: NodeId) -> usize {
        let mut stack = vec![root];
        let mut n = 0;
        while let Some(x) = stack.pop() {
            n += 1;
            stack.extend_from_slice(self.children_of(x));
        }
        n
    }

    /// The primitives of the leaves reachable from `root`.
    pub fn prims_from(&self, root: NodeId) -> Vec<PrimId> {
        let mut stack = vec![root];
        let mut out = Vec::new();
        while let Some(x) = stack.pop() {
            match self.nodes[x.index()] {
                CsgNode::Leaf(p) => out.push(p),
                CsgNode::Op { .. } => stack.extend_from_slice(self.children_of(x)),
            }
        }
        out
    }

    /// Adds a leaf with its culling bounds given (for subtree arenas, whose
    /// nodes are never `finish`ed).
    pub fn leaf_with_bounds(&mut self, prim: PrimId, bounds: Aabb) -> NodeId {
        self.push_bounds(bounds);
        self.leaf(prim)
    }

    /// Adds an operator with its culling bounds given.
    pub fn op_with_bounds(&mut self, op: Op, children: Vec<NodeId>, bounds: Aabb) -> NodeId {
        self.push_bounds(bounds);
        self.op(op, children)
    }

    fn push_bounds(&mut self, b: Aabb) {
        self.bounds.push(b);
        self.cull_bounds.push(b.inflated(1e-9));
    }

    fn push(&mut self, n: CsgNode) -> NodeId {
        let id = NodeId(self.nodes.len() as u32);
        self.nodes.push(n);
        id
    }

    /// Sets the root and computes every node's bounds bottom-up from the
    /// primitives' world bounds (Algorithm 1, first step: boolean
    /// operations on boxes).
    pub fn finish(&mut self, root: NodeId, prims: &[Primitive]) {
        self.root = Some(root);
        self.bounds = Vec::with_capacity(self.nodes.len());
        for i in 0..self.nodes.len() {
            let b = match self.nodes[i] {
                CsgNode::Leaf(p) => prims[p.index()].bounds,
                CsgNode::Op { op, .. } => {
                    let mut it = self
                        .children_of(NodeId(i as u32))
                        .iter()
                        .map(|c| self.bounds[c.index()]);
                    match op {
                        Op::Union | Op::Assembly => it.fold(Aabb::EMPTY, |a, b| a.union(&b)),
                        Op::Intersection => it.fold(Aabb::EVERYTHING, |a, b| a.intersect(&b)),
                        Op::Difference => it.next().unwrap_or(Aabb::EMPTY),
                    }
                }
            };
            self.bounds.push(if b.is_empty() { Aabb::EMPTY } else { b });
        }
        self.cull_bounds = self.bounds.iter().map(|b| b.inflated(1e-9)).collect();
    }
}

impl CsgTree {
    /// The paper's Algorithm 1: each node's minimal box is the intersection
    /// of its own bounds with every ancestor's, so a primitive's box covers
    /// only the part of it that survives the operators above it (figure 1).
    /// Returned per node; for a leaf it is its primitive's minimal box, empty
    /// when nothing of the primitive can be seen (`ROBUSTNESS.md` case 14).
    /// Iterative: parents are visited before children by walking the
    /// children-before-parents arena backwards.
    ///
    /// An ancestor cuts a child by its box inflated as for culling (1e-9 of
    /// its magnitude), not by its exact box: a primitive's computed spans
    /// may reach past its exact box by their rounding, and Roth, which
    /// culls by the inflated boxes, then still meets the child there. A
    /// sphere of radius 1e30 reaching to 3 from the eye was entered, to
    /// rounding, at the eye: the box subtracted from it, cut by its exact
    /// box to a sliver, was left out of every cell, and the cells saw the
    /// sphere's far side where Roth saw the box's face.
    pub fn minimal_boxes(&self) -> Vec<Aabb> {
        let mut mini = vec![Aabb::EMPTY; self.nodes.len()];
        let Some(root) = self.root else { return mini };
        mini[root.index()] = self.bounds[root.index()];
        for i in (0..self.nodes.len()).rev() {
            let m = mini[i].inflated(1e-9);
            for c in self.children_of(NodeId(i as u32)) {
                mini[c.index()] = self.bounds[c.index()].intersect(&m);
            }
        }
        mini
    }
}
