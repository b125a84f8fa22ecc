//! Subcommands beyond `render` and `inspect`, one file each with its clap
//! arguments and its run function, so that `cli.rs` only lists them. They
//! validate their options, call the library, and write their output files
//! atomically (`report::image_io::write_atomically`).

pub mod convert;
pub mod generate;

use std::path::Path;

use crate::Result;

/// Writes `text` to `path` atomically: nothing is left behind on failure.
fn write_text(path: &Path, text: &str) -> Result<()> {
    crate::report::image_io::write_atomically(path, |file| {
        std::io::Write::write_all(file, text.as_bytes()).map_err(|e| e.to_string())
    })
}
