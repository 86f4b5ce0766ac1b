//! Measurement: per-frame speed of each method (and, later, accuracy and stability charts).
//!
//! Figures are medians over interleaved rounds, reported with their ratio to a baseline measured in
//! the same process, because these machines are noisy.

pub mod speed;
