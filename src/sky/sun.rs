//! The sun disk: its size, its radiance through the atmosphere and the clouds, and the calibration
//! of its brightness against the sky.
//!
//! The Hosek-Wilkie model is sky only, so the sun is a uniform disk of the real angular size whose
//! radiance is an exo-atmospheric scale × Beer-Lambert transmittance along the Kasten-Young air
//! mass (F. Kasten and A. T. Young, Applied Optics 28(22), 1989; so it reddens and fades toward the
//! horizon) × the cloud transmittance in front of it. The scale is calibrated once per sky so that
//! at noon the sun carries [`SUN_TO_SKY_RATIO`] × the clear sky's energy. The disk is drawn by
//! exact area coverage ([`super::disc`]), so the map holds exactly radiance × its solid angle.

use glam::DVec3;

use super::clouds::Clouds;
use super::disc::cap_solid_angle;
use super::hosek_wilkie::HwModel;
use super::sun_path::NOON_ELEVATION_DEG;
use crate::envmap::luminance64;

/// Angular diameter of the sun disk, in degrees (the real sun: 0.53°).
pub const SUN_ANGULAR_DIAMETER_DEG: f64 = 0.53;
/// Ratio of the sun's ∫ L dω (luminance) to the clear sky's ∫ L dω over the upper hemisphere, with
/// the sun at [`NOON_ELEVATION_DEG`]. Clear-sky measurements put direct normal irradiance at about
/// 850–950 W/m² against 60–120 W/m² of diffuse: the sun carries roughly 10–15× the sky's energy.
/// The sun's radiance scale is calibrated once per sky so that this holds at noon; at other
/// elevations Beer-Lambert extinction along the air mass decides (see
/// [`SyntheticSky::sun_radiance`](super::SyntheticSky::sun_radiance)).
pub const SUN_TO_SKY_RATIO: f64 = 12.0;
/// Fraction of the sun's radiance a full cloud removes.
const SUN_CLOUD_OPACITY: f64 = 0.85;

/// Angular radius of the sun disk, rad.
pub(super) fn sun_radius() -> f64 {
    (0.5 * SUN_ANGULAR_DIAMETER_DEG).to_radians()
}

/// The sun's extinction and exo-atmospheric radiance.
pub(super) struct Sun {
    /// Exo-atmospheric sun radiance (before extinction and clouds), calibrated by SUN_TO_SKY_RATIO.
    scale: f64,
    /// Per-channel optical depth at air mass 1.
    tau: [f64; 3],
}

impl Sun {
    /// The sun for `turbidity`, its scale calibrated on the clear noon sky of `model` (which is
    /// left set to noon): luminance, fine quadrature.
    pub(super) fn calibrated(turbidity: f64, model: &mut HwModel) -> Sun {
        // Extinction: Rayleigh τ ≈ 0.0088 λ^-4.05 plus Ångström aerosol β λ^-1.3 with
        // β = 0.04608 T − 0.04586 (Preetham, Shirley & Smits 1999), λ in µm at 610/550/465 nm.
        let beta = (0.04608 * turbidity - 0.04586).max(0.0);
        let tau = [0.61f64, 0.55, 0.465].map(|l| 0.0088 * l.powf(-4.05) + beta * l.powf(-1.3));
        let mut sun = Sun { scale: 0.0, tau };

        let noon = NOON_ELEVATION_DEG.to_radians();
        model.set(noon);
        let noon_sun = DVec3::new(0.0, noon.sin(), -noon.cos());
        let sky_integral = model.clear_sky_integral(noon_sun, 128, 256);
        let t_noon = sun.transmittance(NOON_ELEVATION_DEG);
        sun.scale = SUN_TO_SKY_RATIO * luminance64(sky_integral)
            / (luminance64(t_noon) * sun_solid_angle());
        sun
    }

    /// Beer-Lambert transmittance per channel at sun elevation `elev_deg`.
    fn transmittance(&self, elev_deg: f64) -> [f64; 3] {
        let m = air_mass(elev_deg);
        self.tau.map(|tau| (-tau * m).exp())
    }

    /// Radiance of the disk at sun direction `dir`, time t, behind `clouds` (see
    /// [`SyntheticSky::sun_radiance`](super::SyntheticSky::sun_radiance)); 0 once the whole disk
    /// has set.
    pub(super) fn radiance(&self, dir: DVec3, clouds: &Clouds, t: f64) -> [f32; 3] {
        if dir.y <= -sun_radius().sin() {
            return [0.0; 3];
        }
        let elev = dir.y.clamp(-1.0, 1.0).asin().to_degrees();
        let tr = self.transmittance(elev);
        let clouds = 1.0 - SUN_CLOUD_OPACITY * clouds.sun_cover(dir, t);
        tr.map(|x| (self.scale * x * clouds) as f32)
    }
}

/// Solid angle of the sun disk, sr: 2π(1 − cos r) = 4π sin²(r/2).
pub(super) fn sun_solid_angle() -> f64 {
    cap_solid_angle(sun_radius())
}

/// Relative optical air mass (Kasten & Young 1989), elevation in degrees, clamped just below the
/// horizon where the sun is hidden anyway.
fn air_mass(elev_deg: f64) -> f64 {
    let e = elev_deg.max(-0.5);
    1.0 / (e.to_radians().sin() + 0.50572 * (e + 6.07995).powf(-1.6364))
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;
    use crate::envmap::EnvMap;
    use crate::sky::disc::angle_between;
    use crate::sky::testing::{sky, upper_integral};
    use crate::sky::{SwitchLight, SyntheticConfig, SyntheticSky};

    #[test]
    fn sun_is_the_brightest_pixel_in_its_direction() {
        for width in [256, 1024] {
            let mut s = sky(width, |c| c.switch_light = None);
            let rise = s.next_sunrise(0.0);
            for t in [rise + 30.0, rise + 90.0, rise + 150.0, 0.0] {
                let map = s.render(t);
                let (mut best, mut best_l) = (0, -1.0);
                for (k, p) in map.pixels.iter().enumerate() {
                    let l = EnvMap::luminance(*p);
                    if l > best_l {
                        (best, best_l) = (k, l);
                    }
                }
                let (i, j) = (best % map.width, best / map.width);
                let (dir, _) = map.projection.pixel(i, j, map.width, map.height).unwrap();
                let pixel = (PI / map.height as f64) * 2f64.sqrt();
                let err = angle_between(dir, s.sun_direction(t));
                assert!(
                    err <= pixel,
                    "width {width} t {t}: {err} rad off, pixel {pixel}"
                );
                // Brightest by far: the sun pixel outshines everything away from the sun.
                let mut others = 0.0f32;
                for (k, p) in map.pixels.iter().enumerate() {
                    let (ii, jj) = (k % map.width, k / map.width);
                    let (d, _) = map.projection.pixel(ii, jj, map.width, map.height).unwrap();
                    if angle_between(d, s.sun_direction(t)) > 5.0f64.to_radians() {
                        others = others.max(EnvMap::luminance(*p));
                    }
                }
                assert!(best_l > 10.0 * others, "sun {best_l} vs rest {others}");
            }
        }
    }

    #[test]
    fn sun_energy_is_exact_at_any_resolution() {
        for width in [256, 1024, 333 * 2] {
            for clouds in [0.0, 0.5] {
                let mut s = sky(width, |c| {
                    c.clouds = clouds;
                    c.switch_light = None;
                });
                let rise = s.next_sunrise(0.0);
                for t in [rise + 20.0, rise + 90.0, rise + 133.3] {
                    let with = upper_integral(&s.render(t));
                    s.draw_sun = false;
                    let without = upper_integral(&s.render(t));
                    s.draw_sun = true;
                    let radiance = s.sun_radiance(t);
                    let omega = SyntheticSky::sun_solid_angle();
                    for c in 0..3 {
                        let want = radiance[c] as f64 * omega;
                        let got = with[c] - without[c];
                        let rel = (got - want).abs() / want;
                        assert!(rel < 0.01, "w {width} t {t} c {c}: {got} vs {want}");
                    }
                }
            }
        }
        // The analytic cap: 0.53° across.
        let omega = SyntheticSky::sun_solid_angle();
        let r = (0.265f64).to_radians();
        assert!((omega - PI * r * r).abs() / omega < 1e-5);
    }

    #[test]
    fn sun_carries_the_documented_share_at_noon() {
        let mut s = sky(512, |c| {
            c.clouds = 0.0;
            c.switch_light = None;
        });
        let noon = s.next_sunrise(0.0) + s.period_s() / 4.0;
        let with = luminance64(upper_integral(&s.render(noon)));
        s.draw_sun = false;
        let sky_only = luminance64(upper_integral(&s.render(noon)));
        let ratio = (with - sky_only) / sky_only;
        assert!(
            (ratio - SUN_TO_SKY_RATIO).abs() < 0.05 * SUN_TO_SKY_RATIO,
            "{ratio}"
        );
    }

    /// The energy budget the docs quote, printed with `--nocapture`: on the clear default sky at
    /// noon the sky's ∫ L dω is ≈ 70 model units and the sun's ≈ 840 ([`SyntheticSky::sun_radiance`]);
    /// the lamp's is ≈ 17 ([`crate::sky::SwitchLight`]'s default).
    #[test]
    fn energy_budget() {
        let mut s = SyntheticSky::new(SyntheticConfig {
            switch_light: None,
            clouds: 0.0,
            ..SyntheticConfig::default()
        });
        let rise = s.next_sunrise(0.0);
        let mut noon = (0.0, 0.0);
        for (name, t) in [
            ("sunrise+10 s", rise + 10.0),
            ("morning", rise + 45.0),
            ("noon", rise + 90.0),
            ("midnight", rise + 270.0),
        ] {
            let m = s.render(t);
            let all = luminance64(upper_integral(&m));
            s.draw_sun = false;
            let sky = luminance64(upper_integral(&s.render(t)));
            s.draw_sun = true;
            let ground = EnvMap::luminance(m.pixels[m.pixels.len() - 1]);
            eprintln!(
                "{name}: elev {:.1}°, sky ∫L dω {sky:.4}, sun {:.4}, ground radiance {ground:.4}, \
                 sun radiance {:?}",
                s.sun_elevation_deg(t),
                all - sky,
                s.sun_radiance(t)
            );
            if name == "noon" {
                noon = (sky, all - sky);
            }
        }
        let lamp = SwitchLight::default();
        let lamp_energy = lamp.radiance as f64 * cap_solid_angle(lamp.radius_deg.to_radians());
        eprintln!("lamp ∫L dω {lamp_energy:.4}");
        let (sky, sun) = noon;
        assert!((sky - 70.0).abs() < 0.1 * 70.0, "noon sky {sky}");
        assert!((sun - 840.0).abs() < 0.1 * 840.0, "noon sun {sun}");
        assert!(
            (lamp_energy - 17.0).abs() < 0.1 * 17.0,
            "lamp {lamp_energy}"
        );
    }
}
