//! The `quality` experiment's results: each point's knobs, run time and
//! error; the Pareto front; the model's error (predicted virtual time
//! against measured wall time); and their printed table, CSV file and plot
//! (error against time on log-log axes). Reads measurements; never traces.

use std::io::Write;
use std::path::Path;

use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::render::Adaptive;

use super::ImageMetrics;
use super::image_io::write_atomically;

/// The settings of one quality point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Knobs {
    /// Samples per pixel of the first (or only) pass.
    pub spp: u32,
    pub adaptive: Option<Adaptive>,
    /// Reflection/refraction recursion limit.
    pub max_depth: u32,
}

impl Knobs {
    /// Which sweep the point belongs to: `spp`, `adaptive` or `depth`.
    pub fn family(&self, scene_depth: u32) -> &'static str {
        if self.adaptive.is_some() {
            "adaptive"
        } else if self.max_depth != scene_depth {
            "depth"
        } else {
            "spp"
        }
    }

    /// A short description, e.g. `spp 1 + 16 where > 0.05, depth 3`.
    pub fn label(&self) -> String {
        let aa = match self.adaptive {
            None => String::new(),
            Some(a) => format!(" + {} where > {}", a.extra_spp, a.threshold),
        };
        format!("spp {}{aa}, depth {}", self.spp, self.max_depth)
    }
}

/// One measured point of the sweep.
#[derive(Clone, Debug)]
pub struct Point {
    pub knobs: Knobs,
    pub family: &'static str,
    pub wall_seconds: f64,
    pub virtual_seconds: Option<f64>,
    pub metrics: ImageMetrics,
    /// Primary samples over all passes, and the image's pixels.
    pub samples: u64,
    pub pixels: u64,
    pub refined_pixels: u64,
    pub rays: u64,
    /// No other point is both at least as fast and at least as accurate
    /// (and strictly better in one).
    pub pareto: bool,
}

impl Point {
    /// The model's error for this point: the predicted virtual time
    /// against the measured wall time, when a machine rendered it.
    pub fn model_error(&self) -> Option<f64> {
        self.virtual_seconds
            .map(|v| relative_error(v, self.wall_seconds))
    }
}

/// `(predicted - measured) / measured`: positive when the model is slow.
pub fn relative_error(predicted: f64, measured: f64) -> f64 {
    (predicted - measured) / measured
}

/// Marks the points that no other point dominates in (time, RMSE).
pub fn mark_pareto(points: &mut [Point]) {
    let key = |p: &Point| (p.wall_seconds, p.metrics.rmse);
    for i in 0..points.len() {
        let (t, e) = key(&points[i]);
        points[i].pareto = !points.iter().any(|q| {
            let (tq, eq) = key(q);
            tq <= t && eq <= e && (tq < t || eq < e)
        });
    }
}

/// The model's error over the points a machine rendered, in words:
/// `n/a (machine not available)` until a point carries virtual time.
pub fn model_summary(points: &[Point]) -> String {
    let errs: Vec<f64> = points.iter().filter_map(Point::model_error).collect();
    if errs.is_empty() {
        return "n/a (machine not available)".into();
    }
    let mean = errs.iter().map(|e| e.abs()).sum::<f64>() / errs.len() as f64;
    let worst = errs
        .iter()
        .fold(0.0f64, |w, e| if e.abs() > w.abs() { *e } else { w });
    format!(
        "mean |relative error| {:.1}%, worst {:+.1}%, over {} points",
        100.0 * mean,
        100.0 * worst,
        errs.len()
    )
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map(|v| format!("{v:.digits$}")).unwrap_or_default()
}

/// The table printed by `quality`, as Markdown (fastest first).
pub fn table(points: &[Point]) -> String {
    let mut rows: Vec<&Point> = points.iter().collect();
    rows.sort_by(|a, b| a.wall_seconds.total_cmp(&b.wall_seconds));
    let mut s = String::from(
        "| knobs | family | samples/px | wall s | virtual s | RMSE | PSNR dB | max error | Pareto |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for p in rows {
        let px = p.samples as f64 / p.pixels.max(1) as f64;
        s += &format!(
            "| {} | {} | {:.2} | {:.3} | {} | {:.5} | {:.2} | {:.4} | {} |\n",
            p.knobs.label(),
            p.family,
            px,
            p.wall_seconds,
            opt(p.virtual_seconds, 3),
            p.metrics.rmse,
            p.metrics.psnr,
            p.metrics.max_error,
            if p.pareto { "*" } else { "" }
        );
    }
    s
}

/// The CSV of the points, in sweep order, one header line.
pub fn csv(points: &[Point]) -> String {
    let mut s = String::from(
        "family,spp,aa_threshold,aa_extra_spp,max_depth,samples,refined_pixels,rays,\
         wall_seconds,virtual_seconds,model_relative_error,rmse,psnr,max_error,pareto\n",
    );
    for p in points {
        let k = &p.knobs;
        s += &format!(
            "{},{},{},{},{},{},{},{},{:.6},{},{},{:.8},{},{:.8},{}\n",
            p.family,
            k.spp,
            opt(k.adaptive.map(|a| a.threshold), 4),
            k.adaptive
                .map(|a| a.extra_spp.to_string())
                .unwrap_or_default(),
            k.max_depth,
            p.samples,
            p.refined_pixels,
            p.rays,
            p.wall_seconds,
            opt(p.virtual_seconds, 6),
            opt(p.model_error(), 6),
            p.metrics.rmse,
            // JSON and CSV readers choke on "inf": leave it empty.
            opt(Some(p.metrics.psnr).filter(|x| x.is_finite()), 4),
            p.metrics.max_error,
            p.pareto
        );
    }
    s
}

/// Writes `csv(points)` to `path` atomically.
pub fn write_csv(path: &Path, points: &[Point]) -> Result<()> {
    let text = csv(points);
    write_atomically(path, |f| {
        f.write_all(text.as_bytes()).map_err(|e| e.to_string())
    })
}

/// The plot's size in pixels.
const PLOT_SIZE: (u32, u32) = (900, 640);

/// The plot's font: DejaVu Sans cut down to ASCII (`assets/fonts/`),
/// compiled in, so that plots need no system fonts.
static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-ASCII.ttf");

/// Writes the plot of error against wall time (log-log) to `path` (PNG),
/// atomically: each family's points, and the Pareto front as a line
/// through ringed points.
pub fn write_plot(path: &Path, title: &str, points: &[Point]) -> Result<()> {
    let err = |message: String| Error::Write {
        path: path.to_path_buf(),
        message,
    };
    let (w, h) = PLOT_SIZE;
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    draw_plot(&mut buf, title, points).map_err(err)?;
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| err("plot size".into()))?;
    write_atomically(path, |f| {
        let mut out = std::io::BufWriter::new(f);
        img.write_to(&mut out, image::ImageFormat::Png)
            .map_err(|e| e.to_string())?;
        out.flush().map_err(|e| e.to_string())
    })
}

/// A log axis range holding `values`: from the power of ten below them
/// (plotters labels a log axis from its first power of ten on), at least
/// a decade long, a little past the largest.
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return 0.1..1.0;
    }
    let decade = 10f64.powf(lo.log10().floor());
    // A hair below the power of ten: plotters finds its first label by
    // rounding a logarithm up, which rounding error can push a decade on.
    decade * 0.999..(hi * 1.3).max(decade * 10.0)
}

/// A tick label with two significant digits and no float noise
/// (0.30000000000000004 reads 0.3).
fn tick(v: f64) -> String {
    if v <= 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (1 - v.log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Family colours and order in the legend.
const FAMILIES: [(&str, RGBColor); 3] = [
    ("spp", RGBColor(31, 119, 180)),
    ("adaptive", RGBColor(255, 127, 14)),
    ("depth", RGBColor(44, 160, 44)),
];

fn draw_plot(buf: &mut [u8], title: &str, points: &[Point]) -> std::result::Result<(), String> {
    // Registering is idempotent; the font is ours, so it parses.
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
        .map_err(|_| "the bundled plot font does not parse".to_string())?;
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let root = BitMapBackend::with_buffer(buf, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    // Zero error (a point equal to the reference) has no place on a log
    // axis: it is drawn at the axis' floor.
    let xr = log_range(points.iter().map(|p| p.wall_seconds));
    let yr = log_range(points.iter().map(|p| p.metrics.rmse));
    let floor = yr.start;
    let y = |p: &Point| p.metrics.rmse.max(floor);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(xr.log_scale(), yr.log_scale())
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("wall time (s)")
        .y_desc("RMSE against the reference (display values)")
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 16))
        .x_labels(12)
        .y_labels(12)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(|x| e(&x))?;
    for (family, color) in FAMILIES {
        let pts: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.family == family)
            .map(|p| (p.wall_seconds, y(p)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        // The spp and adaptive sweeps are series (more samples, lower
        // threshold): join them in sweep order; depth points stand alone.
        if family != "depth" {
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), color.mix(0.5)))
                .map_err(|x| e(&x))?;
        }
        chart
            .draw_series(pts.iter().map(|&xy| Circle::new(xy, 5, color.filled())))
            .map_err(|x| e(&x))?
            .label(family)
            .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
    }
    let mut front: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| p.pareto)
        .map(|p| (p.wall_seconds, y(p)))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart
        .draw_series(LineSeries::new(
            front.iter().copied(),
            BLACK.stroke_width(2),
        ))
        .map_err(|x| e(&x))?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new([(x - 10, y), (x + 10, y)], BLACK.stroke_width(2)));
    chart
        .draw_series(
            front
                .iter()
                .map(|&xy| Circle::new(xy, 9, BLACK.stroke_width(2))),
        )
        .map_err(|x| e(&x))?;
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(t: f64, e: f64) -> Point {
        Point {
            knobs: Knobs {
                spp: 1,
                adaptive: None,
                max_depth: 5,
            },
            family: "spp",
            wall_seconds: t,
            virtual_seconds: None,
            metrics: ImageMetrics {
                rmse: e,
                psnr: 0.0,
                max_error: 0.0,
            },
            samples: 0,
            pixels: 1,
            refined_pixels: 0,
            rays: 0,
            pareto: false,
        }
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let mut p = vec![
            point(1.0, 0.10),
            point(2.0, 0.05),
            point(2.5, 0.07), // slower and worse than (2.0, 0.05)
            point(4.0, 0.01),
            point(4.0, 0.01), // a tie dominates neither
        ];
        mark_pareto(&mut p);
        let front: Vec<bool> = p.iter().map(|p| p.pareto).collect();
        assert_eq!(front, vec![true, true, false, true, true]);
    }

    #[test]
    fn model_error_is_relative_to_the_measured_time() {
        assert!((relative_error(1.5, 1.0) - 0.5).abs() < 1e-12);
        assert!((relative_error(0.8, 1.0) + 0.2).abs() < 1e-12);
        let mut p = point(2.0, 0.1);
        assert_eq!(p.model_error(), None);
        p.virtual_seconds = Some(3.0);
        assert!((p.model_error().unwrap() - 0.5).abs() < 1e-12);
    }
}
