//! `hypercast gen KIND … -o OUT`: a generated scene written as RON, JSON or
//! NFF by the output's extension. The generators are `crate::gen`'s; this
//! file holds their options, bounded so that a generated scene fits in
//! memory, and writes the result atomically.

use std::path::{Path, PathBuf};

use crate::Result;
use crate::r#gen::{RandomCsgOptions, random_csg};
use crate::r#gen::{jagged_ball, rings, sphereflake};
use crate::scene::SceneSyntax;

#[derive(clap::Args, Debug)]
pub struct GenArgs {
    #[command(subcommand)]
    pub scene: GenScene,
}

#[derive(clap::Subcommand, Debug)]
pub enum GenScene {
    /// Eric Haines' sphereflake (SPD "balls"): (9^(N+1) − 1)/8 spheres, a floor, three lights.
    Sphereflake {
        /// Recursion level: 4 is the SPD's (7,381 spheres); 6 has 597,871.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(0..=6))]
        level: u32,
        #[command(flatten)]
        out: Output,
    },
    /// The SPD's rings: 5k rings on the k-th of N pentagons, each 30 cylinders and 30 spheres.
    Rings {
        /// Size factor: 7 is the SPD's (8,401 primitives).
        #[arg(long, default_value_t = rings::DEFAULT_SIZE, value_parser = clap::value_parser!(u32).range(1..=30))]
        size: u32,
        #[command(flatten)]
        out: Output,
    },
    /// The paper's jagged ball (figure 16): a CSG ball with 200 cuts and spikes.
    JaggedBall {
        /// Seed of the choice of cut or spike per point.
        #[arg(long, default_value_t = 1987)]
        seed: u64,
        /// Cuts and additions on the ball.
        #[arg(long, default_value_t = jagged_ball::POINTS as u32, value_parser = clap::value_parser!(u32).range(0..=100_000))]
        points: u32,
        #[command(flatten)]
        out: Output,
    },
    /// A random CSG scene: every primitive and operator, transforms, mirrors and glass.
    RandomCsg {
        /// The same seed and options give the same scene.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Number of primitives.
        #[arg(long, value_parser = clap::value_parser!(u32).range(0..=1_000_000))]
        primitives: u32,
        /// Image width of the scene's camera.
        #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(1..=65536))]
        width: u32,
        /// Image height of the scene's camera.
        #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=65536))]
        height: u32,
        #[command(flatten)]
        out: Output,
    },
}

#[derive(clap::Args, Debug)]
pub struct Output {
    /// Output file, by extension: .ron, .json or .nff (NFF only for scenes it can express).
    #[arg(short, long)]
    pub output: PathBuf,
    /// No summary line.
    #[arg(short, long)]
    pub quiet: bool,
}

pub fn run(a: GenArgs) -> Result<()> {
    let (out, name) = match &a.scene {
        GenScene::Sphereflake { level, out } => (out, format!("sphereflake level {level}")),
        GenScene::Rings { size, out } => (out, format!("rings size {size}")),
        GenScene::JaggedBall { seed, out, .. } => (out, format!("jagged ball seed {seed}")),
        GenScene::RandomCsg { seed, out, .. } => (out, format!("random CSG seed {seed}")),
    };
    // Refuse bad options before generating anything.
    let syntax = SceneSyntax::from_path(&out.output)?;
    crate::cli::check_writable_dir(&out.output)?;
    let model = match &a.scene {
        GenScene::Sphereflake { level, .. } => sphereflake::sphereflake(*level),
        GenScene::Rings { size, .. } => rings::rings(*size),
        GenScene::JaggedBall { seed, points, .. } => {
            jagged_ball::jagged_ball(*seed, *points as usize)
        }
        GenScene::RandomCsg {
            seed,
            primitives,
            width,
            height,
            ..
        } => random_csg(
            *seed,
            *primitives as usize,
            &RandomCsgOptions {
                width: *width,
                height: *height,
                ..Default::default()
            },
        ),
    };
    let text = crate::scene::load::write_scene(&model, syntax, Path::new(&name))?;
    super::write_text(&out.output, &text)?;
    if !out.quiet {
        eprintln!("hypercast: wrote {} ({name})", out.output.display());
    }
    Ok(())
}
