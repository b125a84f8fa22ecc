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

    /// The first boundary with `t_min < t < t_max`. On equal `t` a solid's
    /// boundary is preferred to a surface's, and an entry to an exit (one
    /// fixed rule, so every accelerator picks the same one).
    pub fn first_between(&self, t_min: f64, t_max: f64) -> Option<Boundary> {
        let mut best: Option<Boundary> = None;
        let mut consider = |b: &Boundary| {
            if b.t > t_min && b.t < t_max && best.is_none_or(|x| b.t < x.t) {
                best = Some(*b);
            }
        };
        // Spans are sorted by entry; an assembly's may overlap, so scan all
        // (span lists are short).
        for s in &self.spans {
            consider(&s.enter);
            consider(&s.exit);
        }
        for b in &self.sheets {
            consider(b);
        }
        best
    }
}

/// One end of a child's span, as the sweep sees it.
#[derive(Clone, Copy, Debug)]
pub struct Event {
    t: f64,
    child: u32,
    /// +1 entering the child, -1 leaving it.
    delta: i32,
    boundary: Boundary,
}

/// Scratch space for `combine`, reused across calls so that the inner loop
/// does not allocate.
#[derive(Default, Debug)]
pub struct CombineScratch {
    events: Vec<Event>,
    depth: Vec<i32>,
}

use super::Op;

/// Combines the span lists of an operator's children into `out` (cleared
/// first) by one sweep over all their ends (Roth 1982, generalised to n-ary
/// operators).
///
/// Regularisation (`ROBUSTNESS.md`): all ends at the same `t` are applied
/// together before membership is looked at, so touching spans merge, spans
/// that would have zero length never appear, and coincident faces (A − B
/// with a shared face) cancel. The one tie rule: when several ends at the
/// same `t` change membership, the boundary kept is that of the lowest child
/// index (then the first of that child's ends). A subtracted child's ends
/// are cut surfaces: their `flip` is toggled so the normal faces out of the
/// result. An assembly (the paper's null operator) combines exactly as a
/// union: its children should not overlap, and where they touch (a wall of
/// boxes) the shared faces vanish as in a union, so every list is
/// normalised and a subtree that drops operators (Algorithm 3) gives the
/// same spans as the whole tree. Membership counts depth per child.
pub fn combine(op: Op, children: &[SpanList], out: &mut SpanList, scratch: &mut CombineScratch) {
    out.clear();
    if matches!(op, Op::Union | Op::Assembly) {
        for c in children {
            out.sheets.extend_from_slice(&c.sheets);
        }
        if children.len() > 1 {
            out.sheets.sort_by(|a, b| a.t.total_cmp(&b.t));
        }
    }
    let events = &mut scratch.events;
    events.clear();
    for (i, c) in children.iter().enumerate() {
        let flip = op == Op::Difference && i > 0;
        for s in &c.spans {
            let mut enter = s.enter;
            let mut exit = s.exit;
            enter.flip ^= flip;
            exit.flip ^= flip;
            events.push(Event {
                t: enter.t,
                child: i as u32,
                delta: 1,
                boundary: enter,
            });
            events.push(Event {
                t: exit.t,
                child: i as u32,
                delta: -1,
                boundary: exit,
            });
        }
    }
    // Stable sort by t keeps, among equal t, the order (child, span order),
    // which is what the tie rule needs.
    events.sort_by(|a, b| a.t.total_cmp(&b.t));
    let depth = &mut scratch.depth;
    depth.clear();
    depth.resize(children.len(), 0);
    let n = children.len();
    // Number of children (or subtracted children) we are currently inside.
    let mut inside_count = 0usize;
    let member = |depth: &[i32], inside_count: usize| -> bool {
        match op {
            Op::Union | Op::Assembly => inside_count > 0,
            Op::Intersection => inside_count == n,
            Op::Difference => depth[0] > 0 && inside_count == usize::from(depth[0] > 0),
        }
    };
    let mut open: Option<Boundary> = None;
    let mut i = 0;
    while i < events.len() {
        let t = events[i].t;
        let before = member(depth, inside_count);
        let mut j = i;
        while j < events.len() && events[j].t == t {
            let e = events[j];
            let d = &mut depth[e.child as usize];
            let was = *d > 0;
            *d += e.delta;
            let now = *d > 0;
            if was != now {
                if now {
                    inside_count += 1
                } else {
                    inside_count -= 1
                }
            }
            j += 1;
        }
        let after = member(depth, inside_count);
        if before != after {
            // The lowest-index end at this t that moves membership the same way.
            let entering = after;
            let chosen = events[i..j]
                .iter()
                .find(|e| {
                    let child_enters = e.delta > 0;
                    let subtracted = op == Op::Difference && e.child > 0;
                    (child_enters != subtracted) == entering
                })
                .or(events.get(i))
                .map(|e| e.boundary);
            if let Some(b) = chosen {
                if entering {
                    open = Some(b);
                } else if let Some(enter) = open.take() {
                    out.spans.push(Span { enter, exit: b });
                }
            }
        }
        i = j;
    }
}
