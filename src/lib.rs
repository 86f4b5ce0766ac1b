//! vemlight: HDR video environment maps → small, temporally stable sets of directional lights.
//!
//! The modules in pipeline order (DESIGN.md, "The pipeline"; each imports only modules above it):
//! [`mapping`] (the equal-area square ↔ sphere maps, a leaf), [`envmap`] (decoding and
//! projections), [`sky`] (the synthetic sky model), [`capture`] (frame sources), [`sampling`]
//! (resampling into the domain square, the warp, the progressive points), [`lights`] (light
//! power and direction), [`temporal`] (filtering over frames), [`lightset`] (the wire document),
//! [`daemon`] (the pipeline threads and the hub), [`publish`] (the sets through a NATS
//! broker), [`server`] (HTTP and WebSocket); [`eval`]
//! measures; [`render`] (feature `render`) is the wgpu client; [`cli`] is the command line.

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
pub mod publish;
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
