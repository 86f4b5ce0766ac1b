//! The light itself (DESIGN.md "A light") and what is read off a set of lights: the angular
//! radius of a region (ALGORITHMS.md §12), the primary light (ALGORITHMS.md §6) and the total
//! irradiance. A leaf: every extraction method imports it, it imports none of them.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A directional light (DESIGN.md "A light").
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Light {
    /// Stable id: the index of the progressive point the light comes from (ordered methods).
    pub id: u32,
    /// Unit vector pointing toward the light, world frame (+Y up, −Z forward).
    pub to_light: [f32; 3],
    /// Radiance integrated over the light's solid angle, linear RGB (map units × sr).
    pub irradiance: [f32; 3],
    /// Solid angle (sr) of the region the light stands for.
    pub solid_angle: f32,
    /// Angular radius (radians) of the uniform disc whose energy has the same RMS spread about
    /// `to_light` as the light's region (ALGORITHMS.md §12): 2·√(1 − |M|/P), P = ∫Y dω and
    /// M = ∫Y ω dω over the region. What a client's soft shadow (a disc light, PCSS, a sun radius)
    /// needs; 0 for a point. Older documents without it read as 0.
    #[serde(default)]
    pub angular_radius: f32,
    /// With a client's shadow budget (`shadowed=K`, see [`super::budget`]): whether this light is
    /// one of the K worth a shadow map. Absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadowed: Option<bool>,
}

impl Light {
    pub fn dir(&self) -> DVec3 {
        DVec3::from_array(self.to_light.map(f64::from))
    }

    pub fn luminance(&self) -> f64 {
        crate::envmap::luminance64(self.irradiance.map(f64::from))
    }

    /// Whether the light carries any energy (DESIGN.md: every light of a set does).
    pub fn carries_energy(&self) -> bool {
        self.irradiance.iter().any(|&c| c > 0.0)
    }

    /// The region's luminance moment M = ∫Y ω dω, recovered from the luminance and the angular
    /// radius (|M| = P·(1 − r²/4), ALGORITHMS.md §12): lights merged by summing moments keep
    /// the combined region's spread.
    pub fn moment(&self) -> DVec3 {
        let r = self.angular_radius as f64;
        self.dir() * self.luminance() * (1.0 - 0.25 * r * r).max(0.0)
    }
}

/// The angular radius of a region of luminance energy `energy` whose moment has length
/// `moment_len` (ALGORITHMS.md §12): the radius of the uniform disc with the same RMS spread,
/// 2·√(1 − |M|/P), at most π.
pub fn angular_radius(energy: f64, moment_len: f64) -> f32 {
    if energy <= 0.0 || !energy.is_finite() || !moment_len.is_finite() {
        return 0.0;
    }
    let spread = (1.0 - moment_len / energy).clamp(0.0, 1.0);
    (2.0 * spread.sqrt()).min(std::f64::consts::PI) as f32
}

/// The largest angular radius a light toward `to_light` may have without its disc crossing the
/// horizon (ALGORITHMS.md §12, "Not across the horizon"): the angle between the direction and the
/// horizontal plane.
pub fn horizon_gap(to_light: [f32; 3]) -> f32 {
    to_light[1].clamp(-1.0, 1.0).abs().asin()
}

/// The strongest light or tight cluster of lights (the sun), WebXR's "primary light".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PrimaryLight {
    /// Irradiance-weighted mean direction toward the cluster (unit vector).
    pub to_light: [f32; 3],
    /// Sum of the cluster's irradiance, linear RGB.
    pub irradiance: [f32; 3],
    /// Ids of the lights in the cluster.
    pub light_ids: Vec<u32>,
}

/// Lights within this angle of the brightest light form the primary cluster (ALGORITHMS.md §6: 2–5°).
pub const PRIMARY_CLUSTER_DEG: f64 = 5.0;

/// The brightest light (by luminance) and every light within [`PRIMARY_CLUSTER_DEG`] of it.
pub fn primary_light(lights: &[Light]) -> Option<PrimaryLight> {
    let brightest = lights
        .iter()
        .filter(|l| l.luminance() > 0.0)
        .max_by(|a, b| a.luminance().total_cmp(&b.luminance()))?;
    let axis = brightest.dir();
    let cos_limit = PRIMARY_CLUSTER_DEG.to_radians().cos();
    let mut dir = DVec3::ZERO;
    let mut irr = [0.0f64; 3];
    let mut ids = Vec::new();
    for l in lights.iter().filter(|l| l.dir().dot(axis) >= cos_limit) {
        dir += l.dir() * l.luminance();
        for c in 0..3 {
            irr[c] += l.irradiance[c] as f64;
        }
        ids.push(l.id);
    }
    Some(PrimaryLight {
        to_light: dir.try_normalize().unwrap_or(axis).as_vec3().to_array(),
        irradiance: irr.map(|v| v as f32),
        light_ids: ids,
    })
}

/// Σ irradiance over lights, per channel, in f64.
pub fn total_irradiance(lights: &[Light]) -> [f64; 3] {
    let mut s = [0.0f64; 3];
    for l in lights {
        for c in 0..3 {
            s[c] += l.irradiance[c] as f64;
        }
    }
    s
}

/// The angular radius of a cell with a bright core (ALGORITHMS.md §12, "Core and rest"): the
/// uniform disc whose half-energy radius is the cell's, with its core and the rest of it each
/// taken as a uniform disc about the same centre, of the RMS spread each has. `cell` and `core`
/// are (P, |M|) over the cell and over its core. Where the core holds most of the light (a clear
/// sun in its faint glare) this is about the core's own radius, which a faint wide halo cannot
/// carry off as it does the whole cell's RMS; where the rest holds most (a sun through haze or
/// leaves, a lamp in its glow) the disc widens toward the rest's, and it is continuous between.
pub fn core_halo_radius(cell: (f64, f64), core: (f64, f64)) -> f32 {
    let ((p, m), (pc, mc)) = (cell, core);
    if !(p.is_finite() && m.is_finite() && pc.is_finite() && mc.is_finite()) || p <= 0.0 {
        return 0.0;
    }
    if pc <= 0.0 {
        return angular_radius(p, m);
    }
    let r_core = angular_radius(pc, mc) as f64;
    if pc >= p {
        return r_core as f32;
    }
    let (share, rest) = (pc / p, p - pc);
    // The rest's k-means energy P − |M| is the cell's less the core's (§10); its disc is at
    // least as wide as the core's.
    let rest_spread = ((p - m) - (pc - mc)).max(0.0) / rest;
    let r_rest = (2.0 * rest_spread.min(1.0).sqrt()).max(r_core);
    let (c2, h2) = (r_core * r_core, r_rest * r_rest);
    // Energy within ρ of the centre: share·ρ²/c² + (1 − share)·ρ²/h² while ρ ≤ r_core, then
    // share + (1 − share)·ρ²/h²; ρ₅₀ where that is one half.
    let outside = h2 * (0.5 - share) / (1.0 - share);
    let rho2 = if c2 > 0.0 {
        let inside = 0.5 / (share / c2 + (1.0 - share) / h2);
        if inside <= c2 { inside } else { outside }
    } else {
        outside.max(0.0)
    };
    // A uniform disc of radius R holds half its energy within R/√2.
    (2.0 * rho2).sqrt().min(std::f64::consts::PI) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (P, |M|) of a uniform disc of radius `r` (radians) holding `p`: |M| = P·(1 − r²/4)
    /// (ALGORITHMS.md §12), so that `angular_radius` gives back `r`.
    fn disc(p: f64, r: f64) -> (f64, f64) {
        (p, p * (1.0 - r * r / 4.0))
    }

    /// A core of `share` on a disc of radius `rc` and the rest on a disc of radius `rh`.
    fn cell(share: f64, rc: f64, rh: f64) -> ((f64, f64), (f64, f64)) {
        let (core, rest) = (disc(share, rc), disc(1.0 - share, rh));
        ((core.0 + rest.0, core.1 + rest.1), core)
    }

    #[test]
    fn the_half_energy_disc_matches_the_two_disc_median() {
        let (rc, rh) = (0.5f64.to_radians(), 4f64.to_radians());
        for share in [0.05, 0.2, 0.3, 0.45, 0.6, 0.8, 0.95] {
            let (c, k) = cell(share, rc, rh);
            // Energy within ρ: share·min(ρ/rc, 1)² + (1 − share)·(ρ/rh)²; bisect for one half.
            let within =
                |rho: f64| share * (rho / rc).min(1.0).powi(2) + (1.0 - share) * (rho / rh).powi(2);
            let (mut lo, mut hi) = (0.0, rh);
            for _ in 0..100 {
                let mid = 0.5 * (lo + hi);
                if within(mid) < 0.5 {
                    lo = mid
                } else {
                    hi = mid
                }
            }
            let expected = std::f64::consts::SQRT_2 * lo;
            let got = core_halo_radius(c, k) as f64;
            assert!(
                (got - expected).abs() <= 1e-4 * expected,
                "share {share}: {got} vs {expected}"
            );
        }
    }

    #[test]
    fn the_radius_runs_from_the_rests_to_the_cores_without_a_jump() {
        let (rc, rh) = (0.3f64.to_radians(), 6f64.to_radians());
        let radius = |s: f64| {
            let (c, k) = cell(s, rc, rh);
            core_halo_radius(c, k) as f64
        };
        // All rest: the rest's disc; all core: the core's.
        assert!((radius(1e-9) - rh).abs() < 1e-3 * rh);
        assert!((radius(1.0 - 1e-9) - rc).abs() < 1e-3 * rc);
        // Monotone in the core's share, and continuous: no step between shares 10⁻⁷ apart
        // (a threshold between the two radii would step by up to rh − rc anywhere).
        let mut last = radius(0.001);
        for i in 2..1000 {
            let s = i as f64 / 1000.0;
            let r = radius(s);
            assert!(r <= last + 1e-9, "not monotone at share {s}");
            assert!(
                (radius(s + 1e-7) - r).abs() < 1e-3 * rh,
                "step at share {s}"
            );
            last = r;
        }
    }

    #[test]
    fn a_faint_wide_halo_leaves_a_clear_sun_its_own_radius() {
        // A 0.27° sun holding 80 % of its cell, the rest spread over 20°: the cell's RMS disc
        // would be degrees wide; the half-energy disc is √(1/(2·0.625))… = 1.118 × the sun's.
        let (rc, rh) = (0.27f64.to_radians(), 20f64.to_radians());
        let (c, k) = cell(0.8, rc, rh);
        let r = core_halo_radius(c, k) as f64;
        assert!(
            r > rc && r < 1.12 * rc,
            "{} vs sun {}",
            r.to_degrees(),
            rc.to_degrees()
        );
        assert!((angular_radius(c.0, c.1) as f64) > 10.0 * rc);
    }

    #[test]
    fn bad_moments_give_a_finite_radius() {
        for (c, k) in [
            ((0.0, 0.0), (0.0, 0.0)),
            ((1.0, f64::NAN), (0.5, 0.5)),
            ((1.0, 0.9), (0.0, 0.0)),
            ((1.0, 1.2), (0.5, 0.6)),
            ((1.0, 0.5), (1.0, 1.0)),
        ] {
            let r = core_halo_radius(c, k);
            assert!(
                r.is_finite() && (0.0..=std::f32::consts::PI).contains(&r),
                "{c:?} {k:?}: {r}"
            );
        }
    }
}
