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

/// The ticks of a log axis over `[lo, hi]` (both positive): labelled at
/// 1, 2 and 5 times the powers of ten, and a light line at every integer
/// multiple of them. Plotters' own labelled all nine multiples, which ran
/// into each other toward the top of each decade.
pub fn log_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let (mut bold, mut light) = (Vec::new(), Vec::new());
    if !(lo > 0.0 && hi.is_finite() && lo < hi) {
        return (bold, light);
    }
    let (first, last) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    for k in first..=last {
        let decade = 10f64.powi(k);
        for m in 1..=9 {
            let v = decade * f64::from(m);
            if (lo..=hi).contains(&v) {
                light.push(v);
                if matches!(m, 1 | 2 | 5) {
                    bold.push(v);
                }
            }
        }
    }
    (bold, light)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_label_one_two_five_and_line_every_multiple() {
        let (bold, light) = log_ticks(0.0999, 6.4);
        assert_eq!(bold, vec![0.1, 0.2, 0.5, 1.0, 2.0, 5.0]);
        assert_eq!(light.len(), 9 + 6);
        assert!(light.iter().all(|v| (0.0999..=6.4).contains(v)));
        assert_eq!(log_ticks(0.0, 1.0), (vec![], vec![]));
    }
}
