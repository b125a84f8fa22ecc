//! Issue 5's stress cases full size, as a user runs them: each case writes
//! its scene to a temporary folder and renders it through the command line
//! (`hypercast render ... --stats`), in a process of its own, and reports
//! wall time and peak resident memory (`VmHWM`). `tests/it/stress.rs` holds
//! the same classes at sizes CI can afford; the results of this experiment
//! are recorded in `docs/robustness.md`.
//!
//!     cargo run --release --example stress            # every case, a markdown table
//!     cargo run --release --example stress -- CASE    # one case, one row

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use hypercast::r#gen::stress::{Chain, deep_chain, mirror_hall, sphere_lattice};

/// A case: its name, what it is, and the scene text with the extra render
/// arguments (the scene's camera gives the size unless they say otherwise).
struct Case {
    name: &'static str,
    what: &'static str,
    scene: fn() -> String,
    args: &'static [&'static str],
}

const CASES: &[Case] = &[
    Case {
        name: "primitives-100k",
        what: "100,000 spheres (flat union), 640×480, cells",
        scene: || sphere_lattice(100_000, 640, 480),
        args: &[],
    },
    Case {
        name: "primitives-100k-cluster",
        what: "the same on 2 nodes of `topology/cluster-d6.ron` (1 GiB each)",
        scene: || sphere_lattice(100_000, 640, 480),
        args: &["--topology", "topology/cluster-d6.ron", "--dim", "1"],
    },
    Case {
        name: "primitives-100k-roth",
        what: "the same, Roth's brute force, 160×120",
        scene: || sphere_lattice(100_000, 160, 120),
        args: &["--accel", "roth"],
    },
    Case {
        name: "chain-10k-difference",
        what: "left-deep chain of 10,000 differences, 640×480, cells",
        scene: || deep_chain(10_000, Chain::LeftDifference, 640, 480),
        args: &[],
    },
    Case {
        name: "chain-10k-union",
        what: "right-deep chain of 10,000 unions, 640×480, cells",
        scene: || deep_chain(10_000, Chain::RightUnion, 640, 480),
        args: &[],
    },
    Case {
        name: "chain-10k-union-roth",
        what: "the same, Roth's brute force",
        scene: || deep_chain(10_000, Chain::RightUnion, 640, 480),
        args: &["--accel", "roth"],
    },
    Case {
        name: "output-4096",
        what: "scenes/small/sphere.ron at 4096×4096, PNG",
        scene: || std::fs::read_to_string(repo("scenes/small/sphere.ron")).expect("sphere.ron"),
        args: &["--width", "4096", "--height", "4096"],
    },
    Case {
        name: "mirror-hall-64",
        what: "closed room of mirrors, max_depth 64, 640×480",
        scene: || mirror_hall(64, false, 640, 480),
        args: &[],
    },
    Case {
        name: "glass-hall-64",
        what: "the room with a glass ball, max_depth 64, 640×480",
        scene: || mirror_hall(64, true, 640, 480),
        args: &[],
    },
];

fn repo(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Peak resident set size of this process, in KiB (`/proc/self/status`).
fn peak_rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Runs one case in this process and prints its table row.
fn run_case(case: &Case) {
    let dir = tempfile::tempdir().expect("a temporary folder");
    let scene = dir.path().join(format!("{}.ron", case.name));
    std::fs::write(&scene, (case.scene)()).expect("scene written");
    let stats = dir.path().join("stats.json");
    let image = dir.path().join("out.png");
    let mut argv: Vec<&str> = vec!["hypercast", "render"];
    let (scene_s, stats_s, image_s) = (
        scene.to_str().unwrap(),
        stats.to_str().unwrap(),
        image.to_str().unwrap(),
    );
    argv.extend([scene_s, "-o", image_s, "--stats", stats_s, "--quiet"]);
    // Files of the project (topologies) by their path in the repository.
    let args: Vec<String> = case
        .args
        .iter()
        .map(|a| match a.strip_prefix("topology/") {
            Some(_) => repo(a).to_string_lossy().into_owned(),
            None => a.to_string(),
        })
        .collect();
    argv.extend(args.iter().map(String::as_str));
    let start = Instant::now();
    let cli = <hypercast::cli::Cli as clap::Parser>::try_parse_from(&argv).expect("arguments");
    let result = hypercast::cli::run(cli);
    let wall = start.elapsed().as_secs_f64();
    let peak = peak_rss_kib().map_or("?".into(), |k| format!("{:.0}", k as f64 / 1024.0));
    let outcome = match result {
        Err(e) => format!("refused: {e}"),
        Ok(()) => {
            let v: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&stats).expect("stats"))
                    .expect("stats JSON");
            let rays = &v["rays"];
            let mut s = format!(
                "ok: {} primitives, rays {}/{}/{}/{} (primary/shadow/reflected/refracted)",
                v["primitives"],
                rays["primary"],
                rays["shadow"],
                rays["reflected"],
                rays["refracted"]
            );
            if let Some(cells) = v["cells"].as_u64() {
                s += &format!(
                    ", {cells} cells, structure {:.1} MiB, build {:.2} s",
                    v["structure_bytes"].as_f64().unwrap_or(0.0) / 1048576.0,
                    v["build_seconds"].as_f64().unwrap_or(0.0)
                );
            }
            s
        }
    };
    println!(
        "| `{}` | {} | {wall:.2} | {peak} | {outcome} |",
        case.name, case.what
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(name) = args.first() {
        let case = CASES
            .iter()
            .find(|c| c.name == name)
            .unwrap_or_else(|| panic!("no case {name}; cases: {}", names()));
        run_case(case);
        return;
    }
    println!("| case | what | wall s | peak RSS MiB | result |");
    println!("|---|---|---|---|---|");
    let exe = std::env::current_exe().expect("own path");
    for case in CASES {
        // A process per case, so that each peak is its own.
        let out = Command::new(&exe)
            .arg(case.name)
            .output()
            .expect("case runs");
        if out.status.success() {
            print!("{}", String::from_utf8_lossy(&out.stdout));
        } else {
            println!(
                "| `{}` | {} | | | failed: {:?} {} |",
                case.name,
                case.what,
                out.status,
                String::from_utf8_lossy(&out.stderr)
                    .trim()
                    .replace('\n', " ")
            );
        }
    }
}

fn names() -> String {
    CASES.iter().map(|c| c.name).collect::<Vec<_>>().join(", ")
}
