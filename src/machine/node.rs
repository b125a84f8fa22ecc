//! A node of the hypercube: a thread that shares nothing. It waits for its
//! load message, then, until the host says stop: takes the paths its
//! neighbours send, traces each one's active ray through the cells it
//! holds (shading, spawning, moving on to the next ray of the path), sends
//! a path on when its walk reaches a cell held elsewhere (e-cube routing,
//! hop by hop; a shadow ray that leaves while rays wait behind it goes on
//! alone, as a leaf), starts the primary paths of the pixels its super
//! cells own when the host has given it credit, and reports finished
//! samples.
//!
//! Memory: everything the node holds is counted (its share, the paths in
//! its queue and in its outgoing batches, encoded messages waiting for a
//! link) and the peak is reported. The host sized the windows of primary
//! paths so that all paths in flight fit any node (`host`).
//!
//! Time: the node's virtual clock advances by the thread CPU time of its
//! computing divided by the topology's compute speed (`work_for_a_while`),
//! by the send cost of each message, and jumps to a message's arrival time
//! when it was idle. Whatever arrives, to trace or to pass on, is taken in
//! order of virtual arrival. Messages are batched per link as the modelled
//! node would (`batch_wait`), and the emulation carries a slice's messages
//! for one link in one envelope (`codec`).

use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};

use super::codec::{
    Carried, PathContext, RaysOut, WireDone, append_frame, append_stamped, decode, encode_into,
    for_each_frame_body, pack_done_into, rays_in, restamp, unpack_rays,
};
use super::host::stack_bound;
use super::message::{
    Active, Finished, LinkModel, NodeReport, Part, Path, Routed, Share, ToHost, ToNode,
};
use super::routing::{NodeId, next_dimension};
use super::ticks::{Ticks, thread_cpu_seconds};
use super::transport::{Link, NodeLinks};
use crate::cells::{CellStructure, CellTracer, REMOTE, Region, Walk};
use crate::render::sample_offset_from;
use crate::scene::Scene;
use crate::trace::{CameraFrame, Film, RayJob, RayKind, Shader, Tracer};

/// Paths per batch message on a link.
const BATCH: usize = 64;
/// The room (bytes) a node's envelopes have (`flush`): a full batch of
/// paths, and some frames beside it. Grown from empty, one frame of a few
/// dozen bytes took three reallocations (5% of a d = 1 render's
/// instructions), a batch a dozen.
const ENVELOPE_ROOM: usize = 8 << 10;
/// Envelopes a node keeps, once it has taken them, to send its own in.
/// Emulation only (the modelled machine's buffers are the frames a node
/// holds, which its memory counts): a node sends about as many envelopes
/// to its neighbours as it receives from them, so reusing theirs spares
/// the host's allocator an allocation and a free on another thread's heap
/// per envelope. With `ENVELOPE_ROOM`, the reallocations of growing
/// envelopes went from 2.1% to 0.6% of the CPU of the sphereflake at
/// d = 5 (perf samples).
const SPARE_ENVELOPES: usize = 8;
/// Finished samples per message to the host.
const DONE_BATCH: usize = 256;
/// Shadow rays a path may send off alone (`Node::trace`) at least: a bound
/// on the pieces of one sample in flight, which the host's memory plan
/// counts. The plan allows one per light where memory leaves room
/// (`host::fork_limit`, `Share::forks`).
pub const MAX_FORKS: u16 = 4;
/// Message start-ups a batch may wait for more paths (`batch_wait`).
const BATCH_WAIT: f64 = 2.0;
/// Message start-ups a finished record the host answers with a credit may
/// wait for more records (`done_due`). A credit only matters once its
/// node's window runs low, and a window lasts far longer (41 samples at
/// d = 5 on the iPSC-D5, some 35 ms of work each), while every message
/// to the host costs its sender a start-up; a node that idles or waits
/// sends its records at once. Against two start-ups, as paths wait: at
/// d = 1 on the jagged ball, messages 449,000 to 226,000 and CPU 0.96x
/// (ten interleaved rounds); the sphereflake at d = 5, 3.28 M messages to
/// 2.52 M and 805 virtual seconds per busy second against 822 (three runs
/// each).
const DONE_WAIT: f64 = 64.0;
/// How far (in slices of work, `SLICE`) a node may run ahead of its
/// neighbours in virtual time. Threads get the host's cores in no relation
/// to their virtual clocks; a node far ahead would take its neighbours'
/// late-sent paths late, as if the links were slow, and stall on credit.
/// So the nodes keep in step: each tells its neighbours its clock (`Clock`
/// frames, emulation only), and one that gets more than this ahead of a
/// neighbour waits for it. (A bounded-lag scheme: the node with the
/// slowest clock never waits, so the machine never deadlocks.)
///
/// The lag is a delay the model adds: a path sent to a node that is ahead
/// is taken up to the lag late. How far threads drift apart depends on how
/// many share a core (`Pacing::for_host`): with many nodes per core (32 on 2),
/// one slice, measured on the sphereflake at 1024x1024 (two runs each): 4
/// slices gave 5,500 virtual seconds on the iPSC-D5, 1 slice 4,260, a
/// quarter slice 3,660; wall time 4.45 s, 4.46 s and 5.5 s at d = 5.
const LAG_SLICES: f64 = 1.0;
/// The lag when every node has a core of its own: the threads run side by
/// side and drift only when the scheduler preempts one (for the host
/// thread), and a short lag then makes them wait for each other at every
/// preemption. Sphereflake at 1024x1024, d = 1 on 2 cores, two runs each:
/// 8 slices gave 3.33-3.45 s wall and 36,000-36,300 virtual seconds, 1
/// slice 4.08-4.39 s and 37,600-38,800 (at d = 5, 8 slices gave 6,600-8,100
/// virtual seconds against 5,600-5,700 for one). Later, with the host's
/// link coalesced less (`HOST_COALESCE_OWN_CORE`), three interleaved
/// rounds: 8 slices 1.065-1.091 s, 32 slices 1.043-1.065 s, 64 slices
/// 1.034-1.046 s, the virtual seconds the same (13,450-13,700; 128 slices
/// raised them by 2-3%); with 8 slices each node waited 0.03-0.06 s for
/// the other. 64 against 32 again, at 1024x1024, processes of six and
/// renders of four interleaved rounds: the sphereflake 1.06-1.07 s
/// against 1.07-1.09 s, the jagged ball 0.392-0.396 s against 0.399-0.408
/// s, the house 1.236-1.245 s against 1.261-1.267 s, virtual seconds the
/// same.
const LAG_SLICES_OWN_CORE: f64 = 64.0;
/// The most slices of lag when nodes share cores (`Pacing::for_host`).
const LAG_SLICES_SHARED: f64 = 8.0;
/// Host time a node works between two looks at its links and its
/// neighbours' clocks (`LAG_SLICES`).
const SLICE: f64 = 25e-6;
/// Host time between two readings of a node's CPU time (`CpuWindow`),
/// unless the node waits first. Reading it is a system call of about
/// 0.7 µs on this host's virtual machine: read at the ends of every
/// 25 µs slice it took 6% of a node's time; over 100 µs of slices, 1.5%.
/// (Longer slices would save the same but let the clocks drift further
/// apart: with 100 µs slices the sphereflake's d = 5 render took 1.6
/// times the virtual seconds per busy second.)
const CPU_WINDOW: f64 = 100e-6;
/// How long (host time) the messages for the host may gather before they
/// are handed to the link, unless the node is about to idle. Emulation
/// only: every message keeps its own virtual stamp, so the model is the
/// same; but the host thread, which shares the host's cores with the
/// nodes, wakes a few thousand times a second instead of once per slice
/// of every node.
const HOST_COALESCE: f64 = 500e-6;
/// `HOST_COALESCE` when every node has a core of its own. A node's credits
/// come back through the host: at d = 1 on the sphereflake a window was
/// 135 paths, some 230 µs of a node's work, less than the 500 µs its
/// records waited, and a node whose paths finished on the other node ran
/// out of credit and idled 0.05-0.06 s of its 1 s. At 100 µs: 0.01-0.02 s,
/// the render 1.065-1.091 s against 1.104-1.187 s, and 13,450-13,700
/// virtual seconds against 13,730-14,840 (three interleaved rounds; 50 µs
/// and 200 µs were no better). With many nodes a core the host would wake
/// for each, and 100 µs made d = 5 no faster (2.99-3.04 s against
/// 2.98-3.03 s).
const HOST_COALESCE_OWN_CORE: f64 = 100e-6;

/// How the node threads keep pace on this host when `nodes` of them share
/// `cores` cores: how far a node's clock may run ahead of its neighbours'
/// (`LAG_SLICES`), and how long its messages for the host may gather
/// (`HOST_COALESCE`). Emulation only: they change when threads wait and
/// when the host hears of finished work, never the image.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pacing {
    /// Slices of work a node may run ahead of its neighbours: where nodes
    /// share cores, `LAG_SLICES_SHARED` over the nodes a core holds, at
    /// least `LAG_SLICES` (4 for two a core, as at d = 2 on two cores; one
    /// from eight a core, as at d = 4 and 5); `LAG_SLICES_OWN_CORE` where
    /// each has its own.
    pub lag_slices: f64,
    /// Host seconds the messages for the host may gather.
    pub host_coalesce: f64,
}

impl Pacing {
    pub fn for_host(nodes: usize, cores: usize) -> Pacing {
        let per_core = nodes as f64 / cores.max(1) as f64;
        if per_core <= 1.0 {
            return Pacing {
                lag_slices: LAG_SLICES_OWN_CORE,
                host_coalesce: HOST_COALESCE_OWN_CORE,
            };
        }
        Pacing {
            lag_slices: (LAG_SLICES_SHARED / per_core).clamp(LAG_SLICES, LAG_SLICES_SHARED),
            host_coalesce: HOST_COALESCE,
        }
    }
}

/// The bytes a node's share occupies once loaded: the structure, the
/// primitives, and the tracer's per-primitive and per-operator mailboxes.
pub fn share_bytes(cells: &CellStructure, scene: &Scene) -> u64 {
    use std::mem::size_of;
    let prims: usize = scene.primitives.iter().map(primitive_bytes).sum();
    let tracer = CellTracer::bytes_for(cells, scene);
    (cells.bytes()
        + prims
        + scene.materials.len() * size_of::<crate::scene::Material>()
        + scene.lights.len() * size_of::<crate::scene::Light>()
        + tracer) as u64
}

/// The bytes a node holds for one primitive of its scene.
pub fn primitive_bytes(p: &crate::csg::Primitive) -> usize {
    std::mem::size_of::<crate::csg::Primitive>() + p.heap_bytes()
}

/// Why a node stopped early.
pub type NodeError = String;

/// Runs node `id` on its links until the host says stop. Errors are
/// reported to the host by the caller.
pub fn run(id: u16, links: &mut dyn NodeLinks, faults: Faults) -> Result<(), NodeError> {
    // The load message first. Neighbours loaded earlier may already send
    // rays: those frames wait, as bytes, until the node knows its share
    // (and its memory), then are held and taken first.
    let mut early: Vec<(f64, Vec<u8>)> = Vec::new();
    let mut load = None;
    let mut stopped = false;
    while load.is_none() {
        match links
            .try_recv()
            .map_err(|c| format!("link {:?} closed before loading", c.0))?
        {
            Some(bytes) => for_each_frame_body(&bytes, |sent_at, body| {
                if stopped {
                    return Ok(());
                }
                if load.is_some() || rays_in(body).is_some() {
                    early.push((sent_at, body.to_vec()));
                    return Ok(());
                }
                match decode::<ToNode>(body)? {
                    ToNode::Load(share) => {
                        let t = sent_at + share.link.latency;
                        load = Some((share, t));
                    }
                    ToNode::Stop => stopped = true,
                    ToNode::Clock { .. } => early.push((sent_at, body.to_vec())),
                    _ => return Err("a message before the load message".into()),
                }
                Ok(())
            })?,
            None => links.wait(&[]),
        }
        if stopped {
            return Ok(());
        }
    }
    let (share, arrival) = load.ok_or("no load message")?;
    let share = *share;
    let mut node = Node::new(id, &share, links, arrival, faults)?;
    for (_, body) in &early {
        node.hold(body.len());
    }
    for (sent_at, body) in early {
        node.take_frame(sent_at, &body)?;
        node.release(body.len());
    }
    node.run()
}

/// The work since a node last read its CPU time (`work_for_a_while`):
/// that reading, the slices' estimates of their cost in virtual seconds,
/// the floor the clock keeps when they are replaced by the CPU time, and
/// the host seconds within it that were the emulation's.
struct CpuWindow {
    cpu0: f64,
    opened: Ticks,
    estimated: f64,
    floor: f64,
    excluded: f64,
    /// When the last slice in it ended.
    slice_end: Ticks,
}

impl CpuWindow {
    /// A window from CPU time `cpu0` and the clock `clock`, at `now`.
    fn open(cpu0: f64, clock: f64, now: Ticks) -> Self {
        CpuWindow {
            cpu0,
            opened: now,
            estimated: 0.0,
            floor: clock,
            excluded: 0.0,
            slice_end: now,
        }
    }
}

/// Puts the shadow rays among `spawned` after the others (on top of the
/// stack), each kind in the order it came: a stable sort by kind. The
/// shader spawns its shadow rays first, so that is a rotation; the sort
/// (0.5% of a `--dim 1` render's CPU for a handful of rays) stays for any
/// other order.
fn shadows_on_top(spawned: &mut [RayJob]) {
    let shadows = spawned
        .iter()
        .take_while(|j| j.kind == RayKind::Shadow)
        .count();
    if spawned[shadows..].iter().all(|j| j.kind != RayKind::Shadow) {
        spawned.rotate_left(shadows);
    } else {
        spawned.sort_by_key(|j| j.kind == RayKind::Shadow);
    }
}

/// The paths waiting in a node, taken earliest arrival first (ties by
/// sample, so the order is deterministic).
///
/// Each path is boxed (`Carried::Path`; a path passing through keeps its
/// bytes on the heap, `Passing`): the heap moves its entries at every
/// push and pop, and a path is some 200 bytes. The sphereflake at
/// 384x384 on 32 nodes, under callgrind: the heap's pushes, pops and
/// copies took 705 million instructions with the paths inline, 453
/// million boxed, against 2.5 billion in the walk. (Reused slots instead of boxes saved another 3%
/// of a render's instructions, but a freed slot is memory the node keeps
/// beyond its paths, which the memory plan does not size for.)
#[derive(Default)]
struct Queue {
    heap: BinaryHeap<Queued>,
}

impl Queue {
    fn push(&mut self, arrival: f64, c: Carried) {
        self.heap.push(Queued {
            arrival,
            sample: c.sample(),
            carried: c,
        });
    }

    /// The earliest arrival waiting.
    fn earliest(&self) -> Option<f64> {
        self.heap.peek().map(|q| q.arrival)
    }

    /// The earliest path and its arrival.
    fn pop(&mut self) -> Option<(f64, Carried)> {
        self.heap.pop().map(|q| (q.arrival, q.carried))
    }
}

/// A waiting path and its place in the heap.
struct Queued {
    arrival: f64,
    sample: u64,
    carried: Carried,
}

impl Ord for Queued {
    fn cmp(&self, o: &Self) -> Ordering {
        o.arrival
            .total_cmp(&self.arrival)
            .then(o.sample.cmp(&self.sample))
    }
}

impl PartialOrd for Queued {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

impl PartialEq for Queued {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}

impl Eq for Queued {}

/// Test-only faults a node is started with (`MachineOptions::fail` and
/// `stall`): a harness's, not the modelled machine's, so no message
/// carries them.
#[derive(Clone, Copy, Debug, Default)]
pub struct Faults {
    /// Fail after this many paths processed.
    pub fail_after: Option<u64>,
    /// Host seconds of CPU to burn after each send.
    pub stall_on_send: Option<f64>,
}

struct Node<'a> {
    id: u16,
    share: &'a Share,
    faults: Faults,
    links: &'a mut dyn NodeLinks,
    tracer: CellTracer<'a>,
    shader: Shader<'a>,
    cam: CameraFrame,
    primaries: Primaries,
    /// Credits usable now, and credits on their way with their arrival.
    credits: u32,
    arriving_credits: VecDeque<(f64, u32)>,
    /// Paths to trace, earliest virtual arrival first.
    queue: Queue,
    /// Per link (dimensions, then the host): paths to batch, encoded
    /// messages waiting for room.
    batches: Vec<Vec<Carried>>,
    /// Per link, when its open batch got its first path (virtual time).
    opened: Vec<f64>,
    /// When the open batch of finished samples got its first record that
    /// the host must answer with a credit (None: it has none).
    done_urgent: Option<f64>,
    /// Per dimension, the bound the neighbour last announced on its clock;
    /// and the bound this node last announced (`announce`).
    heard: Vec<f64>,
    announced: f64,
    /// Host seconds spent, in the current slice, on the emulation's own
    /// work (encoding messages), which the clock does not charge.
    excluded: f64,
    /// While a unit of work runs (`work_for_a_while`): the host time and
    /// `excluded` up to which its computing is on the clock already, and
    /// the virtual seconds charged in it so far (`catch_up`).
    unit: Option<(Ticks, f64)>,
    unit_charged: f64,
    /// The outermost `excluding` block running, if any: when it began, and
    /// `excluded` then.
    exclusion: Option<(Ticks, f64)>,
    /// The slices since the node's CPU time was last read, if any.
    cpu_window: Option<CpuWindow>,
    /// Per link, the envelope of messages waiting to go (`codec`).
    waiting: Vec<Vec<u8>>,
    /// Per link, where in `waiting` the clock frame not yet sent starts: a
    /// newer bound takes its stamp (`tell`) instead of adding a frame.
    clock_frame: Vec<Option<usize>>,
    /// Envelopes received and taken, emptied, for the next ones to send
    /// (`SPARE_ENVELOPES`).
    spare: Vec<Vec<u8>>,
    /// Per link, whether its envelope holds more than `Clock` frames.
    carries: Vec<bool>,
    done: Vec<Finished>,
    /// The bytes of the last batch of finished records sent, kept to pack
    /// the next one in (`send_done`).
    done_wire: WireDone,
    /// Finished records no credit covers (`Share::local_credits`: samples
    /// credited here, `credit_locally`, and background samples) still in
    /// `done`, and those in the host link's waiting envelope.
    uncovered_in_done: u32,
    uncovered_waiting: u32,
    generated_reported: bool,
    stopping: bool,
    /// Bytes of rays held (queue, batches, encoded messages).
    ray_bytes: u64,
    report: NodeReport,
    clock: f64,
    model: LinkModel,
    paths_processed: u64,
    /// When the host link was last handed its waiting messages.
    host_flushed: Ticks,
    /// The most rays a path's stack holds (`host::stack_bound`), which its
    /// capacity never passes (`trace`).
    stack_rays: usize,
}

impl<'a> Node<'a> {
    fn new(
        id: u16,
        share: &'a Share,
        links: &'a mut dyn NodeLinks,
        clock: f64,
        faults: Faults,
    ) -> Result<Self, NodeError> {
        let d = share.dimension as usize;
        let memory = share_bytes(&share.cells, &share.scene);
        let cells: u64 = Region::BOTH
            .iter()
            .map(|&r| {
                let rc = share.cells.region(r);
                (0..rc.supers.len() as u32)
                    .filter(|&s| share.owner[r as usize][s as usize] == id)
                    .map(|s| rc.cells_of(s).len() as u64)
                    .sum::<u64>()
            })
            .sum();
        let super_cells = share.owner.iter().flatten().filter(|&&o| o == id).count() as u64;
        // Copies: super cells of others whose content the share holds.
        let copies: u64 = Region::BOTH
            .iter()
            .map(|&r| {
                let rc = share.cells.region(r);
                (0..rc.supers.len() as u32)
                    .filter(|&s| share.owner[r as usize][s as usize] != id)
                    .filter(|&s| rc.cells_of(s).any(|k| rc.subtree[k] < REMOTE))
                    .count() as u64
            })
            .sum();
        let report = NodeReport {
            node: id,
            cells,
            super_cells,
            copies,
            primitives: share.scene.primitives.len() as u64,
            memory_bytes: memory,
            structure_bytes: share.cells.bytes() as u64,
            memory_budget_bytes: share.budget,
            peak_memory_bytes: memory,
            ..Default::default()
        };
        Ok(Node {
            id,
            faults,
            share,
            links,
            tracer: CellTracer::new(&share.cells, &share.scene),
            shader: Shader::with_samples(&share.scene, share.spp),
            cam: CameraFrame::new(&share.scene, share.width, share.height),
            primaries: Primaries::new(share, id),
            credits: share.window,
            arriving_credits: VecDeque::new(),
            queue: Queue::default(),
            batches: vec![Vec::new(); d + 1],
            opened: vec![0.0; d + 1],
            done_urgent: None,
            host_flushed: Ticks::now(),
            excluded: 0.0,
            unit: None,
            unit_charged: 0.0,
            exclusion: None,
            cpu_window: None,
            heard: vec![0.0; d],
            announced: 0.0,
            waiting: (0..=d).map(|_| Vec::with_capacity(ENVELOPE_ROOM)).collect(),
            clock_frame: vec![None; d + 1],
            spare: Vec::new(),
            carries: vec![false; d + 1],
            done: Vec::new(),
            done_wire: WireDone::default(),
            uncovered_in_done: 0,
            uncovered_waiting: 0,
            generated_reported: false,
            stopping: false,
            ray_bytes: 0,
            report,
            clock,
            model: share.link,
            paths_processed: 0,
            // The share keeps every light and material, and the depth.
            stack_rays: stack_bound(&share.scene),
        })
    }

    fn link_index(&self, l: Link) -> usize {
        match l {
            Link::Dim(k) => k as usize,
            Link::Host => self.share.dimension as usize,
        }
    }

    fn link_of(&self, i: usize) -> Link {
        if i == self.share.dimension as usize {
            Link::Host
        } else {
            Link::Dim(i as u32)
        }
    }

    fn hold(&mut self, bytes: usize) {
        self.ray_bytes += bytes as u64;
        let now = self.report.memory_bytes + self.ray_bytes;
        self.report.peak_memory_bytes = self.report.peak_memory_bytes.max(now);
    }

    fn release(&mut self, bytes: usize) {
        self.ray_bytes -= bytes as u64;
    }

    fn run(&mut self) -> Result<(), NodeError> {
        self.send_host(&ToHost::Loaded { node: self.id })?;
        loop {
            self.receive_all()?;
            if self.stopping {
                break;
            }
            if self.ahead() {
                // Its clock as measured, not estimated: the wait is not
                // work, and the neighbours are told where it stands.
                self.close_cpu_window();
                if !self.ahead() {
                    continue;
                }
                // Wait, in real time, for the neighbours to catch up; they
                // must know where this node stands (they may be waiting
                // for it too, on older news).
                if self.announced != self.clock {
                    self.tell(self.clock)?;
                }
                self.flush(true)?;
                let sending: Vec<Link> = (0..self.waiting.len())
                    .filter(|&i| !self.waiting[i].is_empty())
                    .map(|i| self.link_of(i))
                    .collect();
                self.links.wait(&sending);
                continue;
            }
            let worked = self.work_for_a_while()?;
            if !worked {
                // About to idle: what it sends now carries its measured
                // clock, not an estimate, and the wait is not counted.
                self.close_cpu_window();
            }
            self.announce(worked)?;
            self.flush(!worked)?;
            // Sending may have made room for background samples, which
            // nothing would wake the node for.
            if !worked && !self.stopping && !self.background_ready() {
                let sending: Vec<Link> = (0..self.waiting.len())
                    .filter(|&i| !self.waiting[i].is_empty())
                    .map(|i| self.link_of(i))
                    .collect();
                self.links.wait(&sending);
            }
        }
        self.close_cpu_window();
        self.report.virtual_seconds = self.clock;
        let c = self.tracer.counters;
        self.report.intersection_tests = c.intersection_tests;
        self.report.mailbox_hits = c.mailbox_hits;
        self.report.cells_visited = c.cells_visited;
        self.report.subtree_evaluations = c.subtree_evaluations;
        let report = Box::new(std::mem::take(&mut self.report));
        self.send_host(&ToHost::Report(report))?;
        // The report must leave before the thread ends.
        while !self.waiting[self.link_index(Link::Host)].is_empty() {
            self.flush(true)?;
            if !self.waiting[self.link_index(Link::Host)].is_empty() {
                self.links.wait(&[Link::Host]);
            }
        }
        Ok(())
    }

    /// The most virtual time a node may run ahead of a neighbour: a few
    /// slices of its work (`Pacing::lag_slices`).
    fn lag(&self) -> f64 {
        self.share.pacing.lag_slices * SLICE / self.model.compute_speed
    }

    /// Whether the node is so far ahead of a neighbour, in virtual time,
    /// that it must let it catch up (`LAG_SLICES`).
    fn ahead(&self) -> bool {
        let slowest = self.heard.iter().copied().fold(f64::INFINITY, f64::min);
        self.clock > slowest + self.lag()
    }

    /// Tells the neighbours how far its clock got, when it moved by half
    /// the allowed lag since it last did; or that it has nothing to do
    /// (infinity), so that nobody waits for it.
    fn announce(&mut self, worked: bool) -> Result<(), NodeError> {
        let bound = if worked {
            if self.announced.is_finite() && self.clock < self.announced + self.lag() / 2.0 {
                return Ok(());
            }
            self.clock
        } else if self.announced == f64::INFINITY {
            return Ok(());
        } else {
            f64::INFINITY
        };
        self.tell(bound)
    }

    /// Sends the neighbours a bound on this node's clock.
    ///
    /// Why the machine cannot deadlock: a node waits only after telling
    /// its clock, and a working node tells it whenever it moves by half
    /// the lag; so what the node with the slowest clock has heard of each
    /// neighbour is at most half the lag behind that neighbour's clock, so
    /// at most half the lag behind its own, and it never waits.
    ///
    /// A link whose envelope still holds a clock frame gets the new bound
    /// in that frame: the neighbour, which takes an envelope's frames
    /// together, learns the same as from two frames, and a link that stays
    /// full (its neighbour's thread waiting for a core) holds one clock
    /// frame, not one per half lag, which the memory plan does not size.
    fn tell(&mut self, bound: f64) -> Result<(), NodeError> {
        self.announced = bound;
        let from = self.id;
        for k in 0..self.share.dimension as usize {
            if let Some(at) = self.clock_frame[k]
                && restamp(&mut self.waiting[k], at, bound)
            {
                continue;
            }
            self.clock_frame[k] = Some(self.waiting[k].len());
            let len = append_stamped(&mut self.waiting[k], &ToNode::Clock { from }, |_| bound)?;
            self.hold(len.held);
        }
        Ok(())
    }

    /// Works (`work_a_little`, unit after unit) for about `SLICE` of host
    /// time, and advances the clock by what that work cost. False when
    /// there was nothing to do.
    ///
    /// The clock measures computing only: the tracing, shading and
    /// bookkeeping a node of the modelled machine would do. Encoding,
    /// decoding and moving messages are the link model's (`send_cost`,
    /// latency): the time spent encoding within a slice is taken off it
    /// (`excluded`), and so is the time between slices, where messages are
    /// decoded (`handle`) and sent (`flush`), or the emulation's own costs,
    /// scaled by the node speed, would be charged twice.
    ///
    /// Thread CPU time is the measure (what the node computed, not what the
    /// host's scheduler gave other threads), but reading it is a system
    /// call, dearer than a short unit of work: it is read once per
    /// `CpuWindow`. Within it each unit advances the clock by its
    /// monotonic-clock time, so that messages sent mid-window carry a
    /// sensible stamp; when the window closes, its CPU time replaces the
    /// sum of those estimates. (A unit in which the thread was descheduled
    /// stamps its messages late by up to the time it waited: the model
    /// errs on the slow side.)
    fn work_for_a_while(&mut self) -> Result<bool, NodeError> {
        let speed = self.model.compute_speed;
        let now = Ticks::now();
        let (mut window, start) = match self.cpu_window.take() {
            Some(w) if now.seconds_since(w.slice_end) < CPU_WINDOW => (w, now),
            // Long enough since the last slice that the thread may have
            // been descheduled: settled now, with that time charged (as
            // the CPU time it was, some microseconds of emulation), so
            // that no wait is taken off the node's CPU time.
            Some(w) => {
                let (cpu, at) = self.settle(w);
                (CpuWindow::open(cpu, self.clock, at), Ticks::now())
            }
            // Host time from before the reading: a window's CPU time must
            // lie within its host time (`settle`).
            None => (
                CpuWindow::open(thread_cpu_seconds(), self.clock, now),
                Ticks::now(),
            ),
        };
        // Since the last slice: decoding and sending, the emulation's.
        window.excluded += start.seconds_since(window.slice_end);
        let mut t0 = start;
        let mut estimated = 0.0;
        let mut worked = false;
        self.excluded = 0.0;
        loop {
            let before = self.clock;
            self.unit = Some((t0, self.excluded));
            self.unit_charged = 0.0;
            let worked_now = self.work_a_little();
            let (t_mark, excluded) = self.unit.take().ok_or("a unit's start vanished")?;
            estimated += self.unit_charged;
            if !worked_now? {
                // Finding nothing to do is not work: the modelled node
                // idles. (Counted, its CPU time came out as busy with no
                // clock time for it, and a node's busy time could pass the
                // run's end.)
                t0 = Ticks::now();
                self.excluded = excluded + t0.seconds_since(t_mark);
                break;
            }
            worked = true;
            // The unit may have jumped the clock to an arrival, or paid a
            // send (stamped at the clock, its computing so far included):
            // a floor the correction below must not undercut.
            if self.clock - self.unit_charged > before {
                window.floor = window.floor.max(self.clock);
            }
            let t1 = Ticks::now();
            let unit = (t1.seconds_since(t_mark) - (self.excluded - excluded)).max(0.0);
            t0 = t1;
            let dt = unit / speed;
            self.clock += dt;
            estimated += dt;
            if t1.seconds_since(start) >= SLICE {
                break;
            }
        }
        // The slice ends where its last unit did: what follows (sending,
        // receiving) is the emulation's, left to the next slice's gap or
        // the window's tail.
        let end = t0;
        window.estimated += estimated;
        window.excluded += self.excluded;
        window.slice_end = end;
        self.cpu_window = Some(if end.seconds_since(window.opened) >= CPU_WINDOW {
            // One reading closes this window and opens the next.
            let (cpu, at) = self.settle(window);
            CpuWindow::open(cpu, self.clock, at)
        } else {
            window
        });
        Ok(worked)
    }

    /// Runs `f`, the emulation's own work (packing, encoding, passing a
    /// path on), and takes its host time off the slice's computing
    /// (`excluded`) once: what `f` itself excluded, when it nests another
    /// such call (forwarding seals and enqueues), is part of that time,
    /// not added again.
    fn excluding<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        let (t0, before) = (Ticks::now(), self.excluded);
        let outer = self.exclusion;
        if outer.is_none() {
            self.exclusion = Some((t0, before));
        }
        let r = f(self);
        self.exclusion = outer;
        self.excluded = before + t0.elapsed();
        r
    }

    /// Settles the window before the node waits, so that the wait is not
    /// counted as work (`work_for_a_while`).
    fn close_cpu_window(&mut self) {
        if let Some(w) = self.cpu_window.take() {
            self.settle(w);
        }
    }

    /// Reads the CPU time and puts what the window's work cost in place of
    /// its estimates; the time since its last slice (until after the
    /// reading) was the emulation's, unless it was long enough to hide a
    /// wait. Returns the reading and the host time just before it, where
    /// the next window may start.
    ///
    /// The window's CPU time is read within its host time (opened before
    /// its first reading, closed after its last), so that it never
    /// exceeds the host time its slices were estimated by: a reading
    /// outside it (the system call takes microseconds on a loaded host)
    /// once charged a node computing after its last message.
    fn settle(&mut self, w: CpuWindow) -> (f64, Ticks) {
        let before = Ticks::now();
        let cpu_now = thread_cpu_seconds();
        let tail = Ticks::now().seconds_since(w.slice_end);
        let tail = if tail < CPU_WINDOW { tail } else { 0.0 };
        // A thread computes no longer than it runs: what the reading
        // gives beyond its units' host time (the estimates, before their
        // sends too, `catch_up`) was the emulation's, in a gap long enough
        // to be taken for a wait (`tail`). Charged, it once had a node
        // busy past the run's end (on a loaded host, about one small
        // render in 25,000), and it pushed the node's clock on.
        let speed = self.model.compute_speed;
        let cpu = (cpu_now - w.cpu0 - w.excluded - tail).clamp(0.0, w.estimated * speed);
        self.report.busy_seconds += cpu;
        self.clock = (self.clock - w.estimated + cpu / speed).max(w.floor);
        (cpu_now, before)
    }

    /// Takes every message offered now.
    fn receive_all(&mut self) -> Result<(), NodeError> {
        while let Some(bytes) = self
            .links
            .try_recv()
            .map_err(|c| format!("link {:?} closed", c.0))?
        {
            self.handle(bytes)?;
        }
        Ok(())
    }

    /// Takes one envelope.
    fn handle(&mut self, bytes: Vec<u8>) -> Result<(), NodeError> {
        self.hold(bytes.len());
        // Each frame is taken as it is decoded; the bytes are let go after
        // the last (held until then, with what they decoded to).
        for_each_frame_body(&bytes, |sent_at, body| self.take_frame(sent_at, body))?;
        self.release(bytes.len());
        self.keep_spare(bytes);
        Ok(())
    }

    /// Keeps an envelope that has been taken, to send the next one in.
    fn keep_spare(&mut self, mut bytes: Vec<u8>) {
        // Not the host's small ones.
        if self.spare.len() < SPARE_ENVELOPES && bytes.capacity() >= ENVELOPE_ROOM {
            bytes.clear();
            self.spare.push(bytes);
        }
    }

    /// Takes one message from its frame's body (its bytes held). It is
    /// here once sent and across the wire; what it brings waits, with that
    /// arrival time, until the node's clock gets there (`work_a_little`).
    fn take_frame(&mut self, sent_at: f64, body: &[u8]) -> Result<(), NodeError> {
        let Some(batch) = rays_in(body) else {
            return self.take(sent_at, decode(body)?);
        };
        // Paths, the bulk of what arrives, are read straight from the
        // bytes (`codec::unpack_rays`), each held as it is made.
        let arrival = sent_at + self.model.latency;
        let ctx = self.path_context();
        let me = self.id;
        unpack_rays(batch, &ctx, me, |c| {
            self.hold(c.held());
            self.arrive(c, arrival)
        })
    }

    /// Takes one message but paths (`take_frame`).
    fn take(&mut self, sent_at: f64, body: ToNode) -> Result<(), NodeError> {
        let arrival = sent_at + self.model.latency;
        match body {
            // `take_frame` reads paths from their bytes.
            ToNode::Rays(_) => return Err("a batch of paths decoded whole".into()),
            ToNode::Credit(n) => self.arriving_credits.push_back((arrival, n)),
            ToNode::Stop => self.stopping = true,
            ToNode::Clock { from } => {
                let k = (from ^ self.id).trailing_zeros() as usize;
                if k < self.heard.len() {
                    self.heard[k] = sent_at;
                }
            }
            ToNode::Load(_) => return Err("a second load message".into()),
        }
        Ok(())
    }

    /// A path arriving over a link (its bytes held): ours to trace, or to
    /// pass on.
    fn arrive(&mut self, c: Carried, arrival: f64) -> Result<(), NodeError> {
        // Paths to pass on wait their turn too: the iPSC's routing is done
        // by the node's processor, in the order messages arrive in virtual
        // time (taking one early would push the clock past work that
        // arrived before it).
        self.queue.push(arrival, c);
        Ok(())
    }

    /// Puts a path (its bytes held) in the batch of the next link toward
    /// its destination.
    fn route(&mut self, mut c: Carried) -> Result<(), NodeError> {
        let k = next_dimension(NodeId(self.id), NodeId(c.dest()))
            .ok_or("routing a path to its own node")?;
        c.add_hop()?;
        self.report.hops += 1;
        let i = k as usize;
        if self.batches[i].is_empty() {
            self.opened[i] = self.clock;
        }
        self.batches[i].push(c);
        self.seal_if_due(i)
    }

    /// One unit of work: a queued path, or a new primary path. False when
    /// there was nothing to do.
    fn work_a_little(&mut self) -> Result<bool, NodeError> {
        // The modelled order: what has arrived by the node's clock, the
        // earliest first; new primary paths whenever nothing that arrived
        // earlier waits; the clock jumps ahead only when nothing is left
        // before. (A node cannot undo work its thread already did, so a
        // message that the host delivered late in real time but early in
        // virtual time is taken late: the model errs on the slow side.)
        while let Some(&(t, n)) = self.arriving_credits.front() {
            if t > self.clock {
                break;
            }
            self.credits += n;
            self.report.credits_from_host += u64::from(n);
            self.arriving_credits.pop_front();
        }
        let earliest = self.queue.earliest();
        let queued_before_now = earliest.is_some_and(|t| t <= self.clock);
        if !queued_before_now {
            match self.primaries.peek(&self.share.cells, &self.cam) {
                Some(true) if self.record_room() => {
                    return self.start_primary().map(|()| true);
                }
                Some(false) if self.credits > 0 => {
                    return self.start_primary().map(|()| true);
                }
                // A background sample waits for the host's link to take
                // the records before it (`record_room`; the node sends them
                // when it idles).
                Some(true) => {}
                Some(false) => {
                    // Only credit lets the node start a primary path: wait
                    // for it, unless a path arrives first.
                    if let Some(&(t, n)) = self
                        .arriving_credits
                        .front()
                        .filter(|&&(t, _)| earliest.is_none_or(|a| t < a))
                    {
                        self.report.waiting_seconds += (t - self.clock).max(0.0);
                        self.clock = self.clock.max(t);
                        self.credits += n;
                        self.report.credits_from_host += u64::from(n);
                        self.arriving_credits.pop_front();
                        return self.start_primary().map(|()| true);
                    }
                }
                None if !self.generated_reported => {
                    self.generated_reported = true;
                    let samples = self.primaries.generated;
                    self.send_host(&ToHost::Generated {
                        node: self.id,
                        samples,
                    })?;
                    return Ok(true);
                }
                _ => {}
            }
        }
        if let Some((arrival, carried)) = self.queue.pop() {
            self.report.waiting_seconds += (arrival - self.clock).max(0.0);
            self.clock = self.clock.max(arrival);
            match carried {
                Carried::Path(r) if r.dest == self.id => self.trace(r.path)?,
                passing => {
                    // Passing a path on costs the modelled node a message
                    // start-up (`send_cost`), not the host's time to do it.
                    self.report.paths_forwarded += 1;
                    self.excluding(|n| n.route(passing))?;
                }
            }
            return Ok(true);
        }
        Ok(false)
    }

    /// Starts the next primary sample: a background sample of an empty
    /// pixel area finishes at once; any other needs (and takes) a credit.
    fn start_primary(&mut self) -> Result<(), NodeError> {
        let (job, sample, background) = self
            .primaries
            .next(&self.share.cells, &self.cam)
            .ok_or("a peeked sample vanished")?;
        self.report.rays_created[RayKind::Primary.index()] += 1;
        if background {
            self.report.rays_finished[RayKind::Primary.index()] += 1;
            self.uncovered_in_done += 1;
            return self.finish_sample(Finished {
                sample,
                origin: self.id,
                sum: Film::quantize(self.shader.miss(&job)),
                traced: false,
                credited: false,
                part: Part::Root { forks: 0 },
            });
        }
        self.credits -= 1;
        let path = Path {
            sample,
            origin: self.id,
            sum: [0; 3],
            active: Active {
                job,
                number: 0,
                t_min: 0.0,
                at: None,
            },
            stack: Vec::new(),
            forks: 0,
            leaf: false,
        };
        self.hold(path.bytes());
        self.trace(path)
    }

    /// Follows a path (its bytes held) as far as this node's cells go:
    /// until it leaves for another node or is finished. The same rules, in
    /// the same order, as `Shader::run_path`.
    fn trace(&mut self, mut path: Path) -> Result<(), NodeError> {
        let mut held = path.bytes();
        self.paths_processed += 1;
        if self
            .faults
            .fail_after
            .is_some_and(|n| self.paths_processed > n)
        {
            panic!(
                "injected fault after {n} paths",
                n = self.paths_processed - 1
            );
        }
        loop {
            let a = &mut path.active;
            self.report.rays_processed += 1;
            let shadow = a.job.kind == RayKind::Shadow;
            let from = a.at.take();
            self.tracer.leaving(a.job.leaving);
            self.tracer.toward(a.job.light);
            let walk = if shadow {
                self.tracer
                    .walk_shadow(&a.job.ray, a.t_min, a.job.t_max, from)
            } else {
                self.tracer.walk(&a.job.ray, a.t_min, a.job.t_max, from)
            };
            let finished_with = match walk {
                Walk::Remote(p) => {
                    a.at = Some(p);
                    let dest = self.share.owner[p.region as usize][p.super_cell as usize];
                    if !(shadow && !path.stack.is_empty() && path.forks < self.share.forks) {
                        // Its bytes move, held, into the batch.
                        return self.route(Carried::Path(Box::new(Routed {
                            dest,
                            hops: 0,
                            path,
                        })));
                    }
                    // A shadow ray leaving while rays wait behind it: it
                    // goes on alone, as a leaf that can spawn nothing, and
                    // the path stays with the rays that start here, which
                    // saves the path's trip there and back.
                    path.forks += 1;
                    self.report.leaves_sent += 1;
                    let leaf = Path {
                        sample: path.sample,
                        origin: path.origin,
                        sum: [0; 3],
                        active: a.clone(),
                        stack: Vec::new(),
                        forks: 0,
                        leaf: true,
                    };
                    self.hold(leaf.bytes());
                    self.route(Carried::Path(Box::new(Routed {
                        dest,
                        hops: 0,
                        path: leaf,
                    })))?;
                    let job = path
                        .stack
                        .pop()
                        .expect("checked non-empty above, and routing the leaf does not touch it");
                    path.active = Active {
                        job,
                        number: path.active.number + 1,
                        t_min: 0.0,
                        at: None,
                    };
                    continue;
                }
                Walk::Hit(h) if shadow => {
                    if self.shader.shadow_crossing(&mut a.job, &h) {
                        a.t_min = h.t;
                        continue;
                    }
                    None
                }
                Walk::Miss => Some(self.shader.miss(&a.job)),
                Walk::Hit(h) => {
                    let (stack, created) = (&mut path.stack, &mut self.report.rays_created);
                    let base = stack.len();
                    let most = self.stack_rays;
                    let c = self.shader.shade(&a.job, &h, &mut |j: RayJob| {
                        created[j.kind.index()] += 1;
                        // Grown as `Vec` grows it (doubling, from 4), but
                        // never past the stack's bound, which no push
                        // passes: the host's plan counts a path at that
                        // capacity (`host::path_bound`), not twice it.
                        if stack.len() == stack.capacity() {
                            let want = (2 * stack.capacity()).max(4).min(most).max(stack.len() + 1);
                            stack.reserve_exact(want - stack.len());
                        }
                        stack.push(j);
                    });
                    // Shadow rays first (on top): then, when a reflected
                    // or refracted ray leaves the node, the rays still
                    // waiting rarely start here, and a shadow ray that
                    // leaves can go alone (above); and the host's bound
                    // on a stack (`host::stack_bound`) counts on this
                    // order. The image does not depend on the order:
                    // contributions sum in fixed point.
                    shadows_on_top(&mut stack[base..]);
                    // The primitive each leaves, by its index in the whole
                    // scene, which every node knows.
                    let cells = &self.share.cells;
                    for j in &mut stack[base..] {
                        j.leaving = j.leaving.map(|p| cells.global_primitive(p));
                    }
                    let waiting = stack.len() as u64;
                    self.report.max_stack_rays = self.report.max_stack_rays.max(waiting);
                    // The stack may have grown: hold the difference.
                    let now = path.bytes();
                    if now > held {
                        self.hold(now - held);
                        held = now;
                    }
                    Some(c)
                }
            };
            let a = &path.active;
            if let Some(c) = finished_with {
                let q = Film::quantize(c);
                for (s, q) in path.sum.iter_mut().zip(q) {
                    *s = s.wrapping_add(q);
                }
            }
            self.report.rays_finished[a.job.kind.index()] += 1;
            match path.stack.pop() {
                Some(job) => {
                    path.active = Active {
                        job,
                        number: path.active.number + 1,
                        t_min: 0.0,
                        at: None,
                    };
                }
                None => {
                    self.release(held);
                    let whole = !path.leaf && path.forks == 0;
                    let credited = whole && path.origin == self.id && self.credit_locally()?;
                    return self.finish_sample(Finished {
                        sample: path.sample,
                        origin: path.origin,
                        sum: path.sum,
                        traced: true,
                        credited,
                        part: if path.leaf {
                            Part::Leaf
                        } else {
                            Part::Root { forks: path.forks }
                        },
                    });
                }
            }
        }
    }

    /// Takes back the credit of a sample of this node's own that finished
    /// whole here, instead of waiting for the host to return it (a round
    /// trip through the host link and the host's thread, for a sample the
    /// node already knows is done). Memory stays bounded: at most
    /// `local_credits` such records wait for the host's link (the room the
    /// host's plan keeps for a window of finished samples), beyond that
    /// the credit comes from the host as for any other.
    fn credit_locally(&mut self) -> Result<bool, NodeError> {
        if !self.record_room() {
            // The records that hold the room go to the host's link now,
            // not when the node idles or its coalescing ends: the room is
            // free once the link takes them. Else a node whose window is
            // a path or two (a share that nearly fills its memory) waited
            // for the host's credit every `local_credits` samples: a
            // round trip through the host's thread, far longer on this
            // host than the samples (the level-4 sphereflake seen from
            // afar, 512x512 on one node of 4.5 MiB, a window of 1: 0.78 s
            // of wall time against 0.31 s on 6 MiB).
            self.send_done()?;
            let host = self.link_index(Link::Host);
            if !self.waiting[host].is_empty() {
                self.host_flushed = Ticks::now();
                self.send_waiting(host)?;
            }
            if !self.record_room() {
                return Ok(false);
            }
        }
        self.uncovered_in_done += 1;
        self.credits += 1;
        Ok(true)
    }

    /// Whether one more finished record that no credit covers may wait
    /// here for the host's link (`Share::local_credits`). A background
    /// sample starts only then: it takes no credit, so without this bound
    /// a node with large empty pixel areas and a busy host link would pile
    /// up their records beyond its memory.
    fn record_room(&self) -> bool {
        self.uncovered_in_done + self.uncovered_waiting < self.share.local_credits
    }

    /// Whether the next sample is a background one that may start now.
    fn background_ready(&mut self) -> bool {
        self.record_room() && self.primaries.peek(&self.share.cells, &self.cam) == Some(true)
    }

    /// Queues a finished record for the host. A record the host answers
    /// with a credit (a traced sample not credited here) goes within
    /// `DONE_WAIT` message start-ups; the others (credited here, or
    /// background) wait for a full batch or for the node to idle: nothing
    /// waits on them, and on the modelled machine each message costs a
    /// start-up (a millisecond on the iPSC, against about 35 ms of work
    /// per sample of the sphereflake). At most `local_credits` records
    /// credited here wait (`credit_locally`), DONE_BATCH of them here.
    fn finish_sample(&mut self, f: Finished) -> Result<(), NodeError> {
        if f.traced && !f.credited && self.done_urgent.is_none() {
            self.done_urgent = Some(self.clock);
        }
        self.hold(size_of::<Finished>());
        self.done.push(f);
        if self.done.len() >= DONE_BATCH || self.done_due() {
            self.send_done()?;
        }
        Ok(())
    }

    /// Whether the finished records hold one the host must answer, and
    /// it has waited `DONE_WAIT` start-ups.
    fn done_due(&self) -> bool {
        self.done_urgent
            .is_some_and(|t| self.clock - t >= DONE_WAIT * self.model.overhead)
    }

    fn send_done(&mut self) -> Result<(), NodeError> {
        if self.done.is_empty() {
            return Ok(());
        }
        self.done_urgent = None;
        self.uncovered_waiting += std::mem::take(&mut self.uncovered_in_done);
        // Listed, then encoded (held by `enqueue`).
        self.release(self.done.len() * size_of::<Finished>());
        // Packing is encoding (as in `seal`).
        let finished = self.excluding(|n| {
            let mut finished = std::mem::take(&mut n.done_wire);
            pack_done_into(n.id, &n.done, &mut finished);
            n.done.clear();
            finished
        });
        let body = ToHost::Done {
            node: self.id,
            finished,
        };
        let sent = self.send_host(&body);
        // The buffer, for the next batch.
        if let ToHost::Done { finished, .. } = body {
            self.done_wire = finished;
        }
        sent
    }

    /// How long (virtual seconds) a batch may wait for more paths: a few
    /// message start-ups, so that batching saves start-up cost without
    /// holding a path back much longer than its own sending would.
    fn batch_wait(&self) -> f64 {
        BATCH_WAIT * self.model.overhead
    }

    /// Sends link `i`'s batch if it is full or has waited long enough.
    fn seal_if_due(&mut self, i: usize) -> Result<(), NodeError> {
        let b = &self.batches[i];
        if b.len() >= BATCH || (!b.is_empty() && self.clock - self.opened[i] >= self.batch_wait()) {
            self.seal(i)?;
        }
        Ok(())
    }

    /// Encodes the batch of link `i` into a message waiting to be sent.
    fn seal(&mut self, i: usize) -> Result<(), NodeError> {
        let paths = std::mem::take(&mut self.batches[i]);
        if paths.is_empty() {
            return Ok(());
        }
        let held: usize = paths.iter().map(Carried::held).sum();
        // Packed as it is encoded (`RaysOut`): the link model's work, not
        // the node's compute (`enqueue` takes it off).
        let ctx = self.path_context();
        let out = RaysOut {
            paths: &paths,
            ctx: &ctx,
        };
        self.enqueue_with(i, |buf| out.write(buf))?;
        self.release(held);
        Ok(())
    }

    /// What paths on the wire may leave out (`codec::wire_routed`).
    fn path_context(&self) -> PathContext<'a> {
        PathContext {
            lights: &self.share.scene.lights,
            spp: self.share.spp,
            cells: &self.share.cells,
        }
    }

    fn send_host(&mut self, body: &ToHost) -> Result<(), NodeError> {
        let i = self.link_index(Link::Host);
        self.enqueue(i, body)
    }

    /// Puts the computing the running unit of work has done so far on the
    /// clock, so that a message sent from within the unit (a finished
    /// sample's record, a batch of paths) is stamped when it is sent, not
    /// when the unit began. Before this, a path's records left at its
    /// unit's start, up to a unit's work early: the host could end the run
    /// before the node had computed them, and `scale`'s utilisation came
    /// out above 1 on small renders (`work_for_a_while`).
    ///
    /// Within the emulation's own work (`excluding`, as when a forwarded
    /// path fills a batch), the computing ends where that work began: the
    /// unit's accounting resumes from there, and the block's time is taken
    /// off when it ends.
    fn catch_up(&mut self) {
        if let Some((t0, excluded)) = self.unit {
            let (cut, cut_excluded) = self
                .exclusion
                .unwrap_or_else(|| (Ticks::now(), self.excluded));
            let done = cut.seconds_since(t0) - (cut_excluded - excluded);
            let dt = done.max(0.0) / self.model.compute_speed;
            self.clock += dt;
            self.unit_charged += dt;
            self.unit = Some((cut, cut_excluded));
        }
    }

    /// Stamps, encodes and queues a message on link `i`; the clock pays
    /// its sending cost.
    fn enqueue<T: serde::Serialize>(&mut self, i: usize, body: &T) -> Result<(), NodeError> {
        self.enqueue_with(i, |buf| encode_into(buf, body))
    }

    /// `enqueue` of a message that `write` encodes (`RaysOut::write`).
    fn enqueue_with(
        &mut self,
        i: usize,
        write: impl FnOnce(&mut Vec<u8>) -> Result<(), String>,
    ) -> Result<(), NodeError> {
        self.catch_up();
        let len = self.excluding(|n| {
            let (model, clock) = (n.model, &mut n.clock);
            append_frame(&mut n.waiting[i], write, |len| {
                *clock += model.send_cost(len);
                *clock
            })
        })?;
        self.carries[i] = true;
        self.report.messages_sent += 1;
        self.report.bytes_sent += len.wire as u64;
        self.hold(len.held);
        Ok(())
    }

    /// Sends what the links take. `all`: also seal partial batches (the
    /// node is about to idle, so holding them back would only delay).
    fn flush(&mut self, all: bool) -> Result<(), NodeError> {
        for i in 0..self.batches.len() {
            if all {
                self.seal(i)?;
            } else {
                self.seal_if_due(i)?;
            }
        }
        if all || self.done_due() {
            self.send_done()?;
        }
        // Each link's waiting messages go as one envelope, or wait for
        // room (and grow) if the link is full.
        let host = self.link_index(Link::Host);
        for i in 0..self.waiting.len() {
            if self.waiting[i].is_empty() {
                continue;
            }
            if i == host && !all {
                if self.host_flushed.elapsed() < self.share.pacing.host_coalesce {
                    continue;
                }
                self.host_flushed = Ticks::now();
            }
            self.send_waiting(i)?;
        }
        // Test-only (`MachineOptions::stall`).
        if let Some(stall) = self.faults.stall_on_send {
            let t0 = Ticks::now();
            while t0.elapsed() < stall {
                std::hint::spin_loop();
            }
        }
        Ok(())
    }

    /// Sends link `i`'s waiting envelope if the link takes it; if it is
    /// full, the envelope waits (and grows).
    fn send_waiting(&mut self, i: usize) -> Result<(), NodeError> {
        let bytes = std::mem::take(&mut self.waiting[i]);
        let clock_frame = self.clock_frame[i].take();
        let n = bytes.len();
        match self.links.try_send(self.link_of(i), bytes) {
            Ok(None) => {
                // The next envelope is one received (`SPARE_ENVELOPES`),
                // or a new one with room.
                self.waiting[i] = self
                    .spare
                    .pop()
                    .unwrap_or_else(|| Vec::with_capacity(ENVELOPE_ROOM));
                self.release(n);
                self.carries[i] = false;
                if i == self.link_index(Link::Host) {
                    self.uncovered_waiting = 0;
                }
            }
            Ok(Some(back)) => {
                self.waiting[i] = back;
                self.clock_frame[i] = clock_frame;
            }
            // A neighbour that has stopped needs no more clock news;
            // anything else it would have needed.
            Err(_) if !self.carries[i] && self.link_of(i) != Link::Host => {
                self.release(n);
            }
            Err(c) => return Err(format!("link {:?} closed", c.0)),
        }
        Ok(())
    }
}

/// The primary samples of a pass that a node owns, generated lazily. For
/// a pass over every pixel: for each front super cell it owns, the pixels
/// its rectangle touches, and of their samples those whose ray stays in
/// that super cell (every sample belongs to exactly one super cell, so to
/// exactly one node). For a pass over listed pixels (adaptive refinement):
/// the listed pixels' samples whose super cell it owns.
struct Primaries {
    id: u16,
    owner: Vec<u16>,
    supers: Vec<u32>,
    list: Option<Vec<u32>>,
    spp: u32,
    first_sample: u32,
    width: u32,
    /// Position: super cell index (or list index), its pixel box, next
    /// pixel and sample.
    at: usize,
    bx: [u32; 4],
    i: u32,
    j: u32,
    k: u32,
    pending: Option<(RayJob, u64, bool)>,
    generated: u64,
    /// The super cell of the last sample: where the next one's is looked
    /// for first.
    last_super: u32,
}

impl Primaries {
    fn new(share: &Share, id: u16) -> Self {
        let owner = share.owner[Region::Front as usize].clone();
        let supers = (0..owner.len() as u32)
            .filter(|&s| owner[s as usize] == id)
            .collect();
        let mut p = Primaries {
            id,
            owner,
            supers,
            list: share.pixels.clone(),
            spp: share.spp.max(1),
            first_sample: share.first_sample,
            width: share.width,
            at: 0,
            bx: [0; 4],
            i: 0,
            j: 0,
            k: 0,
            pending: None,
            generated: 0,
            last_super: 0,
        };
        if p.list.is_none() {
            let cam = CameraFrame::new(&share.scene, share.width, share.height);
            p.advance_super(&share.cells, &cam);
        }
        p
    }

    /// Whether the next sample is background; None when all are out.
    fn peek(&mut self, cs: &CellStructure, cam: &CameraFrame) -> Option<bool> {
        if self.pending.is_none() {
            self.pending = self.produce(cs, cam);
        }
        self.pending.map(|p| p.2)
    }

    fn next(&mut self, cs: &CellStructure, cam: &CameraFrame) -> Option<(RayJob, u64, bool)> {
        self.pending.take().or_else(|| self.produce(cs, cam))
    }

    /// The next candidate (pixel, sample) and the super cell it must fall
    /// in (None: any super cell this node owns).
    fn candidate(
        &mut self,
        cs: &CellStructure,
        cam: &CameraFrame,
    ) -> Option<(u32, u32, Option<u32>)> {
        let k = self.k;
        if let Some(list) = &self.list {
            let &pixel = list.get(self.at)?;
            self.k += 1;
            if self.k == self.spp {
                self.k = 0;
                self.at += 1;
            }
            return Some((pixel, k, None));
        }
        let &s = self.supers.get(self.at)?;
        let (i, j) = (self.i, self.j);
        // Advance: sample, pixel, row, super cell.
        self.k += 1;
        if self.k == self.spp {
            self.k = 0;
            self.i += 1;
            if self.i == self.bx[1] {
                self.i = self.bx[0];
                self.j += 1;
                if self.j == self.bx[3] {
                    self.at += 1;
                    self.advance_super(cs, cam);
                }
            }
        }
        Some((j * self.width + i, k, Some(s)))
    }

    fn produce(&mut self, cs: &CellStructure, cam: &CameraFrame) -> Option<(RayJob, u64, bool)> {
        let front = cs.region(Region::Front);
        loop {
            let (pixel, k, want) = self.candidate(cs, cam)?;
            let (i, j) = (pixel % self.width, pixel / self.width);
            let (fx, fy) = sample_offset_from(pixel, k, self.spp, self.first_sample);
            let job = cam.primary(i, j, fx, fy, 1.0 / self.spp as f64);
            let s = cs.primary_super_cell_from(&job.ray, want.unwrap_or(self.last_super));
            self.last_super = s;
            let mine = match want {
                Some(w) => s == w,
                None => self.owner[s as usize] == self.id,
            };
            if !mine {
                continue;
            }
            self.generated += 1;
            let sample = pixel as u64 * self.spp as u64 + k as u64;
            return Some((job, sample, front.super_cell_is_empty(s)));
        }
    }

    fn advance_super(&mut self, cs: &CellStructure, cam: &CameraFrame) {
        while let Some(&s) = self.supers.get(self.at) {
            let r = cs.region(Region::Front).supers[s as usize].rect;
            let (w, h) = (cam.width as f64, cam.height as f64);
            let fx = |x: f64| (x / cam.half_w + 1.0) * w / 2.0;
            let fy = |y: f64| (1.0 - y / cam.half_h) * h / 2.0;
            let clamp = |v: f64, n: f64| v.max(0.0).min(n);
            let (i0, i1) = (
                clamp(fx(r.x0).floor() - 1.0, w),
                clamp(fx(r.x1).ceil() + 1.0, w),
            );
            let (j0, j1) = (
                clamp(fy(r.y1).floor() - 1.0, h),
                clamp(fy(r.y0).ceil() + 1.0, h),
            );
            if i0 < i1 && j0 < j1 {
                self.bx = [i0 as u32, i1 as u32, j0 as u32, j1 as u32];
                self.i = self.bx[0];
                self.j = self.bx[2];
                self.k = 0;
                return;
            }
            self.at += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::{Ray, Vec3};

    /// `shadows_on_top` is the stable sort by kind it stands for, in the
    /// shader's order and in any other: every sequence of up to six rays
    /// of three kinds, each numbered by its pixel to see the order kept.
    #[test]
    fn shadows_go_on_top_in_the_order_they_came() {
        let kinds = [RayKind::Shadow, RayKind::Reflected, RayKind::Refracted];
        for n in 0..=6u32 {
            for code in 0..3u32.pow(n) {
                let jobs: Vec<RayJob> = (0..n)
                    .map(|i| RayJob {
                        ray: Ray::new(Vec3::ZERO, Vec3::Z),
                        kind: kinds[(code / 3u32.pow(i) % 3) as usize],
                        pixel: i,
                        depth: 0,
                        weight: [1.0; 3],
                        t_max: f64::INFINITY,
                        leaving: None,
                        light: None,
                    })
                    .collect();
                let mut sorted = jobs.clone();
                sorted.sort_by_key(|j| j.kind == RayKind::Shadow);
                let mut ours = jobs;
                shadows_on_top(&mut ours);
                let order = |v: &[RayJob]| v.iter().map(|j| (j.pixel, j.kind)).collect::<Vec<_>>();
                assert_eq!(order(&ours), order(&sorted), "code {code} of {n} rays");
            }
        }
    }

    /// Nodes with a core each keep the long lag and the short coalescing
    /// (the threads drift only when preempted, and credits must come back
    /// quickly); nodes sharing cores get a lag that shrinks to one slice
    /// as more share one, and the long coalescing.
    #[test]
    fn pacing_follows_the_nodes_per_core() {
        for (nodes, cores) in [(1, 2), (2, 2), (4, 4), (1, 1)] {
            let p = Pacing::for_host(nodes, cores);
            assert_eq!(p.lag_slices, LAG_SLICES_OWN_CORE, "{nodes} on {cores}");
            assert_eq!(
                p.host_coalesce, HOST_COALESCE_OWN_CORE,
                "{nodes} on {cores}"
            );
        }
        let lag = |nodes, cores| Pacing::for_host(nodes, cores).lag_slices;
        assert_eq!(lag(4, 2), LAG_SLICES_SHARED / 2.0);
        assert_eq!(lag(32, 2), LAG_SLICES);
        assert_eq!(lag(1024, 2), LAG_SLICES);
        assert!(lag(8, 2) <= lag(4, 2));
        assert_eq!(Pacing::for_host(32, 2).host_coalesce, HOST_COALESCE);
        // No cores reported counts as one.
        assert_eq!(Pacing::for_host(2, 0), Pacing::for_host(2, 1));
    }
}
