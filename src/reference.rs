//! Roth's brute force, the oracle (`--accel roth`): every ray against the
//! whole CSG tree, with bounding-box culling at tree nodes (which never
//! changes a span list, see `CsgTree::cull_bounds`). Written for
//! obviousness; every faster path is tested against it.

use crate::csg::{EvalCounts, Evaluator, PrimHits, PrimId};
use crate::geom::Ray;
use crate::scene::Scene;
use crate::trace::{Hit, Tracer};

/// The brute-force tracer of one thread.
pub struct RothTracer<'a> {
    scene: &'a Scene,
    eval: Evaluator,
    /// Primitive intersection tests performed.
    pub intersection_tests: u64,
    pub counts: EvalCounts,
    /// The primitive the current job's ray leaves (`Tracer::leaving`).
    leaving: Option<PrimId>,
}

impl<'a> RothTracer<'a> {
    pub fn new(scene: &'a Scene) -> Self {
        RothTracer {
            scene,
            eval: Evaluator::new(),
            intersection_tests: 0,
            counts: EvalCounts::default(),
            leaving: None,
        }
    }

    /// The span list of the whole tree along `ray` (for tests).
    pub fn spans(&mut self, ray: &Ray) -> crate::csg::SpanList {
        let Some(root) = self.scene.tree.root else {
            return Default::default();
        };
        let prims = &self.scene.primitives;
        let tests = &mut self.intersection_tests;
        self.eval
            .evaluate(&self.scene.tree, root, ray, true, &mut self.counts, |p| {
                *tests += 1;
                prims[p.index()].intersect(ray)
            })
            .clone()
    }
}

impl Tracer for RothTracer<'_> {
    fn nearest(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        let root = self.scene.tree.root?;
        let prims = &self.scene.primitives;
        let tests = &mut self.intersection_tests;
        let leaving = self.leaving;
        let spans = self
            .eval
            .evaluate(&self.scene.tree, root, ray, true, &mut self.counts, |p| {
                if Some(p) == leaving {
                    return PrimHits::Miss;
                }
                *tests += 1;
                let h: PrimHits = prims[p.index()].intersect(ray);
                h
            });
        spans.first_between(t_min, t_max).map(Hit::from)
    }

    fn leaving(&mut self, prim: Option<PrimId>) {
        self.leaving = prim;
    }

    fn counters(&self) -> crate::render::TraceCounters {
        crate::render::TraceCounters {
            intersection_tests: self.intersection_tests,
            ..Default::default()
        }
    }
}
