//! A node's share of the cell structure (the paper's closing plan, section
//! 9: the cells distributed over the nodes of a hypercube).
//!
//! A node holds the *skeleton* of the whole structure, which is what the
//! walk between cells reads (the BSP, the super cells' rectangles and
//! corner pointers, every cell's depth slab) and which doubles as the
//! cell-to-node map, but the *content* (CSG subtrees and the primitives
//! they reference) only of the cells it owns. A cell with content held
//! elsewhere is marked `REMOTE`: a walk stops there and the ray moves to
//! the owner. Empty cells are walked by whoever holds the ray, so rays
//! cross empty space without a message.

use std::collections::BTreeMap;

use super::{CellStructure, NO_SUBTREE, REMOTE, Region, SubtreeLeaf};
use crate::csg::{CsgNode, CsgTree, NodeId, PrimId};
use crate::geom::Aabb;
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
        let old = &self.subtrees;
        // The subtree nodes reachable from owned cells.
        let mut keep = vec![false; old.nodes.len()];
        let mut stack = Vec::new();
        for r in &self.regions {
            for c in &r.cells {
                if c.subtree < REMOTE && owns(r.region, c.super_cell) && !keep[c.subtree as usize] {
                    stack.push(NodeId(c.subtree));
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
        let mut prims = BTreeMap::new();
        let mut origins = BTreeMap::new();
        for (i, n) in old.nodes.iter().enumerate() {
            if keep[i] {
                if let CsgNode::Leaf(p) = n {
                    prims.insert(p.0, 0u32);
                }
                origins.insert(self.origin[i], 0u32);
            }
        }
        for (k, v) in prims.values_mut().enumerate() {
            *v = k as u32;
        }
        for (k, v) in origins.values_mut().enumerate() {
            *v = k as u32;
        }
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
            origin.push(origins[&self.origin[i]]);
            match old.nodes[i] {
                CsgNode::Leaf(p) => {
                    tree.leaf(PrimId(prims[&p.0]));
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
        for r in &mut regions {
            let region = r.region;
            r.remote_hull = vec![EMPTY_HULL; r.cells.len()];
            for (k, c) in r.cells.iter_mut().enumerate() {
                if c.subtree >= REMOTE {
                    continue;
                }
                if !owns(region, c.super_cell) {
                    r.remote_hull[k] = self.leaf_hull(c.subtree);
                    c.subtree = REMOTE;
                    continue;
                }
                let root = new_id[c.subtree as usize];
                if leaf_span[root as usize] == [0, 0] {
                    let [a, b] = self.leaf_span[c.subtree as usize];
                    let start = subtree_leaves.len() as u32;
                    subtree_leaves.extend(self.subtree_leaves[a as usize..b as usize].iter().map(
                        |l| SubtreeLeaf {
                            node: new_id[l.node as usize],
                            prim: prims[&l.prim],
                            ..*l
                        },
                    ));
                    leaf_span[root as usize] = [start, subtree_leaves.len() as u32];
                }
                c.subtree = root;
            }
            // Super cells' primitive lists (global ids): only "empty or not"
            // is read, for pixel areas, and only of owned super cells.
            for (s, leaf) in r.partition.leaves.iter_mut().enumerate() {
                if !owns(region, s as u32) {
                    leaf.prims = Vec::new();
                }
            }
        }
        debug_assert!(
            regions
                .iter()
                .all(|r| r.cells.iter().all(|c| c.subtree == NO_SUBTREE
                    || c.subtree == REMOTE
                    || (c.subtree as usize) < tree.nodes.len()))
        );
        let share = CellStructure {
            view: self.view,
            regions,
            subtrees: tree,
            origin,
            origin_count: origins.len(),
            leaf_span,
            subtree_leaves,
            scene_box: self.scene_box,
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
                .keys()
                .map(|&p| scene.primitives[p as usize].clone())
                .collect(),
            tree: CsgTree::new(),
            max_depth: scene.max_depth,
        };
        (share, local)
    }

    /// The hull of the culling boxes of the leaves of the subtree rooted at
    /// `root`, rounded outwards to f32 and padded. Every boundary the
    /// subtree can return is a crossing of a leaf whose culling box the ray
    /// meets, and lies on the part of that leaf's surface that survives the
    /// operators (the leaf's minimal box, Algorithm 1): inside the hull.
    /// The pad (relative 1e-6 of the hull's largest coordinate) covers the
    /// rounding of computed crossings, which the machine tests check
    /// against a single node on every bundled and on random scenes.
    fn leaf_hull(&self, root: u32) -> [f32; 6] {
        let [a, b] = self.leaf_span[root as usize];
        let hull = self.subtree_leaves[a as usize..b as usize]
            .iter()
            .fold(Aabb::EMPTY, |h, l| h.union(&l.cull));
        if hull.is_empty() {
            return EMPTY_HULL;
        }
        let (lo, hi) = (hull.min.to_array(), hull.max.to_array());
        let scale = lo.iter().chain(&hi).fold(1.0f64, |m, v| m.max(v.abs()));
        let pad = scale * 1e-6;
        let mut out = [0f32; 6];
        for i in 0..3 {
            out[i] = ((lo[i] - pad) as f32).next_down();
            out[i + 3] = ((hi[i] + pad) as f32).next_up();
        }
        out
    }
}

/// A hull no ray meets (min above max).
const EMPTY_HULL: [f32; 6] = [1.0, 1.0, 1.0, -1.0, -1.0, -1.0];
