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
            }
        }
    }
}
