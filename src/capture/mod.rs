//! Frame sources; the capture stage of DESIGN.md.
//!
//! A frame source hands the pipeline one linear-RGB lat-long [`crate::envmap::EnvMap`] per
//! capture tick. [`synthetic`] is the built-in dynamic sky that `vemlight serve` uses by default,
//! so the daemon runs with no camera and no data.

pub mod synthetic;
