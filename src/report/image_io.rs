//! Image files: PNG and PPM (sRGB, 8 bits) and OpenEXR (linear float),
//! chosen by extension and written atomically (a temporary file in the same
//! folder, then a rename), so a failed or interrupted run never leaves a
//! partial image. Also reading a reference image and measuring error.

use std::borrow::Cow;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

use image::codecs::pnm::{PnmEncoder, PnmSubtype, SampleEncoding};
use image::{ExtendedColorType, ImageEncoder, ImageFormat, Rgb32FImage, RgbImage};

use crate::error::{Error, Result};
use crate::trace::Film;

/// The output formats, by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputFormat {
    Png,
    Ppm,
    Exr,
}

impl OutputFormat {
    /// The format for `path`'s extension, or a usage error naming it.
    pub fn for_path(path: &Path) -> Result<OutputFormat> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("png") => Ok(OutputFormat::Png),
            Some("ppm") => Ok(OutputFormat::Ppm),
            Some("exr") => Ok(OutputFormat::Exr),
            _ => Err(Error::Usage(format!(
                "{}: unknown output format; use .png, .ppm or .exr",
                path.display()
            ))),
        }
    }
}

/// The sRGB transfer function of a linear value, clamped to [0, 1].
pub fn srgb_encode(linear: f32) -> f32 {
    let c = if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    };
    if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

fn srgb_decode(v: f32) -> f32 {
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Display values (sRGB-encoded, in [0, 1]) of linear pixels.
pub fn to_display(linear: &[[f32; 3]]) -> Vec<[f32; 3]> {
    linear.iter().map(|p| p.map(srgb_encode)).collect()
}

/// 8-bit sRGB bytes of linear pixels.
pub fn to_srgb8(linear: &[[f32; 3]]) -> Vec<u8> {
    srgb8_of(linear, |p| *p)
}

/// 8-bit sRGB bytes of a film's pixels: `to_srgb8` of its `to_linear`,
/// without the linear image in between (12 MB at 1024x1024, whose page
/// faults were most of the time making it).
pub fn film_to_srgb8(film: &Film) -> Vec<u8> {
    srgb8_of(film.sums(), Film::linear)
}

fn srgb8_of<T: Sync>(pixels: &[T], linear: impl Fn(&T) -> [f32; 3] + Sync) -> Vec<u8> {
    let table = Srgb8::get();
    let mut out = vec![0u8; pixels.len() * 3];
    crate::trace::map_parallel(pixels, &mut out, 3, |p, o| {
        for (o, c) in o.iter_mut().zip(linear(p)) {
            *o = table.byte(c);
        }
    });
    out
}

/// The 8-bit sRGB byte of a linear value, computed directly: what
/// `Srgb8::byte` gives without the transfer function's `powf`.
fn srgb8_direct(c: f32) -> u8 {
    (srgb_encode(c) * 255.0).round() as u8
}

/// `srgb8_direct` by table, for the millions of values of an image (a
/// `powf` each took most of the time of writing a PNG): the byte at the
/// start of the value's bucket of bit patterns (its exponent and top
/// mantissa bits), raised past each byte's threshold (the least value
/// with that byte) the value reaches. Both tables come from
/// `srgb8_direct`, which never decreases as the value grows, so the bytes
/// are the same.
struct Srgb8 {
    /// Per bucket (`bits >> BUCKET_SHIFT` of a value in [0, 1]), the byte
    /// of its first value.
    base: Vec<u8>,
    /// `threshold[k]`: the least value in [0, 1] whose byte is at least k
    /// (`threshold[0]` is 0).
    threshold: [f32; 256],
}

const BUCKET_SHIFT: u32 = 16;

impl Srgb8 {
    fn get() -> &'static Srgb8 {
        static TABLE: std::sync::OnceLock<Srgb8> = std::sync::OnceLock::new();
        TABLE.get_or_init(|| {
            let one = 1.0f32.to_bits();
            let base = (0..=one >> BUCKET_SHIFT)
                .map(|b| srgb8_direct(f32::from_bits(b << BUCKET_SHIFT)))
                .collect();
            let mut threshold = [0.0; 256];
            for (k, t) in threshold.iter_mut().enumerate().skip(1) {
                // The least bit pattern in [0, 1] whose byte reaches k
                // (non-negative floats order as their bits).
                let (mut lo, mut hi) = (0u32, one);
                while lo < hi {
                    let mid = lo + (hi - lo) / 2;
                    if usize::from(srgb8_direct(f32::from_bits(mid))) >= k {
                        hi = mid;
                    } else {
                        lo = mid + 1;
                    }
                }
                *t = f32::from_bits(lo);
            }
            Srgb8 { base, threshold }
        })
    }

    #[inline]
    fn byte(&self, c: f32) -> u8 {
        // NaN, negatives and zero are 0 and values past 1 are 255, as
        // `srgb_encode` clamps them.
        if c.is_nan() || c <= 0.0 {
            return 0;
        }
        if c >= 1.0 {
            return 255;
        }
        let mut b = self.base[(c.to_bits() >> BUCKET_SHIFT) as usize];
        while b < 255 && c >= self.threshold[b as usize + 1] {
            b += 1;
        }
        b
    }
}

/// Writes linear pixels to `path` atomically in the format of its extension.
pub fn write_image(path: &Path, width: u32, height: u32, linear: &[[f32; 3]]) -> Result<()> {
    write_pixels(
        path,
        (width, height),
        || to_srgb8(linear),
        || Cow::Borrowed(linear),
    )
}

/// Writes a film's pixels (`write_image` of its `to_linear`, the same
/// bytes) to `path`, where the format takes 8-bit sRGB without making the
/// linear image first (`film_to_srgb8`).
pub fn write_film(path: &Path, film: &Film) -> Result<()> {
    write_pixels(
        path,
        (film.width, film.rows),
        || film_to_srgb8(film),
        || Cow::Owned(film.to_linear()),
    )
}

/// Writes an image atomically in the format of `path`'s extension, from
/// its 8-bit sRGB bytes or its linear pixels, whichever the format takes.
fn write_pixels<'a>(
    path: &Path,
    (width, height): (u32, u32),
    srgb8: impl FnOnce() -> Vec<u8>,
    linear: impl FnOnce() -> Cow<'a, [[f32; 3]]>,
) -> Result<()> {
    let format = OutputFormat::for_path(path)?;
    write_atomically(path, |file| {
        let mut w = BufWriter::new(file);
        let result = match format {
            OutputFormat::Png | OutputFormat::Ppm => {
                let img =
                    RgbImage::from_raw(width, height, srgb8()).ok_or("image size mismatch")?;
                if format == OutputFormat::Png {
                    img.write_to(&mut w, ImageFormat::Png)
                } else {
                    // `ImageFormat::Pnm` alone writes PAM (`P7`), which PPM
                    // readers refuse: ask for the binary pixmap, `P6`.
                    PnmEncoder::new(&mut w)
                        .with_subtype(PnmSubtype::Pixmap(SampleEncoding::Binary))
                        .write_image(img.as_raw(), width, height, ExtendedColorType::Rgb8)
                }
            }
            OutputFormat::Exr => {
                let data: Vec<f32> = linear().iter().flatten().copied().collect();
                let img =
                    Rgb32FImage::from_raw(width, height, data).ok_or("image size mismatch")?;
                img.write_to(&mut w, ImageFormat::OpenExr)
            }
        };
        result.map_err(|e| e.to_string())?;
        std::io::Write::flush(&mut w).map_err(|e| e.to_string())
    })
}

/// The folder a file path names its file in (`.` for a bare name): where
/// it is written, and what `cli` checks before a run.
pub fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The file a write to `path` replaces: `path`, or, where it is a symbolic
/// link, the file it points to (links of links followed, at most 40, the
/// kernel's own limit). The rename of `write_atomically` would otherwise
/// replace the link with a plain file and leave its target as it was,
/// which is not what writing to a link means anywhere else.
pub fn write_target(path: &Path) -> PathBuf {
    let mut p = path.to_path_buf();
    for _ in 0..40 {
        match std::fs::read_link(&p) {
            // A relative target is relative to the link's folder.
            Ok(t) => p = folder_of(&p).join(t),
            Err(_) => break,
        }
    }
    p
}

/// The temporary files `write_atomically` is writing, so that an interrupt
/// can remove them (`discard_unfinished`): a signal ends the process
/// without the destructors that remove them otherwise. A plain process-wide
/// list, not node state: only the command's own thread writes files.
static UNFINISHED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn unfinished() -> MutexGuard<'static, Vec<PathBuf>> {
    // A panic while the list was held left it consistent (one push or one
    // retain), so a poisoned lock is still good to use.
    UNFINISHED.lock().unwrap_or_else(|p| p.into_inner())
}

/// Removes the temporary files of writes still under way. The interrupt
/// handler (`main`) calls it before the process exits, so that Ctrl-C or a
/// SIGTERM in the middle of writing an image leaves no `.hypercast-*.tmp`
/// behind; files already renamed into place are whole and stay.
pub fn discard_unfinished() {
    for tmp in unfinished().drain(..) {
        let _ = std::fs::remove_file(tmp);
    }
}

/// Test only: the seconds `write_atomically` waits before its commit point,
/// announcing its temporary file on standard error, so that a test can
/// interrupt a write at a moment it knows.
const HOLD_ENV: &str = "HYPERCAST_TEST_HOLD_COMMIT";

/// Writes `path` through a temporary file in the same folder and a rename,
/// the commit point: until it, `path` is untouched, and a failure leaves
/// nothing behind (the temporary file is removed when dropped, or by
/// `discard_unfinished` when the process is interrupted).
pub fn write_atomically<F>(path: &Path, fill: F) -> Result<()>
where
    F: FnOnce(&mut std::fs::File) -> std::result::Result<(), String>,
{
    let err = |message: String| Error::Write {
        path: path.to_path_buf(),
        message,
    };
    let target = write_target(path);
    let dir = folder_of(&target);
    // Created and listed under the list's lock, and renamed and unlisted
    // under it too, so that an interrupt sees every temporary file that
    // exists and none that has become `path`.
    let mut tmp = {
        let mut list = unfinished();
        let tmp = tempfile::Builder::new()
            .prefix(".hypercast-")
            .suffix(".tmp")
            .tempfile_in(dir)
            .map_err(|e| {
                // tempfile's message ends with the random name it tried,
                // which tells the user nothing.
                let why = e.to_string();
                let why = why.split(" at path ").next().unwrap_or(&why);
                err(format!("cannot create a file in {}: {why}", dir.display()))
            })?;
        list.push(tmp.path().to_path_buf());
        tmp
    };
    let written = tmp.path().to_path_buf();
    let result = (|| {
        fill(tmp.as_file_mut()).map_err(err)?;
        tmp.as_file().sync_all().map_err(|e| err(e.to_string()))?;
        // Temporary files are created private; an output file is not.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let _ = tmp
                .as_file()
                .set_permissions(std::fs::Permissions::from_mode(0o644));
        }
        if let Some(secs) = std::env::var(HOLD_ENV).ok().and_then(|s| s.parse().ok()) {
            eprintln!("hypercast: holding {}", written.display());
            std::thread::sleep(std::time::Duration::from_secs_f64(secs));
        }
        let mut list = unfinished();
        list.retain(|p| *p != written);
        tmp.persist(&target).map_err(|e| err(e.error.to_string()))?;
        Ok(())
    })();
    if result.is_err() {
        // The temporary file is gone (dropped with its handle) or renamed.
        unfinished().retain(|p| *p != written);
    }
    result
}

/// A reference image as display values (sRGB-encoded, [0, 1]).
#[derive(Clone, Debug)]
pub struct DisplayImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
    /// True for 8-bit files (PNG, PPM): a render is compared after the same
    /// rounding to 8 bits, so an identical render has zero error.
    pub eight_bit: bool,
}

impl DisplayImage {
    /// Display values of linear pixels, rounded as this image was.
    pub fn comparable(&self, linear: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let d = to_display(linear);
        if self.eight_bit {
            d.into_iter()
                .map(|p| p.map(|c| (c * 255.0).round() / 255.0))
                .collect()
        } else {
            d
        }
    }
}

/// Reads an image as display values (sRGB-encoded, [0, 1]); EXR files are
/// linear and are encoded the same way as rendered pixels. Only a regular
/// file of at most `input::MAX_INPUT_BYTES` is read (`crate::input`); the
/// decoders' own limits (`image::Limits`) bound what decoding allocates.
pub fn read_display_image(path: &Path) -> Result<DisplayImage> {
    let file = crate::input::open(path)?;
    let refused = |e: image::ImageError| match e {
        image::ImageError::IoError(source) => Error::Read {
            path: path.to_path_buf(),
            source,
        },
        other => Error::Usage(format!("{}: not a readable image: {other}", path.display())),
    };
    // As `image::open` does: the format by the extension, none guessed.
    let format = ImageFormat::from_path(path).map_err(refused)?;
    let img = image::ImageReader::with_format(std::io::BufReader::new(file), format)
        .decode()
        .map_err(refused)?;
    let linear_file = matches!(OutputFormat::for_path(path), Ok(OutputFormat::Exr));
    let (w, h) = (img.width(), img.height());
    let px: Vec<[f32; 3]> = if linear_file {
        img.to_rgb32f()
            .pixels()
            .map(|p| p.0.map(srgb_encode))
            .collect()
    } else {
        img.to_rgb8()
            .pixels()
            .map(|p| p.0.map(|c| c as f32 / 255.0))
            .collect()
    };
    Ok(DisplayImage {
        width: w,
        height: h,
        pixels: px,
        eight_bit: !linear_file,
    })
}

/// Error of an image against a reference, on display values in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageMetrics {
    pub rmse: f64,
    /// Peak signal-to-noise ratio in dB (infinite for identical images).
    pub psnr: f64,
    pub max_error: f64,
}

/// Compares display values of equal size.
pub fn compare(image: &[[f32; 3]], reference: &[[f32; 3]]) -> ImageMetrics {
    let mut sum = 0.0f64;
    let mut max = 0.0f64;
    for (a, b) in image.iter().zip(reference) {
        for k in 0..3 {
            let d = (a[k] as f64 - b[k] as f64).abs();
            sum += d * d;
            max = max.max(d);
        }
    }
    let n = (image.len() * 3).max(1) as f64;
    let rmse = (sum / n).sqrt();
    let psnr = if rmse == 0.0 {
        f64::INFINITY
    } else {
        -20.0 * rmse.log10()
    };
    ImageMetrics {
        rmse,
        psnr,
        max_error: max,
    }
}

/// Linear values of display values (inverse of `to_display`).
pub fn from_display(display: &[[f32; 3]]) -> Vec<[f32; 3]> {
    display.iter().map(|p| p.map(srgb_decode)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_bytes_by_table_are_the_direct_ones() {
        let table = Srgb8::get();
        let one = 1.0f32.to_bits();
        // Every 61st bit pattern of [0, 1] (about 17 million values), each
        // threshold and its neighbours, and the clamped and odd values.
        let mut values: Vec<f32> = (0..=one).step_by(61).map(f32::from_bits).collect();
        for t in table.threshold {
            let b = t.to_bits();
            values.extend((b.saturating_sub(2)..=b + 2).map(f32::from_bits));
        }
        values.extend([
            -1.0,
            -0.0,
            1.0,
            1.5,
            f32::INFINITY,
            f32::NAN,
            f32::MIN_POSITIVE,
        ]);
        for c in values {
            assert_eq!(table.byte(c), srgb8_direct(c), "byte of {c:e}");
        }
    }

    /// A film written as it is gives the file its linear image gives, in
    /// every format: the conversion skips the linear image, not a step.
    #[test]
    fn a_film_is_written_as_its_linear_image_is() {
        let (w, h) = (37, 23);
        let mut film = Film::new(w, h);
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for p in 0..w * h {
            for _ in 0..3 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                // Radiances in [0, 2), some past white, and some black.
                let v = if x.is_multiple_of(7) {
                    0.0
                } else {
                    (x >> 11) as f64 / (1u64 << 52) as f64
                };
                film.add(p, crate::geom::Vec3::new(v, v * 0.5, 1.0 - v.min(1.0)));
            }
        }
        let dir = tempfile::tempdir().unwrap();
        for ext in ["png", "ppm", "exr"] {
            let (a, b) = (
                dir.path().join(format!("a.{ext}")),
                dir.path().join(format!("b.{ext}")),
            );
            write_film(&a, &film).unwrap();
            write_image(&b, w, h, &film.to_linear()).unwrap();
            let (a, b) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
            assert!(a == b, "{ext}: the files differ");
        }
    }

    #[test]
    fn srgb_round_trips() {
        for v in [0.0f32, 0.001, 0.2, 0.5, 1.0] {
            assert!((srgb_decode(srgb_encode(v)) - v).abs() < 1e-5);
        }
    }

    #[test]
    fn identical_images_have_infinite_psnr() {
        let a = vec![[0.1, 0.2, 0.3]; 4];
        let m = compare(&a, &a);
        assert_eq!(m.rmse, 0.0);
        assert!(m.psnr.is_infinite());
        let b = vec![[0.1, 0.2, 0.4]; 4];
        let m = compare(&a, &b);
        assert!((m.max_error - 0.1).abs() < 1e-6);
    }

    #[test]
    fn unknown_extension_is_refused_before_anything_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.jpg");
        assert!(write_image(&p, 1, 1, &[[0.0; 3]]).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
