//! The CSG tree: an arena of n-ary operator nodes over primitive leaves, with
//! the node bounds and minimal primitive boxes of the paper's Algorithm 1.

use super::{PrimId, Primitive};
use crate::geom::Aabb;

/// Index of a node in `CsgTree::nodes`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct NodeId(pub u32);

impl NodeId {
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// The operators of `SCENE_FORMAT.md`, all n-ary.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Op {
    Union,
    Intersection,
    /// The first child minus all the others.
    Difference,
    /// The paper's null operator: children that do not overlap. Spans are
    /// concatenated, not merged, so overlapping children keep their inner
    /// faces (documented in `ARCHITECTURE.md`).
    Assembly,
}

#[derive(Clone, Debug, PartialEq)]
pub enum CsgNode {
    Leaf(PrimId),
    Op { op: Op, children: Vec<NodeId> },
}

/// A CSG tree. Nodes are stored children-before-parents, so a forward pass
/// is a post-order traversal (no recursion: trees may be 10,000 levels deep).
#[derive(Clone, Debug, Default)]
pub struct CsgTree {
    pub nodes: Vec<CsgNode>,
    pub root: Option<NodeId>,
    /// Per node, the bounds of what it can contain (Algorithm 1's first
    /// step). Empty for nodes that contain nothing (case 14).
    pub bounds: Vec<Aabb>,
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
        self.push(CsgNode::Op { op, children })
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
            let b = match &self.nodes[i] {
                CsgNode::Leaf(p) => prims[p.index()].bounds,
                CsgNode::Op { op, children } => {
                    let mut it = children.iter().map(|c| self.bounds[c.index()]);
                    match op {
                        Op::Union | Op::Assembly => it.fold(Aabb::EMPTY, |a, b| a.union(&b)),
                        Op::Intersection => it.fold(Aabb::EVERYTHING, |a, b| a.intersect(&b)),
                        Op::Difference => it.next().unwrap_or(Aabb::EMPTY),
                    }
                }
            };
            self.bounds.push(if b.is_empty() { Aabb::EMPTY } else { b });
        }
    }
}
