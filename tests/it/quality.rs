//! Antialiasing and error against run time (issue 5, items 1-3): samples
//! and adaptive passes are deterministic (bit-identical for any thread
//! count and either accelerator), refinement lowers the error, 16 samples
//! come within 1% of a 256-sample reference, and `quality` writes its
//! table, CSV and plot or refuses bad options cleanly.

use std::path::Path;

use hypercast::cells::CellOptions;
use hypercast::render::{self, Accel, Adaptive, HostRender, RenderOptions};
use hypercast::report::{self, compare, image_io::to_display};
use hypercast::scene::Scene;
use hypercast::scene::load::load_scene;

use crate::cli::{check_refusal, files_in, metrics, path_str, render_ok, run, stderr};
use crate::util;

fn jagged_ball() -> Scene {
    load_scene(&util::repo("scenes/jagged_ball.ron")).expect("jagged_ball.ron loads")
}

fn render(
    scene: &Scene,
    (width, height): (u32, u32),
    spp: u32,
    adaptive: Option<Adaptive>,
    accel: Accel,
    threads: usize,
) -> HostRender {
    let opts = RenderOptions {
        width,
        height,
        spp,
        threads,
    };
    let r = render::render_host(
        scene,
        &opts,
        adaptive,
        accel,
        CellOptions::default(),
        &|_| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    util::assert_finite(&r.film);
    r
}

/// Display-value RMSE of two renders of the same size.
fn rmse(a: &HostRender, b: &HostRender) -> f64 {
    compare(
        &to_display(&a.film.to_linear()),
        &to_display(&b.film.to_linear()),
    )
    .rmse
}

const AA: Adaptive = Adaptive {
    threshold: 0.05,
    extra_spp: 8,
};

/// `DESIGN.md`: the image is bit-identical for every thread schedule; the
/// samples are seeded by pixel and sample index only. Band assignment to
/// threads differs between 1, 2 and 3 threads, so a sample that depended
/// on its thread would show.
#[test]
fn same_sampling_is_bit_identical_for_any_thread_count() {
    let scene = jagged_ball();
    for accel in [Accel::Roth, Accel::Cells] {
        for adaptive in [None, Some(AA)] {
            let one = render(&scene, (40, 30), 4, adaptive, accel, 1);
            for threads in [2, 3] {
                let many = render(&scene, (40, 30), 4, adaptive, accel, threads);
                assert!(
                    one.film.sums() == many.film.sums(),
                    "{} {adaptive:?}: 1 and {threads} threads differ",
                    accel.name()
                );
                assert_eq!(one.aa, many.aa);
            }
        }
    }
}

/// The architecture invariant (cells equal Roth) holds through both
/// adaptive passes: the refined set and the combined film are the same.
#[test]
fn adaptive_cells_equal_adaptive_roth() {
    let scene = jagged_ball();
    let roth = render(&scene, (48, 36), 1, Some(AA), Accel::Roth, 2);
    let cells = render(&scene, (48, 36), 1, Some(AA), Accel::Cells, 2);
    assert_eq!(roth.aa, cells.aa);
    assert!(roth.aa.refined_pixels > 0, "the ball has edges to refine");
    assert!(roth.film.sums() == cells.film.sums());
}

/// Refinement goes where the edges are: some but not all pixels are
/// refined, a lower threshold refines more, the refined render is closer
/// to a many-sample reference than its first pass alone, and pass 2 traces
/// only the refined pixels' extra samples.
#[test]
fn adaptive_refinement_lowers_the_error_where_neighbours_differ() {
    let scene = jagged_ball();
    let size = (48, 36);
    let pixels = 48 * 36;
    let reference = render(&scene, size, 64, None, Accel::Cells, 2);
    let plain = render(&scene, size, 1, None, Accel::Cells, 2);
    let coarse = render(
        &scene,
        size,
        1,
        Some(Adaptive {
            threshold: 0.2,
            ..AA
        }),
        Accel::Cells,
        2,
    );
    let fine = render(&scene, size, 1, Some(AA), Accel::Cells, 2);
    assert!(coarse.aa.refined_pixels > 0);
    assert!(fine.aa.refined_pixels > coarse.aa.refined_pixels);
    assert!(
        fine.aa.refined_pixels < pixels,
        "not every pixel is an edge"
    );
    assert_eq!(fine.aa.samples, pixels + 8 * fine.aa.refined_pixels);
    assert_eq!(
        fine.stats.rays.get(hypercast::trace::RayKind::Primary),
        fine.aa.samples,
        "one primary ray per sample of both passes"
    );
    assert_eq!(
        fine.stats.pixels_traced + fine.stats.pixels_background,
        pixels,
        "every pixel counted once"
    );
    let (e1, e2, e3) = (
        rmse(&plain, &reference),
        rmse(&coarse, &reference),
        rmse(&fine, &reference),
    );
    assert!(
        e2 < e1 && e3 < e2,
        "rmse 1 spp {e1}, T 0.2 {e2}, T 0.05 {e3}"
    );
}

/// A threshold no pair of pixels exceeds renders pass 1 only: the same
/// film as the plain render.
#[test]
fn adaptive_without_contrast_is_the_plain_render() {
    let scene = util::scene(
        r#"(camera: (eye: (0, -5, 0), look_at: (0, 0, 0), fov_y: 30, width: 16, height: 12),
            background: (0.5, 0.5, 0.5), objects: [])"#,
    );
    let plain = render(&scene, (16, 12), 2, None, Accel::Roth, 2);
    let aa = render(&scene, (16, 12), 2, Some(AA), Accel::Roth, 2);
    assert_eq!(aa.aa.passes, 1);
    assert!(plain.film.sums() == aa.film.sums());
}

/// Issue 5's acceptance: at 16 samples per pixel the RMSE against a
/// 256-sample Roth reference is below 1% of the display range on
/// jagged_ball.ron (here at 64x48; the full-size figure is in README.md).
#[test]
fn sixteen_spp_is_within_one_percent_of_a_256_spp_reference() {
    let scene = jagged_ball();
    let size = (64, 48);
    let reference = render(&scene, size, 256, None, Accel::Roth, 2);
    let sixteen = render(&scene, size, 16, None, Accel::Cells, 2);
    let one = render(&scene, size, 1, None, Accel::Cells, 2);
    let (e16, e1) = (rmse(&sixteen, &reference), rmse(&one, &reference));
    assert!(e16 < 0.01, "rmse at 16 spp: {e16}");
    // The measure can tell: one sample per pixel is well above it.
    assert!(e1 > 0.02, "rmse at 1 spp: {e1}");
}

/// The binary: `--threads` does not change the image file.
#[test]
fn images_with_the_same_spp_are_identical_for_any_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/small/mirror.ron");
    for aa in [&[][..], &["--aa-threshold", "0.05"][..]] {
        let mut images = Vec::new();
        for threads in ["1", "3"] {
            let name = format!("t{threads}.exr");
            let mut args = vec![
                "render",
                path_str(&scene),
                "-o",
                &name,
                "--width",
                "40",
                "--height",
                "30",
                "--spp",
                "4",
                "--threads",
                threads,
                "-q",
            ];
            args.extend_from_slice(aa);
            let o = run(tmp.path(), &args);
            assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
            images.push(std::fs::read(tmp.path().join(&name)).unwrap());
        }
        assert!(images[0] == images[1], "{aa:?}");
    }
}

#[test]
fn render_reports_error_beside_wall_time_and_in_stats() {
    let tmp = tempfile::tempdir().unwrap();
    render_ok(tmp.path(), "ref.exr", &["--spp", "16", "-q"]);
    let o = render_ok(
        tmp.path(),
        "aa.png",
        &[
            "--aa-threshold",
            "0.1",
            "--reference",
            "ref.exr",
            "--stats",
            "with.json",
            "-q",
        ],
    );
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(out.contains("s wall"), "{out}");
    assert!(out.contains(" max "), "{out}");
    let (rmse, _) = metrics(&o);
    assert!(rmse > 0.0 && rmse < 0.05, "rmse {rmse}");
    let json = |name: &str| -> serde_json::Value {
        let text = std::fs::read_to_string(tmp.path().join(name)).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    let v = json("with.json");
    assert!((v["rmse"].as_f64().unwrap() - rmse).abs() < 1e-6, "{v}");
    assert!(v["psnr"].as_f64().unwrap() > 20.0, "{v}");
    assert_eq!(v["aa_threshold"], 0.1);
    assert!(v["aa_refined_pixels"].as_u64().unwrap() > 0, "{v}");
    // Without a reference the keys are there, and null.
    render_ok(tmp.path(), "b.png", &["--stats", "without.json", "-q"]);
    let v = json("without.json");
    for key in ["rmse", "psnr"] {
        assert!(v.get(key).is_some_and(|x| x.is_null()), "{key}: {v}");
    }
}

#[test]
fn bad_antialiasing_and_quality_options_are_refused() {
    let sphere = util::repo("scenes/small/sphere.ron");
    let sphere = path_str(&sphere);
    let mut problems = Vec::new();
    let cases: [(&[&str], &str); 7] = [
        (&["render", sphere, "--aa-threshold", "0"], "--aa-threshold"),
        (
            &["render", sphere, "--aa-threshold", "1.5"],
            "--aa-threshold",
        ),
        (
            &["render", sphere, "--aa-threshold", "NaN"],
            "--aa-threshold",
        ),
        (
            &["render", sphere, "--aa-threshold", "0.1", "--aa-spp", "0"],
            "--aa-spp",
        ),
        (&["quality", sphere, "--max-spp", "0"], "--max-spp"),
        (
            &["quality", sphere, "--reference-spp", "0"],
            "--reference-spp",
        ),
        (&["quality", "missing.ron"], "missing.ron"),
    ];
    for (args, want) in cases {
        let tmp = tempfile::tempdir().unwrap();
        problems.extend(check_refusal(tmp.path(), args, want));
    }
    // --aa-spp means nothing without --aa-threshold: clap refuses it.
    let tmp = tempfile::tempdir().unwrap();
    let o = run(tmp.path(), &["render", sphere, "--aa-spp", "4"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(files_in(tmp.path()).is_empty());
    // --out naming a file, and a reference of the wrong size.
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("file"), "x").unwrap();
    let o = run(tmp.path(), &["quality", sphere, "--out", "file"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_eq!(files_in(tmp.path()).len(), 1);
    let tmp = tempfile::tempdir().unwrap();
    render_ok(tmp.path(), "small.png", &["-q"]);
    let o = run(
        tmp.path(),
        &["quality", sphere, "--reference", "small.png", "--out", "q"],
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("small.png"), "{}", stderr(&o));
    assert!(!tmp.path().join("q").exists(), "nothing made on refusal");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Reads `quality.csv`: a header and one row per point.
fn csv_rows(dir: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(dir.join("quality.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{l}");
            header
                .iter()
                .cloned()
                .zip(cells.iter().map(|c| c.to_string()))
                .collect()
        })
        .collect()
}

/// `quality` on a small sweep: the reference, CSV and plot are written;
/// the spp series' error falls as its samples (and time) grow; the Pareto
/// front is marked; the model's error is measured on the machine, with a
/// host-calibrated topology, on every dimension this host has cores for.
#[test]
fn quality_writes_table_csv_and_plot_with_falling_error() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/jagged_ball.ron");
    let o = run(
        tmp.path(),
        &[
            "quality",
            path_str(&scene),
            "--out",
            "q",
            "--width",
            "48",
            "--height",
            "36",
            "--reference-spp",
            "64",
            "--max-spp",
            "8",
            "--threads",
            "2",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let dir = tmp.path().join("q");
    let rows = csv_rows(&dir);
    // spp 1, 2, 4, 8; four thresholds; depths 0, 1, 2 (the scene's is 5);
    // then spp 1, spp 4 and threshold 0.1 on the machine per dimension.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let dims = (0..8u32).filter(|d| 1 << d <= cores).count();
    let (host, model): (Vec<_>, Vec<_>) = rows.iter().partition(|r| r["dimension"].is_empty());
    assert_eq!(host.len(), 4 + 4 + 3, "{rows:?}");
    assert_eq!(model.len(), 3 * dims, "{rows:?}");
    let spp: Vec<f64> = host
        .iter()
        .filter(|r| r["family"] == "spp")
        .map(|r| r["rmse"].parse().unwrap())
        .collect();
    assert!(spp.windows(2).all(|w| w[1] < w[0]), "spp rmse {spp:?}");
    let pareto = host.iter().filter(|r| r["pareto"] == "true").count();
    assert!(pareto >= 2, "{pareto} Pareto points");
    assert!(host.iter().all(|r| r["virtual_seconds"].is_empty()));
    let num = |r: &std::collections::HashMap<String, String>, k: &str| -> f64 {
        r[k].parse().unwrap_or_else(|_| panic!("{k}: {r:?}"))
    };
    for m in &model {
        assert_eq!(m["pareto"], "false", "{m:?}");
        let (wall, virt) = (num(m, "wall_seconds"), num(m, "virtual_seconds"));
        assert!(wall > 0.0 && virt > 0.0, "{m:?}");
        let err = num(m, "model_relative_error");
        // The CSV gives seconds to 1e-6 and the error to 1e-6: on runs of
        // a few milliseconds that rounding alone moves the ratio by 1e-4.
        let rounding = 2.0 * (5e-7 / wall) * (1.0 + virt / wall) + 1e-6;
        assert!((err - (virt - wall) / wall).abs() <= rounding, "{m:?}");
        // The process's CPU time over the span the wall time measures: some
        // (the old reckoning, all of the run less the build's and pre-pass's
        // wall time, went to 0 on small renders), and within the cores.
        let cpu = num(m, "cpu_seconds");
        assert!(cpu > 0.0, "{m:?}");
        assert!(cpu <= cores as f64 * wall + 2e-3, "{m:?}");
        // The machine renders the very image the host did.
        let same = host
            .iter()
            .find(|h| {
                ["family", "spp", "aa_threshold", "max_depth"]
                    .iter()
                    .all(|k| h[*k] == m[*k])
            })
            .unwrap_or_else(|| panic!("no host point for {m:?}"));
        assert_eq!(same["rmse"], m["rmse"], "{m:?}");
        assert_eq!(same["samples"], m["samples"], "{m:?}");
    }
    let table = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(table.contains("| spp 8, depth 5 | spp |"), "{table}");
    assert!(table.contains("calibration: latency "), "{table}");
    assert!(table.contains("| spp 4, depth 5 | 0 | 1 |"), "{table}");
    assert!(
        table.contains("model error (virtual against wall time): d 0: mean |error| "),
        "{table}"
    );
    let plot = image::open(dir.join("quality.png")).expect("a readable PNG");
    assert!(plot.width() > 400 && plot.height() > 300);
    let reference = report::read_display_image(&dir.join("reference.exr")).unwrap();
    assert_eq!((reference.width, reference.height), (48, 36));
    // Only the three outputs, no temporary files.
    assert_eq!(files_in(&dir).len(), 3, "{:?}", files_in(&dir));
}
