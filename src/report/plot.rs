//! What every plot shares: the bundled font (DejaVu Sans cut down to
//! ASCII, `assets/fonts/`, so plots need no system fonts) and writing a
//! drawn RGB buffer as a PNG, atomically.

use std::io::Write;
use std::path::Path;

use plotters::style::FontStyle;

use super::image_io::write_atomically;
use crate::error::{Error, Result};

static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-ASCII.ttf");

/// Makes the bundled font the plots' "sans-serif" (idempotent).
pub fn register_font() -> std::result::Result<(), String> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
        .map_err(|_| "the bundled plot font does not parse".to_string())
}

/// Draws into a white `size` RGB buffer with `draw` and writes it to
/// `path` as a PNG, atomically.
pub fn write_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&mut [u8]) -> std::result::Result<(), String>,
) -> Result<()> {
    let err = |message: String| Error::Write {
        path: path.to_path_buf(),
        message,
    };
    let (w, h) = size;
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    register_font().map_err(err)?;
    draw(&mut buf).map_err(err)?;
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| err("plot size".into()))?;
    write_atomically(path, |f| {
        let mut out = std::io::BufWriter::new(f);
        img.write_to(&mut out, image::ImageFormat::Png)
            .map_err(|e| e.to_string())?;
        out.flush().map_err(|e| e.to_string())
    })
}
