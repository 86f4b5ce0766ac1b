//! The synthetic dynamic sky: a lat-long HDR sky with exact ground truth, rendered at any time t.
//! Capture's default frame source (`vemlight serve` with no data, DESIGN.md "Processes and
//! endpoints") and the evaluation's hard skies and sun-path sequence both render it.
//!
//! Why it exists: no HDR *video* environment map is published anywhere we can depend on, yet the
//! capture daemon must run, and its lights must move, with no data and no camera. So it renders its
//! own: a Hosek-Wilkie clear sky (`hosek_wilkie.rs`) lit by a sun that travels a day arc
//! (`sun_path.rs`), an analytic 0.53° sun disk (`sun.rs`), drifting clouds (`clouds.rs`), a uniform
//! ground, and a lamp that switches on and off (`lamp.rs`), which exercises the temporal filter's
//! response to a step. `render.rs` composes them into a frame, row by row on the lat-long grid
//! (`grid.rs`); both discs are drawn by exact area coverage (`disc.rs`).
//!
//! Every frame has exact ground truth: [`SyntheticSky::sun_direction`], [`SyntheticSky::sun_radiance`]
//! and the lamp's radiance × cap solid angle, because both discs are rendered by exact area
//! coverage (their ∫ L dω equals radiance × solid angle of the cap at any resolution, even though
//! the sun is smaller than a pixel at 1024×512).
//!
//! Night and twilight: the model is valid for sun elevations 0..90°; below the horizon its sky
//! (at the horizon's parameters) fades by e per 3° of depression over a constant night floor, and
//! near the horizon its elevation input is smoothed (see `hosek_wilkie.rs`), so frames 1/30 s apart
//! never differ by more than ~1.5 % in total energy at the default speeds, sunrise included.
//!
//! Speed: a 1024×512 frame allocates nothing once warm; `cargo bench --bench sky` times it.

mod clouds;
mod disc;
mod grid;
mod hosek_wilkie;
mod lamp;
mod render;
mod sun;
mod sun_path;
#[cfg(test)]
mod testing;

use clouds::Clouds;
use grid::Grid;
use hosek_wilkie::HwModel;
use sun::Sun;
use sun_path::SunPath;

pub use lamp::SwitchLight;
pub use render::{NIGHT_RADIANCE, ROWS_PER_BATCH};
pub use sun::{SUN_ANGULAR_DIAMETER_DEG, SUN_TO_SKY_RATIO};
pub use sun_path::NOON_ELEVATION_DEG;

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
    clouds: Clouds,
    /// The clear-sky model at the current sun elevation.
    model: HwModel,
    /// The clear sky's mean luminance over the upper hemisphere, for the current model.
    sky_mean_lum: f32,
    /// Per-row and per-column tables of the current resolution.
    grid: Grid,
    /// The sun's and the lamp's disc coverage (see [`disc::cover_cap`]), kept between frames.
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
}

/// Rec. 709 luminance.
fn luminance(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}
