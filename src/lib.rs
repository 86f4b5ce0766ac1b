//! vemlight: HDR video environment maps → small, temporally stable sets of directional lights.
//!
//! Stages (DESIGN.md): [`capture`] produces frames, [`envmap`] decodes and projects, [`sampling`]
//! resamples into the equal-area domain and warps the fixed progressive points, [`lights`] computes
//! light power and direction, [`lightset`] is the wire document.

// Loops over RGB channels and SIMD lanes read more clearly with an index.
#![allow(clippy::needless_range_loop)]

pub mod capture;
pub mod envmap;
pub mod eval;
pub mod lights;
pub mod lightset;
pub mod metrics;
pub mod sampling;
pub mod server;
pub mod temporal;
