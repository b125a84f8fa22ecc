//! The paper's cells against Roth's brute force: random CSG scenes render
//! bit-identically with both (issue 3), and the cell cases of
//! `ROBUSTNESS.md` (14-21, 27, 28), each against Roth or an exact value,
//! each checking that no t, normal, cell bound or pixel is NaN or infinite.

use std::path::Path;
use std::sync::Mutex;

use hypercast::cells::traverse::{RegionRay, Step};
use hypercast::cells::{CellOptions, CellStructure, CellTracer, NO_SUBTREE, Region, SegmentChoice};
use hypercast::csg::{CsgNode, NodeId, PrimId, Shape};
use hypercast::r#gen::random::{CameraPlacement, RandomCsgOptions, random_csg};
use hypercast::geom::{Aabb, Ray, Vec3};
use hypercast::reference::RothTracer;
use hypercast::render::{RenderOptions, render_cells, render_roth, render_with};
use hypercast::scene::load::{compile_model, scene_to_string};
use hypercast::scene::model::{self, Node, SceneFile};
use hypercast::scene::{Scene, SceneSyntax, parse_scene_str};
use hypercast::trace::{CameraFrame, Film, Hit, Tracer};

// ---------------------------------------------------------------------------
// Helpers.

pub(crate) fn load(ron: &str) -> Scene {
    parse_scene_str(ron, SceneSyntax::Ron, Path::new("cells.ron"))
        .unwrap_or_else(|e| panic!("{e}\n{ron}"))
}

fn options(width: u32, height: u32) -> RenderOptions {
    RenderOptions {
        width,
        height,
        spp: 1,
        threads: 2,
    }
}

/// Both ways of cutting the screen plane: the default cost model, which
/// may leave a small scene uncut, and the paper's rule, which cuts along
/// every rectangle edge (so that cell boundaries lie where a test puts them).
const CHOICES: [SegmentChoice; 2] = [SegmentChoice::Sampled, SegmentChoice::FewestSplits];

/// The structures of `scene` for `CHOICES`.
pub(crate) fn structures(scene: &Scene, width: u32, height: u32) -> Vec<CellStructure> {
    CHOICES
        .iter()
        .map(|&choice| {
            let cs = CellStructure::build(
                scene,
                width,
                height,
                CellOptions {
                    choice,
                    ..Default::default()
                },
            )
            .unwrap();
            assert_cell_bounds_not_nan(&cs);
            cs
        })
        .collect()
}

/// Pixels are fixed-point sums (NaN cannot be stored, and `Film::quantize`
/// debug-asserts finite contributions, which debug test builds check).
fn assert_pixels_finite(film: &Film) {
    for (i, p) in film.to_linear().iter().enumerate() {
        assert!(p.iter().all(|c| c.is_finite()), "pixel {i} is {p:?}");
    }
}

/// Every cell bound is a number: finite, or ±∞ at the plane's edges.
fn assert_cell_bounds_not_nan(cs: &CellStructure) {
    for rc in &cs.regions {
        for (s, leaf) in rc.partition.leaves.iter().enumerate() {
            let r = leaf.rect;
            assert!(
                ![r.x0, r.x1, r.y0, r.y1].iter().any(|v| v.is_nan()),
                "{:?} super cell {s}: {r:?}",
                rc.region
            );
            assert!(
                r.x0 <= r.x1 && r.y0 <= r.y1,
                "{:?} super cell {s}: {r:?}",
                rc.region
            );
        }
        for (k, c) in rc.cells().enumerate() {
            assert!(
                !c.zlo.is_nan() && !c.zhi.is_nan() && c.zlo <= c.zhi,
                "{:?} cell {k}: {c:?}",
                rc.region
            );
        }
    }
}

/// Renders at `width`×`height` with Roth and with cells built by each of
/// `choices`, and asserts identical films; returns Roth's film and the
/// structures.
pub(crate) fn assert_renders_equal_with(
    scene: &Scene,
    width: u32,
    height: u32,
    choices: &[SegmentChoice],
) -> (Film, Vec<CellStructure>) {
    let opts = options(width, height);
    let (roth, _) = render_roth(scene, &opts, &|_| {});
    assert_pixels_finite(&roth);
    let mut out = Vec::new();
    for &choice in choices {
        let cells = std::panic::catch_unwind(|| {
            render_cells(
                scene,
                &opts,
                CellOptions {
                    choice,
                    ..Default::default()
                },
                &|_| {},
            )
        });
        let Ok((film, _, cs)) = cells else {
            panic!(
                "cells ({choice:?}) panicked:\n{}",
                differences(scene, &opts, choice)
            );
        };
        assert_pixels_finite(&film);
        assert_cell_bounds_not_nan(&cs);
        if roth.sums() != film.sums() {
            panic!(
                "cells ({choice:?}) and Roth differ:\n{}",
                differences(scene, &opts, choice)
            );
        }
        out.push(cs);
    }
    (roth, out)
}

pub(crate) fn assert_renders_equal(
    scene: &Scene,
    width: u32,
    height: u32,
) -> (Film, Vec<CellStructure>) {
    assert_renders_equal_with(scene, width, height, &CHOICES)
}

/// Checks a hit's t and normal and returns the normal (unit, finite).
pub(crate) fn checked_normal(scene: &Scene, ray: &Ray, h: &Hit) -> Vec3 {
    assert!(h.t.is_finite(), "t = {} for {ray:?}", h.t);
    let n = scene.primitives[h.prim.index()].normal(ray, h.t, h.part);
    let n = if h.flip { -n } else { n };
    assert!(
        n.is_finite() && (n.length() - 1.0).abs() < 1e-9,
        "normal {n} at t = {} for {ray:?}",
        h.t
    );
    n
}

/// The nearest hit with `t_min < t < t_max` by both tracers, asserted equal.
pub(crate) fn nearest_both(
    scene: &Scene,
    cs: &CellStructure,
    ray: &Ray,
    t_min: f64,
    t_max: f64,
) -> Option<Hit> {
    let a = RothTracer::new(scene).nearest(ray, t_min, t_max);
    let b = CellTracer::new(cs, scene).nearest(ray, t_min, t_max);
    assert_eq!(
        a, b,
        "Roth (left) and cells (right) differ for {ray:?} in ({t_min}, {t_max})"
    );
    if let Some(h) = &a {
        checked_normal(scene, ray, h);
    }
    a
}

/// Every boundary along the ray after `t_min`, by repeated `nearest` calls
/// of both tracers (asserted equal and strictly increasing in t).
pub(crate) fn hits_along(scene: &Scene, cs: &CellStructure, ray: &Ray, t_min: f64) -> Vec<Hit> {
    let mut out: Vec<Hit> = Vec::new();
    let mut t = t_min;
    while let Some(h) = nearest_both(scene, cs, ray, t, f64::INFINITY) {
        assert!(h.t > t, "hit t {} not after {t}", h.t);
        t = h.t;
        out.push(h);
        assert!(out.len() < 1000, "endless hits along {ray:?}");
    }
    out
}

/// Hits are of the given primitives at the given t (to 1e-12 relative).
fn assert_hits(hits: &[Hit], expected: &[(u32, f64)]) {
    let got: Vec<(u32, f64)> = hits.iter().map(|h| (h.prim.0, h.t)).collect();
    let close = got.len() == expected.len()
        && got
            .iter()
            .zip(expected)
            .all(|(g, e)| g.0 == e.0 && (g.1 - e.1).abs() <= 1e-12 * e.1.abs().max(1.0));
    assert!(close, "hits {got:?}, expected {expected:?}");
}

/// A cell visited by a walk: region, cell index, entry and exit t.
pub(crate) type Visit = (Region, u32, f64, f64);

/// The cells a ray crosses after `t_min`, as `CellTracer::nearest` walks
/// them, asserting that the walk ends within the number of cells, never
/// visits a cell twice (cells are convex) and that the entry t never
/// decreases.
pub(crate) fn walk(cs: &CellStructure, ray: &Ray, t_min: f64) -> Vec<Visit> {
    let cam = cs.view.ray(ray);
    let mut order = [Region::Front, Region::Back];
    if cam.d.z > 0.0 {
        order.swap(0, 1);
    }
    let mut out: Vec<Visit> = Vec::new();
    let mut last_t = f64::NEG_INFINITY;
    for region in order {
        let (lo, hi) = cam.region_interval(region);
        let lo = lo.max(t_min);
        // Written so that a NaN bound also skips the region.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(lo < hi) {
            continue;
        }
        let rr = RegionRay::new(region, cam);
        let mut c = cs.locate(&rr, lo);
        let mut t_in = lo;
        loop {
            assert!(
                out.len() <= cs.stats.cells,
                "the walk of {ray:?} takes more steps than there are cells"
            );
            assert!(
                t_in >= last_t && !t_in.is_nan(),
                "entry t went from {last_t} to {t_in} along {ray:?}"
            );
            assert!(
                !out.iter().any(|v| v.0 == region && v.1 == c.cell),
                "cell {c:?} visited twice along {ray:?}"
            );
            last_t = t_in;
            let (t_out, next) = cs.step(&rr, c, t_in);
            assert!(
                t_out >= t_in,
                "cell {c:?} exited at {t_out} before its entry {t_in}"
            );
            out.push((region, c.cell, t_in, t_out));
            match next {
                Step::Next(n, t) if t < hi => {
                    c = n;
                    t_in = t;
                }
                _ => break,
            }
        }
    }
    out
}

/// Primitives referenced by a subtree of the cells' arena.
fn subtree_prims(cs: &CellStructure, root: u32) -> Vec<PrimId> {
    let mut out = Vec::new();
    let mut stack = vec![NodeId(root)];
    while let Some(n) = stack.pop() {
        match cs.subtrees.nodes[n.index()] {
            CsgNode::Leaf(p) => out.push(p),
            CsgNode::Op { .. } => stack.extend_from_slice(cs.subtrees.children_of(n)),
        }
    }
    out
}

/// A tracer that asks both accelerators and records every ray where they
/// differ, for reproducing a failing render.
struct Compare<'a> {
    roth: RothTracer<'a>,
    cells: CellTracer<'a>,
    diffs: &'a Mutex<Vec<String>>,
    /// The primitive the current ray leaves (`Tracer::leaving`).
    leaving: Option<PrimId>,
}

impl Tracer for Compare<'_> {
    fn leaving(&mut self, prim: Option<PrimId>) {
        self.leaving = prim;
        self.roth.leaving(prim);
        self.cells.leaving(prim);
    }

    fn toward(&mut self, light: Option<u16>) {
        self.cells.toward(light);
    }

    fn nearest(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        let a = self.roth.nearest(ray, t_min, t_max);
        // A failed debug assertion in the walk is a difference too.
        let b = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            self.cells.nearest(ray, t_min, t_max)
        }))
        .map_err(|_| "a panic");
        if b != Ok(a) {
            self.diffs.lock().unwrap().push(format!(
                "ray origin {:?} dir {:?} in ({t_min:e}, {t_max:e}) leaving {:?}: roth {a:?}, cells {b:?}",
                ray.origin.to_array(),
                ray.dir.to_array(),
                self.leaving,
            ));
        }
        a
    }

    /// A shadow ray's answer is whether something blocks it: each tracer
    /// may stop at another blocker (`CellTracer::walk_shadow`).
    fn shadow(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        let a = self.roth.shadow(ray, t_min, t_max);
        let b = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            self.cells.shadow(ray, t_min, t_max)
        }))
        .map(|b| b.is_some())
        .map_err(|_| "a panic");
        if b != Ok(a.is_some()) {
            self.diffs.lock().unwrap().push(format!(
                "shadow ray origin {:?} dir {:?} in ({t_min:e}, {t_max:e}) leaving {:?}: roth {a:?}, cells blocked {b:?}",
                ray.origin.to_array(),
                ray.dir.to_array(),
                self.leaving,
            ));
        }
        a
    }
}

/// Where cells and Roth disagree: primary rays wrongly skipped as
/// background, and every ray (primary or secondary, in the order the
/// renderer traces them) whose nearest hit differs, with its exact numbers.
fn differences(scene: &Scene, opts: &RenderOptions, choice: SegmentChoice) -> String {
    let cs = CellStructure::build(
        scene,
        opts.width,
        opts.height,
        CellOptions {
            choice,
            ..Default::default()
        },
    )
    .unwrap();
    let mut out = String::new();
    let cam = CameraFrame::new(scene, opts.width, opts.height);
    let mut roth = RothTracer::new(scene);
    for j in 0..opts.height {
        for i in 0..opts.width {
            let ray = cam.primary(i, j, 0.5, 0.5, 1.0).ray;
            if CellTracer::primary_is_background(&cs, &ray)
                && roth.nearest(&ray, 0.0, f64::INFINITY).is_some()
            {
                out += &format!(
                    "pixel ({i}, {j}) skipped as background, but Roth hits along {ray:?}\n"
                );
            }
        }
    }
    let diffs = Mutex::new(Vec::new());
    let one = RenderOptions {
        threads: 1,
        ..opts.clone()
    };
    render_with(
        scene,
        &one,
        || Compare {
            roth: RothTracer::new(scene),
            cells: CellTracer::new(&cs, scene),
            diffs: &diffs,
            leaving: None,
        },
        |_, _| false,
        &|_| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let diffs = diffs.into_inner().unwrap();
    out += &format!("{} rays differ\n", diffs.len());
    for d in diffs.iter().take(10) {
        out += d;
        out += "\n";
    }
    out
}

// ---------------------------------------------------------------------------
// Issue 3: random CSG scenes.

/// 400 random scenes of 1 to 60 primitives (random transforms, every
/// operator and primitive, surfaces, mirrors and glass, cameras outside,
/// inside, and with most of the scene behind the eye) render bit-identically
/// with Roth and with cells, both ways of cutting the screen. A failure
/// prints the seed, the scene as RON and the rays that differ.
#[test]
fn random_csg_scenes_render_identically_with_cells_and_roth() {
    let mut failures = Vec::new();
    for seed in seeds(0..400) {
        let (model, about) = random_scene(seed);
        // Through RON, so that the printed text is exactly what was tested.
        let ron = scene_to_string(&model, SceneSyntax::Ron).unwrap();
        let scene = load(&ron);
        let r = random_scene_options();
        let (roth, _) = render_roth(&scene, &r, &|_| {});
        assert_pixels_finite(&roth);
        for choice in CHOICES {
            let cells = std::panic::catch_unwind(|| {
                render_cells(
                    &scene,
                    &r,
                    CellOptions {
                        choice,
                        ..Default::default()
                    },
                    &|_| {},
                )
            });
            let Ok((film, _, cs)) = cells else {
                eprintln!(
                    "{about}: cells ({choice:?}) panicked\n{}\n{ron}",
                    differences(&scene, &r, choice)
                );
                failures.push((seed, choice));
                continue;
            };
            assert_cell_bounds_not_nan(&cs);
            if roth.sums() != film.sums() {
                eprintln!(
                    "{about}: cells ({choice:?}) and Roth differ\n{}\n{ron}",
                    differences(&scene, &r, choice)
                );
                failures.push((seed, choice));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "seeds where cells and Roth differ: {failures:?}"
    );
}

/// The eye on the boundary of a minimal box (Algorithm 1), every other
/// seed that of a Box primitive, one in five at a cone's apex or a
/// polygon's vertex: on a face, an edge or a corner, exactly or nudged in
/// or out by a little more than the build's rounding bands, looking into
/// the box, along its face or away from it. There the box's
/// projection has no bounds, and every side plane of the screen system
/// passes next to the box's boundary: the case a hunt found once by
/// chance (seed 58571 of `random_rays_in_random_scenes_hit_what_roth_hits`,
/// the eye on a box's top face). 120 lit random scenes, half with mirrors
/// and glass, render bit-identically with Roth and with cells, both ways
/// of cutting the screen; and rays the image does not shoot (aimed at the
/// eye from inside the box, leaving from the eye, through cell corners)
/// hit what Roth's hit. Seed 2731, the first of 20,000 to fail, found
/// boxes holding the eye clipped away (`cells::EyeAt::Inside`), and seed
/// 47615, the only one of 30,000..60,000 after that, a cone's roots
/// blurred at its apex (`shape::cone_discriminant`); the rays
/// aimed at the eye are scaled so that rounding puts their crossing there
/// a little before or past it, without which it passed. (Before that fix,
/// with the band of `View::eye_near_boundary` cut back to leave out an
/// eye on the face of a minimal box, as when seed 58571 failed, 8 seeds
/// of 0..4,000 failed here; the fix covers that case too.)
#[test]
fn random_scenes_seen_from_a_box_face_edge_or_corner_render_identically() {
    let mut failures = Vec::new();
    let mut placed = 0;
    // And seeds a hunt once found failing, always: 2731 puts the eye on an
    // edge of a box inside the boxes of the other operands of its
    // intersection (`cells::EyeAt::Inside`); 47615 on the corner of a
    // cone's box that is its apex, where a ray aimed at the eye met the
    // cone short of it, outside its box (`shape::cone_discriminant`).
    for seed in seeds(0..120).chain([2731, 47615]) {
        let (primitives, mut model) = lit_random_scene(seed, 40);
        let scene = load(&scene_to_string(&model, SceneSyntax::Ron).unwrap());
        let mut next = xorshift(0xA076_1D64_78BD_642F ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let Some((b, eye, first, fixed)) = on_a_box_boundary(&scene, seed, &mut next) else {
            continue;
        };
        let centre = (b.min + b.max) * 0.5;
        let free = (first + fixed) % 3;
        let dir = match seed / 3 % 3 {
            0 => centre - eye,
            1 => {
                // Along the face (or edge): the free axis, tilted a little.
                let mut d = Vec3::ZERO;
                d[free] = 1.0;
                d + (centre - eye).normalize_or_zero() * 0.01
            }
            _ => eye - centre,
        };
        if dir == Vec3::ZERO {
            continue;
        }
        let dir = dir.normalize();
        model.camera.eye = eye.to_array();
        model.camera.look_at = (eye + dir).to_array();
        model.camera.up = if dir.z.abs() > 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        let ron = scene_to_string(&model, SceneSyntax::Ron).unwrap();
        let scene = load(&ron);
        placed += 1;
        let r = random_scene_options();
        let (roth, _) = render_roth(&scene, &r, &|_| {});
        assert_pixels_finite(&roth);
        for choice in CHOICES {
            let opts = CellOptions {
                choice,
                ..Default::default()
            };
            let cells = std::panic::catch_unwind(|| render_cells(&scene, &r, opts, &|_| {}));
            let same = match &cells {
                Ok((film, _, cs)) => {
                    assert_cell_bounds_not_nan(cs);
                    roth.sums() == film.sums()
                }
                Err(_) => false,
            };
            if !same {
                eprintln!(
                    "seed {seed}, {primitives} primitives, eye {eye:?} on {fixed} faces of {b:?}: \
                     cells ({choice:?}) and Roth differ\n{}\n{ron}",
                    differences(&scene, &r, choice)
                );
                failures.push((seed, choice));
            }
        }
        // Rays the image does not shoot: aimed at the eye from inside the
        // box or anywhere, leaving from the eye itself, or through a cell
        // corner (rays of a walk meet the eye only by rounding, so their
        // hits must agree however they pass it).
        let choice = CHOICES[(seed / 9 % 2) as usize];
        let opts = CellOptions {
            choice,
            ..Default::default()
        };
        let cs = CellStructure::build(&scene, r.width, r.height, opts).unwrap();
        let mut roth_tracer = RothTracer::new(&scene);
        let mut tracer = CellTracer::new(&cs, &scene);
        let point = |next: &mut dyn FnMut() -> u64, inside: bool| {
            let u = Vec3::new(unit(next()), unit(next()), unit(next()));
            if inside {
                b.min + (b.max - b.min) * u
            } else {
                (u * 2.0 - 1.0) * 15.0
            }
        };
        for k in 0..150 {
            let (o, d) = match k % 4 {
                // Scaled, so that rounding puts the eye's `t` a little
                // before or past the crossing there (a ray from inside the
                // box may leave it just past the eye, in the front region
                // after the eye plane).
                0 | 1 => {
                    let o = point(&mut next, k % 4 == 0);
                    (o, (eye - o) * (0.1 + 10.0 * unit(next())))
                }
                2 => (eye, point(&mut next, k % 8 == 2) - eye),
                _ => {
                    let o = point(&mut next, false);
                    let u = [0; 4].map(|_| unit(next()).min(0.999_999));
                    (o, cell_corner(&cs, u).map_or(eye - o, |c| c - o))
                }
            };
            if d == Vec3::ZERO {
                continue;
            }
            let ray = Ray::new(o, d);
            let a = roth_tracer.nearest(&ray, 0.0, f64::INFINITY);
            let c = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                tracer.nearest(&ray, 0.0, f64::INFINITY)
            }));
            if c.as_ref().map_or(true, |c| *c != a) {
                eprintln!(
                    "seed {seed}, eye {eye:?} on {fixed} faces of {b:?}, {choice:?}: ray origin {:?} \
                     dir {:?}: roth {a:?}, cells {:?}\n{ron}",
                    o.to_array(),
                    d.to_array(),
                    c.map_err(|_| "a panic")
                );
                failures.push((seed, choice));
                break;
            }
        }
    }
    assert_agreed_where_placed(&failures, placed, seeds(0..120).count(), "cameras");
}

/// The end of a test that places a point on a minimal box's boundary:
/// cells and Roth agree on every seed, and at least nine seeds in ten of
/// `tried` had a point placed.
fn assert_agreed_where_placed<T: std::fmt::Debug>(
    failures: &[T],
    placed: usize,
    tried: usize,
    what: &str,
) {
    assert!(
        failures.is_empty(),
        "seeds where cells and Roth differ: {failures:?}"
    );
    assert!(placed * 10 >= tried * 9, "only {placed} {what} placed");
}

/// A number in [0, 1] from one of `xorshift`'s, in steps of a millionth.
fn unit(n: u64) -> f64 {
    (n % 1_000_001) as f64 / 1e6
}

/// A xorshift stream of 53-bit numbers from `seed` (made odd: the state
/// must not be 0), for the tests' own random choices.
fn xorshift(seed: u64) -> impl FnMut() -> u64 {
    let mut s = seed | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s >> 11
    }
}

/// A point on the boundary of a random minimal box of `scene` (every other
/// seed, where there is one, the box of a Box primitive that no transform
/// turns: a point on the solid's own surface; one seed in five a corner
/// of a surface, `sharp_points`): on a face, an edge or a corner by the
/// seed, exactly or nudged in or out by a little more than
/// the rounding bands the build keeps around a box (1e-12 of the scene's
/// reach) or its padding (1e-9 of the box's magnitude). Also the box, the
/// first fixed axis and how many are fixed (the next ones, cyclically).
/// None when no box is finite.
fn on_a_box_boundary(
    scene: &Scene,
    seed: u64,
    next: &mut impl FnMut() -> u64,
) -> Option<(Aabb, Vec3, usize, usize)> {
    let solid: Vec<_> = scene
        .primitives
        .iter()
        .filter(|p| matches!(p.shape, Shape::Box { .. }) && p.transform.is_none())
        .map(|p| p.bounds)
        .collect();
    let boxes: Vec<_> = if seed % 2 == 1 && !solid.is_empty() {
        solid
    } else {
        scene.tree.minimal_boxes()
    };
    let boxes: Vec<_> = boxes
        .into_iter()
        .filter(|b| !b.is_empty() && (b.max - b.min).is_finite())
        .collect();
    if boxes.is_empty() {
        return None;
    }
    let nudge = [0.0, 0.0, 1e-13, 1e-11, 1e-9, 1e-7][(seed / 5 % 6) as usize];
    let nudged = |p: &mut Vec3, a: usize, next: &mut dyn FnMut() -> u64| {
        if nudge > 0.0 {
            let sign = if next().is_multiple_of(2) { 1.0 } else { -1.0 };
            p[a] += sign * nudge * (p[a].abs() + 1.0);
        }
    };
    // One seed in five, where there is one, a point where the surface
    // itself has a corner: a pointed cone's apex, a triangle's or a
    // polygon's vertex (where a ray's roots meet, and every face of the
    // box may pass).
    if seed % 5 == 4 {
        let corners: Vec<_> = scene.primitives.iter().flat_map(sharp_points).collect();
        if !corners.is_empty() {
            let (b, mut p) = corners[next() as usize % corners.len()];
            for a in 0..3 {
                nudged(&mut p, a, &mut *next);
            }
            return Some((b, p, 0, 3));
        }
    }
    let b = boxes[next() as usize % boxes.len()];
    let mut p = b.min + (b.max - b.min) * Vec3::new(unit(next()), unit(next()), unit(next()));
    // One fixed coordinate: a face; two: an edge; three: a corner.
    let first = next() as usize % 3;
    let fixed = 1 + (seed % 3) as usize;
    for a in (first..first + fixed).map(|a| a % 3) {
        p[a] = if next().is_multiple_of(2) {
            b.min[a]
        } else {
            b.max[a]
        };
        nudged(&mut p, a, &mut *next);
    }
    Some((b, p, first, fixed))
}

/// The points where a primitive's surface has a corner, in world space,
/// each with the primitive's box: a pointed cone's apex, the vertices of a
/// triangle or a polygon.
fn sharp_points(p: &hypercast::csg::Primitive) -> Vec<(Aabb, Vec3)> {
    let points = match &p.shape {
        Shape::Cone {
            base,
            base_radius,
            top,
            top_radius,
            ..
        } => [(*base, *base_radius), (*top, *top_radius)]
            .into_iter()
            .filter(|&(_, r)| r == 0.0)
            .map(|(c, _)| c)
            .collect(),
        Shape::Triangle { a, b, c } => vec![*a, *b, *c],
        Shape::Polygon(poly) => poly.vertices.clone(),
        _ => vec![],
    };
    points
        .into_iter()
        .map(|q| p.transform.as_ref().map_or(q, |m| m.point(q)))
        .filter(|q| q.is_finite() && !p.bounds.is_empty())
        .map(|q| (p.bounds, q))
        .collect()
}

/// Lights on the boundary of a minimal box (`on_a_box_boundary`), so that
/// shadow rays end exactly on a face, an edge or a corner of a box, or a
/// hair inside or outside it, where the shadow walk's shortcuts (the ball
/// around a light that no box reaches, the stop at the first exposed
/// solid, the shadow cache) decide by the boxes. 150 lit random scenes,
/// half with mirrors and glass, with one to three lights each, render
/// bit-identically with Roth, both ways of cutting the screen, with the
/// shadow cache and without it.
#[test]
fn random_scenes_lit_from_a_box_face_edge_or_corner_render_identically() {
    let mut failures = Vec::new();
    let mut placed = 0;
    for seed in seeds(0..150) {
        let (primitives, mut model) = lit_random_scene(seed, 40);
        let scene = load(&scene_to_string(&model, SceneSyntax::Ron).unwrap());
        let mut next = xorshift(0x2545_F491_4F6C_DD1D ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let Some((b, light, _, fixed)) = on_a_box_boundary(&scene, seed, &mut next) else {
            continue;
        };
        let k = next() as usize % model.lights.len();
        model.lights[k].position = light.to_array();
        let ron = scene_to_string(&model, SceneSyntax::Ron).unwrap();
        let scene = load(&ron);
        placed += 1;
        let r = random_scene_options();
        let (roth, _) = render_roth(&scene, &r, &|_| {});
        assert_pixels_finite(&roth);
        for (choice, no_shadow_cache) in [
            (SegmentChoice::Sampled, false),
            (SegmentChoice::Sampled, true),
            (SegmentChoice::FewestSplits, false),
        ] {
            let opts = CellOptions {
                choice,
                no_shadow_cache,
                ..Default::default()
            };
            let cells = std::panic::catch_unwind(|| render_cells(&scene, &r, opts, &|_| {}));
            if !cells.is_ok_and(|(film, _, _)| roth.sums() == film.sums()) {
                eprintln!(
                    "seed {seed}, {primitives} primitives, light {k} at {light:?} on {fixed} faces \
                     of {b:?}: cells ({choice:?}, no shadow cache: {no_shadow_cache}) and Roth \
                     differ\n{}\n{ron}",
                    differences(&scene, &r, choice)
                );
                failures.push((seed, choice, no_shadow_cache));
            }
        }
    }
    assert_agreed_where_placed(&failures, placed, seeds(0..150).count(), "lights");
}

/// A random scene of up to `max` primitives with 1 to 3 lights, half of
/// them with mirrors and glass, trees 1 to 4 deep, the camera outside,
/// inside or with geometry behind the eye, by the seed.
pub(crate) fn lit_random_scene(
    seed: u64,
    max: usize,
) -> (usize, hypercast::scene::model::SceneFile) {
    let opts = RandomCsgOptions {
        max_tree_depth: 1 + (seed % 4) as u32,
        mirrors_and_glass: seed % 2 == 1,
        lights: Some(1 + (seed % 3) as u32),
        camera: [
            CameraPlacement::Outside,
            CameraPlacement::Inside,
            CameraPlacement::BehindEye,
        ][(seed % 3) as usize],
        ..RandomCsgOptions::default()
    };
    let primitives = 1 + (seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize % max;
    (primitives, random_csg(seed, primitives, &opts))
}

/// Random scenes where shadow rays take the cells' shortcuts
/// (`CellTracer::walk_shadow`): a shadow walk that meets no glass box and
/// ends at a light outside every box stops at the first cell where the ray
/// passes through an exposed solid, after asking the shadow cache, and any
/// shadow walk stops short of its light by the ball around it that no box
/// reaches (in 147 of the 147 scenes some light has one). 150
/// scenes of 1 to 60 primitives, half with glass and mirrors, flat unions
/// and deeper trees, lights inside and outside the primitives' boxes,
/// render bit-identically with Roth, with the shadow cache and without it
/// (it answers most shadow rays before they walk, so it would hide a
/// walk's mistake); and the test does exercise the
/// shortcuts: in over a quarter of the scenes (55 of 147) they save
/// intersection tests against the same cells without them (elsewhere a
/// light lies in some box, or glass is in the way, or nothing casts a
/// shadow).
#[test]
fn random_scenes_render_identically_with_the_shadow_shortcuts() {
    let mut failures = Vec::new();
    let (mut lit, mut saved, mut balls) = (0, 0, 0);
    for seed in seeds(0..150) {
        let (primitives, model) = lit_random_scene(seed, 60);
        let ron = scene_to_string(&model, SceneSyntax::Ron).unwrap();
        let scene = load(&ron);
        let r = random_scene_options();
        let (roth, _) = render_roth(&scene, &r, &|_| {});
        for choice in CHOICES {
            let opts = CellOptions {
                choice,
                ..Default::default()
            };
            let (film, stats, cs) = render_cells(&scene, &r, opts, &|_| {});
            if roth.sums() != film.sums() {
                eprintln!(
                    "seed {seed}, {primitives} primitives: cells ({choice:?}) and Roth differ\n{}\n{ron}",
                    differences(&scene, &r, choice)
                );
                failures.push((seed, choice));
            }
            if choice == SegmentChoice::Sampled {
                // Without the shadow cache, which answers most shadow rays
                // before they walk, and so would hide a walk's mistake.
                let uncached = CellOptions {
                    no_shadow_cache: true,
                    ..opts
                };
                if render_cells(&scene, &r, uncached, &|_| {}).0.sums() != roth.sums() {
                    eprintln!("seed {seed}: cells without the shadow cache and Roth differ\n{ron}");
                    failures.push((seed, choice));
                }
            }
            if choice == SegmentChoice::Sampled && primitives > 1 {
                lit += 1;
                balls += usize::from(cs.shadows.free_radius.iter().any(|&r| r > 0.0));
                // The same cells, every shadow ray walked to its nearest
                // surface.
                let plain = render_with(
                    &scene,
                    &r,
                    || NoShortcuts(CellTracer::new(&cs, &scene)),
                    |t, j| t.0.skips_primary(&j.ray),
                    &|_| {},
                )
                .unwrap_or_else(|e| panic!("{e}"))
                .1;
                if stats.counters.intersection_tests < plain.counters.intersection_tests {
                    saved += 1;
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "seeds where cells and Roth differ: {failures:?}"
    );
    assert!(
        saved * 4 >= lit,
        "{saved} of {lit} scenes with fewer tests by the shadow shortcuts"
    );
    assert!(
        balls * 2 >= lit,
        "{balls} of {lit} scenes with a light that has room around it"
    );
}

/// A shadow walk leaves out the stretch next to its light that no
/// primitive's box reaches (`ShadowFacts::free_radius`), and only that: a
/// slab 0.001 thick, 0.01 below the light, still shadows the floor under
/// it as Roth sees it, and the ball's radius is the gap less its margins
/// (a walk cut at twice the radius would miss the slab and light the
/// floor under it). A light inside a box gets no ball.
#[test]
fn shadow_walks_stop_short_of_the_light_only_where_nothing_is() {
    let scene = load(
        "(camera: (eye: (0, -6, 4), look_at: (0, 0, 0), fov_y: 50, width: 64, height: 48),
          lights: [(position: (0, 0, 2.01)), (position: (3, 3, 0.5))],
          objects: [
            Box(min: (-4, -4, -0.1), max: (4, 4, 0)),
            Box(min: (-0.5, -0.5, 1.999), max: (0.5, 0.5, 2.0)),
            Box(min: (2.5, 2.5, 0.1), max: (3.5, 3.5, 1.0)),
          ])",
    );
    let cs = CellStructure::build(&scene, 64, 48, CellOptions::default()).unwrap();
    let r = &cs.shadows.free_radius;
    assert!(r[0] > 0.0099 && r[0] < 0.01, "{r:?}");
    assert_eq!(r[1], 0.0, "the second light is inside a box");
    let (film, _) = assert_renders_equal(&scene, 64, 48);
    // Without the shadow cache too, which would stop the rays straight up
    // by the slab once a slanting ray had found it.
    let uncached = CellOptions {
        no_shadow_cache: true,
        ..Default::default()
    };
    let (walked, _, _) = render_cells(&scene, &options(64, 48), uncached, &|_| {});
    assert!(
        walked.sums() == film.sums(),
        "cells without the cache differ"
    );
    // The slab's shadow is on the floor: without the slab, more light.
    let open = load(
        "(camera: (eye: (0, -6, 4), look_at: (0, 0, 0), fov_y: 50, width: 64, height: 48),
          lights: [(position: (0, 0, 2.01)), (position: (3, 3, 0.5))],
          objects: [
            Box(min: (-4, -4, -0.1), max: (4, 4, 0)),
            Box(min: (2.5, 2.5, 0.1), max: (3.5, 3.5, 1.0)),
          ])",
    );
    let (lit, _) = render_roth(&open, &options(64, 48), &|_| {});
    let darker = film
        .sums()
        .iter()
        .zip(lit.sums())
        .filter(|(a, b)| a[0] < b[0])
        .count();
    assert!(darker > 300, "{darker} pixels in the slab's shadow");
}

/// The shadow cache keeps a small solid whose primitives are not exposed
/// (`ShadowFacts::solids`): a roof less its skylight, between a floor and
/// the light, is one solid of two boxes. Cells equal Roth with and
/// without the cache, the cache spares the walks of the floor's shadow
/// rays under the roof (the roof is their only blocker, and no primitive
/// of it is exposed, so only the solid can be cached), and a share that
/// holds one of the solid's primitives holds both, as one solid.
#[test]
fn shadow_rays_stopped_by_a_small_difference_are_answered_by_the_cache() {
    let scene = load(
        "(camera: (eye: (0, -7, 5), look_at: (0, 0, 0), fov_y: 50, width: 64, height: 48),
          lights: [(position: (0.3, 0.2, 3))],
          objects: [
            Box(min: (-4, -4, -0.1), max: (4, 4, 0)),
            Difference(children: [
                Box(min: (-2, -2, 1.9), max: (2, 2, 2)),
                Box(min: (-0.5, -0.5, 1.8), max: (0.5, 0.5, 2.1)),
            ]),
          ])",
    );
    let cs = CellStructure::build(&scene, 64, 48, CellOptions::default()).unwrap();
    let facts = &cs.shadows;
    assert_eq!(facts.solid_of(0), None, "the floor is exposed itself");
    let roof = facts.solid_of(1).expect("the roof is in a solid");
    assert_eq!(
        facts.solid_of(2),
        Some(roof),
        "the skylight is in the roof's"
    );
    let (film, _) = assert_renders_equal(&scene, 64, 48);
    let uncached = CellOptions {
        no_shadow_cache: true,
        ..Default::default()
    };
    let opts = options(64, 48);
    let (walked, plain, _) = render_cells(&scene, &opts, uncached, &|_| {});
    assert!(
        walked.sums() == film.sums(),
        "cells without the cache differ"
    );
    let (_, cached, _) = render_cells(&scene, &opts, CellOptions::default(), &|_| {});
    let (a, b) = (cached.counters.cells_visited, plain.counters.cells_visited);
    assert!(
        a * 10 < b * 9,
        "cells entered: {a} with the cache, {b} without"
    );
    for region in Region::BOTH {
        for s in 0..cs.region(region).supers.len() as u32 {
            let (share, _) = cs.restrict(&scene, &|r, t| r == region && t == s);
            let ids = &share.primitive_ids;
            let local = |g: u32| ids.iter().position(|&x| x == g).map(|k| k as u32);
            match (local(1), local(2)) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    let root = share.shadows.solid_of(a);
                    assert!(root.is_some() && root == share.shadows.solid_of(b));
                }
                held => panic!("super cell {s}: half a solid held, {held:?}"),
            }
        }
    }
}

/// Random CSG scenes on a wide ground slab, so that walks keep to the box
/// of everything but the ground when they do not cross it (`WideClip`):
/// cells and Roth still agree on every pixel, with mirrors, glass, lights
/// and cameras inside, outside and behind the eye.
#[test]
fn random_scenes_on_a_wide_ground_render_identically_with_the_clip() {
    let ground = "objects: [\n        Union(material: \"white\", children: [Box(min: (-150.0, -8.2, -150.0), max: (150.0, -8.0, 150.0))]),";
    let mut failures = Vec::new();
    let mut clipped = 0;
    for seed in seeds(0..150) {
        let (primitives, model) = lit_random_scene(seed, 40);
        let ron =
            scene_to_string(&model, SceneSyntax::Ron)
                .unwrap()
                .replacen("objects: [", ground, 1);
        let (_, cs) = compare_with_roth(seed, primitives, &ron, &mut failures);
        clipped += usize::from(cs.clip.is_some());
    }
    assert!(
        failures.is_empty(),
        "seeds where cells and Roth differ: {failures:?}"
    );
    assert!(clipped >= 140, "{clipped} of 150 scenes clipped");
}

/// Renders random scene `ron` (seed `seed`, `primitives` primitives) with
/// Roth and with the cells at the random scenes' size; where the two
/// differ, prints the scene and records the seed in `failures`. Roth's
/// film and the cells' structure, for the caller's own checks.
fn compare_with_roth(
    seed: u64,
    primitives: usize,
    ron: &str,
    failures: &mut Vec<u64>,
) -> (Film, CellStructure) {
    let scene = load(ron);
    let r = random_scene_options();
    let (roth, _) = render_roth(&scene, &r, &|_| {});
    let (film, _, cs) = render_cells(&scene, &r, CellOptions::default(), &|_| {});
    if roth.sums() != film.sums() {
        eprintln!("seed {seed}, {primitives} primitives: cells and Roth differ\n{ron}");
        failures.push(seed);
    }
    (roth, cs)
}

/// Random scene `ron` (as `lit_random_scene` writes it) on a ground
/// reaching far beyond it, met by exact arithmetic: by `seed`, a sphere of
/// radius 1e15 whose top is at `y = −8`, a polygon reaching 1e20 tilted
/// out of every coordinate plane, a drum of radius 1e15 or a cone (its
/// radius 1e15 at the middle) lying along a tilted horizontal axis, its
/// top at `y = −8` there, or an ellipsoid of semi-axes 1e15, 2.5e14 and
/// 1e15, its top at `y = −8`.
pub(crate) fn on_far_ground(ron: &str, seed: u64) -> String {
    let far = 1e20f64;
    let tilted = |x: f64, z: f64| format!("({x:?}, {:?}, {z:?})", -8.0 + (x - z) / 64.0);
    let ground = match seed % 6 {
        0 => "Sphere(center: (0, -1000000000000008.0, 0), radius: 1e15)".to_string(),
        1 => format!(
            "Polygon(vertices: [{}, {}, {}])",
            tilted(-far, -far),
            tilted(far, -far),
            tilted(0.0, far)
        ),
        // A drum lying along (1, 0, 2), its top along a line at y = −8.
        2 => "Cylinder(base: (-1e15, -1000000000000008.0, -2e15), \
              top: (1e15, -1000000000000008.0, 2e15), radius: 1e15)"
            .to_string(),
        // An ellipsoid of semi-axes 1e15, 2.5e14 and 1e15, its top at
        // y = −8.
        4 => "Transform(translate: (0, -250000000000008.0, 0), scale: (1e15, 2.5e14, 1e15), \
              child: Sphere(center: (0, 0, 0), radius: 1))"
            .to_string(),
        // An elliptic drum lying along z, of semi-axes 1e15 and 5e14
        // across, its top at y = −8.
        5 => "Transform(translate: (0, -500000000000008.0, 0), scale: (1e15, 5e14, 1e15), \
              child: Cylinder(base: (0, 0, -1), top: (0, 0, 1), radius: 1))"
            .to_string(),
        // A cone on the same axis, its radius 1e15 at the middle.
        _ => "Cone(base: (-1e15, -1000000000000008.0, -2e15), base_radius: 984375000000000.0, \
              top: (1e15, -1000000000000008.0, 2e15), top_radius: 1015625000000000.0)"
            .to_string(),
    };
    ron.replacen(
        "objects: [",
        &format!("objects: [\n        Union(material: \"white\", children: [{ground}]),"),
        1,
    )
}

/// Random CSG scenes on a ground reaching far beyond them, met by exact
/// arithmetic (`csg::shape::on_plane`, `sphere_hits`,
/// `far_cylinder_roots`, `far_cone_roots`, `ellipsoid_hits`,
/// `mapped_cylinder_hits`): a sphere of radius 1e15 whose top is at
/// `y = −8`, a polygon reaching 1e20 tilted out of every coordinate plane,
/// a lying drum and cone of radius 1e15, and an ellipsoid and an elliptic
/// drum as large. Cells and
/// Roth agree on every pixel, with
/// mirrors, glass, lights and cameras inside, outside and behind the eye.
#[test]
fn random_scenes_on_a_ground_reaching_far_render_identically() {
    let mut failures = Vec::new();
    let mut shown = 0;
    let all = seeds(0..60);
    for seed in all.clone() {
        let (primitives, model) = lit_random_scene(seed, 40);
        let bare = scene_to_string(&model, SceneSyntax::Ron).unwrap();
        let ron = on_far_ground(&bare, seed);
        let (roth, _) = compare_with_roth(seed, primitives, &ron, &mut failures);
        let (without, _) = render_roth(&load(&bare), &random_scene_options(), &|_| {});
        shown += usize::from(roth.sums() != without.sums());
    }
    assert!(
        failures.is_empty(),
        "seeds where cells and Roth differ: {failures:?}"
    );
    // The ground is seen, or seen in, or shadowed on, in most scenes.
    let n = (all.end - all.start) as usize;
    assert!(
        shown * 3 >= n * 2,
        "the ground shows in {shown} of {n} scenes"
    );
}

/// The cells without the shadow shortcuts: every shadow ray walks to its
/// nearest surface.
struct NoShortcuts<'a>(CellTracer<'a>);

impl Tracer for NoShortcuts<'_> {
    fn leaving(&mut self, prim: Option<PrimId>) {
        self.0.leaving(prim);
    }

    fn nearest(&mut self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        self.0.nearest(ray, t_min, t_max)
    }

    fn counters(&self) -> hypercast::render::TraceCounters {
        self.0.counters
    }
}

/// The seeds of the random tests: `default`, or the range `a..b` given by
/// `HYPERCAST_SEEDS` for longer hunts (stress counts scale by configuration).
pub(crate) fn seeds(default: std::ops::Range<u64>) -> std::ops::Range<u64> {
    let Ok(v) = std::env::var("HYPERCAST_SEEDS") else {
        return default;
    };
    let (a, b) = v.split_once("..").expect("HYPERCAST_SEEDS is a range a..b");
    a.parse().expect("HYPERCAST_SEEDS start")..b.parse().expect("HYPERCAST_SEEDS end")
}

/// The size `HYPERCAST_SIZE=WxH` gives the random-scene tests for a hunt
/// (pixel rays at other sizes take other paths past cell boundaries).
pub(crate) fn hunt_size() -> Option<(u32, u32)> {
    let v = std::env::var("HYPERCAST_SIZE").ok()?;
    let (w, h) = v.split_once('x').expect("HYPERCAST_SIZE is WxH");
    Some((
        w.parse().expect("HYPERCAST_SIZE width"),
        h.parse().expect("HYPERCAST_SIZE height"),
    ))
}

/// The render options of the random cells-against-Roth scenes: 64x48, or
/// `hunt_size`.
fn random_scene_options() -> RenderOptions {
    let (w, h) = hunt_size().unwrap_or((64, 48));
    options(w, h)
}

/// The options and primitive count of random scene `seed`: every camera
/// placement, tree depths 2 to 6, and 1 to 60 primitives.
fn random_scene(seed: u64) -> (SceneFile, String) {
    let opts = RandomCsgOptions {
        max_tree_depth: 2 + (seed % 5) as u32,
        surfaces: !seed.is_multiple_of(7),
        camera: [
            CameraPlacement::Outside,
            CameraPlacement::Inside,
            CameraPlacement::BehindEye,
        ][(seed % 3) as usize],
        trace_depth: 3,
        ..RandomCsgOptions::default()
    };
    let primitives = 1 + (seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize % 60;
    let model = random_csg(seed, primitives, &opts);
    let about = format!("seed {seed}, {primitives} primitives, {opts:?}");
    (model, about)
}

/// Rays from anywhere in and around random scenes, in any direction
/// (including along axes, with zero, −0.0 and subnormal components,
/// through corners of cells, where a ray leaves by an edge, and along
/// lines through the eye, whose screen motion is noise): the side-face
/// walk of non-primary rays, in both regions and with both ways of cutting
/// the screen, finds what Roth finds.
#[test]
fn random_rays_in_random_scenes_hit_what_roth_hits() {
    let mut failures = Vec::new();
    // And seeds a hunt once found failing, always: 58571 aims a ray from
    // inside a box at the eye, which lies on the box's top face; its exit,
    // at the very start of the region after the eye plane, was in a cell
    // clipped to the directions from the eye into the box, without it
    // (`View::eye_near_boundary`).
    for seed in seeds(0..100).chain([58571]) {
        // The rays' own stream, by the seed alone, so that a failing seed
        // reproduces in any range (xorshift: the state must not be 0).
        let mut bits = xorshift(0x9E37_79B9_7F4A_7C15 ^ seed.wrapping_mul(0xD1B5_4A32_D192_ED03));
        let mut next = move || bits() as f64 / (1u64 << 53) as f64;
        let (model, about) = random_scene(seed);
        let ron = scene_to_string(&model, SceneSyntax::Ron).unwrap();
        let scene = load(&ron);
        let choice = CHOICES[(seed % 2) as usize];
        let cs = CellStructure::build(
            &scene,
            64,
            48,
            CellOptions {
                choice,
                ..Default::default()
            },
        )
        .unwrap();
        assert_cell_bounds_not_nan(&cs);
        let mut roth = RothTracer::new(&scene);
        let mut tracer = CellTracer::new(&cs, &scene);
        for k in 0..500 {
            let mut o = Vec3::new(next(), next(), next()) * 30.0 - 15.0;
            let mut d = Vec3::new(next(), next(), next()) * 2.0 - 1.0;
            // Some directions along the axes or planes, with signed zeros
            // and subnormals.
            match k % 5 {
                0 => d[k / 5 % 3] = [0.0, -0.0, 1e-310][k / 15 % 3],
                1 => {
                    let a = k / 5 % 3;
                    d = Vec3::ZERO;
                    d[a] = if next() < 0.5 { -1.0 } else { 1.0 };
                }
                // Through a corner of a cell, where a ray leaves by an edge.
                2 => {
                    if let Some(p) = cell_corner(&cs, [next(), next(), next(), next()]) {
                        d = p - o;
                    }
                }
                // Along a line through the eye, away from it or toward it:
                // the ray keeps its screen position (its motion across
                // the screen is rounding noise), and every side plane
                // meets its line at the eye.
                3 | 4 => {
                    // From inside a primitive's box, where the ray soon
                    // meets what its cell holds.
                    let prims = &scene.primitives;
                    let b = prims[(next() * prims.len() as f64) as usize].bounds;
                    if k % 5 == 4 && !b.is_empty() && (b.max - b.min).is_finite() {
                        o = b.min + (b.max - b.min) * Vec3::new(next(), next(), next());
                    }
                    // Within rounding of the eye, not through it exactly.
                    let jitter = Vec3::new(next(), next(), next()) - 0.5;
                    d = o - scene.camera.eye + jitter * (o - scene.camera.eye).length() * 1e-15;
                    if k % 2 == 1 {
                        d = -d;
                    }
                }
                _ => {}
            }
            let t_min = if k % 7 == 0 { next() * 10.0 } else { 0.0 };
            let ray = Ray::new(o, d);
            let a = roth.nearest(&ray, t_min, f64::INFINITY);
            let b = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                tracer.nearest(&ray, t_min, f64::INFINITY)
            }));
            if let Some(h) = &a {
                checked_normal(&scene, &ray, h);
            }
            if b.as_ref().map_or(true, |b| *b != a) {
                let b = b.map_err(|_| "a panic");
                eprintln!(
                    "{about}, {choice:?}: ray origin {:?} dir {:?} t_min {t_min:e}: roth {a:?}, cells {b:?}\n{ron}",
                    o.to_array(),
                    d.to_array()
                );
                failures.push(seed);
                break;
            }
        }
    }
    assert!(
        failures.is_empty(),
        "seeds where a ray's hit differs: {failures:?}"
    );
}

/// A world point at a corner of a cell of `cs` picked by `u` (four numbers
/// in [0, 1)): a corner of its super cell at its near depth. None when that
/// corner is at infinity.
fn cell_corner(cs: &CellStructure, u: [f64; 4]) -> Option<Vec3> {
    let rc = &cs.regions[(u[0] * 2.0) as usize];
    let k = (u[1] * rc.cell_count() as f64) as usize;
    let cell = (k < rc.cell_count()).then(|| rc.cell(k as u32))?;
    let r = rc.partition.leaves[cell.super_cell as usize].rect;
    let corner = (u[2] * 4.0) as usize;
    let (sx, sy) = ([r.x0, r.x1][corner % 2], [r.y0, r.y1][corner / 2]);
    let z = if u[3] < 0.5 { cell.zlo } else { cell.zhi };
    if !(sx.is_finite() && sy.is_finite() && z.is_finite()) {
        return None;
    }
    let v = &cs.view;
    Some(match rc.region {
        Region::Front => v.eye + v.right * (sx * z) + v.up * (sy * z) + v.forward * z,
        Region::Back => v.eye + v.right * sx + v.up * sy + v.forward * z,
    })
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 14: an intersection with nothing inside.

const CASE_14_CULLED: &str = "Intersection(children: [Sphere(center: (-5, 0, 0), radius: 1), Sphere(center: (5, 0, 0), radius: 1)])";

#[test]
fn case_14_an_empty_intersection_is_culled_and_in_no_cell() {
    let scene = load(&format!(
        "(camera: (eye: (0, -20, 0), look_at: (0, 0, 0), fov_y: 40, width: 32, height: 24),
          lights: [(position: (0, -10, 10))], objects: [{CASE_14_CULLED}])"
    ));
    let (film, structures) = assert_renders_equal(&scene, 32, 24);
    for cs in &structures {
        assert_eq!(cs.stats.culled_primitives, 2);
        for rc in &cs.regions {
            assert!(
                rc.partition.leaves.iter().all(|l| l.prims.is_empty()),
                "{:?}",
                rc.region
            );
            assert!(
                rc.subtree.iter().all(|&t| t == NO_SUBTREE),
                "{:?}",
                rc.region
            );
        }
    }
    // All background (black by default).
    assert!(film.sums().iter().all(|p| *p == [0; 3]));
}

#[test]
fn case_14_union_with_an_empty_intersection_has_the_other_objects_bounds() {
    let scene = load(&format!(
        "(camera: (eye: (0, -20, 0), look_at: (0, 0, 0), fov_y: 40, width: 32, height: 24),
          lights: [(position: (0, -10, 10))],
          objects: [Union(children: [Box(min: (-1, -1, -1), max: (1, 1, 1)), {CASE_14_CULLED}])])"
    ));
    let tree = &scene.tree;
    let root = tree.root.unwrap();
    let union = tree.children_of(root)[0];
    let box_bounds = scene.primitives[0].bounds;
    assert!(!box_bounds.is_empty());
    assert_eq!(tree.bounds[union.index()], box_bounds);
    assert_eq!(tree.bounds[root.index()], box_bounds);
    assert_eq!(tree.minimal_boxes()[root.index()], box_bounds);
    let (_, structures) = assert_renders_equal(&scene, 32, 24);
    for cs in &structures {
        assert_eq!(cs.stats.culled_primitives, 2);
        let mut referenced = 0;
        for rc in &cs.regions {
            for leaf in &rc.partition.leaves {
                assert!(leaf.prims.iter().all(|&p| p == 0), "{:?}", leaf.prims);
            }
            for c in rc.cells().filter(|c| c.subtree != NO_SUBTREE) {
                assert_eq!(subtree_prims(cs, c.subtree), vec![PrimId(0)]);
                referenced += 1;
            }
        }
        assert!(referenced > 0, "the box is in no cell");
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 15: 2000 overlapping spheres.

/// 2000 unit spheres with centres within 0.1 of (0, 0, 10), in a balanced
/// union or a left-deep chain of unions.
fn pile_of_spheres(balanced: bool) -> SceneFile {
    let mut bits = xorshift(0x2545_F491_4F6C_DD1D);
    // Within 0.1 of the centre: ±0.1/√3 per coordinate.
    let mut next = move || (bits() as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * 0.057;
    let spheres: Vec<Node> = (0..2000)
        .map(|_| Node::Sphere {
            center: [next(), next(), 10.0 + next()],
            radius: 1.0,
            material: None,
        })
        .collect();
    fn balanced_union(mut v: Vec<Node>) -> Node {
        if v.len() == 1 {
            return v.pop().unwrap();
        }
        let right = v.split_off(v.len() / 2);
        Node::Union {
            children: vec![balanced_union(v), balanced_union(right)],
            material: None,
        }
    }
    let root = if balanced {
        balanced_union(spheres)
    } else {
        let mut it = spheres.into_iter();
        let first = it.next().unwrap();
        it.fold(first, |acc, s| Node::Union {
            children: vec![acc, s],
            material: None,
        })
    };
    SceneFile {
        camera: model::Camera {
            eye: [0.0, -12.0, 14.0],
            look_at: [0.0, 0.0, 10.0],
            up: [0.0, 0.0, 1.0],
            fov_y: 15.0,
            width: 32,
            height: 24,
        },
        background: [0.1, 0.1, 0.3],
        ambient: [1.0; 3],
        lights: vec![model::Light {
            position: [5.0, -10.0, 20.0],
            color: [1.0; 3],
        }],
        materials: Default::default(),
        objects: vec![root],
        max_depth: 3,
    }
}

#[test]
fn case_15_two_thousand_overlapping_spheres_balanced_and_left_deep() {
    // Deep models recurse when dropped: keep them on a large stack.
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(|| {
            for balanced in [true, false] {
                let model = pile_of_spheres(balanced);
                let (scene, _) = compile_model(&model, Path::new("pile.ron")).unwrap();
                assert_eq!(scene.primitives.len(), 2000);
                // The paper's rule is quadratic in the segments: default only.
                let (_, structures) =
                    assert_renders_equal_with(&scene, 32, 24, &[SegmentChoice::Sampled]);
                let cs = &structures[0];
                assert!(cs.stats.cells <= 64 * 2000, "{} cells", cs.stats.cells);
                assert!(cs.stats.prims_per_cell_max <= 2000);
            }
        })
        .unwrap()
        .join()
        .unwrap();
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 16 and 17: rays through corners and along edges of cells.

/// Unit boxes `[i, i+1]×[j, j+1]×[k, k+1]`, i, j, k in 0..3, except those
/// on the diagonal x = y = z: their faces put cell boundaries on the integer
/// grid, and the diagonal only touches them at corners.
fn grid_boxes() -> String {
    let mut s = String::new();
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                if !(i == j && j == k) {
                    s += &format!(
                        "Box(min: ({i}, {j}, {k}), max: ({}, {}, {})),",
                        i + 1,
                        j + 1,
                        k + 1
                    );
                }
            }
        }
    }
    s
}

/// Cameras for which the integer grid is a cell grid: from below, where the
/// back region's screen is world (x, y) and its depth −(z + 10), so every
/// grid plane is a cell boundary; and in front, where depth planes are.
const GRID_CAMERAS: [&str; 2] = [
    "(eye: (0, 0, -10), look_at: (0, 0, -11), up: (0, 1, 0), fov_y: 40, width: 32, height: 24)",
    "(eye: (0, 0, -10), look_at: (0, 0, 0), up: (0, 1, 0), fov_y: 40, width: 32, height: 24)",
];

#[test]
fn case_16_ray_through_cell_corners_hits_both_tiny_spheres_in_order() {
    for camera in GRID_CAMERAS {
        let scene = load(&format!(
            "(camera: {camera}, objects: [
                Sphere(center: (1, 1, 1), radius: 0.001), Sphere(center: (2, 2, 2), radius: 0.001), {}])",
            grid_boxes()
        ));
        let ray = Ray::new(Vec3::splat(0.5), Vec3::ONE);
        for (choice, cs) in CHOICES.iter().zip(structures(&scene, 32, 24)) {
            let visits = walk(&cs, &ray, 0.0);
            if *choice == SegmentChoice::FewestSplits {
                // The grid is cut along every face: the ray crosses cell
                // boundaries at the corners themselves.
                for t in [0.5, 1.5] {
                    assert!(
                        visits.iter().any(|v| (v.3 - t).abs() < 1e-6),
                        "no cell boundary at t = {t}: {visits:?}"
                    );
                }
            }
            let hits = hits_along(&scene, &cs, &ray, 0.0);
            // Entry and exit of each sphere, nothing else.
            let d = 0.001 / 3f64.sqrt();
            assert_hits(
                &hits,
                &[(0, 0.5 - d), (0, 0.5 + d), (1, 1.5 - d), (1, 1.5 + d)],
            );
        }
        assert_renders_equal(&scene, 32, 24);
    }
}

/// The super cells a ray walks along the segment a–b have a side on every
/// screen coordinate that is constant along it: the segment lies on super
/// cell faces, where the walk must still find its way. (Depth cuts are the
/// builder's choice, and may be merged away.)
fn assert_walk_along_boundaries(cs: &CellStructure, visits: &[Visit], a: Vec3, b: Vec3) {
    for region in Region::BOTH {
        let coords = |p: Vec3| {
            let c = cs.view.point(p);
            match region {
                Region::Front => [c.x / c.z, c.y / c.z, c.z],
                Region::Back => [c.x, c.y, c.z],
            }
        };
        let (ca, cb) = (coords(a), coords(b));
        let mine: Vec<&Visit> = visits.iter().filter(|v| v.0 == region).collect();
        if mine.is_empty() {
            continue;
        }
        for k in 0..2 {
            if (ca[k] - cb[k]).abs() > 1e-12 * ca[k].abs().max(1.0) {
                continue;
            }
            let on_face = mine.iter().any(|v| {
                let rc = cs.region(region);
                let cell = rc.cell(v.1);
                let r = rc.partition.leaves[cell.super_cell as usize].rect;
                let bounds = [[r.x0, r.x1], [r.y0, r.y1]][k];
                bounds
                    .iter()
                    .any(|e| (e - ca[k]).abs() < 1e-6 * ca[k].abs().max(1.0))
            });
            assert!(
                on_face,
                "{region:?}: no super cell side at screen coordinate {k} = {} along the ray: {mine:?}",
                ca[k]
            );
        }
    }
}

/// Four cylinders along x whose bounding boxes meet at the line y = z = 1
/// (which none of them touches), so that four cells share that edge.
const FOUR_CYLINDERS: &str = "
    Cylinder(base: (0, 0.5, 0.5), top: (6, 0.5, 0.5), radius: 0.5),
    Cylinder(base: (0, 1.5, 0.5), top: (6, 1.5, 0.5), radius: 0.5),
    Cylinder(base: (0, 0.5, 1.5), top: (6, 0.5, 1.5), radius: 0.5),
    Cylinder(base: (0, 1.5, 1.5), top: (6, 1.5, 1.5), radius: 0.5),";

#[test]
fn case_17_ray_along_an_edge_of_four_cells_finds_the_sphere_in_each() {
    let cameras = [
        GRID_CAMERAS[0],
        GRID_CAMERAS[1],
        // Looking along the edge: it is the corner of four super cells.
        "(eye: (-10, 1, 1), look_at: (0, 1, 1), fov_y: 40, width: 32, height: 24)",
    ];
    for camera in cameras {
        for (dy, dz) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
            let scene = load(&format!(
                "(camera: {camera}, lights: [(position: (3, -5, 8))], objects: [
                    Sphere(center: (3, {}, {}), radius: 0.5), {FOUR_CYLINDERS}])",
                1.0 + dy,
                1.0 + dz
            ));
            let ray = Ray::new(Vec3::new(0.5, 1.0, 1.0), Vec3::X);
            for (choice, cs) in CHOICES.iter().zip(structures(&scene, 32, 24)) {
                let visits = walk(&cs, &ray, 0.0);
                if *choice == SegmentChoice::FewestSplits {
                    assert_walk_along_boundaries(
                        &cs,
                        &visits,
                        Vec3::new(0.5, 1.0, 1.0),
                        Vec3::new(5.0, 1.0, 1.0),
                    );
                }
                let first = nearest_both(&scene, &cs, &ray, 0.0, f64::INFINITY)
                    .expect("the sphere is missed");
                assert_eq!(first.prim, PrimId(0));
                // Entry at x = 3 − √(0.5² − 2·0.25²).
                assert!(
                    (first.t - (2.5 - 0.125f64.sqrt())).abs() < 1e-12,
                    "{first:?}"
                );
                hits_along(&scene, &cs, &ray, 0.0);
            }
            assert_renders_equal(&scene, 32, 24);
        }
    }
}

#[test]
fn case_17_ray_starting_on_a_cell_face_finds_the_first_cell() {
    for camera in GRID_CAMERAS {
        let scene = load(&format!(
            "(camera: {camera}, objects: [
                Sphere(center: (0.5, 0.5, 0.5), radius: 0.25), Sphere(center: (-1, 0.5, 0.5), radius: 0.25), {}])",
            grid_boxes()
        ));
        let ray = Ray::new(Vec3::new(1.0, 0.5, 0.5), -Vec3::X);
        for cs in structures(&scene, 32, 24) {
            walk(&cs, &ray, 0.0);
            let hits = hits_along(&scene, &cs, &ray, 0.0);
            assert_hits(&hits, &[(0, 0.25), (0, 0.75), (1, 1.75), (1, 2.25)]);
        }
        assert_renders_equal(&scene, 32, 24);
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 18: a mirror whose face is a cell boundary.

#[test]
fn case_18_mirror_face_on_a_cell_boundary() {
    let scene = load(
        "(camera: (eye: (0, -8, 4), look_at: (0, 0, 0.5), fov_y: 50, width: 64, height: 48),
          background: (0.1, 0.2, 0.4),
          lights: [(position: (4, -6, 10))],
          materials: {
            \"mirror\": (color: (0.9, 0.9, 0.9), diffuse: 0.1, reflect: 0.9),
            \"red\": (color: (0.9, 0.1, 0.1)),
          },
          objects: [
            Box(min: (-4, -4, -1), max: (4, 4, 0), material: \"mirror\"),
            Sphere(center: (0, 0, 1), radius: 1, material: \"red\"),
            Box(min: (1, -3, 0), max: (2, -2, 1)),
            Box(min: (-3, 1, 0), max: (-1, 2, 2), material: \"mirror\"),
          ])",
    );
    let (_, structures) = assert_renders_equal(&scene, 64, 48);
    // Rays that start on the mirror's face: up, into it, and along it.
    for cs in &structures {
        for (x, y) in [(0.5, 0.25), (1.0, -3.0), (-2.0, 1.0), (3.0, 3.0)] {
            for dz in [1.0, -1.0, 0.0] {
                for d in [
                    Vec3::new(0.3, 0.2, dz),
                    Vec3::new(-0.5, 0.5, dz),
                    Vec3::new(0.0, 0.0, dz),
                ] {
                    if d != Vec3::ZERO {
                        let ray = Ray::new(Vec3::new(x, y, 0.0), d);
                        walk(cs, &ray, 0.0);
                        hits_along(&scene, cs, &ray, 0.0);
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 19: geometry crossing the eye plane.

#[test]
fn case_19_box_crossing_the_eye_plane_and_a_corner_on_it() {
    let scene = load(
        "(camera: (eye: (0, 0, 0), look_at: (0, 0, 1), up: (0, 1, 0), fov_y: 90, width: 64, height: 48),
          background: (0.1, 0.2, 0.4),
          lights: [(position: (0, 3, -2)), (position: (-2, 0, 6))],
          materials: { \"mirror\": (reflect: 0.8) },
          objects: [
            Box(min: (0.5, -1, -5), max: (1, 1, 5)),
            Box(min: (-1, 0.5, 0), max: (-0.5, 1, 2)),
            Box(min: (-3, -3, 6), max: (3, 3, 7), material: \"mirror\"),
          ])",
    );
    let (_, structures) = assert_renders_equal(&scene, 64, 48);
    // Rays from the eye along the eye plane and into the back region.
    for cs in &structures {
        for d in [
            Vec3::X,
            Vec3::new(1.0, 0.5, 0.0),
            Vec3::new(1.0, 0.0, -1.0),
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::new(0.75, 0.0, 1.0),
        ] {
            walk(cs, &Ray::new(Vec3::ZERO, d), 0.0);
            hits_along(&scene, cs, &Ray::new(Vec3::ZERO, d), 0.0);
        }
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 20: reflections of spheres behind and at the eye plane.

const CASE_20_MIRROR: &str = "Box(min: (-20, -20, 10), max: (20, 20, 11), material: \"mirror\")";
const CASE_20_BEHIND: &str = "Sphere(center: (0, 0, -5), radius: 1, material: \"red\")";
const CASE_20_AT_EYE: &str = "Sphere(center: (2, 0, 0.05), radius: 0.5, material: \"green\")";

fn case_20_scene(objects: &[&str]) -> Scene {
    load(&format!(
        "(camera: (eye: (0, 0, 0), look_at: (0, 0, 1), up: (0, 1, 0), fov_y: 60, width: 64, height: 48),
          background: (0.1, 0.1, 0.1),
          lights: [(position: (0, 5, 5))],
          materials: {{
            \"mirror\": (color: (1, 1, 1), ambient: 0, diffuse: 0, reflect: 1),
            \"red\": (color: (1, 0, 0), ambient: 0.5),
            \"green\": (color: (0, 1, 0), ambient: 0.5),
          }},
          objects: [{}])",
        objects.join(",")
    ))
}

#[test]
fn case_20_spheres_behind_and_at_the_eye_plane_are_seen_in_the_mirror() {
    let all = case_20_scene(&[CASE_20_MIRROR, CASE_20_BEHIND, CASE_20_AT_EYE]);
    let (film, _) = assert_renders_equal(&all, 64, 48);
    let cam = CameraFrame::new(&all, 64, 48);
    // Where a point at depth z (< 10) appears in the mirror z = 10: the
    // reflected ray from the eye reaches it after 20 − z along the screen
    // direction (sx, sy, 1). (Screen x is world −x here.)
    let pixel_of = |p: Vec3| {
        let (sx, sy) = (
            p.dot(cam.right) / (20.0 - p.z),
            p.dot(cam.up) / (20.0 - p.z),
        );
        let i = ((sx / cam.half_w + 1.0) / 2.0 * 64.0) as usize;
        let j = ((1.0 - sy / cam.half_h) / 2.0 * 48.0) as usize;
        j * 64 + i
    };
    for (sphere, centre) in [
        (CASE_20_BEHIND, Vec3::new(0.0, 0.0, -5.0)),
        (CASE_20_AT_EYE, Vec3::new(2.0, 0.0, 0.05)),
    ] {
        let without: Vec<&str> = [CASE_20_MIRROR, CASE_20_BEHIND, CASE_20_AT_EYE]
            .into_iter()
            .filter(|o| *o != sphere)
            .collect();
        let (other, _) = render_roth(&case_20_scene(&without), &options(64, 48), &|_| {});
        let p = pixel_of(centre);
        assert_ne!(
            film.sums()[p],
            other.sums()[p],
            "{sphere} is not seen at pixel {p}"
        );
        // Seen in its own colour: red or green, not the mirrored background.
        let c = film.to_linear()[p];
        assert!(c[0].max(c[1]) > 2.0 * c[2], "{sphere} at pixel {p}: {c:?}");
    }
}

/// Found by case 20 with the paper's BSP rule: a reflected ray leaves the
/// mirror's super cell [−2, 2]² within an ulp of its upper-left corner. Its
/// top-face crossing comes one ulp before its left-face crossing, the exit
/// point clamped to the top face lies on the corner while moving left, and
/// the corner-stitch walk from the LU_UP pointer only climbs right: no
/// neighbour (a debug assertion; release builds leave the front region and
/// miss the sphere that Roth hits at t = 8.70).
#[test]
fn corner_stitch_walk_leaving_a_super_cell_by_its_corner() {
    let scene = load(
        "(camera: (eye: (0, 0, 0), look_at: (0, 0, 1), up: (0, 1, 0), fov_y: 60, width: 64, height: 48),
          objects: [
            Box(min: (-20, -20, 10), max: (20, 20, 11)),
            Sphere(center: (0, 0, -5), radius: 1),
            Sphere(center: (2, 0, 0.05), radius: 0.5),
            Sphere(center: (7.47, 7.47, 2.27), radius: 0.3),
          ])",
    );
    let ray = Ray::new(
        Vec3::new(4.2098457128410205, 4.209845712841021, 9.999999999999714),
        Vec3::new(0.3617293316532928, 0.3617293316532929, -0.859246053958541),
    );
    for cs in &structures(&scene, 64, 48) {
        walk(cs, &ray, 0.0);
        let h = nearest_both(&scene, cs, &ray, 0.0, f64::INFINITY).expect("the sphere is missed");
        assert_eq!(h.prim, PrimId(3));
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 21: thin gaps far away.

#[test]
fn case_21_thin_gaps_at_a_million_and_ten_million() {
    for distance in [1e6, 1e7] {
        // Seen obliquely from `distance`, with a view just wider than it.
        let eye = Vec3::new(0.6, -0.48, 0.64) * distance;
        let fov = 2.0 * (2.5 / distance).atan().to_degrees();
        let scene = load(&format!(
            "(camera: (eye: ({}, {}, {}), look_at: (0, 0, 0), fov_y: {fov:e}, width: 64, height: 48),
              background: (0.1, 0.2, 0.4),
              lights: [(position: ({}, {}, {}))],
              objects: [
                Difference(children: [
                    Box(min: (-1, -1, -1), max: (1, 1, 1)),
                    Box(min: (-2, -0.0005, -2), max: (2, 0.0005, 2)),
                    Box(min: (-0.0005, -2, -2), max: (0.0005, 2, 2)),
                ]),
                Difference(children: [
                    Sphere(center: (0, 0, 2), radius: 1),
                    Sphere(center: (0, 0, 2), radius: 0.999),
                    Box(min: (0, -2, 2), max: (2, 0, 4)),
                ]),
              ])",
            eye.x,
            eye.y,
            eye.z,
            eye.x * 0.5,
            eye.y,
            eye.z * 1.5
        ));
        let (_, structures) = assert_renders_equal(&scene, 64, 48);
        // Rays through the gaps themselves.
        for cs in &structures {
            for (x, y) in [(0.0, 0.5), (0.5, 0.0), (0.0002, 0.0002), (0.25, 0.0004)] {
                let target = Vec3::new(x, y, 1.0);
                hits_along(&scene, cs, &Ray::new(eye, target - eye), 0.0);
            }
        }
    }
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 27: a camera inside a difference, and on a surface.

#[test]
fn case_27_camera_inside_a_difference_sees_the_cut_at_t_4() {
    let ron = |z: f64| {
        format!(
            "(camera: (eye: (0, 0, {z}), look_at: (0, 0, {}), up: (0, 1, 0), fov_y: 60, width: 32, height: 24),
              lights: [(position: (0, 0, 0.5))],
              objects: [Difference(children: [Sphere(center: (0, 0, 0), radius: 10), Sphere(center: (0, 0, 5), radius: 1)])])",
            z + 1.0
        )
    };
    let scene = load(&ron(0.0));
    let ray = Ray::new(Vec3::ZERO, Vec3::Z);
    for cs in &structures(&scene, 32, 24) {
        let h = nearest_both(&scene, cs, &ray, 0.0, f64::INFINITY).unwrap();
        assert!((h.t - 4.0).abs() <= 1e-12, "{h:?}");
        assert_eq!(h.prim, PrimId(1));
        assert!(h.flip);
        // The solid's outward normal there points into the hole: +z.
        let n = checked_normal(&scene, &ray, &h);
        assert!((n - Vec3::Z).length() < 1e-12, "{n}");
        // Then the hole's far side, then the big sphere from inside.
        assert_hits(
            &hits_along(&scene, cs, &ray, 0.0),
            &[(1, 4.0), (1, 6.0), (0, 10.0)],
        );
    }
    assert_renders_equal(&scene, 32, 24);

    // On the big sphere's surface, looking in: the cut at t = 14.
    let scene = load(&ron(-10.0));
    let ray = Ray::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
    for cs in &structures(&scene, 32, 24) {
        assert_hits(
            &hits_along(&scene, cs, &ray, 0.0),
            &[(1, 14.0), (1, 16.0), (0, 20.0)],
        );
    }
    assert_renders_equal(&scene, 32, 24);
    // And on the hole's surface, looking through it.
    let scene = load(&ron(4.0));
    let ray = Ray::new(Vec3::new(0.0, 0.0, 4.0), Vec3::Z);
    for cs in &structures(&scene, 32, 24) {
        assert_hits(&hits_along(&scene, cs, &ray, 0.0), &[(1, 2.0), (0, 6.0)]);
    }
    assert_renders_equal(&scene, 32, 24);
}

// ---------------------------------------------------------------------------
// ROBUSTNESS.md 28: subnormal and negative-zero direction components.

#[test]
fn case_28_subnormal_and_negative_zero_directions_act_as_zero() {
    let cameras = [
        // The rays are primary rays along the view, sideways across the
        // screen, and in the back region.
        "(eye: (0, 0, 0), look_at: (1, 0, 0), fov_y: 40, width: 32, height: 24)",
        "(eye: (4, -10, 0), look_at: (4, 0, 0), fov_y: 60, width: 32, height: 24)",
        "(eye: (20, 0, 0.5), look_at: (30, 0, 0.5), fov_y: 40, width: 32, height: 24)",
    ];
    for camera in cameras {
        let scene = load(&format!(
            "(camera: {camera}, objects: [
                Sphere(center: (5, 0, 0), radius: 1),
                Box(min: (8, -0.5, -1), max: (9, 1, 1)),
                Box(min: (11, -1, -0.5), max: (12, 0.5, 1)),
                Cylinder(base: (14, 0, -1), top: (14, 0, 1), radius: 0.5),
            ])"
        ));
        for cs in &structures(&scene, 32, 24) {
            // Origins off every face: a ray along a face may rightly leave it with
            // a subnormal component.
            for o in [
                Vec3::ZERO,
                Vec3::new(0.0, 0.0, 0.25),
                Vec3::new(0.0, 0.25, -0.125),
            ] {
                let base = Ray::new(o, Vec3::X);
                let expected = hits_along(&scene, cs, &base, 0.0);
                let expected_walk: Vec<(Region, u32)> =
                    walk(cs, &base, 0.0).iter().map(|v| (v.0, v.1)).collect();
                for d in [
                    Vec3::new(1.0, 1e-310, 0.0),
                    Vec3::new(1.0, -0.0, 0.0),
                    Vec3::new(1.0, 0.0, -0.0),
                    Vec3::new(1.0, -1e-310, 1e-310),
                ] {
                    let ray = Ray::new(o, d);
                    assert_eq!(hits_along(&scene, cs, &ray, 0.0), expected, "{ray:?}");
                    let w: Vec<(Region, u32)> =
                        walk(cs, &ray, 0.0).iter().map(|v| (v.0, v.1)).collect();
                    assert_eq!(w, expected_walk, "{ray:?}");
                }
            }
        }
    }
}

/// The machine's extra super cells (`CellOptions::min_super_cells`): the
/// BSP makes at least that many where it has lines to split by, and the
/// image stays Roth's.
#[test]
fn forced_super_cells_are_there_and_change_no_pixel() {
    let scene = hypercast::scene::load_scene(&crate::util::repo("scenes/jagged_ball.ron")).unwrap();
    let opts = options(96, 72);
    let (roth, _) = render_roth(&scene, &opts, &|_| {});
    let plain = CellStructure::build(&scene, 96, 72, CellOptions::default()).unwrap();
    let want = 4 * plain.region(Region::Front).supers.len();
    let forced = CellOptions {
        min_super_cells: want,
        ..Default::default()
    };
    let (film, _, cs) = render_cells(&scene, &opts, forced, &|_| {});
    assert!(cs.region(Region::Front).supers.len() >= want);
    assert_eq!(roth.sums(), film.sums());
}

/// Extra super cells are forced only where the cost model alone makes
/// fewer than asked, unless `force_from_root` (the machine's plan without
/// copies) forces them from the BSP's first level on: the sphereflake's
/// cost model makes hundreds, so 64 cost no forced split, except from the
/// root. Either way the image stays Roth's.
#[test]
fn super_cells_are_forced_from_the_root_only_when_asked() {
    let scene =
        hypercast::scene::load_scene(&crate::util::repo("scenes/sphereflake4.nff")).unwrap();
    let opts = options(64, 64);
    let (roth, _) = render_roth(&scene, &opts, &|_| {});
    for force_from_root in [false, true] {
        let o = CellOptions {
            min_super_cells: 64,
            force_from_root,
            ..Default::default()
        };
        let (film, _, cs) = render_cells(&scene, &opts, o, &|_| {});
        assert!(cs.region(Region::Front).supers.len() >= 64);
        assert_eq!(
            cs.stats.forced_splits > 0,
            force_from_root,
            "{} forced splits",
            cs.stats.forced_splits
        );
        assert_eq!(
            roth.sums(),
            film.sums(),
            "force_from_root {force_from_root}"
        );
    }
}

/// Which lights the shadow shortcuts may use (`ShadowFacts::clear_lights`):
/// a light in the hollow of a shell (a sphere less a smaller one) or outside
/// everything is outside the solid; one in the shell's material, or on its
/// surface, is not. And a glass primitive is listed, so that shadow rays
/// meeting its box walk to their nearest surface.
#[test]
fn lights_outside_the_solid_are_told_apart_from_lights_inside_or_on_it() {
    let scene = load(
        "(camera: (eye: (0, -10, 0), look_at: (0, 0, 0), up: (0, 0, 1), fov_y: 40, width: 32, height: 24),
          lights: [(position: (0, 0, 0)), (position: (1.5, 0, 0)), (position: (0, 9, 0)), (position: (2, 0, 0)), (position: (0, 0, 1.5))],
          materials: { \"glass\": (transmit: 0.9, ior: 1.5) },
          objects: [
            Difference(children: [Sphere(center: (0, 0, 0), radius: 2), Sphere(center: (0, 0, 0), radius: 1)]),
            Sphere(center: (5, 5, 5), radius: 0.5, material: \"glass\"),
          ])",
    );
    let cs = CellStructure::build(&scene, 32, 24, CellOptions::default()).unwrap();
    let f = &cs.shadows;
    assert_eq!(f.clear_lights, [true, false, true, false, false]);
    assert_eq!(f.glass.as_ref().map(Vec::len), Some(1));
    // The shell's outer sphere is under a difference: not exposed; the
    // glass sphere is at the top.
    assert!(!f.is_exposed(0) && !f.is_exposed(1) && f.is_exposed(2));
}

/// The super cells are cut into cells on several threads for large scenes
/// (`CellOptions::build_threads`); the structure must not depend on how
/// many: the same cells, subtrees and leaf lists in the same order.
#[test]
fn the_structure_is_the_same_for_any_number_of_build_threads() {
    let model = hypercast::r#gen::sphereflake::sphereflake(3);
    let scene = compile_model(&model, Path::new("sf3")).unwrap().0;
    let json = |threads: usize| {
        let opts = CellOptions {
            build_threads: threads,
            min_super_cells: 24,
            ..CellOptions::default()
        };
        let mut cs = CellStructure::build(&scene, 96, 80, opts).unwrap();
        cs.stats.build_seconds = 0.0;
        serde_json::to_string(&cs).unwrap()
    };
    let one = json(1);
    assert!(json(1) == one, "two builds on one thread differ");
    assert!(one.len() > 10_000, "a structure worth cutting in parallel");
    for threads in [2, 3, 7] {
        assert!(
            json(threads) == one,
            "{threads} threads built another structure"
        );
    }
}
