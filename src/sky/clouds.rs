//! The cloud layer: a drifting cover that greys the sky and dims the sun.
//!
//! A periodic fBm value-noise texture, thresholded at the quantile that makes the covered fraction
//! the configured one, mapped onto the dome azimuthal-equidistantly (radius ∝ zenith angle: no seam
//! and no pinch at the zenith) and resampled once per resolution into a lat-long cover map
//! ([`Clouds::resample`]). The drift is a rotation about +Y, so per frame it is a fractional column
//! shift of that map (one lerp per pixel, no trig). Cloud radiance is grey, [`CLOUD_GAIN`] × the
//! clear sky's mean luminance; the sun sees a blurred copy of the cover, so that a cloud edge
//! crossing it dims it over about a second rather than in one frame (temporal continuity).

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use glam::DVec3;

use super::grid::Grid;

/// Side of the periodic cloud texture, texels (a power of two: wrapping is a mask).
const CLOUD_TEX: usize = 256;
/// Value-noise lattice cells across the texture for the first fBm octave.
const CLOUD_BASE_CELLS: usize = 6;
const CLOUD_OCTAVES: usize = 5;
/// Texture tiles from the zenith to the horizon: the dome is mapped azimuthal-equidistantly
/// (radius ∝ zenith angle), which has no seam and no pinch at the zenith, and turns the drift into
/// a plain rotation of the texture coordinates.
const CLOUD_DOME_TILES: f64 = 1.0;
/// Half-width of the cloud edge in noise units (smoothstep around the cover threshold).
const CLOUD_EDGE: f32 = 0.05;
/// Cloud radiance = this × the clear sky's mean luminance (grey): sunlit cloud tops are brighter
/// than the average blue sky.
pub(super) const CLOUD_GAIN: f32 = 1.2;
/// Box-blur radius (texels, applied twice) of the cover the sun sees: a soft edge, so that a cloud
/// crossing the sun dims it over ~1 s rather than in one frame (temporal continuity).
const CLOUD_SOFT_RADIUS: usize = 10;

/// The cloud cover texture and its drift.
pub(super) struct Clouds {
    /// Cover (0..1) per texel of the CLOUD_TEX² texture; empty for a clear sky.
    cover: Vec<f32>,
    /// `cover` blurred, for the sun's dimming; empty for a clear sky.
    soft: Vec<f32>,
    /// `cover` resampled to the sky rows of the current resolution (lat-long, no drift).
    lat_long: Vec<f32>,
    /// Azimuthal drift, degrees per second.
    drift_deg_per_s: f64,
}

impl Clouds {
    /// No clouds.
    pub(super) fn clear(drift_deg_per_s: f64) -> Self {
        Clouds {
            cover: Vec::new(),
            soft: Vec::new(),
            lat_long: Vec::new(),
            drift_deg_per_s,
        }
    }

    /// Periodic fBm value noise → cover via a threshold at the (1 − `fraction`) quantile, so the
    /// cover fraction of the texture is `fraction` (in 0..=1); plus a blurred copy for the sun's
    /// dimming.
    pub(super) fn new(fraction: f64, drift_deg_per_s: f64) -> Self {
        let n = CLOUD_TEX;
        let mut noise = vec![0.0f32; n * n];
        for ty in 0..n {
            for tx in 0..n {
                let (u, v) = (tx as f64 / n as f64, ty as f64 / n as f64);
                let (mut sum, mut amp, mut norm) = (0.0, 1.0, 0.0);
                for o in 0..CLOUD_OCTAVES {
                    let cells = CLOUD_BASE_CELLS << o;
                    sum += amp * value_noise(u * cells as f64, v * cells as f64, cells, o as u32);
                    norm += amp;
                    amp *= 0.5;
                }
                noise[ty * n + tx] = (sum / norm) as f32;
            }
        }
        let cover = if fraction >= 1.0 {
            vec![1.0; n * n]
        } else {
            let mut sorted = noise.clone();
            let k = (((1.0 - fraction) * (n * n) as f64) as usize).min(n * n - 1);
            let (_, thr, _) = sorted.select_nth_unstable_by(k, f32::total_cmp);
            let thr = *thr;
            noise
                .iter()
                .map(|&v| smoothstep(thr - CLOUD_EDGE, thr + CLOUD_EDGE, v))
                .collect()
        };
        let mut soft = cover.clone();
        let mut tmp = vec![0.0f32; n * n];
        for _ in 0..2 {
            box_blur_wrap(&soft, &mut tmp, n, CLOUD_SOFT_RADIUS, true);
            box_blur_wrap(&tmp, &mut soft, n, CLOUD_SOFT_RADIUS, false);
        }
        Clouds {
            cover,
            soft,
            lat_long: Vec::new(),
            drift_deg_per_s,
        }
    }

    /// Whether there are no clouds at all.
    pub(super) fn is_clear(&self) -> bool {
        self.cover.is_empty()
    }

    /// Resamples the cover into the lat-long sky rows of `grid` (after it changed resolution).
    pub(super) fn resample(&mut self, grid: &Grid) {
        self.lat_long.clear();
        if self.is_clear() {
            return;
        }
        let h = grid.res.1;
        let cloud_scale = CLOUD_DOME_TILES * CLOUD_TEX as f64 / FRAC_PI_2;
        for (j, _) in grid.rows.iter().enumerate().take_while(|(_, r)| r.sky) {
            // The texture radius of the row's zenith angle.
            let theta = PI * (j as f64 + 0.5) / h as f64;
            let r = (theta * cloud_scale) as f32;
            for (&sp, &cp) in grid.col_sin.iter().zip(&grid.col_cos) {
                let (x, y) = (r * cp, r * sp);
                self.lat_long.push(bilinear_wrap(&self.cover, x, y));
            }
        }
    }

    /// Azimuth offset of the cloud layer at time t, radians.
    pub(super) fn offset(&self, t: f64) -> f64 {
        (self.drift_deg_per_s.to_radians() * t).rem_euclid(TAU)
    }

    /// The blurred cover the sun sees in direction `dir` at time t (0 without clouds).
    pub(super) fn sun_cover(&self, dir: DVec3, t: f64) -> f64 {
        self.cover_at(&self.soft, dir, t)
    }

    /// Cover of `tex` seen in direction `dir` at time t (0 without clouds).
    fn cover_at(&self, tex: &[f32], dir: DVec3, t: f64) -> f64 {
        if tex.is_empty() {
            return 0.0;
        }
        let theta = dir.y.clamp(-1.0, 1.0).acos();
        let phi = dir.x.atan2(-dir.z) + self.offset(t);
        let r = theta * CLOUD_DOME_TILES * CLOUD_TEX as f64 / FRAC_PI_2;
        let (x, y) = ((r * phi.cos()) as f32, (r * phi.sin()) as f32);
        bilinear_wrap(tex, x, y) as f64
    }

    /// Blends sky row `j` (`px`, of the resolution last [resampled](Self::resample)) toward the
    /// cloud radiance `grey` by the cover drifted by `shift` (whole columns, then the fraction of
    /// the next). Nothing without clouds.
    pub(super) fn overlay_row(
        &self,
        j: usize,
        shift: (usize, f32),
        grey: [f32; 3],
        px: &mut [[f32; 3]],
    ) {
        if self.is_clear() {
            return;
        }
        let w = px.len();
        let (n0, fs) = shift;
        let cover = &self.lat_long[j * w..(j + 1) * w];
        for (i, p) in px.iter_mut().enumerate() {
            let i0 = if i + n0 < w { i + n0 } else { i + n0 - w };
            let i1 = if i0 + 1 < w { i0 + 1 } else { 0 };
            let k = cover[i0] + fs * (cover[i1] - cover[i0]);
            for c in 0..3 {
                p[c] += k * (grey[c] - p[c]);
            }
        }
    }
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Bilinear lookup in the periodic CLOUD_TEX² texture at texel coordinates (x, y), |x|, |y| ≤ 2
/// tiles.
#[inline]
fn bilinear_wrap(tex: &[f32], x: f32, y: f32) -> f32 {
    const N: usize = CLOUD_TEX;
    const MASK: usize = N - 1;
    const OFFSET: f32 = (4 * N) as f32;
    // A fixed-size view: the masked indices below are provably in bounds (no checks per load).
    let tex: &[f32; N * N] = tex.try_into().expect("cloud texture is CLOUD_TEX²");
    // The offset makes truncation a floor (f32::floor is a library call on baseline x86-64).
    let (xo, yo) = (x + OFFSET, y + OFFSET);
    let (x0, y0) = (xo as usize, yo as usize);
    let (ax, ay) = (xo - x0 as f32, yo - y0 as f32);
    let (x0u, x1u) = (x0 & MASK, (x0 + 1) & MASK);
    let (y0u, y1u) = ((y0 & MASK) * N, ((y0 + 1) & MASK) * N);
    let (t0, t1) = (tex[y0u + x0u], tex[y0u + x1u]);
    let (b0, b1) = (tex[y1u + x0u], tex[y1u + x1u]);
    let top = t0 + ax * (t1 - t0);
    let bot = b0 + ax * (b1 - b0);
    top + ay * (bot - top)
}

/// Hash of an integer lattice point to [0, 1).
fn lattice(x: usize, y: usize, seed: u32) -> f64 {
    let mut v = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ seed.wrapping_mul(0xcb1a_b31f)
        ^ 0x9e37_79b9;
    v ^= v >> 16;
    v = v.wrapping_mul(0x7feb_352d);
    v ^= v >> 15;
    v = v.wrapping_mul(0x846c_a68b);
    v ^= v >> 16;
    v as f64 / 4_294_967_296.0
}

/// Value noise with a quintic fade, periodic with `period` cells in x and y.
fn value_noise(x: f64, y: f64, period: usize, seed: u32) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (x - fx, y - fy);
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (fade(tx), fade(ty));
    let xi = (fx as i64).rem_euclid(period as i64) as usize;
    let yi = (fy as i64).rem_euclid(period as i64) as usize;
    let (xj, yj) = ((xi + 1) % period, (yi + 1) % period);
    let v00 = lattice(xi, yi, seed);
    let v10 = lattice(xj, yi, seed);
    let v01 = lattice(xi, yj, seed);
    let v11 = lattice(xj, yj, seed);
    let top = v00 + sx * (v10 - v00);
    let bot = v01 + sx * (v11 - v01);
    top + sy * (bot - top)
}

/// One periodic box-blur pass of radius `r` along x (`horizontal`) or y of an n×n texture.
fn box_blur_wrap(src: &[f32], dst: &mut [f32], n: usize, r: usize, horizontal: bool) {
    let norm = 1.0 / (2 * r + 1) as f32;
    for a in 0..n {
        for b in 0..n {
            let mut s = 0.0;
            for k in 0..=2 * r {
                let c = (b + n + k - r) % n;
                s += if horizontal {
                    src[a * n + c]
                } else {
                    src[c * n + a]
                };
            }
            if horizontal {
                dst[a * n + b] = s * norm;
            } else {
                dst[b * n + a] = s * norm;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::sky::testing::sky;

    #[test]
    fn clouds_cover_the_configured_fraction_and_drift() {
        let s = sky(64, |c| c.clouds = 0.3);
        let cover = &s.clouds.cover;
        let covered = cover.iter().map(|&v| v as f64).sum::<f64>() / cover.len() as f64;
        assert!((covered - 0.3).abs() < 0.03, "{covered}");
        let mut s = sky(128, |c| c.switch_light = None);
        let a = s.render(10.0);
        let b = s.render(10.0);
        assert_eq!(a.pixels, b.pixels, "deterministic");
        let c = s.render(20.0);
        assert_ne!(a.pixels, c.pixels);
    }
}
