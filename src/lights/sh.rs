//! L2 spherical harmonics of the radiance (DESIGN.md; ALGORITHMS.md §7 for the irradiance baseline).
//!
//! Basis: the real orthonormal SH evaluated on the world-frame unit vector (x, y, z) as it is
//! (+Y up, −Z forward), in the order l(l+1)+m used by WebXR and three.js:
//! Y₀₀ = 0.282095; Y₁₋₁ = 0.488603·y, Y₁₀ = 0.488603·z, Y₁₁ = 0.488603·x;
//! Y₂₋₂ = 1.092548·xy, Y₂₋₁ = 1.092548·yz, Y₂₀ = 0.315392·(3z² − 1), Y₂₁ = 1.092548·xz,
//! Y₂₂ = 0.546274·(x² − y²). Coefficients are radiance: L_lm = ∫ L(ω) Y_lm(ω) dω, RGB interleaved.

use crate::sampling::DomainImage;
use glam::{DVec3, Vec3, Vec3A};
use std::f64::consts::PI;

/// The nine basis functions at a unit direction.
pub fn basis(d: DVec3) -> [f64; 9] {
    let (x, y, z) = (d.x, d.y, d.z);
    [
        0.282_094_791,
        0.488_602_512 * y,
        0.488_602_512 * z,
        0.488_602_512 * x,
        1.092_548_431 * x * y,
        1.092_548_431 * y * z,
        0.315_391_565 * (3.0 * z * z - 1.0),
        1.092_548_431 * x * z,
        0.546_274_215 * (x * x - y * y),
    ]
}

/// Radiance coefficients of a domain image: 27 floats, [c0.r, c0.g, c0.b, c1.r, …], with each
/// texel's basis values taken at its centre (the eval's SH baseline).
pub fn project(image: &DomainImage) -> [f64; 27] {
    let side = image.side;
    let sr = image.texel_solid_angle();
    let mut out = [0.0f64; 27];
    // Sum row by row in f32, then into f64: a row is short enough for f32.
    for (j, rad_row) in image.radiance.chunks(side).enumerate() {
        let mut acc = [0.0f32; 27];
        for (i, p) in rad_row.iter().enumerate() {
            let d = image
                .domain
                .square_to_dir(DomainImage::texel_centre(side, i, j));
            let y = basis(d).map(|y| (y * sr) as f32);
            for k in 0..9 {
                for c in 0..3 {
                    acc[3 * k + c] += p[c] * y[k];
                }
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o += a as f64;
        }
    }
    out
}

/// Radiance coefficients with each texel's basis values taken at its first-moment direction (its
/// luminance-weighted mean direction, which the resampling keeps exactly) instead of its centre.
/// Against a per-pixel projection of the source, over the eight shared maps, this on the
/// half-resolution square is 1.2e-4 – 9.8e-4 off (relative L2 over the 27 coefficients) where
/// [`project`] on the full square is 1.6e-4 – 1.3e-2 off: a sun's texel centre can be half a texel
/// from the sun (sunrise.exr 3.9e-4 vs 4.9e-3), while on the smooth studio and apartment maps the
/// coarser square loses a little (3.5e-4 vs 1.7e-4, 9.8e-4 vs 1.6e-4). So `sh9` projects the Lloyd
/// steps' half-resolution image: a quarter of the texels (0.11 instead of 0.18 ms on sunrise.exr,
/// basis values evaluated per texel included), and a worst case 13× smaller.
pub fn project_at_moments(image: &DomainImage) -> [f64; 27] {
    let side = image.side;
    let sr = image.texel_solid_angle() as f32;
    let mut out = [0.0f64; 27];
    for (j, (rad_row, moment_row)) in image
        .radiance
        .chunks(side)
        .zip(image.moment.chunks(side))
        .enumerate()
    {
        // Sum a row in f32 (RGB in one register per coefficient), then into f64.
        let mut acc = [Vec3A::ZERO; 9];
        for (i, (p, m)) in rad_row.iter().zip(moment_row).enumerate() {
            let d = Vec3::from_array(*m).try_normalize().unwrap_or_else(|| {
                image
                    .domain
                    .square_to_dir(DomainImage::texel_centre(side, i, j))
                    .as_vec3()
            });
            let p = Vec3A::from_array(*p) * sr;
            for (a, y) in acc.iter_mut().zip(basis(d.as_dvec3())) {
                let y = y as f32;
                *a += p * y;
            }
        }
        for (k, a) in acc.iter().enumerate() {
            for c in 0..3 {
                out[3 * k + c] += a[c] as f64;
            }
        }
    }
    out
}

/// Irradiance at normal `n` from radiance coefficients (Ramamoorthi & Hanrahan 2001):
/// E(n) = Σ Â_l L_lm Y_lm(n), Â₀ = π, Â₁ = 2π/3, Â₂ = π/4.
pub fn irradiance(coeffs: &[f64; 27], n: DVec3) -> [f64; 3] {
    const BAND: [f64; 9] = [
        PI,
        2.0 * PI / 3.0,
        2.0 * PI / 3.0,
        2.0 * PI / 3.0,
        PI / 4.0,
        PI / 4.0,
        PI / 4.0,
        PI / 4.0,
        PI / 4.0,
    ];
    let y = basis(n);
    let mut e = [0.0; 3];
    for k in 0..9 {
        for c in 0..3 {
            e[c] += BAND[k] * coeffs[3 * k + c] * y[k];
        }
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::Domain;

    #[test]
    fn constant_sky_has_only_dc_and_exact_irradiance() {
        // L = 1 everywhere: L₀₀ = √(4π), and E(n) = π·L₀₀·Y₀₀ = π for every normal.
        let img = DomainImage::from_fn(Domain::Sphere, 128, |_| [1.0; 3]);
        let c = project(&img);
        assert!((c[0] - (4.0 * PI).sqrt()).abs() < 1e-3, "{}", c[0]);
        for k in 1..9 {
            assert!(c[3 * k].abs() < 1e-3, "coefficient {k}: {}", c[3 * k]);
        }
        let e = irradiance(&c, DVec3::new(0.3, 0.5, -0.2).normalize());
        assert!((e[0] - PI).abs() < 1e-3);
    }

    #[test]
    fn cosine_lobe_sky_irradiance_matches_closed_form() {
        // L(ω) = max(0, ω·Y): E(+Y) = ∫ cos² = 2π/3, E(−Y) = 0 (L2 is exact up to ≈ 1e−2 here:
        // the clamped cosine has energy above l = 2).
        let img = DomainImage::from_fn(Domain::Sphere, 256, |d| [d.y.max(0.0) as f32; 3]);
        let c = project(&img);
        let up = irradiance(&c, DVec3::Y)[0];
        let down = irradiance(&c, -DVec3::Y)[0];
        assert!((up - 2.0 * PI / 3.0).abs() < 0.03 * 2.0 * PI / 3.0, "{up}");
        assert!(down.abs() < 0.05, "{down}");
        // The sky is brighter above: the Y₁₋₁ (y) coefficient is positive in this basis.
        assert!(c[3] > 0.0);
    }
}
