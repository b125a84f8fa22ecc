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

use crossbeam_channel::{Receiver, Select, Sender, TryRecvError, TrySendError, bounded, unbounded};

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

/// A node's channels.
pub struct ChannelNode {
    to: Vec<Sender<Vec<u8>>>,
    from: Vec<Receiver<Vec<u8>>>,
    /// Neighbours that have stopped: no more to receive from them.
    done: Vec<bool>,
    to_host: Sender<Vec<u8>>,
    from_host: Receiver<Vec<u8>>,
    next: usize,
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
}

/// The links of a hypercube of dimension `d`, each node-to-node and
/// node-to-host channel holding at most `capacity` messages (at least 1).
pub fn channels(d: u32, capacity: usize) -> (ChannelHost, Vec<ChannelNode>) {
    let n = 1usize << d;
    let cap = capacity.max(1);
    let mut host_to = Vec::with_capacity(n);
    let mut host_from = Vec::with_capacity(n);
    let mut nodes: Vec<ChannelNode> = (0..n)
        .map(|_| {
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
    };
    (host, nodes)
}

impl NodeLinks for ChannelNode {
    fn try_send(&mut self, link: Link, bytes: Vec<u8>) -> Result<Option<Vec<u8>>, Closed> {
        let tx = match link {
            Link::Dim(k) => &self.to[k as usize],
            Link::Host => &self.to_host,
        };
        match tx.try_send(bytes) {
            Ok(()) => Ok(None),
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
        let mut sel = Select::new();
        sel.recv(&self.from_host);
        for (k, rx) in self.from.iter().enumerate() {
            if !self.done[k] {
                sel.recv(rx);
            }
        }
        for l in sending {
            match l {
                Link::Dim(k) => sel.send(&self.to[*k as usize]),
                Link::Host => sel.send(&self.to_host),
            };
        }
        // Ready means an operation would not block (or its other end is
        // gone); the caller then tries again.
        sel.ready();
    }
}

impl HostLinks for ChannelHost {
    fn send(&mut self, node: u16, bytes: Vec<u8>) -> Result<(), Closed> {
        self.to[node as usize]
            .send(bytes)
            .map_err(|_| Closed(Link::Dim(u32::from(node))))
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
                        return Ok(b);
                    }
                    Err(TryRecvError::Empty) => open = true,
                    Err(TryRecvError::Disconnected) => self.done[k] = true,
                }
            }
            if !open {
                return Err(Closed(Link::Host));
            }
            let mut sel = Select::new();
            for (k, rx) in self.from.iter().enumerate() {
                if !self.done[k] {
                    sel.recv(rx);
                }
            }
            sel.ready();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
