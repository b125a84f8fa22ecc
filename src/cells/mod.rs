//! The paper's space subdivision and space tracing (Priol, Arnaldi and
//! Bouatouch 1987, sections 3-8): minimal boxes (Algorithm 1, in `csg`),
//! the screen-plane BSP and super cells (`bsp`), depth partitioning into
//! cells, corner stitching, per-cell CSG subtrees (Algorithm 3, `subtree`),
//! and the traversal with mailboxes (`traverse`). Reads the scene and the
//! CSG layer; knows nothing of nodes, messages or files.

pub mod bsp;
pub mod projection;
pub mod share;
pub mod subtree;
pub mod traverse;

use std::collections::HashMap;
use std::time::Instant;

use crate::csg::{CsgNode, CsgTree, NodeId, Op, PrimId, Primitive};
use crate::error::{Result, start_worker};
use crate::geom::{Aabb, Vec3};
use crate::scene::Scene;
use crate::trace::CameraFrame;

pub use bsp::{BspNode, Hot, Partition, SegmentChoice};
pub use projection::{CamBox, CamRay, Rect, Region, View};
pub use traverse::{CELL_WORK, CellTracer, Copies, Move, TEST_WORK, Walk, WalkPoint};

/// No subtree: the cell is empty.
pub const NO_SUBTREE: u32 = u32::MAX;

/// The cell holds primitives, but its subtree lives on another node of the
/// machine (`CellStructure::restrict`): a walk that reaches it stops there.
/// A remote cell's subtree is `REMOTE + i`, `i` the index of its hull in
/// `RegionCells::remote_hull` (so that empty and owned cells keep none);
/// subtree roots are below `REMOTE`.
pub const REMOTE: u32 = 1 << 31;

/// Whether a cell's subtree field says the cell is held elsewhere.
#[inline]
pub fn is_remote(subtree: u32) -> bool {
    (REMOTE..NO_SUBTREE).contains(&subtree)
}

/// A cell: a slab `[zlo, zhi)` in depth of a super cell (section 3.3), as
/// `RegionCells::cell` puts it together. The structure keeps only what the
/// walk reads, per cell its `zlo` and its subtree (`RegionCells`); the
/// rest follows from the order of the cells.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    pub zlo: f64,
    pub zhi: f64,
    pub super_cell: u32,
    /// Root of the cell's CSG subtree in `CellStructure::subtrees`,
    /// `NO_SUBTREE`, or remote (`is_remote`).
    pub subtree: u32,
}

/// What the walk reads of a super cell: its rectangle and its eight corner
/// pointers (section 4, figure 6), in one 64-byte cache line. The same as
/// the partition's `Leaf::rect` and `Leaf::stitches`, without the primitive
/// list, so that the corner-stitch walk of figure 13 touches one line per
/// super cell (the 88-byte `Leaf`s with their list pointers straddled two).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[repr(C, align(64))]
pub struct SuperCell {
    pub rect: Rect,
    pub stitches: [u32; 8],
}

/// The cells of one region: its screen partition (super cells with their
/// corner pointers) and each super cell's cells, front to back. The front
/// and back pointers of a cell are implicit: its neighbours in the lists.
///
/// Every node of the machine holds this skeleton of the whole structure
/// (`CellStructure::restrict`), so it is kept lean: per cell 4 bytes of
/// subtree and 8 of depth (a cell's far end is the next one's near end:
/// the cells of a super cell tile the region's depth range), plus, in a
/// share, 12 of hull for a cell held elsewhere.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RegionCells {
    pub region: Region,
    /// The BSP. Its leaves (rectangles, primitive lists, corner pointers)
    /// are the builder's; a node's share has none (`supers` holds what
    /// the walk reads).
    pub partition: Partition,
    /// Cells of super cell `s`: `first_cell[s]..first_cell[s + 1]`, sorted
    /// by depth.
    pub first_cell: Vec<u32>,
    /// Per cell, the near end of its depth slab. Depth cuts are chosen as
    /// f32 values (`depth_partition`), so 4 bytes hold them exactly.
    pub zlo: Vec<f32>,
    /// Per cell, the root of its CSG subtree in `CellStructure::subtrees`,
    /// `NO_SUBTREE` (empty) or remote (held by another node, `REMOTE`).
    pub subtree: Vec<u32>,
    /// Per super cell, what the walk reads (the partition's leaves in a
    /// compact copy).
    pub supers: Vec<SuperCell>,
    /// In a node's share (`CellStructure::restrict`), for each subtree of
    /// the cells held elsewhere (a cell's `REMOTE + i` names its hull), the
    /// hull of the subtree's leaves' culling boxes,
    /// quantised outwards on the scene box (`share::Hull`); empty on a
    /// whole structure. A ray whose part in such a cell misses the hull
    /// cannot meet anything there, so the walk goes on without sending the
    /// ray to the owner (`traverse::CellTracer::walk`).
    pub remote_hull: Vec<share::Hull>,
}

impl RegionCells {
    pub fn cells_of(&self, s: u32) -> std::ops::Range<usize> {
        self.first_cell[s as usize] as usize..self.first_cell[s as usize + 1] as usize
    }

    /// Number of cells.
    pub fn cell_count(&self) -> usize {
        self.zlo.len()
    }

    /// The far end of cell `k` of super cell `s`: the next cell's near end,
    /// or the end of the region's depth range after the last.
    #[inline]
    pub fn zhi(&self, s: u32, k: u32) -> f64 {
        let next = k as usize + 1;
        if next < self.first_cell[s as usize + 1] as usize {
            self.zlo[next].into()
        } else {
            self.region.depth_range().1
        }
    }

    /// The super cell cell `k` belongs to.
    pub fn super_cell_of(&self, k: u32) -> u32 {
        (self.first_cell.partition_point(|&f| f <= k) - 1) as u32
    }

    /// Cell `k`, put together.
    pub fn cell(&self, k: u32) -> Cell {
        let s = self.super_cell_of(k);
        Cell {
            zlo: self.zlo[k as usize].into(),
            zhi: self.zhi(s, k),
            super_cell: s,
            subtree: self.subtree[k as usize],
        }
    }

    /// Every cell, in order.
    pub fn cells(&self) -> impl Iterator<Item = Cell> + '_ {
        (0..self.cell_count() as u32).map(|k| self.cell(k))
    }

    /// The cell of super cell `s` containing depth `z` for a ray moving
    /// with sign `m` in depth (half-open slabs, ties by direction).
    #[inline]
    pub fn cell_at_depth(&self, s: u32, z: f64, m: f64) -> u32 {
        let r = self.cells_of(s);
        let zlo = &self.zlo[r.clone()];
        let before = |lo: f32| {
            let lo = f64::from(lo);
            lo < z || (lo == z && m >= 0.0)
        };
        // Super cells have few cells: a scan, short of a binary search.
        let k = if zlo.len() <= 8 {
            zlo.iter().take_while(|&&lo| before(lo)).count()
        } else {
            zlo.partition_point(|&lo| before(lo))
        };
        (r.start + k.saturating_sub(1)) as u32
    }

    /// True when none of super cell `s`'s cells has a subtree: its pixels
    /// are background (the paper's pixel areas, section 3.2). (A cell held
    /// by another node is `REMOTE`, not empty.)
    pub fn super_cell_is_empty(&self, s: u32) -> bool {
        self.subtree[self.cells_of(s)]
            .iter()
            .all(|&t| t == NO_SUBTREE)
    }
}

/// Build settings.
#[derive(Clone, Copy, Debug, Default)]
pub struct CellOptions {
    pub choice: SegmentChoice,
    /// Front super cells the BSP makes at least, where its regions hold
    /// primitives to split by (`bsp::partition_in`). The machine asks for
    /// `SUPER_CELLS_PER_NODE` per node, so that its mapping can balance
    /// them (a super cell is never split over nodes); one node needs none.
    pub min_super_cells: usize,
    /// Forces `min_super_cells` from the BSP's first level on, instead of
    /// only where the cost model alone makes fewer. Where nodes hold no
    /// copies (`--replicas none`, the paper's plan alone), the first cuts
    /// then line the nodes' boundaries up with the scene's: the
    /// sphereflake at d = 1 (1024x1024) sends 235,000 paths between its
    /// two nodes instead of 287,000 (3.26 M hops at d = 5 instead of
    /// 3.40 M).
    pub force_from_root: bool,
    /// Leaves out the shadow cache (`CellTracer::walk_shadow`), for
    /// experiments and for tests of the machine's pre-pass: the cache's
    /// hits depend on the order rays reach a node, which the pre-pass can
    /// only approach, and without it the pre-pass predicts every node's
    /// work exactly.
    pub no_shadow_cache: bool,
    /// Threads that cut super cells into cells (`cut_super_cells`); 0:
    /// the host's cores, for scenes large enough to gain from them. The
    /// structure is the same for any number.
    pub build_threads: usize,
}

/// Front super cells per node the machine asks the build for. The cost
/// model alone stops at 36 on `jagged_ball.ron`: on 32 nodes its busy
/// imbalance was 3.2 and its makespan about 5,200 virtual seconds; with 4
/// per node 2.4 and 3,600-4,400, with 8 1.9 and 3,800-3,900, with 16 2.1
/// and 4,000 (1024x1024, two runs each). Forcing them on every render
/// would cost a single node time (4 per node of 32: jagged_ball 0.142 s
/// against 0.123 s at 640x480), so only the machine asks, by its node
/// count.
pub const SUPER_CELLS_PER_NODE: usize = 8;

/// Counts that describe a built structure (`--stats`, `inspect`).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
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
    /// Splits the cost model alone would not have made (for the
    /// machine's balance, `Partition::forced`): 0 where the structure is
    /// the one a single node builds.
    pub forced_splits: u64,
    pub bytes: usize,
    /// How far every minimal box is grown for the rounding of the walk
    /// (`walk_rounding`), in world units: nil on scenes of everyday sizes,
    /// as large as the scene's detail on one reaching 1e13 times beyond
    /// it, where the subdivision can no longer split the view
    /// (`docs/robustness.md`).
    pub walk_margin: f64,
}

/// The whole subdivision of a scene for one camera.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CellStructure {
    pub view: View,
    pub regions: [RegionCells; 2],
    /// Every cell's subtree, in one arena (roots in `Cell::subtree`).
    pub subtrees: CsgTree,
    /// Per node of `subtrees`, the scene tree node it stands for (mailboxes
    /// of culling results are kept per scene node, `traverse`).
    pub origin: Vec<u32>,
    /// One more than the largest value in `origin`: the number of
    /// operator mailboxes a tracer keeps.
    pub origin_count: usize,
    /// Per cell subtree (indexed by its root in `subtrees`), its leaves in
    /// `subtree_leaves[leaf_span[root][0]..leaf_span[root][1]]`.
    pub leaf_span: Vec<[u32; 2]>,
    pub subtree_leaves: Vec<SubtreeLeaf>,
    /// A box around every primitive's minimal box, inflated: the space the
    /// cells partition (section 3, "the 3D space bounding the whole
    /// scene"). Rays are followed through the cells only inside it.
    pub scene_box: Aabb,
    /// What shadow walks may take short (`CellTracer::walk_shadow`).
    pub shadows: ShadowFacts,
    /// The space of all primitives but the widest, where a walk that does
    /// not cross that one is kept (`CellTracer::walk`); None when leaving
    /// no primitive out shrinks the scene box enough.
    pub clip: Option<Box<WideClip>>,
    /// In a node's share, the whole scene's index of each primitive its
    /// scene holds (ascending: a share keeps the whole scene's order);
    /// empty for the whole structure, whose indices are the scene's.
    pub primitive_ids: Vec<u32>,
    pub stats: BuildStats,
}

impl CellStructure {
    pub fn region(&self, r: Region) -> &RegionCells {
        &self.regions[r as usize]
    }

    /// The whole scene's index of primitive `p` of this structure's scene.
    pub fn global_primitive(&self, p: PrimId) -> PrimId {
        match self.primitive_ids.get(p.index()) {
            Some(&g) => PrimId(g),
            None => p,
        }
    }

    /// This structure's index of the whole scene's primitive `g`, if its
    /// scene holds it.
    pub fn local_primitive(&self, g: PrimId) -> Option<PrimId> {
        if self.primitive_ids.is_empty() {
            return Some(g);
        }
        let k = self.primitive_ids.binary_search(&g.0).ok()?;
        Some(PrimId(k as u32))
    }

    /// Builds the subdivision (sections 3-6) of `scene` for its camera.
    /// Fails (`Error::Render`) only if the OS refuses a thread of the
    /// depth cuts (`cut_super_cells`).
    pub fn build(
        scene: &Scene,
        width: u32,
        height: u32,
        opts: CellOptions,
    ) -> Result<CellStructure> {
        Self::build_with_hot(scene, width, height, opts, &[[].as_slice(), &[]])
    }

    /// `build`, with the leaves of each region's partition kept small
    /// inside its hot spots (`bsp::Hot`).
    pub fn build_with_hot(
        scene: &Scene,
        width: u32,
        height: u32,
        opts: CellOptions,
        hot: &[&[bsp::Hot]; 2],
    ) -> Result<CellStructure> {
        let start = Instant::now();
        let cam = CameraFrame::new(scene, width, height);
        let view = View::new(&cam);
        let tree = &scene.tree;
        // Algorithm 1: minimal boxes, per node.
        let minimal = tree.minimal_boxes();
        let mut prim_box = vec![Aabb::EMPTY; scene.primitives.len()];
        // Each primitive's minimal box as Algorithm 1 gives it, before the
        // padding below: where the eye lies within that padding of its
        // boundary, no side of it can be told (`whole`).
        let mut core_box = vec![Aabb::EMPTY; scene.primitives.len()];
        for (i, n) in tree.nodes.iter().enumerate() {
            if let CsgNode::Leaf(p) = n {
                core_box[p.index()] = minimal[i];
                prim_box[p.index()] = minimal[i].inflated_each(1e-12);
            }
        }
        // Each box is grown by the rounding of the walk itself, not only
        // by its own (`walk_rounding`): a ray from a sphere of radius 1e6
        // around the scene crossed a floor seen edge-on behind the eye,
        // whose super cell, 5e-12 wide, the walk crossed in no `t` at all,
        // and the cell after it did not hold the floor.
        let margin = walk_rounding(&prim_box, view.eye);
        for b in &mut prim_box {
            if !b.is_empty() {
                *b = Aabb {
                    min: b.min - Vec3::splat(margin),
                    max: b.max + Vec3::splat(margin),
                };
            }
        }
        let culled = prim_box.iter().filter(|b| b.is_empty()).count();
        let scene_box = prim_box
            .iter()
            .fold(Aabb::EMPTY, |a, b| a.union(b))
            .inflated(1e-9);
        let mut builder = subtree::SubtreeBuilder::new(tree, &minimal, scene.primitives.len());
        let mut subtrees = CsgTree::new();
        let mut origin = Vec::new();
        let mut memo: HashMap<Vec<u32>, u32> = HashMap::new();
        let (mut splits, mut forced) = (0, 0);
        // Primitives per cell, for the statistics only.
        let mut prim_counts = Vec::new();
        // A box with the eye at its boundary, to rounding and padding, is
        // in every super cell over its whole depth, in both regions
        // (`View::eye_near_boundary`): its corners give the depth,
        // unclipped. (With the padding left out of the band, a box whose
        // face held the eye exactly, which the padding then put just
        // inside, was clipped to the directions from the eye into it: a
        // ray that left the box through the eye, its exit at the very
        // start of the region after the eye plane, found that cell
        // without the box, and missed the exit Roth found.) A box holding
        // the eye deeper is clipped, but never away (`EyeAt::Inside`).
        let eye_at: Vec<EyeAt> = prim_box
            .iter()
            .zip(&core_box)
            .map(|(b, core)| {
                if view.eye_near_boundary(b, core) {
                    EyeAt::Boundary
                } else if b.contains(view.eye) {
                    EyeAt::Inside
                } else {
                    EyeAt::Outside
                }
            })
            .collect();
        let mut region_cells = |region: Region| -> Result<RegionCells> {
            let projected: Vec<Option<(Rect, f64, f64)>> = prim_box
                .iter()
                .zip(&core_box)
                .map(|(b, core)| view.project_box(b, core, region))
                .collect();
            let rects: Vec<Option<Rect>> = projected.iter().map(|p| p.map(|(r, _, _)| r)).collect();
            // The front region's screen window: where primary rays go.
            let window = (region == Region::Front).then(|| Rect {
                x0: -cam.half_w,
                x1: cam.half_w,
                y0: -cam.half_h,
                y1: cam.half_h,
            });
            // A primitive costs a ray crossing its super cell in proportion
            // to the share of the depth range it spans there (the depth
            // partition keeps it out of the other cells), plus a share for
            // the rays along depth that cross every cell (primary rays).
            let (zmin, zmax) = projected
                .iter()
                .flatten()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                    (a.min(p.1), b.max(p.2))
                });
            let extent = zmax - zmin;
            let all: f64 = 0.2;
            let weights: Vec<f64> = projected
                .iter()
                .map(|p| match p {
                    Some((_, z0, z1)) if extent.is_finite() && extent > 0.0 => {
                        all + (1.0 - all) * ((z1 - z0) / extent).min(1.0)
                    }
                    _ => 1.0,
                })
                .collect();
            let min_leaves = if region == Region::Front {
                opts.min_super_cells
            } else {
                0
            };
            // Forced splits only where the cost model alone makes fewer
            // super cells than asked, unless `force_from_root`: forced
            // from the start, the first levels of the BSP (when only a
            // few regions exist) split where it would not pay, even for a
            // scene that makes plenty (the sphereflake of level 4 gained
            // 2 super cells on 492 at d = 1, and the host then had to
            // build the single node's structure too, to bound its copies:
            // `machine::replicas`).
            let partition_with = |min_leaves| {
                bsp::partition_in(
                    &rects,
                    opts.choice,
                    window,
                    Some(&weights),
                    min_leaves,
                    hot[region as usize],
                )
            };
            let mut partition = partition_with(if opts.force_from_root { min_leaves } else { 0 });
            if !opts.force_from_root && partition.leaves.len() < min_leaves {
                partition = partition_with(min_leaves);
            }
            splits += partition.splits;
            forced += partition.forced;
            let cam_boxes: Vec<Option<projection::CamBox>> = prim_box
                .iter()
                .zip(&rects)
                .map(|(b, r)| r.map(|_| view.cam_box(b)))
                .collect();
            // Each super cell's depth partition is its own (section 3.3), so
            // they are cut in parallel (`cut_super_cells`); their cells'
            // subtrees are then built here in super-cell order, so the
            // structure is the same whatever the threads.
            let cut = cut_super_cells(
                region,
                &mut partition.leaves,
                &cam_boxes,
                &eye_at,
                opts.build_threads,
            )?;
            let mut first_cell = Vec::with_capacity(partition.leaves.len() + 1);
            let (mut zlos, mut subtree_of) = (Vec::new(), Vec::new());
            for cells in cut {
                first_cell.push(zlos.len() as u32);
                for cell in cells {
                    prim_counts.push(cell.prims.len());
                    let subtree = if cell.prims.is_empty() {
                        NO_SUBTREE
                    } else {
                        *memo.entry(cell.prims).or_insert_with_key(|k| {
                            builder
                                .build(k, &mut subtrees, &mut origin)
                                .map_or(NO_SUBTREE, |n| n.0)
                        })
                    };
                    zlos.push(cell.zlo);
                    subtree_of.push(subtree);
                }
            }
            first_cell.push(zlos.len() as u32);
            let supers = partition
                .leaves
                .iter()
                .map(|l| SuperCell {
                    rect: l.rect,
                    stitches: l.stitches,
                })
                .collect();
            Ok(RegionCells {
                region,
                partition,
                first_cell,
                zlo: zlos,
                subtree: subtree_of,
                supers,
                remote_hull: Vec::new(),
            })
        };
        let regions = [region_cells(Region::Front)?, region_cells(Region::Back)?];
        // The distinct subtrees' leaf lists, laid out in the order the
        // subtrees were built (super cell after super cell), not in the
        // memo's hash order, which changed from build to build: the same
        // structure, byte for byte, every time, and the lists of
        // neighbouring cells near each other in memory.
        let distinct = memo.len();
        let mut roots: Vec<u32> = memo.into_values().collect();
        roots.sort_unstable();
        let (leaf_span, subtree_leaves) = subtree_leaf_lists(&subtrees, roots.into_iter());
        // Roots are below REMOTE: 2^31 subtree nodes would be hundreds of
        // GB, past any memory this runs in.
        assert!(
            subtrees.nodes.len() < REMOTE as usize,
            "subtree arena too large"
        );
        let mut cs = CellStructure {
            view,
            regions,
            subtrees,
            origin,
            origin_count: tree.nodes.len(),
            shadows: ShadowFacts::of(scene, &minimal, !opts.no_shadow_cache),
            clip: WideClip::of(scene, &prim_box, &scene_box),
            primitive_ids: Vec::new(),
            leaf_span,
            subtree_leaves,
            scene_box,
            stats: BuildStats::default(),
        };
        cs.stats = cs.compute_stats(tree, culled, distinct, splits, &prim_counts);
        cs.stats.forced_splits = forced;
        cs.stats.walk_margin = margin;
        cs.stats.build_seconds = start.elapsed().as_secs_f64();
        Ok(cs)
    }

    fn compute_stats(
        &self,
        tree: &CsgTree,
        culled: usize,
        distinct: usize,
        splits: u64,
        prim_counts: &[usize],
    ) -> BuildStats {
        let mut s = BuildStats {
            culled_primitives: culled,
            distinct_subtrees: distinct,
            bsp_splits: splits,
            tree_nodes: tree.root.map_or(0, |r| tree.size_from(r)),
            ..Default::default()
        };
        let prim_sum: usize = prim_counts.iter().sum();
        s.prims_per_cell_max = prim_counts.iter().copied().max().unwrap_or(0);
        let mut sub_sum = 0usize;
        let mut nonempty = 0usize;
        let mut sizes: HashMap<u32, usize> = HashMap::new();
        for r in &self.regions {
            s.super_cells += r.supers.len();
            s.cells += r.cell_count();
            for &t in &r.subtree {
                if t == NO_SUBTREE {
                    s.empty_cells += 1;
                    continue;
                }
                nonempty += 1;
                let n = *sizes
                    .entry(t)
                    .or_insert_with(|| self.subtrees.size_from(NodeId(t)));
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
        let mut b = size_of::<Self>() + self.shadows.bytes() + self.primitive_ids.len() * 4;
        if let Some(c) = &self.clip {
            b += size_of::<WideClip>() + c.prim.heap_bytes();
        }
        for r in &self.regions {
            b += r.subtree.len() * 4
                + r.first_cell.len() * 4
                + r.supers.len() * size_of::<SuperCell>()
                + r.zlo.len() * 4
                + r.remote_hull.len() * size_of::<share::Hull>();
            b += r.partition.nodes.len() * size_of::<bsp::BspNode>();
            b += r
                .partition
                .leaves
                .iter()
                .map(|l| size_of::<bsp::Leaf>() + l.prims.len() * 4)
                .sum::<usize>();
        }
        let t = &self.subtrees;
        b += t.nodes.len() * size_of::<CsgNode>()
            + t.children.len() * 4
            + t.bounds.len() * 2 * size_of::<Aabb>()
            + self.origin.len() * 4
            + self.leaf_span.len() * 8
            + self.subtree_leaves.len() * size_of::<SubtreeLeaf>();
        b
    }
}

/// A walk's clip to the space of every primitive but one, the widest: a
/// ray that crosses no boundary of that one over its range can meet a
/// surface only in the box of the others (every surface of the scene's
/// solid lies on some primitive, within its minimal box). A ground plane
/// under a small object is the case: a ray that leaves the object upward
/// or sideways need not walk the empty cells above the whole ground. Kept
/// with every share, since the walk resumed on another node must make the
/// same choice from the ray alone.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WideClip {
    pub prim: Primitive,
    /// The primitive's culling box (its bounds, inflated as
    /// `CsgTree::cull_bounds` are): a ray whose range misses it crosses
    /// none of its boundaries there, without a test.
    pub cull: Aabb,
    /// The primitive's index in the structure's scene (a share's
    /// renumbering), or `NOT_HELD` where the share holds no cell of it:
    /// the clip's test fills its mailbox, which the walk then finds.
    pub id: u32,
    /// The primitive's index in the whole scene, to know it in a ray's
    /// `RayJob::leaving` on any node.
    pub global: PrimId,
    /// A box around the other primitives' minimal boxes, inflated as the
    /// scene box is.
    pub rest: Aabb,
}

/// How much smaller (in surface area, which is what random rays meet) the
/// box of the rest must be than the scene box for `WideClip` to be kept:
/// the clip costs every walk one intersection test, and it moves work
/// between super cells, which the machine's balance must follow. Measured
/// (callgrind, one thread, 256x256, build included): the sphereflake's
/// floor leaves 1.3% of the area, and the render takes 8.5% fewer
/// instructions; the jagged ball's base 5.4%, 18% fewer. `csg_basics.ron`'s
/// base leaves 18%: 3.0% fewer (at 320x240), while its predicted imbalance
/// on 32 nodes went from 1.17 to 1.26. `house.ron`'s widest, a sphere,
/// leaves 48%: 3.9% more.
const WIDE_GAIN: f64 = 0.1;

/// `WideClip::id` of a share that holds no cell of the clip's primitive.
pub const NOT_HELD: u32 = u32::MAX;

impl WideClip {
    /// The primitive whose leaving out shrinks the scene box the most, if
    /// that shrinks it by `WIDE_GAIN`. `prim_box`: each primitive's
    /// minimal box (empty for culled ones).
    fn of(scene: &Scene, prim_box: &[Aabb], scene_box: &Aabb) -> Option<Box<WideClip>> {
        let area = |b: &Aabb| {
            let e = b.max - b.min;
            2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
        };
        let n = prim_box.len();
        // Unions of the boxes after each primitive, then of those before.
        let mut after = vec![Aabb::EMPTY; n + 1];
        for i in (0..n).rev() {
            after[i] = prim_box[i].union(&after[i + 1]);
        }
        let mut before = Aabb::EMPTY;
        let mut best: Option<(f64, usize, Aabb)> = None;
        for (i, b) in prim_box.iter().enumerate() {
            let rest = before.union(&after[i + 1]);
            before = before.union(b);
            let a = area(&rest);
            if b.is_empty() || rest.is_empty() || !a.is_finite() {
                continue;
            }
            if best.is_none_or(|(x, _, _)| a < x) {
                best = Some((a, i, rest));
            }
        }
        let (a, i, rest) = best?;
        (a <= WIDE_GAIN * area(scene_box)).then(|| {
            Box::new(WideClip {
                prim: scene.primitives[i].clone(),
                cull: scene.primitives[i].bounds.inflated(1e-9),
                id: i as u32,
                global: PrimId(i as u32),
                rest: rest.inflated(1e-9),
            })
        })
    }
}

/// What a shadow walk may assume of the whole scene (`CellTracer::
/// walk_shadow`), found once from the scene's tree and kept with every
/// share, since a node sees only its own primitives.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShadowFacts {
    /// Per primitive of the structure's scene, a bit: every operator above
    /// it in the scene's tree is a union or an assembly, so inside it is
    /// inside the scene's solid wherever it is (the shadow cache keeps only
    /// these).
    pub exposed: Vec<u64>,
    /// Per light, whether it surely lies outside the scene's solid
    /// (`outside_the_solid`).
    pub clear_lights: Vec<bool>,
    /// Per light, the radius of a ball around it that no primitive's
    /// minimal box reaches (`free_radius`): a shadow ray's last stretch to
    /// its light, inside that ball, meets nothing, and its walk leaves it
    /// out (`CellTracer::walk_shadow`).
    pub free_radius: Vec<f64>,
    /// The minimal boxes (inflated) of the primitives whose material lets
    /// light through, or None when there are more than `MAX_GLASS`: a
    /// shadow ray that meets none of them meets only opaque surfaces.
    pub glass: Option<Vec<Aabb>>,
    /// Whether walks keep the shadow cache (`CellOptions::no_shadow_cache`).
    pub cache: bool,
    /// Small exposed solids (an operator other than a union, every
    /// operator above it a union or an assembly, with at most
    /// `MAX_SOLID_LEAVES` leaves), copied from the scene's tree with the
    /// structure's primitive numbers: inside one is inside the scene's
    /// solid wherever it is, as inside an exposed primitive is, so the
    /// shadow cache may keep one that stopped a shadow ray (the north wall
    /// less its window, a lamp's hollow shade). Every share that holds a
    /// primitive of one holds all of its primitives.
    pub solids: CsgTree,
    /// Per primitive, the root in `solids` of the solid it is a leaf of,
    /// or `NO_SOLID`; empty where the scene has no such solid (in every
    /// share of its structure too).
    pub solid_of: Vec<u32>,
}

/// The most leaves of a solid the shadow cache may keep
/// (`ShadowFacts::solids`): testing it costs a test a leaf.
pub const MAX_SOLID_LEAVES: usize = 8;

/// `ShadowFacts::solid_of` of a primitive in no cached solid.
pub const NO_SOLID: u32 = u32::MAX;

/// Transmitting primitives up to which shadow rays are checked against
/// their boxes (`ShadowFacts::glass`): beyond, every shadow ray walks to
/// its nearest surface.
pub const MAX_GLASS: usize = 64;

/// Where a point surely is against a solid: inside, outside, or too near
/// a surface to say.
#[derive(Clone, Copy, PartialEq)]
enum Side {
    In,
    Out,
    Near,
}

/// Whether `p` surely lies outside the scene's solid: by the tree, three
/// ways (`Side`), each primitive classified by its crossings with lines
/// through `p` (`leaf_side`), and every primitive whose minimal box
/// (inflated) does not hold `p` outside, as Algorithm 1 lets it be
/// wherever it cannot change the solid. Within a millionth of the scene's
/// size of a surface, a primitive is `Near` and decides nothing.
fn outside_the_solid(scene: &Scene, minimal: &[Aabb], p: crate::geom::Vec3) -> bool {
    let tree = &scene.tree;
    let Some(root) = tree.root else {
        return true;
    };
    let all = minimal.get(root.index()).copied().unwrap_or(Aabb::EMPTY);
    let size = all.largest_side();
    if !size.is_finite() || size <= 0.0 {
        return !all.inflated(1e-9).contains(p);
    }
    let mut side = vec![Side::Out; tree.nodes.len()];
    for (i, n) in tree.nodes.iter().enumerate() {
        side[i] = match *n {
            CsgNode::Leaf(q) => {
                if !minimal[i].inflated(1e-9).contains(p) {
                    Side::Out
                } else {
                    leaf_side(&scene.primitives[q.index()], p, size)
                }
            }
            CsgNode::Op { op, .. } => {
                let kids = tree.children_of(NodeId(i as u32));
                let of = |c: &NodeId| side[c.index()];
                let any = |s: Side| kids.iter().any(|c| of(c) == s);
                // A union is inside where any operand is, an intersection
                // outside where any is; else near where any is near.
                let settle = |wins: Side, otherwise: Side| {
                    if any(wins) {
                        wins
                    } else if any(Side::Near) {
                        Side::Near
                    } else {
                        otherwise
                    }
                };
                match op {
                    Op::Union | Op::Assembly => settle(Side::In, Side::Out),
                    Op::Intersection if kids.is_empty() => Side::Out,
                    Op::Intersection => settle(Side::Out, Side::In),
                    Op::Difference => {
                        let (first, rest) = kids
                            .split_first()
                            .map_or((Side::Out, &[][..]), |(f, r)| (of(f), r));
                        let rest_in = rest.iter().any(|c| of(c) == Side::In);
                        let rest_near = rest.iter().any(|c| of(c) == Side::Near);
                        if first == Side::Out || rest_in {
                            Side::Out
                        } else if first == Side::Near || rest_near {
                            Side::Near
                        } else {
                            Side::In
                        }
                    }
                }
            }
        };
    }
    side[root.index()] == Side::Out
}

/// Where `p` lies against one primitive, by its crossings with lines
/// through `p` of the scene's length `size` (`t` is then a fraction of it):
/// `In` where a line in an arbitrary direction, off the axes, leaves it
/// ahead and entered behind, both by more than a millionth (every solid
/// primitive is convex); `Near` where a crossing of any line comes within
/// that of `p`; `Out` only where every line says so.
///
/// One line is not enough for `Out`: a line through a point on an edge or
/// a corner may touch the solid there alone, and miss it (seed 24886 of
/// the scene mutants: a light on a box's edge was taken for outside, and
/// shadow rays from inside the box were stopped where Roth finds no
/// surface before the light). A line through an edge of a box enters it
/// where its direction `d` has `(d·n₁)(d·n₂) > 0`, `n₁` and `n₂` the two
/// faces' normals; over the three axes and the four diagonals these
/// products sum to multiples of `n₁·n₂ = 0` and are not all zero, so one
/// of them enters. The same holds at a cylinder's rims, and in a
/// transformed box's own space, whose directions are mapped to the world
/// here; a cone's apex is met along its axis. Those lines only ever make
/// a primitive `Near`, never `In`: the axes lie in a box's faces, where a
/// chord through a point of the face holds it without the point being
/// inside.
fn leaf_side(prim: &crate::csg::Primitive, p: crate::geom::Vec3, size: f64) -> Side {
    use crate::csg::{PrimHits, Shape};
    use crate::geom::{Ray, Vec3};
    let m = 1e-6;
    let side = |d: Vec3| -> Side {
        match prim.intersect(&Ray::new(p, d)) {
            PrimHits::Miss => Side::Out,
            PrimHits::Solid { enter, exit } => {
                if enter.t < -m && exit.t > m {
                    Side::In
                } else if enter.t > m || exit.t < -m {
                    Side::Out
                } else {
                    Side::Near
                }
            }
            PrimHits::Sheet { hits, count } => {
                if hits[..count as usize].iter().any(|c| c.t.abs() <= m) {
                    Side::Near
                } else {
                    Side::Out
                }
            }
        }
    };
    let first = side(Vec3::new(0.8017, 0.4631, 0.3779).normalize() * size);
    if first != Side::Out {
        return first;
    }
    let axis = match &prim.shape {
        Shape::Cylinder { base, top, .. } | Shape::Cone { base, top, .. } => Some(*top - *base),
        _ => None,
    };
    let object = [
        Vec3::X,
        Vec3::Y,
        Vec3::Z,
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(1.0, 1.0, -1.0),
        Vec3::new(1.0, -1.0, 1.0),
        Vec3::new(-1.0, 1.0, 1.0),
    ];
    for d in object.into_iter().chain(axis) {
        let d = prim.transform.as_ref().map_or(d, |t| t.vector(d));
        let d = d.normalize_or_zero() * size;
        if !d.is_finite() || d == Vec3::ZERO || side(d) != Side::Out {
            return Side::Near;
        }
    }
    Side::Out
}

/// The radius of a ball around `p` that no primitive's minimal box
/// reaches, with margins far above the rounding of the distances and of
/// the crossings a ray might be given there: each box inflated by a
/// relative 1e-6 (the cells hold boxes inflated by 1e-9, and grown by the
/// walk's rounding, `walk_rounding`), and the radius taken 1e-6 short of
/// the nearest and 1e-9 of the scene's reach shorter (a crossing computed
/// from a point that far off is placed to about 1e-16 of it). Zero where
/// `p` is in or next to a box, or the numbers are not finite.
fn free_radius(scene: &Scene, minimal: &[Aabb], p: Vec3) -> f64 {
    let tree = &scene.tree;
    let reach = largest_coordinate(minimal).max(p.abs().max_element());
    let mut nearest = f64::INFINITY;
    for (n, b) in tree.nodes.iter().zip(minimal) {
        if !matches!(n, CsgNode::Leaf(_)) || b.is_empty() {
            continue;
        }
        let b = b.inflated(1e-6);
        let gap = (b.min - p).max(p - b.max).max(Vec3::ZERO);
        nearest = nearest.min(gap.length());
    }
    let r = nearest * (1.0 - 1e-6) - 1e-9 * reach;
    if r.is_finite() && r > 0.0 { r } else { 0.0 }
}

impl ShadowFacts {
    fn of(scene: &Scene, minimal: &[Aabb], cache: bool) -> ShadowFacts {
        let tree = &scene.tree;
        // Top-down over the children-before-parents arena: from the root,
        // through unions and assemblies only.
        let mut open = vec![false; tree.nodes.len()];
        if let Some(r) = tree.root {
            open[r.index()] = true;
        }
        let mut exposed = vec![0u64; scene.primitives.len().div_ceil(64)];
        let mut glass = Vec::new();
        for i in (0..tree.nodes.len()).rev() {
            match tree.nodes[i] {
                CsgNode::Leaf(p) => {
                    if open[i] {
                        exposed[p.index() / 64] |= 1 << (p.index() % 64);
                    }
                    let m = scene.material(scene.primitives[p.index()].material);
                    if m.transmit > 0.0 && !minimal[i].is_empty() {
                        glass.push(minimal[i].inflated(1e-9));
                    }
                }
                CsgNode::Op { op, .. } => {
                    if open[i] && matches!(op, Op::Union | Op::Assembly) {
                        for c in tree.children_of(NodeId(i as u32)) {
                            open[c.index()] = true;
                        }
                    }
                }
            }
        }
        let clear_lights = scene
            .lights
            .iter()
            .map(|l| outside_the_solid(scene, minimal, l.position))
            .collect();
        let free_radius = scene
            .lights
            .iter()
            .map(|l| free_radius(scene, minimal, l.position))
            .collect();
        let (solids, solid_of) = exposed_solids(tree, &open, scene.primitives.len());
        ShadowFacts {
            exposed,
            clear_lights,
            free_radius,
            glass: (glass.len() <= MAX_GLASS).then_some(glass),
            cache,
            solids,
            solid_of,
        }
    }

    /// The root in `solids` of the solid primitive `p` is a leaf of.
    pub fn solid_of(&self, p: u32) -> Option<u32> {
        self.solid_of
            .get(p as usize)
            .copied()
            .filter(|&r| r != NO_SOLID)
    }

    /// The primitives of the solid rooted at `root` in `solids`.
    pub fn solid_primitives(&self, root: u32) -> Vec<u32> {
        let prims = self.solids.prims_from(NodeId(root));
        prims.into_iter().map(|p| p.0).collect()
    }

    /// Whether primitive `p` of the structure's scene is exposed.
    pub fn is_exposed(&self, p: u32) -> bool {
        self.exposed
            .get(p as usize / 64)
            .is_some_and(|w| w >> (p % 64) & 1 == 1)
    }

    /// The facts for a share whose primitives are the scene's `kept`
    /// (global numbers, ascending: their local order). The solids kept
    /// are those whose primitives are all in `kept` (the share holds every
    /// primitive of a solid it holds one of, `CellStructure::restrict_with`),
    /// renumbered.
    pub fn restricted(&self, kept: &[u32]) -> ShadowFacts {
        let mut exposed = Vec::new();
        for (k, &p) in kept.iter().enumerate() {
            if k % 64 == 0 {
                exposed.push(0);
            }
            if self.is_exposed(p) {
                exposed[k / 64] |= 1 << (k % 64);
            }
        }
        let (mut solids, mut solid_of) = (CsgTree::new(), Vec::new());
        if !self.solid_of.is_empty() {
            let local = |g: u32| kept.binary_search(&g).ok().map(|k| k as u32);
            // Each solid once, in the order of its first primitive.
            let mut copied: HashMap<u32, u32> = HashMap::new();
            solid_of = vec![NO_SOLID; kept.len()];
            for (k, &g) in kept.iter().enumerate() {
                let Some(root) = self.solid_of(g) else {
                    continue;
                };
                if let Some(&r) = copied.get(&root) {
                    solid_of[k] = r;
                    continue;
                }
                let held = self
                    .solid_primitives(root)
                    .into_iter()
                    .all(|q| local(q).is_some());
                let r = if held {
                    copy_subtree(&self.solids, root, &mut solids, &|p| {
                        PrimId(local(p.0).expect("every primitive of the solid is held"))
                    })
                } else {
                    NO_SOLID
                };
                copied.insert(root, r);
                solid_of[k] = r;
            }
        }
        ShadowFacts {
            exposed,
            solids,
            solid_of,
            ..self.clone()
        }
    }

    fn bytes(&self) -> usize {
        let t = &self.solids;
        self.exposed.len() * 8
            + t.nodes.len() * (std::mem::size_of::<CsgNode>() + 2 * std::mem::size_of::<Aabb>())
            + t.children.len() * std::mem::size_of::<NodeId>()
            + self.solid_of.len() * std::mem::size_of::<u32>()
            + self.clear_lights.len()
            + self.free_radius.len() * std::mem::size_of::<f64>()
            + self
                .glass
                .as_ref()
                .map_or(0, |g| g.len() * std::mem::size_of::<Aabb>())
    }
}

/// The small exposed solids of `tree` (`ShadowFacts::solids`), `open`
/// marking the nodes every operator above which is a union or an
/// assembly, and per primitive of the `prims` the root of its solid.
/// Both empty where there is none.
fn exposed_solids(tree: &CsgTree, open: &[bool], prims: usize) -> (CsgTree, Vec<u32>) {
    // Leaves per node, children before parents.
    let mut leaves = vec![0usize; tree.nodes.len()];
    for i in 0..tree.nodes.len() {
        leaves[i] = match tree.nodes[i] {
            CsgNode::Leaf(_) => 1,
            CsgNode::Op { .. } => tree
                .children_of(NodeId(i as u32))
                .iter()
                .map(|c| leaves[c.index()])
                .sum(),
        };
    }
    let mut solids = CsgTree::new();
    let mut solid_of = Vec::new();
    for i in 0..tree.nodes.len() {
        let CsgNode::Op { op, .. } = tree.nodes[i] else {
            continue;
        };
        if !open[i] || matches!(op, Op::Union | Op::Assembly) || leaves[i] > MAX_SOLID_LEAVES {
            continue;
        }
        if tree.bounds.get(i).is_none_or(|b| b.is_empty()) {
            // Nothing inside (Algorithm 1): nothing to stop a ray.
            continue;
        }
        let root = copy_subtree(tree, i as u32, &mut solids, &|p| p);
        if solid_of.is_empty() {
            solid_of = vec![NO_SOLID; prims];
        }
        for p in tree.prims_from(NodeId(i as u32)) {
            solid_of[p.index()] = root;
        }
    }
    (solids, solid_of)
}

/// Copies the subtree of `from` rooted at `root` to the end of `to` (its
/// nodes in their arena order, so children stay before parents), with
/// its bounds and its leaves' primitives renamed by `prim`; returns its
/// new root.
fn copy_subtree(
    from: &CsgTree,
    root: u32,
    to: &mut CsgTree,
    prim: &dyn Fn(PrimId) -> PrimId,
) -> u32 {
    let mut nodes = Vec::new();
    let mut stack = vec![NodeId(root)];
    while let Some(n) = stack.pop() {
        nodes.push(n.0);
        stack.extend_from_slice(from.children_of(n));
    }
    nodes.sort_unstable();
    let mut new_id = HashMap::new();
    for &i in &nodes {
        let n = NodeId(i);
        let id = match from.nodes[n.index()] {
            CsgNode::Leaf(p) => to.leaf(prim(p)),
            CsgNode::Op { op, .. } => {
                let children = from
                    .children_of(n)
                    .iter()
                    .map(|c| NodeId(new_id[&c.0]))
                    .collect();
                to.op(op, children)
            }
        };
        new_id.insert(i, id.0);
        to.bounds.push(from.bounds[n.index()]);
        to.cull_bounds.push(from.cull_bounds[n.index()]);
    }
    new_id[&root]
}

/// A leaf of a cell's subtree, for the traversal's first look at a cell
/// (`CellTracer::in_cell`): its node in `CellStructure::subtrees`, its
/// primitive, whether it is the subtree's result when it is the only leaf
/// with anything along the ray (every operator above it is a union or an
/// assembly, or a difference of which it is in the first operand), whether
/// it is exposed (every operator above it is a union or an assembly: inside
/// it is inside the subtree's solid, and so, within the cell, inside the
/// scene's), and its culling box (`CsgTree::cull_bounds` of `node`).
///
/// The box is a copy kept beside the leaf so that the first look reads one
/// contiguous list: most leaves a ray meets in a cell are culled by their
/// box (sphereflake level 4: 29 slab tests per ray for 2.8 intersection
/// tests), and reading the box from the arena by `node` was a scattered
/// load per leaf.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SubtreeLeaf {
    pub cull: Aabb,
    pub node: u32,
    pub prim: u32,
    pub lone_is_result: bool,
    pub exposed: bool,
}

/// The leaf lists of the subtrees rooted at `roots`.
fn subtree_leaf_lists(
    tree: &CsgTree,
    roots: impl Iterator<Item = u32>,
) -> (Vec<[u32; 2]>, Vec<SubtreeLeaf>) {
    let mut span = vec![[0u32; 2]; tree.nodes.len()];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for root in roots {
        if root == NO_SUBTREE {
            continue;
        }
        let start = out.len() as u32;
        stack.push((NodeId(root), true, true));
        while let Some((n, passes, exposed)) = stack.pop() {
            match tree.nodes[n.index()] {
                CsgNode::Leaf(p) => out.push(SubtreeLeaf {
                    cull: tree.cull_bounds[n.index()],
                    node: n.0,
                    prim: p.0,
                    lone_is_result: passes,
                    exposed,
                }),
                CsgNode::Op { op, .. } => {
                    let joins = matches!(op, Op::Union | Op::Assembly);
                    for (i, c) in tree.children_of(n).iter().enumerate() {
                        let keeps = match op {
                            Op::Union | Op::Assembly => true,
                            Op::Difference => i == 0,
                            Op::Intersection => false,
                        };
                        stack.push((*c, passes && keeps, exposed && joins));
                    }
                }
            }
        }
        span[root as usize] = [start, out.len() as u32];
    }
    (span, out)
}

/// One cell of a super cell's depth partition, before its subtree is
/// built: its primitives, sorted (the key under which equal subtrees are
/// shared), and its near depth.
struct CutCell {
    prims: Vec<u32>,
    zlo: f32,
}

/// How far the walk may misplace a point of a ray, in world units: the
/// rounding of a camera coordinate (`View::point`) and of a crossing
/// (`traverse`) is some ulps of the largest magnitude they combine: the
/// eye's, and the ray's origin's and point's, all in the scene box (rays
/// start on surfaces, or at the eye). Cells hold what lies within this of
/// them, so that rounding never puts a hit in a cell that does not hold
/// its primitive. `WALK_ROUNDING` of that magnitude: some four thousand
/// ulps, as `projection::INFLATE_REL` is for the projected bounds. Nil on
/// the scenes of everyday sizes (3e-11 on the bundled ones); 1e-6 around
/// a sphere of radius 1e6.
fn walk_rounding(prim_box: &[Aabb], eye: Vec3) -> f64 {
    let margin = (largest_coordinate(prim_box) + eye.abs().max_element()) * WALK_ROUNDING;
    if margin.is_finite() { margin } else { 0.0 }
}

/// The largest magnitude of a coordinate of the non-empty boxes: the
/// scene's reach, on which rounding scales (`walk_rounding`,
/// `free_radius`).
fn largest_coordinate(boxes: &[Aabb]) -> f64 {
    boxes
        .iter()
        .filter(|b| !b.is_empty())
        .map(|b| b.min.abs().max(b.max.abs()).max_element())
        .fold(0.0, f64::max)
}

/// Relative rounding of the walk (`walk_rounding`).
const WALK_ROUNDING: f64 = 1e-12;

/// Super cells of at least this many listed primitives in all make the
/// depth partitions worth a second thread by default (a thread costs tens
/// of microseconds; the sphereflake of level 4 at 512x512 lists 13,812,
/// cut in 9 ms on one thread).
const PARALLEL_CUT_PRIMS: usize = 4096;

/// Where the eye lies with respect to a primitive's padded minimal box,
/// which decides how the box's depth in a super cell is found
/// (`cut_super_cells`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum EyeAt {
    /// On its boundary, to rounding (`View::eye_near_boundary`): no side
    /// of it can be told, so it takes its whole depth in every super cell.
    Boundary,
    /// Inside, deeper than rounding. Clipped by each super cell's prism,
    /// which in front always meets it: in a super cell thin enough, the
    /// prism's part in the box lies next to the eye, narrower than the
    /// clip's rounding, and the clip loses it. (Found by
    /// `random_scenes_seen_from_a_box_face_edge_or_corner_render_identically`,
    /// seed 2731: the eye on an edge of a box, inside the boxes of the
    /// other operands of its intersection, which Algorithm 1 cut by the
    /// box's own grown by 1e-9; a super cell 7.5e-10 wide lost them, so
    /// its first cell held the box alone, whose intersection was then
    /// empty, and a ray leaving the box through the eye missed its exit.)
    Inside,
    /// Outside: clipped, and left out where the clip finds nothing.
    Outside,
}

/// Cuts every super cell of a region into cells along depth (section 3.3,
/// `depth_partition`), dropping from each the primitives whose box does
/// not reach into it. Independent per super cell, so spread over the
/// host's cores for large scenes: on two cores, the sphereflake's cuts
/// (492 super cells listing 13,812 primitives at 512x512) took 5 ms
/// instead of 9 ms, its whole build 22-26 ms instead of 26-30 ms.
/// Returns each super cell's cells, in order; fails (`Error::Render`)
/// only if the OS refuses a thread.
fn cut_super_cells(
    region: Region,
    leaves: &mut [bsp::Leaf],
    cam_boxes: &[Option<projection::CamBox>],
    eye_at: &[EyeAt],
    threads: usize,
) -> Result<Vec<Vec<CutCell>>> {
    let cut_one = |leaf: &mut bsp::Leaf| -> Vec<CutCell> {
        // Each primitive's depth extent over this super cell; those whose
        // box does not reach into it at all are dropped.
        let mut extents = Vec::with_capacity(leaf.prims.len());
        leaf.prims.retain(|&p| {
            let cb = cam_boxes[p as usize]
                .as_ref()
                .expect("the BSP lists only primitives with a screen rect, and each has a cam box");
            let range = match eye_at[p as usize] {
                EyeAt::Boundary => Some(View::depth_range_whole(cb, region)),
                EyeAt::Inside => View::depth_range_in(cb, region, &leaf.rect).or_else(|| {
                    // Every direction from the eye starts inside the box,
                    // so in front every super cell's prism meets it; a
                    // clip that says otherwise lost to rounding a part
                    // too thin for it, next to the eye, and the box's
                    // whole depth stands in.
                    (region == Region::Front).then(|| View::depth_range_whole(cb, region))
                }),
                EyeAt::Outside => View::depth_range_in(cb, region, &leaf.rect),
            };
            match range {
                Some((z0, z1)) => {
                    extents.push((p, z0, z1));
                    true
                }
                None => false,
            }
        });
        let mut cells = Vec::new();
        depth_partition(region, &extents, &mut |cell_prims, zlo, _zhi| {
            let mut prims = cell_prims.to_vec();
            prims.sort_unstable();
            debug_assert_eq!(f64::from(zlo as f32), zlo, "a depth cut is an f32");
            cells.push(CutCell {
                prims,
                zlo: zlo as f32,
            });
        });
        cells
    };
    let threads = match threads {
        0 if leaves.iter().map(|l| l.prims.len()).sum::<usize>() < PARALLEL_CUT_PRIMS => 1,
        0 => crate::trace::host_cores().min(8),
        n => n,
    };
    if threads < 2 {
        return Ok(leaves.iter_mut().map(cut_one).collect());
    }
    // Chunks handed out in turn, so that a few heavy super cells do not
    // leave one thread with most of the work.
    let chunk = leaves.len().div_ceil(threads * 8).max(1);
    let work = std::sync::Mutex::new(leaves.chunks_mut(chunk).enumerate());
    // One thread's share: chunks taken in turn until none is left.
    let cut_chunks = || {
        let mut mine = Vec::new();
        loop {
            // Poisoned only by a panic in `next`, which it has not.
            let taken = work.lock().map(|mut w| w.next());
            let Ok(Some((i, leaves))) = taken else {
                break;
            };
            mine.push((i, leaves.iter_mut().map(cut_one).collect::<Vec<_>>()));
        }
        mine
    };
    let mut done = std::thread::scope(|s| -> Result<Vec<(usize, Vec<Vec<CutCell>>)>> {
        let mut workers = Vec::with_capacity(threads);
        for i in 0..threads {
            let started = start_worker(s, ("cut", "cell build thread"), (i, threads), cut_chunks);
            match started {
                Ok(w) => workers.push(w),
                Err(e) => {
                    // No chunk is handed out any more: the threads
                    // started finish the one they hold, and the scope
                    // joins them (`start_worker` says why the build fails).
                    if let Ok(mut w) = work.lock() {
                        w.by_ref().for_each(drop);
                    }
                    return Err(e);
                }
            }
        }
        Ok(workers
            .into_iter()
            .flat_map(|w| w.join().expect("cutting a super cell does not panic"))
            .collect())
    })?;
    done.sort_unstable_by_key(|d| d.0);
    let cut: Vec<Vec<CutCell>> = done.into_iter().flat_map(|d| d.1).collect();
    assert_eq!(cut.len(), leaves.len(), "every super cell cut once");
    Ok(cut)
}

/// Depth partitioning of one super cell (section 3.3, figure 5): the
/// depth extents of its primitives cut it into cells, empty ones included,
/// so that the cells partition the region. `emit(prims, zlo, zhi)` is
/// called front to back; a cell `[zlo, zhi)` holds every primitive whose
/// extent `[z0, z1]` reaches into it (`z0 < zhi` and `z1 > zlo`).
///
/// Deviation from the paper, which cuts at every extent's ends: the cuts
/// are chosen by a cost model (`DepthCost`), so that runs of thin slabs
/// where primitives come and go one at a time become one cell. Every cut
/// at the ends of extents costs a ray a step and a subtree evaluation;
/// with cuts everywhere (the paper's rule) jagged_ball's primary rays
/// crossed 5.8 cells each, house's 12.6 (320×240, 0.9 and 1.3 ms of the
/// per-ray budget); see `CellStructure::build` for the measured effect.
/// The cost model also bounds the number of cells where many extents
/// overlap (`ROBUSTNESS.md` case 15): a cut that leaves every primitive on
/// both sides never pays.
fn depth_partition(
    region: Region,
    extents: &[(u32, f64, f64)],
    emit: &mut dyn FnMut(&[u32], f64, f64),
) {
    // Extents widened to f32 values, so that every cut (an extent's end)
    // is an f32 and a cell's depth is held in 4 bytes on every node that
    // holds the skeleton. Widening only ever adds a primitive to a cell
    // it grazes: exact.
    let extents: Vec<(u32, f64, f64)> = extents
        .iter()
        .map(|&(p, z0, z1)| (p, f32_below(z0), f32_above(z1)))
        .collect();
    let extents = &extents[..];
    let (rz0, rz1) = region.depth_range();
    let zmin = extents
        .iter()
        .map(|e| e.1)
        .fold(f64::INFINITY, f64::min)
        .max(rz0);
    let zmax = extents
        .iter()
        .map(|e| e.2)
        .fold(f64::NEG_INFINITY, f64::max)
        .min(rz1);
    if extents.is_empty() || zmin.partial_cmp(&zmax) != Some(std::cmp::Ordering::Less) {
        // Nothing, or nothing with depth: one cell with whatever there is.
        let all: Vec<u32> = extents
            .iter()
            .filter(|e| e.1 < rz1 && e.2 > rz0)
            .map(|e| e.0)
            .collect();
        emit(&all, rz0, rz1);
        return;
    }
    // Cut positions in [zmin, zmax], in order.
    let mut cuts = vec![zmin];
    let cost = DepthCost::new(zmax - zmin);
    let mut by_start: Vec<u32> = (0..extents.len() as u32).collect();
    let mut by_end = by_start.clone();
    by_start.sort_unstable_by(|&a, &b| extents[a as usize].1.total_cmp(&extents[b as usize].1));
    by_end.sort_unstable_by(|&a, &b| extents[a as usize].2.total_cmp(&extents[b as usize].2));
    cost.split(extents, &by_start, &by_end, zmin, zmax, &mut cuts);
    cuts.push(zmax);
    let mut prims = Vec::new();
    let mut bounds = vec![rz0];
    for c in cuts.into_iter().chain([rz1]) {
        if c > *bounds.last().expect("starts as [rz0], only pushed to") {
            bounds.push(c);
        }
    }
    for w in bounds.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        prims.clear();
        prims.extend(extents.iter().filter(|e| e.1 < hi && e.2 > lo).map(|e| e.0));
        emit(&prims, lo, hi);
    }
}

/// The largest f32 at or below `x`, and the smallest at or above it.
fn f32_below(x: f64) -> f64 {
    let f = x as f32;
    f64::from(if f64::from(f) > x { f.next_down() } else { f })
}

fn f32_above(x: f64) -> f64 {
    let f = x as f32;
    f64::from(if f64::from(f) < x { f.next_up() } else { f })
}

/// The cost model of the depth partition, a surface-area heuristic along
/// depth: a cell costs one step (`DEPTH_STEP`) plus one per primitive in
/// it, for the rays that visit it. Rays visit a cell in proportion to
/// `DEPTH_ALL + (1 − DEPTH_ALL) · thickness / extent`: primary rays cross
/// the cells of their super cell front to back whatever their thickness,
/// other rays cross them sideways, in proportion to their thickness.
struct DepthCost {
    extent: f64,
    all: f64,
    step: f64,
}

/// Share of rays that cross every cell of a super cell (primary rays).
///
/// Primary rays are about a fifth of all rays (sphereflake level 4: 1
/// primary, 3.7 shadow and 0.7 reflected rays per pixel) and stop at their
/// first hit, so few of them cross a super cell's cells front to back; the
/// rest cross cells sideways, in proportion to their thickness. Measured
/// in instructions of the walk (callgrind, one ray in 4 per axis), 0.5 →
/// 0.1 removes 16% on the sphereflake (leaves looked at per ray 38 → 25),
/// 13% on jagged_ball and 11% on house; with the other cost constants
/// (see `bsp::TRAVERSE`), 0.05.
const DEPTH_ALL: f64 = 0.05;
/// Cost of a step between cells, against 1 per primitive (see
/// `bsp::TRAVERSE`).
const DEPTH_STEP: f64 = 0.5;

impl DepthCost {
    fn new(extent: f64) -> Self {
        DepthCost {
            extent,
            all: DEPTH_ALL,
            step: DEPTH_STEP,
        }
    }

    fn weight(&self, lo: f64, hi: f64) -> f64 {
        self.all + (1.0 - self.all) * (hi - lo) / self.extent
    }

    /// Pushes the cuts of `[lo, hi)` in order. The region holds the
    /// extents listed in `by_start` and in `by_end`, sorted by their starts
    /// and by their ends: sorted once (`depth_partition`) and split in
    /// order, so a level costs a pass, not a sort (n log n for the whole
    /// tree). The sweep sees the same values in the same order as when
    /// each level sorted its own: the same cuts.
    fn split(
        &self,
        extents: &[(u32, f64, f64)],
        by_start: &[u32],
        by_end: &[u32],
        lo: f64,
        hi: f64,
        cuts: &mut Vec<f64>,
    ) {
        let n = by_start.len();
        if n == 0 {
            return;
        }
        let start = |k: usize| extents[by_start[k] as usize].1;
        let end = |k: usize| extents[by_end[k] as usize].2;
        let whole = self.weight(lo, hi);
        let mut best = (n as f64, None);
        // Candidates: the extents' ends inside (lo, hi), in order; a cell
        // [lo, c) holds the extents starting before c, [c, hi) those ending
        // after c.
        let (mut i, mut j) = (0usize, 0usize);
        let (mut before, mut ended) = (0usize, 0usize);
        while i < n || j < n {
            let c = match (i < n, j < n) {
                (true, true) => start(i).min(end(j)),
                (true, false) => start(i),
                (false, true) => end(j),
                (false, false) => break,
            };
            while before < n && start(before) < c {
                before += 1;
            }
            while ended < n && end(ended) <= c {
                ended += 1;
            }
            while i < n && start(i) == c {
                i += 1;
            }
            while j < n && end(j) == c {
                j += 1;
            }
            if !(c > lo && c < hi) {
                continue;
            }
            let cost = self.step
                + (self.weight(lo, c) * before as f64 + self.weight(c, hi) * (n - ended) as f64)
                    / whole;
            if cost < best.0 {
                best = (cost, Some(c));
            }
        }
        let Some(c) = best.1 else { return };
        // [lo, c) holds the extents starting before c: a prefix of
        // `by_start`; [c, hi) those ending after c: a suffix of `by_end`.
        let starts_left = by_start.partition_point(|&e| extents[e as usize].1 < c);
        let ends_right = by_end.partition_point(|&e| extents[e as usize].2 <= c);
        let ends_left: Vec<u32> = by_end
            .iter()
            .copied()
            .filter(|&e| extents[e as usize].1 < c)
            .collect();
        self.split(extents, &by_start[..starts_left], &ends_left, lo, c, cuts);
        cuts.push(c);
        let starts_right: Vec<u32> = by_start
            .iter()
            .copied()
            .filter(|&e| extents[e as usize].2 > c)
            .collect();
        self.split(extents, &starts_right, &by_end[ends_right..], c, hi, cuts);
    }
}
