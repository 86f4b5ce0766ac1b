//! The sun's day arc: where the sun is at time t.
//!
//! A constant-speed great circle rather than a solar ephemeris: the daemon's lights must move
//! smoothly through sunrise, noon, sunset and night in a few minutes of wall time, and the tests
//! need closed forms for the sunrise time, the noon elevation and the period. The arc passes
//! through east (+X) and west (−X) and culminates at [`NOON_ELEVATION_DEG`] toward −Z (DESIGN.md's
//! world frame: +Y up).

use std::f64::consts::{PI, TAU};

use glam::DVec3;

/// Elevation of the sun at noon on the synthetic day arc, in degrees.
pub const NOON_ELEVATION_DEG: f64 = 60.0;

/// The arc: its angle at t = 0 (0 = sunrise in the east, π/2 = noon, π = sunset) and its rate.
pub(super) struct SunPath {
    /// Arc angle at t = 0, rad.
    alpha0: f64,
    /// Angular speed along the arc, rad/s.
    omega: f64,
}

impl SunPath {
    /// The arc through elevation `start_elevation_deg` at t = 0 (on the rising half), travelled at
    /// `speed_deg_per_s`.
    pub(super) fn new(start_elevation_deg: f64, speed_deg_per_s: f64) -> Self {
        // On the arc, sin(elevation) = sin(α)·sin(noon elevation); α0 on the rising half.
        let alpha0 = (start_elevation_deg.to_radians().sin()
            / NOON_ELEVATION_DEG.to_radians().sin())
        .clamp(-1.0, 1.0)
        .asin();
        SunPath {
            alpha0,
            omega: speed_deg_per_s.to_radians(),
        }
    }

    fn arc_angle(&self, t: f64) -> f64 {
        (self.alpha0 + self.omega * t).rem_euclid(TAU)
    }

    /// Seconds from one sunrise to the next (infinite when the sun does not move).
    pub(super) fn period_s(&self) -> f64 {
        TAU / self.omega.abs()
    }

    /// The first sunrise at or after `t` (the sun crosses the horizon rising, in the east, +X).
    pub(super) fn next_sunrise(&self, t: f64) -> f64 {
        let omega = self.omega;
        if omega == 0.0 {
            return f64::INFINITY;
        }
        // Arc angle ≡ 0 (mod 2π) when rising for ω > 0; for ω < 0 the sun runs the arc backwards
        // and rises at α = π.
        let target = if omega > 0.0 { 0.0 } else { PI };
        let alpha = self.arc_angle(t);
        let to_go = ((target - alpha) / omega).rem_euclid(self.period_s());
        t + to_go
    }

    /// Unit vector toward the sun centre at time t (world frame): `d(α) = cos α·X̂ + sin α·N̂` with
    /// `N̂ = (0, sin 60°, −cos 60°)` (see [`SyntheticSky::sun_direction`](super::SyntheticSky::sun_direction)).
    pub(super) fn direction(&self, t: f64) -> DVec3 {
        let (sa, ca) = self.arc_angle(t).sin_cos();
        let (sn, cn) = NOON_ELEVATION_DEG.to_radians().sin_cos();
        DVec3::new(ca, sa * sn, -sa * cn).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::testing::sky;

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
}
