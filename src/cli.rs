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
use crate::machine::{self, MachineOptions, MachineStats, Mapping, Topology};
use crate::render::{self, AaSummary, Accel, Adaptive, RenderOptions, RenderStats};
use crate::report::{self, ImageMetrics, image_io::folder_of, stats::num};
use crate::scene::{self, Scene};
use crate::trace::RayKind;

/// Prints to standard output, as `print!` does, through `write_stdout`.
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::cli::write_stdout(format_args!($($arg)*))
    };
}

/// Prints a line to standard output, as `println!` does, through
/// `write_stdout`.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::cli::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

mod quality;

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
    /// Render once per hypercube dimension: speedup, efficiency and its factors, messages, imbalance.
    Scale(ScaleArgs),
    /// Error against run time: sweep samples per pixel, adaptive threshold and depth.
    Quality(quality::QualityArgs),
    /// Write a generated scene (sphereflake, rings, jagged ball, random CSG) as RON, JSON or NFF.
    Gen(crate::cmd::generate::GenArgs),
    /// Convert a scene to POV-Ray 3.7 (.pov), RON, JSON or NFF.
    Convert(crate::cmd::convert::ConvertArgs),
}

/// The modelled machine's options, shared by `render`, `inspect` and `scale`.
#[derive(clap::Args, Debug, Clone)]
pub struct MachineArgs {
    /// Topology file of the modelled machine (default: the built-in iPSC-D5, 32 nodes of 4.5 MiB).
    #[arg(long)]
    pub topology: Option<PathBuf>,
    /// Hypercube dimension, 2^D nodes (0: one node); overrides the topology's.
    /// One node per host core renders fastest (`--dim 1` on two cores).
    #[arg(long)]
    pub dim: Option<u32>,
    /// Memory per node, e.g. 4.5MiB, 512KiB, 2GiB or bytes; overrides the topology's.
    #[arg(long, value_parser = parse_size_arg)]
    pub node_memory: Option<u64>,
    /// How super cells are mapped to nodes: balanced by a cost pre-pass, or equal image areas.
    #[arg(long, value_enum, default_value_t = Mapping::Balanced)]
    pub mapping: Mapping,
    /// Whether a node holds copies of other nodes' super cells in the memory its share leaves
    /// free, so that rays reaching them need no message (none: the paper's plan alone; whole:
    /// every node holds everything).
    #[arg(long, value_enum, default_value_t = machine::Replicas::Auto)]
    pub replicas: machine::Replicas,
    /// Envelopes (a slice's messages for one link) each link holds before its sender must wait (1 to 1024).
    #[arg(long, default_value_t = machine::DEFAULT_CAPACITY)]
    pub link_capacity: usize,
    /// Leave out the shadow cache (each node's last blocker per light, tried before a shadow ray walks).
    #[arg(long)]
    pub no_shadow_cache: bool,
    /// Test only: node N fails after K paths (N:K).
    #[arg(long, hide = true)]
    pub inject_fault: Option<String>,
}

fn parse_size_arg(s: &str) -> std::result::Result<u64, String> {
    machine::parse_size(s)
}

impl MachineArgs {
    /// The topology with the overrides applied.
    pub fn topology(&self) -> Result<Topology> {
        let base = match &self.topology {
            Some(p) => Topology::load(p)?,
            None => Topology::ipsc_d5(),
        };
        base.with_overrides(self.dim, self.node_memory)
    }

    /// Machine options for a render of `width`×`height` at `spp`.
    pub fn options(
        &self,
        width: u32,
        height: u32,
        spp: u32,
        bsp: SegmentChoice,
    ) -> Result<MachineOptions> {
        if self.link_capacity == 0 || self.link_capacity > machine::MAX_CAPACITY {
            return Err(Error::Usage(format!(
                "--link-capacity must be in 1..={}, got {}",
                machine::MAX_CAPACITY,
                self.link_capacity
            )));
        }
        let mut o = MachineOptions::new(width, height, spp);
        o.cells = CellOptions {
            choice: bsp,
            no_shadow_cache: self.no_shadow_cache,
            ..Default::default()
        };
        o.mapping = self.mapping;
        o.replicas = self.replicas;
        o.capacity = self.link_capacity;
        o.fail = match &self.inject_fault {
            None => None,
            Some(f) => {
                let bad =
                    || Error::Usage(format!("--inject-fault: expected NODE:PATHS, got {f:?}"));
                let (a, b) = f.split_once(':').ok_or_else(bad)?;
                Some((a.parse().map_err(|_| bad())?, b.parse().map_err(|_| bad())?))
            }
        };
        Ok(o)
    }
}

#[derive(clap::Args, Debug)]
pub struct ScaleArgs {
    /// Scene file: .ron, .json or .nff.
    pub scene: PathBuf,
    /// Dimensions to run, each once, as a range A..B (inclusive) or a list
    /// 0,2,5; run smallest first, and speedups are against the smallest.
    #[arg(long, default_value = "0..5")]
    pub dims: String,
    /// Rounds of runs, each round every dimension once; times are medians,
    /// speedups the median of each round's ratio.
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// Folder for scaling.csv and scaling.png (created if missing).
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
    /// Image width (default: the scene camera's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Samples per pixel.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    #[command(flatten)]
    pub machine: MachineArgs,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
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
    #[command(flatten)]
    pub machine: MachineArgs,
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
    /// Adaptive antialiasing: more samples where a pixel differs from a
    /// neighbour by more than T (0 < T <= 1, linear radiance).
    #[arg(long, value_name = "T")]
    pub aa_threshold: Option<f64>,
    /// Samples added to each pixel that --aa-threshold refines.
    #[arg(
        long,
        value_name = "N",
        requires = "aa_threshold",
        default_value_t = 16
    )]
    pub aa_spp: u32,
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
    /// Host threads for --accel roth (default: all cores); the machine runs one thread per node.
    #[arg(long)]
    pub threads: Option<usize>,
    /// How the screen-plane BSP chooses its splitting segments (cells only).
    #[arg(long, value_enum, default_value_t = BspArg::Sampled)]
    pub bsp: BspArg,
    #[command(flatten)]
    pub machine: MachineArgs,
    /// No progress bar and no summary.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(a) => run_render(a),
        Command::Inspect(a) => run_inspect(a),
        Command::Scale(a) => run_scale(a),
        Command::Quality(a) => quality::run(a),
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
    adaptive: Option<Adaptive>,
    accel: Accel,
    reference: Option<(PathBuf, report::DisplayImage)>,
    stats: Option<PathBuf>,
    /// The modelled machine, for `--accel cells`.
    machine: Option<(Topology, MachineOptions)>,
    /// Whether the user chose the machine's size (`--dim`, `--topology`),
    /// rather than taking the default's 32 nodes (`cores_hint`).
    machine_chosen: bool,
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
    let target = report::image_io::write_target(path);
    if target.is_symlink() {
        // Still a link after as many as the kernel follows: a loop.
        return Err(Error::Usage(format!(
            "{}: too many levels of symbolic links",
            path.display()
        )));
    }
    let dir = folder_of(&target);
    if !dir.is_dir() {
        return Err(Error::Usage(format!(
            "{}: the folder {} does not exist",
            path.display(),
            dir.display()
        )));
    }
    if path.is_dir() {
        return Err(Error::Usage(format!(
            "{}: is a folder; give a file name",
            path.display()
        )));
    }
    Ok(())
}

/// Refuses a run whose outputs would replace one of its inputs, or one
/// another (`convert s.ron -o s.ron` would rewrite the scene without its
/// comments; `--stats` on the scene would replace it; two outputs on one
/// path would lose the first), before anything is read or rendered.
/// Paths name the same file if they resolve to the same folder and name,
/// or, for files that exist, to the same file (links included).
pub(crate) fn check_apart(inputs: &[(&str, &Path)], outputs: &[(&str, &Path)]) -> Result<()> {
    for (i, &(what, out)) in outputs.iter().enumerate() {
        let earlier = outputs[..i].iter();
        for &(other, path) in inputs.iter().chain(earlier) {
            if same_file(out, path) {
                return Err(Error::Usage(format!(
                    "{}: the {what} would replace the {other} {}; choose another name",
                    out.display(),
                    path.display()
                )));
            }
        }
    }
    Ok(())
}

/// Whether two paths name one file (see `check_apart`).
fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
        return x.dev() == y.dev() && x.ino() == y.ino();
    }
    // One does not exist yet: compare where each would be.
    let place = |p: &Path| -> Option<PathBuf> {
        let p = report::image_io::write_target(p);
        Some(folder_of(&p).canonicalize().ok()?.join(p.file_name()?))
    };
    matches!((place(a), place(b)), (Some(x), Some(y)) if x == y)
}

fn prepare_render(a: RenderArgs) -> Result<RenderJob> {
    let output = a.output.clone().unwrap_or_else(|| default_output(&a.scene));
    // Refuse a bad output before the (possibly long) render, not after.
    report::image_io::OutputFormat::for_path(&output)?;
    check_writable_dir(&output)?;
    if let Some(s) = &a.stats {
        check_writable_dir(s)?;
    }
    let mut inputs = vec![("scene", a.scene.as_path())];
    inputs.extend(a.reference.as_deref().map(|r| ("reference", r)));
    let mut outputs = vec![("image", output.as_path())];
    outputs.extend(a.stats.as_deref().map(|s| ("statistics", s)));
    check_apart(&inputs, &outputs)?;
    if a.spp == 0 || a.spp > 65536 {
        return Err(Error::Usage(format!(
            "--spp must be in 1..=65536, got {}",
            a.spp
        )));
    }
    let adaptive = match a.aa_threshold {
        None => None,
        Some(t) => Some(adaptive_option(t, a.aa_spp)?),
    };
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
        Some(p) => Some((p.clone(), read_reference(p, width, height)?)),
    };
    let threads = host_threads(a.threads)?;
    let machine = match a.accel {
        AccelArg::Roth => None,
        AccelArg::Cells => Some((
            a.machine.topology()?,
            a.machine.options(width, height, a.spp, a.bsp.into())?,
        )),
    };
    Ok(RenderJob {
        machine,
        machine_chosen: a.machine.dim.is_some() || a.machine.topology.is_some(),
        scene_path: a.scene,
        scene,
        output,
        opts: RenderOptions {
            width,
            height,
            spp: a.spp,
            threads,
        },
        adaptive,
        accel: match a.accel {
            AccelArg::Cells => Accel::Cells,
            AccelArg::Roth => Accel::Roth,
        },
        reference,
        stats: a.stats,
        quiet: a.quiet,
    })
}

/// A `--reference` image, refused unless it is `width` x `height`.
fn read_reference(path: &Path, width: u32, height: u32) -> Result<report::DisplayImage> {
    let img = report::read_display_image(path)?;
    if (img.width, img.height) != (width, height) {
        return Err(Error::Usage(format!(
            "{}: reference is {}x{}, the render is {width}x{height}",
            path.display(),
            img.width,
            img.height
        )));
    }
    Ok(img)
}

/// `--aa-threshold` and `--aa-spp`, checked.
fn adaptive_option(threshold: f64, extra_spp: u32) -> Result<Adaptive> {
    if !(threshold > 0.0 && threshold <= 1.0) {
        return Err(Error::Usage(format!(
            "--aa-threshold must be in (0, 1], got {threshold}"
        )));
    }
    if extra_spp == 0 || extra_spp > 65536 {
        return Err(Error::Usage(format!(
            "--aa-spp must be in 1..=65536, got {extra_spp}"
        )));
    }
    Ok(Adaptive {
        threshold,
        extra_spp,
    })
}

fn host_threads(t: Option<usize>) -> Result<usize> {
    let threads = t.unwrap_or_else(crate::trace::host_cores);
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

/// Whether progress shows: on a terminal, unless `quiet`.
fn shows_progress(quiet: bool) -> bool {
    !quiet && std::io::stderr().is_terminal()
}

/// A progress bar over `total` units on a terminal, hidden otherwise.
pub fn progress_bar(total: u64, quiet: bool, what: &str) -> ProgressBar {
    if !shows_progress(quiet) {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix} [{bar:40}] {percent:>3}% {elapsed_precise} eta {left}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .with_key("left", Eta::default())
        .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}

/// Runs `f` under a spinner that says `what` with its clock running, on a
/// terminal and unless `quiet`: for work of unknown length, such as the
/// plan `inspect` makes (20 s for the level-6 sphereflake at 256x256, and
/// as long again to plan larger machines for a refusal's advice), or the
/// encoding of a large image.
fn spinning<T>(quiet: bool, what: &str, f: impl FnOnce() -> T) -> T {
    let pb = if !shows_progress(quiet) {
        ProgressBar::hidden()
    } else {
        let pb = ProgressBar::new_spinner();
        pb.set_style(
            ProgressStyle::with_template("{prefix} {spinner} {elapsed_precise}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        pb.set_prefix(what.to_string());
        pb
    };
    let out = ticking(&pb, f);
    pb.finish_and_clear();
    out
}

/// The bar's time left, at the mean rate since its first unit of work.
/// indicatif's own estimate leans on the first units, which come slowly
/// (the machine fills its nodes with paths before rows finish, and the
/// plan before them advances nothing): it said "eta 3d" at the start of a
/// render of 3 s. Shown once a twentieth of the work is done; "--" before.
#[derive(Clone, Default)]
struct Eta {
    /// When the bar was first seen past zero, and its position then.
    first: Option<(std::time::Instant, u64)>,
    /// The latest tick.
    now: Option<std::time::Instant>,
}

impl indicatif::style::ProgressTracker for Eta {
    fn clone_box(&self) -> Box<dyn indicatif::style::ProgressTracker> {
        Box::new(self.clone())
    }

    fn tick(&mut self, state: &indicatif::ProgressState, now: std::time::Instant) {
        if self.first.is_none() && state.pos() > 0 {
            self.first = Some((now, state.pos()));
        }
        self.now = Some(now);
    }

    fn reset(&mut self, _: &indicatif::ProgressState, _: std::time::Instant) {
        *self = Eta::default();
    }

    fn write(&self, state: &indicatif::ProgressState, w: &mut dyn std::fmt::Write) {
        let left = match (self.first, self.now, state.len()) {
            (Some((t0, p0)), Some(now), Some(len)) => {
                seconds_left(now.duration_since(t0).as_secs_f64(), p0, state.pos(), len)
            }
            _ => None,
        };
        let _ = match left {
            Some(s) => write!(
                w,
                "{:#}",
                indicatif::HumanDuration(std::time::Duration::from_secs_f64(s))
            ),
            None => write!(w, "--"),
        };
    }
}

/// Seconds left for work at `pos` of `len`, having gone from `first` to
/// `pos` in `elapsed` seconds; `None` until a twentieth of `len` is done
/// since `first`, when the rate says little yet.
fn seconds_left(elapsed: f64, first: u64, pos: u64, len: u64) -> Option<f64> {
    let done = pos.saturating_sub(first);
    if done == 0 || done.saturating_mul(20) < len || elapsed.is_nan() || elapsed <= 0.0 {
        return None;
    }
    let left = len.saturating_sub(pos) as f64 * elapsed / done as f64;
    left.is_finite().then_some(left.min(1e9))
}

/// Runs `f` while a thread redraws `pb` four times a second, so that its
/// clock runs while nothing advances it (the machine's planning). Where
/// the bar is hidden, or the OS refuses the thread, `f` runs alone:
/// indicatif's own steady tick would panic there.
fn ticking<T>(pb: &ProgressBar, f: impl FnOnce() -> T) -> T {
    use std::sync::atomic::{AtomicBool, Ordering};
    if pb.is_hidden() {
        return f();
    }
    let done = AtomicBool::new(false);
    std::thread::scope(|s| {
        let ticker = std::thread::Builder::new()
            .name("hypercast-progress".into())
            .spawn_scoped(s, || {
                while !done.load(Ordering::Acquire) {
                    pb.tick();
                    std::thread::park_timeout(std::time::Duration::from_millis(250));
                }
            });
        let out = f();
        done.store(true, Ordering::Release);
        // Woken, so that the command does not wait out its pause.
        if let Ok(t) = &ticker {
            t.thread().unpark();
        }
        out
    })
}

/// What a render gave, whoever rendered it.
struct RenderOutcome {
    film: crate::trace::Film,
    stats: RenderStats,
    cells: Option<CellStructure>,
    aa: AaSummary,
    /// The modelled machine's predicted makespan; `None` for renders on
    /// this host's threads (`--accel roth`).
    virtual_seconds: Option<f64>,
    machine: Option<MachineStats>,
}

/// Renders a job: the one place that picks the renderer for `render`.
fn render_job(job: &RenderJob, progress: &(dyn Fn(u32) + Sync)) -> Result<RenderOutcome> {
    let r = render::render_host(
        &job.scene,
        &job.opts,
        job.adaptive,
        job.accel,
        CellOptions::default(),
        progress,
    )?;
    Ok(RenderOutcome {
        film: r.film,
        stats: r.stats,
        cells: r.cells,
        aa: r.aa,
        virtual_seconds: None,
        machine: None,
    })
}

/// "1.234 s wall" and, when the machine predicted it, "0.567 s virtual".
fn times(wall: f64, virtual_seconds: Option<f64>) -> String {
    match virtual_seconds {
        None => format!("{wall:.3} s wall"),
        Some(v) => format!("{wall:.3} s wall, {v:.3} s virtual"),
    }
}

fn run_render(a: RenderArgs) -> Result<()> {
    let job = prepare_render(a)?;
    let passes = if job.adaptive.is_some() { 2 } else { 1 };
    let out = match &job.machine {
        None => {
            let pb = progress_bar(passes * job.opts.height as u64, job.quiet, "render");
            let progress = |rows: u32| pb.inc(rows as u64);
            let out = render_job(&job, &progress);
            pb.finish_and_clear();
            out?
        }
        Some((topo, mopts)) => {
            let samples = job.opts.width as u64 * job.opts.height as u64 * job.opts.spp as u64;
            // The bar says "plan" while the machine is planned (a build,
            // the mapping's pre-pass, and, for a share that does not fit,
            // the plans of larger dimensions: 10 s and more for 100,000
            // primitives), its clock running, and "render" from the first
            // sample on.
            let pb = progress_bar(samples, job.quiet, "plan");
            let progress = |n: u64| {
                if pb.position() == 0 {
                    pb.set_prefix("render");
                }
                pb.inc(n)
            };
            let result = ticking(&pb, || {
                machine::render_adaptive(&job.scene, topo, mopts, job.adaptive, &progress)
            });
            pb.finish_and_clear();
            let (film, ms, cs, aa) = result?;
            RenderOutcome {
                film,
                stats: ms.as_render_stats(),
                cells: Some(cs),
                aa,
                virtual_seconds: Some(ms.virtual_seconds),
                machine: Some(ms),
            }
        }
    };
    let machine_stats = &out.machine;
    // A large image takes seconds to encode (4096x4096 as PNG: 2.5 s).
    spinning(job.quiet, "write", || {
        report::write_film(&job.output, &out.film)
    })?;
    let metrics = job
        .reference
        .as_ref()
        .map(|(_, r)| report::compare(&r.comparable(&out.film.to_linear()), &r.pixels));
    if let Some(p) = &job.stats {
        let mut v = stats_json(&job, &out, metrics.as_ref());
        if let Some(cs) = &out.cells {
            report::stats::extend(&mut v, structure_json(cs));
        }
        if let (Some(ms), Some((topo, _))) = (machine_stats, &job.machine) {
            report::stats::extend(&mut v, machine_json(topo, ms));
        }
        report::stats::write_json(p, &v)?;
    }
    let stats = &out.stats;
    if !job.quiet {
        let how = match (machine_stats, &job.machine) {
            (Some(ms), Some((topo, _))) => {
                let nodes = counted(ms.per_node.len(), "node");
                format!("cells on {} with {nodes}", topo.name)
            }
            _ => format!(
                "{}, {}",
                job.accel.name(),
                counted(job.opts.threads, "thread")
            ),
        };
        let aa = match job.adaptive {
            None => String::new(),
            Some(_) => format!(" + {} refined pixels", out.aa.refined_pixels),
        };
        eprintln!(
            "hypercast: wrote {} ({}x{}, {} spp{aa}, {how}) in {}; {} rays, {} intersection tests",
            job.output.display(),
            job.opts.width,
            job.opts.height,
            job.opts.spp,
            times(stats.wall_seconds, out.virtual_seconds),
            stats.rays.total(),
            stats.counters.intersection_tests
        );
        if let Some(ms) = machine_stats {
            eprintln!(
                "hypercast: modelled machine: {:.3} s virtual; {} messages, {} bytes, {} hops; busy imbalance {:.2} (max/mean)",
                ms.virtual_seconds, ms.messages, ms.message_bytes, ms.hops, ms.imbalance
            );
            if let Some(note) = whole_for_note(ms.whole_for) {
                eprintln!("hypercast: note: {note}");
            }
            if let Some((topo, _)) = &job.machine
                && let Some(hint) = whole_scene_hint(ms, topo.node_memory)
            {
                eprintln!("hypercast: hint: {hint}");
            }
            let cores = crate::trace::host_cores();
            let usable = ms.per_node.len().min(cores);
            if let Some(note) = busy_host_note(ms.host_share(cores), usable) {
                eprintln!("hypercast: note: {note}");
            }
            if !job.machine_chosen
                && let Some(hint) = cores_hint(ms.per_node.len(), cores, stats.wall_seconds)
            {
                eprintln!("hypercast: hint: {hint}");
            }
        }
        if let Some(hint) = out
            .cells
            .as_ref()
            .and_then(|cs| coarse_margin_hint(&job.scene, cs.stats.walk_margin))
        {
            eprintln!("hypercast: hint: {hint}");
        }
    }
    if let Some(m) = metrics {
        // Error beside run time, always printed when asked for.
        outln!(
            "rmse {:.6}  psnr {:.2} dB  max {:.6}  {}",
            m.rmse,
            m.psnr,
            m.max_error,
            times(stats.wall_seconds, out.virtual_seconds)
        )?;
    }
    Ok(())
}

/// Where the default placement sent paths between nodes although every
/// node could hold the whole scene with room to spare (at most half its
/// memory), the option that renders it without them. The default keeps
/// the paper's distributed structure, whose structure over all nodes
/// stays within twice a single node's (`replicas::REPLICA_CAP`); on the
/// bundled scenes at the iPSC-D5's 32 nodes, holding everything on every
/// node was 1.7-4.6 times faster in wall time, 1.5-4.9 in virtual time
/// (README, "The hypercube machine").
///
/// Said too where no path travelled but the work sat on few nodes (a busy
/// imbalance of `WHOLE_HINT_UNEVEN` or more) on a render of a second or
/// more (in shorter ones the imbalance is mostly the nodes' fixed costs:
/// `scenes/small/sphere.ron` at 320x240 on 32 nodes, 2.3-3.7 with the
/// default placement, 9-11 with the whole scene): a scene of three primitives
/// and 300 lights kept its work on one node of 32 (its splits would have
/// sent rays between nodes at every turn), 67,400 virtual seconds and
/// 6.1 s of wall time against 5,700 and 5.6 s with the whole scene on
/// every node, where the pre-pass deals the pixels out. The default now
/// takes the whole scene itself there (`machine::host::Plan::or_whole`),
/// and never hints after it has: the hint is left for what it does not
/// take, an imbalance the pre-pass did not predict.
fn whole_scene_hint(ms: &MachineStats, node_memory: u64) -> Option<String> {
    let mib = |b: u64| b as f64 / 1048576.0;
    let uneven =
        ms.per_node.len() > 1 && ms.imbalance >= WHOLE_HINT_UNEVEN && ms.wall_seconds >= 1.0;
    if ms.replicas != Some(machine::Replicas::Auto)
        || ms.whole
        || !(ms.hops > 0 || uneven)
        || ms.replicated_bytes > node_memory / 2
    {
        return None;
    }
    let why = if ms.hops > 0 {
        "renders it with no paths between nodes".to_string()
    } else {
        format!(
            "deals out its work, which sat on few nodes here (busy imbalance {:.2})",
            ms.imbalance
        )
    };
    Some(format!(
        "every node could hold this whole scene ({:.2} MiB of {:.2} MiB); \
         --replicas whole {why} \
         (the scene copied to every node, not distributed as in the paper)",
        mib(ms.replicated_bytes),
        mib(node_memory)
    ))
}

/// Where `--replicas auto` put the whole scene on every node
/// (`machine::host::Plan::whole_for`), what the paper's plan would have
/// done and how to have it.
fn whole_for_note(whole_for: Option<f64>) -> Option<String> {
    whole_for.map(|uneven| {
        format!(
            "every node held the whole scene: distributed as in the paper, the work would have \
             sat on few nodes (predicted imbalance {uneven:.1}); --replicas none keeps the \
             paper's plan"
        )
    })
}

/// The stats' name of where the structure lies: `whole` on every node, or
/// `distributed` over them (with copies where `--replicas auto` placed
/// them).
fn placement(whole: bool) -> &'static str {
    if whole { "whole" } else { "distributed" }
}

/// The busy imbalance from which a render that sent no path between nodes
/// gets `whole_scene_hint`.
const WHOLE_HINT_UNEVEN: f64 = 2.0;

/// Where the default machine's node threads outnumbered the host's cores
/// on a render of a second or more, the dimension that gives each core one
/// node: the quickest picture, and the same image (the level-4 sphereflake
/// at 1024x1024 on two cores: 1.05-1.21 s at `--dim 1` against 2.83-3.23 s
/// on the default 32 nodes, README). Not said where the user chose the
/// machine: then the 32 nodes are the experiment.
fn cores_hint(nodes: usize, cores: usize, wall_seconds: f64) -> Option<String> {
    let dim = cores.max(1).ilog2();
    (nodes > cores && wall_seconds >= 1.0).then(|| {
        format!(
            "{} shared this host's {}; for the quickest picture give each core \
             one node: --dim {dim} (the same image)",
            counted(nodes, "node thread"),
            counted(cores, "core")
        )
    })
}

/// Said where the nodes had less than half the host's cores they could
/// use (`MachineStats::host_share`): other work on the host, whose turns
/// the wall time counts in full and the virtual time hardly (a node's
/// clock follows its own CPU time: the level-5 sphereflake at d = 5 took
/// 20 s instead of 2.1-2.4 s beside four busy loops, and 2,872 virtual
/// seconds against 2,673).
fn busy_host_note(share: Option<f64>, usable: usize) -> Option<String> {
    let share = share.filter(|&s| s < 0.5)?;
    Some(format!(
        "the nodes had {:.0}% of the {} they could use while they ran (other work on this host?): \
         the wall time overstates the run; the virtual time counts each node's own CPU time",
        100.0 * share,
        counted(usable, "core")
    ))
}

fn stats_json(job: &RenderJob, out: &RenderOutcome, m: Option<&ImageMetrics>) -> serde_json::Value {
    let s = &out.stats;
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
        "aa_threshold": job.adaptive.map(|a| a.threshold),
        "aa_spp": job.adaptive.map(|a| a.extra_spp),
        "aa_refined_pixels": out.aa.refined_pixels,
        "samples": out.aa.samples,
        "wall_seconds": s.wall_seconds,
        "virtual_seconds": out.virtual_seconds,
        "rays": rays,
        "intersection_tests": s.counters.intersection_tests,
        "mailbox_hits": s.counters.mailbox_hits,
        "cells_visited": s.counters.cells_visited,
        "subtree_evaluations": s.counters.subtree_evaluations,
        "pixels_traced": s.pixels_traced,
        "pixels_background": s.pixels_background,
        "primitives": job.scene.primitives.len(),
        "messages": 0,
        "message_bytes": 0,
        "hops": 0,
        "per_node": [],
        "rmse": m.map(|m| num(m.rmse)),
        "psnr": m.map(|m| num(m.psnr)),
        "max_error": m.map(|m| num(m.max_error)),
        "reference": job.reference.as_ref().map(|(p, _)| p.display().to_string()),
    })
}

/// The keys of a machine run (`CLI.md`), replacing the single-node ones.
pub fn machine_json(topo: &Topology, ms: &MachineStats) -> Vec<(&'static str, serde_json::Value)> {
    let per_node: Vec<serde_json::Value> = ms
        .per_node
        .iter()
        .map(|n| {
            json!({
                "node": n.node,
                "cells": n.cells,
                "super_cells": n.super_cells,
                "copies": n.copies,
                "primitives": n.primitives,
                "memory_bytes": n.memory_bytes,
                "structure_bytes": n.structure_bytes,
                "memory_budget_bytes": n.memory_budget_bytes,
                "peak_memory_bytes": n.peak_memory_bytes,
                "rays_processed": n.rays_processed,
                "messages_sent": n.messages_sent,
                "bytes_sent": n.bytes_sent,
                "hops": n.hops,
                "paths_forwarded": n.paths_forwarded,
                "leaves_sent": n.leaves_sent,
                "credits_from_host": n.credits_from_host,
                "max_stack_rays": n.max_stack_rays,
                "intersection_tests": n.intersection_tests,
                "mailbox_hits": n.mailbox_hits,
                "cells_visited": n.cells_visited,
                "subtree_evaluations": n.subtree_evaluations,
                "busy_seconds": n.busy_seconds,
                "virtual_seconds": n.virtual_seconds,
                "waiting_seconds": n.waiting_seconds,
            })
        })
        .collect();
    vec![
        ("topology", json!(topo.name)),
        ("dimension", json!(ms.dimension)),
        ("nodes", json!(ms.per_node.len())),
        ("virtual_seconds", num(ms.virtual_seconds)),
        ("messages", json!(ms.messages)),
        ("message_bytes", json!(ms.message_bytes)),
        ("hops", json!(ms.hops)),
        ("mapping", json!(ms.mapping.map(|m| m.name()))),
        ("replicas", json!(ms.replicas.map(|r| r.name()))),
        ("placement", json!(placement(ms.whole))),
        ("distributed_predicted_imbalance", json!(ms.whole_for)),
        (
            "copies",
            json!(ms.per_node.iter().map(|n| n.copies).sum::<u64>()),
        ),
        ("window", json!(ms.window)),
        ("imbalance", num(ms.imbalance)),
        ("predicted_imbalance", num(ms.predicted_imbalance)),
        ("prepass_seconds", num(ms.prepass_seconds)),
        ("run_seconds", num(ms.run_seconds)),
        ("run_cpu_seconds", num(ms.run_cpu_seconds)),
        ("split_super_cells", json!(ms.split_super_cells)),
        ("subdivision", json!(ms.subdivision.name())),
        (
            "peak_memory_bytes",
            json!(ms.per_node.iter().map(|n| n.peak_memory_bytes).max()),
        ),
        ("replicated_scene_bytes", json!(ms.replicated_bytes)),
        ("per_node", json!(per_node)),
    ]
}

/// A hint where the walk's margin (`BuildStats::walk_margin`) is a
/// hundredth or more of the median primitive's size: the scene reaches so
/// far beyond its detail that the grown boxes blur the subdivision.
fn coarse_margin_hint(scene: &Scene, margin: f64) -> Option<String> {
    let mut sizes: Vec<f64> = scene
        .primitives
        .iter()
        .map(|p| p.bounds.largest_side())
        .filter(|s| s.is_finite() && *s > 0.0)
        .collect();
    if sizes.is_empty() {
        return None;
    }
    sizes.sort_by(f64::total_cmp);
    let median = sizes[(sizes.len() - 1) / 2];
    (margin >= 0.01 * median).then(|| {
        format!(
            "every box is grown by {margin:.2e} for the walk's rounding, against a median primitive of size \
             {median:.2e}: the scene reaches so far beyond its detail that the subdivision splits little, and rays \
             test more (exact all the same; docs/robustness.md, \"Scenes reaching 1e13 beyond their detail\")"
        )
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
        ("walk_margin", json!(s.walk_margin)),
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
    let outputs: Vec<(&str, &Path)> = [("overlay", &a.overlay), ("statistics", &a.stats)]
        .into_iter()
        .filter_map(|(what, p)| Some((what, p.as_deref()?)))
        .collect();
    check_apart(&[("scene", &a.scene)], &outputs)?;
    let threads = host_threads(a.threads)?;
    let (scene, width, height) = load_for_run(&a.scene, a.width, a.height, a.quiet)?;
    // The structure the modelled machine would use (the machine asks for
    // more super cells on more nodes, `CellOptions::min_super_cells`).
    let topo = a.machine.topology()?;
    let mopts = a.machine.options(width, height, 1, a.bsp.into())?;
    let plan = spinning(a.quiet, "plan", || {
        machine::host::Plan::new(&scene, &topo, &mopts)
    })?;
    let cs = &plan.cells;
    let s = &cs.stats;
    let front = cs.region(crate::cells::Region::Front);
    let back = cs.region(crate::cells::Region::Back);
    outln!("scene               {}", a.scene.display())?;
    outln!(
        "primitives          {} ({} culled: empty minimal box)",
        scene.primitives.len(),
        s.culled_primitives
    )?;
    outln!("csg tree nodes      {}", s.tree_nodes)?;
    outln!(
        "super cells         {} (front {}, behind the eye plane {})",
        s.super_cells,
        front.partition.leaves.len(),
        back.partition.leaves.len()
    )?;
    outln!("cells               {} ({} empty)", s.cells, s.empty_cells)?;
    outln!(
        "primitives per cell mean {:.2}, max {}",
        s.prims_per_cell_mean,
        s.prims_per_cell_max
    )?;
    outln!(
        "subtree nodes/cell  mean {:.2}, max {} (whole tree {})",
        s.subtree_nodes_mean,
        s.subtree_nodes_max,
        s.tree_nodes
    )?;
    outln!("distinct subtrees   {}", s.distinct_subtrees)?;
    outln!("bsp segment splits  {}", s.bsp_splits)?;
    outln!(
        "walk margin         {:.2e} (boxes grown for the walk's rounding)",
        s.walk_margin
    )?;
    if let Some(hint) = coarse_margin_hint(&scene, s.walk_margin) {
        eprintln!("hypercast: hint: {hint}");
    }
    outln!(
        "structure bytes     {} ({:.2} MiB)",
        s.bytes,
        s.bytes as f64 / (1024.0 * 1024.0)
    )?;
    outln!("build time          {:.4} s", s.build_seconds)?;
    let mut v = json!({"scene": a.scene.display().to_string(), "width": width, "height": height, "primitives": scene.primitives.len()});
    report::stats::extend(&mut v, structure_json(cs));
    // The mapping on the modelled machine: what each node would hold.
    outln!(
        "machine             {} with {} of {:.2} MiB, {} mapping",
        topo.name,
        counted(topo.nodes(), "node"),
        topo.node_memory as f64 / 1048576.0,
        mopts.mapping.name()
    )?;
    outln!(
        "replicated scene    {:.2} MiB per node if every node held everything",
        plan.replicated_bytes as f64 / 1048576.0
    )?;
    outln!(
        "paths in flight     {} per node (each at most {} bytes)",
        plan.window,
        plan.path_bytes
    )?;
    if plan.split_super_cells > 0 {
        outln!(
            "split for balance   {} super cells over half a node's share, built {} more time(s)",
            plan.split_super_cells,
            plan.rebuilds
        )?;
    }
    if plan.subdivision != machine::host::Subdivision::Balanced {
        outln!("subdivision         {}", plan.subdivision.describe())?;
    }
    if let Some(uneven) = plan.whole_for {
        outln!(
            "placement           the whole scene on every node: distributed, the plan predicted imbalance {uneven:.3} (--replicas none keeps it)"
        )?;
    } else if plan.whole {
        outln!("placement           the whole scene on every node (--replicas whole)")?;
    }
    outln!(
        "node  super_cells  copies  cells  primitives  memory_MiB  structure_MiB  estimated_work"
    )?;
    let mut nodes_json = Vec::new();
    for (i, (share, local)) in plan.node_shares().enumerate() {
        let owned: Vec<(usize, usize)> = (0..2)
            .flat_map(|r| {
                plan.owner[r]
                    .iter()
                    .enumerate()
                    .filter(|(_, o)| **o as usize == i)
                    .map(move |(s, _)| (r, s))
            })
            .collect();
        let cells: usize = owned
            .iter()
            .map(|&(r, s)| share.regions[r].cells_of(s as u32).len())
            .sum();
        // `+ 0.0`: an empty float sum is -0.0, which prints as "-0".
        let work: f64 = owned.iter().map(|&(r, s)| plan.work[r][s]).sum::<f64>() + 0.0;
        outln!(
            "{i:>4}  {:>11}  {:>6}  {cells:>5}  {:>10}  {:>10.3}  {:>13.3}  {work:>14.0}",
            owned.len(),
            plan.copies_held(i),
            local.primitives.len(),
            plan.share_bytes[i] as f64 / 1048576.0,
            share.bytes() as f64 / 1048576.0
        )?;
        nodes_json.push(json!({"node": i, "super_cells": owned.len(), "copies": plan.copies_held(i), "cells": cells, "primitives": local.primitives.len(), "memory_bytes": plan.share_bytes[i], "structure_bytes": share.bytes(), "estimated_work": work}));
    }
    let held: usize = plan.node_shares().map(|(c, _)| c.bytes()).sum();
    outln!(
        "structure held     {:.2} MiB over all nodes, {:.2}x the whole structure",
        held as f64 / 1048576.0,
        held as f64 / s.bytes.max(1) as f64
    )?;
    // What the plan's splits and mapping came to: the render's busy
    // imbalance is this, give or take the pre-pass's error.
    let uneven = plan.predicted_imbalance(topo.dimension);
    outln!("predicted imbalance {uneven:.3} (the most estimated work of a node against the mean)")?;
    if let Err(e) = plan.check(&scene, &topo) {
        let e = spinning(a.quiet, "plan larger machines", || {
            machine::host::advise(e, &scene, &topo, &mopts)
        });
        outln!("does not fit: {e}")?;
    }
    report::stats::extend(
        &mut v,
        [
            ("topology", json!(topo.name)),
            ("dimension", json!(topo.dimension)),
            ("nodes", json!(topo.nodes())),
            ("memory_budget_bytes", json!(topo.node_memory)),
            ("replicated_scene_bytes", json!(plan.replicated_bytes)),
            ("window", json!(plan.window)),
            ("split_super_cells", json!(plan.split_super_cells)),
            ("subdivision", json!(plan.subdivision.name())),
            ("placement", json!(placement(plan.whole))),
            ("distributed_predicted_imbalance", json!(plan.whole_for)),
            ("predicted_imbalance", num(uneven)),
            ("per_node", json!(nodes_json)),
        ],
    );
    if let Some(p) = &a.stats {
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
        let rendered = render::render_with(
            &scene,
            &opts,
            || crate::cells::CellTracer::new(cs, &scene),
            |t, job| t.skips_primary(&job.ray),
            &progress,
        );
        pb.finish_and_clear();
        let (film, _) = rendered?;
        let mut img = film.to_linear();
        let cam = crate::trace::CameraFrame::new(&scene, width, height);
        let most = report::overlay::draw_super_cells(&mut img, &cam, cs, Some(&plan.owner[0]));
        report::write_image(o, width, height, &img)?;
        if !a.quiet {
            let scale = match most {
                1 => "red 1".to_string(),
                _ => format!("blue 1 to red {most}"),
            };
            eprintln!(
                "hypercast: wrote {}: super cells outlined by their primitives, {scale}, grey \
                 none; tinted by the node that owns them",
                o.display()
            );
        }
    }
    Ok(())
}

fn run_scale(a: ScaleArgs) -> Result<()> {
    let dims = report::scale::parse_dims(&a.dims).map_err(Error::Usage)?;
    if a.repeat == 0 || a.repeat > 100 {
        return Err(Error::Usage(format!(
            "--repeat must be in 1..=100, got {}",
            a.repeat
        )));
    }
    if a.spp == 0 || a.spp > 65536 {
        return Err(Error::Usage(format!(
            "--spp must be in 1..=65536, got {}",
            a.spp
        )));
    }
    if a.machine.dim.is_some() {
        return Err(Error::Usage("scale takes --dims, not --dim".into()));
    }
    if a.out.exists() && !a.out.is_dir() {
        return Err(Error::Usage(format!(
            "--out {}: not a folder",
            a.out.display()
        )));
    }
    let (scene, width, height) = load_for_run(&a.scene, a.width, a.height, a.quiet)?;
    let topo = a.machine.topology()?;
    let opts = a
        .machine
        .options(width, height, a.spp, SegmentChoice::default())?;
    let runs = dims.len() as u64 * (a.repeat as u64 + 1);
    let pb = progress_bar(runs, a.quiet, "scale");
    // Advanced once a run: its clock runs between (`ticking`).
    let rows = ticking(&pb, || {
        report::scale::measure(&scene, &topo, &dims, a.repeat, &opts, &|done, _| {
            pb.set_position(done as u64)
        })
    });
    pb.finish_and_clear();
    let rows = rows?;
    out!("{}", report::scale::table(&rows))?;
    let cores = crate::trace::host_cores();
    for r in &rows {
        if let Some(note) = busy_host_note(r.host_share, r.nodes.min(cores)) {
            eprintln!("hypercast: note: at d = {}, {note}", r.dimension);
        }
        if let Some(note) = whole_for_note(r.whole_for) {
            eprintln!("hypercast: note: at d = {}, {note}", r.dimension);
        }
    }
    // Made only now, so that a refused scene or dimension leaves nothing
    // behind (the table above is printed either way).
    std::fs::create_dir_all(&a.out).map_err(|e| Error::Write {
        path: a.out.clone(),
        message: e.to_string(),
    })?;
    // Modes other than the defaults are named, so that plots of one
    // scene side by side say which is which.
    let mut modes = String::new();
    if opts.replicas != machine::Replicas::default() {
        modes += &format!(", --replicas {}", opts.replicas.name());
    }
    if opts.mapping != Mapping::default() {
        modes += &format!(", --mapping {}", opts.mapping.name());
    }
    let title = format!(
        "{} on {} ({}x{}, {} spp{modes})",
        a.scene
            .file_name()
            .map_or("scene".into(), |s| s.to_string_lossy()),
        topo.name,
        width,
        height,
        a.spp
    );
    report::scale::write_outputs(&a.out, &title, &rows)?;
    if !a.quiet {
        eprintln!(
            "hypercast: wrote {} and {}",
            a.out.join("scaling.csv").display(),
            a.out.join("scaling.png").display()
        );
    }
    Ok(())
}

/// Writes a report's text to standard output. A reader that has gone
/// (`hypercast inspect scene.ron | head`) is no error: it has what it
/// wanted, and the command goes on to write its files. (`print!` panicked
/// there.) Any other failure to write is one, so that a table sent to a
/// full disk is not lost in silence.
pub(crate) fn write_stdout(args: std::fmt::Arguments) -> Result<()> {
    use std::io::Write;
    match std::io::stdout().lock().write_fmt(args) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(Error::Write {
            path: "standard output".into(),
            message: e.to_string(),
        }),
        _ => Ok(()),
    }
}

/// `n` and `noun`, plural unless `n` is 1 ("1 node", "32 nodes").
fn counted(n: usize, noun: &str) -> String {
    format!("{n} {noun}{}", if n == 1 { "" } else { "s" })
}

#[cfg(test)]
mod tests {
    /// The summary line counts "1 node" and "32 nodes", "1 thread".
    #[test]
    fn counts_take_the_plural_unless_one() {
        assert_eq!(super::counted(1, "node"), "1 node");
        assert_eq!(super::counted(32, "node"), "32 nodes");
        assert_eq!(super::counted(0, "thread"), "0 threads");
    }

    /// The hint to give each core one node: only where node threads
    /// outnumber the cores on a render of a second or more, naming the
    /// dimension of one node per core.
    #[test]
    fn the_cores_hint_names_one_node_per_core() {
        use super::cores_hint;
        let h = cores_hint(32, 2, 2.8).expect("a hint");
        assert!(
            h.starts_with("32 node threads shared this host's 2 cores"),
            "{h}"
        );
        assert!(h.contains("--dim 1 "), "{h}");
        assert!(cores_hint(32, 8, 2.8).unwrap().contains("--dim 3 "));
        assert!(cores_hint(32, 6, 2.8).unwrap().contains("--dim 2 "));
        assert!(cores_hint(32, 1, 2.8).unwrap().contains("--dim 0 "));
        assert_eq!(cores_hint(32, 2, 0.5), None, "a quick render needs no hint");
        assert_eq!(cores_hint(2, 2, 2.8), None, "one node per core already");
        assert_eq!(cores_hint(32, 64, 2.8), None);
    }

    /// The whole-scene hint: where paths travelled between nodes that could
    /// each hold the scene twice over, and where none did but the work of
    /// a render of a second or more sat on few nodes; not for a placement
    /// the user chose, one node, a scene over half a node, or a short or
    /// even run without paths.
    #[test]
    fn the_whole_scene_hint_names_why() {
        use crate::machine::message::NodeReport;
        use crate::machine::{MachineStats, Replicas};
        let mib = 1u64 << 20;
        let ms = |hops: u64, imbalance: f64, wall_seconds: f64| MachineStats {
            replicas: Some(Replicas::Auto),
            replicated_bytes: mib,
            per_node: vec![NodeReport::default(); 32],
            hops,
            imbalance,
            wall_seconds,
            ..MachineStats::default()
        };
        let hint = |m: &MachineStats| super::whole_scene_hint(m, 4 * mib);
        let crossed = hint(&ms(10, 1.1, 0.1)).expect("a hint");
        assert!(crossed.contains("with no paths between nodes"), "{crossed}");
        let gathered = hint(&ms(0, 32.0, 6.1)).expect("a hint");
        assert!(
            gathered.contains("deals out its work") && gathered.contains("imbalance 32.00"),
            "{gathered}"
        );
        assert_eq!(hint(&ms(0, 32.0, 0.5)), None, "a short run");
        assert_eq!(hint(&ms(0, 1.5, 6.1)), None, "an even run");
        let mut one = ms(0, 32.0, 6.1);
        one.per_node.truncate(1);
        assert_eq!(hint(&one), None, "one node");
        let mut chosen = ms(10, 1.1, 0.1);
        chosen.replicas = Some(Replicas::None);
        assert_eq!(hint(&chosen), None, "a placement the user chose");
        let mut taken = ms(0, 32.0, 6.1);
        taken.whole = true;
        assert_eq!(hint(&taken), None, "the whole scene the default took");
        assert_eq!(
            super::whole_scene_hint(&ms(10, 1.1, 0.1), mib),
            None,
            "too large"
        );
    }

    /// A run that had less than half the cores it could use says so; a
    /// run too short to tell, or one that had them, does not.
    #[test]
    fn a_starved_run_is_noted() {
        let note = super::busy_host_note(Some(0.18), 2).expect("a note");
        assert!(note.contains("18% of the 2 cores"), "{note}");
        assert!(
            super::busy_host_note(Some(0.2), 1)
                .unwrap()
                .contains("of the 1 core ")
        );
        assert_eq!(super::busy_host_note(Some(0.93), 2), None);
        assert_eq!(super::busy_host_note(None, 2), None);
        let stats = crate::machine::MachineStats {
            run_seconds: 16.0,
            run_cpu_seconds: 5.6,
            per_node: vec![Default::default(); 32],
            ..Default::default()
        };
        assert_eq!(stats.host_share(2), Some(0.175));
        assert_eq!(stats.host_share(64), Some(5.6 / 16.0 / 32.0));
        let short = crate::machine::MachineStats {
            run_seconds: 0.05,
            ..stats
        };
        assert_eq!(short.host_share(2), None);
    }

    /// The bar's time left is the mean rate's since the first unit, and
    /// says nothing before a twentieth of the work.
    #[test]
    fn time_left_is_the_mean_rates_once_a_twentieth_is_done() {
        use super::seconds_left;
        // 1,000 rows, the first seen at row 10; 40 more rows in 2 s.
        assert_eq!(seconds_left(2.0, 10, 50, 1000), None);
        assert_eq!(seconds_left(2.0, 10, 60, 1000), Some(37.6));
        assert_eq!(seconds_left(0.0, 10, 600, 1000), None);
        assert_eq!(seconds_left(3.0, 0, 1000, 1000), Some(0.0));
        // Six runs of `scale`: the second done one second after the first.
        assert_eq!(seconds_left(1.0, 1, 2, 6), Some(4.0));
    }
}
