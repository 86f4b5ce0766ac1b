//! The switch light: a nearby round lamp that turns on and off.
//!
//! It exists to give the temporal filter a step to respond to (the sun and clouds only ever change
//! smoothly): on for the first half of each period, off for the second. A nearby source, it is
//! drawn over sky and ground and does not light the ground; like the sun it is drawn by exact area
//! coverage ([`super::disc`]), so it adds exactly radiance × cap solid angle to the map's energy.

use std::f64::consts::PI;

use glam::DVec3;

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

impl SwitchLight {
    /// Whether the lamp is on at time t (on for the first half of each period).
    pub fn is_on(&self, t: f64) -> bool {
        if !(self.period_s.is_finite() && self.period_s > 0.0) {
            return true;
        }
        (t / self.period_s).rem_euclid(1.0) < 0.5
    }

    /// The lamp as a disc to draw: (unit direction to its centre, angular radius in rad, radiance);
    /// `None` when it has no direction, no size or no finite radiance.
    pub(super) fn disc(&self) -> Option<(DVec3, f64, f32)> {
        let radius = self.radius_deg.to_radians().clamp(0.0, PI);
        let radiance = self.radiance.max(0.0);
        (self.to_light.length_squared() > 0.0 && radiance.is_finite() && radius > 0.0)
            .then(|| (self.to_light.normalize(), radius, radiance))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::disc::cap_solid_angle;
    use crate::sky::testing::{sky, total};

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
}
