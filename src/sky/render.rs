//! A frame's layers and the renderer of one sky row; [`SyntheticSky::render_by_rows`] composes
//! them into the sky at time t as a lat-long map, row batch by row batch.
//!
//! Layers, in order: the clear-sky model (faded at twilight) over the [`NIGHT_RADIANCE`] floor,
//! the drifting clouds, the sun disk (hidden by the ground below the horizon), the ground, and the
//! lamp over everything. The ground is uniform and Lambertian: radiance albedo × E / π, with E the
//! horizontal-plane irradiance the sky rows and the sun deliver, so it is known only once every
//! sky row is done. Rows are handed on in batches of [`ROWS_PER_BATCH`], top to bottom, as a
//! camera's sensor is read out, so the daemon resamples each batch while the rest renders
//! (DESIGN.md, "The pipeline"); the result is bit for bit the whole-frame render's.
//!
//! [`SyntheticSky::render_by_rows`]: super::SyntheticSky::render_by_rows

use super::clouds::Clouds;
use super::grid::Grid;
use super::hosek_wilkie::HwModel;

/// Night-sky radiance floor (linear RGB, model units), added everywhere above the horizon so the
/// map is never all zero, even at midnight.
pub const NIGHT_RADIANCE: [f32; 3] = [6.0e-4, 8.0e-4, 1.2e-3];
/// Rows the synthetic source renders before handing them on (16 of 512: the daemon's resampling
/// of the last batch, after the frame is complete, is 1/32 of a frame's).
pub const ROWS_PER_BATCH: usize = 16;

/// What every sky row of one frame shares.
pub(super) struct SkyFrame {
    /// Twilight fade of the model.
    pub(super) fade: f32,
    /// Radiance of overcast cloud.
    pub(super) grey: [f32; 3],
    /// Direction toward the sun.
    pub(super) sun: (f32, f32, f32),
    /// The clouds' drift: whole columns, then the fraction of the next.
    pub(super) cloud_shift: (usize, f32),
}

/// Renders sky row `j` of `grid` into `px` (the clear-sky `model` faded at twilight over the
/// night floor, then the drifting `clouds`); returns the horizontal-plane irradiance the row
/// delivers to the ground (Σ L cos θ dω).
pub(super) fn sky_row(
    grid: &Grid,
    model: &HwModel,
    clouds: &Clouds,
    frame: &SkyFrame,
    j: usize,
    px: &mut [[f32; 3]],
) -> [f64; 3] {
    let row = &grid.rows[j];
    let (sx, sy, sz) = frame.sun;
    let ka = row.st * sx;
    let kb = row.st * sz;
    let kc = row.ct * sy;
    let a = row.a.map(|x| x * frame.fade);
    let ac = row.ac.map(|x| x * frame.fade);
    let cols = grid.col_sin.iter().zip(&grid.col_cos);
    for (p, (&sp, &cp)) in px.iter_mut().zip(cols) {
        let cos_gamma = ka * sp - kb * cp + kc;
        let g = model.g(cos_gamma);
        for c in 0..3 {
            p[c] = (a[c] * g[c] + ac[c]).max(0.0) + NIGHT_RADIANCE[c];
        }
    }
    clouds.overlay_row(j, frame.cloud_shift, frame.grey, px);
    let mut row_sum = [0.0f32; 3];
    for p in px.iter() {
        for c in 0..3 {
            row_sum[c] += p[c];
        }
    }
    let weight = row.ct as f64 * row.d_omega;
    row_sum.map(|s| s as f64 * weight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::{EnvMap, Projection};
    use crate::sky::SyntheticConfig;
    use crate::sky::testing::{sky, total};
    use std::ops::Range;

    #[test]
    fn maps_are_finite_non_negative_and_never_black() {
        let mut s = sky(128, |_| {});
        let rise = s.next_sunrise(0.0);
        let p = s.period_s();
        let mut out = s.render(0.0);
        for k in 0..48 {
            let t = rise + p * k as f64 / 48.0;
            s.render_into(t, &mut out);
            assert_eq!(out.pixels.len(), 128 * 64);
            assert!(
                out.pixels
                    .iter()
                    .flatten()
                    .all(|v| v.is_finite() && *v >= 0.0)
            );
            assert!(total(&out) > 0.0, "t {t}");
            // Every pixel, ground included, is lit, also at midnight.
            assert!(
                out.pixels.iter().all(|p| EnvMap::luminance(*p) > 0.0),
                "t {t}"
            );
        }
        // Night is dim but not black; day is bright.
        let mut s = sky(128, |c| c.switch_light = None);
        let midnight = total(&s.render(rise + 0.75 * p));
        let noon = total(&s.render(rise + 0.25 * p));
        assert!(
            midnight > 0.0 && midnight < 1e-3 * noon,
            "{midnight} vs {noon}"
        );
        // Extreme configurations stay finite too.
        let extremes: [fn(&mut SyntheticConfig); 4] = [
            |c: &mut SyntheticConfig| c.clouds = 1.0,
            |c: &mut SyntheticConfig| c.turbidity = 100.0,
            |c: &mut SyntheticConfig| c.sun_speed_deg_per_s = 0.0,
            |c: &mut SyntheticConfig| c.ground_albedo = f64::NAN,
        ];
        for f in extremes {
            let mut s = sky(64, f);
            let m = s.render(1234.5);
            assert!(
                m.pixels
                    .iter()
                    .flatten()
                    .all(|v| v.is_finite() && *v >= 0.0)
            );
            assert!(total(&m) > 0.0);
        }
    }

    #[test]
    fn consecutive_frames_are_continuous() {
        // A whole day at 30 frames/s (small maps: the sun and lamp energies are exact at any size).
        let mut s = sky(64, |_| {});
        let mut out = s.render(0.0);
        let dt = 1.0 / 30.0;
        let frames = (s.period_s() / dt) as usize + 60;
        let mut prev = total(&out);
        let mut worst = (0.0, 0.0);
        for k in 1..=frames {
            let t = k as f64 * dt;
            s.render_into(t, &mut out);
            let e = total(&out);
            if s.switch_light_on(t) == s.switch_light_on(t - dt) {
                let rel = (e - prev).abs() / prev.max(e);
                if rel > worst.0 {
                    worst = (rel, t);
                }
            }
            prev = e;
        }
        eprintln!("worst relative change {:.4} at t = {:.2}", worst.0, worst.1);
        assert!(worst.0 < 0.02, "{worst:?}");
    }

    /// Rows are handed on top to bottom in batches that cover the frame, each final when handed
    /// on (the sun, the lamp and the ground included), with the clouds and the lamp on.
    #[test]
    fn rows_are_handed_on_final_in_batches() {
        let mut s = sky(256, |c| {
            c.clouds = 0.5;
            c.start_elevation_deg = 30.0;
        });
        for t in [0.0, 1.3] {
            let mut batches: Vec<(Range<usize>, Vec<[f32; 3]>)> = Vec::new();
            let mut out = s.render(t + 100.0); // a dirty buffer
            s.render_by_rows(t, &mut out, &mut |m, rows| {
                let px = m.pixels[rows.start * m.width..rows.end * m.width].to_vec();
                batches.push((rows, px));
            });
            let whole = s.render(t);
            assert!(s.switch_light_on(t), "the lamp is drawn");
            let mut next = 0;
            for (rows, px) in &batches {
                assert_eq!(rows.start, next);
                assert_eq!(rows.len(), ROWS_PER_BATCH.min(whole.height - next));
                let w = whole.width;
                assert!(
                    px == &whole.pixels[rows.start * w..rows.end * w],
                    "{rows:?} at t={t}"
                );
                next = rows.end;
            }
            assert_eq!(next, whole.height);
            assert_eq!(out.pixels, whole.pixels);
        }
    }

    #[test]
    fn render_into_reuses_the_buffer() {
        let mut s = sky(256, |_| {});
        let mut out = s.render(0.0);
        let ptr = out.pixels.as_ptr();
        for k in 0..10 {
            s.render_into(k as f64 * 0.7, &mut out);
        }
        assert_eq!(out.pixels.as_ptr(), ptr);
        assert_eq!((out.width, out.height), (256, 128));
        assert!(matches!(out.projection, Projection::LatLong));
    }
}
