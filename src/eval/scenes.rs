//! Maps and sequences built for the evaluation: rotated real maps, an exposure ramp, a lamp switched
//! on, procedural skies with a Gaussian sun, and the hard cases of the stability table.
//!
//! Everything here is lat-long (DESIGN.md convention) and deterministic, so the tests of
//! tests/stability.rs see the same inputs as `vemlight eval`.

use crate::envmap::{EnvMap, Projection};
use glam::{DQuat, DVec3};
use std::f64::consts::PI;

/// Width and height of the procedural maps of the hard cases (pixels of 1.4°).
pub const HARD_W: usize = 256;
pub const HARD_H: usize = 128;

/// Radiance of a lat-long map along `dir`, bilinear between pixel centres (wrapping in φ, clamped
/// in θ): smooth in the direction, so a slowly rotated map changes smoothly too.
pub fn bilinear_along(map: &EnvMap, dir: DVec3) -> [f32; 3] {
    debug_assert_eq!(map.projection, Projection::LatLong);
    let (w, h) = (map.width as f64, map.height as f64);
    let theta = dir.y.clamp(-1.0, 1.0).acos();
    let phi = dir.x.atan2(-dir.z);
    let x = (phi / (2.0 * PI) + 0.5) * w - 0.5;
    let y = (theta / PI * h - 0.5).clamp(0.0, h - 1.0);
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = ((x - x0) as f32, (y - y0) as f32);
    let i0 = (x0 as i64).rem_euclid(map.width as i64) as usize;
    let i1 = (i0 + 1) % map.width;
    let j0 = y0 as usize;
    let j1 = (j0 + 1).min(map.height - 1);
    let p = |i: usize, j: usize| map.pixels[j * map.width + i];
    let mut out = [0.0f32; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let top = p(i0, j0)[c] * (1.0 - tx) + p(i1, j0)[c] * tx;
        let bottom = p(i0, j1)[c] * (1.0 - tx) + p(i1, j1)[c] * tx;
        *o = top * (1.0 - ty) + bottom * ty;
    }
    out
}

/// Per-pixel directions of a lat-long grid, computed once and reused for every frame.
pub struct LatLongDirs {
    pub width: usize,
    pub height: usize,
    dirs: Vec<DVec3>,
}

impl LatLongDirs {
    pub fn new(width: usize, height: usize) -> Self {
        let mut dirs = Vec::with_capacity(width * height);
        for j in 0..height {
            for i in 0..width {
                dirs.push(
                    Projection::LatLong
                        .pixel(i, j, width, height)
                        .expect("lat-long")
                        .0,
                );
            }
        }
        LatLongDirs {
            width,
            height,
            dirs,
        }
    }

    /// A map whose radiance along each pixel direction is `f(direction)`.
    pub fn map(&self, f: impl Fn(DVec3) -> [f32; 3]) -> EnvMap {
        let pixels = self.dirs.iter().map(|&d| f(d)).collect();
        EnvMap::from_pixels(self.width, self.height, pixels, Projection::LatLong)
            .expect("lat-long size")
    }

    /// `src` rotated by `rot` (the content seen along d is what `src` sees along rot⁻¹·d).
    pub fn rotated(&self, src: &EnvMap, rot: DQuat) -> EnvMap {
        let inv = rot.inverse();
        self.map(|d| bilinear_along(src, inv * d))
    }
}

/// Angle between two unit vectors, degrees (robust near 0).
pub fn angle_deg(a: DVec3, b: DVec3) -> f64 {
    2.0 * ((a - b).length() * 0.5).clamp(0.0, 1.0).asin().to_degrees()
}

/// A unit vector from elevation above the horizon and azimuth φ (DESIGN.md: φ = 0 looks along −Z,
/// φ = π/2 along +X), degrees.
pub fn dir_from_elev_azim(elev_deg: f64, azim_deg: f64) -> DVec3 {
    let theta = (90.0 - elev_deg).to_radians();
    let phi = azim_deg.to_radians();
    DVec3::new(
        theta.sin() * phi.sin(),
        theta.cos(),
        -theta.sin() * phi.cos(),
    )
}

/// A clear procedural sky: blue gradient above, grey ground below, and a Gaussian sun
/// (σ = `sun_sigma_deg`) toward `sun` whose ∫ L dω is `sun_share` of the whole map's.
pub struct SunSky {
    pub sun_sigma_deg: f64,
    pub sun_share: f64,
}

impl SunSky {
    fn sky(d: DVec3) -> [f32; 3] {
        if d.y >= 0.0 {
            let t = d.y as f32;
            [0.35 + 0.25 * t, 0.5 + 0.3 * t, 0.9 + 0.3 * t]
        } else {
            [0.12, 0.11, 0.1]
        }
    }

    /// The map with the sun toward `sun` (a unit vector).
    pub fn render(&self, dirs: &LatLongDirs, sun: DVec3) -> EnvMap {
        let sky = dirs.map(Self::sky);
        let sky_lum = lum_integral(&sky);
        // A Gaussian bump exp(−γ²/2σ²) has ∫ dω ≈ 2πσ² for small σ.
        let s = self.sun_sigma_deg.to_radians();
        let bump_integral = 2.0 * PI * s * s;
        let amp = (self.sun_share / (1.0 - self.sun_share) * sky_lum / bump_integral) as f32;
        let warm = [1.0f32, 0.95, 0.85];
        let lum_warm = EnvMap::luminance(warm);
        dirs.map(|d| {
            let g = angle_deg(d, sun).to_radians();
            let bump = amp * (-(g * g) / (2.0 * s * s)).exp() as f32 / lum_warm;
            let b = Self::sky(d);
            [
                b[0] + bump * warm[0],
                b[1] + bump * warm[1],
                b[2] + bump * warm[2],
            ]
        })
    }
}

/// ∫ Y dω over the whole lat-long map.
pub fn lum_integral(map: &EnvMap) -> f64 {
    let mut s = 0.0;
    for j in 0..map.height {
        let sr = Projection::LatLong
            .pixel(0, j, map.width, map.height)
            .expect("lat-long")
            .1;
        for i in 0..map.width {
            s += EnvMap::luminance(map.pixels[j * map.width + i]) as f64 * sr;
        }
    }
    s
}

/// `map` with a lamp: a disc of uniform grey radiance of the given angular radius toward `dir`,
/// its radiance chosen so the lamp's ∫ L dω is `share` of the map's ∫ L dω before it is added.
pub fn with_lamp(map: &EnvMap, dir: DVec3, radius_deg: f64, share: f64) -> EnvMap {
    let cos_r = radius_deg.to_radians().cos();
    let total = lum_integral(map);
    // The pixels inside the cap, found once, and the cap's solid angle.
    let mut cap_sr = 0.0;
    let mut cap = Vec::new();
    for j in 0..map.height {
        for i in 0..map.width {
            let (d, sr) = map
                .projection
                .pixel(i, j, map.width, map.height)
                .expect("lat-long");
            if d.dot(dir) >= cos_r {
                cap_sr += sr;
                cap.push(j * map.width + i);
            }
        }
    }
    let radiance = if cap_sr > 0.0 {
        (share * total / cap_sr) as f32
    } else {
        0.0
    };
    let mut out = map.clone();
    for k in cap {
        for c in &mut out.pixels[k] {
            *c += radiance;
        }
    }
    out
}

/// Every pixel scaled by `gain`.
pub fn scaled(map: &EnvMap, gain: f32) -> EnvMap {
    let mut out = map.clone();
    for p in &mut out.pixels {
        for c in p.iter_mut() {
            *c *= gain;
        }
    }
    out
}

/// The synthetic hard skies of the evaluation, `width` × `width/2` lat-long: the built-in
/// Hosek-Wilkie sky with a sun of the real 0.53° and the model's energy and circumsolar glare
/// (low and high, clear and hazy, one with clouds), and a room lit by a window and a lamp — the
/// cases the shared maps have few of.
pub fn hard_skies(width: usize) -> Vec<(String, EnvMap)> {
    let sky = |elev, turbidity, clouds| still_sky(width, elev, turbidity, clouds);
    vec![
        ("sky-low-clear".into(), sky(6.0, 2.0, 0.0)),
        ("sky-high-clear".into(), sky(55.0, 2.0, 0.0)),
        ("sky-low-hazy".into(), sky(12.0, 8.0, 0.0)),
        ("sky-high-hazy-clouds".into(), sky(40.0, 6.0, 0.4)),
        ("room-window-lamp".into(), room(width)),
    ]
}

/// The built-in sky (Hosek-Wilkie with a real-size sun) at one instant, `width` × `width`/2: the sun
/// `elevation` degrees up, the given turbidity and cloud cover, nothing moving.
pub fn still_sky(width: usize, elevation: f64, turbidity: f64, clouds: f64) -> EnvMap {
    still_sky_model(width, elevation, turbidity, clouds).render(0.0)
}

/// The sky model behind [`still_sky`] (render it at t = 0; `sun_direction(0.0)` is its sun).
pub fn still_sky_model(
    width: usize,
    elevation: f64,
    turbidity: f64,
    clouds: f64,
) -> crate::sky::SyntheticSky {
    use crate::sky::{SyntheticConfig, SyntheticSky};
    SyntheticSky::new(SyntheticConfig {
        width,
        height: width / 2,
        start_elevation_deg: elevation,
        sun_speed_deg_per_s: 0.0,
        turbidity,
        clouds,
        cloud_drift_deg_per_s: 0.0,
        switch_light: None,
        ..SyntheticConfig::default()
    })
}

/// A kind of scene lit by compact and large lamps, drawn at random by [`lamp_scene`]: the hard
/// cases the real maps and the sky sweep have few of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LampScene {
    /// A night street: a dark sky and ground, a moon (0.26°) 10–70° up, and 2–13 street lamps
    /// (0.3–1.5°) 2–42° up, each adding 3–33 % of the light already there.
    Night,
    /// A room lit by 4–15 ceiling lamps (0.8–3.3°) 35–85° up over dim walls, each adding 5–25 %.
    Ceiling,
    /// A studio: 2–4 softboxes of even radiance (4–16°) 5–55° up over a dark room, each adding
    /// 50–250 %, and a small bright lamp (0.5°).
    Softboxes,
}

impl LampScene {
    pub const ALL: [LampScene; 3] = [LampScene::Night, LampScene::Ceiling, LampScene::Softboxes];

    pub fn name(self) -> &'static str {
        match self {
            LampScene::Night => "night-street",
            LampScene::Ceiling => "ceiling-lamps",
            LampScene::Softboxes => "softboxes",
        }
    }
}

/// A `width` × `width`/2 lat-long scene of `kind`, its lamps drawn from `seed` (a fixed generator,
/// so a seed is the same scene on every machine).
pub fn lamp_scene(kind: LampScene, seed: u64, width: usize) -> EnvMap {
    let mut state = seed.wrapping_mul(7919).wrapping_add(13);
    let mut uniform = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let dirs = LatLongDirs::new(width, width / 2);
    match kind {
        LampScene::Night => {
            let mut map = dirs.map(|d| {
                if d.y >= 0.0 {
                    let t = d.y as f32;
                    [0.002 + 0.001 * (1.0 - t), 0.003 + 0.001 * (1.0 - t), 0.006]
                } else {
                    [0.0015, 0.0014, 0.0012]
                }
            });
            let elev = 10.0 + 60.0 * uniform();
            let azim = 360.0 * uniform();
            map = with_lamp(&map, dir_from_elev_azim(elev, azim), 0.26, 0.3 + uniform());
            for _ in 0..2 + (uniform() * 12.0) as usize {
                let (elev, radius) = (2.0 + 40.0 * uniform(), 0.3 + 1.2 * uniform());
                let dir = dir_from_elev_azim(elev, 360.0 * uniform());
                map = with_lamp(&map, dir, radius, 0.03 + 0.3 * uniform());
            }
            map
        }
        LampScene::Ceiling => {
            let mut map = dirs.map(|d| {
                let wall = if d.y < -0.3 { 0.04 } else { 0.06 };
                [wall, wall * 0.97, wall * 0.9]
            });
            for _ in 0..4 + (uniform() * 12.0) as usize {
                let (elev, radius) = (35.0 + 50.0 * uniform(), 0.8 + 2.5 * uniform());
                let dir = dir_from_elev_azim(elev, 360.0 * uniform());
                map = with_lamp(&map, dir, radius, 0.05 + 0.2 * uniform());
            }
            map
        }
        LampScene::Softboxes => {
            let mut map = dirs.map(|_| [0.01, 0.01, 0.01]);
            for _ in 0..2 + (uniform() * 3.0) as usize {
                let (elev, radius) = (5.0 + 50.0 * uniform(), 4.0 + 12.0 * uniform());
                let dir = dir_from_elev_azim(elev, 360.0 * uniform());
                map = with_lamp(&map, dir, radius, 0.5 + 2.0 * uniform());
            }
            let dir = dir_from_elev_azim(20.0 + 40.0 * uniform(), 360.0 * uniform());
            with_lamp(&map, dir, 0.5, 0.2)
        }
    }
}

/// A room lit by a window and a lamp: dim walls, a brighter floor patch, a window of bright
/// daylight on the −Z wall (about 30° × 30°), and a small ceiling lamp (1° radius) carrying 40 %
/// of the room's other light.
pub fn room(width: usize) -> EnvMap {
    let dirs = LatLongDirs::new(width, width / 2);
    let base = dirs.map(|d| {
        let wall = if d.y < -0.3 { 0.05 } else { 0.08 };
        let ahead = -d.z;
        let window = ahead > 0.5 && (d.x / ahead).abs() < 0.3 && {
            let up = d.y / ahead;
            (0.05..0.6).contains(&up)
        };
        if window {
            [2.6, 3.0, 3.6]
        } else {
            [wall, wall * 0.95, wall * 0.9]
        }
    });
    with_lamp(&base, dir_from_elev_azim(65.0, 120.0), 1.0, 0.4)
}
