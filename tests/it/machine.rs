//! The hypercube machine (issue 4): images bit-identical to one node for
//! every dimension and channel capacity, every ray finished exactly once,
//! no node over budget, refusal of what cannot fit, and faults that end
//! the run with the failing node named.

use hypercast::machine::{self, MachineOptions, Topology};
use hypercast::scene::{Scene, load_scene};
use hypercast::trace::Film;

use crate::util::{cells, repo};

pub fn topo(d: u32) -> Topology {
    Topology::ipsc_d5()
        .with_overrides(Some(d), None)
        .expect("valid override")
}

pub fn machine(
    scene: &Scene,
    d: u32,
    w: u32,
    h: u32,
    capacity: usize,
) -> (Film, machine::MachineStats) {
    let mut o = MachineOptions::new(w, h, 1);
    o.capacity = capacity;
    let (film, stats, _) =
        machine::render(scene, &topo(d), &o, &|_| {}).unwrap_or_else(|e| panic!("d = {d}: {e}"));
    (film, stats)
}

fn check_stats(s: &machine::MachineStats) {
    assert_eq!(s.per_node.len(), 1 << s.dimension);
    for n in &s.per_node {
        assert!(
            n.peak_memory_bytes <= n.memory_budget_bytes,
            "node {} over budget: {n:?}",
            n.node
        );
        assert!(n.peak_memory_bytes >= n.memory_bytes);
    }
    assert!(s.virtual_seconds > 0.0);
}

#[test]
fn every_dimension_gives_the_single_node_image() {
    let scene = load_scene(&repo("scenes/jagged_ball.ron")).unwrap();
    let (w, h) = (64, 48);
    let (one, _) = cells(&scene, w, h);
    for d in 0..=5 {
        for capacity in [machine::DEFAULT_CAPACITY, 1] {
            let (film, stats) = machine(&scene, d, w, h, capacity);
            check_stats(&stats);
            let diff = film
                .sums()
                .iter()
                .zip(one.sums())
                .filter(|(a, b)| a != b)
                .count();
            assert_eq!(
                diff, 0,
                "d = {d}, capacity {capacity}: {diff} pixels differ"
            );
            if d > 0 {
                assert!(stats.messages > 0 && stats.hops > 0);
                // Shadow rays leave as leaves, and the image holds.
                let leaves: u64 = stats.per_node.iter().map(|n| n.leaves_sent).sum();
                assert!(leaves > 0, "d = {d}: no shadow ray went alone");
            }
        }
    }
}

#[test]
fn a_scene_too_large_for_one_node_is_refused_then_fits_on_32() {
    // The sphereflake of level 4 (7,382 primitives) needs about 5.2 MiB
    // whole: more than one iPSC node's 4.5 MiB.
    let scene = load_scene(&repo("scenes/sphereflake4.nff")).unwrap();
    let o = MachineOptions::new(48, 48, 1);
    let e = machine::render(&scene, &topo(0), &o, &|_| {}).expect_err("refused at d = 0");
    let msg = e.to_string();
    assert!(matches!(e, hypercast::error::Error::Capacity(_)), "{msg}");
    assert!(
        msg.contains("node 0 needs") && msg.contains("budget 4.50 MiB") && msg.contains("--dim"),
        "{msg}"
    );
    assert_eq!(e.exit_code(), 2);
    let (_, stats, _) = machine::render(&scene, &topo(5), &o, &|_| {}).expect("fits at d = 5");
    check_stats(&stats);
}

#[test]
fn random_scenes_on_random_dimensions_equal_one_node() {
    use hypercast::r#gen::random::{RandomCsgOptions, random_csg};
    for seed in 0..6u64 {
        let model = random_csg(seed, 12 + seed as usize * 5, &RandomCsgOptions::default());
        let (scene, _) =
            hypercast::scene::load::compile_model(&model, std::path::Path::new("random.ron"))
                .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        let d = ((seed * 5 + 1) % 7) as u32;
        let (w, h) = (32, 24);
        let (one, _) = cells(&scene, w, h);
        let (film, stats) = machine(&scene, d, w, h, 1 + seed as usize % 3);
        check_stats(&stats);
        assert_eq!(film.sums(), one.sums(), "seed {seed}, d = {d}");
    }
}

#[test]
fn a_failing_node_ends_the_run_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    let start = std::time::Instant::now();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hypercast"))
        .args([
            "render",
            repo("scenes/jagged_ball.ron").to_str().unwrap(),
            "--dim",
            "3",
        ])
        .args([
            "--width",
            "64",
            "--height",
            "48",
            "--inject-fault",
            "5:3",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("node 5 failed"), "{err}");
    assert!(!out.exists(), "no output after a failure");
    assert!(start.elapsed().as_secs() < 10, "took {:?}", start.elapsed());
}
