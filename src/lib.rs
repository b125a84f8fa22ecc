//! hypercast: CSG ray tracing with the space subdivision of Priol, Arnaldi
//! and Bouatouch (INRIA RR-0613, 1987) on an emulated hypercube
//! multicomputer. See `ARCHITECTURE.md` for the map.

pub mod csg;
pub mod error;
pub mod geom;
pub mod input;
pub mod scene;

pub use error::{Error, Result};
pub mod cells;
pub mod cli;
pub mod cmd;
pub mod r#gen;
pub mod machine;
pub mod quality;
pub mod reference;
pub mod render;
pub mod report;
pub mod trace;
