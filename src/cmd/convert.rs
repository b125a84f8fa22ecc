//! `hypercast convert SCENE -o OUT [--flat]`: a scene in another syntax.
//! `.pov` is POV-Ray 3.7 SDL (`scene::pov`), for cross-checking a scene in
//! the renderer users know; `.ron`, `.json` and `.nff` are our own
//! (`scene::load`, `scene::nff`; NFF only for what it can express).
//! `--flat` converts the flat per-object-colour variant (`scene::flat`)
//! instead, for comparing renderers pixel by pixel.

use std::path::{Path, PathBuf};

use crate::scene::{SceneSyntax, flat, load, pov};
use crate::{Error, Result};

#[derive(clap::Args, Debug)]
pub struct ConvertArgs {
    /// Scene file: .ron, .json or .nff.
    pub scene: PathBuf,
    /// Output file, by extension: .pov (POV-Ray 3.7), .ron, .json or .nff.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Convert the flat variant: each primitive its own colour, ambient
    /// light only, no lights (for comparing renderers pixel by pixel).
    #[arg(long)]
    pub flat: bool,
    /// Camera image width (default: the scene's). POV-Ray's camera takes
    /// its aspect ratio from this size, so give the size you will render.
    #[arg(long)]
    pub width: Option<u32>,
    /// Camera image height (default: the scene's).
    #[arg(long)]
    pub height: Option<u32>,
    /// No summary line.
    #[arg(short, long)]
    pub quiet: bool,
}

/// What an output file's extension asks for.
#[derive(Clone, Copy)]
enum Target {
    Pov,
    Scene(SceneSyntax),
}

fn target(path: &Path) -> Result<Target> {
    let pov = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("pov"));
    if pov {
        return Ok(Target::Pov);
    }
    SceneSyntax::from_path(path)
        .map(Target::Scene)
        .map_err(|_| {
            Error::Usage(format!(
                "{}: unknown output type: the name must end in .pov, .ron, .json or .nff",
                path.display()
            ))
        })
}

pub fn run(a: ConvertArgs) -> Result<()> {
    // Refuse bad options before reading anything.
    let target = target(&a.output)?;
    crate::cli::check_writable_dir(&a.output)?;
    crate::cli::check_apart(&[("scene", &a.scene)], &[("output", &a.output)])?;
    // The whole conversion on the loading thread's stack: models thousands
    // of levels deep are walked, and dropped, recursively (`scene::model`).
    let text = load::on_load_stack(|| -> Result<String> {
        let mut model = load::load_model(&a.scene)?;
        let camera = &mut model.camera;
        camera.width = a.width.unwrap_or(camera.width);
        camera.height = a.height.unwrap_or(camera.height);
        load::check_resolution(camera.width, camera.height)
            .map_err(|m| Error::Usage(format!("--width/--height: {m}")))?;
        let model = if a.flat {
            flat::flat_model(&model)?
        } else {
            model
        };
        match target {
            Target::Pov => pov::write_pov(&model, &a.scene),
            Target::Scene(syntax) => crate::scene::load::write_scene(&model, syntax, &a.scene),
        }
    })??;
    super::write_text(&a.output, &text)?;
    if !a.quiet {
        eprintln!(
            "hypercast: wrote {}{}",
            a.output.display(),
            if a.flat { " (flat colours)" } else { "" }
        );
    }
    Ok(())
}
