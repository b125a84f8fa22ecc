//! Which node owns which super cell (its cells, their subtrees, the pixels
//! of its pixel area). Super cells are ordered by a depth-first walk of the
//! screen BSP, so that runs of the order are compact screen regions; the
//! order is cut into 2^d runs and run i goes to node `gray(i)`, so that
//! neighbouring regions land on hypercube neighbours (consecutive Gray
//! codes differ in one bit). Where the cuts fall is the load balance:
//!
//! * `Balanced` (default) weighs each super cell by the work a cheap
//!   pre-pass measured there: every `stride`-th pixel of every
//!   `stride`-th row traced through the whole structure on the host, all
//!   its ray kinds, counting cells entered and intersection tests (a
//!   mailbox hit counting as a test, since on the machine it mostly is
//!   one, on another node), after Priol and Bouatouch's static load
//!   balancing on the iPSC; on more than one node, a second pre-pass walks
//!   as the machine will under the first pass's mapping (`prepass`).
//!   Measured on the iPSC-D5, against counting
//!   tests alone: the sphereflake at 1024x1024 on 32 nodes 1.33 against
//!   1.37-1.41 busy imbalance, on 8 nodes 1.10 against 1.14; the jagged
//!   ball on 8 nodes 1.49 against 1.65 (makespan 1,300 against 1,510
//!   virtual seconds);
//! * `EqualArea`, the naive split, weighs each super cell by its share of
//!   the image, so that every node owns as many pixels.

use crate::cells::{BspNode, CellStructure, CellTracer, Partition, Region};
use crate::machine::routing::gray;
use crate::render::pixel_jobs;
use crate::scene::Scene;
use crate::trace::{CameraFrame, Film, RayCounts, Shader};

/// How the load is balanced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Mapping {
    #[default]
    Balanced,
    EqualArea,
}

impl Mapping {
    pub fn name(self) -> &'static str {
        match self {
            Mapping::Balanced => "balanced",
            Mapping::EqualArea => "equal-area",
        }
    }
}

/// Pixels per side of the pre-pass's sampling grid cell.
pub const PREPASS_STRIDE: u32 = 8;

/// The estimated work of every super cell, per region.
pub fn estimate(
    cs: &CellStructure,
    scene: &Scene,
    width: u32,
    height: u32,
    mapping: Mapping,
    d: u32,
) -> [Vec<f64>; 2] {
    match mapping {
        Mapping::EqualArea => Region::BOTH.map(|r| {
            let rc = cs.region(r);
            if r == Region::Back {
                // No pixel lies behind the eye: spread those evenly.
                return vec![0.0; rc.supers.len()];
            }
            let cam = CameraFrame::new(scene, width, height);
            rc.supers
                .iter()
                .map(|s| {
                    let w = (s.rect.x1.min(cam.half_w) - s.rect.x0.max(-cam.half_w)).max(0.0);
                    let h = (s.rect.y1.min(cam.half_h) - s.rect.y0.max(-cam.half_h)).max(0.0);
                    w * h
                })
                .collect()
        }),
        Mapping::Balanced => {
            let first = prepass(cs, scene, width, height, None);
            if d == 0 {
                return first;
            }
            // Walked again as the machine will: cold mailboxes where a ray
            // crosses to another owner under the first pass's mapping.
            let owner = assign(cs, &first, d);
            prepass(cs, scene, width, height, Some(owner))
        }
    }
}

/// Traces every `PREPASS_STRIDE`-th pixel of every `PREPASS_STRIDE`-th row
/// through the whole structure, all its ray kinds, recording the work per
/// super cell; with `owner`, as the machine walks under that mapping (a
/// ray that crosses to another node's super cell meets again, as tests,
/// the primitives it met before).
///
/// Why two passes: the first pass alone balances what one node would do,
/// but on the machine the work a ray repeats after a crossing falls on
/// the node it crosses to. Sphereflake level 4, 1024x1024, 32 nodes, four
/// alternating runs each: busy imbalance 1.28-1.34 with one pass,
/// 1.25-1.27 with two (makespan 3,350-4,130 against 3,250-3,850 virtual
/// seconds); a third pass changed nothing. (The nodes' intersection tests
/// are less even with two, 1.56 against 1.42 max/mean, but busy time is
/// what the modelled nodes spend.)
fn prepass(
    cs: &CellStructure,
    scene: &Scene,
    width: u32,
    height: u32,
    owner: Option<[Vec<u16>; 2]>,
) -> [Vec<f64>; 2] {
    let cam = CameraFrame::new(scene, width, height);
    let shader = Shader::new(scene);
    let mut tracer = CellTracer::new(cs, scene);
    match owner {
        Some(o) => tracer.record_work_for(o),
        None => tracer.record_work(),
    }
    let mut film = Film::new(width, height);
    let (mut counts, mut stack, mut jobs) = (RayCounts::default(), Vec::new(), Vec::new());
    let half = PREPASS_STRIDE / 2;
    for j in (half.min(height - 1)..height).step_by(PREPASS_STRIDE as usize) {
        for i in (half.min(width - 1)..width).step_by(PREPASS_STRIDE as usize) {
            jobs.clear();
            pixel_jobs(&cam, i, j, 1, &mut jobs);
            for job in jobs.drain(..) {
                shader.run_path(&mut tracer, job, &mut film, &mut counts, &mut stack);
            }
        }
    }
    let work = tracer.recorded_work().expect("recording");
    [0, 1].map(|r| work[r].iter().map(|&w| w as f64).collect())
}

/// Super cells of a partition in depth-first BSP order.
pub fn bsp_order(p: &Partition) -> Vec<u32> {
    let mut out = Vec::with_capacity(p.leaves.len());
    let mut stack = vec![0u32];
    while let Some(n) = stack.pop() {
        match p.nodes[n as usize] {
            BspNode::Leaf(l) => out.push(l),
            BspNode::Split { lo, hi, .. } => {
                stack.push(hi);
                stack.push(lo);
            }
        }
    }
    out
}

/// The owner of every super cell of each region, for `2^d` nodes: the
/// regions' super cells in BSP order (front, then back) cut into runs of
/// equal estimated work, run i on node `gray(i)`. Every super cell also
/// weighs a little (a share of the mean), so that work-free stretches
/// still spread out.
pub fn assign(cs: &CellStructure, work: &[Vec<f64>; 2], d: u32) -> [Vec<u16>; 2] {
    let nodes = 1usize << d;
    let order: Vec<(usize, u32)> = Region::BOTH
        .iter()
        .flat_map(|&r| {
            bsp_order(&cs.region(r).partition)
                .into_iter()
                .map(move |s| (r as usize, s))
        })
        .collect();
    let total: f64 = order.iter().map(|&(r, s)| work[r][s as usize]).sum();
    let floor = 0.01 * total.max(1.0) / order.len().max(1) as f64;
    let weight = |r: usize, s: u32| work[r][s as usize] + floor;
    let sum: f64 = order.iter().map(|&(r, s)| weight(r, s)).sum();
    let mut owner = Region::BOTH.map(|r| vec![0u16; cs.region(r).supers.len()]);
    let mut acc = 0.0;
    for &(r, s) in &order {
        let w = weight(r, s);
        // The run whose share of the total contains this cell's middle.
        let run = (((acc + w / 2.0) / sum) * nodes as f64) as usize;
        acc += w;
        owner[r][s as usize] = gray(run.min(nodes - 1) as u16);
    }
    owner
}

/// The largest estimated load of a node against the mean (1 is perfect).
pub fn predicted_imbalance(work: &[Vec<f64>; 2], owner: &[Vec<u16>; 2], d: u32) -> f64 {
    let mut load = vec![0.0; 1 << d];
    for r in 0..2 {
        for (s, &o) in owner[r].iter().enumerate() {
            load[o as usize] += work[r][s];
        }
    }
    let mean = load.iter().sum::<f64>() / load.len() as f64;
    if mean > 0.0 {
        load.iter().cloned().fold(0.0, f64::max) / mean
    } else {
        1.0
    }
}
