//! Which node owns which super cell (its cells, their subtrees, the pixels
//! of its pixel area). Each region's screen is cut into a grid of
//! `2^dx` columns by `2^dy` rows of equal estimated work, and the cell in
//! column c, row r goes to node `gray(c) << dy | gray(r)`, so that
//! neighbouring screen regions land on hypercube neighbours (`grid`); then
//! super cells move between neighbouring regions until the loads are even
//! (`refine`). The estimate is the load balance:
//!
//! * `Balanced` (default) weighs each super cell by the work a cheap
//!   pre-pass measured there: every `prepass_stride`-th pixel of every
//!   `prepass_stride`-th row traced through the whole structure on the
//!   host, all its ray kinds, counting cells entered and intersection
//!   tests, after Priol and Bouatouch's static load balancing on the
//!   iPSC. On more than one node the pre-pass then walks as the machine
//!   will under the mapping so far (a ray moves to a node where its part
//!   in a cell meets that cell's content, with cold mailboxes; the walk
//!   through other cells is its node's work), the grid is cut again by
//!   what it measured (`RECUTS`) and then refined. So walked, the
//!   pre-pass predicts each node's cells and tests: at every pixel,
//!   exactly; at every 8th of every 8th row, correlated at 0.99 with what
//!   the nodes then count;
//! * `EqualArea`, the naive split, weighs each super cell by its share of
//!   the image, so that every node owns as many pixels.

use crate::cells::projection::finite_span;
use crate::cells::{CellStructure, CellTracer, Copies, Hot, Move, Rect, Region};
use crate::error::{Result, start_worker};
use crate::machine::routing::gray;
use crate::render::pixel_jobs;
use crate::scene::Scene;
use crate::trace::{CameraFrame, Film, RayCounts, Shader};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};

/// How the load is balanced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Mapping {
    #[default]
    Balanced,
    EqualArea,
}

impl Mapping {
    /// The name `--mapping` takes.
    pub fn name(self) -> String {
        super::value_name(self)
    }
}

/// Pixels per side of the pre-pass's sampling grid cell, at most
/// (`prepass_stride`): the stride at which 32 nodes of a 1024x1024 image
/// get their `PREPASS_PER_NODE` pixels.
pub const PREPASS_STRIDE: u32 = 8;
/// The coarsest stride a pre-pass takes (`prepass_stride`).
pub const PREPASS_STRIDE_MAX: u32 = 16;
/// Pre-pass pixels per node that `prepass_stride` keeps at least, where
/// the stride may grow past `PREPASS_STRIDE`.
pub const PREPASS_PER_NODE: u64 = 512;

/// Pixels per side of the pre-pass's sampling grid for a `width` by
/// `height` image on `nodes` nodes: `PREPASS_STRIDE`, or coarser, up to
/// `PREPASS_STRIDE_MAX`, while every node still gets `PREPASS_PER_NODE`
/// pixels on average. A node's load sums its share of the pixels, so
/// fewer nodes need fewer pixels for the same estimate, while the pre-pass
/// (three traces and more) runs before any node starts: at d = 1 on the
/// sphereflake at 1024x1024 stride 16 took the mapping from 0.11-0.14 s
/// to 0.04-0.05 s of a 1.8-2.2 s render, with predicted loads even to
/// 1.0007 instead of 1.0002 and the busy imbalance within the noise (three
/// interleaved runs each: 1.005-1.033 against 1.008-1.032).
pub fn prepass_stride(width: u32, height: u32, nodes: usize) -> u32 {
    let per_node = |stride| prepass_pixels_at(width, height, stride) / nodes.max(1) as u64;
    (PREPASS_STRIDE..=PREPASS_STRIDE_MAX)
        .rev()
        .find(|&stride| per_node(stride) >= PREPASS_PER_NODE)
        .unwrap_or(PREPASS_STRIDE)
}

/// The pixels the pre-pass for `nodes` nodes traces of a `width` by
/// `height` image: every `prepass_stride`-th of every `prepass_stride`-th
/// row, from the middle of the first grid cell (`prepass`).
pub fn prepass_pixels(width: u32, height: u32, nodes: usize) -> u64 {
    prepass_pixels_at(width, height, prepass_stride(width, height, nodes))
}

/// `prepass_stride` for `map_whole`, finer than `PREPASS_STRIDE` (down to
/// every pixel) where the image is too small for `WHOLE_PREPASS_PER_NODE`
/// pixels a node at it. With the whole scene on every node the pre-pass's
/// estimate alone deals out the super cells, and a super cell it did not
/// sample weighs nothing: every such one went to the same node, the least
/// loaded. A room of mirrors at 80x60 on 32 nodes (2.2 pixels a node at
/// `PREPASS_STRIDE`) ran 14,986 virtual seconds, busy imbalance 23.5, and
/// 983 s, 1.21, at stride 2; `scenes/small/behind_eye.ron` at 64x48 on
/// 128 nodes 177 s (89) and 7.4 s (1.63) at stride 1. A small image's
/// pre-pass is cheap, so the floor costs the plan little.
pub fn whole_prepass_stride(width: u32, height: u32, nodes: usize) -> u32 {
    let stride = prepass_stride(width, height, nodes);
    let per_node = |stride| prepass_pixels_at(width, height, stride) / nodes.max(1) as u64;
    if stride > PREPASS_STRIDE || per_node(stride) >= WHOLE_PREPASS_PER_NODE {
        return stride;
    }
    (1..PREPASS_STRIDE)
        .rev()
        .find(|&s| per_node(s) >= WHOLE_PREPASS_PER_NODE)
        .unwrap_or(1)
}

/// Pre-pass pixels per node that `whole_prepass_stride` samples at least
/// where the image allows.
pub const WHOLE_PREPASS_PER_NODE: u64 = 32;

fn prepass_pixels_at(width: u32, height: u32, stride: u32) -> u64 {
    let along = |n| sampled(n, stride).count() as u64;
    along(width) * along(height)
}

/// The columns (or rows) of `n` that a pre-pass of `stride` traces: every
/// `stride`-th, from the middle of the first grid cell.
fn sampled(n: u32, stride: u32) -> std::iter::StepBy<std::ops::Range<u32>> {
    ((stride / 2).min(n - 1)..n).step_by(stride as usize)
}

/// What `map` gives: the work per super cell and region, the owner of
/// every super cell, and the moves of rays between nodes.
pub type Mapped = ([Vec<f64>; 2], [Vec<u16>; 2], Vec<Move>);

/// The estimated work of every super cell, per region, the owner of
/// every super cell for `2^d` nodes (`assign`; for `Balanced` on more
/// than one node, the grid cut again by pre-passes walked under the
/// mapping, `RECUTS`, then `refine`), and every move of the rays of the
/// last pre-pass walked under the mapping between nodes (none where none
/// was walked so: one node, or `EqualArea`): the estimate of the paths
/// the machine will send, and where (`host::replicas`). Fails
/// (`Error::Render`) only if the OS refuses a pre-pass thread.
pub fn map(
    cs: &CellStructure,
    scene: &Scene,
    width: u32,
    height: u32,
    mapping: Mapping,
    d: u32,
) -> Result<Mapped> {
    // Which super cells touch, once for every mapping made here.
    let beside = neighbours(cs);
    match mapping {
        Mapping::EqualArea => {
            let work = Region::BOTH.map(|r| {
                let rc = cs.region(r);
                if r == Region::Back {
                    // No pixel lies behind the eye: spread those evenly.
                    return vec![0.0; rc.supers.len()];
                }
                let cam = CameraFrame::new(scene, width, height);
                rc.supers
                    .iter()
                    .map(|s| {
                        let w = (s.rect.x1.min(cam.half_w) - s.rect.x0.max(-cam.half_w)).max(0.0);
                        let h = (s.rect.y1.min(cam.half_h) - s.rect.y0.max(-cam.half_h)).max(0.0);
                        w * h
                    })
                    .collect()
            });
            let owner = assign(cs, &beside, &work, d);
            Ok((work, owner, Vec::new()))
        }
        Mapping::Balanced => {
            let stride = prepass_stride(width, height, 1 << d);
            let (first, _) = prepass(cs, scene, width, height, Walked::Alone, stride)?;
            if d == 0 {
                let owner = assign(cs, &beside, &first, d);
                return Ok((first, owner, Vec::new()));
            }
            // Every cell's hull, once for the walks below.
            let skeleton = skeleton(cs, scene);
            // Walked again as the machine will, under the mapping so far:
            // the work a ray repeats after crossing to another node falls
            // on that node. The grid is cut again by the mean of what the
            // walks measured (`RECUTS`), which moves the cuts less at each
            // round, so the walk stays close to what it measured; a few
            // super cells then move between nodes (`refine`).
            let mut owner = grid(cs, &first, d);
            let walk = |owner: &[Vec<u16>; 2]| {
                prepass(
                    cs,
                    scene,
                    width,
                    height,
                    Walked::Under((owner, &skeleton, None)),
                    stride,
                )
            };
            let (mut work, mut moves) = walk(&owner)?;
            let mut sum = first;
            for round in 1..=RECUTS {
                if predicted_imbalance(&work, &owner, d) <= EVEN {
                    break;
                }
                for (s, w) in sum.iter_mut().zip(&work) {
                    for (a, b) in s.iter_mut().zip(w) {
                        *a += b;
                    }
                }
                let mean = sum
                    .clone()
                    .map(|v| v.into_iter().map(|x| x / (round + 1) as f64).collect());
                let next = grid(cs, &mean, d);
                // The pre-pass is the same for the same owners (each thread
                // takes fixed rows with a tracer of its own): a grid cut
                // as the last one was keeps that walk's work and moves (on
                // the sphereflake at d = 1 one round in three, a pre-pass
                // of 6 ms).
                if next != owner {
                    owner = next;
                    (work, moves) = walk(&owner)?;
                }
            }
            refine(&beside, &work, &mut owner, d);
            Ok((work, owner, moves))
        }
    }
}

/// `map`'s balanced mapping for nodes that each hold the whole structure
/// (`Replicas::Whole`): no ray leaves the node of its pixel, so a node's
/// load is the work of its pixels' paths, wherever in the scene they go.
/// One pre-pass books that work to each pixel's super cell
/// (`Walked::ByPixel`), and the super cells are dealt out on it alone
/// (`spread`): with no ray moving between nodes, neighbouring screen
/// regions need not share a node, and walking under the mapping would
/// book the same again. No moves.
pub fn map_whole(
    cs: &CellStructure,
    scene: &Scene,
    width: u32,
    height: u32,
    d: u32,
) -> Result<Mapped> {
    let stride = whole_prepass_stride(width, height, 1 << d);
    let (work, _) = prepass(cs, scene, width, height, Walked::ByPixel, stride)?;
    let owner = spread(&work, d);
    Ok((work, owner, Vec::new()))
}

/// The work a sample costs its node beyond its rays' walks, in the
/// pre-pass's units (`CellTracer::recorded_total`; some 22 ns each on this
/// host, session 46's regression): starting it, and its finished record
/// for the host, about 100 ns. Booked with the whole scene on every node
/// (`Walked::ByPixel`), where pixels are dealt out by their work alone:
/// without it a background pixel area weighed nothing, and every empty
/// super cell went to one node. `scenes/small/sphere.ron` at 320x240 on
/// 32 nodes, whose image is mostly background: busy imbalance 9-11 and
/// 70-110 virtual seconds before, against 2.3-3.7 and 17-27 with the
/// default placement.
const SAMPLE_UNITS: u64 = 4;

/// Super cells dealt to `2^d` nodes by their work alone, heaviest first,
/// each to the node least loaded so far (Graham's LPT rule; ties to the
/// lower super cell and node). Back super cells, where no pixel is, hold
/// no work and go to node 0.
fn spread(work: &[Vec<f64>; 2], d: u32) -> [Vec<u16>; 2] {
    let mut owner = work.clone().map(|w| vec![0u16; w.len()]);
    let front = &work[Region::Front as usize];
    let mut order: Vec<usize> = (0..front.len()).collect();
    order.sort_by(|&a, &b| front[b].total_cmp(&front[a]).then(a.cmp(&b)));
    let mut load = vec![0.0f64; 1 << d];
    for s in order {
        let (node, _) = load
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1).then(a.0.cmp(&b.0)))
            .expect("a hypercube has 2^d >= 1 nodes");
        load[node] += front[s];
        owner[Region::Front as usize][s] = node as u16;
    }
    owner
}

/// A super cell heavier than this share of a node's mean load is split by
/// the build (`hot`), into pieces of at most `HOT_PIECE` by area.
/// At 1024x1024 on 32 nodes, `jagged_ball.ron` had super cells of a
/// node's load and more, `house.ron` of 3.1 nodes'; split, their busy
/// imbalance went from 1.7-2.0 to 1.5 and from 3.0 to 1.4 (the
/// sphereflake's heaviest is 0.49: it is not split, and its structure over
/// 32 nodes stays within twice the single node's). At 0.75 the jagged ball
/// stayed at 1.64 (counted work). Tried and dropped: four refining rounds
/// keeping the most even mapping (it made sphereflake super cells heavy
/// enough to split, 633 instead of 535, and was no more even), moves in
/// chains of two and moves that only lower the loads' spread (both more
/// even by the estimate, less even or more hops in the run).
pub const HOT_LOAD: f64 = 0.5;
pub const HOT_PIECE: f64 = 0.25;

/// Pixels a piece of a hot super cell keeps at least (`hot`): splitting
/// finer than a few pixels' rays cannot even out anything, and every cut
/// adds cells.
pub const HOT_MIN_PIXELS: f64 = 16.0;

/// Where `hot` cuts a heavy super cell in front of the eye.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Span {
    /// Within the span of the region's finite coordinates.
    Finite,
    /// Within that span and the screen window: an unbounded super cell's
    /// pixels may lie past every finite cut, out to the screen's edges.
    Edges,
    /// Within its overlap with the screen window, where it has one: its
    /// pixels' work is there, however far its rectangle reaches (a camera
    /// of a hundredth of a degree sees a patch of one super cell whose
    /// rectangle is thousands of windows wide).
    Window,
}

/// The parts of each region's plane where the build must split its super
/// cells smaller (`bsp::Hot`), by the work `work` estimates per super cell
/// for `2^d` nodes: each super cell of more than `HOT_LOAD` of a node's
/// mean load, into pieces of at most `HOT_PIECE` of it (supposing its work
/// spread evenly over its rectangle) and at least `HOT_MIN_PIXELS` pixels
/// of `cam`'s `width` by `height` image. In front of the eye a super cell
/// is cut within `span` (an unbounded one, as the partition is of the
/// whole plane, within finite coordinates in every case).
/// `Span::Edges` is what nodes that hold everything take (`map_whole`),
/// where a split costs no crossing: on 32 nodes the jagged ball's heaviest super
/// cells (its floor, 1.5 to 2 nodes' loads) reached past every finite cut,
/// and unsplit they kept the loads at 1.55-1.57 predicted and 1.62-1.66
/// measured; cut to the edges, 1.002-1.006 and 1.20-1.26. Where rays walk
/// between nodes, the floor's pieces sent them across so often that the
/// plan kept no split at all (`Plan::new`), and the render took 717-729
/// virtual seconds against 567-600. Behind the eye, where no pixel is,
/// pieces are measured against the span of the region's primitives.
pub fn hot(
    cs: &CellStructure,
    work: &[Vec<f64>; 2],
    d: u32,
    (cam, width, height): (&CameraFrame, u32, u32),
    span: Span,
) -> [Vec<Hot>; 2] {
    let mean = work.iter().flatten().sum::<f64>() / (1u64 << d) as f64;
    let pixel_area = (2.0 * cam.half_w / f64::from(width)) * (2.0 * cam.half_h / f64::from(height));
    Region::BOTH.map(|r| {
        let rc = cs.region(r);
        let supers = &rc.supers;
        let (mut lo, mut hi) = finite_span(supers.iter().map(|s| &s.rect));
        let min_area = match r {
            Region::Front => {
                if span == Span::Edges {
                    for (k, half) in [cam.half_w, cam.half_h].into_iter().enumerate() {
                        lo[k] = lo[k].min(-half);
                        hi[k] = hi[k].max(half);
                    }
                }
                HOT_MIN_PIXELS * pixel_area
            }
            Region::Back => {
                // Behind the eye the cost model often keeps one super cell
                // for the whole plane (no pixel's primary ray weighs it),
                // without a finite coordinate: cut within the span of the
                // region's primitives, into pieces no finer than the
                // front's, counting that span as an image of as many
                // pixels.
                let (plo, phi) = rc.partition.span;
                for k in 0..2 {
                    lo[k] = lo[k].min(plo[k]);
                    hi[k] = hi[k].max(phi[k]);
                }
                let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
                HOT_MIN_PIXELS * area / (f64::from(width) * f64::from(height))
            }
        };
        let finite = (lo, hi);
        let window = Rect {
            x0: -cam.half_w,
            x1: cam.half_w,
            y0: -cam.half_h,
            y1: cam.half_h,
        };
        supers
            .iter()
            .zip(&work[r as usize])
            .filter(|&(_, &w)| d > 0 && w > HOT_LOAD * mean)
            .filter_map(|(s, &w)| {
                let seen = (r == Region::Front && span == Span::Window)
                    .then(|| s.rect.overlap(&window))
                    .flatten();
                let rect = match seen {
                    Some(seen) => seen,
                    None => {
                        let [Some((x0, x1)), Some((y0, y1))] = clamped(&s.rect, finite) else {
                            return None;
                        };
                        Rect { x0, x1, y0, y1 }
                    }
                };
                let area = (rect.x1 - rect.x0) * (rect.y1 - rect.y0);
                let max_area = (area / (w / (HOT_PIECE * mean)).ceil()).max(min_area);
                (area > max_area).then_some(Hot { rect, max_area })
            })
            .collect()
    })
}

/// `r`'s extent along each axis clamped to `span` (`finite_span`); None
/// along an axis without finite coordinates.
fn clamped(r: &Rect, (lo, hi): ([f64; 2], [f64; 2])) -> [Option<(f64, f64)>; 2] {
    [0, 1].map(|k| {
        (lo[k] <= hi[k]).then(|| (r.lo(k).clamp(lo[k], hi[k]), r.hi(k).clamp(lo[k], hi[k])))
    })
}

/// Traces every `stride`-th pixel of every `stride`-th row
/// through the whole structure, all its ray kinds, recording the work per
/// super cell (`Walked`): where one node would do it, as the machine walks
/// under a mapping (`CellTracer::record_work_for`), or, for nodes that
/// hold everything, on the super cell of each path's pixel.
///
/// Why walk as the machine does: the first pass alone balances what one
/// node would do, but on the machine the work a ray repeats after a
/// crossing falls on the node it crosses to, and a node walks through the
/// cells whose content its rays miss. An earlier model that made every
/// change of owner a crossing (the machine's walk-through ignored)
/// counted 26 million tests where the nodes made 20 million, and its
/// per-node loads did not correlate with the nodes' (-0.1).
///
/// Also returned: its rays' moves between nodes (walking under a mapping;
/// none without one), in the order of the rows. Fails (`Error::Render`) only if the OS
/// refuses a thread.
fn prepass(
    cs: &CellStructure,
    scene: &Scene,
    width: u32,
    height: u32,
    walk: Walked,
    stride: u32,
) -> Result<([Vec<f64>; 2], Vec<Move>)> {
    let cam = CameraFrame::new(scene, width, height);
    // On the host's cores, before any node starts, rows shared out in
    // turn. Each pixel's work is counted by its own rays alone (mailboxes
    // are keyed by ray), so the sums are the same for any thread count.
    let threads = crate::trace::host_cores();
    let rows: Vec<u32> = sampled(height, stride).collect();
    // Set when a thread is refused: the plan fails, so the threads already
    // started stop at their next row instead of tracing their share.
    let refused = AtomicBool::new(false);
    // One thread's share: every `threads`-th sampled row from its `t`-th.
    let trace_rows = |t: usize| {
        let shader = Shader::new(scene);
        let mut tracer = CellTracer::new(cs, scene);
        match walk {
            Walked::Under((owner, skeleton, None)) => {
                tracer.record_work_for(owner.clone(), skeleton)
            }
            Walked::Under((owner, skeleton, Some(copies))) => {
                tracer.record_work_with_copies(owner.clone(), skeleton, copies.clone())
            }
            Walked::Alone => tracer.record_work(),
            // As on a node that owns every super cell: no mailbox hit
            // counts as a test (none stands for a test after a move).
            Walked::ByPixel => {
                tracer.record_work_for(Region::BOTH.map(|r| vec![0; cs.region(r).supers.len()]), cs)
            }
        }
        // Per front super cell, the work of the paths of its pixels.
        let mut by_pixel = vec![0u64; cs.region(Region::Front).supers.len()];
        let (mut counts, mut stack, mut jobs) = (RayCounts::default(), Vec::new(), Vec::new());
        for &j in rows.iter().skip(t).step_by(threads) {
            if refused.load(Relaxed) {
                break;
            }
            // What the paths deliver is dropped: a row's band takes it (a
            // path's rays all carry its pixel). A whole film per thread
            // and pass was a clearing of 24 MiB each at 1024x1024, half
            // the pre-pass's time at d = 1.
            let mut film = Film::band(width, j, 1);
            for i in sampled(width, stride) {
                jobs.clear();
                pixel_jobs(&cam, i, j, 1, &mut jobs);
                let (before, pixel) = (tracer.recorded_total(), jobs.first().map(|j| j.ray));
                for job in jobs.drain(..) {
                    shader.run_path(&mut tracer, job, &mut film, &mut counts, &mut stack);
                }
                if let (Walked::ByPixel, Some(ray)) = (walk, pixel) {
                    let s = cs.primary_super_cell(&ray) as usize;
                    by_pixel[s] += tracer.recorded_total() - before + SAMPLE_UNITS;
                }
            }
        }
        let mut work = tracer
            .recorded_work()
            .expect("record_work or record_work_for was called above")
            .clone();
        if matches!(walk, Walked::ByPixel) {
            work = [by_pixel, vec![0; work[1].len()]];
        }
        (work, tracer.recorded_moves().to_vec())
    };
    let started = threads.min(rows.len()).max(1);
    let parts = std::thread::scope(|scope| -> Result<Vec<Recorded>> {
        let mut handles = Vec::with_capacity(started);
        for t in 0..started {
            let trace_rows = &trace_rows;
            // A thread the OS refuses fails the plan (`start_worker` says
            // why); the threads started stop at their next row, and the
            // scope joins them.
            let handle = start_worker(
                scope,
                ("prepass", "pre-pass thread"),
                (t, started),
                move || trace_rows(t),
            )
            .inspect_err(|_| refused.store(true, Relaxed))?;
            handles.push(handle);
        }
        Ok(handles
            .into_iter()
            .map(|h| {
                h.join()
                    .expect("a pre-pass thread panicked (a bug, not bad input)")
            })
            .collect())
    })?;
    let work = [0, 1].map(|r| {
        (0..parts[0].0[r].len())
            .map(|s| parts.iter().map(|p| p.0[r][s]).sum::<u64>() as f64)
            .collect()
    });
    let moves = parts.iter().flat_map(|p| p.1.iter().copied()).collect();
    Ok((work, moves))
}

/// How a pre-pass walks as the machine will: the owner of every super
/// cell, the structure as a node that owns nothing holds it (`skeleton`),
/// and the copies nodes hold, if any.
type WalkUnder<'a> = (&'a [Vec<u16>; 2], &'a CellStructure, Option<&'a Copies>);

/// How a pre-pass walks, and where it books the work (`prepass`).
#[derive(Clone, Copy)]
enum Walked<'a> {
    /// As one node would: to the super cell where it is done.
    Alone,
    /// As the machine will under a mapping (`WalkUnder`): to the super
    /// cell the ray's node does it for.
    Under(WalkUnder<'a>),
    /// As a node that holds everything: to the super cell of the path's
    /// pixel, where such nodes start the path and finish it.
    ByPixel,
}

/// What a pre-pass thread recorded: work per super cell, and the moves.
type Recorded = ([Vec<u64>; 2], Vec<Move>);

/// Each node's work under `owner` (with `copies`, where nodes hold copies
/// of others' super cells, `machine::replicas`) as the pre-pass predicts
/// it, from every `stride`-th pixel of every `stride`-th row (1: every
/// pixel), in the units of `CellTracer::record_work`: cells entered and
/// `cells::TEST_WORK` per intersection test. Fails as `map` does.
#[allow(clippy::too_many_arguments)]
pub fn predicted_loads(
    cs: &CellStructure,
    scene: &Scene,
    width: u32,
    height: u32,
    owner: &[Vec<u16>; 2],
    copies: Option<&Copies>,
    d: u32,
    stride: u32,
) -> Result<Vec<f64>> {
    let skeleton = skeleton(cs, scene);
    let (work, _) = prepass(
        cs,
        scene,
        width,
        height,
        Walked::Under((owner, &skeleton, copies)),
        stride.max(1),
    )?;
    Ok(loads(&work, owner, d))
}

/// The predicted imbalance under which `rebalance_with_copies` leaves
/// the mapping as it is: closer than `EVEN`, since a refinement costs no
/// walk here. (On two nodes of 8 MiB the sphereflake's copies left 1.015
/// predicted, and node 1 busy 4-8% longer than node 0; refined, 1.0005.)
const EVEN_WITH_COPIES: f64 = 1.005;

/// The work per super cell that the pre-pass measures walking under
/// `owner` where nodes hold `copies` of others' super cells
/// (`machine::replicas`): a ray that reaches a copy on its node stays
/// there, so its work there falls on that node. Where the loads it
/// predicts are uneven (past `EVEN_WITH_COPIES`), `owner` is refined by
/// it (`refine`),
/// and true is returned. Fails as `map` does.
pub fn rebalance_with_copies(
    cs: &CellStructure,
    scene: &Scene,
    (width, height): (u32, u32),
    owner: &mut [Vec<u16>; 2],
    copies: &Copies,
    d: u32,
) -> Result<([Vec<f64>; 2], bool)> {
    let skeleton = skeleton(cs, scene);
    let stride = prepass_stride(width, height, 1 << d);
    let (work, _) = prepass(
        cs,
        scene,
        width,
        height,
        Walked::Under((owner, &skeleton, Some(copies))),
        stride,
    )?;
    if predicted_imbalance(&work, owner, d) <= EVEN_WITH_COPIES {
        return Ok((work, false));
    }
    let before = owner.clone();
    refine(&neighbours(cs), &work, owner, d);
    let changed = *owner != before;
    Ok((work, changed))
}

/// The structure as a node that owns nothing holds it: every cell with
/// content remote, with its hull, which the pre-pass walks by
/// (`CellTracer::record_work_for`).
fn skeleton(cs: &CellStructure, scene: &Scene) -> CellStructure {
    cs.restrict(scene, &|_, _| false).0
}

/// The sum of the work of each node's super cells.
fn loads(work: &[Vec<f64>; 2], owner: &[Vec<u16>; 2], d: u32) -> Vec<f64> {
    let mut load = vec![0.0; 1 << d];
    for r in 0..2 {
        for (s, &o) in owner[r].iter().enumerate() {
            load[o as usize] += work[r][s];
        }
    }
    load
}

/// How many times, at most, the grid is cut again by the work the
/// pre-pass measured walking under the mappings so far (`map`), and the
/// predicted imbalance under which it is not (the cuts are then even
/// enough; on two nodes the first grid is, and the pre-pass walks once).
///
/// Predicted imbalance of the nodes' counted work (cells + 4 tests, which
/// is deterministic) on 32 nodes, the mapping before (the grid refined
/// against two walks) against three re-cuts and one refine: sphereflake
/// level 4 at 1024x1024 1.152 and 1.104, the jagged ball 1.339 and 1.298,
/// the house 1.483 and 1.461, `csg_basics.ron` 1.334 and 1.150, the
/// glass scene 1.294 and 1.164. Measured busy imbalance on the
/// sphereflake 1.15-1.18 before, 1.11-1.12 after, for slightly fewer hops
/// (3.65 M against 3.67 M). Four re-cuts predicted 1.065 and ran at
/// 1.09-1.10, but took 3.91 M hops; the structure held over the nodes is
/// 1.998x the single node's in all three. (Rounds of `refine` alone, the
/// way before that: 1.24 after one, 1.18 after two, 1.22 after four, as
/// each move changes the work it was chosen by, and more rounds
/// fragment the regions.)
const RECUTS: usize = 3;
const EVEN: f64 = 1.03;

/// A super cell's place in the mapping: its region, index, the centre of
/// its rectangle (clamped to the finite part of the plane) and its weight.
#[derive(Clone, Copy)]
struct Item {
    region: usize,
    s: u32,
    x: f64,
    y: f64,
    w: f64,
}

/// The owner of every super cell of each region, for `2^d` nodes: a
/// Gray-coded grid (`grid`), then refined (`refine`) over the super
/// cells' `neighbours`.
fn assign(cs: &CellStructure, beside: &Beside, work: &[Vec<f64>; 2], d: u32) -> [Vec<u16>; 2] {
    let mut owner = grid(cs, work, d);
    refine(beside, work, &mut owner, d);
    owner
}

/// Every super cell also weighs a little (a share of the mean), so that
/// work-free stretches still spread out.
fn weights(work: &[Vec<f64>; 2]) -> [Vec<f64>; 2] {
    let count: usize = work.iter().map(Vec::len).sum();
    let total: f64 = work.iter().flatten().sum();
    let floor = 0.01 * total.max(1.0) / count.max(1) as f64;
    work.clone()
        .map(|v| v.into_iter().map(|w| w + floor).collect())
}

/// The first mapping: each region's screen is cut into `2^dx` columns of
/// equal weight, each column into `2^dy` rows of equal weight
/// (`dx + dy = d`, the extra bit on the axis along which the work spreads
/// more), and the super cell whose centre falls in column `c`, row `r`
/// goes to node `gray(c) << dy | gray(r)`. Neighbouring columns and
/// neighbouring rows then differ in one bit: a ray crossing to the next
/// region on screen goes one hop.
///
/// Why not one run of a space-filling order (the BSP's depth-first order
/// cut into `2^d` runs, run i on `gray(i)`, as before): there only
/// consecutive runs are neighbours; regions side by side on screen but
/// apart in the order are several hops apart, and rays cross sideways.
/// Sphereflake level 4, 1024x1024, 32 nodes: 5.17 million hops, 1.79
/// million of them forwarding, 81 bytes per ray; with the grid 3.48
/// million, 0.58 million and 59.
fn grid(cs: &CellStructure, work: &[Vec<f64>; 2], d: u32) -> [Vec<u16>; 2] {
    let weight = weights(work);
    let mut owner = Region::BOTH.map(|r| vec![0u16; cs.region(r).supers.len()]);
    for r in Region::BOTH {
        let items = items(cs, &weight, r);
        if items.is_empty() {
            continue;
        }
        let spread = |f: fn(&Item) -> f64| {
            let sum: f64 = items.iter().map(|i| i.w).sum();
            let mean = items.iter().map(|i| i.w * f(i)).sum::<f64>() / sum;
            items
                .iter()
                .map(|i| i.w * (f(i) - mean).powi(2))
                .sum::<f64>()
                / sum
        };
        let wide = spread(|i| i.x) >= spread(|i| i.y);
        let dx = if wide { d.div_ceil(2) } else { d / 2 };
        let dy = d - dx;
        for (c, column) in cut(items, |i| i.x, 1 << dx).into_iter().enumerate() {
            for (row, cell) in cut(column, |i| i.y, 1 << dy).into_iter().enumerate() {
                let node = gray(c as u16) << dy | gray(row as u16);
                for i in cell {
                    owner[i.region][i.s as usize] = node;
                }
            }
        }
    }
    owner
}

/// The super cells of region `r` with their centres and weights.
fn items(cs: &CellStructure, weight: &[Vec<f64>; 2], r: Region) -> Vec<Item> {
    let rc = cs.region(r);
    // Unbounded rectangles (the partition is of the whole plane) are
    // clamped to the span of the finite coordinates.
    let span = finite_span(rc.supers.iter().map(|s| &s.rect));
    rc.supers
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let [x, y] = clamped(&s.rect, span).map(|e| e.map_or(0.0, |(a, b)| (a + b) / 2.0));
            Item {
                region: r as usize,
                s: i as u32,
                x,
                y,
                w: weight[r as usize][i],
            }
        })
        .collect()
}

/// `items` sorted by `key` and cut into `parts` runs of equal weight (an
/// item goes to the run whose share of the total holds its middle).
fn cut(mut items: Vec<Item>, key: fn(&Item) -> f64, parts: usize) -> Vec<Vec<Item>> {
    items.sort_by(|a, b| key(a).total_cmp(&key(b)));
    let sum: f64 = items.iter().map(|i| i.w).sum();
    let mut out = vec![Vec::new(); parts];
    let mut acc = 0.0;
    for i in items {
        let run = (((acc + i.w / 2.0) / sum) * parts as f64) as usize;
        acc += i.w;
        out[run.min(parts - 1)].push(i);
    }
    out
}

/// Evens out the loads by moving super cells, one at a time, from the
/// most loaded node to a node that owns a super cell beside it on screen
/// (so regions stay compact and crossings stay short), the move that
/// lowers the larger of the two loads most, until no move lowers the
/// largest load. The grid's cuts balance columns and rows, but a super
/// cell is never split, and a few heavy ones (the sphereflake's big
/// sphere) leave some nodes well above the mean.
fn refine(beside: &Beside, work: &[Vec<f64>; 2], owner: &mut [Vec<u16>; 2], d: u32) {
    let weight = weights(work);
    let mut load = loads(&weight, owner, d);
    // Each move scans every super cell: a bound keeps huge structures
    // cheap (a few moves per node is what balancing takes).
    for _ in 0..8 * load.len() {
        let h = (0..load.len())
            .max_by(|&a, &b| load[a].total_cmp(&load[b]))
            .expect("loads has 2^d >= 1 nodes");
        let mut best: Option<(usize, usize, u16, f64)> = None;
        for r in 0..2 {
            for (s, &o) in owner[r].iter().enumerate() {
                if o as usize != h {
                    continue;
                }
                let w = weight[r][s];
                for &t in &beside[r][s] {
                    let to = owner[r][t as usize];
                    if to as usize == h {
                        continue;
                    }
                    let worst = (load[h] - w).max(load[to as usize] + w);
                    if worst < load[h] && best.is_none_or(|b| worst < b.3) {
                        best = Some((r, s, to, worst));
                    }
                }
            }
        }
        let Some((r, s, to, _)) = best else { break };
        load[h] -= weight[r][s];
        load[to as usize] += weight[r][s];
        owner[r][s] = to;
    }
}

/// Per region, each super cell's `adjacent` ones.
type Beside = [Vec<Vec<u32>>; 2];

fn neighbours(cs: &CellStructure) -> Beside {
    Region::BOTH.map(|r| adjacent(&cs.region(r).supers))
}

/// For each super cell, the super cells that share a piece of an edge
/// with it. Neighbours meet on a splitting line, so their coordinates
/// there are the same number.
fn adjacent(supers: &[crate::cells::SuperCell]) -> Vec<Vec<u32>> {
    use std::collections::HashMap;
    /// A cell's extent along a line, and the cell.
    type Span = (f64, f64, u32);
    let mut out = vec![Vec::new(); supers.len()];
    // Per axis: for each line, the spans (along the other axis) of the
    // cells ending there and of those starting there.
    for axis in 0..2 {
        let mut lines: HashMap<u64, (Vec<Span>, Vec<Span>)> = HashMap::new();
        for (i, c) in supers.iter().enumerate() {
            let r = &c.rect;
            let (a0, a1, span) = if axis == 0 {
                (r.x0, r.x1, (r.y0, r.y1))
            } else {
                (r.y0, r.y1, (r.x0, r.x1))
            };
            lines
                .entry(a1.to_bits())
                .or_default()
                .0
                .push((span.0, span.1, i as u32));
            lines
                .entry(a0.to_bits())
                .or_default()
                .1
                .push((span.0, span.1, i as u32));
        }
        for (_, (mut ending, mut starting)) in lines {
            ending.sort_by(|a, b| a.0.total_cmp(&b.0));
            starting.sort_by(|a, b| a.0.total_cmp(&b.0));
            // Two sorted lists of intervals tiling (parts of) the line:
            // walk them together, pairing the ones that overlap.
            let (mut i, mut j) = (0, 0);
            while i < ending.len() && j < starting.len() {
                let (a, b) = (ending[i], starting[j]);
                if a.1.min(b.1) > a.0.max(b.0) {
                    out[a.2 as usize].push(b.2);
                    out[b.2 as usize].push(a.2);
                }
                if a.1 <= b.1 {
                    i += 1;
                } else {
                    j += 1;
                }
            }
        }
    }
    // In index order, whatever order the lines came in (the hash map's
    // is random), so that the mapping is the same on every run.
    for v in &mut out {
        v.sort_unstable();
        v.dedup();
    }
    out
}

/// The largest estimated load of a node against the mean (1 is perfect).
pub fn predicted_imbalance(work: &[Vec<f64>; 2], owner: &[Vec<u16>; 2], d: u32) -> f64 {
    super::max_over_mean(loads(work, owner, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cells::{CellOptions, Rect};
    use crate::scene::load::compile_model;

    fn flake(min_super_cells: usize) -> (CellStructure, Scene) {
        let model = crate::r#gen::sphereflake::sphereflake(2);
        let scene = compile_model(&model, std::path::Path::new("flake.ron"))
            .expect("compiles")
            .0;
        let opts = CellOptions {
            min_super_cells,
            ..CellOptions::default()
        };
        (CellStructure::build(&scene, 64, 64, opts).unwrap(), scene)
    }

    /// Whether two rectangles share a piece of an edge.
    fn touch(a: &Rect, b: &Rect) -> bool {
        let overlap = |a0: f64, a1: f64, b0: f64, b1: f64| a1.min(b1) > a0.max(b0);
        ((a.x1 == b.x0 || b.x1 == a.x0) && overlap(a.y0, a.y1, b.y0, b.y1))
            || ((a.y1 == b.y0 || b.y1 == a.y0) && overlap(a.x0, a.x1, b.x0, b.x1))
    }

    #[test]
    fn neighbours_are_the_super_cells_sharing_an_edge() {
        let (cs, _) = flake(64);
        for r in Region::BOTH {
            let supers = &cs.region(r).supers;
            let beside = adjacent(supers);
            for (i, a) in supers.iter().enumerate() {
                let mut want: Vec<u32> = (0..supers.len() as u32)
                    .filter(|&j| j as usize != i && touch(&a.rect, &supers[j as usize].rect))
                    .collect();
                let mut got = beside[i].clone();
                want.sort_unstable();
                got.sort_unstable();
                assert_eq!(got, want, "{r:?} super cell {i}");
            }
        }
    }

    #[test]
    fn the_grid_puts_screen_neighbours_on_near_nodes_and_shares_the_work() {
        let (cs, _) = flake(64);
        let d = 3;
        let work = Region::BOTH.map(|r| vec![1.0; cs.region(r).supers.len()]);
        let owner = grid(&cs, &work, d);
        let rc = cs.region(Region::Front);
        let beside = adjacent(&rc.supers);
        // Columns and rows are Gray coded: side by side on screen is at
        // most one hop per axis apart.
        let mut hops = 0;
        let mut pairs = 0;
        for (s, b) in beside.iter().enumerate() {
            for &t in b {
                let h = (owner[0][s] ^ owner[0][t as usize]).count_ones();
                assert!(h <= 2, "super cells {s} and {t}: {h} hops");
                hops += h;
                pairs += 1;
            }
        }
        assert!(
            f64::from(hops) < 0.5 * f64::from(pairs),
            "{hops} hops over {pairs} pairs"
        );
        let load = loads(&work, &owner, d);
        let mean = load.iter().sum::<f64>() / load.len() as f64;
        for (n, l) in load.iter().enumerate() {
            assert!(
                *l > 0.5 * mean && *l < 1.5 * mean,
                "node {n}: {l} against {mean}"
            );
        }
    }

    /// With the whole scene on every node, the pre-pass samples finer
    /// than `PREPASS_STRIDE` only where a node would get fewer than
    /// `WHOLE_PREPASS_PER_NODE` pixels at it, and then at the coarsest
    /// stride that gives them, or every pixel.
    #[test]
    fn the_whole_scenes_prepass_samples_small_images_finer() {
        assert_eq!(whole_prepass_stride(1024, 1024, 32), PREPASS_STRIDE);
        assert_eq!(whole_prepass_stride(1024, 1024, 1), PREPASS_STRIDE_MAX);
        assert_eq!(whole_prepass_stride(80, 60, 32), 2);
        assert_eq!(whole_prepass_stride(64, 48, 128), 1);
        for (w, h) in [(1024, 1024), (320, 240), (80, 60), (64, 48), (7, 3)] {
            for d in 0..8 {
                let n = 1usize << d;
                let stride = whole_prepass_stride(w, h, n);
                let per_node = |s| prepass_pixels_at(w, h, s) / n as u64;
                if stride < PREPASS_STRIDE {
                    assert_eq!(prepass_stride(w, h, n), PREPASS_STRIDE);
                    assert!(per_node(stride + 1) < WHOLE_PREPASS_PER_NODE);
                    assert!(stride == 1 || per_node(stride) >= WHOLE_PREPASS_PER_NODE);
                } else {
                    assert_eq!(stride, prepass_stride(w, h, n), "{w}x{h}, {n} nodes");
                }
            }
        }
    }

    /// The pre-pass samples coarser only where every node keeps its
    /// `PREPASS_PER_NODE` pixels, within `PREPASS_STRIDE` and
    /// `PREPASS_STRIDE_MAX`.
    #[test]
    fn the_prepass_stride_keeps_enough_pixels_per_node() {
        assert_eq!(prepass_stride(1024, 1024, 1), PREPASS_STRIDE_MAX);
        assert_eq!(prepass_stride(1024, 1024, 2), PREPASS_STRIDE_MAX);
        assert_eq!(prepass_stride(1024, 1024, 32), PREPASS_STRIDE);
        // Too small an image for 512 pixels a node: the finest stride.
        assert_eq!(prepass_stride(64, 48, 32), PREPASS_STRIDE);
        for (w, h) in [(1024, 1024), (640, 480), (4096, 2160), (97, 5)] {
            for d in 0..8 {
                let n = 1usize << d;
                let stride = prepass_stride(w, h, n);
                assert!((PREPASS_STRIDE..=PREPASS_STRIDE_MAX).contains(&stride));
                let per_node = prepass_pixels(w, h, n) / n as u64;
                // Coarser than the finest only with the pixels to spare,
                // and no coarser stride would have kept them.
                if stride > PREPASS_STRIDE {
                    assert!(per_node >= PREPASS_PER_NODE, "{w}x{h}, {n} nodes");
                }
                if stride < PREPASS_STRIDE_MAX {
                    let coarser = prepass_pixels_at(w, h, stride + 1) / n as u64;
                    assert!(coarser < PREPASS_PER_NODE, "{w}x{h}, {n} nodes");
                }
            }
        }
    }

    /// The mapping is the same on every run (the statistics of a render,
    /// hops and bytes, depend on it): no hash map's order leaks into it.
    #[test]
    fn the_mapping_is_the_same_every_time() {
        let (cs, _) = flake(64);
        let work = Region::BOTH.map(|r| {
            (0..cs.region(r).supers.len())
                .map(|s| 1.0 + (s * 7 % 11) as f64)
                .collect::<Vec<f64>>()
        });
        let first = assign(&cs, &neighbours(&cs), &work, 4);
        for _ in 0..4 {
            assert_eq!(assign(&cs, &neighbours(&cs), &work, 4), first);
        }
    }

    /// A pre-pass walked twice under the same owners books the same work
    /// and the same moves, whatever the threads' timing: what lets `map`
    /// keep a walk's results for a grid cut as the last one was.
    #[test]
    fn a_prepass_under_the_same_owners_gives_the_same_work_and_moves() {
        let (cs, scene) = flake(64);
        let (first, _) = prepass(&cs, &scene, 64, 64, Walked::Alone, 2).unwrap();
        let owner = grid(&cs, &first, 3);
        let skeleton = skeleton(&cs, &scene);
        let walk = || {
            prepass(
                &cs,
                &scene,
                64,
                64,
                Walked::Under((&owner, &skeleton, None)),
                2,
            )
            .unwrap()
        };
        let (work, moves) = walk();
        assert!(!moves.is_empty(), "rays cross between the grid's nodes");
        for _ in 0..3 {
            assert_eq!(walk(), (work.clone(), moves.clone()));
        }
    }

    #[test]
    fn refining_never_raises_the_largest_load() {
        let (cs, _) = flake(64);
        let d = 3;
        // Uneven work: a few heavy super cells.
        let work = Region::BOTH.map(|r| {
            (0..cs.region(r).supers.len())
                .map(|s| {
                    if s % 17 == 0 {
                        40.0
                    } else {
                        1.0 + (s % 5) as f64
                    }
                })
                .collect::<Vec<f64>>()
        });
        let mut owner = grid(&cs, &work, d);
        let weight = weights(&work);
        let before = loads(&weight, &owner, d);
        refine(&neighbours(&cs), &work, &mut owner, d);
        let after = loads(&weight, &owner, d);
        let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
        assert!(max(&after) <= max(&before), "{before:?} -> {after:?}");
        assert!((before.iter().sum::<f64>() - after.iter().sum::<f64>()).abs() < 1e-9);
        assert!(owner.iter().flatten().all(|&o| o < 1 << d));
    }
}
