//! The emulated hypercube multicomputer of the paper's closing plan: the
//! topology of the modelled machine (`topology`) and its routing. Reads the
//! cell structure and the shading rules; owns nodes, links and messages.

pub mod routing;
pub mod topology;

pub use topology::{Topology, parse_size};
