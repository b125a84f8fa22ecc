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
        if out.sheets.len() > 1 {
            out.sheets.sort_by(|a, b| a.t.total_cmp(&b.t));
        }
    }
    if let [a, b] = children
        && let ([a], [b]) = (&a.spans[..], &b.spans[..])
    {
        // Most combinations are of two single spans (a cell's subtree in
        // its window: A − B, A ∪ B); their sweep, worked out.
        two_spans(op, a, b, out);
        return;
    }
    combine_by_sweep(op, children, out, scratch);
}

/// `combine`'s spans by the sweep itself, for any children (`out`'s
/// sheets already combined, its spans empty).
fn combine_by_sweep(
    op: Op,
    children: &[SpanList],
    out: &mut SpanList,
    scratch: &mut CombineScratch,
) {
    let events = &mut scratch.events;
    events.clear();
    for (i, c) in children.iter().enumerate() {
        for s in &c.spans {
            events.extend(ends_of(op, i, s));
        }
    }
    // Stable sort by t keeps, among equal t, the order (child, span order),
    // which is what the tie rule needs.
    events.sort_by(|a, b| a.t.total_cmp(&b.t));
    let depth = &mut scratch.depth;
    depth.clear();
    depth.resize(children.len(), 0);
    sweep(op, events, depth, out);
}

/// `combine`'s sweep for two children of one span each, `a` of the first
/// child and `b` of the second, into `out`'s spans (cleared).
///
/// The sweep sorts the four ends by `t` (`total_cmp`, stably: `a`'s ends
/// before `b`'s on equal keys), applies the ends of equal `t` (`==`) as one
/// group, and where membership changes keeps the group's first end that
/// moves it that way. An end of `b` can share a group with one of `a`
/// only, so each choice below is between two ends: `first(x, y)`, whether
/// the sweep's order puts `a`'s end (at `x`) before `b`'s (at `y`). Only
/// a signed zero makes that differ from "`a`'s end first" in a group:
/// `total_cmp` puts −0 before +0, `==` groups them.
#[inline]
fn two_spans(op: Op, a: &Span, b: &Span, out: &mut SpanList) {
    let first = |x: f64, y: f64| x.total_cmp(&y).is_le();
    let (a0, a1, b0, b1) = (a.enter.t, a.exit.t, b.enter.t, b.exit.t);
    let mut push = |enter: Boundary, exit: Boundary| out.spans.push(Span { enter, exit });
    match op {
        Op::Union | Op::Assembly => {
            if a0 <= b1 && b0 <= a1 {
                // Overlapping or touching: one span, from the earlier entry
                // to the later exit; a touching pair's shared group changes
                // nothing.
                let enter = if a0 < b0 || (a0 == b0 && first(a0, b0)) {
                    a.enter
                } else {
                    b.enter
                };
                let exit = if a1 > b1 || (a1 == b1 && first(a1, b1)) {
                    a.exit
                } else {
                    b.exit
                };
                push(enter, exit);
            } else if a1 < b0 {
                push(a.enter, a.exit);
                push(b.enter, b.exit);
            } else {
                push(b.enter, b.exit);
                push(a.enter, a.exit);
            }
        }
        Op::Intersection => {
            // From the later entry to the earlier exit, if that is a span;
            // an entry and an exit at the same `t` change nothing.
            let (lo, enter) = if a0 > b0 || (a0 == b0 && first(a0, b0)) {
                (a0, a.enter)
            } else {
                (b0, b.enter)
            };
            let (hi, exit) = if a1 < b1 || (a1 == b1 && first(a1, b1)) {
                (a1, a.exit)
            } else {
                (b1, b.exit)
            };
            if lo < hi {
                push(enter, exit);
            }
        }
        Op::Difference => {
            // `b`'s ends are cut surfaces.
            let cut = |x: Boundary| Boundary { flip: !x.flip, ..x };
            if b1 <= a0 || b0 >= a1 {
                // `b` leaves `a` whole. At a shared `t` the entry may be
                // `b`'s exit, or the exit `b`'s entry: whichever the sweep
                // has first, as both move membership the same way.
                let enter = if b1 == a0 && !first(a0, b1) {
                    cut(b.exit)
                } else {
                    a.enter
                };
                let exit = if b0 == a1 && !first(a1, b0) {
                    cut(b.enter)
                } else {
                    a.exit
                };
                push(enter, exit);
            } else {
                // `b` overlaps `a`'s inside: what is left before and after
                // it (no end of `a` can share `b0` or `b1` here).
                if a0 < b0 {
                    push(a.enter, cut(b.enter));
                }
                if b1 < a1 {
                    push(cut(b.exit), a.exit);
                }
            }
        }
    }
}

/// The two ends of child `i`'s span `s`, as `combine`'s sweep sees them:
/// a subtracted child's ends are cut surfaces (`flip` toggled).
#[inline(always)]
fn ends_of(op: Op, i: usize, s: &Span) -> [Event; 2] {
    let flip = op == Op::Difference && i > 0;
    let (mut enter, mut exit) = (s.enter, s.exit);
    enter.flip ^= flip;
    exit.flip ^= flip;
    [
        Event {
            t: enter.t,
            child: i as u32,
            delta: 1,
            boundary: enter,
        },
        Event {
            t: exit.t,
            child: i as u32,
            delta: -1,
            boundary: exit,
        },
    ]
}

/// `combine`'s sweep over the children's ends, sorted by `t` (stably, so
/// that among equal `t` they keep the order child, then span), with
/// `depth` zeroed, one per child.
#[inline(always)]
fn sweep(op: Op, events: &[Event], depth: &mut [i32], out: &mut SpanList) {
    let n = depth.len();
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Ends drawn from few values, signed zeros among them, so that ties
    /// of every kind are common.
    const TS: [f64; 6] = [-1.0, -0.0, 0.0, 1.0, 2.0, 3.0];

    fn boundary(t: f64, prim: u32, flip: bool) -> Boundary {
        Boundary {
            t,
            prim: PrimId(prim),
            part: prim as u8,
            flip,
        }
    }

    fn span_strategy(prim: u32) -> impl Strategy<Value = Span> {
        (0..TS.len(), 0..TS.len(), any::<bool>(), any::<bool>())
            .prop_filter("enter before exit", |(i, j, ..)| TS[*i] < TS[*j])
            .prop_map(move |(i, j, f0, f1)| Span {
                enter: boundary(TS[i], prim, f0),
                exit: boundary(TS[j], prim + 1, f1),
            })
    }

    fn op_strategy() -> impl Strategy<Value = Op> {
        prop_oneof![
            Just(Op::Union),
            Just(Op::Assembly),
            Just(Op::Intersection),
            Just(Op::Difference),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        /// The worked-out sweep of two single spans is the sweep's, end
        /// for end (which boundary, which flip), signed zeros included.
        #[test]
        fn two_single_spans_combine_as_the_sweep_does(
            op in op_strategy(),
            a in span_strategy(0),
            b in span_strategy(10),
        ) {
            let children = [
                SpanList { spans: vec![a], sheets: Vec::new() },
                SpanList { spans: vec![b], sheets: Vec::new() },
            ];
            let mut fast = SpanList::default();
            combine(op, &children, &mut fast, &mut CombineScratch::default());
            let mut swept = SpanList::default();
            combine_by_sweep(op, &children, &mut swept, &mut CombineScratch::default());
            prop_assert_eq!(&fast.spans, &swept.spans);
            // Bit for bit, as `==` takes −0 for +0.
            let bits = |l: &SpanList| -> Vec<(u64, u64)> {
                l.spans.iter().map(|s| (s.enter.t.to_bits(), s.exit.t.to_bits())).collect()
            };
            prop_assert_eq!(bits(&fast), bits(&swept));
        }
    }
}
