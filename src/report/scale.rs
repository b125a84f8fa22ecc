//! The scaling experiment (`hypercast scale`): one machine render per
//! hypercube dimension, with the balanced mapping (`--repeat` rounds of
//! every dimension; times are medians, speedups the median of each
//! round's ratio) and once with the naive equal-area mapping, so that the
//! load balance can be judged; a table, `scaling.csv` and `scaling.png`
//! (speedup and efficiency, wall and virtual, against node count). Every
//! render's image is checked to equal the first one's, bit for bit.

use std::fmt::Write as _;
use std::path::Path;

use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::image_io::write_atomically;
use crate::error::{Error, Refusal, Result};
use crate::machine::message::NodeReport;
use crate::machine::{self, MachineOptions, MachineStats, Mapping, Topology};
use crate::scene::Scene;
use crate::trace::Film;

/// One dimension's results.
#[derive(Clone, Debug)]
pub struct ScaleRow {
    pub dimension: u32,
    pub nodes: usize,
    /// Medians over the repeats (balanced mapping); speedups (and so
    /// efficiencies) are the median over the rounds of the ratio to the
    /// first (smallest) dimension's run of the same round.
    pub wall_seconds: f64,
    pub virtual_seconds: f64,
    pub speedup_wall: f64,
    pub efficiency_wall: f64,
    pub speedup_virtual: f64,
    pub efficiency_virtual: f64,
    pub messages: u64,
    pub message_bytes: u64,
    pub hops: u64,
    /// Busy-time imbalance (max/mean) measured with each mapping, and as
    /// the pre-pass predicted it for the balanced one.
    pub imbalance_balanced: f64,
    pub imbalance_equal_area: f64,
    pub predicted_imbalance: f64,
    pub virtual_seconds_equal_area: f64,
    pub peak_memory_bytes: u64,
    pub budget_bytes: u64,
    /// Rays created (every one finished once), and the bytes on the wire
    /// per ray.
    pub rays: u64,
    pub bytes_per_ray: f64,
    /// The cell structure held over all nodes (`NodeReport::structure_bytes`
    /// summed), and its ratio to the whole structure's (one node's at
    /// d = 0): what distributing the cells costs in memory.
    pub structure_bytes: u64,
    pub structure_ratio: f64,
    /// The largest node's intersection tests against the mean: a measure
    /// of the balance that, unlike busy time, does not move with the
    /// host's load (busy time follows it closely, not exactly).
    pub imbalance_tests: f64,
    /// The same for the work the balanced mapping evens out: cells
    /// entered and `cells::TEST_WORK` per test (`machine::mapping`).
    pub imbalance_work: f64,
    /// Where the virtual efficiency goes (`EfficiencyFactors`), medians
    /// over the rounds.
    pub factors: EfficiencyFactors,
    /// The share of the host's cores the nodes had while they ran
    /// (`MachineStats::host_share`), median over the rounds: well under 1,
    /// other work on the host made the wall times unfit to compare.
    pub host_share: Option<f64>,
    /// Where the default placement put the whole scene on every node, as
    /// the distributed plan would have left most nodes idle: that plan's
    /// predicted imbalance (`MachineStats::whole_for`).
    pub whole_for: Option<f64>,
}

/// A run's virtual efficiency against the first dimension's run of the
/// same round, taken apart into three factors, so that a user can tell
/// what distributing the work costs the modelled machine from what the
/// emulation adds. For one pair of runs the efficiency is exactly
/// `utilisation / base utilisation / (work_ratio * cost_ratio)` (the
/// first run's utilisation is about 1: one node never waits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EfficiencyFactors {
    /// The work all nodes did (cells entered and `cells::TEST_WORK` per
    /// intersection test, the units the balanced mapping evens out), over
    /// the first run's: what distribution adds to the algorithm's work (a
    /// ray that moves to another node resumes its walk there, past that
    /// node's cold mailboxes).
    pub work_ratio: f64,
    /// The nodes' computing time (host CPU seconds) per unit of that work,
    /// over the first run's. This is the emulation's, not the model's: the
    /// node threads take turns in the host's caches and see rays from
    /// everywhere instead of in pixel order, where a node of the modelled
    /// machine has its own processor and memory.
    pub cost_ratio: f64,
    /// The share of the modelled machine's node time (nodes times virtual
    /// seconds) that its nodes spent computing; the rest went to sending,
    /// waiting (for paths in transit, for credit, for the bounded lag) and
    /// idling at the end while the slowest node finished.
    pub utilisation: f64,
    /// The share of that node time spent waiting: for paths in transit,
    /// for credit, and at the end. Not a factor of the efficiency: the
    /// rest of the node time, `1 - utilisation - waiting`, is the link
    /// model's sending (`message_overhead` and bytes over bandwidth).
    pub waiting: f64,
}

impl EfficiencyFactors {
    /// The factors of `run` against `base`, for a topology of compute speed
    /// `speed` (virtual seconds are host seconds over it).
    pub fn of(run: &MachineStats, base: &MachineStats, speed: f64) -> EfficiencyFactors {
        let work = |r: &MachineStats| -> f64 { r.per_node.iter().map(counted_work).sum() };
        let (w, w0) = (work(run), work(base));
        EfficiencyFactors {
            work_ratio: w / w0,
            cost_ratio: (busy(run) / w) / (busy(base) / w0),
            utilisation: utilisation(run, speed),
            waiting: waiting(run),
        }
    }
}

/// A node's counted work: cells entered and `cells::TEST_WORK` per test,
/// the units the balanced mapping evens out (`machine::mapping`).
fn counted_work(n: &NodeReport) -> f64 {
    (crate::cells::CELL_WORK * n.cells_visited + crate::cells::TEST_WORK * n.intersection_tests)
        as f64
}

/// The share of a run's node time (nodes times virtual seconds) its nodes
/// spent computing (`EfficiencyFactors::utilisation`).
fn utilisation(r: &MachineStats, speed: f64) -> f64 {
    busy(r) / speed / (r.per_node.len() as f64 * r.virtual_seconds)
}

/// The share of a run's node time its nodes spent waiting
/// (`EfficiencyFactors::waiting`).
fn waiting(r: &MachineStats) -> f64 {
    let waited: f64 = r.per_node.iter().map(|n| n.waiting_seconds).sum();
    waited / (r.per_node.len() as f64 * r.virtual_seconds)
}

/// The host CPU seconds all of a run's nodes spent computing.
fn busy(r: &MachineStats) -> f64 {
    r.per_node.iter().map(|n| n.busy_seconds).sum()
}

/// Parses `--dims`: `A..B` (inclusive) or a list `0,2,5`, into ascending
/// order. A dimension given twice is refused, naming it: the second run
/// would only repeat a row of the table (`--repeat` is how to measure a
/// dimension again). The order is ascending whatever the list's, because
/// speedups and efficiencies are taken against the first dimension's runs
/// (`measure`): that must be the smallest, or `1,0` measured one node
/// against two.
pub fn parse_dims(s: &str) -> std::result::Result<Vec<u32>, String> {
    let bad = || format!("--dims: expected a range like 0..5 or a list like 0,2,5, got {s:?}");
    let mut dims: Vec<u32> = if let Some((a, b)) = s.split_once("..") {
        let a: u32 = a.trim().parse().map_err(|_| bad())?;
        let b: u32 = b
            .trim_start_matches('=')
            .trim()
            .parse()
            .map_err(|_| bad())?;
        if a > b {
            return Err(bad());
        }
        (a..=b).collect()
    } else {
        s.split(',')
            .map(|x| x.trim().parse().map_err(|_| bad()))
            .collect::<std::result::Result<_, _>>()?
    };
    if dims.is_empty() {
        return Err(bad());
    }
    dims.sort_unstable();
    if let Some(w) = dims.windows(2).find(|w| w[0] == w[1]) {
        return Err(format!(
            "--dims: {} is given more than once; name each dimension once (--repeat runs them again)",
            w[0]
        ));
    }
    if let Some(d) = dims.iter().find(|&&d| d > machine::topology::MAX_DIMENSION) {
        return Err(format!(
            "--dims: {d} is more than the largest dimension, {}",
            machine::topology::MAX_DIMENSION
        ));
    }
    Ok(dims)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Runs the experiment over `dims`, strictly ascending as `parse_dims`
/// gives them (anything else is refused as a usage error): speedups are
/// against the first, so the smallest. `progress(done, total)` counts
/// renders.
pub fn measure(
    scene: &Scene,
    topo: &Topology,
    dims: &[u32],
    repeat: u32,
    opts: &MachineOptions,
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<ScaleRow>> {
    if !dims.is_sorted_by(|a, b| a < b) {
        return Err(Error::Usage(format!(
            "--dims: the dimensions must be distinct and ascending, got {dims:?}"
        )));
    }
    let total = dims.len() * (repeat.max(1) as usize + 1);
    let mut done = 0;
    let mut first: Option<Film> = None;
    let mut rows: Vec<ScaleRow> = Vec::new();
    // The whole structure's bytes: what one node holds (the structure a
    // single node builds, all of it its own). No pre-pass is needed for
    // that, so no plan.
    let whole_structure = {
        let one_node = crate::cells::CellOptions {
            min_super_cells: 0,
            ..opts.cells
        };
        let cs = crate::cells::CellStructure::build(scene, opts.width, opts.height, one_node)?;
        cs.restrict(scene, &|_, _| true).0.bytes() as u64
    };
    let mut check = |film: &Film, d: u32| -> Result<()> {
        match &first {
            None => first = Some(film.clone()),
            Some(f) if f.sums() != film.sums() => {
                return Err(Error::Render(format!(
                    "the image at --dim {d} differs from the first one: the machine broke exactness"
                )));
            }
            Some(_) => {}
        }
        Ok(())
    };
    // Rounds, not dimensions, outermost: each round renders every
    // dimension once, so the runs compared in a speedup are minutes apart
    // at most, not the whole experiment. The host's speed drifts by a
    // fifth over a minute on a shared machine, and dimension after
    // dimension that drift went straight into the ratios.
    let machines: Vec<Topology> = dims
        .iter()
        .map(|&d| topo.clone().with_overrides(Some(d), None))
        .collect::<Result<_>>()?;
    let naive = MachineOptions {
        mapping: Mapping::EqualArea,
        ..opts.clone()
    };
    // A dimension whose shares do not fit is named (the machine's message
    // names the node and the memory it needs).
    let at_d = |d: u32| {
        move |e: Error| match e {
            Error::Capacity(r) => Error::Capacity(Refusal {
                among_dims: Some(d),
                ..r
            }),
            Error::Render(m) => Error::Render(format!("at d = {d}: {m}")),
            e => e,
        }
    };
    // One render, checked against the first and counted.
    let mut run = |d: u32, t: &Topology, o: &MachineOptions| -> Result<MachineStats> {
        let (film, stats, _) = machine::render(scene, t, o, &|_| {}).map_err(at_d(d))?;
        check(&film, d)?;
        done += 1;
        progress(done, total);
        Ok(stats)
    };
    let mut runs: Vec<Vec<MachineStats>> = vec![Vec::new(); dims.len()];
    let mut equal_area: Vec<MachineStats> = Vec::new();
    for round in 0..repeat.max(1) {
        for ((&d, t), of_d) in dims.iter().zip(&machines).zip(&mut runs) {
            of_d.push(run(d, t, opts)?);
            // The equal-area mapping once, in the first round: a share
            // that does not fit it stops the experiment there, not after
            // every round.
            if round == 0 {
                equal_area.push(run(d, t, &naive)?);
            }
        }
    }
    let Some(base) = runs.first() else {
        return Ok(rows);
    };
    let cores = crate::trace::host_cores();
    for (((&d, t), of_d), eq) in dims.iter().zip(&machines).zip(&runs).zip(&equal_area) {
        let wall = median(of_d.iter().map(|r| r.wall_seconds).collect());
        let virt = median(of_d.iter().map(|r| r.virtual_seconds).collect());
        // Counts are the same every run but the busy times are not: the
        // run nearest the median wall time stands for the rest.
        let rep = of_d
            .iter()
            .min_by(|a, b| {
                (a.wall_seconds - wall)
                    .abs()
                    .total_cmp(&(b.wall_seconds - wall).abs())
            })
            .expect("repeat.max(1) runs were made");
        // Speedups are the median of each round's ratio to the first
        // dimension's run of the same round.
        let ratio = |of: fn(&MachineStats) -> f64| {
            median(
                of_d.iter()
                    .zip(base)
                    .map(|(r, r0)| of(r0) / of(r))
                    .collect(),
            )
        };
        let (speedup_wall, speedup_virtual) =
            (ratio(|r| r.wall_seconds), ratio(|r| r.virtual_seconds));
        let per_round: Vec<EfficiencyFactors> = of_d
            .iter()
            .zip(base)
            .map(|(r, r0)| EfficiencyFactors::of(r, r0, t.compute_speed))
            .collect();
        let factor = |f: fn(&EfficiencyFactors) -> f64| median(per_round.iter().map(f).collect());
        let factors = EfficiencyFactors {
            work_ratio: factor(|f| f.work_ratio),
            cost_ratio: factor(|f| f.cost_ratio),
            utilisation: factor(|f| f.utilisation),
            waiting: factor(|f| f.waiting),
        };
        let nodes = 1usize << d;
        let scale = nodes as f64 / (1usize << dims[0]) as f64;
        let structure_bytes: u64 = rep.per_node.iter().map(|n| n.structure_bytes).sum();
        rows.push(ScaleRow {
            dimension: d,
            nodes,
            wall_seconds: wall,
            virtual_seconds: virt,
            speedup_wall,
            efficiency_wall: speedup_wall / scale,
            speedup_virtual,
            efficiency_virtual: speedup_virtual / scale,
            messages: rep.messages,
            message_bytes: rep.message_bytes,
            hops: rep.hops,
            imbalance_balanced: rep.imbalance,
            imbalance_equal_area: eq.imbalance,
            predicted_imbalance: rep.predicted_imbalance,
            virtual_seconds_equal_area: eq.virtual_seconds,
            peak_memory_bytes: rep
                .per_node
                .iter()
                .map(|n| n.peak_memory_bytes)
                .max()
                .unwrap_or(0),
            budget_bytes: t.node_memory,
            rays: rep.rays.total(),
            bytes_per_ray: rep.message_bytes as f64 / rep.rays.total().max(1) as f64,
            structure_bytes,
            structure_ratio: structure_bytes as f64 / whole_structure.max(1) as f64,
            imbalance_tests: machine::max_over_mean(
                rep.per_node.iter().map(|n| n.intersection_tests as f64),
            ),
            imbalance_work: machine::max_over_mean(rep.per_node.iter().map(counted_work)),
            factors,
            host_share: of_d
                .iter()
                .map(|r| r.host_share(cores))
                .collect::<Option<Vec<f64>>>()
                .map(median),
            whole_for: rep.whole_for,
        });
    }
    Ok(rows)
}

const HEADER: [&str; 30] = [
    "dimension",
    "nodes",
    "wall_seconds",
    "virtual_seconds",
    "speedup_wall",
    "efficiency_wall",
    "speedup_virtual",
    "efficiency_virtual",
    "messages",
    "message_bytes",
    "hops",
    "imbalance_balanced",
    "imbalance_equal_area",
    "predicted_imbalance",
    "virtual_seconds_equal_area",
    "peak_memory_bytes",
    "budget_bytes",
    "peak_over_budget",
    "rays",
    "bytes_per_ray",
    "structure_bytes",
    "structure_ratio",
    "imbalance_tests",
    "imbalance_work",
    "work_ratio",
    "cost_ratio",
    "utilisation",
    "waiting",
    "host_share",
    "whole_for",
];

fn fields(r: &ScaleRow) -> [String; 30] {
    [
        r.dimension.to_string(),
        r.nodes.to_string(),
        format!("{:.4}", r.wall_seconds),
        format!("{:.4}", r.virtual_seconds),
        format!("{:.3}", r.speedup_wall),
        format!("{:.3}", r.efficiency_wall),
        format!("{:.3}", r.speedup_virtual),
        format!("{:.3}", r.efficiency_virtual),
        r.messages.to_string(),
        r.message_bytes.to_string(),
        r.hops.to_string(),
        format!("{:.3}", r.imbalance_balanced),
        format!("{:.3}", r.imbalance_equal_area),
        format!("{:.3}", r.predicted_imbalance),
        format!("{:.4}", r.virtual_seconds_equal_area),
        r.peak_memory_bytes.to_string(),
        r.budget_bytes.to_string(),
        format!(
            "{:.3}",
            r.peak_memory_bytes as f64 / r.budget_bytes.max(1) as f64
        ),
        r.rays.to_string(),
        format!("{:.1}", r.bytes_per_ray),
        r.structure_bytes.to_string(),
        format!("{:.3}", r.structure_ratio),
        format!("{:.3}", r.imbalance_tests),
        format!("{:.3}", r.imbalance_work),
        format!("{:.3}", r.factors.work_ratio),
        format!("{:.3}", r.factors.cost_ratio),
        format!("{:.3}", r.factors.utilisation),
        format!("{:.3}", r.factors.waiting),
        // Empty where the runs were too short to tell.
        r.host_share.map_or(String::new(), |s| format!("{s:.3}")),
        // Empty where the structure was distributed.
        r.whole_for.map_or(String::new(), |u| format!("{u:.3}")),
    ]
}

/// The rows as CSV, one header line.
pub fn csv(rows: &[ScaleRow]) -> String {
    let mut s = HEADER.join(",");
    s.push('\n');
    for r in rows {
        s += &fields(r).join(",");
        s.push('\n');
    }
    s
}

/// The rows as an aligned text table.
pub fn table(rows: &[ScaleRow]) -> String {
    let cols = [
        0usize, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 19, 21, 24, 25, 26, 27,
    ];
    let cells: Vec<Vec<String>> = std::iter::once(HEADER.map(String::from).to_vec())
        .chain(rows.iter().map(|r| fields(r).to_vec()))
        .map(|row| cols.iter().map(|&c| row[c].clone()).collect())
        .collect();
    let widths: Vec<usize> = (0..cols.len())
        .map(|c| cells.iter().map(|r| r[c].len()).max().unwrap_or(0))
        .collect();
    let mut s = String::new();
    for row in &cells {
        for (c, v) in row.iter().enumerate() {
            let _ = write!(s, "{:>w$}  ", v, w = widths[c]);
        }
        s = s.trim_end().to_string();
        s.push('\n');
    }
    s
}

/// Writes `scaling.csv` and `scaling.png` into `dir`.
pub fn write_outputs(dir: &Path, title: &str, rows: &[ScaleRow]) -> Result<()> {
    let text = csv(rows);
    write_atomically(&dir.join("scaling.csv"), |f| {
        std::io::Write::write_all(f, text.as_bytes()).map_err(|e| e.to_string())
    })?;
    super::plot::write_png(&dir.join("scaling.png"), SIZE, |buf| draw(buf, title, rows))
}

/// The plot's size: three panels of 500 by 520.
const SIZE: (u32, u32) = (1500, 520);

fn draw(buf: &mut [u8], title: &str, rows: &[ScaleRow]) -> std::result::Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let root = BitMapBackend::with_buffer(buf, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let root = root.titled(title, ("sans-serif", 20)).map_err(|x| e(&x))?;
    let (left, rest) = root.split_horizontally(500);
    let (right, factors) = rest.split_horizontally(500);
    let max_nodes = rows.iter().map(|r| r.nodes).max().unwrap_or(1) as f64;
    // Node counts are powers of two: the axis is the dimension, labelled
    // with its node count, so that every count gets its tick.
    let max_dim = rows.iter().map(|r| r.dimension).max().unwrap_or(0) as f64;
    let x = Axis {
        range: -0.25..max_dim.max(1.0) + 0.25,
        labels: max_dim as usize + 2,
    };
    let blue = RGBColor(31, 119, 180);
    let orange = RGBColor(255, 127, 14);
    let grey = RGBColor(120, 120, 120);
    // Speedup against node count, with the ideal line.
    let top = rows
        .iter()
        .flat_map(|r| [r.speedup_wall, r.speedup_virtual])
        .fold(max_nodes, f64::max)
        * 1.25;
    // Below 1 too: the host's wall-time speedup falls under 1 when 32 node
    // threads share two cores, and a clipped curve would hide it.
    let bottom = rows
        .iter()
        .flat_map(|r| [r.speedup_wall, r.speedup_virtual])
        .filter(|v| *v > 0.0)
        .fold(1.0, f64::min)
        * 0.8;
    let mut c = ChartBuilder::on(&left)
        .caption("speedup", ("sans-serif", 16))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(
            x.range.clone(),
            (bottom..top)
                .log_scale()
                .with_key_points(powers_of_two(bottom, top)),
        )
        .map_err(|x| e(&x))?;
    mesh(&mut c, &x)?;
    let ideal: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.dimension as f64, r.nodes as f64))
        .collect();
    c.draw_series(LineSeries::new(ideal, grey.stroke_width(1)))
        .map_err(|x| e(&x))?
        .label("ideal")
        .legend(move |(x, y)| PathElement::new([(x - 10, y), (x + 10, y)], grey));
    curves(
        &mut c,
        rows,
        &[
            ("wall (host)", blue, |r| r.speedup_wall),
            ("virtual (model)", orange, |r| r.speedup_virtual),
        ],
        SeriesLabelPosition::UpperLeft,
    )?;
    // Efficiency, and the imbalance of both mappings.
    linear_panel(
        &right,
        "efficiency and imbalance",
        &x,
        rows,
        &[
            ("efficiency, wall", blue, |r| r.efficiency_wall),
            ("efficiency, virtual", orange, |r| r.efficiency_virtual),
            ("imbalance, balanced", RGBColor(44, 160, 44), |r| {
                r.imbalance_balanced
            }),
            ("imbalance, equal area", RGBColor(214, 39, 40), |r| {
                r.imbalance_equal_area
            }),
        ],
        SeriesLabelPosition::UpperRight,
    )?;
    // Where the virtual efficiency goes (`EfficiencyFactors`): it is the
    // utilisation over the product of the two ratios.
    linear_panel(
        &factors,
        "virtual efficiency = utilisation / (work x cost)",
        &x,
        rows,
        &[
            ("work (x one node's)", RGBColor(148, 103, 189), |r| {
                r.factors.work_ratio
            }),
            (
                "host CPU per work (x one node's)",
                RGBColor(140, 86, 75),
                |r| r.factors.cost_ratio,
            ),
            ("utilisation", grey, |r| r.factors.utilisation),
            ("efficiency, virtual", orange, |r| r.efficiency_virtual),
        ],
        SeriesLabelPosition::UpperLeft,
    )?;
    root.present().map_err(|x| e(&x))
}

/// The node-count axis every panel shares: the dimension, with room on
/// either side, and a tick per dimension.
struct Axis {
    range: std::ops::Range<f64>,
    labels: usize,
}

/// A curve of a panel: its legend, its colour, and its value in a row.
type Curve = (&'static str, RGBColor, fn(&ScaleRow) -> f64);

/// A panel's chart: the node-count axis against `Y`.
type Chart<'a, 'b, Y> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, Y>>;

/// A panel with a linear axis from 0 to above its highest finite value
/// (and at least above 1, where speedup and balance are ideal), with room
/// at the top for the legend's rows, so that it covers no curve.
fn linear_panel(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    caption: &str,
    x: &Axis,
    rows: &[ScaleRow],
    series: &[Curve],
    legend: SeriesLabelPosition,
) -> std::result::Result<(), String> {
    let top = rows
        .iter()
        .flat_map(|r| series.iter().map(move |(_, _, f)| f(r)))
        .filter(|v| v.is_finite())
        .fold(1.0, f64::max)
        * (1.15 + 0.07 * series.len() as f64);
    let mut c = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 16))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(48)
        .build_cartesian_2d(x.range.clone(), 0.0..top)
        .map_err(|e| e.to_string())?;
    mesh(&mut c, x)?;
    curves(&mut c, rows, series, legend)
}

/// The speedup axis's ticks: the powers of two between `lo` and `hi`, the
/// node counts the ideal line passes (a decade's nine ticks crowded the
/// top of the axis, and plotters drew its last one twice).
fn powers_of_two(lo: f64, hi: f64) -> Vec<f64> {
    let first = lo.log2().ceil() as i32;
    let last = hi.log2().floor() as i32;
    (first..=last).map(|k| 2f64.powi(k)).collect()
}

/// A panel's grid and axes, the horizontal one labelled by node count.
fn mesh<Y>(c: &mut Chart<'_, '_, Y>, x: &Axis) -> std::result::Result<(), String>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    c.configure_mesh()
        .x_desc("nodes")
        .x_labels(x.labels)
        .x_label_formatter(&node_count_label)
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .draw()
        .map_err(|e| e.to_string())
}

/// Each curve as a line with a dot per row, then the legend of all the
/// panel's labelled series at `legend`.
fn curves<'a, 'b: 'a, Y>(
    c: &mut Chart<'a, 'b, Y>,
    rows: &[ScaleRow],
    series: &[Curve],
    legend: SeriesLabelPosition,
) -> std::result::Result<(), String>
where
    Y: Ranged<ValueType = f64>,
{
    let e = |x: &dyn std::fmt::Display| x.to_string();
    for &(name, color, f) in series {
        let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.dimension as f64, f(r))).collect();
        c.draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
            .map_err(|x| e(&x))?
            .label(name)
            .legend(move |(x, y)| {
                PathElement::new([(x - 10, y), (x + 10, y)], color.stroke_width(2))
            });
        c.draw_series(pts.into_iter().map(|p| Circle::new(p, 4, color.filled())))
            .map_err(|x| e(&x))?;
    }
    c.configure_series_labels()
        .label_font(("sans-serif", 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(legend)
        .draw()
        .map_err(|x| e(&x))
}

/// A label of the dimension axis: the node count 2^d at whole d, nothing
/// between.
fn node_count_label(d: &f64) -> String {
    let r = d.round();
    if (d - r).abs() < 1e-9 && (0.0..=16.0).contains(&r) {
        format!("{}", 1u64 << r as u32)
    } else {
        String::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cells::{CELL_WORK, TEST_WORK};

    #[test]
    fn dims_parse_ranges_and_lists() {
        assert_eq!(parse_dims("0..5"), Ok(vec![0, 1, 2, 3, 4, 5]));
        assert_eq!(parse_dims("2..=3"), Ok(vec![2, 3]));
        assert_eq!(parse_dims("0, 2,5"), Ok(vec![0, 2, 5]));
        assert!(parse_dims("5..2").is_err());
        assert!(parse_dims("x").is_err());
        assert!(parse_dims("0..11").is_err());
    }

    /// Audit: `--dims 2,2` gave two rows of one dimension, and `--dims
    /// 1,0` speedups of one node measured against two. A repeat is refused
    /// naming it; a list in any order runs smallest first.
    #[test]
    fn dims_are_ascending_and_each_given_once() {
        assert_eq!(parse_dims("1,0"), Ok(vec![0, 1]));
        assert_eq!(parse_dims("5, 0,2"), Ok(vec![0, 2, 5]));
        for (repeated, d) in [("2,2", 2), ("0,3,1,3", 3), ("4,1,4,4", 4)] {
            let e = parse_dims(repeated).expect_err(repeated);
            let want = format!("--dims: {d} is given more than once");
            assert!(e.starts_with(&want), "{repeated}: {e}");
        }
    }

    #[test]
    fn the_speedup_axis_is_ticked_at_node_counts() {
        assert_eq!(
            powers_of_two(0.4, 40.0),
            vec![0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
        );
        assert_eq!(powers_of_two(0.8, 2.5), vec![1.0, 2.0]);
        assert_eq!(powers_of_two(1.0, 2.0), vec![1.0, 2.0]);
    }

    fn node(busy_seconds: f64, cells_visited: u64, intersection_tests: u64) -> NodeReport {
        NodeReport {
            busy_seconds,
            cells_visited,
            intersection_tests,
            ..NodeReport::default()
        }
    }

    fn waited(mut n: NodeReport, waiting_seconds: f64) -> NodeReport {
        n.waiting_seconds = waiting_seconds;
        n
    }

    #[test]
    fn efficiency_factors_multiply_to_the_virtual_efficiency() {
        // A compute speed of one half: virtual seconds are twice the host's.
        let speed = 0.5;
        let base = MachineStats {
            virtual_seconds: 4.2,
            per_node: vec![node(2.0, 100, 25)],
            ..MachineStats::default()
        };
        let run = MachineStats {
            virtual_seconds: 3.5,
            per_node: vec![
                waited(node(1.5, 60, 15), 0.25),
                waited(node(1.5, 70, 20), 0.45),
            ],
            ..MachineStats::default()
        };
        let f = EfficiencyFactors::of(&run, &base, speed);
        // Work (cells and TEST_WORK per test): 270 against 200.
        let work = |c: u64, t: u64| (CELL_WORK * c + TEST_WORK * t) as f64;
        let w_ratio = (work(60, 15) + work(70, 20)) / work(100, 25);
        assert!((f.work_ratio - w_ratio).abs() < 1e-12, "{f:?}");
        assert!((f.cost_ratio - 3.0 / 2.0 / w_ratio).abs() < 1e-12, "{f:?}");
        assert!((f.utilisation - 3.0 / speed / (2.0 * 3.5)).abs() < 1e-12);
        assert!((f.waiting - 0.7 / (2.0 * 3.5)).abs() < 1e-12, "{f:?}");
        // The speedup over one node, per node.
        let efficiency = base.virtual_seconds / run.virtual_seconds / 2.0;
        let u0 = EfficiencyFactors::of(&base, &base, speed);
        assert_eq!((u0.work_ratio, u0.cost_ratio), (1.0, 1.0));
        let product = f.utilisation / u0.utilisation / (f.work_ratio * f.cost_ratio);
        assert!(
            (product - efficiency).abs() < 1e-12,
            "{product} {efficiency}"
        );
    }
}
