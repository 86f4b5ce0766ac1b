//! The built-in synthetic dynamic sky: the default frame source of `vemlight serve`.
//!
//! Why it exists: no HDR *video* environment map is published anywhere we can depend on, yet the
//! capture daemon must run, and its lights must move, with no data and no camera. So it renders its
//! own: a Hosek-Wilkie clear sky (L. Hošek and A. Wilkie, "An Analytic Model for Full Spectral
//! Sky-Dome Radiance", ACM TOG 31(4), SIGGRAPH 2012; RGB datasets via the `hw-skymodel` crate)
//! lit by a sun that travels a day arc, an analytic 0.53° sun disk, drifting clouds, a uniform
//! ground, and a lamp that switches on and off, which exercises the temporal filter's response to
//! a step (DESIGN.md, "Time-varying skies").
//!
//! Every frame has exact ground truth: [`SyntheticSky::sun_direction`], [`SyntheticSky::sun_radiance`]
//! and the lamp's radiance × cap solid angle, because both discs are rendered by exact area
//! coverage (their ∫ L dω equals radiance × solid angle of the cap at any resolution, even though
//! the sun is smaller than a pixel at 1024×512).
//!
//! Speed: the Hosek-Wilkie formula factors as
//! `L(θ, γ) = A(θ) · (G(γ) + I·√cos θ)` with `A(θ) = R·(1 + a·e^{b/(cos θ + 0.01)})` (the paper's
//! extended Perez formula; `R` the per-channel radiance scale). In a lat-long map θ is constant along a row, so `A` and
//! `A·I·√cos θ` are per-row constants and only `G(γ)` varies per pixel: it comes from a 1-D table
//! over `sin(γ/2) = √((1 − cos γ)/2)` for γ ≤ 90° and over `cos(γ/2) = √((1 + cos γ)/2)` beyond
//! (so no `acos` per pixel, and steps of < 0.08° in γ at both the sun and the anti-solar point),
//! rebuilt whenever the sun moves. This is exact in θ and cheaper than a bilinear (θ, γ) table.
//! Direction cosines come from per-row and per-column sin/cos tables built once per resolution.
//! Clouds: a periodic fBm value-noise texture, mapped onto the dome azimuthal-equidistantly and
//! resampled once per resolution into a lat-long cover map; the drift is a rotation about +Y, so
//! per frame it is a fractional column shift of that map (one lerp per pixel, no trig).
//!
//! Night and twilight: the model is valid for sun elevations 0..90°; below the horizon its sky
//! (at the horizon's parameters) fades by e per 3° of depression over a constant night floor, and
//! near the horizon its elevation input is smoothed (see `model_elevation`), so frames 1/30 s apart
//! never differ by more than ~1.5 % in total energy at the default speeds, sunrise included.

use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2, PI, TAU};

use glam::DVec3;
use hw_skymodel::rgb::{SkyParams, SkyState};
use std::ops::Range;

use crate::envmap::{EnvMap, InputRepairs, Projection};

/// Elevation of the sun at noon on the synthetic day arc, in degrees.
pub const NOON_ELEVATION_DEG: f64 = 60.0;
/// Angular diameter of the sun disk, in degrees (the real sun: 0.53°).
pub const SUN_ANGULAR_DIAMETER_DEG: f64 = 0.53;
/// Ratio of the sun's ∫ L dω (luminance) to the clear sky's ∫ L dω over the upper hemisphere, with
/// the sun at [`NOON_ELEVATION_DEG`]. Clear-sky measurements put direct normal irradiance at about
/// 850–950 W/m² against 60–120 W/m² of diffuse: the sun carries roughly 10–15× the sky's energy.
/// The sun's radiance scale is calibrated once per sky so that this holds at noon; at other
/// elevations Beer-Lambert extinction along the air mass decides (see [`SyntheticSky::sun_radiance`]).
pub const SUN_TO_SKY_RATIO: f64 = 12.0;
/// Night-sky radiance floor (linear RGB, model units), added everywhere above the horizon so the
/// map is never all zero, even at midnight.
pub const NIGHT_RADIANCE: [f32; 3] = [6.0e-4, 8.0e-4, 1.2e-3];

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
const CLOUD_GAIN: f32 = 1.2;
/// Fraction of the sun's radiance a full cloud removes.
const SUN_CLOUD_OPACITY: f64 = 0.85;
/// Box-blur radius (texels, applied twice) of the cover the sun sees: a soft edge, so that a cloud
/// crossing the sun dims it over ~1 s rather than in one frame (temporal continuity).
const CLOUD_SOFT_RADIUS: usize = 10;
/// Supersampling per axis of the pixels on a disc's edge.
const EDGE_SUPERSAMPLE: usize = 8;
/// Rows the synthetic source renders before handing them on (16 of 512: the daemon's resampling
/// of the last batch, after the frame is complete, is 1/32 of a frame's).
pub const ROWS_PER_BATCH: usize = 16;

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

/// A round lamp of uniform radiance that is on for the first half of each period, off for the
/// second. It is a nearby source: it is drawn over sky and ground and does not light the ground.
#[derive(Clone, Debug, PartialEq)]
pub struct SwitchLight {
    /// Seconds per on/off cycle (on for half, off for half); ≤ 0 or non-finite: always on.
    pub period_s: f64,
    /// Unit vector toward the lamp's centre (world frame; normalised on use).
    pub to_light: DVec3,
    /// Radiance (grey, linear, model units).
    pub radiance: f32,
    /// Angular radius of the lamp's disc, degrees.
    pub radius_deg: f64,
}

impl Default for SwitchLight {
    fn default() -> Self {
        SwitchLight {
            period_s: 10.0,
            // West-ish, behind the viewer, 20° up: away from the sun's arc.
            to_light: DVec3::new(-0.55, 0.34, 0.76).normalize(),
            // ∫ L dω = 2000 × 8.6 msr ≈ 17: a quarter of the clear noon sky's ∫ L dω (≈ 70 in
            // model units; the sun's is ≈ 840), so switching it moves the lights by day as well.
            radiance: 2000.0,
            radius_deg: 3.0,
        }
    }
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

/// Per-row constants of the current resolution and model.
#[derive(Clone, Copy, Debug, Default)]
struct Row {
    st: f32,
    ct: f32,
    /// Solid angle of one pixel of the row, sr.
    d_omega: f64,
    /// Cloud-texture radius of the row's zenith angle, texels.
    cloud_r: f32,
    /// The pixel centre is above the horizon.
    sky: bool,
    /// `A(θ)` per channel.
    a: [f32; 3],
    /// `A(θ)·I·√cos θ` per channel.
    ac: [f32; 3],
}

/// The synthetic sky. Holds the cloud texture, the model's tables and per-resolution geometry,
/// so that [`SyntheticSky::render_into`] allocates nothing once warm.
pub struct SyntheticSky {
    cfg: SyntheticConfig,
    /// Arc angle at t = 0 (0 = sunrise in the east, π/2 = noon, π = sunset) and its rate, rad/s.
    alpha0: f64,
    omega: f64,
    /// Exo-atmospheric sun radiance (before extinction and clouds), calibrated by SUN_TO_SKY_RATIO.
    sun_scale: f64,
    /// Per-channel optical depth at air mass 1.
    tau: [f64; 3],
    /// Cloud cover texture (0..1) and its blurred copy for the sun; empty when `clouds` ≤ 0.
    cover: Vec<f32>,
    cover_soft: Vec<f32>,
    /// `cover` resampled to the sky rows of the current resolution (lat-long, no drift).
    cover_ll: Vec<f32>,
    /// Model state: input elevation (NaN before the first build), parameters, G(γ) table, the clear
    /// sky's mean luminance over the upper hemisphere.
    model_elev: f64,
    params: [f32; 27],
    model_radiance: [f32; 3],
    gamma_table: Vec<[f32; 3]>,
    sky_mean_lum: f32,
    /// Geometry of the resolution `rows` and `col_sin`/`col_cos` were built for.
    res: (usize, usize),
    rows: Vec<Row>,
    col_sin: Vec<f32>,
    col_cos: Vec<f32>,
    /// The sun's and the lamp's disc coverage (see [`Self::cover_cap`]), kept between frames.
    sun_splat: Vec<(usize, f64, usize)>,
    lamp_splat: Vec<(usize, f64, usize)>,
    #[cfg(test)]
    draw_sun: bool,
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

        // On the arc, sin(elevation) = sin(α)·sin(noon elevation); α0 on the rising half.
        let alpha0 = (cfg.start_elevation_deg.to_radians().sin()
            / NOON_ELEVATION_DEG.to_radians().sin())
        .clamp(-1.0, 1.0)
        .asin();

        // Extinction: Rayleigh τ ≈ 0.0088 λ^-4.05 plus Ångström aerosol β λ^-1.3 with
        // β = 0.04608 T − 0.04586 (Preetham, Shirley & Smits 1999), λ in µm at 610/550/465 nm.
        let beta = (0.04608 * cfg.turbidity - 0.04586).max(0.0);
        let tau = [0.61f64, 0.55, 0.465].map(|l| 0.0088 * l.powf(-4.05) + beta * l.powf(-1.3));

        let mut sky = SyntheticSky {
            alpha0,
            omega: cfg.sun_speed_deg_per_s.to_radians(),
            sun_scale: 0.0,
            tau,
            cover: Vec::new(),
            cover_soft: Vec::new(),
            cover_ll: Vec::new(),
            model_elev: f64::NAN,
            params: [0.0; 27],
            model_radiance: [0.0; 3],
            gamma_table: vec![[0.0; 3]; 2 * (GAMMA_TABLE_N + 1)],
            sky_mean_lum: 0.0,
            res: (0, 0),
            rows: Vec::new(),
            col_sin: Vec::new(),
            col_cos: Vec::new(),
            sun_splat: Vec::new(),
            lamp_splat: Vec::new(),
            cfg,
            #[cfg(test)]
            draw_sun: true,
        };

        // Calibrate the sun on the clear noon sky (luminance, fine quadrature).
        let noon = NOON_ELEVATION_DEG.to_radians();
        sky.set_model(noon);
        let noon_sun = DVec3::new(0.0, noon.sin(), -noon.cos());
        let sky_integral = sky.clear_sky_integral(noon_sun, 128, 256);
        let t_noon = sky.transmittance(NOON_ELEVATION_DEG);
        sky.sun_scale = SUN_TO_SKY_RATIO * luminance(sky_integral)
            / (luminance(t_noon) * Self::sun_solid_angle());

        if sky.cfg.clouds > 0.0 {
            sky.build_clouds();
        }
        sky
    }

    /// The configuration in use (after clamping).
    pub fn config(&self) -> &SyntheticConfig {
        &self.cfg
    }

    /// Solid angle of the 0.53° sun disk, sr: 2π(1 − cos r) = 4π sin²(r/2).
    pub fn sun_solid_angle() -> f64 {
        cap_solid_angle((0.5 * SUN_ANGULAR_DIAMETER_DEG).to_radians())
    }

    /// Seconds from one sunrise to the next (infinite when the sun does not move).
    pub fn period_s(&self) -> f64 {
        TAU / self.omega.abs()
    }

    /// The first sunrise at or after `t` (the sun crosses the horizon rising, in the east, +X).
    pub fn next_sunrise(&self, t: f64) -> f64 {
        if self.omega == 0.0 {
            return f64::INFINITY;
        }
        // Arc angle ≡ 0 (mod 2π) when rising for ω > 0; for ω < 0 the sun runs the arc backwards
        // and rises at α = π.
        let target = if self.omega > 0.0 { 0.0 } else { PI };
        let alpha = self.arc_angle(t);
        let to_go = ((target - alpha) / self.omega).rem_euclid(self.period_s());
        t + to_go
    }

    fn arc_angle(&self, t: f64) -> f64 {
        (self.alpha0 + self.omega * t).rem_euclid(TAU)
    }

    /// Unit vector toward the sun centre at time t (world frame).
    ///
    /// The sun moves at constant speed on the great circle through east (+X) and west (−X) that
    /// culminates at [`NOON_ELEVATION_DEG`] toward −Z: `d(α) = cos α·X̂ + sin α·N̂` with
    /// `N̂ = (0, sin 60°, −cos 60°)`, so elevation = asin(sin α · sin 60°): 0 at sunrise (α = 0),
    /// 60° at noon, 0 at sunset (α = π), and a night of equal length below the horizon. Periodic,
    /// defined for any t.
    pub fn sun_direction(&self, t: f64) -> DVec3 {
        let (sa, ca) = self.arc_angle(t).sin_cos();
        let (sn, cn) = NOON_ELEVATION_DEG.to_radians().sin_cos();
        DVec3::new(ca, sa * sn, -sa * cn).normalize()
    }

    /// Elevation of the sun centre above the horizon at time t, degrees.
    pub fn sun_elevation_deg(&self, t: f64) -> f64 {
        self.sun_direction(t).y.clamp(-1.0, 1.0).asin().to_degrees()
    }

    /// Radiance of the sun disk at time t (linear RGB, model units): the calibrated exo-atmospheric
    /// radiance × Beer-Lambert transmittance along the Kasten-Young air mass (so it reddens and
    /// fades toward the horizon) × the cloud transmittance in front of it; 0 once the whole disk
    /// has set. The part of the disk below the horizon is hidden by the ground, so the map holds
    /// radiance × the visible part of [`Self::sun_solid_angle`]. Scale: the sun's ∫ L dω is
    /// [`SUN_TO_SKY_RATIO`] × the clear sky's at noon (≈ 840 vs ≈ 70 model units at turbidity 3).
    pub fn sun_radiance(&self, t: f64) -> [f32; 3] {
        let dir = self.sun_direction(t);
        if dir.y <= -(0.5 * SUN_ANGULAR_DIAMETER_DEG).to_radians().sin() {
            return [0.0; 3];
        }
        let elev = dir.y.clamp(-1.0, 1.0).asin().to_degrees();
        let tr = self.transmittance(elev);
        let clouds = 1.0 - SUN_CLOUD_OPACITY * self.cover_at(&self.cover_soft, dir, t);
        tr.map(|x| (self.sun_scale * x * clouds) as f32)
    }

    /// Whether the switch light is on at time t (on for the first half of each period).
    pub fn switch_light_on(&self, t: f64) -> bool {
        match &self.cfg.switch_light {
            None => false,
            Some(l) => {
                if !(l.period_s.is_finite() && l.period_s > 0.0) {
                    return true;
                }
                (t / l.period_s).rem_euclid(1.0) < 0.5
            }
        }
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
        let rebuild_model = model_elev != self.model_elev;
        if rebuild_model {
            self.set_model(model_elev);
            let lum = self.clear_sky_integral(sun, 16, 32);
            self.sky_mean_lum = (luminance(lum) / TAU) as f32;
        }
        if self.res != (w, h) {
            self.build_geometry(w, h);
        } else if rebuild_model {
            self.update_rows();
        }

        // The sun (hidden by the ground below the horizon) and the lamp (a nearby source drawn
        // over everything): their pixels' coverage, added batch by batch below.
        #[cfg(test)]
        let draw_sun = self.draw_sun;
        #[cfg(not(test))]
        let draw_sun = true;
        let sun_radius = (0.5 * SUN_ANGULAR_DIAMETER_DEG).to_radians();
        let sun_radiance = self.sun_radiance(t);
        let mut sun_disc = Disc::take(&mut self.sun_splat);
        if draw_sun && sun_radiance != [0.0; 3] {
            sun_disc.scale = self.cover_cap(&mut sun_disc.cover, sun, sun_radius);
        }
        let mut lamp_disc = Disc::take(&mut self.lamp_splat);
        let mut lamp_radiance = [0.0; 3];
        if self.switch_light_on(t)
            && let Some(lamp) = self.cfg.switch_light.clone()
            && lamp.to_light.length_squared() > 0.0
        {
            let radius = lamp.radius_deg.to_radians().clamp(0.0, PI);
            let r = lamp.radiance.max(0.0);
            if r.is_finite() && radius > 0.0 {
                lamp_radiance = [r; 3];
                lamp_disc.scale =
                    self.cover_cap(&mut lamp_disc.cover, lamp.to_light.normalize(), radius);
            }
        }

        // Twilight: the model (clamped to sunrise) fades out as the sun sinks.
        let fade = (elev_deg.min(0.0) / TWILIGHT_FADE_DEG).exp() as f32;
        let grey_lum = fade * CLOUD_GAIN * self.sky_mean_lum;
        // The drift is a rotation about +Y, i.e. a shift of `shift` columns of the lat-long cover.
        let shift = self.cloud_offset(t) / (TAU / w as f64);
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
                if self.rows[j].sky {
                    let px = &mut out.pixels[j * w..(j + 1) * w];
                    let e = self.sky_row(&frame, j, px);
                    for c in 0..3 {
                        ground_irradiance[c] += e[c];
                    }
                }
            }
            sun_disc.draw(
                &self.rows,
                &mut out.pixels,
                batch.end,
                sun_radiance,
                true,
                &mut sun_irradiance,
            );
            for j in batch.clone() {
                if !self.rows[j].sky {
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
                &self.rows,
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

    /// Rebuilds the model state for input elevation `elev` (radians, clamped to 0..=π/2) and its
    /// G(γ) table.
    fn set_model(&mut self, elev: f64) {
        let elevation = (elev.clamp(0.0, FRAC_PI_2) as f32).clamp(0.0, std::f32::consts::FRAC_PI_2);
        let a = self.cfg.ground_albedo as f32;
        let state = SkyState::new(&SkyParams {
            elevation,
            turbidity: self.cfg.turbidity as f32,
            albedo: [a; 3],
        })
        .expect("sky-model inputs are clamped to their valid ranges");
        let (params, radiance) = state.raw();
        self.params = params;
        self.model_radiance = radiance;
        self.model_elev = elev;
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
    fn clear_sky_integral(&self, sun: DVec3, nt: usize, np: usize) -> [f64; 3] {
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
    fn row_terms(&self, ct: f64) -> ([f64; 3], [f64; 3]) {
        let ct = ct.abs();
        let mut a = [0.0; 3];
        let mut ac = [0.0; 3];
        for c in 0..3 {
            let p = &self.params[9 * c..9 * c + 9];
            let r = self.model_radiance[c] as f64;
            let big_a = r * (1.0 + p[0] as f64 * (p[1] as f64 / (ct + 0.01)).exp());
            a[c] = big_a;
            ac[c] = big_a * p[7] as f64 * ct.sqrt();
        }
        (a, ac)
    }

    fn build_geometry(&mut self, w: usize, h: usize) {
        self.res = (w, h);
        self.col_sin.clear();
        self.col_cos.clear();
        for i in 0..w {
            let phi = TAU * ((i as f64 + 0.5) / w as f64 - 0.5);
            self.col_sin.push(phi.sin() as f32);
            self.col_cos.push(phi.cos() as f32);
        }
        self.rows.clear();
        let cloud_scale = CLOUD_DOME_TILES * CLOUD_TEX as f64 / FRAC_PI_2;
        for j in 0..h {
            let theta = PI * (j as f64 + 0.5) / h as f64;
            let t0 = PI * j as f64 / h as f64;
            let t1 = PI * (j + 1) as f64 / h as f64;
            self.rows.push(Row {
                st: theta.sin() as f32,
                ct: theta.cos() as f32,
                d_omega: TAU / w as f64 * (t0.cos() - t1.cos()),
                cloud_r: (theta * cloud_scale) as f32,
                sky: theta < FRAC_PI_2,
                a: [0.0; 3],
                ac: [0.0; 3],
            });
        }
        self.update_rows();
        self.cover_ll.clear();
        if !self.cover.is_empty() {
            for row in self.rows.iter().take_while(|r| r.sky) {
                for (&sp, &cp) in self.col_sin.iter().zip(&self.col_cos) {
                    let (x, y) = (row.cloud_r * cp, row.cloud_r * sp);
                    self.cover_ll.push(bilinear_wrap(&self.cover, x, y));
                }
            }
        }
    }

    fn update_rows(&mut self) {
        for j in 0..self.rows.len() {
            let ct = self.rows[j].ct as f64;
            let (a, ac) = self.row_terms(ct);
            self.rows[j].a = a.map(|x| x as f32);
            self.rows[j].ac = ac.map(|x| x as f32);
        }
    }

    /// Beer-Lambert transmittance per channel at sun elevation `elev_deg`.
    fn transmittance(&self, elev_deg: f64) -> [f64; 3] {
        let m = air_mass(elev_deg);
        self.tau.map(|tau| (-tau * m).exp())
    }

    /// Azimuth offset of the cloud layer at time t, radians.
    fn cloud_offset(&self, t: f64) -> f64 {
        (self.cfg.cloud_drift_deg_per_s.to_radians() * t).rem_euclid(TAU)
    }

    /// Cloud cover of `tex` seen in direction `dir` at time t (0 without clouds or below the
    /// horizon's edge of the dome mapping).
    fn cover_at(&self, tex: &[f32], dir: DVec3, t: f64) -> f64 {
        if tex.is_empty() {
            return 0.0;
        }
        let theta = dir.y.clamp(-1.0, 1.0).acos();
        let phi = dir.x.atan2(-dir.z) + self.cloud_offset(t);
        let r = theta * CLOUD_DOME_TILES * CLOUD_TEX as f64 / FRAC_PI_2;
        let (x, y) = ((r * phi.cos()) as f32, (r * phi.sin()) as f32);
        bilinear_wrap(tex, x, y) as f64
    }

    /// Periodic fBm value noise → cover via a threshold at the (1 − clouds) quantile, so the cover
    /// fraction of the texture is `clouds`; plus a blurred copy for the sun's dimming.
    fn build_clouds(&mut self) {
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
        let cover = if self.cfg.clouds >= 1.0 {
            vec![1.0; n * n]
        } else {
            let mut sorted = noise.clone();
            let k = (((1.0 - self.cfg.clouds) * (n * n) as f64) as usize).min(n * n - 1);
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
        self.cover = cover;
        self.cover_soft = soft;
    }

    /// Renders sky row `j` into `px` (the model, then the drifting clouds); returns the
    /// horizontal-plane irradiance the row delivers to the ground (Σ L cos θ dω).
    fn sky_row(&self, frame: &SkyFrame, j: usize, px: &mut [[f32; 3]]) -> [f64; 3] {
        let w = px.len();
        let row = &self.rows[j];
        let (sx, sy, sz) = frame.sun;
        let ka = row.st * sx;
        let kb = row.st * sz;
        let kc = row.ct * sy;
        let a = row.a.map(|x| x * frame.fade);
        let ac = row.ac.map(|x| x * frame.fade);
        for (p, (&sp, &cp)) in px.iter_mut().zip(self.col_sin.iter().zip(&self.col_cos)) {
            let cos_gamma = ka * sp - kb * cp + kc;
            let g = gamma_lookup(&self.gamma_table, cos_gamma);
            for c in 0..3 {
                p[c] = (a[c] * g[c] + ac[c]).max(0.0) + NIGHT_RADIANCE[c];
            }
        }
        if !self.cover.is_empty() {
            let (n0, fs) = frame.cloud_shift;
            let cover = &self.cover_ll[j * w..(j + 1) * w];
            for (i, p) in px.iter_mut().enumerate() {
                let i0 = if i + n0 < w { i + n0 } else { i + n0 - w };
                let i1 = if i0 + 1 < w { i0 + 1 } else { 0 };
                let k = cover[i0] + fs * (cover[i1] - cover[i0]);
                for c in 0..3 {
                    p[c] += k * (frame.grey[c] - p[c]);
                }
            }
        }
        let mut row_sum = [0.0f32; 3];
        for p in px.iter() {
            for c in 0..3 {
                row_sum[c] += p[c];
            }
        }
        let weight = row.ct as f64 * row.d_omega;
        row_sum.map(|s| s as f64 * weight)
    }

    /// The lat-long pixels a disc of centre `centre` and angular radius `radius` (rad) covers,
    /// by exact area coverage, into `cover` as (pixel, covered solid angle, row), in pixel order:
    /// pixels entirely inside get full weight, pixels on the edge are supersampled (8×8 cells
    /// with a linear-ramp coverage of each cell). Returns the scale that normalises their total
    /// solid angle to the cap's 2π(1 − cos r) (0 when nothing is covered), so that the disc's
    /// ∫ L dω is radiance × cap solid angle at any resolution, even for sub-pixel discs.
    fn cover_cap(&self, cover: &mut Vec<(usize, f64, usize)>, centre: DVec3, radius: f64) -> f64 {
        let (w, h) = self.res;
        let (dtheta, dphi) = (PI / h as f64, TAU / w as f64);
        let theta_c = centre.y.clamp(-1.0, 1.0).acos();
        let phi_c = centre.x.atan2(-centre.z);
        let j0 = ((theta_c - radius) / dtheta).floor().max(0.0) as usize;
        let j1 = (((theta_c + radius) / dtheta).floor() as usize).min(h - 1);
        // Azimuth half-width of the cap over rows j0..=j1 (all columns near a pole).
        let (lo, hi) = (j0 as f64 * dtheta, (j1 + 1) as f64 * dtheta);
        let min_sin = lo.sin().min(hi.sin());
        let (i0, i1) = if lo <= 0.0 || hi >= PI || radius.sin() >= min_sin || radius >= FRAC_PI_2 {
            (0, w as i64 - 1)
        } else {
            let half = (radius.sin() / min_sin).asin();
            let a = ((phi_c - half + PI) / dphi).floor() as i64;
            let b = ((phi_c + half + PI) / dphi).floor() as i64;
            if b - a + 1 >= w as i64 {
                (0, w as i64 - 1)
            } else {
                (a, b)
            }
        };

        cover.clear();
        let mut total = 0.0;
        let n = EDGE_SUPERSAMPLE;
        for j in j0..=j1 {
            let t0 = j as f64 * dtheta;
            let t1 = t0 + dtheta;
            let d_omega = self.rows[j].d_omega;
            let sin_max = if t0 < FRAC_PI_2 && t1 > FRAC_PI_2 {
                1.0
            } else {
                t0.sin().max(t1.sin())
            };
            // Angular radius of the pixel around its centre (half diagonal, an upper bound).
            let r_pix = 0.5 * (dtheta * dtheta + (dphi * sin_max).powi(2)).sqrt();
            let theta = t0 + 0.5 * dtheta;
            for ii in i0..=i1 {
                let i = ii.rem_euclid(w as i64) as usize;
                let phi = (i as f64 + 0.5) * dphi - PI;
                let delta = angle_between(centre, lat_long_dir(theta, phi));
                let covered = if delta + r_pix <= radius {
                    d_omega
                } else if delta - r_pix >= radius {
                    continue;
                } else {
                    let mut covered = 0.0;
                    for a in 0..n {
                        let ta = t0 + dtheta * a as f64 / n as f64;
                        let tb = t0 + dtheta * (a + 1) as f64 / n as f64;
                        let cell = dphi / n as f64 * (ta.cos() - tb.cos());
                        let size = cell.sqrt();
                        let tm = 0.5 * (ta + tb);
                        for b in 0..n {
                            let pm = i as f64 * dphi - PI + dphi * (b as f64 + 0.5) / n as f64;
                            let ds = angle_between(centre, lat_long_dir(tm, pm));
                            covered += cell * (0.5 + (radius - ds) / size).clamp(0.0, 1.0);
                        }
                    }
                    covered
                };
                if covered > 0.0 {
                    total += covered;
                    cover.push((j * w + i, covered, j));
                }
            }
        }
        if total <= 0.0 {
            cover.clear();
            return 0.0;
        }
        cap_solid_angle(radius) / total
    }
}

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

/// A disc's coverage ([`SyntheticSky::cover_cap`]) being drawn batch by batch.
struct Disc {
    cover: Vec<(usize, f64, usize)>,
    scale: f64,
    /// Entries of `cover` already drawn.
    drawn: usize,
}

impl Disc {
    /// An empty disc reusing `buffer`.
    fn take(buffer: &mut Vec<(usize, f64, usize)>) -> Disc {
        let mut cover = std::mem::take(buffer);
        cover.clear();
        Disc {
            cover,
            scale: 0.0,
            drawn: 0,
        }
    }

    /// Adds the disc's uniform `radiance` to its pixels in the rows before `end_row` not yet
    /// drawn (with `sky_only`, skipping ground rows: the ground hides that part), and the
    /// horizontal-plane irradiance the drawn part delivers (Σ L cos θ dω) to `irradiance`.
    fn draw(
        &mut self,
        rows: &[Row],
        pixels: &mut [[f32; 3]],
        end_row: usize,
        radiance: [f32; 3],
        sky_only: bool,
        irradiance: &mut [f64; 3],
    ) {
        let todo = self.cover[self.drawn..].partition_point(|&(_, _, j)| j < end_row);
        for &(p, covered, j) in &self.cover[self.drawn..self.drawn + todo] {
            let row = &rows[j];
            if sky_only && !row.sky {
                continue;
            }
            let omega = covered * self.scale;
            let frac = (omega / row.d_omega) as f32;
            for c in 0..3 {
                pixels[p][c] += radiance[c] * frac;
                irradiance[c] += radiance[c] as f64 * omega * row.ct as f64;
            }
        }
        self.drawn += todo;
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
fn model_elevation(elev_deg: f64) -> f64 {
    let t = if elev_deg >= MODEL_KNEE_DEG {
        (elev_deg.min(90.0) / 90.0).cbrt()
    } else {
        let tk = (MODEL_KNEE_DEG / 90.0).cbrt();
        let slope = tk / (3.0 * MODEL_KNEE_DEG);
        (tk + slope * (elev_deg - MODEL_KNEE_DEG)).max(0.0)
    };
    FRAC_PI_2 * t * t * t
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

/// Relative optical air mass (Kasten & Young 1989), elevation in degrees, clamped just below the
/// horizon where the sun is hidden anyway.
fn air_mass(elev_deg: f64) -> f64 {
    let e = elev_deg.max(-0.5);
    1.0 / (e.to_radians().sin() + 0.50572 * (e + 6.07995).powf(-1.6364))
}

/// Rec. 709 luminance.
fn luminance(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Solid angle of a spherical cap of angular radius r: 2π(1 − cos r) = 4π sin²(r/2).
fn cap_solid_angle(r: f64) -> f64 {
    let s = (0.5 * r).sin();
    4.0 * PI * s * s
}

/// DESIGN.md lat-long direction for zenith angle θ and azimuth φ.
fn lat_long_dir(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * sp, ct, -st * cp)
}

/// Angle between unit vectors, accurate for small angles: 2 asin(|a − b| / 2).
fn angle_between(a: DVec3, b: DVec3) -> f64 {
    2.0 * (0.5 * (a - b).length()).min(1.0).asin()
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

/// The synthetic sky as a [`FrameSource`](super::FrameSource): frames at `fps`, sky time following
/// the wall clock, so the sun moves at its configured speed whatever the frame rate.
pub struct SyntheticSource {
    sky: SyntheticSky,
    fps: f64,
    start: std::time::Instant,
    next: std::time::Instant,
}

impl SyntheticSource {
    pub fn new(cfg: SyntheticConfig, fps: f64) -> Self {
        let now = std::time::Instant::now();
        SyntheticSource {
            sky: SyntheticSky::new(cfg),
            fps,
            start: now,
            next: now,
        }
    }
}

impl super::FrameSource for SyntheticSource {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, super::SourceError> {
        self.next_frame_by_rows(out, &mut |_, _| {})
    }

    fn next_frame_by_rows(
        &mut self,
        out: &mut EnvMap,
        rows: &mut dyn FnMut(&EnvMap, Range<usize>),
    ) -> Result<bool, super::SourceError> {
        super::pace(&mut self.next, self.fps);
        self.sky
            .render_by_rows(self.start.elapsed().as_secs_f64(), out, rows);
        Ok(true)
    }

    fn describe(&self) -> String {
        let c = self.sky.config();
        format!("synthetic:{}x{}", c.width, c.height)
    }

    fn nominal_fps(&self) -> f64 {
        self.fps
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Domain;

    fn sky(width: usize, f: impl FnOnce(&mut SyntheticConfig)) -> SyntheticSky {
        let mut cfg = SyntheticConfig {
            width,
            height: width / 2,
            ..SyntheticConfig::default()
        };
        f(&mut cfg);
        SyntheticSky::new(cfg)
    }

    /// ∫ L dω over the pixels above the horizon, with the solid angles of envmap.rs.
    fn upper_integral(map: &EnvMap) -> [f64; 3] {
        let mut sum = [0.0; 3];
        for j in 0..map.height / 2 {
            for i in 0..map.width {
                let (_, sr) = map.projection.pixel(i, j, map.width, map.height).unwrap();
                for c in 0..3 {
                    sum[c] += map.pixels[j * map.width + i][c] as f64 * sr;
                }
            }
        }
        sum
    }

    fn total(map: &EnvMap) -> f64 {
        luminance(map.integral(Domain::Sphere))
    }

    #[test]
    fn separable_model_matches_hw_skymodel() {
        let s = sky(64, |c| c.clouds = 0.0);
        for elev_deg in [0.0f64, 3.0, 20.0, 60.0, 89.0] {
            let mut s2 = sky(64, |c| c.clouds = 0.0);
            s2.set_model(elev_deg.to_radians());
            let state = SkyState::new(&SkyParams {
                elevation: elev_deg.to_radians() as f32,
                turbidity: s.cfg.turbidity as f32,
                albedo: [s.cfg.ground_albedo as f32; 3],
            })
            .unwrap();
            for theta_deg in [0.0f64, 30.0, 60.0, 85.0, 89.9] {
                let (fa, fac) = s2.row_terms(theta_deg.to_radians().cos());
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
                        let got = fa[c] * hw_g(&s2.params[9 * c..9 * c + 9], gamma) + fac[c];
                        let err = (got - want as f64).abs() / (want.abs() as f64).max(1e-3);
                        assert!(
                            err < 1e-3,
                            "e {elev_deg} θ {theta_deg} γ {gamma_deg}: {got} vs {want}"
                        );
                        // And the per-pixel table lookup.
                        let g = gamma_lookup(&s2.gamma_table, gamma.cos() as f32)[c] as f64;
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

    #[test]
    fn sun_follows_the_day_arc() {
        let s = sky(64, |_| {});
        assert!((s.sun_elevation_deg(0.0) - 5.0).abs() < 1e-9);
        let rise = s.next_sunrise(0.0);
        let period = s.period_s();
        assert!((period - 360.0).abs() < 1e-9);
        assert!(rise > 0.0 && rise < period, "{rise}");
        assert!(s.sun_elevation_deg(rise).abs() < 1e-9);
        let east = s.sun_direction(rise);
        assert!(
            (east - DVec3::X).length() < 1e-9,
            "rises in the east (+X): {east}"
        );
        let noon = rise + period / 4.0;
        assert!((s.sun_elevation_deg(noon) - NOON_ELEVATION_DEG).abs() < 1e-9);
        let d = s.sun_direction(noon);
        assert!(d.x.abs() < 1e-9 && d.z < 0.0, "culminates toward −Z: {d}");
        let set = rise + period / 2.0;
        assert!(s.sun_elevation_deg(set).abs() < 1e-9);
        assert!(
            (s.sun_direction(set) + DVec3::X).length() < 1e-9,
            "sets in the west"
        );
        assert!((s.sun_elevation_deg(rise + 0.75 * period) + NOON_ELEVATION_DEG).abs() < 1e-9);
        // Monotone rise to noon, periodic, unit length everywhere.
        let mut last = -1.0;
        for k in 0..=90 {
            let e = s.sun_elevation_deg(rise + period / 4.0 * k as f64 / 90.0);
            assert!(e > last - 1e-12);
            last = e;
        }
        for t in [0.0, 17.3, 1e3, 1e6] {
            let (a, b) = (s.sun_direction(t), s.sun_direction(t + period));
            assert!((a - b).length() < 1e-6 && (a.length() - 1.0).abs() < 1e-12);
        }
        assert!((s.next_sunrise(rise) - rise).abs() < 1e-9);
    }

    #[test]
    fn sun_is_the_brightest_pixel_in_its_direction() {
        for width in [256, 1024] {
            let mut s = sky(width, |c| c.switch_light = None);
            let rise = s.next_sunrise(0.0);
            for t in [rise + 30.0, rise + 90.0, rise + 150.0, 0.0] {
                let map = s.render(t);
                let (mut best, mut best_l) = (0, -1.0);
                for (k, p) in map.pixels.iter().enumerate() {
                    let l = EnvMap::luminance(*p);
                    if l > best_l {
                        (best, best_l) = (k, l);
                    }
                }
                let (i, j) = (best % map.width, best / map.width);
                let (dir, _) = map.projection.pixel(i, j, map.width, map.height).unwrap();
                let pixel = (PI / map.height as f64) * 2f64.sqrt();
                let err = angle_between(dir, s.sun_direction(t));
                assert!(
                    err <= pixel,
                    "width {width} t {t}: {err} rad off, pixel {pixel}"
                );
                // Brightest by far: the sun pixel outshines everything away from the sun.
                let mut others = 0.0f32;
                for (k, p) in map.pixels.iter().enumerate() {
                    let (ii, jj) = (k % map.width, k / map.width);
                    let (d, _) = map.projection.pixel(ii, jj, map.width, map.height).unwrap();
                    if angle_between(d, s.sun_direction(t)) > 5.0f64.to_radians() {
                        others = others.max(EnvMap::luminance(*p));
                    }
                }
                assert!(best_l > 10.0 * others, "sun {best_l} vs rest {others}");
            }
        }
    }

    #[test]
    fn sun_energy_is_exact_at_any_resolution() {
        for width in [256, 1024, 333 * 2] {
            for clouds in [0.0, 0.5] {
                let mut s = sky(width, |c| {
                    c.clouds = clouds;
                    c.switch_light = None;
                });
                let rise = s.next_sunrise(0.0);
                for t in [rise + 20.0, rise + 90.0, rise + 133.3] {
                    let with = upper_integral(&s.render(t));
                    s.draw_sun = false;
                    let without = upper_integral(&s.render(t));
                    s.draw_sun = true;
                    let radiance = s.sun_radiance(t);
                    let omega = SyntheticSky::sun_solid_angle();
                    for c in 0..3 {
                        let want = radiance[c] as f64 * omega;
                        let got = with[c] - without[c];
                        let rel = (got - want).abs() / want;
                        assert!(rel < 0.01, "w {width} t {t} c {c}: {got} vs {want}");
                    }
                }
            }
        }
        // The analytic cap: 0.53° across.
        let omega = SyntheticSky::sun_solid_angle();
        let r = (0.265f64).to_radians();
        assert!((omega - PI * r * r).abs() / omega < 1e-5);
    }

    #[test]
    fn sun_carries_the_documented_share_at_noon() {
        let mut s = sky(512, |c| {
            c.clouds = 0.0;
            c.switch_light = None;
        });
        let noon = s.next_sunrise(0.0) + s.period_s() / 4.0;
        let with = luminance(upper_integral(&s.render(noon)));
        s.draw_sun = false;
        let sky_only = luminance(upper_integral(&s.render(noon)));
        let ratio = (with - sky_only) / sky_only;
        assert!(
            (ratio - SUN_TO_SKY_RATIO).abs() < 0.05 * SUN_TO_SKY_RATIO,
            "{ratio}"
        );
    }

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

    #[test]
    fn switch_light_adds_exactly_its_energy() {
        let lamp = SwitchLight::default();
        for width in [128, 1024] {
            let mut with = sky(width, |_| {});
            let mut without = sky(width, |c| c.switch_light = None);
            for t in [1.0, 4.9, 5.1, 9.0, 61.0, 66.0] {
                let on = with.switch_light_on(t);
                assert_eq!(on, (t % 10.0) < 5.0);
                let d = total(&with.render(t)) - total(&without.render(t));
                let want = if on {
                    lamp.radiance as f64 * cap_solid_angle(lamp.radius_deg.to_radians())
                } else {
                    0.0
                };
                assert!(
                    (d - want).abs() <= 0.02 * want.max(1e-12),
                    "w {width} t {t}: {d} vs {want}"
                );
            }
        }
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

    #[test]
    fn clouds_cover_the_configured_fraction_and_drift() {
        let s = sky(64, |c| c.clouds = 0.3);
        let covered = s.cover.iter().map(|&v| v as f64).sum::<f64>() / s.cover.len() as f64;
        assert!((covered - 0.3).abs() < 0.03, "{covered}");
        let mut s = sky(128, |c| c.switch_light = None);
        let a = s.render(10.0);
        let b = s.render(10.0);
        assert_eq!(a.pixels, b.pixels, "deterministic");
        let c = s.render(20.0);
        assert_ne!(a.pixels, c.pixels);
    }

    /// Prints the energy budget of the default sky (`-- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn energy_budget() {
        let mut s = SyntheticSky::new(SyntheticConfig {
            switch_light: None,
            clouds: 0.0,
            ..SyntheticConfig::default()
        });
        let rise = s.next_sunrise(0.0);
        for (name, t) in [
            ("sunrise+10 s", rise + 10.0),
            ("morning", rise + 45.0),
            ("noon", rise + 90.0),
            ("midnight", rise + 270.0),
        ] {
            let m = s.render(t);
            let all = luminance(upper_integral(&m));
            s.draw_sun = false;
            let sky = luminance(upper_integral(&s.render(t)));
            s.draw_sun = true;
            let ground = EnvMap::luminance(m.pixels[m.pixels.len() - 1]);
            eprintln!(
                "{name}: elev {:.1}°, sky ∫L dω {sky:.4}, sun {:.4}, ground radiance {ground:.4}, \
                 sun radiance {:?}",
                s.sun_elevation_deg(t),
                all - sky,
                s.sun_radiance(t)
            );
        }
        let lamp = SwitchLight::default();
        eprintln!(
            "lamp ∫L dω {:.4}",
            lamp.radiance as f64 * cap_solid_angle(lamp.radius_deg.to_radians())
        );
    }

    /// This thread's time on a CPU (Linux schedstat, ns): robust to other processes sharing cores.
    fn thread_cpu_ns() -> Option<u64> {
        let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
        s.split_whitespace().next()?.parse().ok()
    }

    /// Prints the release-mode render time at 1024×512 (`cargo test --release --lib
    /// capture::synthetic::tests::render_time -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn render_time() {
        type Tweak = fn(&mut SyntheticConfig);
        let variants: [(&str, Tweak); 4] = [
            ("default", |_| {}),
            ("no clouds", |c| c.clouds = 0.0),
            ("no clouds, no lamp", |c| {
                c.clouds = 0.0;
                c.switch_light = None;
            }),
            ("static sun, no clouds, no lamp", |c| {
                c.clouds = 0.0;
                c.switch_light = None;
                c.sun_speed_deg_per_s = 0.0;
            }),
        ];
        for (name, f) in variants {
            let mut cfg = SyntheticConfig::default();
            f(&mut cfg);
            let mut s = SyntheticSky::new(cfg);
            let mut out = s.render(0.0);
            let frames = 300;
            let cpu0 = thread_cpu_ns();
            let start = std::time::Instant::now();
            for k in 0..frames {
                s.render_into(30.0 + k as f64 / 30.0, &mut out);
            }
            let ms = start.elapsed().as_secs_f64() * 1e3 / frames as f64;
            let cpu = match (cpu0, thread_cpu_ns()) {
                (Some(a), Some(b)) => {
                    format!("{:.3} ms on-CPU", (b - a) as f64 * 1e-6 / frames as f64)
                }
                _ => "on-CPU time unavailable".into(),
            };
            eprintln!(
                "render_into 1024×512 ({name}): {ms:.3} ms/frame wall, {cpu} (single thread)"
            );
        }
    }
}
