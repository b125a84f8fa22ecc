//! Constructive solid geometry by span lists (Roth 1982): primitives, span
//! algebra, the CSG tree with its bounds (the paper's Algorithm 1) and its
//! per-region restriction (Algorithm 3). Pure computation: no I/O, no
//! threads, cannot fail.

pub mod eval;
pub mod exact;
pub mod shape;
pub mod span;
pub mod tree;

pub use eval::{EvalCounts, Evaluator};
pub use shape::{Crossing, Polygon, PrimHits, Primitive, Shape};
pub use span::{Boundary, Span, SpanList};
pub use tree::{CsgNode, CsgTree, NodeId, Op};

/// Index of a primitive in `Scene::primitives`.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Default,
    serde::Serialize,
    serde::Deserialize,
)]
pub struct PrimId(pub u32);

impl PrimId {
    pub fn index(self) -> usize {
        self.0 as usize
    }
}
