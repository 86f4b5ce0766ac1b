//! Shadowed accuracy: irradiance on the ground under occluders, what a client draws (ALGORITHMS.md §9).
//!
//! A scene is a ground plane y = 0 with a few occluders (spheres, boxes, thin poles) standing on it
//! or floating above it, and probes on a grid of ground points around them (normal +Y). The
//! reference sums every source pixel above the horizon with exact ray–occluder visibility:
//! E(p) = Σ L·ω_y·V(p, ω)·Δω. From lights, E_N(p) = Σ_k Y_k·max(0, l_y)·V̄_k(p), where V̄_k is the
//! visibility averaged over the light's disc of angular radius `angular_radius` (§12) by a fixed
//! spiral of [`CONE_SAMPLES`] rays, or the one ray along `to_light` for a point light. The error is
//! the relative RMS over the probes, √(Σ(E_N − E)²)/√(ΣE²), in luminance, as for the diffuse error.

use crate::envmap::EnvMap;
pub use crate::lights::shadow::{
    CONE_SAMPLES, Occluder, ShadowReference, ShadowScene, disc_rays, lights_irradiance,
};
use glam::DVec3;

/// The occluder scenes of the evaluation: compact and large, resting and floating, thin and wide,
/// so that both a compact sun's penumbra and the sky's soft shadows are probed. `step` is the probe
/// spacing in metres (0.25 in `vemlight eval`).
pub fn scenes(step: f64) -> Vec<ShadowScene> {
    let v = DVec3::new;
    vec![
        ShadowScene::new(
            "spheres",
            vec![
                Occluder::Sphere {
                    centre: v(0.0, 0.5, 0.0),
                    radius: 0.5,
                },
                Occluder::Sphere {
                    centre: v(1.3, 0.9, 0.8),
                    radius: 0.25,
                },
            ],
            2.5,
            step,
        ),
        ShadowScene::new(
            "box-and-table",
            vec![
                Occluder::Box {
                    min: v(-1.2, 0.0, -0.4),
                    max: v(-0.4, 0.8, 0.4),
                },
                // A table top floating 0.75 m above the ground.
                Occluder::Box {
                    min: v(0.3, 0.72, -0.6),
                    max: v(1.5, 0.77, 0.6),
                },
            ],
            2.5,
            step,
        ),
        ShadowScene::new(
            "poles",
            [v(-1.0, 0.0, 0.5), v(0.2, 0.0, -0.7), v(1.1, 0.0, 0.6)]
                .into_iter()
                .map(|b| Occluder::Box {
                    min: b - v(0.04, 0.0, 0.04),
                    max: b + v(0.04, 2.0, 0.04),
                })
                .collect(),
            2.5,
            step,
        ),
    ]
}

/// Sub-samples per side of a bright pixel in [`sky_emitters`].
pub const BRIGHT_SUBSAMPLES: usize = 4;
/// Pixels of at least this fraction of the map's brightest are integrated over their area.
pub const BRIGHT_FRACTION: f32 = 1e-3;

/// Emitters above the horizon (unit direction, luminance × sr × ω_y): every pixel of `map` with
/// ω_y > 0. A pixel stands for radiance over its solid angle, not at a point: on a lat-long map
/// the bright pixels (at least [`BRIGHT_FRACTION`] of the brightest — a sun or a lamp a few
/// pixels across, whose penumbra the probes resolve) are each split into
/// [`BRIGHT_SUBSAMPLES`]² emitters over their area, so that a sun drawn into four pixels casts
/// the penumbra of its disc rather than the four overlapping hard shadows of four points.
pub fn sky_emitters(map: &EnvMap) -> Vec<(DVec3, f64)> {
    use crate::envmap::Projection;
    let peak = map
        .pixels
        .iter()
        .map(|&p| EnvMap::luminance(p))
        .fold(0.0f32, f32::max);
    let (w, h) = (map.width as f64, map.height as f64);
    let latlong_dir = |x: f64, y: f64| {
        let (st, ct) = (std::f64::consts::PI * y / h).sin_cos();
        let (sp, cp) = (2.0 * std::f64::consts::PI * (x / w - 0.5)).sin_cos();
        DVec3::new(st * sp, ct, -st * cp)
    };
    let mut out = Vec::new();
    for j in 0..map.height {
        for i in 0..map.width {
            let Some((d, sr)) = map.projection.pixel(i, j, map.width, map.height) else {
                continue;
            };
            let y = EnvMap::luminance(map.pixels[j * map.width + i]);
            if y <= 0.0 {
                continue;
            }
            if map.projection == Projection::LatLong && y >= BRIGHT_FRACTION * peak {
                let k = BRIGHT_SUBSAMPLES;
                // Sub-pixel solid angles ∝ sin θ at each sub-row, normalised to the pixel's.
                let subs: Vec<(DVec3, f64)> = (0..k * k)
                    .map(|s| {
                        let (u, v) = ((s % k) as f64 + 0.5, (s / k) as f64 + 0.5);
                        let y_pix = j as f64 + v / k as f64;
                        let dir = latlong_dir(i as f64 + u / k as f64, y_pix);
                        (dir, (std::f64::consts::PI * y_pix / h).sin())
                    })
                    .collect();
                let norm: f64 = subs.iter().map(|s| s.1).sum();
                for (dir, wgt) in subs {
                    if dir.y > 0.0 && norm > 0.0 {
                        out.push((dir, y as f64 * sr * wgt / norm * dir.y));
                    }
                }
            } else if d.y > 0.0 {
                out.push((d, y as f64 * sr * d.y));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;
    use crate::lights::{Light, LightExtent};
    use glam::DQuat;

    fn light(d: DVec3, y: f32, radius: f32) -> Light {
        Light {
            id: 0,
            to_light: d.normalize().as_vec3().to_array(),
            irradiance: [y; 3],
            solid_angle: 0.0,
            angular_radius: radius,
            extent: None,
            shadowed: None,
        }
    }

    /// A map that is one small bright disc: its reference equals a light at the disc with the
    /// disc's radius (cone-averaged visibility), and beats the point light at the penumbra.
    #[test]
    fn a_disc_source_is_matched_by_a_light_with_its_radius() {
        let (w, h) = (1024, 512);
        let sun = DVec3::new(0.3, 0.8, -0.4).normalize();
        let r = 2.0f64.to_radians();
        let mut pixels = vec![[0.0f32; 3]; w * h];
        let mut energy = 0.0;
        for j in 0..h {
            for i in 0..w {
                let (d, sr) = Projection::LatLong.pixel(i, j, w, h).unwrap();
                if d.dot(sun) >= r.cos() {
                    pixels[j * w + i] = [100.0; 3];
                    energy += 100.0 * sr;
                }
            }
        }
        let map = EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap();
        let em = sky_emitters(&map);
        for scene in scenes(0.25) {
            let reference = ShadowReference::new(&scene, &em);
            let disc = reference.error(&scene, &[light(sun, energy as f32, r as f32)]);
            let point = reference.error(&scene, &[light(sun, energy as f32, 0.0)]);
            assert!(disc < 0.03, "{}: disc {disc}", scene.name);
            assert!(disc < point, "{}: disc {disc} point {point}", scene.name);
            // Open ground far from the occluders sees the whole source.
            let t = reference.truth();
            let max = t.iter().copied().fold(0.0, f64::max);
            let open = energy * sun.y;
            assert!(
                (max - open).abs() / open < 0.01,
                "{}: {max} vs {open}",
                scene.name
            );
        }
    }

    /// A sun with a glow off to one side: the light (the centroid) sits aside of the sun, and
    /// its two-part extent's core drawn toward the sun's own direction (ALGORITHMS.md §12,
    /// "Two-part extent") draws the sun's shadow where it falls; about the light's, it does not.
    #[test]
    fn a_cores_shadow_is_drawn_from_the_cores_direction() {
        let (w, h) = (2048, 1024);
        let sun = DVec3::new(0.3, 0.8, -0.4).normalize();
        let glow = DQuat::from_axis_angle(DVec3::Y, 12f64.to_radians()) * sun;
        let (rs, rg) = (0.5f64.to_radians(), 10f64.to_radians());
        let mut pixels = vec![[0.0f32; 3]; w * h];
        let (mut es, mut eg, mut moment) = (0.0, 0.0, DVec3::ZERO);
        for j in 0..h {
            for i in 0..w {
                let (d, sr) = Projection::LatLong.pixel(i, j, w, h).unwrap();
                let y = if d.dot(sun) >= rs.cos() {
                    es += 5000.0 * sr;
                    5000.0
                } else if d.dot(glow) >= rg.cos() {
                    eg += 10.0 * sr;
                    10.0
                } else {
                    continue;
                };
                pixels[j * w + i] = [y; 3];
                moment += d * (y as f64 * sr);
            }
        }
        let map = EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap();
        let em = sky_emitters(&map);
        let mut l = light(moment, (es + eg) as f32, 2f32.to_radians());
        assert!(
            l.dir().angle_between(sun) > rs,
            "the light is aside of the sun"
        );
        let extent = LightExtent {
            core_share: (es / (es + eg)) as f32,
            core_radius: rs as f32,
            rest_radius: rg as f32,
            core_to_light: None,
        };
        for scene in scenes(0.25) {
            let reference = ShadowReference::new(&scene, &em);
            l.extent = Some(extent);
            let about_light = reference.error(&scene, &[l]);
            l.extent = Some(extent.toward(sun));
            let toward_core = reference.error(&scene, &[l]);
            assert!(
                toward_core < 0.5 * about_light,
                "{}: {toward_core} vs {about_light}",
                scene.name
            );
        }
    }

    #[test]
    fn rays_hit_what_they_should() {
        let s = Occluder::Sphere {
            centre: DVec3::new(0.0, 1.0, 0.0),
            radius: 0.5,
        };
        assert!(s.hit(DVec3::ZERO, DVec3::Y));
        assert!(!s.hit(DVec3::ZERO, -DVec3::Y));
        assert!(!s.hit(DVec3::ZERO, DVec3::X));
        let b = Occluder::Box {
            min: DVec3::new(-0.1, 0.0, -0.1),
            max: DVec3::new(0.1, 2.0, 0.1),
        };
        assert!(b.hit(
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0).normalize()
        ));
        assert!(!b.hit(
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(-1.0, 1.0, 0.0).normalize()
        ));
        assert!(!b.hit(
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(1.0, 3.0, 0.0).normalize()
        ));
        // Every disc ray lies within the radius.
        let d = DVec3::new(0.2, 0.9, 0.1).normalize();
        for r in disc_rays(d, 0.1) {
            assert!(r.dot(d) >= 0.1f64.cos() - 1e-12);
        }
    }
}
