//! The paper's space subdivision and space tracing (Priol, Arnaldi and
//! Bouatouch 1987, sections 3-8): minimal boxes (Algorithm 1, in `csg`),
//! the screen-plane BSP and super cells (`bsp`), depth partitioning into
//! cells, corner stitching, per-cell CSG subtrees (Algorithm 3, `subtree`),
//! and the traversal with mailboxes (`traverse`). Reads the scene and the
//! CSG layer; knows nothing of nodes, messages or files.

pub mod bsp;
pub mod projection;
pub mod subtree;
pub mod traverse;

use std::collections::HashMap;
use std::time::Instant;

use crate::csg::{CsgNode, CsgTree, NodeId};
use crate::geom::Aabb;
use crate::scene::Scene;
use crate::trace::CameraFrame;

pub use bsp::{Partition, SegmentChoice};
pub use projection::{CamRay, Rect, Region, View};
pub use traverse::CellTracer;

/// No subtree: the cell is empty.
pub const NO_SUBTREE: u32 = u32::MAX;

/// A cell: a slab `[zlo, zhi)` in depth of a super cell (section 3.3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    pub zlo: f64,
    pub zhi: f64,
    pub super_cell: u32,
    /// Root of the cell's CSG subtree in `CellStructure::subtrees`, or
    /// `NO_SUBTREE`.
    pub subtree: u32,
    /// Primitives that reach into the cell.
    pub prims: u32,
}

/// The cells of one region: its screen partition (super cells with their
/// corner pointers) and each super cell's cells, front to back. The front
/// and back pointers of a cell are implicit: its neighbours in `cells`.
#[derive(Clone, Debug)]
pub struct RegionCells {
    pub region: Region,
    pub partition: Partition,
    /// Cells of super cell `s`: `cells[first_cell[s]..first_cell[s + 1]]`,
    /// sorted by depth.
    pub first_cell: Vec<u32>,
    pub cells: Vec<Cell>,
}

impl RegionCells {
    pub fn cells_of(&self, s: u32) -> std::ops::Range<usize> {
        self.first_cell[s as usize] as usize..self.first_cell[s as usize + 1] as usize
    }

    /// The cell of super cell `s` containing depth `z` for a ray moving
    /// with sign `m` in depth (half-open slabs, ties by direction).
    pub fn cell_at_depth(&self, s: u32, z: f64, m: f64) -> u32 {
        let r = self.cells_of(s);
        let cells = &self.cells[r.clone()];
        let k = cells.partition_point(|c| c.zlo < z || (c.zlo == z && m >= 0.0));
        (r.start + k.saturating_sub(1)) as u32
    }

    /// True when no primitive reaches into super cell `s`: its pixels are
    /// background (the paper's pixel areas, section 3.2).
    pub fn super_cell_is_empty(&self, s: u32) -> bool {
        self.partition.leaves[s as usize].prims.is_empty()
    }
}

/// Build settings.
#[derive(Clone, Copy, Debug, Default)]
pub struct CellOptions {
    pub choice: SegmentChoice,
}

/// Counts that describe a built structure (`--stats`, `inspect`).
#[derive(Clone, Debug, Default)]
pub struct BuildStats {
    pub build_seconds: f64,
    pub super_cells: usize,
    pub cells: usize,
    pub empty_cells: usize,
    pub prims_per_cell_mean: f64,
    pub prims_per_cell_max: usize,
    /// Mean and maximum subtree size of non-empty cells, against the
    /// whole tree's size.
    pub subtree_nodes_mean: f64,
    pub subtree_nodes_max: usize,
    pub tree_nodes: usize,
    /// Distinct subtrees (cells with the same primitives share one).
    pub distinct_subtrees: usize,
    /// Primitives dropped because their minimal box is empty (case 14).
    pub culled_primitives: usize,
    pub bsp_splits: u64,
    pub bytes: usize,
}

/// The whole subdivision of a scene for one camera.
#[derive(Clone, Debug)]
pub struct CellStructure {
    pub view: View,
    pub regions: [RegionCells; 2],
    /// Every cell's subtree, in one arena (roots in `Cell::subtree`).
    pub subtrees: CsgTree,
    pub stats: BuildStats,
}

impl CellStructure {
    pub fn region(&self, r: Region) -> &RegionCells {
        &self.regions[r as usize]
    }

    /// Builds the subdivision (sections 3-6) of `scene` for its camera.
    pub fn build(scene: &Scene, width: u32, height: u32, opts: CellOptions) -> CellStructure {
        let start = Instant::now();
        let cam = CameraFrame::new(scene, width, height);
        let view = View::new(&cam);
        let tree = &scene.tree;
        // Algorithm 1: minimal boxes, per node.
        let minimal = tree.minimal_boxes();
        let mut prim_box = vec![Aabb::EMPTY; scene.primitives.len()];
        for (i, n) in tree.nodes.iter().enumerate() {
            if let CsgNode::Leaf(p) = n {
                prim_box[p.index()] = minimal[i].inflated(1e-12);
            }
        }
        let culled = prim_box.iter().filter(|b| b.is_empty()).count();
        let mut builder = subtree::SubtreeBuilder::new(tree, &minimal, scene.primitives.len());
        let mut subtrees = CsgTree::new();
        let mut memo: HashMap<Vec<u32>, u32> = HashMap::new();
        let mut splits = 0;
        let regions = Region::BOTH.map(|region| {
            let projected: Vec<Option<(Rect, f64, f64)>> = prim_box.iter().map(|b| view.project_box(b, region)).collect();
            let rects: Vec<Option<Rect>> = projected.iter().map(|p| p.map(|(r, _, _)| r)).collect();
            let partition = bsp::partition(&rects, opts.choice);
            splits += partition.splits;
            let mut first_cell = Vec::with_capacity(partition.leaves.len() + 1);
            let mut cells = Vec::new();
            for (s, leaf) in partition.leaves.iter().enumerate() {
                first_cell.push(cells.len() as u32);
                depth_partition(region, s as u32, &leaf.prims, &projected, &mut |cell_prims, zlo, zhi| {
                    let subtree = if cell_prims.is_empty() {
                        NO_SUBTREE
                    } else {
                        let mut key = cell_prims.to_vec();
                        key.sort_unstable();
                        *memo.entry(key).or_insert_with_key(|k| builder.build(k, &mut subtrees).map_or(NO_SUBTREE, |n| n.0))
                    };
                    cells.push(Cell {
                        zlo,
                        zhi,
                        super_cell: s as u32,
                        subtree,
                        prims: cell_prims.len() as u32,
                    });
                });
            }
            first_cell.push(cells.len() as u32);
            RegionCells {
                region,
                partition,
                first_cell,
                cells,
            }
        });
        let mut cs = CellStructure {
            view,
            regions,
            subtrees,
            stats: BuildStats::default(),
        };
        cs.stats = cs.compute_stats(tree, culled, memo.len(), splits);
        cs.stats.build_seconds = start.elapsed().as_secs_f64();
        cs
    }

    fn compute_stats(&self, tree: &CsgTree, culled: usize, distinct: usize, splits: u64) -> BuildStats {
        let mut s = BuildStats {
            culled_primitives: culled,
            distinct_subtrees: distinct,
            bsp_splits: splits,
            tree_nodes: tree.root.map_or(0, |r| tree.size_from(r)),
            ..Default::default()
        };
        let mut prim_sum = 0usize;
        let mut sub_sum = 0usize;
        let mut nonempty = 0usize;
        let mut sizes: HashMap<u32, usize> = HashMap::new();
        for r in &self.regions {
            s.super_cells += r.partition.leaves.len();
            s.cells += r.cells.len();
            for c in &r.cells {
                prim_sum += c.prims as usize;
                s.prims_per_cell_max = s.prims_per_cell_max.max(c.prims as usize);
                if c.subtree == NO_SUBTREE {
                    s.empty_cells += 1;
                    continue;
                }
                nonempty += 1;
                let n = *sizes.entry(c.subtree).or_insert_with(|| self.subtrees.size_from(NodeId(c.subtree)));
                sub_sum += n;
                s.subtree_nodes_max = s.subtree_nodes_max.max(n);
            }
        }
        s.prims_per_cell_mean = prim_sum as f64 / s.cells.max(1) as f64;
        s.subtree_nodes_mean = sub_sum as f64 / nonempty.max(1) as f64;
        s.bytes = self.bytes();
        s
    }

    /// Bytes of the structure as held in memory: cells, super cells with
    /// their pointers and primitive lists, BSP nodes and subtree arena.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        let mut b = size_of::<Self>();
        for r in &self.regions {
            b += r.cells.len() * size_of::<Cell>() + r.first_cell.len() * 4;
            b += r.partition.nodes.len() * size_of::<bsp::BspNode>();
            b += r.partition.leaves.iter().map(|l| size_of::<bsp::Leaf>() + l.prims.len() * 4).sum::<usize>();
        }
        let t = &self.subtrees;
        b += t.nodes.len() * size_of::<CsgNode>() + t.children.len() * 4 + t.bounds.len() * 2 * size_of::<Aabb>();
        b
    }
}

/// Depth partitioning of one super cell (section 3.3, figure 5): the
/// depth extents of its primitives cut it into cells, empty ones included,
/// so that the cells partition the region. `emit(prims, zlo, zhi)` is
/// called front to back.
///
/// Where many primitives overlap (more than 15 in a cell), consecutive cuts
/// are merged until an eighth of the cell's primitives have changed, so
/// that piles of overlapping primitives end in a bounded number of cells
/// (`ROBUSTNESS.md` case 15); a merged cell keeps every primitive that
/// reaches into any part of it.
fn depth_partition(region: Region, _s: u32, prims: &[u32], projected: &[Option<(Rect, f64, f64)>], emit: &mut dyn FnMut(&[u32], f64, f64)) {
    let (rz0, rz1) = region.depth_range();
    // Events: (z, is_add, prim).
    let mut events: Vec<(f64, bool, u32)> = Vec::with_capacity(prims.len() * 2);
    for &p in prims {
        if let Some((_, z0, z1)) = projected[p as usize] {
            events.push((z0, true, p));
            events.push((z1, false, p));
        }
    }
    events.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut active: Vec<u32> = Vec::new();
    let mut i = 0;
    // Events at or before the region's near bound apply to the first cell.
    while i < events.len() && events[i].0 <= rz0 {
        apply(&mut active, None, events[i]);
        i += 1;
    }
    let mut cell_set = active.clone();
    let mut cell_lo = rz0;
    let mut changes = 0usize;
    while i < events.len() && events[i].0 < rz1 {
        let b = events[i].0;
        let mut j = i;
        while j < events.len() && events[j].0 == b {
            j += 1;
        }
        let threshold = (cell_set.len() / 8).max(1);
        if changes + (j - i) >= threshold {
            emit(&cell_set, cell_lo, b);
            for e in &events[i..j] {
                apply(&mut active, None, *e);
            }
            cell_set.clone_from(&active);
            cell_lo = b;
            changes = 0;
        } else {
            for e in &events[i..j] {
                apply(&mut active, Some(&mut cell_set), *e);
            }
            changes += j - i;
        }
        i = j;
    }
    emit(&cell_set, cell_lo, rz1);
}

fn apply(active: &mut Vec<u32>, cell_set: Option<&mut Vec<u32>>, (_, add, p): (f64, bool, u32)) {
    if add {
        active.push(p);
        if let Some(s) = cell_set {
            s.push(p);
        }
    } else if let Some(k) = active.iter().position(|&x| x == p) {
        active.swap_remove(k);
    }
}
