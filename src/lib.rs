//! vemlight: HDR video environment maps → small, temporally stable sets of directional lights.
//!
//! Stages (DESIGN.md): [`capture`] produces frames, [`envmap`] decodes and projects, [`sampling`]
//! resamples into the equal-area domain and warps the fixed progressive points, [`lights`] computes
//! light power and direction, [`temporal`] filters them over frames, [`lightset`] is the wire
//! document, [`server`] streams it; [`eval`] measures; [`render`] (feature `render`) is the wgpu
//! client that draws a scene lit by the lights.

// Loops over RGB channels and SIMD lanes read more clearly with an index.
#![allow(clippy::needless_range_loop)]

pub mod capture;
pub mod cli;
pub mod daemon;
pub mod envmap;
pub mod eval;
pub mod lights;
pub mod lightset;
pub mod mapping;
pub mod metrics;
#[cfg(feature = "render")]
pub mod render;
pub mod sampling;
pub mod server;
pub mod sky;
pub mod temporal;

/// Helpers for the unit tests.
#[cfg(test)]
pub(crate) mod test_util {
    /// A small deterministic generator (64-bit LCG → uniform in [0, 1)), so tests need no crate.
    pub fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64) / ((1u64 << 53) as f64)
    }
}
