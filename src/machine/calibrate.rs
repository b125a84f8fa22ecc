//! A topology of this host: its cores as the nodes (`compute_speed` 1, a
//! node is a host core) and its in-process channels as the links, with
//! the link costs measured here, now, by a ping-pong of encoded messages
//! (`calibrate`). With it, a machine render's virtual time predicts the
//! render's own wall time whenever every node thread has a core, and the
//! gap between the two is the model's error (`quality`).
//!
//! What is measured, and how it maps on the link model (`send_cost` is
//! `overhead + bytes / bandwidth` on the sender's clock; a message
//! arrives `latency` after it is sent):
//!
//! * two threads hold the two ends of a real one-dimensional hypercube
//!   link (`transport::channels`); one sends batches of `RayJob`s encoded
//!   by `codec`, each a millisecond after the last, to the other, which
//!   has by then parked in `NodeLinks::wait` as an idle node does, wakes,
//!   and decodes it. Latency only shows in virtual time when a node sat
//!   idle waiting for a message, so the parked receiver is the case to
//!   measure (a tight ping-pong, where the receiver is still spinning,
//!   finds a third to a half of this latency);
//! * a message's one-way time runs from the start of its encoding to the
//!   end of its decoding (one monotonic clock for both threads). Its
//!   medians at four sizes (one ray to a batch of 256) are fitted as
//!   `a + b·bytes`;
//! * `bandwidth` is `1 / b`, the whole pipe's cost per byte (encoding,
//!   copying and decoding it);
//! * `overhead` is the sender's own part at zero bytes: the intercept of
//!   the median time to encode and hand a message to the channel;
//! * `latency` is the rest of the intercept, `a − overhead`: the
//!   receiver's wake-up and decoding's fixed cost.
//!
//! Medians, because the host is shared: a message that waited for the
//! scheduler says nothing about the link.

use std::time::{Duration, Instant};

use super::codec::{decode, encode};
use super::host::DEFAULT_CAPACITY;
use super::topology::Topology;
use super::transport::{Closed, Link, NodeLinks, channels};
use crate::csg::PrimId;
use crate::error::{Error, Result};
use crate::geom::{Ray, Vec3};
use crate::trace::{RayJob, RayKind};

/// Memory per node of the host topology: not a limit this host imposes
/// on one core's share of a scene, so a size at which every bundled scene
/// fits one node and the flow-control window is its largest.
pub const HOST_NODE_MEMORY: u64 = 1 << 30;

/// The topology's name in reports.
pub const HOST_TOPOLOGY: &str = "host-calibrated";

/// Rays per message: a lone ray to a batch of paths.
const SIZES: [usize; 4] = [1, 16, 64, 256];
/// Messages per size, after the warm-up ones, and the pause before each.
const ROUNDS: usize = 200;
const WARM_UP: usize = 20;
const PAUSE: Duration = Duration::from_micros(1000);

/// The medians measured for one message size.
#[derive(Clone, Copy, Debug)]
pub struct LinkSample {
    /// Encoded bytes of the message.
    pub bytes: usize,
    /// Median time from the start of encoding to the end of decoding.
    pub one_way_seconds: f64,
    /// Median time to encode the message and hand it to the channel.
    pub send_seconds: f64,
}

/// The measured link costs of this host.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Seconds from sent to received, beyond the sender's part.
    pub latency: f64,
    /// Seconds the sender spends per message, beyond its bytes.
    pub overhead: f64,
    /// Bytes per second through the whole link (encode, move, decode).
    pub bandwidth: f64,
    pub samples: Vec<LinkSample>,
}

impl Calibration {
    /// The host topology of dimension `d`: these link costs, nodes as
    /// fast as a host core, `HOST_NODE_MEMORY` each.
    pub fn topology(&self, d: u32) -> Topology {
        Topology {
            name: HOST_TOPOLOGY.into(),
            dimension: d,
            node_memory: HOST_NODE_MEMORY,
            link_bandwidth: self.bandwidth,
            link_latency: self.latency,
            message_overhead: self.overhead,
            compute_speed: 1.0,
        }
    }

    /// One line: the three costs and what they came from.
    pub fn describe(&self) -> String {
        let (lo, hi) = (
            self.samples.first().map_or(0, |s| s.bytes),
            self.samples.last().map_or(0, |s| s.bytes),
        );
        format!(
            "latency {:.1} us, overhead {:.1} us, bandwidth {:.0} MB/s, compute speed 1 \
             (messages of {lo} to {hi} bytes to an idle node over the in-process channels)",
            self.latency * 1e6,
            self.overhead * 1e6,
            self.bandwidth / 1e6
        )
    }
}

/// The dimensions this host has cores for: every d with 2^d node threads
/// no more than `cores`.
pub fn host_dimensions(cores: usize) -> Vec<u32> {
    (0..=super::topology::MAX_DIMENSION)
        .filter(|&d| 1usize << d <= cores.max(1))
        .collect()
}

/// Measures this host's link costs (about a second). Fails
/// (`Error::Render`) only if the OS refuses the receiving thread: a
/// calibration without it would measure nothing.
pub fn calibrate() -> Result<Calibration> {
    // The host end stays alive: a node whose host link is gone stops.
    let (_host, mut nodes) = channels(1, DEFAULT_CAPACITY);
    let mut receiving = nodes.pop().expect("a 1-cube has two nodes");
    let mut sending = nodes.pop().expect("a 1-cube has two nodes");
    let base = Instant::now();
    let (sent, received) = std::thread::scope(|s| -> Result<_> {
        let receiver = std::thread::Builder::new()
            .name("hypercast-calibrate".into())
            .spawn_scoped(s, move || receive_all(&mut receiving, base))
            .map_err(|e| {
                Error::Render(format!(
                    "cannot start the link calibration's receiving thread: {e}"
                ))
            })?;
        let mut sent: Vec<(usize, f64)> = Vec::new();
        for &n in &SIZES {
            let jobs: Vec<RayJob> = (0..n).map(ray_job).collect();
            for _ in 0..WARM_UP + ROUNDS {
                // Long enough for the receiver to have parked, as an idle
                // node has.
                std::thread::sleep(PAUSE);
                let t0 = base.elapsed();
                let Ok(msg) = encode(&(t0.as_nanos() as u64, &jobs)) else {
                    break;
                };
                let bytes = msg.len();
                if send(&mut sending, msg).is_err() {
                    break;
                }
                sent.push((bytes, (base.elapsed() - t0).as_secs_f64()));
            }
        }
        // An empty message ends the receiver.
        let _ = send(&mut sending, Vec::new());
        Ok((sent, receiver.join().unwrap_or_default()))
    })?;
    Ok(fit(samples(&sent, &received)))
}

/// Per size, the medians of the measurements after the warm-up ones.
fn samples(sent: &[(usize, f64)], received: &[(usize, f64)]) -> Vec<LinkSample> {
    let mut sizes: Vec<usize> = sent.iter().map(|s| s.0).collect();
    sizes.dedup();
    sizes
        .into_iter()
        .filter_map(|bytes| {
            let of = |v: &[(usize, f64)]| -> Vec<f64> {
                v.iter()
                    .filter(|m| m.0 == bytes)
                    .skip(WARM_UP)
                    .map(|m| m.1)
                    .collect()
            };
            let (mut s, mut r) = (of(sent), of(received));
            (!s.is_empty() && !r.is_empty()).then(|| LinkSample {
                bytes,
                one_way_seconds: median(&mut r),
                send_seconds: median(&mut s),
            })
        })
        .collect()
}

/// The link costs from the samples (see the module's comment).
fn fit(samples: Vec<LinkSample>) -> Calibration {
    let bytes: Vec<f64> = samples.iter().map(|s| s.bytes as f64).collect();
    let one_way: Vec<f64> = samples.iter().map(|s| s.one_way_seconds).collect();
    let send: Vec<f64> = samples.iter().map(|s| s.send_seconds).collect();
    let (a, b) = line(&bytes, &one_way);
    let (a_send, _) = line(&bytes, &send);
    let overhead = a_send.max(0.0);
    // A pipe whose cost per byte is below what the samples resolve
    // (a slope of zero or less) is as fast as the topology allows: a
    // terabyte per second.
    let bandwidth = if b > 1e-12 { 1.0 / b } else { 1e12 };
    Calibration {
        latency: (a - overhead).max(0.0),
        overhead,
        bandwidth,
        samples,
    }
}

/// Least-squares line `y = a + b·x`.
fn line(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    if x.is_empty() {
        return (0.0, 0.0);
    }
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxx: f64 = x.iter().map(|v| (v - mx) * (v - mx)).sum();
    let sxy: f64 = x.iter().zip(y).map(|(u, v)| (u - mx) * (v - my)).sum();
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    (my - b * mx, b)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// A ray as a path's stack holds it.
fn ray_job(i: usize) -> RayJob {
    let f = i as f64;
    RayJob {
        ray: Ray::new(Vec3::new(f, 0.5, -2.0), Vec3::new(0.1, 0.2, 0.97)),
        kind: RayKind::Reflected,
        pixel: i as u32,
        depth: 2,
        weight: [0.5, 0.25, 0.125],
        t_max: f64::INFINITY,
        leaving: Some(PrimId(i as u32)),
        light: None,
    }
}

/// The receiving end: per message, its bytes and the time from the start
/// of its encoding to the end of its decoding, until an empty message.
fn receive_all(links: &mut dyn NodeLinks, base: Instant) -> Vec<(usize, f64)> {
    let mut got = Vec::new();
    while let Some(bytes) = receive(links) {
        if bytes.is_empty() {
            break;
        }
        let Ok((t0, _jobs)) = decode::<(u64, Vec<RayJob>)>(&bytes) else {
            break;
        };
        let one_way = base.elapsed().as_nanos() as f64 - t0 as f64;
        got.push((bytes.len(), one_way * 1e-9));
    }
    got
}

/// Receives as an idle node does: blocked in `wait` until a message is
/// there.
fn receive(links: &mut dyn NodeLinks) -> Option<Vec<u8>> {
    loop {
        match links.try_recv() {
            Ok(Some(bytes)) => return Some(bytes),
            Ok(None) => links.wait(&[]),
            Err(_) => return None,
        }
    }
}

fn send(links: &mut dyn NodeLinks, mut bytes: Vec<u8>) -> Result<(), Closed> {
    loop {
        match links.try_send(Link::Dim(0), bytes)? {
            None => return Ok(()),
            Some(back) => {
                bytes = back;
                links.wait(&[Link::Dim(0)]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_dimensions_are_those_with_a_core_per_node() {
        assert_eq!(host_dimensions(1), vec![0]);
        assert_eq!(host_dimensions(2), vec![0, 1]);
        assert_eq!(host_dimensions(7), vec![0, 1, 2]);
        assert_eq!(host_dimensions(8), vec![0, 1, 2, 3]);
    }

    #[test]
    fn the_fit_splits_the_intercept_between_sender_and_link() {
        // One-way 10 us + 1 ns per byte; the sender's part 3 us + 0.5 ns.
        let samples = [100usize, 1000, 10000]
            .iter()
            .map(|&b| LinkSample {
                bytes: b,
                one_way_seconds: 10e-6 + b as f64 * 1e-9,
                send_seconds: 3e-6 + b as f64 * 0.5e-9,
            })
            .collect();
        let c = fit(samples);
        assert!((c.overhead - 3e-6).abs() < 1e-12, "{c:?}");
        assert!((c.latency - 7e-6).abs() < 1e-12, "{c:?}");
        assert!((c.bandwidth - 1e9).abs() < 1.0, "{c:?}");
        let t = c.topology(1);
        assert_eq!((t.nodes(), t.compute_speed), (2, 1.0));
    }

    #[test]
    fn calibration_measures_positive_finite_costs() {
        let c = calibrate().unwrap();
        assert_eq!(c.samples.len(), SIZES.len(), "{c:?}");
        assert!(c.samples.windows(2).all(|w| w[0].bytes < w[1].bytes));
        for v in [c.latency, c.overhead] {
            assert!(v.is_finite() && v >= 0.0, "{c:?}");
        }
        assert!(c.bandwidth.is_finite() && c.bandwidth > 0.0, "{c:?}");
    }
}
