//! A node's share of the cell structure (the paper's closing plan, section
//! 9: the cells distributed over the nodes of a hypercube).
//!
//! A node holds the *skeleton* of the whole structure, which is what the
//! walk between cells reads (the super cells' rectangles and corner
//! pointers, every cell's depth slab) and which doubles as the
//! cell-to-node map, but the *content* (CSG subtrees and the primitives
//! they reference) only of the cells it owns. A cell with content held
//! elsewhere is marked `REMOTE`, with the hull of that content (one per
//! subtree, shared by the cells it serves): a walk whose ray meets the
//! hull stops there and the ray moves to the owner. Empty cells are
//! walked by whoever holds the ray, so rays cross empty space without a
//! message.

use std::collections::BTreeMap;

use super::{CellStructure, NO_SUBTREE, NOT_HELD, REMOTE, Region, SubtreeLeaf, WideClip};
use crate::csg::{CsgNode, CsgTree, NodeId, PrimId};
use crate::geom::{Aabb, Vec3};
use crate::scene::Scene;

impl CellStructure {
    /// The share of a node that owns the super cells for which `owns`
    /// is true: the same structure with only their subtrees, renumbered,
    /// and a scene with only the primitives those reference (renumbered in
    /// the order of their global ids, so shading is unchanged). The scene
    /// keeps camera, lights and materials (small, and every node shades)
    /// but no CSG tree.
    pub fn restrict(
        &self,
        scene: &Scene,
        owns: &dyn Fn(Region, u32) -> bool,
    ) -> (CellStructure, Scene) {
        self.restrict_with(scene, owns, &self.cell_hulls())
    }

    /// `restrict`, with the hulls of the cells made beforehand
    /// (`cell_hulls`): every share holds the hulls of the cells it does
    /// not own, and making them again for each of 32 shares was most of
    /// the time cutting them.
    pub fn restrict_with(
        &self,
        scene: &Scene,
        owns: &dyn Fn(Region, u32) -> bool,
        hulls: &CellHulls,
    ) -> (CellStructure, Scene) {
        let old = &self.subtrees;
        // The subtree nodes reachable from owned cells.
        let mut keep = vec![false; old.nodes.len()];
        let mut stack = Vec::new();
        for r in &self.regions {
            let owned = (0..r.supers.len() as u32).filter(|&s| owns(r.region, s));
            for k in owned.flat_map(|s| r.cells_of(s)) {
                let t = r.subtree[k];
                if t < REMOTE && !keep[t as usize] {
                    stack.push(NodeId(t));
                    while let Some(n) = stack.pop() {
                        if !keep[n.index()] {
                            keep[n.index()] = true;
                            stack.extend_from_slice(old.children_of(n));
                        }
                    }
                }
            }
        }
        // Primitives and operator mailboxes in use, in global order.
        let mut used_prims = vec![false; scene.primitives.len()];
        let origin_ids = self
            .origin
            .iter()
            .map(|&o| o as usize + 1)
            .max()
            .unwrap_or(0);
        let mut used_origins = vec![false; origin_ids];
        for (i, n) in old.nodes.iter().enumerate() {
            if keep[i] {
                if let CsgNode::Leaf(p) = n {
                    used_prims[p.index()] = true;
                }
                used_origins[self.origin[i] as usize] = true;
            }
        }
        // With each, every primitive of a small solid it is in, which the
        // shadow cache may test whole (`ShadowFacts::solids`).
        if !self.shadows.solid_of.is_empty() {
            let held: Vec<u32> = (0..used_prims.len() as u32)
                .filter(|&g| used_prims[g as usize])
                .collect();
            for g in held {
                if let Some(root) = self.shadows.solid_of(g) {
                    for q in self.shadows.solid_primitives(root) {
                        used_prims[q as usize] = true;
                    }
                }
            }
        }
        let (prims, origins) = (Dense::new(&used_prims), Dense::new(&used_origins));
        // Copy in arena order: children before parents stays true.
        let mut new_id = vec![u32::MAX; old.nodes.len()];
        let mut tree = CsgTree::new();
        let mut origin = Vec::new();
        for i in 0..old.nodes.len() {
            if !keep[i] {
                continue;
            }
            new_id[i] = tree.nodes.len() as u32;
            tree.bounds.push(old.bounds[i]);
            tree.cull_bounds.push(old.cull_bounds[i]);
            origin.push(origins.local(self.origin[i]));
            match old.nodes[i] {
                CsgNode::Leaf(p) => {
                    tree.leaf(PrimId(prims.local(p.0)));
                }
                CsgNode::Op { op, .. } => {
                    let children = old
                        .children_of(NodeId(i as u32))
                        .iter()
                        .map(|c| NodeId(new_id[c.index()]))
                        .collect();
                    tree.op(op, children);
                }
            }
        }
        let mut leaf_span = vec![[0u32; 2]; tree.nodes.len()];
        let mut subtree_leaves: Vec<SubtreeLeaf> = Vec::new();
        let mut regions = self.regions.clone();
        for (r, hulls) in regions.iter_mut().zip(&hulls.0) {
            let region = r.region;
            r.remote_hull = Vec::new();
            // A cell's hull is its subtree's (`cell_hulls`), so cells held
            // elsewhere with the same subtree share one.
            let mut hull_of: BTreeMap<u32, u32> = BTreeMap::new();
            for s in 0..r.supers.len() as u32 {
                let owned = owns(region, s);
                for k in r.cells_of(s) {
                    let t = r.subtree[k];
                    if t >= REMOTE {
                        continue;
                    }
                    if !owned {
                        let i = *hull_of.entry(t).or_insert_with(|| {
                            r.remote_hull.push(hulls[k]);
                            (r.remote_hull.len() - 1) as u32
                        });
                        r.subtree[k] = REMOTE + i;
                        continue;
                    }
                    r.subtree[k] = self.renumber_subtree(
                        t,
                        &new_id,
                        &prims,
                        &mut leaf_span,
                        &mut subtree_leaves,
                    );
                }
            }
            // The BSP is the builder's: the walk reads `supers`, and finds
            // a point's super cell along their corner stitches
            // (`RegionCells::super_cell_at`).
            r.partition.leaves = Vec::new();
            r.partition.nodes = Vec::new();
        }
        debug_assert!(regions.iter().all(|r| {
            r.subtree.iter().all(|&t| {
                t == NO_SUBTREE
                    || super::is_remote(t) && ((t - REMOTE) as usize) < r.remote_hull.len()
                    || (t as usize) < tree.nodes.len()
            })
        }));
        let share = CellStructure {
            view: self.view,
            regions,
            subtrees: tree,
            origin,
            origin_count: origins.len(),
            leaf_span,
            subtree_leaves,
            scene_box: self.scene_box,
            shadows: self.shadows.restricted(&prims.kept),
            clip: self.clip.as_ref().map(|c| {
                Box::new(WideClip {
                    id: prims.get(c.id).unwrap_or(NOT_HELD),
                    ..(**c).clone()
                })
            }),
            primitive_ids: prims.kept.clone(),
            stats: self.stats.clone(),
        };
        let local = Scene {
            camera: scene.camera.clone(),
            background: scene.background,
            ambient: scene.ambient,
            lights: scene.lights.clone(),
            materials: scene.materials.clone(),
            material_names: Vec::new(),
            primitives: prims
                .kept
                .iter()
                .map(|&p| scene.primitives[p as usize].clone())
                .collect(),
            tree: CsgTree::new(),
            max_depth: scene.max_depth,
        };
        (share, local)
    }

    /// The new root of an owned cell's subtree `t`, with its leaf list
    /// copied (once per subtree) into the share's, renumbered.
    fn renumber_subtree(
        &self,
        t: u32,
        new_id: &[u32],
        prims: &Dense,
        leaf_span: &mut [[u32; 2]],
        subtree_leaves: &mut Vec<SubtreeLeaf>,
    ) -> u32 {
        let root = new_id[t as usize];
        if leaf_span[root as usize] == [0, 0] {
            let [a, b] = self.leaf_span[t as usize];
            let start = subtree_leaves.len() as u32;
            subtree_leaves.extend(self.subtree_leaves[a as usize..b as usize].iter().map(|l| {
                SubtreeLeaf {
                    node: new_id[l.node as usize],
                    prim: prims.local(l.prim),
                    ..*l
                }
            }));
            leaf_span[root as usize] = [start, subtree_leaves.len() as u32];
        }
        root
    }

    /// Per region, per cell, the hull of its subtree's leaves (`Hull`;
    /// `Hull::EMPTY` for a cell without content), for `restrict_with`.
    pub fn cell_hulls(&self) -> CellHulls {
        CellHulls(self.regions.each_ref().map(|r| {
            r.subtree
                .iter()
                .map(|&t| {
                    if t < REMOTE {
                        Hull::around(&self.leaf_hull(t), &self.scene_box)
                    } else {
                        Hull::EMPTY
                    }
                })
                .collect()
        }))
    }

    /// The hull of the culling boxes of the leaves of the subtree rooted at
    /// `root`. Every boundary the subtree can return is a crossing of a
    /// leaf whose culling box the ray meets, and lies on the part of that
    /// leaf's surface that survives the operators (the leaf's minimal box,
    /// Algorithm 1): inside the hull.
    fn leaf_hull(&self, root: u32) -> Aabb {
        let [a, b] = self.leaf_span[root as usize];
        self.subtree_leaves[a as usize..b as usize]
            .iter()
            .fold(Aabb::EMPTY, |h, l| h.union(&l.cull))
    }
}

/// What `restrict_with` would give a node, tallied as super cells are
/// added to what it holds one by one, without making the share: the
/// counts its size depends on (`Tally`). Copies are placed by the
/// longest list of them that fits a node (`machine::replicas`); making a
/// share per length tried took 1 ms a try on the sphereflake, eight tries
/// a node, where this tallies every length in the time of one.
pub struct ShareGrowth<'a> {
    cs: &'a CellStructure,
    held: [Vec<bool>; 2],
    /// Subtree nodes reachable from held cells (`restrict_with`'s `keep`).
    kept: Vec<bool>,
    /// Subtree roots of held cells: their leaf lists are copied once each.
    rooted: Vec<bool>,
    prims: Vec<bool>,
    origins: Vec<bool>,
    /// Per region, per subtree root, the cells not held with that root:
    /// the share keeps one hull for each root that has any.
    unheld: [Vec<u32>; 2],
    /// The small solids held (their roots in `ShadowFacts::solids`).
    solids_held: Vec<u32>,
    tally: Tally,
}

/// The counts a share's size depends on, beyond what every share of a
/// structure holds alike.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    /// Subtree nodes, their operators' children, and leaf list entries.
    pub nodes: usize,
    pub children: usize,
    pub leaves: usize,
    /// Primitives and operator mailboxes (origins) referenced.
    pub prims: usize,
    pub origins: usize,
    /// Hulls of cells held elsewhere.
    pub hulls: usize,
    /// Nodes and operators' children of the small solids held
    /// (`ShadowFacts::solids`), and whether the structure has any (then
    /// every share keeps a root per primitive).
    pub solid_nodes: usize,
    pub solid_children: usize,
    pub solids: bool,
}

impl Tally {
    /// The part of `CellStructure::bytes` of a share with these counts
    /// that depends on them: the rest is the same for every share of one
    /// structure.
    pub fn structure_bytes(&self) -> usize {
        use std::mem::size_of;
        self.nodes * (size_of::<CsgNode>() + 2 * size_of::<Aabb>() + 4 + 8)
            + self.children * 4
            + self.leaves * size_of::<SubtreeLeaf>()
            + self.hulls * size_of::<Hull>()
            // `primitive_ids`, and the shadow facts' bit per primitive.
            + self.prims * 4
            + self.prims.div_ceil(64) * 8
            // The shadow facts' small solids, and their root per primitive.
            + self.solid_nodes * (size_of::<CsgNode>() + 2 * size_of::<Aabb>())
            + self.solid_children * size_of::<NodeId>()
            + if self.solids { self.prims * 4 } else { 0 }
    }
}

impl<'a> ShareGrowth<'a> {
    /// The tally of the share of the super cells for which `held` is true.
    pub fn new(cs: &'a CellStructure, held: &dyn Fn(Region, u32) -> bool) -> ShareGrowth<'a> {
        let nodes = cs.subtrees.nodes.len();
        let mut unheld = [vec![0u32; nodes], vec![0u32; nodes]];
        let mut hulls = 0;
        for (r, u) in cs.regions.iter().zip(&mut unheld) {
            for &t in &r.subtree {
                if t < REMOTE {
                    if u[t as usize] == 0 {
                        hulls += 1;
                    }
                    u[t as usize] += 1;
                }
            }
        }
        let mut g = ShareGrowth {
            cs,
            held: cs.regions.each_ref().map(|r| vec![false; r.supers.len()]),
            kept: vec![false; nodes],
            rooted: vec![false; nodes],
            prims: vec![false; max_prim(cs).max(cs.shadows.solid_of.len())],
            origins: vec![false; max_origin(cs)],
            unheld,
            solids_held: Vec::new(),
            tally: Tally {
                hulls,
                solids: !cs.shadows.solid_of.is_empty(),
                ..Tally::default()
            },
        };
        for r in Region::BOTH {
            for s in 0..cs.region(r).supers.len() as u32 {
                if held(r, s) {
                    g.hold(r, s, &mut |_| {});
                }
            }
        }
        g
    }

    /// Adds super cell `s` of region `r` to what is held; `new_prim` is
    /// told each primitive (global number) the share comes to reference.
    pub fn hold(&mut self, r: Region, s: u32, new_prim: &mut dyn FnMut(u32)) {
        let ri = r as usize;
        if std::mem::replace(&mut self.held[ri][s as usize], true) {
            return;
        }
        let (rc, tree) = (self.cs.region(r), &self.cs.subtrees);
        let mut stack = Vec::new();
        for k in rc.cells_of(s) {
            let t = rc.subtree[k];
            if t >= REMOTE {
                continue;
            }
            let u = &mut self.unheld[ri][t as usize];
            *u -= 1;
            if *u == 0 {
                self.tally.hulls -= 1;
            }
            if !std::mem::replace(&mut self.rooted[t as usize], true) {
                let [a, b] = self.cs.leaf_span[t as usize];
                self.tally.leaves += (b - a) as usize;
            }
            stack.push(NodeId(t));
            while let Some(n) = stack.pop() {
                if std::mem::replace(&mut self.kept[n.index()], true) {
                    continue;
                }
                self.tally.nodes += 1;
                let children = tree.children_of(n);
                self.tally.children += children.len();
                stack.extend_from_slice(children);
                if let CsgNode::Leaf(p) = tree.nodes[n.index()] {
                    self.reference(p.0, new_prim);
                }
                let o = self.cs.origin[n.index()] as usize;
                if !std::mem::replace(&mut self.origins[o], true) {
                    self.tally.origins += 1;
                }
            }
        }
    }

    /// Counts primitive `p` (global number) as referenced, with the
    /// small solid it is in, if any, and that solid's other primitives
    /// (`CellStructure::restrict_with` keeps them all).
    fn reference(&mut self, p: u32, new_prim: &mut dyn FnMut(u32)) {
        if std::mem::replace(&mut self.prims[p as usize], true) {
            return;
        }
        self.tally.prims += 1;
        new_prim(p);
        let facts = &self.cs.shadows;
        let Some(root) = facts.solid_of(p) else {
            return;
        };
        if self.solids_held.contains(&root) {
            return;
        }
        self.solids_held.push(root);
        // A tree: every node but its root is one operator's child.
        let nodes = facts.solids.size_from(NodeId(root));
        self.tally.solid_nodes += nodes;
        self.tally.solid_children += nodes - 1;
        for q in facts.solid_primitives(root) {
            self.reference(q, new_prim);
        }
    }

    pub fn tally(&self) -> Tally {
        self.tally
    }
}

/// One past the largest primitive number a structure's subtrees use.
fn max_prim(cs: &CellStructure) -> usize {
    cs.subtrees
        .nodes
        .iter()
        .filter_map(|n| match n {
            CsgNode::Leaf(p) => Some(p.index() + 1),
            _ => None,
        })
        .max()
        .unwrap_or(0)
}

/// One past the largest operator mailbox number of a structure's subtrees.
fn max_origin(cs: &CellStructure) -> usize {
    cs.origin.iter().map(|&o| o as usize + 1).max().unwrap_or(0)
}

/// A renumbering of the ids in use (of primitives, of operator
/// mailboxes) in their global order, as dense arrays: with `BTreeMap`s,
/// restricting the sphereflake took 10 ms a share.
struct Dense {
    /// Per global id, its local id (`u32::MAX` where not in use).
    local: Vec<u32>,
    /// The global ids in use, ascending (local id order).
    kept: Vec<u32>,
}

impl Dense {
    fn new(used: &[bool]) -> Dense {
        let mut local = vec![u32::MAX; used.len()];
        let mut kept = Vec::new();
        for (g, _) in used.iter().enumerate().filter(|(_, u)| **u) {
            local[g] = kept.len() as u32;
            kept.push(g as u32);
        }
        Dense { local, kept }
    }

    fn get(&self, global: u32) -> Option<u32> {
        self.local
            .get(global as usize)
            .copied()
            .filter(|&l| l != u32::MAX)
    }

    /// The local id of a global id in use.
    fn local(&self, global: u32) -> u32 {
        self.get(global).expect("an id in use has a local id")
    }

    fn len(&self) -> usize {
        self.kept.len()
    }
}

/// Per region, per cell, the hull of the cell's content
/// (`CellStructure::cell_hulls`).
pub struct CellHulls([Vec<Hull>; 2]);

/// A box held in 12 bytes: each bound as a 16-bit fraction of the scene
/// box (`CellStructure::scene_box`), rounded outwards and widened by one
/// step, so that the box it stands for (`Hull::bounds`) contains the one
/// it was made from. A node keeps one per cell held elsewhere; against
/// the 24 bytes of f32 bounds this is a quarter of a share's skeleton.
/// The step (1/65535 of the scene box, a pixel's width or so for a scene
/// filling a 1024-pixel image) only ever lets a ray through to the owner
/// that a tighter box would have walked past.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Hull {
    lo: [u16; 3],
    hi: [u16; 3],
}

impl Hull {
    /// A hull no ray meets.
    pub const EMPTY: Hull = Hull {
        lo: [u16::MAX; 3],
        hi: [0; 3],
    };

    const STEPS: f64 = u16::MAX as f64;

    /// The hull of `b`, padded by a relative 1e-6 of its largest
    /// coordinate for the rounding of computed crossings (the machine
    /// tests check the walk against a single node on every bundled and on
    /// random scenes), on the scale of box `scene`.
    pub fn around(b: &Aabb, scene: &Aabb) -> Hull {
        if b.is_empty() || scene.is_empty() {
            return Hull::EMPTY;
        }
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        let pad = lo.iter().chain(&hi).fold(1.0f64, |m, v| m.max(v.abs())) * 1e-6;
        let (lo, hi) = (lo.map(|v| v - pad), hi.map(|v| v + pad));
        let (s0, s1) = (scene.min.to_array(), scene.max.to_array());
        let mut h = Hull {
            lo: [0; 3],
            hi: [0; 3],
        };
        for i in 0..3 {
            let ext = s1[i] - s0[i];
            let frac = |v: f64| {
                if ext > 0.0 && ext.is_finite() {
                    (v - s0[i]) / ext * Hull::STEPS
                } else {
                    f64::NAN
                }
            };
            let (a, z) = (frac(lo[i]), frac(hi[i]));
            // NaN (a degenerate or infinite axis) takes the whole axis.
            h.lo[i] = if a.is_nan() {
                0
            } else {
                (a.floor() - 1.0).clamp(0.0, Hull::STEPS) as u16
            };
            h.hi[i] = if z.is_nan() {
                u16::MAX
            } else {
                (z.ceil() + 1.0).clamp(0.0, Hull::STEPS) as u16
            };
        }
        h
    }

    /// The box the hull stands for, or None for the empty hull. A bound at
    /// the end of the scale stands for everything beyond it, so that a
    /// hull is never smaller than the box it was made from, whatever the
    /// rounding of the scale.
    pub fn bounds(&self, scene: &Aabb) -> Option<Aabb> {
        if (0..3).any(|i| self.lo[i] > self.hi[i]) {
            return None;
        }
        let (s0, s1) = (scene.min.to_array(), scene.max.to_array());
        let mut lo = [0.0; 3];
        let mut hi = [0.0; 3];
        for i in 0..3 {
            let step = (s1[i] - s0[i]) / Hull::STEPS;
            lo[i] = if self.lo[i] == 0 {
                f64::NEG_INFINITY
            } else {
                s0[i] + self.lo[i] as f64 * step
            };
            hi[i] = if self.hi[i] == u16::MAX {
                f64::INFINITY
            } else {
                s0[i] + self.hi[i] as f64 * step
            };
        }
        Some(Aabb {
            min: Vec3::from_array(lo),
            max: Vec3::from_array(hi),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sphereflake of level 2 (92 primitives).
    fn flake2() -> Scene {
        let model = crate::r#gen::sphereflake::sphereflake(2);
        crate::scene::load::compile_model(&model, std::path::Path::new("flake"))
            .expect("the sphereflake compiles")
            .0
    }

    fn contains(outer: &Aabb, inner: &Aabb) -> bool {
        (0..3).all(|i| outer.min[i] <= inner.min[i] && outer.max[i] >= inner.max[i])
    }

    #[test]
    fn a_hull_contains_its_box_and_is_not_much_larger() {
        let scene = Aabb::new(Vec3::new(-3.0, 1e6, -1e-3), Vec3::new(7.0, 1e6 + 2.0, 1e-3));
        let mut x = 12345u64;
        let mut u = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let p = |u: f64, i: usize| scene.min[i] + u * (scene.max[i] - scene.min[i]);
            let (a, b) = ([u(), u(), u()], [u(), u(), u()]);
            let lo = Vec3::from_array(std::array::from_fn(|i| p(a[i].min(b[i]), i)));
            let hi = Vec3::from_array(std::array::from_fn(|i| p(a[i].max(b[i]), i)));
            let b = Aabb::new(lo, hi);
            let h = Hull::around(&b, &scene).bounds(&scene).expect("not empty");
            assert!(contains(&h, &b), "{h:?} does not contain {b:?}");
            // Within a few steps of the scale and the pad (of the largest
            // coordinate) on every axis.
            let big = b.min.abs().max(b.max.abs()).max_element().max(1.0);
            for i in 0..3 {
                let step = (scene.max[i] - scene.min[i]) / Hull::STEPS;
                let slack = 4.0 * step + 2e-6 * big;
                if h.min[i].is_finite() {
                    assert!(b.min[i] - h.min[i] <= slack, "axis {i}: {h:?} {b:?}");
                }
                if h.max[i].is_finite() {
                    assert!(h.max[i] - b.max[i] <= slack, "axis {i}: {h:?} {b:?}");
                }
            }
        }
        // Boxes beyond the scale and degenerate scales take whole axes.
        let wide = Aabb::new(Vec3::splat(-1e9), Vec3::splat(1e9));
        let h = Hull::around(&wide, &scene).bounds(&scene).unwrap();
        assert!(contains(&h, &wide));
        let flat = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0));
        let h = Hull::around(&flat, &flat).bounds(&flat).unwrap();
        assert!(contains(&h, &flat) && h.min.z == f64::NEG_INFINITY);
        assert_eq!(Hull::around(&Aabb::EMPTY, &scene), Hull::EMPTY);
        assert_eq!(Hull::EMPTY.bounds(&scene), None);
    }

    /// A share keeps one hull per subtree held elsewhere, not one per cell
    /// (a cell's hull is its subtree's), and every remote cell names the
    /// hull the whole structure has for that cell.
    #[test]
    fn a_share_keeps_one_hull_per_remote_subtree() {
        let scene = flake2();
        let options = crate::cells::CellOptions {
            min_super_cells: 32,
            ..Default::default()
        };
        let cs = CellStructure::build(&scene, 128, 128, options).unwrap();
        let hulls = cs.cell_hulls();
        let (share, _) = cs.restrict_with(&scene, &|_, s| s % 3 == 0, &hulls);
        let mut shared = 0;
        for (r, (whole, part)) in cs.regions.iter().zip(&share.regions).enumerate() {
            // Remote index -> the whole structure's subtree it stands for.
            let mut named = BTreeMap::new();
            let mut remote_cells = 0;
            for (k, &t) in part.subtree.iter().enumerate() {
                if !super::super::is_remote(t) {
                    continue;
                }
                remote_cells += 1;
                let i = t - REMOTE;
                let root = *named.entry(i).or_insert(whole.subtree[k]);
                assert_eq!(root, whole.subtree[k], "hull {i} serves two subtrees");
                assert_eq!(part.remote_hull[i as usize], hulls.0[r][k]);
            }
            // One hull per distinct subtree: no two indices for one.
            let roots: std::collections::BTreeSet<u32> = named.values().copied().collect();
            assert_eq!(roots.len(), named.len());
            assert_eq!(part.remote_hull.len(), named.len());
            shared += remote_cells - named.len();
        }
        assert!(
            shared > 0,
            "the test scene has no subtree serving two remote cells"
        );
    }

    /// A share knows each primitive it holds by the whole scene's index
    /// (`RayJob::leaving` travels so), and the whole structure's indices
    /// are the scene's.
    #[test]
    fn a_share_maps_its_primitives_to_the_whole_scene_and_back() {
        let scene = flake2();
        let cs = CellStructure::build(&scene, 64, 64, Default::default()).unwrap();
        let n = scene.primitives.len() as u32;
        for g in [0, 1, n - 1] {
            assert_eq!(cs.local_primitive(PrimId(g)), Some(PrimId(g)));
            assert_eq!(cs.global_primitive(PrimId(g)), PrimId(g));
        }
        let (share, local) = cs.restrict(&scene, &|_, s| s % 2 == 1);
        let held = local.primitives.len();
        assert!(held > 0 && held < scene.primitives.len(), "{held} held");
        let mut found = 0;
        for g in 0..n {
            match share.local_primitive(PrimId(g)) {
                Some(p) => {
                    found += 1;
                    assert_eq!(share.global_primitive(p), PrimId(g));
                    assert_eq!(local.primitives[p.index()], scene.primitives[g as usize]);
                }
                None => assert!(!share.primitive_ids.contains(&g)),
            }
        }
        assert_eq!(found, held);
    }
}
