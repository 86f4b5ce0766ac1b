//! The sampling domain and the warp that places lights in it.
//!
//! Input: an [`EnvMap`](crate::envmap::EnvMap). Output: a [`DomainImage`] (equal-area square),
//! a [`Distribution2D`] over its luminance, and the fixed progressive point set pushed through that
//! warp — the DESIGN.md stages between decoding and light power.

pub mod distribution;
pub mod domain;
pub mod mapping;
pub mod pointset;

pub use distribution::Distribution2D;
pub use domain::{DomainImage, Resampler};
pub use mapping::Domain;
pub use pointset::{N_MAX, progressive_points};

/// Helpers for the unit tests of the sampling stage.
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
