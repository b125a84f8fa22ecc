//! The command line of `CLI.md`: clap arguments, validated into jobs, run.
//! Owns option names and defaults, progress display and the summary lines;
//! the work itself is done by the library layers.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use crate::error::{Error, Result};
use crate::render::{self, Accel, RenderOptions, RenderStats};
use crate::report::{self, stats::num, ImageMetrics};
use crate::scene::{self, Scene};
use crate::trace::RayKind;

#[derive(Parser, Debug)]
#[command(name = "hypercast", version, about = "CSG ray tracing with Priol-Arnaldi-Bouatouch space subdivision on an emulated hypercube")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a scene to an image file.
    Render(RenderArgs),
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum AccelArg {
    /// The paper's space subdivision (default).
    Cells,
    /// Roth's brute force: every ray against the whole tree (the reference).
    Roth,
}

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Scene file: .ron, .json or .nff.
    pub scene: PathBuf,
    /// Output image: .png (default: the scene's stem + .png), .ppm or .exr (linear).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Image width in pixels (default: the scene camera's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Samples per pixel, stratified and deterministic.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    /// Reflection/refraction recursion limit (default: the scene's max_depth).
    #[arg(long)]
    pub max_depth: Option<u32>,
    /// Accelerator.
    #[arg(long, value_enum, default_value_t = AccelArg::Cells)]
    pub accel: AccelArg,
    /// Also report RMSE, PSNR and maximum error against this image.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Write statistics as JSON to this file.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Host threads for single-node work (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar and no summary.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(a) => run_render(a),
    }
}

/// A render, validated: nothing in it can be refused later for bad input.
struct RenderJob {
    scene_path: PathBuf,
    scene: Scene,
    output: PathBuf,
    opts: RenderOptions,
    accel: Accel,
    reference: Option<(PathBuf, Vec<[f32; 3]>)>,
    stats: Option<PathBuf>,
    quiet: bool,
}

fn default_output(scene: &Path) -> PathBuf {
    let stem = scene.file_stem().map(|s| s.to_os_string()).unwrap_or_else(|| "render".into());
    let mut p = PathBuf::from(stem);
    p.set_extension("png");
    p
}

fn check_writable_dir(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(Error::Usage(format!("{}: the folder {} does not exist", path.display(), dir.display())));
    }
    Ok(())
}

fn prepare_render(a: RenderArgs) -> Result<RenderJob> {
    let output = a.output.clone().unwrap_or_else(|| default_output(&a.scene));
    // Refuse a bad output before the (possibly long) render, not after.
    report::image_io::OutputFormat::for_path(&output)?;
    check_writable_dir(&output)?;
    if let Some(s) = &a.stats {
        check_writable_dir(s)?;
    }
    if a.spp == 0 || a.spp > 65536 {
        return Err(Error::Usage(format!("--spp must be in 1..=65536, got {}", a.spp)));
    }
    let (mut scene, warnings) = scene::load::load_scene_with_warnings(&a.scene)?;
    if !a.quiet {
        for w in warnings {
            eprintln!("hypercast: warning: {w}");
        }
    }
    let width = a.width.unwrap_or(scene.camera.width);
    let height = a.height.unwrap_or(scene.camera.height);
    scene::load::check_resolution(width, height).map_err(|m| Error::Usage(format!("--width/--height: {m}")))?;
    if let Some(d) = a.max_depth {
        if d > scene::MAX_DEPTH_LIMIT {
            return Err(Error::Usage(format!("--max-depth must be at most {}, got {d}", scene::MAX_DEPTH_LIMIT)));
        }
        scene.max_depth = d;
    }
    let reference = match &a.reference {
        None => None,
        Some(p) => {
            let (w, h, px) = report::read_display_image(p)?;
            if (w, h) != (width, height) {
                return Err(Error::Usage(format!(
                    "{}: reference is {w}x{h}, the render is {width}x{height}",
                    p.display()
                )));
            }
            Some((p.clone(), px))
        }
    };
    let threads = a.threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    if threads == 0 {
        return Err(Error::Usage("--threads must be at least 1".into()));
    }
    Ok(RenderJob {
        scene_path: a.scene,
        scene,
        output,
        opts: RenderOptions { width, height, spp: a.spp, threads },
        accel: match a.accel {
            AccelArg::Cells => Accel::Cells,
            AccelArg::Roth => Accel::Roth,
        },
        reference,
        stats: a.stats,
        quiet: a.quiet,
    })
}

/// A progress bar over `total` units on a terminal, hidden otherwise.
pub fn progress_bar(total: u64, quiet: bool, what: &str) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template("{prefix} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}

fn run_render(a: RenderArgs) -> Result<()> {
    let job = prepare_render(a)?;
    let pb = progress_bar(job.opts.height as u64, job.quiet, "render");
    let progress = |rows: u32| pb.inc(rows as u64);
    let (film, stats) = match job.accel {
        Accel::Roth => render::render_roth(&job.scene, &job.opts, &progress),
        Accel::Cells => {
            let (film, stats, _cs) = render::render_cells(&job.scene, &job.opts, Default::default(), &progress);
            (film, stats)
        }
    };
    pb.finish_and_clear();
    let linear = film.to_linear();
    report::write_image(&job.output, job.opts.width, job.opts.height, &linear)?;
    let metrics = job
        .reference
        .as_ref()
        .map(|(_, r)| report::compare(&report::image_io::to_display(&linear), r));
    if let Some(p) = &job.stats {
        report::stats::write_json(p, &stats_json(&job, &stats, metrics.as_ref()))?;
    }
    if !job.quiet {
        eprintln!(
            "hypercast: wrote {} ({}x{}, {} spp, {}) in {:.3} s wall; {} rays, {} intersection tests",
            job.output.display(),
            job.opts.width,
            job.opts.height,
            job.opts.spp,
            job.accel.name(),
            stats.wall_seconds,
            stats.rays.total(),
            stats.counters.intersection_tests
        );
    }
    if let Some(m) = metrics {
        // Error beside run time, always printed when asked for.
        println!(
            "rmse {:.6}  psnr {:.2} dB  max {:.6}  wall {:.3} s",
            m.rmse, m.psnr, m.max_error, stats.wall_seconds
        );
    }
    Ok(())
}

fn stats_json(job: &RenderJob, s: &RenderStats, m: Option<&ImageMetrics>) -> serde_json::Value {
    let rays: serde_json::Map<String, serde_json::Value> = RayKind::ALL.iter().map(|k| (k.name().to_string(), json!(s.rays.get(*k)))).collect();
    json!({
        "scene": job.scene_path.display().to_string(),
        "width": job.opts.width,
        "height": job.opts.height,
        "spp": job.opts.spp,
        "accel": job.accel.name(),
        "dimension": 0,
        "nodes": 1,
        "threads": job.opts.threads,
        "wall_seconds": s.wall_seconds,
        "virtual_seconds": null,
        "rays": rays,
        "intersection_tests": s.counters.intersection_tests,
        "mailbox_hits": s.counters.mailbox_hits,
        "pixels_traced": s.pixels_traced,
        "pixels_background": s.pixels_background,
        "primitives": job.scene.primitives.len(),
        "rmse": m.map(|m| num(m.rmse)),
        "psnr": m.map(|m| num(m.psnr)),
        "max_error": m.map(|m| num(m.max_error)),
        "reference": job.reference.as_ref().map(|(p, _)| p.display().to_string()),
    })
}
