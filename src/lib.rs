//! hypercast: CSG ray tracing with the space subdivision of Priol, Arnaldi
//! and Bouatouch (INRIA RR-0613, 1987) on an emulated hypercube
//! multicomputer. See `ARCHITECTURE.md` for the map.

pub mod csg;
pub mod error;
pub mod geom;
pub mod scene;

pub use error::{Error, Result};
