//! Links between nodes, as one small trait per end (`NodeLinks` for a
//! node, `HostLinks` for the coordinator), so that the node logic never
//! sees how bytes move. `channels` builds the in-process implementation:
//! one bounded crossbeam channel per direction of every hypercube edge,
//! one bounded channel from every node to the host, and unbounded ones
//! from the host (the host, like the iPSC's cube manager, is not the
//! memory-bound part). A transport over MPI would implement the same two
//! traits.
//!
//! Sends never block: a full link hands the message back, and the node
//! keeps it (counted in its memory) until `wait` says the link has room.
//! Since a node in `wait` also takes any message offered to it, a full
//! link always has a receiver that will drain it, and no cycle of full
//! links can deadlock, whatever the capacities.
//!
//! A waiting end sleeps on its own `Bell`, which the other ends of its
//! links ring: after a send to it, after taking a message from a link of
//! its that was full, and when they go. (crossbeam's `Select` spins and
//! yields some twenty times before it sleeps; with 32 node threads on two
//! cores every node waits thousands of times a second, and that spinning
//! took an eighth of the CPU of a render at d = 5.)

use std::sync::{Arc, OnceLock};
use std::thread::Thread;

use crossbeam_channel::{Receiver, Sender, TryRecvError, TrySendError, bounded, unbounded};

/// A link of a node: to its neighbour across a dimension, or to the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Link {
    Dim(u32),
    Host,
}

/// The other end is gone (its node stopped or failed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Closed(pub Link);

/// A node's end of its links.
pub trait NodeLinks: Send {
    /// Offers `bytes` to `link`: Ok(None) sent, Ok(Some(bytes)) the link
    /// is full (try again after `wait`).
    fn try_send(&mut self, link: Link, bytes: Vec<u8>) -> Result<Option<Vec<u8>>, Closed>;
    /// A message from any link, the host's first, neighbours in turn.
    fn try_recv(&mut self) -> Result<Option<Vec<u8>>, Closed>;
    /// Blocks until a message can be received or one of `sending` has room.
    fn wait(&mut self, sending: &[Link]);
}

/// The coordinator's end.
pub trait HostLinks {
    fn send(&mut self, node: u16, bytes: Vec<u8>) -> Result<(), Closed>;
    /// The next message from any node; Err when every node has gone.
    fn recv(&mut self) -> Result<Vec<u8>, Closed>;
}

/// Times a waiting end gives its core away before it sleeps. With more
/// node threads than cores, the message it waits for is most often sent
/// by a thread that a yield lets run, and a yield is much cheaper than a
/// sleep and its wake-up (a system call on each side, and on this 2-core
/// virtual machine an interrupt to the other core). A/B against sleeping
/// at once: 40% slower at d = 5. Against crossbeam's `Select` (spinning
/// about 250 pause instructions and yielding 8 times before it sleeps),
/// interleaved runs at d = 5, 1024x1024: wall time 0.82-0.96x of
/// `Select`'s on the jagged ball (4 yields: 0.82, 0.88), 0.91x on the
/// sphereflake; 16 yields 1.04x.
const WAIT_YIELDS: usize = 4;

/// What an end of the links sleeps on while it waits: the thread that
/// waits there, which the other ends wake (`ring`). The wake-up is
/// `Thread::unpark`'s token, so a ring between the waiter's last look at
/// its links and its sleep is not lost: the sleep returns at once.
#[derive(Default)]
struct Bell(OnceLock<Thread>);

impl Bell {
    /// Wakes the waiter, if it sleeps (or makes its next sleep return).
    fn ring(&self) {
        if let Some(t) = self.0.get() {
            t.unpark();
        }
    }

    /// Waits for a ring, unless `ready` (a look at the links, taken once
    /// this thread listens, so that a ring after it is not lost) says there
    /// is something to do. Returns at once the first time: a ring before
    /// anyone listened woke nobody, and what it announced, a link gone,
    /// shows only to the caller's next receive. A thread other than the
    /// first to listen (an end of the links is used by one thread) yields
    /// instead of sleeping where nobody would wake it.
    fn wait(&self, ready: impl Fn() -> bool) {
        let me = std::thread::current();
        let mut first = false;
        let listener = self.0.get_or_init(|| {
            first = true;
            me.clone()
        });
        if first {
            return;
        }
        for _ in 0..WAIT_YIELDS {
            if ready() {
                return;
            }
            std::thread::yield_now();
        }
        if ready() {
            return;
        }
        if listener.id() == me.id() {
            std::thread::park();
        } else {
            std::thread::yield_now();
        }
    }
}

/// Whether taking a message from `rx` may have made room for a sender
/// waiting on it: the link was full before. Only the receiver takes, so a
/// link one short of full now was full before the take (or was filled
/// since: one ring too many, never one too few).
fn was_full(rx: &Receiver<Vec<u8>>) -> bool {
    rx.capacity().is_some_and(|cap| rx.len() + 1 >= cap)
}

/// A node's channels.
pub struct ChannelNode {
    to: Vec<Sender<Vec<u8>>>,
    from: Vec<Receiver<Vec<u8>>>,
    /// Neighbours that have stopped: no more to receive from them.
    done: Vec<bool>,
    to_host: Sender<Vec<u8>>,
    from_host: Receiver<Vec<u8>>,
    next: usize,
    bell: Arc<Bell>,
    /// Per dimension, the neighbour's bell; the host's.
    neighbour_bells: Vec<Arc<Bell>>,
    host_bell: Arc<Bell>,
}

/// The host's channels.
pub struct ChannelHost {
    to: Vec<Sender<Vec<u8>>>,
    /// Per node, its link to the host: a node waiting for room waits on
    /// its own link only, not with every other node on one shared channel
    /// (whose every freed slot woke them all).
    from: Vec<Receiver<Vec<u8>>>,
    /// Nodes that have stopped and whose links are empty.
    done: Vec<bool>,
    next: usize,
    bell: Arc<Bell>,
    node_bells: Vec<Arc<Bell>>,
}

/// The links of a hypercube of dimension `d`, each node-to-node and
/// node-to-host channel holding at most `capacity` messages (at least 1).
pub fn channels(d: u32, capacity: usize) -> (ChannelHost, Vec<ChannelNode>) {
    let n = 1usize << d;
    let cap = capacity.max(1);
    let mut host_to = Vec::with_capacity(n);
    let mut host_from = Vec::with_capacity(n);
    let host_bell = Arc::new(Bell::default());
    let node_bells: Vec<Arc<Bell>> = (0..n).map(|_| Arc::new(Bell::default())).collect();
    let mut nodes: Vec<ChannelNode> = (0..n)
        .map(|i| {
            let (tx, rx) = unbounded();
            host_to.push(tx);
            let (to_host, from_node) = bounded(cap);
            host_from.push(from_node);
            ChannelNode {
                to: Vec::with_capacity(d as usize),
                from: Vec::with_capacity(d as usize),
                done: vec![false; d as usize],
                to_host,
                from_host: rx,
                next: 0,
                bell: node_bells[i].clone(),
                neighbour_bells: (0..d).map(|k| node_bells[i ^ (1 << k)].clone()).collect(),
                host_bell: host_bell.clone(),
            }
        })
        .collect();
    // Dimension by dimension, so that `to[k]` and `from[k]` are the links
    // across dimension k.
    for k in 0..d {
        let mut rx_of = Vec::with_capacity(n);
        for node in &mut nodes {
            let (tx, rx) = bounded(cap);
            node.to.push(tx);
            rx_of.push(rx);
        }
        // Node i's sender across k feeds node i ^ 2^k.
        let mut rx_of: Vec<Option<Receiver<Vec<u8>>>> = rx_of.into_iter().map(Some).collect();
        for i in 0..n {
            let from = rx_of[i ^ (1 << k)]
                .take()
                .expect("i -> i ^ 2^k pairs the nodes, so each receiver is taken once");
            nodes[i].from.push(from);
        }
    }
    let host = ChannelHost {
        to: host_to,
        from: host_from,
        done: vec![false; n],
        next: 0,
        bell: host_bell,
        node_bells,
    };
    (host, nodes)
}

/// Whether a message waits on one of the links `from` not yet `done`.
fn offered(from: &[Receiver<Vec<u8>>], done: &[bool]) -> bool {
    (from.iter().zip(done)).any(|(rx, &done)| !done && !rx.is_empty())
}

impl ChannelNode {
    /// The sending end of `link`, and the bell of the end it reaches.
    fn sender(&self, link: Link) -> (&Sender<Vec<u8>>, &Bell) {
        match link {
            Link::Dim(k) => (&self.to[k as usize], &self.neighbour_bells[k as usize]),
            Link::Host => (&self.to_host, &self.host_bell),
        }
    }

    /// Whether a message waits or one of `sending` has room: `wait` need
    /// not sleep.
    fn ready(&self, sending: &[Link]) -> bool {
        !self.from_host.is_empty()
            || offered(&self.from, &self.done)
            || sending.iter().any(|&l| !self.sender(l).0.is_full())
    }
}

/// A node that stops (or fails) wakes the ends of its links, which then
/// find them closed. Its channel ends go first: a ring before they close
/// could wake a waiter that looks, finds its link still open, and sleeps
/// again with nobody left to wake it (seen: the host asleep in `recv`
/// for 10 s after its last node had gone).
impl Drop for ChannelNode {
    fn drop(&mut self) {
        self.to.clear();
        self.from.clear();
        // The host's ends are fields, not options: each is swapped for an
        // end of a channel of nobody's, and dropped.
        let (unused_to, unused_from) = bounded(0);
        drop(std::mem::replace(&mut self.to_host, unused_to));
        drop(std::mem::replace(&mut self.from_host, unused_from));
        for b in &self.neighbour_bells {
            b.ring();
        }
        self.host_bell.ring();
    }
}

impl Drop for ChannelHost {
    fn drop(&mut self) {
        // The channels first, as for a node.
        self.to.clear();
        self.from.clear();
        for b in &self.node_bells {
            b.ring();
        }
    }
}

impl NodeLinks for ChannelNode {
    fn try_send(&mut self, link: Link, bytes: Vec<u8>) -> Result<Option<Vec<u8>>, Closed> {
        let (tx, bell) = self.sender(link);
        match tx.try_send(bytes) {
            Ok(()) => {
                bell.ring();
                Ok(None)
            }
            Err(TrySendError::Full(b)) => Ok(Some(b)),
            Err(TrySendError::Disconnected(_)) => Err(Closed(link)),
        }
    }

    fn try_recv(&mut self) -> Result<Option<Vec<u8>>, Closed> {
        match self.from_host.try_recv() {
            Ok(b) => return Ok(Some(b)),
            Err(TryRecvError::Empty) => {}
            Err(TryRecvError::Disconnected) => return Err(Closed(Link::Host)),
        }
        let d = self.from.len();
        for i in 0..d {
            let k = (self.next + i) % d;
            if self.done[k] {
                continue;
            }
            match self.from[k].try_recv() {
                Ok(b) => {
                    self.next = (k + 1) % d;
                    if was_full(&self.from[k]) {
                        self.neighbour_bells[k].ring();
                    }
                    return Ok(Some(b));
                }
                Err(TryRecvError::Empty) => {}
                // A neighbour that stopped sends nothing more; only a send
                // to it is an error.
                Err(TryRecvError::Disconnected) => self.done[k] = true,
            }
        }
        Ok(None)
    }

    fn wait(&mut self, sending: &[Link]) {
        // A return means something may have changed (a message, room, a
        // link gone, or nothing); the caller tries again.
        self.bell.wait(|| self.ready(sending));
    }
}

impl HostLinks for ChannelHost {
    fn send(&mut self, node: u16, bytes: Vec<u8>) -> Result<(), Closed> {
        self.to[node as usize]
            .send(bytes)
            .map_err(|_| Closed(Link::Dim(u32::from(node))))?;
        self.node_bells[node as usize].ring();
        Ok(())
    }

    fn recv(&mut self) -> Result<Vec<u8>, Closed> {
        let n = self.from.len();
        loop {
            // The nodes' links in turn, so that none is starved.
            let mut open = false;
            for i in 0..n {
                let k = (self.next + i) % n;
                if self.done[k] {
                    continue;
                }
                match self.from[k].try_recv() {
                    Ok(b) => {
                        self.next = (k + 1) % n;
                        if was_full(&self.from[k]) {
                            self.node_bells[k].ring();
                        }
                        return Ok(b);
                    }
                    Err(TryRecvError::Empty) => open = true,
                    Err(TryRecvError::Disconnected) => self.done[k] = true,
                }
            }
            if !open {
                return Err(Closed(Link::Host));
            }
            let (from, done) = (&self.from, &self.done);
            self.bell.wait(|| offered(from, done));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `f` on its own thread and returns what it gives, failing (not
    /// hanging) if it has not finished within 10 s: a lost wake-up.
    fn within_10s<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || tx.send(f()));
        rx.recv_timeout(std::time::Duration::from_secs(10))
            .expect("a waiting end was never woken")
    }

    /// Receives as an idle node does: `wait` until a message is there.
    fn receive(mut links: ChannelNode) -> (ChannelNode, Result<Vec<u8>, Closed>) {
        loop {
            match links.try_recv() {
                Ok(Some(b)) => return (links, Ok(b)),
                Ok(None) => links.wait(&[]),
                Err(c) => return (links, Err(c)),
            }
        }
    }

    #[test]
    fn a_waiting_end_wakes_for_a_message_for_room_and_when_a_link_goes() {
        let pause = || std::thread::sleep(std::time::Duration::from_millis(50));
        let (mut host, mut nodes) = channels(1, 1);
        let (b, mut a) = (nodes.pop().unwrap(), nodes.pop().unwrap());
        // A message to a node asleep in `wait`.
        let waiter = std::thread::spawn(move || within_10s(move || receive(b)));
        pause();
        assert_eq!(a.try_send(Link::Dim(0), vec![1]), Ok(None));
        let (mut b, got) = waiter.join().unwrap();
        assert_eq!(got, Ok(vec![1]));
        // Room on a full link, for a sender asleep in `wait`.
        assert_eq!(a.try_send(Link::Dim(0), vec![2]), Ok(None));
        let sender = std::thread::spawn(move || {
            within_10s(move || {
                let mut bytes = vec![3];
                while let Some(back) = a.try_send(Link::Dim(0), bytes).unwrap() {
                    bytes = back;
                    a.wait(&[Link::Dim(0)]);
                }
                a
            })
        });
        pause();
        assert_eq!(b.try_recv(), Ok(Some(vec![2])));
        let mut a = sender.join().unwrap();
        assert_eq!(b.try_recv(), Ok(Some(vec![3])));
        // The host, asleep in `recv`, hears a node's message, and that
        // every node has gone.
        drop(b);
        let collector = std::thread::spawn(move || {
            within_10s(move || {
                let first = host.recv();
                (first, host.recv(), host)
            })
        });
        pause();
        assert_eq!(a.try_send(Link::Host, vec![4]), Ok(None));
        pause();
        drop(a);
        let (first, second, _host) = collector.join().unwrap();
        assert_eq!(first, Ok(vec![4]));
        assert_eq!(second, Err(Closed(Link::Host)));
        // A node asleep in `wait` whose host goes.
        let (host, mut nodes) = channels(0, 1);
        let only = nodes.pop().unwrap();
        let waiter = std::thread::spawn(move || within_10s(move || receive(only)));
        pause();
        drop(host);
        assert_eq!(waiter.join().unwrap().1, Err(Closed(Link::Host)));
    }

    #[test]
    fn links_join_exactly_the_hypercube_neighbours() {
        let (mut host, mut nodes) = channels(3, 1);
        for i in 0..8usize {
            for k in 0..3u32 {
                let msg = vec![i as u8, k as u8];
                assert_eq!(nodes[i].try_send(Link::Dim(k), msg), Ok(None));
                let j = i ^ (1 << k);
                assert_eq!(nodes[j].try_recv(), Ok(Some(vec![i as u8, k as u8])));
            }
        }
        // Capacity 1 per link: a node's second message is handed back,
        // another node's own link still has room.
        assert_eq!(nodes[0].try_send(Link::Host, vec![1]), Ok(None));
        assert_eq!(nodes[0].try_send(Link::Host, vec![3]), Ok(Some(vec![3])));
        assert_eq!(nodes[1].try_send(Link::Host, vec![2]), Ok(None));
        let mut got = [host.recv().unwrap(), host.recv().unwrap()];
        got.sort();
        assert_eq!(got, [vec![1], vec![2]]);
        host.send(5, vec![9]).unwrap();
        assert_eq!(nodes[5].try_recv(), Ok(Some(vec![9])));
        assert_eq!(nodes[4].try_recv(), Ok(None));
        // Once every node has gone and its link is empty, the host hears so.
        drop(nodes);
        assert_eq!(host.recv(), Err(Closed(Link::Host)));
    }
}
