//! The synthetic sky itself: its configuration and [`SyntheticSky`], which holds each concept's
//! state (the sun's path, the sun, the clouds, the clear-sky model, the grid, the discs' coverage)
//! and answers for it: where the sun is, how bright, and the frame at time t. The concept modules
//! take plain parameters and import none of this one.

use std::f64::consts::{PI, TAU};
use std::ops::Range;

use glam::DVec3;

use crate::envmap::{EnvMap, InputRepairs, Projection, luminance64};

use super::clouds::{CLOUD_GAIN, Clouds};
use super::disc::{Disc, cover_cap};
use super::grid::Grid;
use super::hosek_wilkie::{HwModel, model_elevation, twilight_fade};
use super::lamp::SwitchLight;
use super::render::{NIGHT_RADIANCE, ROWS_PER_BATCH, SkyFrame, sky_row};
use super::sun::{self, Sun, sun_radius};
use super::sun_path::{NOON_ELEVATION_DEG, SunPath};

/// Configuration of the synthetic sky. Out-of-range values are clamped by [`SyntheticSky::new`].
#[derive(Clone, Debug, PartialEq)]
pub struct SyntheticConfig {
    /// Lat-long width in pixels; forced to 2 × `height` (DESIGN.md: lat-long maps are 2:1).
    pub width: usize,
    /// Lat-long height in pixels.
    pub height: usize,
    /// Sun elevation at t = 0 in degrees, on the rising half of the arc (clamped to ±60°).
    pub start_elevation_deg: f64,
    /// Angular speed of the sun along its arc: the day (rise to rise) lasts 360 / speed seconds.
    pub sun_speed_deg_per_s: f64,
    /// Atmospheric turbidity, clamped to the model's 1..=10.
    pub turbidity: f64,
    /// Ground albedo, 0..=1: the lower hemisphere is ground of radiance albedo × irradiance / π.
    pub ground_albedo: f64,
    /// Cloud cover, the fraction of the sky covered, 0..=1.
    pub clouds: f64,
    /// Azimuthal drift of the cloud layer, degrees per second.
    pub cloud_drift_deg_per_s: f64,
    /// A lamp that turns on and off; `None` for none.
    pub switch_light: Option<SwitchLight>,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        SyntheticConfig {
            width: 1024,
            height: 512,
            start_elevation_deg: 5.0,
            sun_speed_deg_per_s: 1.0,
            turbidity: 3.0,
            ground_albedo: 0.3,
            clouds: 0.3,
            cloud_drift_deg_per_s: 2.0,
            switch_light: Some(SwitchLight::default()),
        }
    }
}

/// The synthetic sky. Holds the cloud texture, the model's tables and per-resolution geometry,
/// so that [`SyntheticSky::render_into`] allocates nothing once warm.
pub struct SyntheticSky {
    cfg: SyntheticConfig,
    /// Where the sun is at time t.
    path: SunPath,
    /// The sun disk's extinction and radiance scale.
    sun: Sun,
    /// The cloud layer (clear when `clouds` ≤ 0).
    pub(super) clouds: Clouds,
    /// The clear-sky model at the current sun elevation.
    pub(super) model: HwModel,
    /// The clear sky's mean luminance over the upper hemisphere, for the current model.
    sky_mean_lum: f32,
    /// Per-row and per-column tables of the current resolution.
    grid: Grid,
    /// The sun's and the lamp's disc coverage (see [`cover_cap`]), kept between frames.
    sun_splat: Vec<(usize, f64, usize)>,
    lamp_splat: Vec<(usize, f64, usize)>,
    #[cfg(test)]
    pub(super) draw_sun: bool,
}

impl SyntheticSky {
    /// Builds the sky: clamps the configuration, calibrates the sun, and precomputes the cloud
    /// texture (the only expensive step, a few milliseconds).
    pub fn new(mut cfg: SyntheticConfig) -> Self {
        cfg.height = cfg.height.max(1);
        cfg.width = 2 * cfg.height;
        let finite_or = |v: f64, d: f64| if v.is_finite() { v } else { d };
        cfg.turbidity = finite_or(cfg.turbidity, 3.0).clamp(1.0, 10.0);
        cfg.ground_albedo = finite_or(cfg.ground_albedo, 0.3).clamp(0.0, 1.0);
        cfg.clouds = finite_or(cfg.clouds, 0.0).clamp(0.0, 1.0);
        cfg.cloud_drift_deg_per_s = finite_or(cfg.cloud_drift_deg_per_s, 0.0);
        cfg.sun_speed_deg_per_s = finite_or(cfg.sun_speed_deg_per_s, 0.0);
        cfg.start_elevation_deg =
            finite_or(cfg.start_elevation_deg, 5.0).clamp(-NOON_ELEVATION_DEG, NOON_ELEVATION_DEG);

        let mut model = HwModel::new(cfg.turbidity, cfg.ground_albedo);
        let sun = Sun::calibrated(cfg.turbidity, &mut model);
        let clouds = if cfg.clouds > 0.0 {
            Clouds::new(cfg.clouds, cfg.cloud_drift_deg_per_s)
        } else {
            Clouds::clear(cfg.cloud_drift_deg_per_s)
        };
        SyntheticSky {
            path: SunPath::new(cfg.start_elevation_deg, cfg.sun_speed_deg_per_s),
            sun,
            clouds,
            model,
            sky_mean_lum: 0.0,
            grid: Grid::default(),
            sun_splat: Vec::new(),
            lamp_splat: Vec::new(),
            cfg,
            #[cfg(test)]
            draw_sun: true,
        }
    }

    /// The configuration in use (after clamping).
    pub fn config(&self) -> &SyntheticConfig {
        &self.cfg
    }

    /// Whether the switch light is on at time t (on for the first half of each period).
    pub fn switch_light_on(&self, t: f64) -> bool {
        self.cfg.switch_light.as_ref().is_some_and(|l| l.is_on(t))
    }

    /// Seconds from one sunrise to the next (infinite when the sun does not move).
    pub fn period_s(&self) -> f64 {
        self.path.period_s()
    }

    /// The first sunrise at or after `t` (the sun crosses the horizon rising, in the east, +X).
    pub fn next_sunrise(&self, t: f64) -> f64 {
        self.path.next_sunrise(t)
    }

    /// Unit vector toward the sun centre at time t (world frame).
    ///
    /// The sun moves at constant speed on the great circle through east (+X) and west (−X) that
    /// culminates at [`NOON_ELEVATION_DEG`] toward −Z: `d(α) = cos α·X̂ + sin α·N̂` with
    /// `N̂ = (0, sin 60°, −cos 60°)`, so elevation = asin(sin α · sin 60°): 0 at sunrise (α = 0),
    /// 60° at noon, 0 at sunset (α = π), and a night of equal length below the horizon. Periodic,
    /// defined for any t.
    pub fn sun_direction(&self, t: f64) -> DVec3 {
        self.path.direction(t)
    }

    /// Elevation of the sun centre above the horizon at time t, degrees.
    pub fn sun_elevation_deg(&self, t: f64) -> f64 {
        self.sun_direction(t).y.clamp(-1.0, 1.0).asin().to_degrees()
    }

    /// Solid angle of the 0.53° sun disk, sr: 2π(1 − cos r) = 4π sin²(r/2).
    pub fn sun_solid_angle() -> f64 {
        sun::sun_solid_angle()
    }

    /// Radiance of the sun disk at time t (linear RGB, model units): the calibrated exo-atmospheric
    /// radiance × Beer-Lambert transmittance along the Kasten-Young air mass (so it reddens and
    /// fades toward the horizon) × the cloud transmittance in front of it; 0 once the whole disk
    /// has set. The part of the disk below the horizon is hidden by the ground, so the map holds
    /// radiance × the visible part of [`Self::sun_solid_angle`]. Scale: the sun's ∫ L dω is
    /// [`SUN_TO_SKY_RATIO`](super::SUN_TO_SKY_RATIO) × the clear sky's at noon (≈ 840 vs ≈ 70 model units at turbidity 3).
    pub fn sun_radiance(&self, t: f64) -> [f32; 3] {
        self.sun.radiance(self.sun_direction(t), &self.clouds, t)
    }

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
            self.sky_mean_lum = (luminance64(lum) / TAU) as f32;
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
                    let e = sky_row(&self.grid, &self.model, &self.clouds, &frame, j, px);
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
}
