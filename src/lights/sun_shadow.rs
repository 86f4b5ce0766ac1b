//! The sun's shadow from the sun (ALGORITHMS.md §12, "Shadow direction"): a single map's
//! brightest compact light casts its shadow from the centroid of the source pixels around it.
//!
//! A light stands at its cell's centroid, and the sky a sun's cell holds beside the sun pulls it
//! a tenth of a degree or two off the sun: enough to light or shade whole the probes on the edge
//! of a shadow (EVALUATION.md, "The sun's shadow given its own direction"). The domain's texels
//! (about 1°) cannot place the sun closer than that, so the direction comes from the source
//! pixels within [`RADIUS_DEG`] of the light. Shading keeps the light's own direction, so the
//! diffuse error is untouched; the shadow direction rides in the two-part extent's core (§12).

use super::light::{Light, LightExtent};
use crate::envmap::{EnvMap, Projection};
use glam::DVec3;

/// Pixels within this angle of the light make its shadow's direction: the sun (0.27° in radius)
/// and its nearest glow, little of the sky beside it.
pub const RADIUS_DEG: f64 = 3.0;

/// Only a light of at most this angular radius is a compact source whose shadow is hard enough
/// for a tenth of a degree to matter.
pub const MAX_LIGHT_RADIUS_DEG: f32 = 2.0;

/// Where the pixels around the light hold more than this many times its energy, the source is
/// shared between lights (a lamp split at many lights), and their centroid is not this light's.
pub const SHARED_SOURCE_RATIO: f64 = 1.1;

/// Centroid iterations: each re-centres the window on the last centroid.
const ITERATIONS: usize = 3;

/// The core's share of the light in the extent that carries the shadow direction: one disc of
/// the light's own radius, all of its shadow from the sun's direction.
const CORE_SHARE: f32 = 0.999;

/// Gives the brightest light of `lights`, if compact, above the horizon and drawn as one disc, a
/// shadow direction from `map`'s pixels (see the module documentation). Other lights are
/// untouched.
pub fn aim_sun_shadow(map: &EnvMap, lights: &mut [Light]) {
    let Some(k) =
        (0..lights.len()).max_by(|&a, &b| lights[a].luminance().total_cmp(&lights[b].luminance()))
    else {
        return;
    };
    let light = lights[k];
    // A light with a two-part extent already draws its core's shadow from the core (§12).
    if light.extent.is_some()
        || light.to_light[1] <= 0.0
        || light.angular_radius.to_degrees() > MAX_LIGHT_RADIUS_DEG
        || light.luminance() <= 0.0
    {
        return;
    }
    let Some((centre, energy)) = centroid_near(map, light.dir(), RADIUS_DEG.to_radians()) else {
        return;
    };
    if energy > SHARED_SOURCE_RATIO * light.luminance() || centre.y <= 0.0 {
        return;
    }
    lights[k].extent = Some(LightExtent {
        core_share: CORE_SHARE,
        core_radius: light.angular_radius,
        rest_radius: light.angular_radius,
        core_to_light: Some(centre.as_vec3().to_array()),
    });
}

/// How far the centre may move from where the pixels were gathered before they are gathered
/// again: the light starts a tenth of a degree or two off the sun.
const MARGIN: f64 = 1.0 * std::f64::consts::PI / 180.0;

/// The luminance-weighted centroid of `map`'s pixels above the horizon within `radius` of
/// `start`, re-centred [`ITERATIONS`] times, and their luminance × sr; `None` where none is lit.
pub fn centroid_near(map: &EnvMap, start: DVec3, radius: f64) -> Option<(DVec3, f64)> {
    let cos_r = radius.cos();
    let mut centre = start.normalize();
    // The lit pixels within `radius` + MARGIN of `anchor` (direction, luminance × sr), so that
    // the re-centred windows are dot products over one gathered list.
    let mut anchor = centre;
    let mut lit = lit_pixels_near(map, anchor, radius + MARGIN);
    let mut energy = 0.0;
    for _ in 0..ITERATIONS {
        if centre.dot(anchor) < MARGIN.cos() {
            anchor = centre;
            lit = lit_pixels_near(map, anchor, radius + MARGIN);
        }
        let mut moment = DVec3::ZERO;
        energy = 0.0;
        for &(dir, e) in &lit {
            if dir.dot(centre) > cos_r {
                moment += dir * e;
                energy += e;
            }
        }
        centre = moment.try_normalize()?;
    }
    Some((centre, energy))
}

/// `map`'s lit pixels above the horizon within `radius` of `centre`: (direction, luminance × sr).
fn lit_pixels_near(map: &EnvMap, centre: DVec3, radius: f64) -> Vec<(DVec3, f64)> {
    use std::f64::consts::PI;
    let cos_r = radius.cos();
    let (w, h) = (map.width, map.height);
    let mut out = Vec::new();
    let mut take = |i: usize, j: usize, dir: DVec3, sr: f64| {
        if dir.y > 0.0 && dir.dot(centre) > cos_r {
            let y = EnvMap::luminance(map.pixels[j * w + i]) as f64;
            if y > 0.0 && y.is_finite() {
                out.push((dir, y * sr));
            }
        }
    };
    match map.projection {
        Projection::LatLong => {
            // A band of rows, and of columns away from the poles; each row's and column's
            // sines and cosines taken once (the same values as `Projection::pixel`).
            let theta = centre.y.clamp(-1.0, 1.0).acos();
            let row = |t: f64| ((t / PI * h as f64).floor().max(0.0) as usize).min(h);
            let rows = row(theta - radius)..(row(theta + radius) + 1).min(h);
            let near_pole = theta - radius <= 0.0 || theta + radius >= PI;
            let cols: Vec<usize> = if near_pole {
                (0..w).collect()
            } else {
                // The widest span of longitude within the band: at its row nearest a pole.
                let s = (theta - radius).sin().min((theta + radius).sin());
                let half = (radius.sin() / s).clamp(-1.0, 1.0).asin();
                let phi = centre.x.atan2(-centre.z);
                let col = |p: f64| ((p / (2.0 * PI) + 0.5) * w as f64).floor() as i64;
                let (lo, hi) = (col(phi - half) - 1, col(phi + half) + 1);
                if hi - lo + 1 >= w as i64 {
                    (0..w).collect()
                } else {
                    (lo..=hi).map(|c| c.rem_euclid(w as i64) as usize).collect()
                }
            };
            let col_sc: Vec<(f64, f64)> = cols
                .iter()
                .map(|&i| (2.0 * PI * ((i as f64 + 0.5) / w as f64 - 0.5)).sin_cos())
                .collect();
            for j in rows {
                let (st, ct) = (PI * (j as f64 + 0.5) / h as f64).sin_cos();
                let t0 = PI * j as f64 / h as f64;
                let t1 = PI * (j + 1) as f64 / h as f64;
                let sr = 2.0 * PI / w as f64 * (t0.cos() - t1.cos());
                for (&i, &(sp, cp)) in cols.iter().zip(&col_sc) {
                    take(i, j, DVec3::new(st * sp, ct, -st * cp), sr);
                }
            }
        }
        _ => {
            // A square about the pixel that sees `centre`, 1.5 times as wide as `radius` in
            // that pixel's own size (its geometric mean): a fisheye's pixels are at most √2
            // (equisolid) or π/2 (equidistant, 1.25 × the mean) times longer one way.
            let Some((ci, cj)) = map.pixel_along(centre) else {
                return out;
            };
            let size = map
                .projection
                .pixel(ci, cj, w, h)
                .map_or(0.0, |(_, sr)| sr.sqrt());
            let half = if size > 0.0 {
                (1.5 * radius / size).ceil() as usize + 2
            } else {
                w.max(h)
            };
            for j in cj.saturating_sub(half)..(cj + half + 1).min(h) {
                for i in ci.saturating_sub(half)..(ci + half + 1).min(w) {
                    if let Some((dir, sr)) = map.projection.pixel(i, j, w, h) {
                        take(i, j, dir, sr);
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2048×1024 lat-long map: a dim sky, a sun of 0.27° radius at `sun`, and a bright patch
    /// `patch_deg` from it along the horizon's direction (sky a sun's cell might hold).
    fn sky_with_sun(sun: DVec3, patch_deg: f64) -> EnvMap {
        let (w, h) = (2048, 1024);
        let side = sun.cross(DVec3::Y).normalize();
        let patch =
            (sun * patch_deg.to_radians().cos() + side * patch_deg.to_radians().sin()).normalize();
        let proj = Projection::LatLong;
        let pixels = (0..w * h)
            .map(|p| {
                let (dir, _) = proj.pixel(p % w, p / w, w, h).expect("lat-long");
                let y = if dir.dot(sun) > 0.27f64.to_radians().cos() {
                    50_000.0
                } else if dir.dot(patch) > 1.5f64.to_radians().cos() {
                    200.0
                } else {
                    1.0
                };
                [y; 3]
            })
            .collect();
        EnvMap::from_pixels(w, h, pixels, proj).expect("valid map")
    }

    fn angle_deg(a: DVec3, b: DVec3) -> f64 {
        a.normalize()
            .dot(b.normalize())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    }

    fn light_toward(dir: DVec3, luminance: f32, radius_deg: f32) -> Light {
        Light {
            id: 0,
            to_light: dir.normalize().as_vec3().to_array(),
            irradiance: [luminance; 3],
            solid_angle: 1e-4,
            angular_radius: radius_deg.to_radians(),
            extent: None,
            shadowed: None,
        }
    }

    #[test]
    fn the_centroid_finds_the_sun_beside_a_patch_of_sky() {
        let sun = DVec3::new(0.3, 0.6, -0.74).normalize();
        let map = sky_with_sun(sun, 6.0);
        // Started 0.5° off, the window re-centres on the sun; the patch 6° away stays outside.
        let start = (sun + 0.5f64.to_radians() * sun.cross(DVec3::X).normalize()).normalize();
        let (c, energy) = centroid_near(&map, start, RADIUS_DEG.to_radians()).expect("lit");
        // The window missed no pixel: every pixel of the map within 3° of the centroid, summed.
        let cos_r = RADIUS_DEG.to_radians().cos();
        let (mut moment, mut full) = (DVec3::ZERO, 0.0);
        for j in 0..map.height {
            for i in 0..map.width {
                let (dir, sr) = map
                    .projection
                    .pixel(i, j, map.width, map.height)
                    .expect("lat-long");
                if dir.y > 0.0 && dir.dot(c) > cos_r {
                    let y = EnvMap::luminance(map.pixels[j * map.width + i]) as f64 * sr;
                    moment += dir * y;
                    full += y;
                }
            }
        }
        assert!(
            angle_deg(c, moment) < 1e-6,
            "{} deg from the full sum",
            angle_deg(c, moment)
        );
        assert!(
            (energy / full - 1.0).abs() < 1e-9,
            "energy {energy}, full sum {full}"
        );
        // The sun is drawn in pixels of 0.18°, a few across; its drawn centroid lies within a
        // fraction of a pixel of its direction, inside the tenth of a degree that matters.
        assert!(angle_deg(c, sun) < 0.05, "{} deg off", angle_deg(c, sun));
    }

    #[test]
    fn a_fisheye_window_misses_no_pixel_near_the_rim() {
        // A sun 12° over the horizon, near the image circle's rim, where a fisheye's pixels are
        // widest across the radius.
        let sun = DVec3::new(0.6, 12f64.to_radians().sin(), -0.75).normalize();
        let fisheye = Projection::Fisheye {
            lens: crate::envmap::Lens::Equisolid,
            fov_deg: 180.0,
            centre: None,
            radius: None,
        };
        let map = sky_with_sun(sun, 6.0).reproject(fisheye, 640, 480);
        let (c, energy) = centroid_near(&map, sun, RADIUS_DEG.to_radians()).expect("lit");
        let cos_r = RADIUS_DEG.to_radians().cos();
        let (mut moment, mut full) = (DVec3::ZERO, 0.0);
        for j in 0..map.height {
            for i in 0..map.width {
                if let Some((dir, sr)) = map.projection.pixel(i, j, map.width, map.height)
                    && dir.y > 0.0
                    && dir.dot(c) > cos_r
                {
                    let y = EnvMap::luminance(map.pixels[j * map.width + i]) as f64 * sr;
                    moment += dir * y;
                    full += y;
                }
            }
        }
        assert!(
            angle_deg(c, moment) < 1e-6,
            "{} deg from the full sum",
            angle_deg(c, moment)
        );
        assert!(
            (energy / full - 1.0).abs() < 1e-9,
            "energy {energy}, full sum {full}"
        );
    }

    #[test]
    fn the_brightest_compact_light_casts_its_shadow_from_the_sun() {
        let sun = DVec3::new(-0.5, 0.35, 0.4).normalize();
        let map = sky_with_sun(sun, 6.0);
        let (_, energy) = centroid_near(&map, sun, RADIUS_DEG.to_radians()).expect("lit");
        // The sun's light pulled 0.2° toward the patch, as its cell's centroid would be.
        let side = sun.cross(DVec3::Y).normalize();
        let pulled = (sun + 0.2f64.to_radians() * side).normalize();
        let mut lights = vec![
            light_toward(pulled, energy as f32, 0.7),
            light_toward(DVec3::new(0.0, 1.0, 0.1), 0.5 * energy as f32, 20.0),
        ];
        let before = lights.clone();
        aim_sun_shadow(&map, &mut lights);
        let e = lights[0]
            .extent
            .expect("the sun's light carries a shadow direction");
        let core = e.core_dir().expect("core direction");
        assert!(
            angle_deg(core, sun) < 0.05,
            "{} deg off",
            angle_deg(core, sun)
        );
        // Shading, energy and the other light are as they were.
        assert_eq!(lights[0].to_light, before[0].to_light);
        assert_eq!(lights[0].irradiance, before[0].irradiance);
        assert_eq!(lights[1], before[1]);
    }

    #[test]
    fn a_wide_or_shared_light_keeps_its_own_shadow() {
        let sun = DVec3::new(0.2, 0.5, -0.8).normalize();
        let map = sky_with_sun(sun, 6.0);
        let (_, energy) = centroid_near(&map, sun, RADIUS_DEG.to_radians()).expect("lit");
        // Too wide to cast a hard shadow.
        let mut wide = vec![light_toward(sun, energy as f32, 5.0)];
        aim_sun_shadow(&map, &mut wide);
        assert!(wide[0].extent.is_none());
        // Holding half of what lies around it: the source is shared with another light.
        let mut shared = vec![light_toward(sun, 0.5 * energy as f32, 0.5)];
        aim_sun_shadow(&map, &mut shared);
        assert!(shared[0].extent.is_none());
        // Below the horizon: nothing to cast on the ground.
        let mut below = vec![light_toward(
            DVec3::new(0.2, -0.5, -0.8),
            energy as f32,
            0.5,
        )];
        aim_sun_shadow(&map, &mut below);
        assert!(below[0].extent.is_none());
    }
}
