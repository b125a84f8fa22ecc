//! The `quality` experiment (`DESIGN.md`, "Error against run time"):
//! render a reference, then the same scene at each setting of the quality
//! knobs (samples per pixel, adaptive threshold, recursion depth), and
//! measure each render's error against the reference beside its run time.
//! Every point of the curve goes through `render_point`, the one place that
//! decides what renders a point (this host's threads). Then the model's
//! error: a few of the points again on the hypercube machine, with a
//! topology calibrated on this host (`machine::calibrate`), for each
//! dimension the host has a core per node for, virtual time against the
//! wall time of the same run (`model_runs`). Tables, CSV and the plot are
//! `report::quality`'s.

use crate::cells::CellOptions;
use crate::error::Result;
use crate::machine::calibrate::Calibration;
use crate::machine::{self, MachineOptions};
use crate::render::{self, Accel, Adaptive, RenderOptions, RenderStats};
use crate::report::quality::{Knobs, Point};
use crate::report::{self, DisplayImage, compare, image_io};
use crate::scene::Scene;
use crate::trace::Film;

/// What rendering one point gave.
pub struct PointRender {
    pub film: Film,
    pub stats: RenderStats,
    /// Pixels the adaptive pass refined.
    pub refined_pixels: u64,
    /// Primary samples over all passes.
    pub samples: u64,
    /// The modelled machine's predicted makespan, when a machine rendered
    /// the point (`None` on this host's threads).
    pub virtual_seconds: Option<f64>,
}

/// Renders `scene` (whose `max_depth` is already the point's) with the
/// point's sampling: the single place where the experiment chooses its
/// renderer, so that moving `quality` onto the hypercube machine is a
/// change of this function's body alone. Fails as `render::render_host`
/// does, only if the OS refuses a thread.
pub fn render_point(
    scene: &Scene,
    width: u32,
    height: u32,
    threads: usize,
    knobs: &Knobs,
    progress: &(dyn Fn(u32) + Sync),
) -> Result<PointRender> {
    let opts = RenderOptions {
        width,
        height,
        spp: knobs.spp,
        threads,
    };
    let r = render::render_host(
        scene,
        &opts,
        knobs.adaptive,
        Accel::Cells,
        CellOptions::default(),
        progress,
    )?;
    Ok(PointRender {
        film: r.film,
        stats: r.stats,
        refined_pixels: r.aa.refined_pixels,
        samples: r.aa.samples,
        virtual_seconds: None,
    })
}

/// Renders the reference: Roth's brute force (the oracle) at `spp`
/// stratified samples per pixel and the scene's own `max_depth`. Fails as
/// `render_point` does.
pub fn render_reference(
    scene: &Scene,
    width: u32,
    height: u32,
    threads: usize,
    spp: u32,
    progress: &(dyn Fn(u32) + Sync),
) -> Result<Film> {
    let opts = RenderOptions {
        width,
        height,
        spp,
        threads,
    };
    render::render_host(
        scene,
        &opts,
        None,
        Accel::Roth,
        CellOptions::default(),
        progress,
    )
    .map(|r| r.film)
}

/// The sweep's bounds.
#[derive(Clone, Copy, Debug)]
pub struct SweepOptions {
    pub width: u32,
    pub height: u32,
    pub threads: usize,
    /// The largest samples per pixel of the `spp` sweep (1, 2, 4, ... up to it).
    pub max_spp: u32,
}

/// The adaptive thresholds swept, from coarse to fine; refined pixels get
/// `ADAPTIVE_EXTRA_SPP` samples on top of one.
pub const ADAPTIVE_THRESHOLDS: [f64; 4] = [0.2, 0.1, 0.05, 0.02];
pub const ADAPTIVE_EXTRA_SPP: u32 = 16;
/// Recursion limits swept (those below the scene's own), at `DEPTH_SPP`.
pub const SWEPT_DEPTHS: [u32; 3] = [0, 1, 2];
pub const DEPTH_SPP: u32 = 4;

/// The points of the sweep, in the order they are rendered.
pub fn knobs(scene_depth: u32, max_spp: u32) -> Vec<Knobs> {
    let mut v = Vec::new();
    let mut spp = 1;
    while spp <= max_spp.max(1) {
        v.push(Knobs {
            spp,
            adaptive: None,
            max_depth: scene_depth,
        });
        spp *= 2;
    }
    for threshold in ADAPTIVE_THRESHOLDS {
        v.push(Knobs {
            spp: 1,
            adaptive: Some(Adaptive {
                threshold,
                extra_spp: ADAPTIVE_EXTRA_SPP,
            }),
            max_depth: scene_depth,
        });
    }
    for d in SWEPT_DEPTHS.into_iter().filter(|&d| d < scene_depth) {
        v.push(Knobs {
            spp: DEPTH_SPP.min(max_spp.max(1)),
            adaptive: None,
            max_depth: d,
        });
    }
    v
}

/// Work units of a render of `rows` rows at `spp` (for a progress bar).
pub fn work_units(rows: u32, spp: u32) -> u64 {
    rows as u64 * spp.max(1) as u64
}

/// Renders every point of `knobs` and measures it against `reference`;
/// `progress` is told work units (`work_units`) as rows finish. Stops at
/// the first point that fails (`render_point`).
pub fn sweep(
    scene: &Scene,
    reference: &DisplayImage,
    opts: &SweepOptions,
    knobs: &[Knobs],
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<Point>> {
    let mut points = knobs
        .iter()
        .map(|k| {
            let mut s = scene.clone();
            s.max_depth = k.max_depth;
            let units = |rows: u32| progress(work_units(rows, k.spp));
            let r = render_point(&s, opts.width, opts.height, opts.threads, k, &units)?;
            let display = reference.comparable(&r.film.to_linear());
            Ok(Point {
                knobs: *k,
                family: k.family(scene.max_depth),
                dimension: None,
                wall_seconds: r.stats.wall_seconds,
                virtual_seconds: r.virtual_seconds,
                cpu_seconds: None,
                metrics: compare(&display, &reference.pixels),
                samples: r.samples,
                pixels: opts.width as u64 * opts.height as u64,
                refined_pixels: r.refined_pixels,
                rays: r.stats.rays.total(),
                pareto: false,
            })
        })
        .collect::<Result<Vec<Point>>>()?;
    report::quality::mark_pareto(&mut points);
    Ok(points)
}

/// The points the model's error is measured on: one and four samples per
/// pixel (one pass each, four times the work apart) and adaptive sampling
/// at threshold 0.1 (two passes), of those `knobs` holds. A subset, so
/// that measuring the model adds about a tenth to the sweep's time.
pub fn model_knobs(knobs: &[Knobs], scene_depth: u32) -> Vec<Knobs> {
    knobs
        .iter()
        .filter(|k| match k.family(scene_depth) {
            "spp" => k.spp == 1 || k.spp == 4,
            "adaptive" => k.adaptive.is_some_and(|a| a.threshold == 0.1),
            _ => false,
        })
        .copied()
        .collect()
}

/// Renders each of `knobs` on the machine of `calibration`'s topology, for
/// each of `dimensions`, and measures it like a point: the runs of the
/// model's error. `progress` is told each run's work units when it ends.
pub fn model_runs(
    scene: &Scene,
    reference: &DisplayImage,
    opts: &SweepOptions,
    knobs: &[Knobs],
    calibration: &Calibration,
    dimensions: &[u32],
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<Point>> {
    let mut points = Vec::new();
    for &d in dimensions {
        let topo = calibration.topology(d);
        for k in knobs {
            let mut s = scene.clone();
            s.max_depth = k.max_depth;
            let mopts = MachineOptions::new(opts.width, opts.height, k.spp);
            let (film, ms, _, aa) =
                machine::render_adaptive(&s, &topo, &mopts, k.adaptive, &|_| {})?;
            progress(aa.passes as u64 * work_units(opts.height, k.spp));
            let display = reference.comparable(&film.to_linear());
            points.push(Point {
                knobs: *k,
                family: k.family(scene.max_depth),
                dimension: Some(d),
                wall_seconds: ms.run_seconds,
                virtual_seconds: Some(ms.virtual_seconds),
                // Over the same span: the build and the pre-pass run on
                // several threads, so their wall time is not their CPU time
                // (subtracted, it left "0.00 cores busy" on small renders).
                cpu_seconds: Some(ms.run_cpu_seconds),
                metrics: compare(&display, &reference.pixels),
                samples: aa.samples,
                pixels: opts.width as u64 * opts.height as u64,
                refined_pixels: aa.refined_pixels,
                rays: ms.rays.total(),
                pareto: false,
            });
        }
    }
    Ok(points)
}

/// A reference given as display values of a linear film (no 8-bit
/// rounding: the render is compared in full precision).
pub fn reference_of(film: &Film) -> DisplayImage {
    DisplayImage {
        width: film.width,
        height: film.rows,
        pixels: image_io::to_display(&film.to_linear()),
        eight_bit: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_knobs_cover_each_family_and_only_shallower_depths() {
        let k = knobs(2, 8);
        let fam = |f: &str| k.iter().filter(|x| x.family(2) == f).count();
        assert_eq!(fam("spp"), 4, "1, 2, 4, 8");
        assert_eq!(fam("adaptive"), ADAPTIVE_THRESHOLDS.len());
        assert_eq!(fam("depth"), 2, "0 and 1, below the scene's 2");
    }

    #[test]
    fn the_model_is_measured_on_one_and_four_spp_and_one_threshold() {
        let labels: Vec<String> = model_knobs(&knobs(5, 64), 5)
            .iter()
            .map(Knobs::label)
            .collect();
        assert_eq!(
            labels,
            [
                "spp 1, depth 5",
                "spp 4, depth 5",
                "spp 1 + 16 where > 0.1, depth 5"
            ]
        );
        // A sweep that stops below 4 spp measures what it has.
        assert_eq!(model_knobs(&knobs(5, 2), 5).len(), 2);
    }
}
