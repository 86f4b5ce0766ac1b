//! Resampling into the equal-area domain and the warp that places lights in it.
//!
//! Input: an [`EnvMap`](crate::envmap::EnvMap). Output: a [`DomainImage`] (equal-area square),
//! a [`Distribution2D`] over its luminance, and the fixed progressive point set pushed through that
//! warp — the DESIGN.md stages between decoding and light power.

pub mod distribution;
pub mod pointset;
pub mod resample;

pub use distribution::Distribution2D;
pub use pointset::{N_MAX, progressive_points};
pub use resample::{DomainImage, Resampler};
