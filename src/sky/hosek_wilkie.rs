//! The clear sky's radiance: the Hosek-Wilkie model (L. Hošek and A. Wilkie, "An Analytic Model
//! for Full Spectral Sky-Dome Radiance", ACM TOG 31(4), SIGGRAPH 2012), RGB datasets via the
//! `hw-skymodel` crate, in a separable form fast enough to evaluate per pixel per frame, and its
//! extension below the horizon.
//!
//! Speed: the formula factors as `L(θ, γ) = A(θ) · (G(γ) + I·√cos θ)` with
//! `A(θ) = R·(1 + a·e^{b/(cos θ + 0.01)})` (the paper's extended Perez formula; `R` the per-channel
//! radiance scale). In a lat-long map θ is constant along a row, so `A` and `A·I·√cos θ` are
//! per-row constants ([`HwModel::row_terms`]) and only `G(γ)` varies per pixel: it comes from a 1-D
//! table over `sin(γ/2) = √((1 − cos γ)/2)` for γ ≤ 90° and over `cos(γ/2) = √((1 + cos γ)/2)`
//! beyond (so no `acos` per pixel, and steps of < 0.08° in γ at both the sun and the anti-solar
//! point), rebuilt whenever the sun moves. This is exact in θ and cheaper than a bilinear (θ, γ)
//! table.
//!
//! Outside its range: the model is valid for sun elevations 0..90°. Its parameters are quintic
//! Béziers in `t = (elevation / 90°)^{1/3}`, whose slope is infinite at the horizon, so near the
//! horizon the elevation input is smoothed ([`model_elevation`]); below it the sky at the
//! horizon's parameters fades by e per [`TWILIGHT_FADE_DEG`] of depression ([`twilight_fade`]).

use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2, PI, TAU};

use glam::DVec3;
use hw_skymodel::rgb::{SkyParams, SkyState};

/// Below the horizon the model's sky fades by a factor e per this many degrees of sun depression:
/// a civil-twilight-like fade, slow enough that frames 1/30 s apart differ by < 2 % at the default
/// sun speed (the elevation then changes by ≤ 0.029° per frame, 1 % of the fade length).
const TWILIGHT_FADE_DEG: f64 = 3.0;
/// The model's parameters are quintic Béziers in `t = (elevation / 90°)^{1/3}`, whose slope in
/// elevation is infinite at the horizon: the sky would jump in the first frame after sunrise.
/// Below this elevation `t` continues linearly (C¹ at the knee) down to 0, which it reaches at 2×
/// this elevation below the horizon; above it the model gets the true elevation.
const MODEL_KNEE_DEG: f64 = 2.0;
/// Intervals of each half of the 1-D `G(γ)` table (γ ≤ 90° over sin(γ/2), γ ≥ 90° over cos(γ/2)).
const GAMMA_TABLE_N: usize = 1024;

/// The model's state for one turbidity, albedo and sun elevation.
pub(super) struct HwModel {
    turbidity: f32,
    albedo: f32,
    /// Input elevation, rad (NaN before the first [`HwModel::set`]).
    pub(super) elev: f64,
    /// Nine parameters `[A, B, C, D, E, F, G, H, I]` per channel, in the crate's order.
    params: [f32; 27],
    /// The per-channel radiance scale `R`.
    radiance: [f32; 3],
    /// `G(γ)` per channel: first half over u = sin(γ/2), second half over u = cos(γ/2).
    gamma_table: Vec<[f32; 3]>,
}

impl HwModel {
    /// A model for `turbidity` (1..=10) and ground `albedo` (0..=1), not yet set to an elevation.
    pub(super) fn new(turbidity: f64, albedo: f64) -> Self {
        HwModel {
            turbidity: turbidity as f32,
            albedo: albedo as f32,
            elev: f64::NAN,
            params: [0.0; 27],
            radiance: [0.0; 3],
            gamma_table: vec![[0.0; 3]; 2 * (GAMMA_TABLE_N + 1)],
        }
    }

    /// Rebuilds the model state for input elevation `elev` (radians, clamped to 0..=π/2) and its
    /// G(γ) table.
    pub(super) fn set(&mut self, elev: f64) {
        let elevation = (elev.clamp(0.0, FRAC_PI_2) as f32).clamp(0.0, std::f32::consts::FRAC_PI_2);
        let state = SkyState::new(&SkyParams {
            elevation,
            turbidity: self.turbidity,
            albedo: [self.albedo; 3],
        })
        .expect("sky-model inputs are clamped to their valid ranges");
        let (params, radiance) = state.raw();
        self.params = params;
        self.radiance = radiance;
        self.elev = elev;
        for (k, g) in self.gamma_table.iter_mut().enumerate() {
            // First half u = sin(γ/2), second half u = cos(γ/2), u ∈ [0, √½].
            let half = k / (GAMMA_TABLE_N + 1);
            let u = (k % (GAMMA_TABLE_N + 1)) as f64 / GAMMA_TABLE_N as f64 * FRAC_1_SQRT_2;
            let gamma = if half == 0 {
                2.0 * u.asin()
            } else {
                2.0 * u.acos()
            };
            for c in 0..3 {
                g[c] = hw_g(&params[9 * c..9 * c + 9], gamma) as f32;
            }
        }
    }

    /// ∫ L dω of the clear, unfaded model sky over the upper hemisphere for a sun in direction
    /// `sun`, by midpoint quadrature on `nt` × `np` (θ, φ) cells (exact cell solid angles).
    pub(super) fn clear_sky_integral(&self, sun: DVec3, nt: usize, np: usize) -> [f64; 3] {
        let mut sum = [0.0; 3];
        let dphi = TAU / np as f64;
        for a in 0..nt {
            let t0 = FRAC_PI_2 * a as f64 / nt as f64;
            let t1 = FRAC_PI_2 * (a + 1) as f64 / nt as f64;
            let theta = 0.5 * (t0 + t1);
            let d_omega = dphi * (t0.cos() - t1.cos());
            let (st, ct) = theta.sin_cos();
            let (fa, fac) = self.row_terms(ct);
            for b in 0..np {
                let phi = (b as f64 + 0.5) * dphi - PI;
                let d = DVec3::new(st * phi.sin(), ct, -st * phi.cos());
                let gamma = d.dot(sun).clamp(-1.0, 1.0).acos();
                for c in 0..3 {
                    let g = hw_g(&self.params[9 * c..9 * c + 9], gamma);
                    sum[c] += (fa[c] * g + fac[c]).max(0.0) * d_omega;
                }
            }
        }
        sum
    }

    /// `A(θ)` and `A(θ)·I·√cos θ` per channel for cos θ = `ct` (Hošek & Wilkie 2012).
    pub(super) fn row_terms(&self, ct: f64) -> ([f64; 3], [f64; 3]) {
        let ct = ct.abs();
        let mut a = [0.0; 3];
        let mut ac = [0.0; 3];
        for c in 0..3 {
            let p = &self.params[9 * c..9 * c + 9];
            let r = self.radiance[c] as f64;
            let big_a = r * (1.0 + p[0] as f64 * (p[1] as f64 / (ct + 0.01)).exp());
            a[c] = big_a;
            ac[c] = big_a * p[7] as f64 * ct.sqrt();
        }
        (a, ac)
    }

    /// `G(γ)` per channel from the table, given cos γ.
    #[inline]
    pub(super) fn g(&self, cos_gamma: f32) -> [f32; 3] {
        gamma_lookup(&self.gamma_table, cos_gamma)
    }
}

/// `G(γ)` per channel from the two-part table, given cos γ.
#[inline]
fn gamma_lookup(table: &[[f32; 3]], cos_gamma: f32) -> [f32; 3] {
    let scale = GAMMA_TABLE_N as f32 * std::f32::consts::SQRT_2;
    let base = if cos_gamma >= 0.0 {
        0
    } else {
        GAMMA_TABLE_N + 1
    };
    let u = ((1.0 - cos_gamma.abs()) * 0.5).clamp(0.0, 0.5).sqrt() * scale;
    let k = (u as usize).min(GAMMA_TABLE_N - 1);
    let f = u - k as f32;
    let table: &[[f32; 3]; 2 * (GAMMA_TABLE_N + 1)] =
        table.try_into().expect("G(γ) table has 2(N + 1) entries");
    let (g0, g1) = (table[base + k], table[base + k + 1]);
    [0, 1, 2].map(|c| g0[c] + f * (g1[c] - g0[c]))
}

/// Model input elevation (radians) for a true sun elevation (degrees): the true one above
/// [`MODEL_KNEE_DEG`], below it the Bézier parameter t = (e/90°)^{1/3} continued linearly.
pub(super) fn model_elevation(elev_deg: f64) -> f64 {
    let t = if elev_deg >= MODEL_KNEE_DEG {
        (elev_deg.min(90.0) / 90.0).cbrt()
    } else {
        let tk = (MODEL_KNEE_DEG / 90.0).cbrt();
        let slope = tk / (3.0 * MODEL_KNEE_DEG);
        (tk + slope * (elev_deg - MODEL_KNEE_DEG)).max(0.0)
    };
    FRAC_PI_2 * t * t * t
}

/// The factor on the model's sky for a true sun elevation (degrees): 1 by day, e^{elev/3°} below
/// the horizon (the model, clamped to sunrise, fades out as the sun sinks).
pub(super) fn twilight_fade(elev_deg: f64) -> f32 {
    (elev_deg.min(0.0) / TWILIGHT_FADE_DEG).exp() as f32
}

/// `G(γ) = C + D e^{Eγ} + F cos²γ + G χ(H, γ)` of the Hošek-Wilkie model for one channel's nine
/// parameters `p = [A, B, C, D, E, F, G, H, I]` (in the order of the `hw-skymodel` crate's state),
/// with `χ(H, γ) = (1 + cos²γ) / (1 + H² − 2H cos γ)^{3/2}`.
fn hw_g(p: &[f32], gamma: f64) -> f64 {
    let p = |k: usize| p[k] as f64;
    let cg = gamma.cos();
    let chi = (1.0 + cg * cg) / (1.0 + p(8) * p(8) - 2.0 * p(8) * cg).powf(1.5);
    p(2) + p(3) * (p(4) * gamma).exp() + p(5) * cg * cg + p(6) * chi
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::testing::sky;

    #[test]
    fn separable_model_matches_hw_skymodel() {
        let s = sky(64, |c| c.clouds = 0.0);
        for elev_deg in [0.0f64, 3.0, 20.0, 60.0, 89.0] {
            let mut s2 = sky(64, |c| c.clouds = 0.0);
            s2.model.set(elev_deg.to_radians());
            let state = SkyState::new(&SkyParams {
                elevation: elev_deg.to_radians() as f32,
                turbidity: s.config().turbidity as f32,
                albedo: [s.config().ground_albedo as f32; 3],
            })
            .unwrap();
            for theta_deg in [0.0f64, 30.0, 60.0, 85.0, 89.9] {
                let (fa, fac) = s2.model.row_terms(theta_deg.to_radians().cos());
                for gamma_deg in [0.3f64, 5.0, 45.0, 120.0, 179.0] {
                    let gamma = gamma_deg.to_radians();
                    let ch = [
                        hw_skymodel::rgb::Channel::R,
                        hw_skymodel::rgb::Channel::G,
                        hw_skymodel::rgb::Channel::B,
                    ];
                    for (c, channel) in ch.into_iter().enumerate() {
                        let want =
                            state.radiance(theta_deg.to_radians() as f32, gamma as f32, channel);
                        let got = fa[c] * hw_g(&s2.model.params[9 * c..9 * c + 9], gamma) + fac[c];
                        let err = (got - want as f64).abs() / (want.abs() as f64).max(1e-3);
                        assert!(
                            err < 1e-3,
                            "e {elev_deg} θ {theta_deg} γ {gamma_deg}: {got} vs {want}"
                        );
                        // And the per-pixel table lookup.
                        let g = gamma_lookup(&s2.model.gamma_table, gamma.cos() as f32)[c] as f64;
                        let got = fa[c] * g + fac[c];
                        let err = (got - want as f64).abs() / (want.abs() as f64).max(1e-3);
                        assert!(
                            err < 2e-3,
                            "table e {elev_deg} θ {theta_deg} γ {gamma_deg}: {got} vs {want}"
                        );
                    }
                }
            }
        }
    }
}
