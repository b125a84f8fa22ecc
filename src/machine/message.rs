//! What travels between the host and the nodes. A node knows nothing but
//! what these messages tell it: its share of the cells (`Share`, in the
//! load message), then rays, credits and the order to stop.
//!
//! Rays travel as *paths*: a path is the ray tree of one primary sample,
//! followed depth first as `Shader::run_path` does on one node. Its active
//! ray moves from node to node; the rays it has spawned but not yet traced
//! travel with it (`stack`), and its contributions are summed in fixed
//! point as it goes (`sum`), so that one message reaches the host per
//! sample. A shadow ray that leaves a node while rays of its path wait
//! there goes on alone, as a leaf path (`Part`). Every ray carries what it
//! needs to finish anywhere: pixel, weight, depth, kind, its number within
//! the path, and where its walk stands.

use serde::{Deserialize, Serialize};

use crate::cells::{CellStructure, WalkPoint};
use crate::scene::Scene;
use crate::trace::RayJob;

/// Host to node.
#[derive(Serialize, Deserialize)]
pub enum ToNode {
    /// The node's share: the first message it gets, once per pass.
    Load(Box<Share>),
    /// A batch of paths over one link, in their wire form
    /// (`codec::RaysOut`).
    Rays(super::codec::WireBatch),
    /// Permission to start this many more primary paths.
    Credit(u32),
    /// Every path is finished: report and stop.
    Stop,
    /// From neighbour `from`, for the emulation only (not a message of the
    /// modelled machine, not counted): the frame's stamp bounds the virtual
    /// time of whatever it will send next (`node::LAG_SLICES`).
    Clock {
        /// The neighbour's node number.
        from: u16,
    },
}

/// Node to host.
#[derive(Serialize, Deserialize)]
pub enum ToHost {
    /// The node has taken its share and is ready to trace.
    Loaded {
        /// The sender's node number.
        node: u16,
    },
    /// Finished samples, in a batch (`codec::pack_done_into`).
    Done {
        /// The sender's node number.
        node: u16,
        /// The samples, packed.
        finished: super::codec::WireDone,
    },
    /// The node has started every sample it owns: this many.
    Generated {
        /// The sender's node number.
        node: u16,
        /// Samples started, background ones included.
        samples: u64,
    },
    /// The node's counts and clocks, after `Stop`.
    Report(Box<NodeReport>),
    /// The node stopped on an error (or an injected fault).
    Failed {
        /// The failed node's number.
        node: u16,
        /// What went wrong, for the user's message.
        error: String,
    },
}

/// A node's share: everything it will ever know about the scene. Nothing
/// in it names the node (a node knows its own number from its links, as
/// the iPSC's nodes did), so nodes with the same share, as every node is
/// with the whole scene (`Replicas::Whole`), get the same bytes, encoded
/// once.
#[derive(Serialize, Deserialize)]
pub struct Share {
    /// The hypercube's dimension d: the node's links are to the nodes
    /// whose numbers differ from its own in one of d bits.
    pub dimension: u32,
    /// The skeleton of every cell, the content of the owned ones
    /// (`CellStructure::restrict`).
    pub cells: CellStructure,
    /// The primitives the owned cells reference, renumbered; lights,
    /// materials, camera.
    pub scene: Scene,
    /// The cell-to-node map: per region, per super cell, its owner.
    pub owner: [Vec<u16>; 2],
    /// The image's size in pixels.
    pub width: u32,
    pub height: u32,
    /// Samples per pixel of this pass, and the index of its first sample
    /// (`render::aa::Pass`).
    pub spp: u32,
    pub first_sample: u32,
    /// The pass's pixels; None: every pixel.
    pub pixels: Option<Vec<u32>>,
    /// Primary paths the node may have unfinished at once (flow control:
    /// with every node's window, the paths in flight fit any node).
    pub window: u32,
    /// Shadow rays a sample may send off alone (`host::fork_limit`): the
    /// leaves the plan counts in each path's bound.
    pub forks: u16,
    /// Finished records no credit covers (of samples credited on this
    /// node, `node::Node::credit_locally`, and of background samples) that
    /// may wait for the host's link at once: as many as fit the room the
    /// plan keeps for a window of paths.
    pub local_credits: u32,
    /// The node's memory budget in bytes: what it holds never exceeds it.
    pub budget: u64,
    /// The modelled machine's costs, for the node's virtual clock.
    pub link: LinkModel,
    /// How the node keeps pace with the others on this host (`node::Pacing`):
    /// an emulation parameter of the host's threads, not of the modelled
    /// machine.
    pub pacing: super::node::Pacing,
}

/// The topology's cost model of computing and communicating.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct LinkModel {
    /// Seconds a message takes per hop, after it is sent.
    pub latency: f64,
    /// Bytes per second on one link.
    pub bandwidth: f64,
    /// Seconds of the sender's time per message (software start-up).
    pub overhead: f64,
    /// Node speed relative to one host core (the clock advances by host
    /// CPU seconds over it).
    pub compute_speed: f64,
}

impl LinkModel {
    /// Virtual seconds the sender spends on a message of `bytes`.
    pub fn send_cost(&self, bytes: usize) -> f64 {
        self.overhead + bytes as f64 / self.bandwidth
    }
}

/// A path on its way to node `dest`, `hops` links so far.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Routed {
    /// The node that owns the cell where the path's walk stopped.
    pub dest: u16,
    /// Links crossed so far (at most the dimension: e-cube routing).
    pub hops: u8,
    /// The path itself.
    pub path: Path,
}

/// The ray tree of one primary sample, being traced depth first.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Path {
    /// `pixel · spp + k`: unique per sample.
    pub sample: u64,
    /// The node that started it (and gets its credit back).
    pub origin: u16,
    /// Fixed-point sum of the contributions so far (`Film::quantize`).
    pub sum: [i64; 3],
    /// The ray being traced.
    pub active: Active,
    /// Spawned rays not yet traced.
    pub stack: Vec<RayJob>,
    /// Shadow rays sent off alone as leaves (`Share::forks`).
    pub forks: u16,
    /// A leaf: one shadow ray of the sample, gone on alone.
    pub leaf: bool,
}

/// The ray being traced.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Active {
    /// The ray, with its pixel, weight, depth and kind.
    pub job: RayJob,
    /// Its number within the path, in tracing order: with `sample`, it
    /// names the ray uniquely.
    pub number: u32,
    /// Boundaries count from here (a shadow ray past a transparent surface).
    pub t_min: f64,
    /// Where its walk stopped, if it did so at another node's cell.
    pub at: Option<WalkPoint>,
}

impl Path {
    /// Bytes the path occupies in a node's memory.
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<Path>() + self.stack.capacity() * std::mem::size_of::<RayJob>()
    }
}

/// A finished sample.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Finished {
    /// `pixel · spp + k` (`Path::sample`).
    pub sample: u64,
    /// The node that started it.
    pub origin: u16,
    /// Fixed-point sum of its contributions (`Film::quantize`).
    pub sum: [i64; 3],
    /// False for samples of empty pixel areas, never traced.
    pub traced: bool,
    /// The origin node took its credit back itself: the whole sample
    /// finished there (`node::Node::credit_locally`), so the host returns
    /// none.
    pub credited: bool,
    /// The root of the sample, or one of its leaves.
    pub part: Part,
}

/// Which piece of a sample finished. A sample is finished when its root
/// (the path it started as) and as many leaves as the root sent off have
/// finished: the root's count comes with the root, and leaves spawn
/// nothing, so the count is exact whatever order the pieces arrive in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Part {
    /// The path the sample started as, with the number of leaves it sent
    /// off.
    Root { forks: u16 },
    /// A shadow ray of the sample that went on alone.
    Leaf,
}

impl NodeReport {
    /// Adds the report of a later pass of the same node.
    pub fn add_pass(&mut self, o: &NodeReport) {
        self.peak_memory_bytes = self.peak_memory_bytes.max(o.peak_memory_bytes);
        self.rays_processed += o.rays_processed;
        for k in 0..4 {
            self.rays_created[k] += o.rays_created[k];
            self.rays_finished[k] += o.rays_finished[k];
        }
        self.messages_sent += o.messages_sent;
        self.bytes_sent += o.bytes_sent;
        self.hops += o.hops;
        self.paths_forwarded += o.paths_forwarded;
        self.leaves_sent += o.leaves_sent;
        self.credits_from_host += o.credits_from_host;
        self.max_stack_rays = self.max_stack_rays.max(o.max_stack_rays);
        self.intersection_tests += o.intersection_tests;
        self.mailbox_hits += o.mailbox_hits;
        self.cells_visited += o.cells_visited;
        self.subtree_evaluations += o.subtree_evaluations;
        self.busy_seconds += o.busy_seconds;
        self.virtual_seconds += o.virtual_seconds;
        self.waiting_seconds += o.waiting_seconds;
    }
}

/// What a node reports when it stops.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct NodeReport {
    /// The reporting node's number.
    pub node: u16,
    /// The cells and super cells it owns, and the primitives its share
    /// holds (those its cells reference).
    pub cells: u64,
    pub super_cells: u64,
    /// Super cells of other nodes it holds copies of (`replicas`).
    pub copies: u64,
    pub primitives: u64,
    /// Bytes of the share (cells, subtrees, primitives, mailboxes).
    pub memory_bytes: u64,
    /// Of those, the cell structure's (`CellStructure::bytes`: the
    /// skeleton every node holds, and the owned cells' subtrees).
    pub structure_bytes: u64,
    /// Its budget in bytes (`Share::budget`).
    pub memory_budget_bytes: u64,
    /// The most bytes it held at once: the share, paths queued and in
    /// flight, finished records, messages (never above the budget).
    pub peak_memory_bytes: u64,
    /// Rays traced here, whole or in part.
    pub rays_processed: u64,
    /// Rays created here, per kind (primary, shadow, reflected, refracted),
    /// and finished here.
    pub rays_created: [u64; 4],
    pub rays_finished: [u64; 4],
    /// Messages of the modelled machine this node sent (frames, to
    /// neighbours and the host), and their bytes.
    pub messages_sent: u64,
    pub bytes_sent: u64,
    /// Links crossed by the paths this node sent (its own and forwarded).
    pub hops: u64,
    /// Paths this node passed on for others (e-cube routing).
    pub paths_forwarded: u64,
    /// Shadow rays sent off alone as leaves (`Part::Leaf`).
    pub leaves_sent: u64,
    /// Credits the host returned for finished samples (the others the
    /// node took back itself, `Node::credit_locally`).
    pub credits_from_host: u64,
    /// The most rays any path's stack held here (`host::stack_bound`
    /// bounds it).
    pub max_stack_rays: u64,
    /// The tracer's counts here (`TraceCounters`): ray-primitive tests,
    /// tests a mailbox saved, cells entered, subtrees evaluated.
    pub intersection_tests: u64,
    pub mailbox_hits: u64,
    pub cells_visited: u64,
    pub subtree_evaluations: u64,
    /// Host CPU seconds of computing (thread time).
    pub busy_seconds: f64,
    /// The node's clock at its last work.
    pub virtual_seconds: f64,
    /// Virtual seconds the node had nothing to do: waiting for paths or
    /// for credit (the rest of its clock is computing and sending).
    pub waiting_seconds: f64,
}
