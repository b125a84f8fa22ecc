//! Single-node rendering: primary rays for every pixel, traced to completion
//! on a synchronous tracer, spread over host threads by row bands. The
//! hypercube machine (`machine`) renders the same rays as messages; both
//! produce bit-identical films because contributions sum in fixed point.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use crate::cells::{CellOptions, CellStructure, CellTracer};
use crate::reference::RothTracer;
use crate::scene::Scene;
use crate::trace::{CameraFrame, Film, RayCounts, RayJob, Shader, Tracer};

/// Which accelerator finds hits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accel {
    /// Roth's brute force, the reference.
    Roth,
    /// The paper's space subdivision.
    Cells,
}

impl Accel {
    pub fn name(self) -> &'static str {
        match self {
            Accel::Roth => "roth",
            Accel::Cells => "cells",
        }
    }
}

/// What to render, beyond the scene.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel (stratified, deterministic).
    pub spp: u32,
    /// Host threads for single-node renders.
    pub threads: usize,
}

/// Counters a tracer keeps; summed over threads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TraceCounters {
    pub intersection_tests: u64,
    pub mailbox_hits: u64,
    /// Cells entered by rays (cells accelerator only).
    pub cells_visited: u64,
    /// Cell subtrees evaluated (cells accelerator only).
    pub subtree_evaluations: u64,
}

/// Statistics of a single-node render.
#[derive(Clone, Debug, Default)]
pub struct RenderStats {
    pub wall_seconds: f64,
    pub rays: RayCounts,
    pub counters: TraceCounters,
    pub pixels_traced: u64,
    pub pixels_background: u64,
}

/// Sample `k` of `spp` within pixel `pixel`: stratified on a grid, jittered
/// by a hash of (pixel, k) only, so every node and thread draws the same
/// samples. One sample sits at the pixel's centre (`SCENE_FORMAT.md`).
pub fn sample_offset(pixel: u32, k: u32, spp: u32) -> (f64, f64) {
    if spp <= 1 {
        return (0.5, 0.5);
    }
    let nx = (spp as f64).sqrt().ceil() as u32;
    let ny = spp.div_ceil(nx);
    let (cx, cy) = (k % nx, k / nx);
    let h = hash2(pixel, k);
    let jx = (h & 0xffff_ffff) as f64 / 4294967296.0;
    let jy = (h >> 32) as f64 / 4294967296.0;
    ((cx as f64 + jx) / nx as f64, (cy as f64 + jy) / ny as f64)
}

/// SplitMix64 of two 32-bit keys.
fn hash2(a: u32, b: u32) -> u64 {
    let mut z = ((a as u64) << 32 | b as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The primary jobs of one pixel.
pub fn pixel_jobs(cam: &CameraFrame, i: u32, j: u32, spp: u32, out: &mut Vec<RayJob>) {
    let pixel = j * cam.width + i;
    let w = 1.0 / spp.max(1) as f64;
    for k in 0..spp.max(1) {
        let (fx, fy) = sample_offset(pixel, k, spp);
        out.push(cam.primary(i, j, fx, fy, w));
    }
}

/// Rows per unit of work handed to a thread.
const BAND_ROWS: u32 = 4;

/// Renders on this host with any synchronous tracer: `make_tracer` builds
/// one per thread; `skip_primary` says which primary rays need no tracing
/// (the paper's pixel areas) and only see the background; `progress` is
/// told rows done.
pub fn render_with<T, M, S>(
    scene: &Scene,
    opts: &RenderOptions,
    make_tracer: M,
    skip_primary: S,
    progress: &(dyn Fn(u32) + Sync),
) -> (Film, RenderStats)
where
    T: Tracer,
    M: Fn() -> T + Sync,
    S: Fn(&RayJob) -> bool + Sync,
{
    let start = Instant::now();
    let cam = CameraFrame::new(scene, opts.width, opts.height);
    let shader = Shader::with_samples(scene, opts.spp);
    let next_band = AtomicU32::new(0);
    let bands = opts.height.div_ceil(BAND_ROWS);
    let threads = opts.threads.max(1).min(bands.max(1) as usize);
    // Bands are added to the image as they finish, not kept until the end:
    // a 4096×4096 film is 400 MB, and a second copy in bands doubled the
    // peak (`docs/robustness.md`). Fixed-point sums make the order free.
    let image = Mutex::new(Film::new(opts.width, opts.height));
    let results: Vec<(RenderStats, TraceCounters)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut tracer = make_tracer();
                    let mut stats = RenderStats::default();
                    let mut stack = Vec::new();
                    let mut jobs = Vec::new();
                    loop {
                        let b = next_band.fetch_add(1, Ordering::Relaxed);
                        if b >= bands {
                            break;
                        }
                        let y0 = b * BAND_ROWS;
                        let rows = BAND_ROWS.min(opts.height - y0);
                        let mut film = Film::band(opts.width, y0, rows);
                        for j in y0..y0 + rows {
                            for i in 0..opts.width {
                                jobs.clear();
                                pixel_jobs(&cam, i, j, opts.spp, &mut jobs);
                                let mut traced = false;
                                for job in jobs.drain(..) {
                                    if skip_primary(&job) {
                                        // Exactly what tracing would give: a miss.
                                        film.add(job.pixel, shader.miss(&job));
                                    } else {
                                        traced = true;
                                        shader.run_path(
                                            &mut tracer,
                                            job,
                                            &mut film,
                                            &mut stats.rays,
                                            &mut stack,
                                        );
                                    }
                                }
                                if traced {
                                    stats.pixels_traced += 1;
                                } else {
                                    stats.pixels_background += 1;
                                }
                            }
                        }
                        image.lock().expect("a render thread panicked").merge(&film);
                        progress(rows);
                    }
                    let c = tracer.counters();
                    (stats, c)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("render thread panicked"))
            .collect()
    });
    let film = image.into_inner().expect("a render thread panicked");
    let mut stats = RenderStats::default();
    for (s, c) in &results {
        stats.rays.merge(&s.rays);
        stats.pixels_traced += s.pixels_traced;
        stats.pixels_background += s.pixels_background;
        stats.counters.intersection_tests += c.intersection_tests;
        stats.counters.mailbox_hits += c.mailbox_hits;
        stats.counters.cells_visited += c.cells_visited;
        stats.counters.subtree_evaluations += c.subtree_evaluations;
    }
    stats.wall_seconds = start.elapsed().as_secs_f64();
    (film, stats)
}

/// Renders with Roth's brute force.
pub fn render_roth(
    scene: &Scene,
    opts: &RenderOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> (Film, RenderStats) {
    render_with(scene, opts, || RothTracer::new(scene), |_| false, progress)
}

/// Renders with the paper's cells: builds the subdivision for the camera,
/// then traces only the pixel areas.
pub fn render_cells(
    scene: &Scene,
    opts: &RenderOptions,
    cell_opts: CellOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> (Film, RenderStats, CellStructure) {
    let cs = CellStructure::build(scene, opts.width, opts.height, cell_opts);
    let (film, mut stats) = render_with(
        scene,
        opts,
        || CellTracer::new(&cs, scene),
        |job| CellTracer::primary_is_background(&cs, &job.ray),
        progress,
    );
    stats.wall_seconds += cs.stats.build_seconds;
    (film, stats, cs)
}
