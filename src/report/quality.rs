//! The `quality` experiment's results: each point's knobs, run time and
//! error; the Pareto front; the model's error (virtual time predicted on a
//! host-calibrated topology against the measured wall time of the same
//! machine run); and their printed tables, CSV file and plot (error
//! against time on log-log axes). Reads measurements; never traces.

use std::io::Write;
use std::path::Path;

use plotters::coord::combinators::WithKeyPoints;
use plotters::prelude::*;

use crate::error::Result;
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

/// One measured render of the sweep: a point of the error-against-time
/// curve (on this host's threads), or a run of the model's error (on the
/// hypercube machine with a host-calibrated topology).
#[derive(Clone, Debug)]
pub struct Point {
    pub knobs: Knobs,
    pub family: &'static str,
    /// The machine's dimension for a run of the model's error; None for
    /// a render on this host's threads.
    pub dimension: Option<u32>,
    /// Host threads: the render's wall time. Machine: the wall time of
    /// the span virtual time models, from loading the nodes to the last
    /// finished sample (`MachineStats::run_seconds`: the host's plan,
    /// which the model does not time, left out).
    pub wall_seconds: f64,
    /// The modelled machine's predicted makespan, for a machine run.
    pub virtual_seconds: Option<f64>,
    /// CPU seconds the process spent over `wall_seconds`, for a machine
    /// run: divided by the wall time, the cores the run really had, which
    /// the model assumes are one per node.
    pub cpu_seconds: Option<f64>,
    pub metrics: ImageMetrics,
    /// Primary samples over all passes, and the image's pixels.
    pub samples: u64,
    pub pixels: u64,
    pub refined_pixels: u64,
    pub rays: u64,
    /// No other host-thread point is both at least as fast and at least
    /// as accurate (and strictly better in one). Never set on machine runs.
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

/// Marks the host-thread points that no other host-thread point
/// dominates in (time, RMSE); machine runs are a measure of the model, not
/// points of the curve.
pub fn mark_pareto(points: &mut [Point]) {
    let key = |p: &Point| (p.wall_seconds, p.metrics.rmse);
    let curve: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| p.dimension.is_none())
        .map(key)
        .collect();
    for p in points.iter_mut() {
        let (t, e) = key(p);
        p.pareto = p.dimension.is_none()
            && !curve
                .iter()
                .any(|&(tq, eq)| tq <= t && eq <= e && (tq < t || eq < e));
    }
}

/// The model's error over the machine runs, per dimension, in words:
/// `d 0: mean |error| 4.1%, from -6.0% to +2.3% over 3 runs; d 1: ...`,
/// or `n/a (no machine runs)`.
pub fn model_summary(points: &[Point]) -> String {
    let mut dims: Vec<u32> = points.iter().filter_map(|p| p.dimension).collect();
    dims.sort_unstable();
    dims.dedup();
    let parts: Vec<String> = dims
        .iter()
        .filter_map(|&d| {
            let errs: Vec<f64> = points
                .iter()
                .filter(|p| p.dimension == Some(d))
                .filter_map(Point::model_error)
                .collect();
            if errs.is_empty() {
                return None;
            }
            let mean = errs.iter().map(|e| e.abs()).sum::<f64>() / errs.len() as f64;
            let lo = errs.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = errs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            Some(format!(
                "d {d}: mean |error| {:.1}%, from {:+.1}% to {:+.1}% over {} runs",
                100.0 * mean,
                100.0 * lo,
                100.0 * hi,
                errs.len()
            ))
        })
        .collect();
    if parts.is_empty() {
        "n/a (no machine runs)".into()
    } else {
        parts.join("; ")
    }
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map(|v| format!("{v:.digits$}")).unwrap_or_default()
}

/// The table of error against time printed by `quality`, as Markdown:
/// the host-thread points, fastest first.
pub fn table(points: &[Point]) -> String {
    let mut rows: Vec<&Point> = points.iter().filter(|p| p.dimension.is_none()).collect();
    rows.sort_by(|a, b| a.wall_seconds.total_cmp(&b.wall_seconds));
    let mut s = String::from(
        "| knobs | family | samples/px | wall s | RMSE | PSNR dB | max error | Pareto |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for p in rows {
        let px = p.samples as f64 / p.pixels.max(1) as f64;
        s += &format!(
            "| {} | {} | {:.2} | {:.3} | {:.5} | {:.2} | {:.4} | {} |\n",
            p.knobs.label(),
            p.family,
            px,
            p.wall_seconds,
            p.metrics.rmse,
            p.metrics.psnr,
            p.metrics.max_error,
            if p.pareto { "*" } else { "" }
        );
    }
    s
}

/// The table of the model's error printed by `quality`, as Markdown: the
/// machine runs by dimension, in sweep order.
pub fn model_table(points: &[Point]) -> String {
    let mut rows: Vec<&Point> = points.iter().filter(|p| p.dimension.is_some()).collect();
    rows.sort_by_key(|p| p.dimension);
    let mut s = String::from(
        "| knobs | d | nodes | machine wall s | virtual s | model error | cores busy |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for p in rows {
        let d = p.dimension.unwrap_or(0);
        s += &format!(
            "| {} | {d} | {} | {:.3} | {} | {} | {} |\n",
            p.knobs.label(),
            1u64 << d,
            p.wall_seconds,
            opt(p.virtual_seconds, 3),
            p.model_error()
                .map(|e| format!("{:+.1}%", 100.0 * e))
                .unwrap_or_default(),
            opt(p.cpu_seconds.map(|c| c / p.wall_seconds), 2),
        );
    }
    s
}

/// The CSV of every render, in sweep order, one header line: the host
/// points (empty `dimension`), then the machine runs of the model's error
/// (`dimension` set, `wall_seconds` the machine's span, `virtual_seconds`
/// and `model_relative_error` filled).
pub fn csv(points: &[Point]) -> String {
    let mut s = String::from(
        "family,spp,aa_threshold,aa_extra_spp,max_depth,dimension,samples,refined_pixels,rays,\
         wall_seconds,virtual_seconds,model_relative_error,cpu_seconds,rmse,psnr,max_error,pareto\n",
    );
    for p in points {
        let k = &p.knobs;
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{:.6},{},{},{},{:.8},{},{:.8},{}\n",
            p.family,
            k.spp,
            opt(k.adaptive.map(|a| a.threshold), 4),
            k.adaptive
                .map(|a| a.extra_spp.to_string())
                .unwrap_or_default(),
            k.max_depth,
            p.dimension.map(|d| d.to_string()).unwrap_or_default(),
            p.samples,
            p.refined_pixels,
            p.rays,
            p.wall_seconds,
            opt(p.virtual_seconds, 6),
            opt(p.model_error(), 6),
            opt(p.cpu_seconds, 6),
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

/// Writes the plot of error against wall time (log-log) to `path` (PNG),
/// atomically: each family's host-thread points, and the Pareto front as
/// a line through ringed points.
pub fn write_plot(path: &Path, title: &str, points: &[Point]) -> Result<()> {
    super::plot::write_png(path, PLOT_SIZE, |buf| draw_plot(buf, title, points))
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

/// A log axis over `r`, ticked by `plot::log_ticks`.
fn log_axis(r: &std::ops::Range<f64>) -> WithKeyPoints<LogCoord<f64>> {
    let (bold, light) = super::plot::log_ticks(r.start, r.end);
    r.clone()
        .log_scale()
        .with_key_points(bold)
        .with_light_points(light)
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
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let curve: Vec<Point> = points
        .iter()
        .filter(|p| p.dimension.is_none())
        .cloned()
        .collect();
    let points = &curve[..];
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
        .build_cartesian_2d(log_axis(&xr), log_axis(&yr))
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
            dimension: None,
            wall_seconds: t,
            virtual_seconds: None,
            cpu_seconds: None,
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

    #[test]
    fn machine_runs_are_summed_up_per_dimension_and_stay_off_the_front() {
        let run = |d: u32, wall: f64, virt: f64| Point {
            dimension: Some(d),
            virtual_seconds: Some(virt),
            cpu_seconds: Some(wall),
            ..point(wall, 0.01)
        };
        let mut p = vec![
            point(1.0, 0.10),
            run(0, 0.5, 0.4),
            run(0, 2.0, 2.2),
            run(1, 1.0, 1.5),
        ];
        assert_eq!(model_summary(&p[..1]), "n/a (no machine runs)");
        assert_eq!(
            model_summary(&p),
            "d 0: mean |error| 15.0%, from -20.0% to +10.0% over 2 runs; \
             d 1: mean |error| 50.0%, from +50.0% to +50.0% over 1 runs"
        );
        // The fast, accurate machine run dominates nothing.
        mark_pareto(&mut p);
        let front: Vec<bool> = p.iter().map(|p| p.pareto).collect();
        assert_eq!(front, vec![true, false, false, false]);
        let t = table(&p);
        assert_eq!(t.lines().count(), 3, "{t}");
        let m = model_table(&p);
        assert_eq!(m.lines().count(), 5, "{m}");
        assert!(
            m.contains("| spp 1, depth 5 | 1 | 2 | 1.000 | 1.500 | +50.0% | 1.00 |"),
            "{m}"
        );
        let c = csv(&p);
        let last = c.lines().last().unwrap();
        assert!(last.starts_with("spp,1,,,5,1,"), "{last}");
        assert!(
            last.contains(",1.000000,1.500000,0.500000,1.000000,"),
            "{last}"
        );
    }
}
