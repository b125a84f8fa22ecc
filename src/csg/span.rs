//! Span lists: the intervals of a ray inside a solid, with the primitive and
//! part that bound each end (Roth 1982). The combination rules live here.

use super::PrimId;

/// One end of a span: where the ray crosses a primitive's surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Boundary {
    pub t: f64,
    pub prim: PrimId,
    /// The primitive's surface part (see `csg::Shape`).
    pub part: u8,
    /// True when the surface is a cut made by a subtracted child: its
    /// outward normal is the primitive's normal reversed.
    pub flip: bool,
}

/// An interval `[enter.t, exit.t]` of the ray inside a solid, `enter.t < exit.t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Span {
    pub enter: Boundary,
    pub exit: Boundary,
}

/// What a CSG (sub)tree contributes along a ray: sorted, disjoint,
/// non-touching spans of its solids, and the crossings of its surfaces
/// (which only unions and assemblies may hold), sorted by `t`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SpanList {
    pub spans: Vec<Span>,
    pub sheets: Vec<Boundary>,
}

impl SpanList {
    pub fn is_empty(&self) -> bool {
        self.spans.is_empty() && self.sheets.is_empty()
    }

    pub fn clear(&mut self) {
        self.spans.clear();
        self.sheets.clear();
    }
}
