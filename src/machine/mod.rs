//! The emulated hypercube multicomputer of the paper's closing plan (section
//! 10: the cell structure distributed over an iPSC-D5 of 32 nodes with 4.5
//! MB each). Owns nodes, links, messages and the modelled machine's time;
//! reads the cell structure (`cells`) and the shading rules (`trace`).
//!
//! * `topology`: the modelled machine (dimension, memory, links, speed);
//! * `calibrate`: this host as a topology, its link costs measured;
//! * `routing`: e-cube routing and Gray codes;
//! * `mapping`: which node owns which super cell (cost pre-pass, Gray codes);
//! * `replicas`: which other nodes' super cells a node holds copies of;
//! * `message` and `codec`: what travels, and its bytes (bincode 2);
//! * `transport`: links as a small trait, with in-process channels;
//! * `node`: a node's loop (tracing, routing, flow control, memory, clock);
//! * `ticks`: the nodes' cheap stopwatch for that clock's bookkeeping;
//! * `host`: the coordinator (loading, credits, exact termination).

pub mod calibrate;
pub mod codec;
pub mod host;
pub mod mapping;
pub mod message;
pub mod node;
pub mod replicas;
pub mod routing;
pub mod ticks;
pub mod topology;
pub mod transport;

pub use host::{
    DEFAULT_CAPACITY, MAX_CAPACITY, MachineOptions, MachineStats, render, render_adaptive,
    stack_bound,
};
pub use mapping::Mapping;
pub use replicas::Replicas;
pub use topology::{Topology, parse_size};

/// The name a command-line option takes for `v`, as clap derives it from
/// the variant, so that reports name a choice as the user types it.
fn value_name(v: impl clap::ValueEnum) -> String {
    v.to_possible_value()
        .expect("no variant of the machine's options is skipped")
        .get_name()
        .to_owned()
}

/// The largest of `v` against their mean, the imbalance of per-node loads
/// (busy time, estimated or counted work); 1 for none or all zero.
pub fn max_over_mean(v: impl IntoIterator<Item = f64>) -> f64 {
    let (mut n, mut sum, mut max) = (0usize, 0.0, 0.0f64);
    for x in v {
        n += 1;
        sum += x;
        max = max.max(x);
    }
    if n == 0 || sum <= 0.0 {
        1.0
    } else {
        max / (sum / n as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    /// Reports (`--stats`, `scale`'s plot titles) name each choice as the
    /// command line takes it, and `scale` passes it back to `render`.
    #[test]
    fn choices_are_named_as_the_command_line_takes_them() {
        assert_eq!(Mapping::EqualArea.name(), "equal-area");
        assert_eq!(Replicas::Whole.name(), "whole");
        for m in Mapping::value_variants() {
            assert_eq!(Mapping::from_str(&m.name(), false), Ok(*m));
        }
        for r in Replicas::value_variants() {
            assert_eq!(Replicas::from_str(&r.name(), false), Ok(*r));
        }
    }
}
