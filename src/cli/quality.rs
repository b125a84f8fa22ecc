//! `hypercast quality SCENE [--out DIR]` (`CLI.md`): validates its options,
//! gets a reference (rendered, or `--reference`), runs the sweep of
//! `crate::quality`, calibrates a topology on this host and measures the
//! model's error with it on the dimensions this host has cores for, and
//! writes `DIR/quality.csv`, `DIR/quality.png` and the printed tables.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::machine::calibrate;
use crate::quality::{self, SweepOptions};
use crate::report::{self, quality as rq};

use super::{host_threads, load_for_run, progress_bar, read_reference};

#[derive(clap::Args, Debug)]
pub struct QualityArgs {
    /// Scene file: .ron, .json or .nff.
    pub scene: PathBuf,
    /// Folder for quality.csv, quality.png and reference.exr (created if missing).
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
    /// Reference image to measure against, instead of rendering one.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Samples per pixel of the rendered reference (Roth's brute force).
    #[arg(long, default_value_t = 256)]
    pub reference_spp: u32,
    /// Largest samples per pixel of the sweep (1, 2, 4, ... up to it).
    #[arg(long, default_value_t = 64)]
    pub max_spp: u32,
    /// Image width (default: the scene camera's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Host threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar and no table (the files are still written).
    #[arg(short, long)]
    pub quiet: bool,
}

fn check_spp(name: &str, n: u32) -> Result<()> {
    if n == 0 || n > 65536 {
        return Err(Error::Usage(format!(
            "{name} must be in 1..=65536, got {n}"
        )));
    }
    Ok(())
}

/// Makes the output folder if missing.
fn out_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::Write {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })
}

pub fn run(a: QualityArgs) -> Result<()> {
    check_spp("--reference-spp", a.reference_spp)?;
    check_spp("--max-spp", a.max_spp)?;
    if a.out.exists() && !a.out.is_dir() {
        return Err(Error::Usage(format!(
            "--out {}: not a folder",
            a.out.display()
        )));
    }
    let threads = host_threads(a.threads)?;
    let (scene, width, height) = load_for_run(&a.scene, a.width, a.height, a.quiet)?;
    let given = match &a.reference {
        None => None,
        Some(p) => Some(read_reference(p, width, height)?),
    };
    // Everything the user gave is valid: only now touch the file system.
    out_dir(&a.out)?;
    let knobs = quality::knobs(scene.max_depth, a.max_spp);
    let model_knobs = quality::model_knobs(&knobs, scene.max_depth);
    // The model's error needs a core per node: d with 2^d <= cores.
    let cores = crate::trace::host_cores();
    let dims = calibrate::host_dimensions(cores);
    let units = |ks: &[rq::Knobs]| -> u64 {
        ks.iter()
            .map(|k| {
                let passes = if k.adaptive.is_some() { 2 } else { 1 };
                passes * quality::work_units(height, k.spp)
            })
            .sum()
    };
    let mut total = units(&knobs) + dims.len() as u64 * units(&model_knobs);
    if given.is_none() {
        total += quality::work_units(height, a.reference_spp);
    }
    let pb = progress_bar(total, a.quiet, "quality");
    let reference = match given {
        Some(img) => img,
        None => {
            pb.set_prefix("reference");
            let units = |rows: u32| pb.inc(quality::work_units(rows, a.reference_spp));
            let film =
                quality::render_reference(&scene, width, height, threads, a.reference_spp, &units)?;
            // Kept, so that a later sweep can reuse it with --reference.
            report::write_image(
                &a.out.join("reference.exr"),
                width,
                height,
                &film.to_linear(),
            )?;
            quality::reference_of(&film)
        }
    };
    pb.set_prefix("sweep");
    let opts = SweepOptions {
        width,
        height,
        threads,
        max_spp: a.max_spp,
    };
    let units = |u: u64| pb.inc(u);
    let mut points = quality::sweep(&scene, &reference, &opts, &knobs, &units)?;
    // Calibrated after the sweep and before the runs it serves, on a host
    // busy with nothing else of ours.
    pb.set_prefix("model");
    let calibration = calibrate::calibrate()?;
    points.extend(quality::model_runs(
        &scene,
        &reference,
        &opts,
        &model_knobs,
        &calibration,
        &dims,
        &units,
    )?);
    pb.finish_and_clear();
    let name = a
        .scene
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let reference_name = match &a.reference {
        Some(p) => p.display().to_string(),
        None => format!("Roth, {} spp", a.reference_spp),
    };
    let csv = a.out.join("quality.csv");
    let png = a.out.join("quality.png");
    rq::write_csv(&csv, &points)?;
    rq::write_plot(
        &png,
        &format!("{name} {width}x{height}: error against time (reference: {reference_name})"),
        &points,
    )?;
    if !a.quiet {
        out!("{}", rq::table(&points))?;
        outln!(
            "pareto front: {} of {} points",
            points.iter().filter(|p| p.pareto).count(),
            points.len()
        )?;
        outln!(
            "\nmodel error: virtual time on a {} topology against the machine's wall time, \
             d = {} ({cores} cores)",
            calibrate::HOST_TOPOLOGY,
            dims.iter()
                .map(u32::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        )?;
        outln!("calibration: {}", calibration.describe())?;
        out!("{}", rq::model_table(&points))?;
        outln!(
            "model error (virtual against wall time): {}",
            rq::model_summary(&points)
        )?;
        eprintln!("hypercast: wrote {} and {}", csv.display(), png.display());
    }
    Ok(())
}
