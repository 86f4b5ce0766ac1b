//! vemlight: HDR video environment maps → small, temporally stable sets of directional lights.
//!
//! Stages (DESIGN.md): [`envmap`] decodes and projects, [`sampling`] resamples into the equal-area
//! domain and warps the fixed progressive points, [`lights`] computes light power and direction,
//! [`lightset`] is the wire document; [`render`] (feature `render`) is the wgpu client that draws a
//! scene lit by them.

pub mod envmap;
pub mod lights;
pub mod lightset;
#[cfg(feature = "render")]
pub mod render;
pub mod sampling;
