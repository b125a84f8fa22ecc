//! The command line of `CLI.md`: clap arguments, validated into jobs, run.
//! Owns option names and defaults, progress display and the summary lines;
//! the work itself is done by the library layers.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use crate::cells::{CellOptions, CellStructure, SegmentChoice};
use crate::error::{Error, Result};
use crate::render::{self, Accel, RenderOptions, RenderStats};
use crate::report::{self, ImageMetrics, stats::num};
use crate::scene::{self, Scene};
use crate::trace::RayKind;

#[derive(Parser, Debug)]
#[command(
    name = "hypercast",
    version,
    about = "CSG ray tracing with Priol-Arnaldi-Bouatouch space subdivision on an emulated hypercube"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a scene to an image file.
    Render(RenderArgs),
    /// Show the paper's subdivision of a scene: counts, memory, and an overlay picture.
    Inspect(InspectArgs),
    /// Write a generated scene (sphereflake, rings, jagged ball, random CSG) as RON, JSON or NFF.
    Gen(crate::cmd::generate::GenArgs),
    /// Convert a scene to POV-Ray 3.7 (.pov), RON, JSON or NFF.
    Convert(crate::cmd::convert::ConvertArgs),
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BspArg {
    /// Fewest splits among a fixed sample of 16 candidate segments (default: near n log n).
    Sampled,
    /// The paper's choice: the segment splitting the fewest others (quadratic).
    FewestSplits,
}

impl From<BspArg> for SegmentChoice {
    fn from(b: BspArg) -> Self {
        match b {
            BspArg::Sampled => SegmentChoice::Sampled,
            BspArg::FewestSplits => SegmentChoice::FewestSplits,
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct InspectArgs {
    /// Scene file: .ron, .json or .nff.
    pub scene: PathBuf,
    /// Draw the super cells over a render into this PNG.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Image width (default: the scene camera's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// How the screen-plane BSP chooses its splitting segments.
    #[arg(long, value_enum, default_value_t = BspArg::Sampled)]
    pub bsp: BspArg,
    /// Also write the counts as JSON to this file.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Host threads for the overlay's render.
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
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
    /// How the screen-plane BSP chooses its splitting segments (cells only).
    #[arg(long, value_enum, default_value_t = BspArg::Sampled)]
    pub bsp: BspArg,
    /// No progress bar and no summary.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(a) => run_render(a),
        Command::Inspect(a) => run_inspect(a),
        Command::Gen(a) => crate::cmd::generate::run(a),
        Command::Convert(a) => crate::cmd::convert::run(a),
    }
}

/// A render, validated: nothing in it can be refused later for bad input.
struct RenderJob {
    scene_path: PathBuf,
    scene: Scene,
    output: PathBuf,
    opts: RenderOptions,
    accel: Accel,
    reference: Option<(PathBuf, report::DisplayImage)>,
    stats: Option<PathBuf>,
    bsp: SegmentChoice,
    quiet: bool,
}

fn default_output(scene: &Path) -> PathBuf {
    let stem = scene
        .file_stem()
        .map(|s| s.to_os_string())
        .unwrap_or_else(|| "render".into());
    let mut p = PathBuf::from(stem);
    p.set_extension("png");
    p
}

pub(crate) fn check_writable_dir(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(Error::Usage(format!(
            "{}: the folder {} does not exist",
            path.display(),
            dir.display()
        )));
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
        return Err(Error::Usage(format!(
            "--spp must be in 1..=65536, got {}",
            a.spp
        )));
    }
    let (mut scene, width, height) = load_for_run(&a.scene, a.width, a.height, a.quiet)?;
    if let Some(d) = a.max_depth {
        if d > scene::MAX_DEPTH_LIMIT {
            return Err(Error::Usage(format!(
                "--max-depth must be at most {}, got {d}",
                scene::MAX_DEPTH_LIMIT
            )));
        }
        scene.max_depth = d;
    }
    let reference = match &a.reference {
        None => None,
        Some(p) => {
            let img = report::read_display_image(p)?;
            if (img.width, img.height) != (width, height) {
                return Err(Error::Usage(format!(
                    "{}: reference is {}x{}, the render is {width}x{height}",
                    p.display(),
                    img.width,
                    img.height
                )));
            }
            Some((p.clone(), img))
        }
    };
    let threads = host_threads(a.threads)?;
    Ok(RenderJob {
        scene_path: a.scene,
        scene,
        output,
        opts: RenderOptions {
            width,
            height,
            spp: a.spp,
            threads,
        },
        accel: match a.accel {
            AccelArg::Cells => Accel::Cells,
            AccelArg::Roth => Accel::Roth,
        },
        reference,
        stats: a.stats,
        bsp: a.bsp.into(),
        quiet: a.quiet,
    })
}

fn host_threads(t: Option<usize>) -> Result<usize> {
    let threads = t.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    if threads == 0 {
        return Err(Error::Usage("--threads must be at least 1".into()));
    }
    Ok(threads)
}

/// Loads a scene, prints its warnings unless quiet, and applies a
/// resolution override.
fn load_for_run(
    path: &Path,
    width: Option<u32>,
    height: Option<u32>,
    quiet: bool,
) -> Result<(Scene, u32, u32)> {
    let (scene, warnings) = scene::load::load_scene_with_warnings(path)?;
    if !quiet {
        for w in warnings {
            eprintln!("hypercast: warning: {w}");
        }
    }
    let width = width.unwrap_or(scene.camera.width);
    let height = height.unwrap_or(scene.camera.height);
    scene::load::check_resolution(width, height)
        .map_err(|m| Error::Usage(format!("--width/--height: {m}")))?;
    Ok((scene, width, height))
}

/// A progress bar over `total` units on a terminal, hidden otherwise.
pub fn progress_bar(total: u64, quiet: bool, what: &str) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
        )
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
    let (film, stats, cs) = match job.accel {
        Accel::Roth => {
            let (film, stats) = render::render_roth(&job.scene, &job.opts, &progress);
            (film, stats, None)
        }
        Accel::Cells => {
            let (film, stats, cs) = render::render_cells(
                &job.scene,
                &job.opts,
                CellOptions { choice: job.bsp },
                &progress,
            );
            (film, stats, Some(cs))
        }
    };
    pb.finish_and_clear();
    let linear = film.to_linear();
    report::write_image(&job.output, job.opts.width, job.opts.height, &linear)?;
    let metrics = job
        .reference
        .as_ref()
        .map(|(_, r)| report::compare(&r.comparable(&linear), &r.pixels));
    if let Some(p) = &job.stats {
        let mut v = stats_json(&job, &stats, metrics.as_ref());
        if let Some(cs) = &cs {
            report::stats::extend(&mut v, structure_json(cs));
        }
        report::stats::write_json(p, &v)?;
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
    let rays: serde_json::Map<String, serde_json::Value> = RayKind::ALL
        .iter()
        .map(|k| (k.name().to_string(), json!(s.rays.get(*k))))
        .collect();
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
        "cells_visited": s.counters.cells_visited,
        "subtree_evaluations": s.counters.subtree_evaluations,
        "pixels_traced": s.pixels_traced,
        "pixels_background": s.pixels_background,
        "primitives": job.scene.primitives.len(),
        "rmse": m.map(|m| num(m.rmse)),
        "psnr": m.map(|m| num(m.psnr)),
        "max_error": m.map(|m| num(m.max_error)),
        "reference": job.reference.as_ref().map(|(p, _)| p.display().to_string()),
    })
}

/// The keys describing a cell structure (`--stats`, `inspect --stats`).
fn structure_json(cs: &CellStructure) -> Vec<(&'static str, serde_json::Value)> {
    let s = &cs.stats;
    vec![
        ("cells", json!(s.cells)),
        ("super_cells", json!(s.super_cells)),
        ("empty_cells", json!(s.empty_cells)),
        (
            "primitives_per_cell",
            json!({"mean": s.prims_per_cell_mean, "max": s.prims_per_cell_max}),
        ),
        (
            "subtree_nodes_per_cell",
            json!({"mean": s.subtree_nodes_mean, "max": s.subtree_nodes_max, "whole_tree": s.tree_nodes}),
        ),
        ("distinct_subtrees", json!(s.distinct_subtrees)),
        ("culled_primitives", json!(s.culled_primitives)),
        ("bsp_splits", json!(s.bsp_splits)),
        ("build_seconds", json!(s.build_seconds)),
        ("structure_bytes", json!(s.bytes)),
    ]
}

fn run_inspect(a: InspectArgs) -> Result<()> {
    if let Some(o) = &a.overlay {
        report::image_io::OutputFormat::for_path(o)?;
        check_writable_dir(o)?;
    }
    if let Some(p) = &a.stats {
        check_writable_dir(p)?;
    }
    let threads = host_threads(a.threads)?;
    let (scene, width, height) = load_for_run(&a.scene, a.width, a.height, a.quiet)?;
    let cs = CellStructure::build(
        &scene,
        width,
        height,
        CellOptions {
            choice: a.bsp.into(),
        },
    );
    let s = &cs.stats;
    let front = cs.region(crate::cells::Region::Front);
    let back = cs.region(crate::cells::Region::Back);
    println!("scene               {}", a.scene.display());
    println!(
        "primitives          {} ({} culled: empty minimal box)",
        scene.primitives.len(),
        s.culled_primitives
    );
    println!("csg tree nodes      {}", s.tree_nodes);
    println!(
        "super cells         {} (front {}, behind the eye plane {})",
        s.super_cells,
        front.partition.leaves.len(),
        back.partition.leaves.len()
    );
    println!("cells               {} ({} empty)", s.cells, s.empty_cells);
    println!(
        "primitives per cell mean {:.2}, max {}",
        s.prims_per_cell_mean, s.prims_per_cell_max
    );
    println!(
        "subtree nodes/cell  mean {:.2}, max {} (whole tree {})",
        s.subtree_nodes_mean, s.subtree_nodes_max, s.tree_nodes
    );
    println!("distinct subtrees   {}", s.distinct_subtrees);
    println!("bsp segment splits  {}", s.bsp_splits);
    println!(
        "structure bytes     {} ({:.2} MiB)",
        s.bytes,
        s.bytes as f64 / (1024.0 * 1024.0)
    );
    println!("build time          {:.4} s", s.build_seconds);
    if let Some(p) = &a.stats {
        let mut v = json!({"scene": a.scene.display().to_string(), "width": width, "height": height, "primitives": scene.primitives.len()});
        report::stats::extend(&mut v, structure_json(&cs));
        report::stats::write_json(p, &v)?;
    }
    if let Some(o) = &a.overlay {
        let opts = RenderOptions {
            width,
            height,
            spp: 1,
            threads,
        };
        let pb = progress_bar(height as u64, a.quiet, "overlay");
        let progress = |rows: u32| pb.inc(rows as u64);
        let (film, _) = render::render_with(
            &scene,
            &opts,
            || crate::cells::CellTracer::new(&cs, &scene),
            |job| crate::cells::CellTracer::primary_is_background(&cs, &job.ray),
            &progress,
        );
        pb.finish_and_clear();
        let mut img = film.to_linear();
        let cam = crate::trace::CameraFrame::new(&scene, width, height);
        report::overlay::draw_super_cells(&mut img, &cam, &cs);
        report::write_image(o, width, height, &img)?;
        if !a.quiet {
            eprintln!("hypercast: wrote {}", o.display());
        }
    }
    Ok(())
}
