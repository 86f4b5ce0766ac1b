//! The synthetic dynamic sky: a lat-long HDR sky with exact ground truth, rendered at any time t.
//! Capture's default frame source (`vemlight serve` with no data, DESIGN.md "Processes and
//! endpoints") and the evaluation's hard skies and sun-path sequence both render it.
//!
//! Why it exists: no HDR *video* environment map is published anywhere we can depend on, yet the
//! capture daemon must run, and its lights must move, with no data and no camera. So it renders its
//! own: a Hosek-Wilkie clear sky (`hosek_wilkie.rs`) lit by a sun that travels a day arc
//! (`sun_path.rs`), an analytic 0.53° sun disk (`sun.rs`), drifting clouds (`clouds.rs`), a uniform
//! ground, and a lamp that switches on and off (`lamp.rs`), which exercises the temporal filter's
//! response to a step. `synthetic.rs` holds the configuration and [`SyntheticSky`], which keeps
//! each part's state and composes a frame from them (`render.rs`: the layers and the sky rows),
//! row by row on the lat-long grid (`grid.rs`); both discs are drawn by exact area coverage
//! (`disc.rs`). Each part takes plain parameters and imports none of `synthetic.rs`.
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
mod synthetic;
#[cfg(test)]
mod testing;

pub use lamp::SwitchLight;
pub use render::{NIGHT_RADIANCE, ROWS_PER_BATCH};
pub use sun::{SUN_ANGULAR_DIAMETER_DEG, SUN_TO_SKY_RATIO};
pub use sun_path::NOON_ELEVATION_DEG;
pub use synthetic::{SyntheticConfig, SyntheticSky};
