//! Issue 3's benchmark: the paper's cells against Roth's brute force, side
//! by side in one run, on the bundled jagged ball and house and on a
//! generated sphereflake of level 4 (7,381 spheres). Prints a markdown
//! table: wall time (median of 3), the ratio, intersection tests per ray,
//! build time and structure bytes. `cargo bench --bench cells_vs_roth`.
//! Roth on the sphereflake is measured on a horizontal band of rows through
//! the flake and the ratio is taken on that same band (said in the table).

use std::path::Path;
use std::time::Instant;

use hypercast::cells::{CellOptions, CellStructure, CellTracer};
use hypercast::render::{RenderOptions, RenderStats, render_roth, render_with};
use hypercast::scene::{Scene, load::compile_model, load_scene};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn cells(scene: &Scene, o: &RenderOptions) -> (f64, RenderStats, CellStructure) {
    let t = Instant::now();
    let cs = CellStructure::build(scene, o.width, o.height, CellOptions::default());
    let (_, st) = render_with(
        scene,
        o,
        || CellTracer::new(&cs, scene),
        |j| CellTracer::primary_is_background(&cs, &j.ray),
        &|_| {},
    );
    (t.elapsed().as_secs_f64(), st, cs)
}

/// Restricts the camera to rows `[y0, y0 + rows)` of a `w × h` image by
/// shrinking the field of view around that band (same rays as those rows).
fn band(scene: &Scene, w: u32, h: u32, rows: u32) -> (Scene, RenderOptions) {
    let mut s = scene.clone();
    let half = (s.camera.fov_y.to_radians() / 2.0).tan() * rows as f64 / h as f64;
    s.camera.fov_y = 2.0 * half.atan().to_degrees();
    (
        s,
        RenderOptions {
            width: w,
            height: rows,
            spp: 1,
            threads: 2,
        },
    )
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
        "| scene | primitives | size | cells s | roth s | roth/cells | tests/ray cells | tests/ray roth | build s | structure bytes |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
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
            "sphereflake level 4 (band of 32 rows of 512x512)",
            band(&flake, 512, 512, 32).0,
            band(&flake, 512, 512, 32).1,
        ),
    ];
    for (name, scene, o) in cases {
        let mut tc = Vec::new();
        let mut tr = Vec::new();
        let mut last = None;
        for _ in 0..3 {
            let (t, st, cs) = cells(&scene, &o);
            tc.push(t);
            let t = Instant::now();
            let (_, rst) = render_roth(&scene, &o, &|_| {});
            tr.push(t.elapsed().as_secs_f64());
            last = Some((st, rst, cs));
        }
        let (st, rst, cs) = last.expect("three runs");
        let (c, r) = (median(tc), median(tr));
        println!(
            "| {name} | {} | {}x{} | {c:.3} | {r:.3} | {:.1}x | {:.2} | {:.2} | {:.4} | {} |",
            scene.primitives.len(),
            o.width,
            o.height,
            r / c,
            st.counters.intersection_tests as f64 / st.rays.total().max(1) as f64,
            rst.counters.intersection_tests as f64 / rst.rays.total().max(1) as f64,
            cs.stats.build_seconds,
            cs.stats.bytes,
        );
    }
    // Build time alone for 10,000 primitives (a sphereflake of level 5 has
    // 66,430; level 4 plus random CSG would mix costs, so time both).
    let t = Instant::now();
    let cs = CellStructure::build(&flake, 512, 512, CellOptions::default());
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
    let cs = CellStructure::build(&rc, 512, 512, CellOptions::default());
    println!(
        "subdivision build, random CSG ({} primitives): {:.3} s ({} cells)",
        rc.primitives.len(),
        t.elapsed().as_secs_f64(),
        cs.stats.cells
    );
}
