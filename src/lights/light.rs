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
