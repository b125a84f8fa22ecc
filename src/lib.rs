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

/// Helpers of the unit tests of more than one module.
#[cfg(test)]
mod testing {
    /// Numbers uniform in [0, 1) from `seed` (a linear congruential
    /// generator): the random rays and scenes of unit tests.
    pub(crate) fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }
}
