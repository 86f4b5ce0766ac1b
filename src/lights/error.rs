//! Diffuse irradiance error of a light set against its map (ALGORITHMS.md §8).
//!
//! Ground truth E(n) = Σ L·max(0, n·ω)·Δω over the map, from lights E_N(n) = Σ_k irradiance_k ·
//! max(0, n·to_light_k), both in luminance, at a fixed Fibonacci sphere of normals. The error is the
//! relative RMS, √(Σ_n (E_N − E)²) / √(Σ_n E²), which stays defined where E is 0 (normals facing
//! away from a hemisphere domain).

use super::Light;
use crate::envmap::EnvMap;
use crate::sampling::DomainImage;
use glam::{DVec3, Vec3};

/// Normals used for error estimates.
pub const ERROR_NORMALS: usize = 256;

/// Side of the reduced copy of the domain square used as ground truth for `--max-error`.
const REDUCED_SIDE: usize = 64;

/// `n` unit vectors spread evenly over the sphere (golden-angle spiral).
pub fn fibonacci_sphere(n: usize) -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), y, r * phi.sin())
        })
        .collect()
}

/// A reference for irradiance: many small emitters (direction, luminance energy), from which E(n) is
/// summed by brute force.
pub struct IrradianceReference {
    normals: Vec<DVec3>,
    truth: Vec<f64>,
}

impl IrradianceReference {
    /// From emitters (unit direction, luminance × sr), e.g. every pixel of a map.
    pub fn from_emitters(emitters: &[(Vec3, f32)]) -> Self {
        let normals = fibonacci_sphere(ERROR_NORMALS);
        let truth = normals
            .iter()
            .map(|n| {
                let n = n.as_vec3();
                emitters
                    .iter()
                    .map(|(d, e)| (*e * n.dot(*d).max(0.0)) as f64)
                    .sum()
            })
            .collect();
        IrradianceReference { normals, truth }
    }

    /// Brute force over every pixel of the source map inside the domain (the test oracle).
    pub fn from_map(map: &EnvMap, domain: crate::sampling::Domain) -> Self {
        let mut emitters = Vec::with_capacity(map.width * map.height);
        for j in 0..map.height {
            for i in 0..map.width {
                if let Some((d, sr)) = map.projection.pixel(i, j, map.width, map.height)
                    && domain.contains(d)
                {
                    let y = EnvMap::luminance(map.pixels[j * map.width + i]);
                    if y > 0.0 {
                        emitters.push((d.as_vec3(), y * sr as f32));
                    }
                }
            }
        }
        Self::from_emitters(&emitters)
    }

    /// From a reduced copy of the domain square: texels binned into a 64×64 grid, each bin an
    /// emitter at its luminance-weighted mean direction (first moment kept, so the binning error is
    /// second order). Cheap enough for every `--max-error` request.
    pub fn from_domain_image(image: &DomainImage) -> Self {
        let side = image.side;
        let g = REDUCED_SIDE.min(side);
        let mut bins = vec![(Vec3::ZERO, 0.0f32); g * g];
        let sr = image.texel_solid_angle() as f32;
        for j in 0..side {
            for i in 0..side {
                let y = image.luminance[j * side + i];
                if y <= 0.0 {
                    continue;
                }
                let d = image
                    .domain
                    .square_to_dir(DomainImage::texel_centre(side, i, j))
                    .as_vec3();
                let b = &mut bins[(j * g / side) * g + i * g / side];
                b.0 += d * y * sr;
                b.1 += y * sr;
            }
        }
        let emitters: Vec<(Vec3, f32)> = bins
            .into_iter()
            .filter(|b| b.1 > 0.0)
            .map(|(d, e)| (d.normalize_or(Vec3::Y), e))
            .collect();
        Self::from_emitters(&emitters)
    }

    /// E_N at every reference normal from a light set.
    pub fn light_irradiance(&self, lights: &[Light]) -> Vec<f64> {
        self.normals
            .iter()
            .map(|n| {
                lights
                    .iter()
                    .map(|l| l.luminance() * n.dot(l.dir()).max(0.0))
                    .sum()
            })
            .collect()
    }

    /// Relative RMS and relative max error of `estimate` (one value per normal).
    pub fn error_of(&self, estimate: &[f64]) -> DiffuseError {
        let mut num = 0.0;
        let mut den = 0.0;
        let mut max_abs: f64 = 0.0;
        for (e, t) in estimate.iter().zip(&self.truth) {
            num += (e - t) * (e - t);
            den += t * t;
            max_abs = max_abs.max((e - t).abs());
        }
        if den <= 0.0 {
            // A black map: any zero estimate is exact.
            return DiffuseError {
                rel_rms: if num > 0.0 { f64::INFINITY } else { 0.0 },
                rel_max: if num > 0.0 { f64::INFINITY } else { 0.0 },
            };
        }
        let rms_truth = (den / self.truth.len() as f64).sqrt();
        DiffuseError {
            rel_rms: (num / den).sqrt(),
            rel_max: max_abs / rms_truth,
        }
    }

    /// Error of a light set.
    pub fn error(&self, lights: &[Light]) -> DiffuseError {
        self.error_of(&self.light_irradiance(lights))
    }

    pub fn normals(&self) -> &[DVec3] {
        &self.normals
    }

    pub fn truth(&self) -> &[f64] {
        &self.truth
    }
}

/// Diffuse irradiance error of a light set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiffuseError {
    /// √(Σ(E_N − E)²) / √(ΣE²) over the normals.
    pub rel_rms: f64,
    /// max |E_N − E| over the normals, divided by the RMS of E.
    pub rel_max: f64,
}
