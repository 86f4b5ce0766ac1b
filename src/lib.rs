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
pub mod envmap;
pub mod eval;
pub mod lights;
pub mod lightset;
pub mod metrics;
#[cfg(feature = "render")]
pub mod render;
pub mod sampling;
pub mod server;
pub mod sky;
pub mod temporal;
