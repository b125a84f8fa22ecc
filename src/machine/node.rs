//! A node of the hypercube: a thread that shares nothing. It waits for its
//! load message, then, until the host says stop: takes the paths its
//! neighbours send, traces each one's active ray through the cells it
//! holds (shading, spawning, moving on to the next ray of the path), sends
//! a path on when its walk reaches a cell held elsewhere (e-cube routing,
//! hop by hop), starts the primary paths of the pixels its super cells own
//! when the host has given it credit, and reports finished samples.
//!
//! Memory: everything the node holds is counted (its share, the paths in
//! its queue and in its outgoing batches, encoded messages waiting for a
//! link) and the peak is reported. The host sized the windows of primary
//! paths so that all paths in flight fit any node (`host`).
//!
//! Time: the node's virtual clock advances by the thread CPU time of its
//! work divided by the topology's compute speed, by the send cost of each
//! message, and jumps to a message's arrival time when it was idle.

use std::collections::VecDeque;

use super::codec::{decode_stamped, encode_stamped};
use super::message::{
    Active, Finished, LinkModel, NodeReport, Path, Routed, Share, ToHost, ToNode,
};
use super::routing::{NodeId, next_dimension};
use super::transport::{Link, NodeLinks};
use crate::cells::{CellStructure, CellTracer, Region, Walk};
use crate::render::sample_offset;
use crate::scene::Scene;
use crate::trace::{CameraFrame, Film, RayJob, RayKind, Shader};

/// Paths per batch message on a link.
const BATCH: usize = 64;
/// Finished samples per message to the host.
const DONE_BATCH: usize = 256;

/// Thread CPU time in seconds: what the node computed, not what the host's
/// scheduler gave other threads meanwhile.
pub fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec, which we own.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return 0.0;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// The bytes a node's share occupies once loaded: the structure, the
/// primitives, and the tracer's per-primitive and per-operator mailboxes.
pub fn share_bytes(cells: &CellStructure, scene: &Scene) -> u64 {
    use std::mem::size_of;
    let prims: usize = scene
        .primitives
        .iter()
        .map(|p| {
            size_of::<crate::csg::Primitive>()
                + match &p.shape {
                    crate::csg::Shape::Polygon(poly) => {
                        poly.vertices.len() * size_of::<crate::geom::Vec3>()
                            + poly.triangles.len() * 12
                    }
                    _ => 0,
                }
        })
        .sum();
    let tracer = CellTracer::bytes_for(cells, scene);
    (cells.bytes()
        + prims
        + scene.materials.len() * size_of::<crate::scene::Material>()
        + scene.lights.len() * size_of::<crate::scene::Light>()
        + tracer) as u64
}

/// Why a node stopped early.
pub type NodeError = String;

/// Runs node `id` on its links until the host says stop. Errors are
/// reported to the host by the caller.
pub fn run(id: u16, links: &mut dyn NodeLinks) -> Result<(), NodeError> {
    // The load message first. Neighbours loaded before this node may
    // already send it rays (the host loads nodes one after another, and
    // links between nodes do not wait for the host's): those are kept, in
    // order, and taken first once loaded.
    let mut early = VecDeque::new();
    let (share, arrival) = loop {
        match links
            .try_recv()
            .map_err(|c| format!("link {:?} closed before loading", c.0))?
        {
            Some(bytes) => {
                let (sent_at, body): (f64, ToNode) = decode_stamped(&bytes)?;
                match body {
                    ToNode::Load(share) => {
                        let t = sent_at + share.link.latency;
                        break (share, t);
                    }
                    ToNode::Stop => return Ok(()),
                    ToNode::Rays(_) | ToNode::Credit(_) => early.push_back(bytes),
                }
            }
            None => links.wait(&[]),
        }
    };
    let share = *share;
    let mut node = Node::new(id, &share, links, arrival)?;
    node.early = early;
    node.run()
}

struct Node<'a> {
    id: u16,
    share: &'a Share,
    links: &'a mut dyn NodeLinks,
    tracer: CellTracer<'a>,
    shader: Shader<'a>,
    cam: CameraFrame,
    primaries: Primaries,
    credits: u32,
    queue: VecDeque<Path>,
    /// Per link (dimensions, then the host): paths to batch, encoded
    /// messages waiting for room.
    batches: Vec<Vec<Routed>>,
    waiting: Vec<VecDeque<Vec<u8>>>,
    done: Vec<Finished>,
    generated_reported: bool,
    stopping: bool,
    /// Bytes of rays held (queue, batches, encoded messages).
    ray_bytes: u64,
    report: NodeReport,
    clock: f64,
    model: LinkModel,
    paths_processed: u64,
    /// Messages from neighbours that came before the load message, taken
    /// before any other.
    early: VecDeque<Vec<u8>>,
}

impl<'a> Node<'a> {
    fn new(
        id: u16,
        share: &'a Share,
        links: &'a mut dyn NodeLinks,
        clock: f64,
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
        let report = NodeReport {
            node: id,
            cells,
            super_cells,
            primitives: share.scene.primitives.len() as u64,
            memory_bytes: memory,
            memory_budget_bytes: share.budget,
            peak_memory_bytes: memory,
            ..Default::default()
        };
        Ok(Node {
            id,
            share,
            links,
            tracer: CellTracer::new(&share.cells, &share.scene),
            shader: Shader::new(&share.scene),
            cam: CameraFrame::new(&share.scene, share.width, share.height),
            primaries: Primaries::new(share, id),
            credits: share.window,
            queue: VecDeque::new(),
            batches: vec![Vec::new(); d + 1],
            waiting: vec![VecDeque::new(); d + 1],
            done: Vec::new(),
            generated_reported: false,
            stopping: false,
            ray_bytes: 0,
            report,
            clock,
            model: share.link,
            paths_processed: 0,
            early: VecDeque::new(),
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
        self.send_host(ToHost::Loaded { node: self.id })?;
        loop {
            self.receive_all()?;
            if self.stopping {
                break;
            }
            let t0 = cpu_seconds();
            let worked = self.work_a_little()?;
            self.charge(t0);
            self.flush(!worked)?;
            if !worked && !self.stopping {
                let sending: Vec<Link> = (0..self.waiting.len())
                    .filter(|&i| !self.waiting[i].is_empty())
                    .map(|i| self.link_of(i))
                    .collect();
                self.links.wait(&sending);
            }
        }
        self.report.virtual_seconds = self.clock;
        let c = self.tracer.counters;
        self.report.intersection_tests = c.intersection_tests;
        self.report.mailbox_hits = c.mailbox_hits;
        self.report.cells_visited = c.cells_visited;
        self.report.subtree_evaluations = c.subtree_evaluations;
        let report = Box::new(std::mem::take(&mut self.report));
        self.send_host(ToHost::Report(report))?;
        // The report must leave before the thread ends.
        while !self.waiting[self.link_index(Link::Host)].is_empty() {
            self.flush(true)?;
            if !self.waiting[self.link_index(Link::Host)].is_empty() {
                self.links.wait(&[Link::Host]);
            }
        }
        Ok(())
    }

    /// Advances the clock by the CPU time since `t0`.
    fn charge(&mut self, t0: f64) {
        let dt = (cpu_seconds() - t0).max(0.0);
        self.report.busy_seconds += dt;
        self.clock += dt / self.model.compute_speed;
    }

    /// Takes every message offered now.
    fn receive_all(&mut self) -> Result<(), NodeError> {
        loop {
            let bytes = match self.early.pop_front() {
                Some(b) => b,
                None => match self
                    .links
                    .try_recv()
                    .map_err(|c| format!("link {:?} closed", c.0))?
                {
                    Some(b) => b,
                    None => break,
                },
            };
            let t0 = cpu_seconds();
            self.hold(bytes.len());
            let (sent_at, body): (f64, ToNode) = decode_stamped(&bytes)?;
            // The decoded paths are held before the bytes are let go.
            if let ToNode::Rays(paths) = &body {
                self.hold(paths.iter().map(|r| r.path.bytes()).sum());
            }
            self.release(bytes.len());
            drop(bytes);
            // The message is here once sent and across the wire; an idle
            // node waited for it.
            self.clock = self.clock.max(sent_at + self.model.latency);
            match body {
                ToNode::Rays(paths) => {
                    for r in paths {
                        self.arrive(r)?;
                    }
                }
                ToNode::Credit(n) => self.credits += n,
                ToNode::Stop => self.stopping = true,
                ToNode::Load(_) => return Err("a second load message".into()),
            }
            self.charge(t0);
        }
        Ok(())
    }

    /// A path arriving over a link (its bytes held): ours to trace, or to
    /// pass on.
    fn arrive(&mut self, r: Routed) -> Result<(), NodeError> {
        if r.dest == self.id {
            self.queue.push_back(r.path);
            Ok(())
        } else {
            self.report.paths_forwarded += 1;
            self.route(r)
        }
    }

    /// Puts a path (its bytes held) in the batch of the next link toward
    /// its destination.
    fn route(&mut self, mut r: Routed) -> Result<(), NodeError> {
        let k = next_dimension(NodeId(self.id), NodeId(r.dest))
            .ok_or("routing a path to its own node")?;
        r.hops += 1;
        self.report.hops += 1;
        self.batches[k as usize].push(r);
        if self.batches[k as usize].len() >= BATCH {
            self.seal(k as usize)?;
        }
        Ok(())
    }

    /// One unit of work: a queued path, or a new primary path. False when
    /// there was nothing to do.
    fn work_a_little(&mut self) -> Result<bool, NodeError> {
        if let Some(path) = self.queue.pop_front() {
            self.trace(path)?;
            return Ok(true);
        }
        // New primary paths while credit lasts; background samples of
        // empty pixel areas finish at once and need none.
        loop {
            let Some(background) = self.primaries.peek(&self.share.cells, &self.cam) else {
                if !self.generated_reported {
                    self.generated_reported = true;
                    let samples = self.primaries.generated;
                    self.send_host(ToHost::Generated {
                        node: self.id,
                        samples,
                    })?;
                    return Ok(true);
                }
                return Ok(false);
            };
            if !background && self.credits == 0 {
                break;
            }
            let (job, sample, _) = self
                .primaries
                .next(&self.share.cells, &self.cam)
                .ok_or("a peeked sample vanished")?;
            self.report.rays_created[RayKind::Primary.index()] += 1;
            if background {
                self.report.rays_finished[RayKind::Primary.index()] += 1;
                self.finish_sample(Finished {
                    sample,
                    origin: self.id,
                    sum: Film::quantize(self.shader.miss(&job)),
                    traced: false,
                })?;
                continue;
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
            };
            self.hold(path.bytes());
            self.trace(path)?;
            return Ok(true);
        }
        Ok(false)
    }

    /// Follows a path (its bytes held) as far as this node's cells go:
    /// until it leaves for another node or is finished. The same rules, in
    /// the same order, as `Shader::run_path`.
    fn trace(&mut self, mut path: Path) -> Result<(), NodeError> {
        let mut held = path.bytes();
        self.paths_processed += 1;
        if self
            .share
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
            let finished_with = match self.tracer.walk(&a.job.ray, a.t_min, a.job.t_max, from) {
                Walk::Remote(p) => {
                    a.at = Some(p);
                    let dest = self.share.owner[p.region as usize][p.super_cell as usize];
                    // Its bytes move, held, into the batch.
                    return self.route(Routed {
                        dest,
                        hops: 0,
                        path,
                    });
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
                    let c = self.shader.shade(&a.job, &h, &mut |j: RayJob| {
                        created[j.kind.index()] += 1;
                        stack.push(j);
                    });
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
                    return self.finish_sample(Finished {
                        sample: path.sample,
                        origin: path.origin,
                        sum: path.sum,
                        traced: true,
                    });
                }
            }
        }
    }

    fn finish_sample(&mut self, f: Finished) -> Result<(), NodeError> {
        self.done.push(f);
        if self.done.len() >= DONE_BATCH {
            self.send_done()?;
        }
        Ok(())
    }

    fn send_done(&mut self) -> Result<(), NodeError> {
        if self.done.is_empty() {
            return Ok(());
        }
        let finished = std::mem::take(&mut self.done);
        self.send_host(ToHost::Done {
            node: self.id,
            finished,
        })
    }

    /// Encodes the batch of link `i` into a message waiting to be sent.
    fn seal(&mut self, i: usize) -> Result<(), NodeError> {
        let paths = std::mem::take(&mut self.batches[i]);
        if paths.is_empty() {
            return Ok(());
        }
        let held: usize = paths.iter().map(|r| r.path.bytes()).sum();
        let body = ToNode::Rays(paths);
        self.enqueue(i, &body)?;
        self.release(held);
        Ok(())
    }

    fn send_host(&mut self, body: ToHost) -> Result<(), NodeError> {
        let i = self.link_index(Link::Host);
        self.enqueue(i, &body)
    }

    /// Stamps, encodes and queues a message on link `i`; the clock pays
    /// its sending cost.
    fn enqueue<T: serde::Serialize>(&mut self, i: usize, body: &T) -> Result<(), NodeError> {
        let (model, clock) = (self.model, &mut self.clock);
        let bytes = encode_stamped(body, |len| {
            *clock += model.send_cost(len);
            *clock
        })?;
        self.report.messages_sent += 1;
        self.report.bytes_sent += bytes.len() as u64;
        self.hold(bytes.len());
        self.waiting[i].push_back(bytes);
        Ok(())
    }

    /// Sends what the links take. `all`: also seal partial batches (the
    /// node is about to idle, so holding them back would only delay).
    fn flush(&mut self, all: bool) -> Result<(), NodeError> {
        if all {
            for i in 0..self.batches.len() {
                self.seal(i)?;
            }
            self.send_done()?;
        }
        for i in 0..self.waiting.len() {
            while let Some(bytes) = self.waiting[i].pop_front() {
                let n = bytes.len();
                match self
                    .links
                    .try_send(self.link_of(i), bytes)
                    .map_err(|c| format!("link {:?} closed", c.0))?
                {
                    None => self.release(n),
                    Some(back) => {
                        self.waiting[i].push_front(back);
                        break;
                    }
                }
            }
        }
        Ok(())
    }
}

/// The primary samples a node owns, generated lazily: for each front super
/// cell it owns, the pixels its rectangle touches, and of their samples
/// those whose ray stays in that super cell (every sample belongs to
/// exactly one super cell, so to exactly one node).
struct Primaries {
    supers: Vec<u32>,
    spp: u32,
    width: u32,
    /// Position: super cell index, its pixel box, next pixel and sample.
    at: usize,
    bx: [u32; 4],
    i: u32,
    j: u32,
    k: u32,
    pending: Option<(RayJob, u64, bool)>,
    generated: u64,
}

impl Primaries {
    fn new(share: &Share, id: u16) -> Self {
        let supers = (0..share.owner[0].len() as u32)
            .filter(|&s| share.owner[Region::Front as usize][s as usize] == id)
            .collect();
        let mut p = Primaries {
            supers,
            spp: share.spp.max(1),
            width: share.width,
            at: 0,
            bx: [0; 4],
            i: 0,
            j: 0,
            k: 0,
            pending: None,
            generated: 0,
        };
        let cam = CameraFrame::new(&share.scene, share.width, share.height);
        p.advance_super(&share.cells, &cam);
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

    fn produce(&mut self, cs: &CellStructure, cam: &CameraFrame) -> Option<(RayJob, u64, bool)> {
        let front = cs.region(Region::Front);
        loop {
            let &s = self.supers.get(self.at)?;
            let (i, j, k) = (self.i, self.j, self.k);
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
            let pixel = j * self.width + i;
            let (fx, fy) = sample_offset(pixel, k, self.spp);
            let job = cam.primary(i, j, fx, fy, 1.0 / self.spp as f64);
            if cs.primary_super_cell(&job.ray) != s {
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
