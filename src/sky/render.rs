//! Composing a frame: the sky at time t as a lat-long [`EnvMap`], row batch by row batch.
//!
//! Layers, in order: the clear-sky model (faded at twilight) over the [`NIGHT_RADIANCE`] floor,
//! the drifting clouds, the sun disk (hidden by the ground below the horizon), the ground, and the
//! lamp over everything. The ground is uniform and Lambertian: radiance albedo × E / π, with E the
//! horizontal-plane irradiance the sky rows and the sun deliver, so it is known only once every
//! sky row is done. Rows are handed on in batches of [`ROWS_PER_BATCH`], top to bottom, as a
//! camera's sensor is read out, so the daemon resamples each batch while the rest renders
//! (DESIGN.md, "The pipeline"); the result is bit for bit the whole-frame render's.

use std::f64::consts::{PI, TAU};
use std::ops::Range;

use crate::envmap::{EnvMap, InputRepairs, Projection};

use super::clouds::CLOUD_GAIN;
use super::disc::{Disc, cover_cap};
use super::hosek_wilkie::{model_elevation, twilight_fade};
use super::sun::sun_radius;
use super::{SyntheticSky, luminance};

/// Night-sky radiance floor (linear RGB, model units), added everywhere above the horizon so the
/// map is never all zero, even at midnight.
pub const NIGHT_RADIANCE: [f32; 3] = [6.0e-4, 8.0e-4, 1.2e-3];
/// Rows the synthetic source renders before handing them on (16 of 512: the daemon's resampling
/// of the last batch, after the frame is complete, is 1/32 of a frame's).
pub const ROWS_PER_BATCH: usize = 16;

/// What every sky row of one frame shares.
struct SkyFrame {
    /// Twilight fade of the model.
    fade: f32,
    /// Radiance of overcast cloud.
    grey: [f32; 3],
    /// Direction toward the sun.
    sun: (f32, f32, f32),
    /// The clouds' drift: whole columns, then the fraction of the next.
    cloud_shift: (usize, f32),
}

impl SyntheticSky {
    /// Renders the sky at time `t` seconds into a new map.
    pub fn render(&mut self, t: f64) -> EnvMap {
        let mut out = EnvMap {
            width: 0,
            height: 0,
            pixels: Vec::new(),
            projection: Projection::LatLong,
            repairs: InputRepairs::default(),
        };
        self.render_into(t, &mut out);
        out
    }

    /// Renders the sky at time `t` into `out` (resized to width×height lat-long if needed), reusing
    /// its buffer: no per-frame allocation once warm.
    pub fn render_into(&mut self, t: f64, out: &mut EnvMap) {
        self.render_by_rows(t, out, &mut |_, _| {});
    }

    /// [`render_into`](Self::render_into), handing each batch of [`ROWS_PER_BATCH`] rows on as soon
    /// as it is final, top to bottom, as a camera's sensor is read out: the daemon resamples each
    /// batch while the rest renders. The pixels are render_into's, bit for bit: the discs'
    /// coverage is computed first and each batch adds its rows' share, and the ground, which the
    /// whole sky lights, comes after the sky rows.
    pub fn render_by_rows(
        &mut self,
        t: f64,
        out: &mut EnvMap,
        rows: &mut dyn FnMut(&EnvMap, Range<usize>),
    ) {
        let (w, h) = (self.cfg.width, self.cfg.height);
        out.width = w;
        out.height = h;
        out.projection = Projection::LatLong;
        out.repairs = InputRepairs::default();
        out.pixels.resize(w * h, [0.0; 3]);

        let sun = self.sun_direction(t);
        let elev_deg = sun.y.clamp(-1.0, 1.0).asin().to_degrees();
        let model_elev = model_elevation(elev_deg);
        // Rebuilt whenever the model's input moved (each frame by day, ~0.2 ms; never at night):
        // at low sun the sky brightens by ~4 % per 0.1° of elevation, so a coarser step flickers.
        let rebuild_model = model_elev != self.model.elev;
        if rebuild_model {
            self.model.set(model_elev);
            let lum = self.model.clear_sky_integral(sun, 16, 32);
            self.sky_mean_lum = (luminance(lum) / TAU) as f32;
        }
        if self.grid.res != (w, h) {
            self.grid.build(w, h, &self.model);
            self.clouds.resample(&self.grid);
        } else if rebuild_model {
            self.grid.update_rows(&self.model);
        }

        // The sun (hidden by the ground below the horizon) and the lamp (a nearby source drawn
        // over everything): their pixels' coverage, added batch by batch below.
        #[cfg(test)]
        let draw_sun = self.draw_sun;
        #[cfg(not(test))]
        let draw_sun = true;
        let sun_radiance = self.sun_radiance(t);
        let mut sun_disc = Disc::take(&mut self.sun_splat);
        if draw_sun && sun_radiance != [0.0; 3] {
            sun_disc.scale = cover_cap(&self.grid, &mut sun_disc.cover, sun, sun_radius());
        }
        let mut lamp_disc = Disc::take(&mut self.lamp_splat);
        let mut lamp_radiance = [0.0; 3];
        if self.switch_light_on(t)
            && let Some((to_light, radius, r)) =
                self.cfg.switch_light.as_ref().and_then(|l| l.disc())
        {
            lamp_radiance = [r; 3];
            lamp_disc.scale = cover_cap(&self.grid, &mut lamp_disc.cover, to_light, radius);
        }

        // Twilight: the model (clamped to sunrise) fades out as the sun sinks.
        let fade = twilight_fade(elev_deg);
        let grey_lum = fade * CLOUD_GAIN * self.sky_mean_lum;
        // The drift is a rotation about +Y, i.e. a shift of `shift` columns of the lat-long cover.
        let shift = self.clouds.offset(t) / (TAU / w as f64);
        let n0 = (shift as usize).min(w - 1);
        let frame = SkyFrame {
            fade,
            grey: NIGHT_RADIANCE.map(|n| n + grey_lum),
            sun: (sun.x as f32, sun.y as f32, sun.z as f32),
            cloud_shift: (n0, (shift - n0 as f64) as f32),
        };

        // The horizontal-plane irradiance the sky rows (then the sun) deliver to the ground.
        let mut ground_irradiance = [0.0f64; 3];
        let mut sun_irradiance = [0.0f64; 3];
        let mut ground: Option<[f32; 3]> = None;
        let albedo = self.cfg.ground_albedo;
        for first in (0..h).step_by(ROWS_PER_BATCH) {
            let batch = first..(first + ROWS_PER_BATCH).min(h);
            for j in batch.clone() {
                if self.grid.rows[j].sky {
                    let px = &mut out.pixels[j * w..(j + 1) * w];
                    let e = self.sky_row(&frame, j, px);
                    for c in 0..3 {
                        ground_irradiance[c] += e[c];
                    }
                }
            }
            sun_disc.draw(
                &self.grid.rows,
                &mut out.pixels,
                batch.end,
                sun_radiance,
                true,
                &mut sun_irradiance,
            );
            for j in batch.clone() {
                if !self.grid.rows[j].sky {
                    // Every sky row is done: the sky rows come first.
                    let g = *ground.get_or_insert_with(|| {
                        std::array::from_fn(|c| {
                            let e = ground_irradiance[c] + sun_irradiance[c];
                            (albedo * e / PI) as f32
                        })
                    });
                    out.pixels[j * w..(j + 1) * w].fill(g);
                }
            }
            lamp_disc.draw(
                &self.grid.rows,
                &mut out.pixels,
                batch.end,
                lamp_radiance,
                false,
                &mut [0.0; 3],
            );
            rows(out, batch);
        }
        self.sun_splat = sun_disc.cover;
        self.lamp_splat = lamp_disc.cover;
    }

    /// Renders sky row `j` into `px` (the model, then the drifting clouds); returns the
    /// horizontal-plane irradiance the row delivers to the ground (Σ L cos θ dω).
    fn sky_row(&self, frame: &SkyFrame, j: usize, px: &mut [[f32; 3]]) -> [f64; 3] {
        let row = &self.grid.rows[j];
        let (sx, sy, sz) = frame.sun;
        let ka = row.st * sx;
        let kb = row.st * sz;
        let kc = row.ct * sy;
        let a = row.a.map(|x| x * frame.fade);
        let ac = row.ac.map(|x| x * frame.fade);
        let cols = self.grid.col_sin.iter().zip(&self.grid.col_cos);
        for (p, (&sp, &cp)) in px.iter_mut().zip(cols) {
            let cos_gamma = ka * sp - kb * cp + kc;
            let g = self.model.g(cos_gamma);
            for c in 0..3 {
                p[c] = (a[c] * g[c] + ac[c]).max(0.0) + NIGHT_RADIANCE[c];
            }
        }
        self.clouds
            .overlay_row(j, frame.cloud_shift, frame.grey, px);
        let mut row_sum = [0.0f32; 3];
        for p in px.iter() {
            for c in 0..3 {
                row_sum[c] += p[c];
            }
        }
        let weight = row.ct as f64 * row.d_omega;
        row_sum.map(|s| s as f64 * weight)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::SyntheticConfig;
    use crate::sky::testing::{sky, total};

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
