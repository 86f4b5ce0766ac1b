//! The lat-long pixel grid the sky is rendered on: per-row and per-column tables built once per
//! resolution, so that a frame needs no trigonometry per pixel.
//!
//! Pixel (i, j) of a w × h map has its centre at zenith angle θ = π(j + ½)/h and azimuth
//! φ = 2π((i + ½)/w − ½), direction (sin θ sin φ, cos θ, −sin θ cos φ) (DESIGN.md's lat-long
//! convention, the one [`crate::envmap::Projection::LatLong`] decodes). Each row also holds the
//! clear-sky model's per-row terms ([`HwModel::row_terms`]), refreshed when the sun moves.

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use glam::DVec3;

use super::hosek_wilkie::HwModel;

/// Per-row constants of the current resolution and model.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Row {
    /// sin θ and cos θ of the row's pixel centres.
    pub(super) st: f32,
    pub(super) ct: f32,
    /// Solid angle of one pixel of the row, sr.
    pub(super) d_omega: f64,
    /// The pixel centre is above the horizon.
    pub(super) sky: bool,
    /// `A(θ)` per channel.
    pub(super) a: [f32; 3],
    /// `A(θ)·I·√cos θ` per channel.
    pub(super) ac: [f32; 3],
}

/// The tables of one resolution.
#[derive(Default)]
pub(super) struct Grid {
    /// (width, height) the tables were built for; (0, 0) before the first frame.
    pub(super) res: (usize, usize),
    pub(super) rows: Vec<Row>,
    /// sin φ and cos φ of each column's pixel centres.
    pub(super) col_sin: Vec<f32>,
    pub(super) col_cos: Vec<f32>,
}

impl Grid {
    /// Rebuilds the tables for a w × h map and `model`.
    pub(super) fn build(&mut self, w: usize, h: usize, model: &HwModel) {
        self.res = (w, h);
        self.col_sin.clear();
        self.col_cos.clear();
        for i in 0..w {
            let phi = TAU * ((i as f64 + 0.5) / w as f64 - 0.5);
            self.col_sin.push(phi.sin() as f32);
            self.col_cos.push(phi.cos() as f32);
        }
        self.rows.clear();
        for j in 0..h {
            let theta = PI * (j as f64 + 0.5) / h as f64;
            let t0 = PI * j as f64 / h as f64;
            let t1 = PI * (j + 1) as f64 / h as f64;
            self.rows.push(Row {
                st: theta.sin() as f32,
                ct: theta.cos() as f32,
                d_omega: TAU / w as f64 * (t0.cos() - t1.cos()),
                sky: theta < FRAC_PI_2,
                a: [0.0; 3],
                ac: [0.0; 3],
            });
        }
        self.update_rows(model);
    }

    /// Refreshes the rows' model terms after the model changed.
    pub(super) fn update_rows(&mut self, model: &HwModel) {
        for row in &mut self.rows {
            let (a, ac) = model.row_terms(row.ct as f64);
            row.a = a.map(|x| x as f32);
            row.ac = ac.map(|x| x as f32);
        }
    }
}

/// DESIGN.md lat-long direction for zenith angle θ and azimuth φ.
pub(super) fn lat_long_dir(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * sp, ct, -st * cp)
}
