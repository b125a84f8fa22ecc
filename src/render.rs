//! Single-node rendering: primary rays for every pixel, traced to completion
//! on a synchronous tracer, spread over host threads by row bands. The
//! hypercube machine (`machine`) renders the same rays as messages; both
//! produce bit-identical films because contributions sum in fixed point.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use crate::cells::{CellOptions, CellStructure, CellTracer};
use crate::error::{Error, Result, start_worker};
use crate::reference::RothTracer;
use crate::scene::Scene;
use crate::trace::{CameraFrame, Film, RayCounts, RayJob, Shader, Tracer};

pub mod aa;

pub use aa::{AaSummary, Adaptive, Pass, PixelSet, Sampling};

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

impl TraceCounters {
    pub fn merge(&mut self, o: &TraceCounters) {
        self.intersection_tests += o.intersection_tests;
        self.mailbox_hits += o.mailbox_hits;
        self.cells_visited += o.cells_visited;
        self.subtree_evaluations += o.subtree_evaluations;
    }
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

impl RenderStats {
    /// Adds another part's rays, counters and pixels (not its wall time).
    pub fn merge(&mut self, o: &RenderStats) {
        self.rays.merge(&o.rays);
        self.counters.merge(&o.counters);
        self.pixels_traced += o.pixels_traced;
        self.pixels_background += o.pixels_background;
    }
}

/// Sample `k` of `spp` within pixel `pixel`: stratified on a grid, jittered
/// by a hash of (pixel, k) only, so every node and thread draws the same
/// samples. One sample sits at the pixel's centre (`SCENE_FORMAT.md`).
pub fn sample_offset(pixel: u32, k: u32, spp: u32) -> (f64, f64) {
    sample_offset_from(pixel, k, spp, 0)
}

/// Sample `k` of a pass of `spp` samples whose first sample has index
/// `first`: stratum `k` of the pass's grid, jittered by a hash of (pixel,
/// first + k), so passes over the same pixel draw different samples. A
/// lone first sample (`spp` 1, `first` 0) is the pixel's centre.
pub fn sample_offset_from(pixel: u32, k: u32, spp: u32, first: u32) -> (f64, f64) {
    if spp <= 1 && first == 0 {
        return (0.5, 0.5);
    }
    let spp = spp.max(1);
    let (nx, ny) = strata(spp);
    let (cx, cy) = (k % nx, k / nx);
    let h = hash2(pixel, first.wrapping_add(k));
    let jx = (h & 0xffff_ffff) as f64 / 4294967296.0;
    let jy = (h >> 32) as f64 / 4294967296.0;
    ((cx as f64 + jx) / nx as f64, (cy as f64 + jy) / ny as f64)
}

/// The grid of `spp` samples: `nx` columns by `ny` rows with `nx·ny = spp`
/// exactly, as square as the divisors of `spp` allow (strips for a prime).
/// Every stratum then has the area its sample's weight `1/spp` stands for.
/// (A grid of `⌈√spp⌉` columns left strata of the last row empty for 3, 5,
/// 7, 8, 32, ... samples, so the row above stood for too much of the pixel:
/// 32 samples converged to another image than 16 did.)
///
/// Asked once per sample: the search goes down from `⌊√spp⌋`, so it ends
/// at once for square counts and within a few steps for most others.
fn strata(spp: u32) -> (u32, u32) {
    let spp = spp.max(1);
    let mut ny = (spp as f64).sqrt() as u32;
    while u64::from(ny) * u64::from(ny) > u64::from(spp) {
        ny -= 1;
    }
    while u64::from(ny + 1) * u64::from(ny + 1) <= u64::from(spp) {
        ny += 1;
    }
    while !spp.is_multiple_of(ny) {
        ny -= 1;
    }
    (spp / ny, ny)
}

/// SplitMix64 of two 32-bit keys.
fn hash2(a: u32, b: u32) -> u64 {
    let mut z = ((a as u64) << 32 | b as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The primary jobs of one pixel (samples `0..spp`).
pub fn pixel_jobs(cam: &CameraFrame, i: u32, j: u32, spp: u32, out: &mut Vec<RayJob>) {
    sample_jobs(cam, j * cam.width + i, spp, 0, out);
}

/// The primary jobs of samples `first..first + spp` of a pixel, each
/// weighted `1/spp`.
fn sample_jobs(cam: &CameraFrame, pixel: u32, spp: u32, first: u32, out: &mut Vec<RayJob>) {
    let (i, j) = (pixel % cam.width, pixel / cam.width);
    let spp = spp.max(1);
    let w = 1.0 / spp as f64;
    for k in 0..spp {
        let (fx, fy) = sample_offset_from(pixel, k, spp, first);
        out.push(cam.primary(i, j, fx, fy, w));
    }
}

/// Rows per unit of work handed to a thread.
const BAND_ROWS: u32 = 4;

/// Renders on this host with any synchronous tracer: `make_tracer` builds
/// one per thread; `skip_primary` asks the thread's tracer which primary
/// rays need no tracing (the paper's pixel areas) and only see the
/// background; `progress` is told rows done. Fails (`Error::Render`) only
/// if the OS refuses a thread.
pub fn render_with<T, M, S>(
    scene: &Scene,
    opts: &RenderOptions,
    make_tracer: M,
    skip_primary: S,
    progress: &(dyn Fn(u32) + Sync),
) -> Result<(Film, RenderStats)>
where
    T: Tracer,
    M: Fn() -> T + Sync,
    S: Fn(&mut T, &RayJob) -> bool + Sync,
{
    let all = PixelSet::all(opts.width, opts.height);
    let pass = Pass {
        pixels: &all,
        spp: opts.spp,
        first_sample: 0,
    };
    render_pass_with(
        scene,
        &pass,
        opts.threads,
        make_tracer,
        skip_primary,
        progress,
    )
}

/// Renders one pass (`aa::Pass`: some pixels, some samples each) on this
/// host over `threads` threads, with the same tracer arguments as
/// `render_with`. The film is full-size and zero outside the pass's
/// pixels; `progress` is told every band of rows, traced or empty.
///
/// Fails (`Error::Render`, naming the thread) if the OS refuses to start
/// a thread (`error::start_worker`): the threads already started stop
/// after their band, and no film is returned.
pub fn render_pass_with<T, M, S>(
    scene: &Scene,
    pass: &Pass<'_>,
    threads: usize,
    make_tracer: M,
    skip_primary: S,
    progress: &(dyn Fn(u32) + Sync),
) -> Result<(Film, RenderStats)>
where
    T: Tracer,
    M: Fn() -> T + Sync,
    S: Fn(&mut T, &RayJob) -> bool + Sync,
{
    let start = Instant::now();
    let (width, height) = (pass.pixels.width, pass.pixels.height);
    let cam = CameraFrame::new(scene, width, height);
    let shader = Shader::with_samples(scene, pass.spp);
    let next_band = AtomicU32::new(0);
    let bands = height.div_ceil(BAND_ROWS);
    let threads = threads.max(1).min(bands.max(1) as usize);
    // Bands are added to the image as they finish, not kept until the end:
    // a 4096×4096 film is 400 MB, and a second copy in bands doubled the
    // peak (`docs/robustness.md`). Fixed-point sums make the order free.
    let image = Mutex::new(Film::new(width, height));
    // One thread's whole share: bands taken in turn until none is left.
    let work = || {
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
            let rows = BAND_ROWS.min(height - y0);
            // A band without pixels of the pass (pass 2 of
            // adaptive sampling) costs no film.
            let mut film = None;
            for pixel in pass.pixels.in_rows(y0, rows) {
                let film = film.get_or_insert_with(|| Film::band(width, y0, rows));
                jobs.clear();
                pass.pixel_jobs(&cam, pixel, &mut jobs);
                let mut traced = false;
                for job in jobs.drain(..) {
                    if skip_primary(&mut tracer, &job) {
                        // Exactly what tracing would give: a miss.
                        film.add(job.pixel, shader.miss(&job));
                    } else {
                        traced = true;
                        shader.run_path(&mut tracer, job, film, &mut stats.rays, &mut stack);
                    }
                }
                if traced {
                    stats.pixels_traced += 1;
                } else {
                    stats.pixels_background += 1;
                }
            }
            if let Some(film) = film {
                image
                    .lock()
                    .expect("poisoned only by a panic in merge, a bug")
                    .merge(&film);
            }
            progress(rows);
        }
        let c = tracer.counters();
        (stats, c)
    };
    let results = std::thread::scope(|s| -> Result<Vec<(RenderStats, TraceCounters)>> {
        let mut handles = Vec::with_capacity(threads);
        for i in 0..threads {
            match start_worker(s, ("render", "render thread"), (i, threads), work) {
                Ok(h) => handles.push(h),
                Err(e) => {
                    // No band is handed out any more: the threads
                    // started finish the one they hold, and the scope
                    // joins them.
                    next_band.store(bands, Ordering::Relaxed);
                    return Err(e);
                }
            }
        }
        Ok(handles
            .into_iter()
            .map(|h| {
                h.join()
                    .expect("a render thread panicked (a bug, not bad input)")
            })
            .collect())
    })?;
    // Every thread was joined without a panic above, so none poisoned it.
    let film = image.into_inner().expect("no render thread panicked");
    let mut stats = RenderStats::default();
    for (s, c) in &results {
        stats.merge(s);
        stats.counters.merge(c);
    }
    stats.wall_seconds = start.elapsed().as_secs_f64();
    Ok((film, stats))
}

/// Renders with Roth's brute force. For tests and benches: a thin
/// `render_host`, infallible where its two dozen callers want it so.
///
/// # Panics
///
/// If the OS refuses a render thread (`render_pass_with`); the command
/// line renders through `render_host`, which reports that as an error.
pub fn render_roth(
    scene: &Scene,
    opts: &RenderOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> (Film, RenderStats) {
    let r = render_host(
        scene,
        opts,
        None,
        Accel::Roth,
        CellOptions::default(),
        progress,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    (r.film, r.stats)
}

/// Renders with the paper's cells: builds the subdivision for the camera,
/// then traces only the pixel areas. For tests and benches, as
/// `render_roth` is.
///
/// # Panics
///
/// If the OS refuses a render thread or one of the build's
/// (`CellStructure::build`), as `render_roth`.
pub fn render_cells(
    scene: &Scene,
    opts: &RenderOptions,
    cell_opts: CellOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> (Film, RenderStats, CellStructure) {
    let r = render_host(scene, opts, None, Accel::Cells, cell_opts, progress)
        .unwrap_or_else(|e| panic!("{e}"));
    let cs = r
        .cells
        .expect("render_host with Accel::Cells returns the structure it built");
    (r.film, r.stats, cs)
}

/// A render on this host, whatever the accelerator and sampling.
pub struct HostRender {
    pub film: Film,
    /// Rays and counters of every pass; pixels traced or background as
    /// pass 1 found them (every pixel once); wall time of the whole render,
    /// the subdivision's build included.
    pub stats: RenderStats,
    /// The subdivision, for `--accel cells`.
    pub cells: Option<CellStructure>,
    pub aa: AaSummary,
}

/// Renders with either accelerator and adaptive sampling on this host:
/// `opts.spp` samples per pixel in pass 1, then `adaptive`'s refinement.
/// The one entry point of CLI renders and quality points; the subdivision
/// is built once for both passes. `progress` is told rows of every pass.
/// Fails (`Error::Render`) only if the OS refuses a thread.
pub fn render_host(
    scene: &Scene,
    opts: &RenderOptions,
    adaptive: Option<Adaptive>,
    accel: Accel,
    cell_opts: CellOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> Result<HostRender> {
    let start = Instant::now();
    let cells = match accel {
        Accel::Roth => None,
        Accel::Cells => Some(CellStructure::build(
            scene,
            opts.width,
            opts.height,
            cell_opts,
        )?),
    };
    let sampling = Sampling {
        spp: opts.spp,
        adaptive,
    };
    let mut stats = RenderStats::default();
    let mut passes = 0;
    let (film, aa) = aa::render_adaptive(opts.width, opts.height, &sampling, |pass| {
        let (film, s) = match &cells {
            None => render_pass_with(
                scene,
                pass,
                opts.threads,
                || RothTracer::new(scene),
                |_, _| false,
                progress,
            )?,
            Some(cs) => render_pass_with(
                scene,
                pass,
                opts.threads,
                || CellTracer::new(cs, scene),
                |tracer, job| tracer.skips_primary(&job.ray),
                progress,
            )?,
        };
        if passes == 0 {
            stats.merge(&s);
        } else {
            // Refined pixels were counted as traced or background once.
            stats.rays.merge(&s.rays);
            stats.counters.merge(&s.counters);
        }
        passes += 1;
        Ok::<Film, Error>(film)
    })?;
    stats.wall_seconds = start.elapsed().as_secs_f64();
    Ok(HostRender {
        film,
        stats,
        cells,
        aa,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strata_tile_the_pixel_exactly() {
        assert_eq!(strata(1), (1, 1));
        assert_eq!(strata(2), (2, 1));
        assert_eq!(strata(7), (7, 1));
        assert_eq!(strata(8), (4, 2));
        assert_eq!(strata(16), (4, 4));
        assert_eq!(strata(32), (8, 4));
        for spp in 1..=300 {
            let (nx, ny) = strata(spp);
            assert!(nx * ny == spp && nx >= ny, "{spp}: {nx} x {ny}");
            // As square as the divisors allow: no divisor lies between.
            assert!(
                (ny + 1..=nx - 1).all(|d| !spp.is_multiple_of(d) || d * d > spp),
                "{spp}: {nx} x {ny}"
            );
        }
        assert_eq!(strata(65536), (256, 256));
        assert_eq!(strata(65521), (65521, 1));
    }

    /// Each pass's samples are one per stratum of equal area, whatever
    /// their number: averaged over many pixels' jitters, they estimate the
    /// integrals of x, y, x·y and y² over the pixel without bias. (The old
    /// grid of ⌈√spp⌉ columns missed 0.04 of y's mean at 8 samples.)
    #[test]
    fn samples_of_any_count_are_unbiased_over_the_pixel() {
        let pixels = 3000u32;
        for spp in 2..=40u32 {
            for first in [0, 1, 17] {
                let mut sums = [0.0f64; 4];
                let mut cells = std::collections::HashSet::new();
                for p in 0..pixels {
                    for k in 0..spp {
                        let (x, y) = sample_offset_from(p, k, spp, first);
                        assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y));
                        sums[0] += x;
                        sums[1] += y;
                        sums[2] += x * y;
                        sums[3] += y * y;
                        if p == 0 {
                            let (nx, ny) = strata(spp);
                            cells.insert(((x * nx as f64) as u32, (y * ny as f64) as u32));
                        }
                    }
                }
                assert_eq!(cells.len(), spp as usize, "spp {spp}: a stratum twice");
                let n = f64::from(pixels * spp);
                let exact = [0.5, 0.5, 0.25, 1.0 / 3.0];
                for (i, (s, e)) in sums.iter().zip(exact).enumerate() {
                    let mean = s / n;
                    // Within 5 standard errors of a uniform sample (the
                    // stratified ones' errors are smaller still).
                    let tol = 5.0 * 0.3 / n.sqrt();
                    assert!(
                        (mean - e).abs() < tol,
                        "spp {spp}, first {first}, moment {i}: {mean} against {e}"
                    );
                }
            }
        }
    }
}
