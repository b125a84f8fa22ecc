//! Replicas: copies of other nodes' super cells that a node holds in the
//! memory its own share leaves free, so that the rays it would send to
//! their owners are traced where they are. The paper's plan spreads the
//! cell structure because one node cannot hold it (section 10); where a
//! node can hold more than its part, a ray that reaches a cell it holds a
//! copy of goes on without a message, and the node's time goes to tracing
//! instead of encoding, sending and decoding paths. (Later distributed
//! ray tracers, Badouel, Bouatouch and Priol's on the iPSC/2 among them,
//! cached remote scene data on each node for the same reason; here the
//! copies are chosen before the render and arrive in the load message,
//! so a node still knows only what messages told it.)
//!
//! Which super cells a node copies (`choose`): those its rays moved to
//! most often in the mapping's last pre-pass (`mapping::map`'s moves) for
//! their size, then any other with content (`wanted`), as long as
//!
//! * the structure over all nodes stays within `REPLICA_CAP` times the
//!   single node's (issue 4's bound on what distribution may cost in
//!   memory), the nodes that want least served first, each within an
//!   equal part of what is left; and
//! * the node keeps room for at least `KEEP_WINDOW` of the window of
//!   primary paths its own share leaves (`host::Plan`): a node whose rays
//!   stay home needs fewer in flight, but not none.
//!
//! Copies move work (the rays a node would have sent, it traces itself),
//! so the pre-pass is walked again with them, and where it finds the
//! loads uneven the mapping is refined and the copies chosen again for it
//! (`place`; where the refined mapping would pass the bound, no copies).
//! A super cell's pixels stay its owner's. The image is the same with and
//! without copies (a cell's content is the same wherever it is walked),
//! and `--replicas none` gives the paper's plan alone. `--replicas whole`
//! (`Replicas::Whole`) is not placed here: every node then holds
//! everything (`host::Plan`), mapped by `mapping::map_whole`.

use std::collections::BTreeMap;

use crate::cells::share::{CellHulls, ShareGrowth, Tally};
use crate::cells::traverse::CellTracer;
use crate::cells::{CellStructure, Copies, Move, Region};
use crate::machine::node;
use crate::scene::Scene;
use crate::trace::collect_parallel;

/// Whether nodes hold copies of other nodes' super cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Replicas {
    // The variants' doc comments are `--replicas`'s help: for users.
    /// Copies of the super cells a node's rays reach most, where memory
    /// allows; the whole scene on every node where, distributed, the work
    /// would sit on few nodes and the scene takes at most half a node
    /// (default).
    // `host::Plan::or_whole`, `AUTO_WHOLE_UNEVEN`.
    #[default]
    Auto,
    /// No copies: every ray that reaches another node's cell goes there
    /// (the paper's plan alone).
    // The super cells the mapping asks for are then cut from the BSP's
    // first level on (`CellOptions::force_from_root`).
    None,
    /// Every node holds the whole scene, so no ray leaves the node of its
    /// pixel (the classic alternative to the paper's plan; refused where
    /// the scene does not fit a node).
    // The super cells still share out the pixels, dealt out by their
    // pixels' work (`mapping::map_whole`).
    Whole,
}

impl Replicas {
    /// The name `--replicas` takes.
    pub fn name(self) -> String {
        super::value_name(self)
    }
}

/// The most the structure held over all nodes may be, copies included,
/// against the whole structure (what one node holding all of it holds):
/// issue 4's bound on the sphereflake at d = 5, kept for every scene and
/// dimension. At d = 1 it lets each of the two nodes hold everything.
pub const REPLICA_CAP: f64 = 2.0;

/// The share of its window (the primary paths in flight it would have
/// without copies) that a node keeps when copies take memory.
pub const KEEP_WINDOW: f64 = 0.5;

/// What a node may copy, most wanted first: the super cells with content
/// that other nodes own, by the moves of its rays to them in `moves` (the
/// pre-pass's) per leaf of their cells' subtrees (what a copy costs,
/// roughly), most first; ties, and super cells no sampled ray reached, in
/// index order. Super cells as (region index, super cell). (By moves
/// alone, the sphereflake at 1024x1024 sent 858,000 hops at d = 3 and
/// 2.76 million at d = 5; per leaf, 715,000 and 2.67 million.)
pub fn wanted(
    cells: &CellStructure,
    owner: &[Vec<u16>; 2],
    moves: &[Move],
    nodes: usize,
) -> Vec<Vec<(usize, u32)>> {
    let mut tally: Vec<BTreeMap<(usize, u32), u64>> = vec![BTreeMap::new(); nodes];
    for m in moves {
        if let Some(t) = tally.get_mut(m.from as usize) {
            *t.entry((m.region as usize, m.super_cell)).or_insert(0) += 1;
        }
    }
    // Super cells with content, and what copying each costs.
    let with_content: Vec<((usize, u32), u64)> = Region::BOTH
        .iter()
        .flat_map(|&r| {
            let rc = cells.region(r);
            (0..rc.supers.len() as u32)
                .filter(move |&s| !rc.super_cell_is_empty(s))
                .map(move |s| ((r as usize, s), leaves_in(cells, r, s)))
        })
        .collect();
    (0..nodes)
        .map(|i| {
            let mut order: Vec<((usize, u32), f64)> = with_content
                .iter()
                .filter(|&&((r, s), _)| owner[r][s as usize] as usize != i)
                .map(|&(c, leaves)| {
                    let t = tally[i].get(&c).copied().unwrap_or(0) as f64;
                    (c, t / (1 + leaves) as f64)
                })
                .collect();
            order.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            order.into_iter().map(|(c, _)| c).collect()
        })
        .collect()
}

/// The leaves of the subtrees of super cell `s`'s cells: what a copy of
/// it costs, roughly.
fn leaves_in(cells: &CellStructure, r: Region, s: u32) -> u64 {
    let rc = cells.region(r);
    rc.cells_of(s)
        .map(|k| rc.subtree[k])
        .filter(|&t| t < crate::cells::REMOTE)
        .map(|t| {
            let [a, b] = cells.leaf_span[t as usize];
            u64::from(b - a)
        })
        .sum()
}

/// The size of node `node`'s share (its own is `own`) with copies of each
/// prefix of `wanted`: entry `k - 1` for the first `k`. Tallied as the
/// copies are added one by one (`ShareGrowth`), from its own share's size
/// by difference; no share is made.
fn prefix_sizes(
    m: &Machine,
    owner: &[Vec<u16>; 2],
    node: usize,
    wanted: &[(usize, u32)],
    own: &NodeShare,
) -> Vec<Size> {
    let held = |r: Region, s: u32| owner[r as usize][s as usize] as usize == node;
    let mut growth = ShareGrowth::new(m.cells, &held);
    let sizes = Sizes::new(m.whole, Size::of(own), growth.tally());
    let mut added_prims = 0;
    wanted
        .iter()
        .map(|&(r, s)| {
            growth.hold(Region::BOTH[r], s, &mut |p| {
                added_prims += sizes.primitive(p)
            });
            sizes.of(growth.tally(), added_prims)
        })
        .collect()
}

/// The length of the longest prefix whose size (`prefix_sizes`) leaves
/// `slack` at or above zero; 0 if none does.
fn longest_fit(sizes: &[Size], slack: &dyn Fn(Size) -> f64) -> usize {
    sizes
        .iter()
        .rposition(|&s| slack(s) >= 0.0)
        .map_or(0, |k| k + 1)
}

/// Node `node`'s share with copies of `copied`, whose size was tallied as
/// `size` (`prefix_sizes`; debug builds check it).
fn share_of_prefix(
    m: &Machine,
    owner: &[Vec<u16>; 2],
    node: usize,
    copied: &[(usize, u32)],
    size: Size,
) -> NodeShare {
    let mut held = Region::BOTH.map(|r| vec![false; m.cells.region(r).supers.len()]);
    for &(r, s) in copied {
        held[r][s as usize] = true;
    }
    let share = m.cells.restrict_with(
        m.scene,
        &|r, s| owner[r as usize][s as usize] as usize == node || held[r as usize][s as usize],
        m.hulls,
    );
    debug_assert_eq!(Size::of(&share), size, "the tally is the share's");
    share
}

/// A share's `Size` from its tally (`ShareGrowth`), by the difference
/// from a share of the same structure whose size and tally are known.
struct Sizes {
    base: Size,
    tally: Tally,
    /// Per global primitive number, its bytes on a node (from the share of
    /// the whole structure, whose primitives are clones as every share's
    /// are).
    primitive: Vec<usize>,
}

impl Sizes {
    fn new((cells, scene): &NodeShare, base: Size, tally: Tally) -> Sizes {
        let ids = &cells.primitive_ids;
        let mut primitive = vec![0; ids.iter().map(|&g| g as usize + 1).max().unwrap_or(0)];
        for (&g, p) in ids.iter().zip(&scene.primitives) {
            primitive[g as usize] = node::primitive_bytes(p);
        }
        Sizes {
            base,
            tally,
            primitive,
        }
    }

    fn primitive(&self, global: u32) -> usize {
        self.primitive[global as usize]
    }

    /// The size of a share with tally `t` whose primitives beyond the
    /// base's take `added_prims` bytes.
    fn of(&self, t: Tally, added_prims: usize) -> Size {
        let (b, base) = (&self.tally, self.base);
        let delta = |now: usize, then: usize| now as i64 - then as i64;
        let structure = delta(t.structure_bytes(), b.structure_bytes());
        let tracer = delta(t.prims, b.prims) * CellTracer::BYTES_PER_PRIMITIVE as i64
            + delta(t.origins, b.origins) * CellTracer::BYTES_PER_ORIGIN as i64;
        let add = |v: u64, d: i64| (v as i64 + d) as u64;
        Size {
            structure: add(base.structure, structure),
            node: add(base.node, structure + tracer + added_prims as i64),
        }
    }
}

/// A share's bytes on its node (`node::share_bytes`) and its structure's
/// (`CellStructure::bytes`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Size {
    pub node: u64,
    pub structure: u64,
}

impl Size {
    pub fn of((c, sc): &NodeShare) -> Size {
        Size {
            node: crate::machine::node::share_bytes(c, sc),
            structure: c.bytes() as u64,
        }
    }
}

/// A node's share: its structure and its scene (`restrict_with`).
pub type NodeShare = (CellStructure, Scene);

/// What copies are placed for: the structure and scene, every cell's
/// hull (`cell_hulls`), the image size, the dimension, the share of a node
/// that holds the whole structure (`restrict_with` of every super cell),
/// and the bytes of the structure a single node builds (`CellStructure::
/// bytes` of it whole), against which `REPLICA_CAP` counts.
pub struct Machine<'a> {
    pub cells: &'a CellStructure,
    pub scene: &'a Scene,
    pub hulls: &'a CellHulls,
    pub size: (u32, u32),
    pub d: u32,
    pub whole: &'a NodeShare,
    pub single: u64,
}

/// What `place` gives.
pub struct Placed {
    /// The owner of every super cell: the mapping's, or refined where the
    /// copies made the loads uneven (`mapping::rebalance_with_copies`).
    pub owner: [Vec<u16>; 2],
    /// Per node, its share with its copies.
    pub shares: Vec<NodeShare>,
    /// Where any node copies anything: per super cell, the nodes that
    /// copy it, and the work per super cell as the pre-pass measured it
    /// with them (under the owner before any refinement).
    pub copies: Option<(Copies, [Vec<f64>; 2])>,
}

/// Copies for every node of `m` (`choose`), from the mapping's `owner`,
/// the nodes' own `shares` under it and the pre-pass's `moves`; then the
/// pre-pass walked with them, and, where that finds the loads uneven, the
/// owner refined and the copies chosen again for it. (Copies move work:
/// the rays a node would have sent, it traces itself. On the sphereflake
/// at d = 5 they took the busy imbalance from 1.13 to 1.25 before this.)
/// `own_shares(owner)` restricts the structure to each node's own super
/// cells; `memory(own)` is what a node's share may take with copies.
/// Fails only if the OS refuses a pre-pass thread.
pub fn place(
    m: &Machine,
    (owner, shares): ([Vec<u16>; 2], Vec<NodeShare>),
    moves: &[Move],
    own_shares: &dyn Fn(&[Vec<u16>; 2]) -> Vec<NodeShare>,
    memory: &dyn Fn(&[NodeShare]) -> u64,
) -> crate::error::Result<Placed> {
    let limit = memory(&shares);
    let held = |shares: &[NodeShare]| shares.iter().map(|(c, _)| c.bytes() as u64).sum::<u64>();
    // What the structure over all nodes may come to: the cap, or what
    // the mapping's own shares hold already where that is more.
    let bound = held(&shares).max((REPLICA_CAP * m.single as f64) as u64);
    let (with, copies) = choose(m, &owner, moves, shares, limit);
    if copies.iter().flatten().all(Vec::is_empty) {
        return Ok(Placed {
            owner,
            shares: with,
            copies: None,
        });
    }
    let mut refined = owner.clone();
    let (work, changed) = crate::machine::mapping::rebalance_with_copies(
        m.cells,
        m.scene,
        m.size,
        &mut refined,
        &copies,
        m.d,
    )?;
    if changed {
        let own = own_shares(&refined);
        let limit = memory(&own);
        // Refined, a node may own more than fits beside a window, or the
        // nodes more than the bound: then the mapping's owner stays.
        if own
            .iter()
            .all(|(c, s)| crate::machine::node::share_bytes(c, s) <= limit)
        {
            let (with, copies) = choose(m, &refined, moves, own, limit);
            if held(&with) <= bound {
                return Ok(Placed {
                    owner: refined,
                    shares: with,
                    copies: Some((copies, work)),
                });
            }
        }
        // The copies unbalance the loads, and the mapping cannot be
        // refined for them: none (on 32 nodes, `csg_basics.ron` at
        // 320x240 predicted 1.35 with them, under the bound, and its
        // refinement went past it).
        return Ok(Placed {
            shares: own_shares(&owner),
            owner,
            copies: None,
        });
    }
    Ok(Placed {
        owner,
        shares: with,
        copies: Some((copies, work)),
    })
}

/// Every node's share with copies, and which copies each holds. A node
/// that copies every super cell it wants holds the whole structure
/// (`Machine::whole`), so what each would add is known before any
/// restriction: the room `REPLICA_CAP` leaves over all nodes goes first,
/// whole, to the nodes that want least (each within an equal part of what
/// is left), and the others share the rest equally and copy the longest
/// prefix of what they want that fits it. No share passes `memory` bytes
/// (`node::share_bytes`). The sizes of every node's prefixes do not
/// depend on the room, so they are tallied over the host's cores, as the
/// shares kept are made; only the room is dealt out node after node.
fn choose(
    m: &Machine,
    owner: &[Vec<u16>; 2],
    moves: &[Move],
    mut shares: Vec<NodeShare>,
    memory: u64,
) -> (Vec<NodeShare>, Copies) {
    let n = shares.len();
    let wanted = wanted(m.cells, owner, moves, n);
    let own: Vec<Size> = shares.iter().map(Size::of).collect();
    let all = Size::of(m.whole);
    let sizes = collect_parallel(n, |i| prefix_sizes(m, owner, i, &wanted[i], &shares[i]));
    let held: u64 = own.iter().map(|s| s.structure).sum();
    let mut room = ((REPLICA_CAP * m.single as f64) as u64).saturating_sub(held);
    let mut copied = vec![0; n];
    // The nodes that want copies, least wanting first.
    let mut order: Vec<usize> = (0..n).filter(|&i| !wanted[i].is_empty()).collect();
    order.sort_by_key(|&i| (all.structure.saturating_sub(own[i].structure), i));
    for (done, &i) in order.iter().enumerate() {
        let each = room / (order.len() - done) as u64;
        let limit = own[i].structure + each;
        let slack =
            |s: Size| (memory as f64 - s.node as f64).min(limit as f64 - s.structure as f64);
        let (k, size) = if slack(all) >= 0.0 {
            (wanted[i].len(), all)
        } else {
            match longest_fit(&sizes[i], &slack) {
                0 => (0, own[i]),
                k => (k, sizes[i][k - 1]),
            }
        };
        copied[i] = k;
        // (A copy may leave a structure smaller: a cell held adds its
        // subtree, which the node may hold already, and drops its hull.)
        room = room.saturating_sub(size.structure.saturating_sub(own[i].structure));
    }
    let made = collect_parallel(n, |i| match copied[i] {
        0 => None,
        k if k == wanted[i].len() => Some(m.whole.clone()),
        k => Some(share_of_prefix(
            m,
            owner,
            i,
            &wanted[i][..k],
            sizes[i][k - 1],
        )),
    });
    for (share, made) in shares.iter_mut().zip(made) {
        if let Some(made) = made {
            *share = made;
        }
    }
    let mut copies: Copies = Region::BOTH.map(|r| vec![Vec::new(); m.cells.region(r).supers.len()]);
    for (i, w) in wanted.iter().enumerate() {
        for &(r, s) in &w[..copied[i]] {
            copies[r][s as usize].push(i as u16);
        }
    }
    (shares, copies)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cells::CellOptions;
    use crate::scene::load::compile_model;

    /// Every prefix's size, made by restricting the structure, against
    /// the tally's (`ShareGrowth`, `Sizes`): the sizes the copies are
    /// placed by are the shares' own, or a node could be given more than
    /// fits it. On the sphereflake and on random CSG scenes (primitives
    /// shared by many cells, operators, polygons), every super cell in a
    /// random order after a random owner's.
    #[test]
    fn every_prefix_is_tallied_at_its_shares_size() {
        let flake = crate::r#gen::sphereflake::sphereflake(2);
        let mut models = vec![(flake, 1u64)];
        for seed in 0..12 {
            models.push((
                crate::r#gen::random_csg(seed, 4 + 5 * seed as usize, &Default::default()),
                seed,
            ));
        }
        for (model, seed) in models {
            let scene = compile_model(&model, std::path::Path::new("t.ron"))
                .expect("compiles")
                .0;
            let cells = CellStructure::build(&scene, 48, 40, CellOptions::default()).unwrap();
            let hulls = cells.cell_hulls();
            let whole = cells.restrict_with(&scene, &|_, _| true, &hulls);
            let mut rng = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
            let mut next = move || {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                rng
            };
            let owner = Region::BOTH.map(|r| {
                (0..cells.region(r).supers.len())
                    .map(|_| (next() % 3) as u16)
                    .collect::<Vec<_>>()
            });
            let mut order: Vec<(usize, u32)> = Region::BOTH
                .iter()
                .flat_map(|&r| {
                    (0..cells.region(r).supers.len() as u32).map(move |s| (r as usize, s))
                })
                .filter(|&(r, s)| owner[r][s as usize] != 0)
                .collect();
            for i in (1..order.len()).rev() {
                order.swap(i, next() as usize % (i + 1));
            }
            let own =
                cells.restrict_with(&scene, &|r, s| owner[r as usize][s as usize] == 0, &hulls);
            let held = |r: Region, s: u32| owner[r as usize][s as usize] == 0;
            let mut growth = ShareGrowth::new(&cells, &held);
            let sizes = Sizes::new(&whole, Size::of(&own), growth.tally());
            let mut added = 0;
            for k in 0..=order.len() {
                if k > 0 {
                    let (r, s) = order[k - 1];
                    growth.hold(Region::BOTH[r], s, &mut |p| added += sizes.primitive(p));
                }
                let prefix = &order[..k];
                let real = Size::of(&cells.restrict_with(
                    &scene,
                    &|r, s| held(r, s) || prefix.contains(&(r as usize, s)),
                    &hulls,
                ));
                assert_eq!(
                    sizes.of(growth.tally(), added),
                    real,
                    "seed {seed}: prefix {k} of {}",
                    order.len()
                );
            }
        }
    }

    /// The copies kept are the longest prefix that fits (found here by
    /// making every prefix's share), whatever share of the room between
    /// the node's own share and the whole one the limit leaves.
    #[test]
    fn the_copies_are_the_longest_prefix_that_fits() {
        let model = crate::r#gen::sphereflake::sphereflake(3);
        let scene = compile_model(&model, std::path::Path::new("flake.ron"))
            .expect("compiles")
            .0;
        let cells = CellStructure::build(&scene, 64, 64, CellOptions::default()).unwrap();
        let hulls = cells.cell_hulls();
        // Two nodes, every other super cell each.
        let owner = Region::BOTH.map(|r| {
            (0..cells.region(r).supers.len())
                .map(|s| (s % 2) as u16)
                .collect::<Vec<_>>()
        });
        let whole = cells.restrict_with(&scene, &|_, _| true, &hulls);
        let m = Machine {
            cells: &cells,
            scene: &scene,
            hulls: &hulls,
            size: (64, 64),
            d: 1,
            whole: &whole,
            single: whole.0.bytes() as u64,
        };
        let wanted = wanted(&cells, &owner, &[], 2);
        let own = cells.restrict_with(&scene, &|r, s| owner[r as usize][s as usize] == 0, &hulls);
        let sizes: Vec<Size> = (0..=wanted[0].len())
            .map(|k| {
                let held: Vec<(usize, u32)> = wanted[0][..k].to_vec();
                Size::of(&cells.restrict_with(
                    &scene,
                    &|r, s| owner[r as usize][s as usize] == 0 || held.contains(&(r as usize, s)),
                    &hulls,
                ))
            })
            .collect();
        assert!(wanted[0].len() > 20, "{}", wanted[0].len());
        let (lo, hi) = (Size::of(&own).node, Size::of(&whole).node);
        for tenth in 1..10 {
            let limit = lo + (hi - lo) * tenth / 10;
            let slack = |s: Size| limit as f64 - s.node as f64;
            let longest = sizes.iter().rposition(|s| slack(*s) >= 0.0).unwrap();
            // As `choose` keeps them: the prefixes tallied, the longest
            // that fits found among them, and only its share made.
            let tallied = prefix_sizes(&m, &owner, 0, &wanted[0], &own);
            let k = longest_fit(&tallied, &slack);
            assert_eq!(k, longest, "limit {tenth}/10");
            let share =
                (k > 0).then(|| share_of_prefix(&m, &owner, 0, &wanted[0][..k], tallied[k - 1]));
            let size = share.as_ref().map_or(Size::of(&own), Size::of);
            assert_eq!(
                size, sizes[k],
                "limit {tenth}/10: the share is the prefix's"
            );
        }
    }
}
