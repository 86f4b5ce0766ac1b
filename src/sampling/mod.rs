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
