//! Issue 3's benchmark: the paper's cells against Roth's brute force, side
//! by side in one run, on the bundled jagged ball and house and on a
//! generated sphereflake of level 4 (7,381 spheres and a floor) at the
//! issue's 512x512. Prints a markdown table: wall time, the ratio,
//! intersection tests per ray, build time and structure bytes.
//! `cargo bench --bench cells_vs_roth`.
//!
//! Every case renders the whole image with both accelerators, on 2 threads.
//! Each run is timed in wall seconds and in CPU seconds of the process (all
//! threads). Neither is steady on a shared machine: other processes take
//! cores and share caches, and a run of a second (cells) suffers more from
//! a burst of load than one of minutes (Roth), which averages it. So cells
//! runs are medians of `CELLS_RUNS` (build included), Roth runs medians of
//! 3 on the bundled scenes and a single run on the sphereflake, where one
//! run of Roth takes minutes (every ray meets the 7,382 children of the
//! scene's top union). Roth's runs sit amid the cells runs. (An earlier
//! version timed a band of 32 rows through the flake with the structure
//! built for that band: the screen window then covered a sixteenth of the
//! image, so the cost model left the rest of the plane, where secondary
//! rays go, hardly subdivided; it measured 12.5x where the whole image
//! gives far more.)

use std::path::Path;
use std::time::Instant;

use hypercast::cells::{CellOptions, CellStructure, CellTracer};
use hypercast::machine::ticks::process_cpu_seconds;
use hypercast::render::{RenderOptions, RenderStats, render_roth, render_with};
use hypercast::scene::{Scene, load::compile_model, load_scene};

/// Cells runs per case (cheap, and the noisiest).
const CELLS_RUNS: usize = 7;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Wall and CPU seconds of `f`.
fn timed<T>(f: impl FnOnce() -> T) -> (f64, f64, T) {
    let (t, c) = (Instant::now(), process_cpu_seconds());
    let out = f();
    let c1 = process_cpu_seconds();
    // `process_cpu_seconds` reads 0 where the clock is unavailable; the
    // table's CPU columns would then be wrong, not merely noisy.
    assert!(c1 > 0.0, "the process CPU clock is available");
    (t.elapsed().as_secs_f64(), c1 - c, out)
}

/// Builds the structure and renders with it (both timed together).
fn cells(scene: &Scene, o: &RenderOptions) -> (RenderStats, CellStructure) {
    let cs = CellStructure::build(scene, o.width, o.height, CellOptions::default()).unwrap();
    let (_, st) = render_with(
        scene,
        o,
        || CellTracer::new(&cs, scene),
        |t, j| t.skips_primary(&j.ray),
        &|_| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    (st, cs)
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let flake = compile_model(
        &hypercast::r#gen::sphereflake::sphereflake(4),
        Path::new("sphereflake-4"),
    )
    .expect("sphereflake compiles")
    .0;
    let jagged = load_scene(&root.join("scenes/jagged_ball.ron")).expect("jagged_ball");
    let house = load_scene(&root.join("scenes/house.ron")).expect("house");
    println!(
        "| scene | primitives | size | runs cells/roth | cells s | roth s | roth/cells | cells CPU s | roth CPU s | roth/cells CPU | tests/ray cells | tests/ray roth | build s | structure bytes |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let cases: Vec<(&str, Scene, RenderOptions)> = vec![
        (
            "jagged_ball.ron",
            jagged,
            RenderOptions {
                width: 640,
                height: 480,
                spp: 1,
                threads: 2,
            },
        ),
        (
            "house.ron",
            house,
            RenderOptions {
                width: 640,
                height: 480,
                spp: 1,
                threads: 2,
            },
        ),
        (
            "sphereflake level 4",
            flake.clone(),
            RenderOptions {
                width: 512,
                height: 512,
                spp: 1,
                threads: 2,
            },
        ),
    ];
    // `cargo bench --bench cells_vs_roth -- WORD` runs the cases whose
    // name contains WORD (cargo's own `--bench` flag is ignored).
    let only: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    for (name, scene, o) in cases {
        if !only.is_empty() && !only.iter().any(|w| name.contains(w.as_str())) {
            continue;
        }
        // Roth once where one run takes minutes (see the header).
        let roth_runs = if scene.primitives.len() > 5_000 { 1 } else { 3 };
        let (mut tc, mut cc, mut tr, mut cr) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut cells_last = None;
        let mut roth_last = None;
        // Roth's runs in the middle of the cells runs.
        let first_roth = (CELLS_RUNS - roth_runs) / 2;
        for i in 0..CELLS_RUNS {
            let (wall, cpu, out) = timed(|| cells(&scene, &o));
            tc.push(wall);
            cc.push(cpu);
            cells_last = Some(out);
            if (first_roth..first_roth + roth_runs).contains(&i) {
                let (wall, cpu, (_, rst)) = timed(|| render_roth(&scene, &o, &|_| {}));
                tr.push(wall);
                cr.push(cpu);
                roth_last = Some(rst);
            }
        }
        let (st, cs) = cells_last.expect("cells runs");
        let rst = roth_last.expect("a Roth run");
        let (c, r) = (median(tc), median(tr));
        let (c_cpu, r_cpu) = (median(cc), median(cr));
        println!(
            "| {name} | {} | {}x{} | {CELLS_RUNS}/{roth_runs} | {c:.3} | {r:.3} | {:.1}x | {c_cpu:.3} | {r_cpu:.3} | {:.1}x | {:.2} | {:.2} | {:.4} | {} |",
            scene.primitives.len(),
            o.width,
            o.height,
            r / c,
            r_cpu / c_cpu,
            st.counters.intersection_tests as f64 / st.rays.total().max(1) as f64,
            rst.counters.intersection_tests as f64 / rst.rays.total().max(1) as f64,
            cs.stats.build_seconds,
            cs.stats.bytes,
        );
    }
    // Build time alone for 10,000 primitives (a sphereflake of level 5 has
    // 66,430; level 4 plus random CSG would mix costs, so time both).
    let t = Instant::now();
    let cs = CellStructure::build(&flake, 512, 512, CellOptions::default()).unwrap();
    println!(
        "\nsubdivision build, sphereflake level 4 ({} primitives): {:.3} s ({} cells)",
        flake.primitives.len(),
        t.elapsed().as_secs_f64(),
        cs.stats.cells
    );
    let rc = compile_model(
        &hypercast::r#gen::random::random_csg(7, 10_000, &Default::default()),
        Path::new("random-10000"),
    )
    .expect("random scene")
    .0;
    let t = Instant::now();
    let cs = CellStructure::build(&rc, 512, 512, CellOptions::default()).unwrap();
    println!(
        "subdivision build, random CSG ({} primitives): {:.3} s ({} cells)",
        rc.primitives.len(),
        t.elapsed().as_secs_f64(),
        cs.stats.cells
    );
}
