//! The tilt of a single map's lights toward the horizon (ALGORITHMS.md §4.2, "Tilt").
//!
//! A light of power P at its cell's centroid c = M/|M| lights every surface that sees the whole
//! cell by P/|M| − 1 ≈ r²/4 too much (the k-means energy, §10), and on a sky lit from everywhere
//! above (overcast, a city's bright sky) those excesses add up on every upward-facing surface — the
//! ground a client draws shadows on. Moving a light's elevation toward sin e = M_y/P, where a point
//! of power P gives a floor exactly the cell's M_y, trades that excess against the light's share of
//! a vertical surface. The fraction, one for the whole set, is the largest eighth that does not
//! overshoot the map's own floor irradiance and keeps the estimated diffuse error (§8, binned
//! reference) within an allowance; where the lights do not over-light the floor, nothing moves.

use super::error::{Emitters, IrradianceReference, relative_error};
use super::light::Light;
use glam::{DVec2, DVec3, Vec3};

/// The fractions tried are k / `TILT_STEPS`, k = 1, 2, ….
const TILT_STEPS: usize = 8;

/// How much a tilt may raise the estimated diffuse error over no tilt. The floor's bias is what
/// a client sees under its occluders (§9); the estimate is binned, with an excess of its own.
/// Measured on tests/data and its turned maps, 16–256 lights: 0.10 and 0.15 take the same
/// shadowed misses away (overcast and apartment at 32 lights), 0.05 and 0 fewer, and all keep the
/// worst diffuse ratio to k-means within 1.20; the smaller of the two that pay is kept.
const TILT_DIFFUSE_ALLOWANCE: f64 = 0.10;

/// The direction of `d` (above the horizon) moved a fraction `a` of the way from its elevation
/// toward the one whose sine is `floor_y`, its azimuth kept.
fn tilted(d: DVec3, floor_y: f64, a: f64) -> DVec3 {
    let y = d.y + a * (floor_y.clamp(0.0, 1.0) - d.y);
    let h = DVec2::new(d.x, d.z);
    let Some(h) = h.try_normalize() else {
        return d;
    };
    let h = h * (1.0 - y * y).max(0.0).sqrt();
    DVec3::new(h.x, y, h.y)
}

/// Tilts the lights above the horizon toward their cells' floor elevations and returns the
/// fraction taken (0: none). `floor_y[k]` is light k's cell's M_y/P; `floor` is the map's
/// ∫ L·max(0, ω_y) dω in the lights' units, the floor a point set should give. The fraction is the
/// largest k/[`TILT_STEPS`] at or below the one that makes the lights' floor equal `floor` whose
/// estimated diffuse error at `check` is within [`TILT_DIFFUSE_ALLOWANCE`] of the untilted one.
/// Energies, ids and the lights below the horizon are untouched.
pub(super) fn tilt_toward_horizon(
    lights: &mut [Light],
    floor_y: &[f64],
    floor: f64,
    check: &IrradianceReference,
) -> f64 {
    debug_assert_eq!(lights.len(), floor_y.len());
    // The lights below the horizon stay: their irradiance at the normals is summed once.
    let below: Vec<(Vec3, f32)> = lights
        .iter()
        .filter(|l| l.to_light[1] <= 0.0)
        .map(|l| (Vec3::from_array(l.to_light), l.luminance() as f32))
        .collect();
    let fixed = Emitters::new(&below).irradiance_at(check.normals());
    let above: Vec<(DVec3, f64, f32)> = lights
        .iter()
        .zip(floor_y)
        .filter(|(l, _)| l.to_light[1] > 0.0)
        .map(|(l, &fy)| (l.dir(), fy, l.luminance() as f32))
        .collect();
    let error = |a: f64| {
        let points: Vec<(Vec3, f32)> = above
            .iter()
            .map(|&(d, fy, e)| (tilted(d, fy, a).as_vec3(), e))
            .collect();
        let mut estimate = Emitters::new(&points).irradiance_at(check.normals());
        for (e, f) in estimate.iter_mut().zip(&fixed) {
            *e += f;
        }
        relative_error(&estimate, check.truth()).rel_rms
    };
    let e0 = error(0.0);
    // The floor's bias Σ_above P·sin e − F is linear in the fraction: b(a) = b0 + a (b1 − b0).
    let bias = |sines: &dyn Fn(&(DVec3, f64, f32)) -> f64| {
        above.iter().map(|l| sines(l) * l.2 as f64).sum::<f64>() - floor
    };
    let b0 = bias(&|l| l.0.y);
    let b1 = bias(&|l| l.1.clamp(0.0, 1.0));
    let mut chosen = 0.0;
    if b0 > 0.0 && b1 < b0 {
        // The largest eighth that does not overshoot a zero bias, then smaller ones, until one
        // keeps the estimated diffuse error within the allowance.
        let a_zero = (b0 / (b0 - b1)).min(1.0);
        let k_max = (a_zero * TILT_STEPS as f64).floor() as usize;
        for k in (1..=k_max).rev() {
            let a = k as f64 / TILT_STEPS as f64;
            // A NaN estimate (it cannot arise from finite lights) fails the comparison.
            if error(a) <= e0 * (1.0 + TILT_DIFFUSE_ALLOWANCE) {
                chosen = a;
                break;
            }
        }
    }
    if chosen > 0.0 {
        for (l, &fy) in lights.iter_mut().zip(floor_y) {
            if l.to_light[1] > 0.0 {
                l.to_light = tilted(l.dir(), fy, chosen).as_vec3().to_array();
            }
        }
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tilt_keeps_unit_length_azimuth_and_reaches_its_target() {
        let d = DVec3::new(0.3, 0.8, -0.2).normalize();
        for a in [0.0, 0.25, 1.0] {
            let t = tilted(d, 0.5, a);
            assert!((t.length() - 1.0).abs() < 1e-12);
            assert!((t.y - (d.y + a * (0.5 - d.y))).abs() < 1e-12);
            let (h0, h1) = (DVec2::new(d.x, d.z), DVec2::new(t.x, t.z));
            assert!(
                h0.normalize().dot(h1.normalize()) > 1.0 - 1e-12,
                "azimuth moved"
            );
        }
        // The zenith has no azimuth to keep: left alone.
        assert_eq!(tilted(DVec3::Y, 0.5, 1.0), DVec3::Y);
    }
}
