//! Diffuse irradiance error of a light set against its map (ALGORITHMS.md §8).
//!
//! Ground truth E(n) = Σ L·max(0, n·ω)·Δω over the map, from lights E_N(n) = Σ_k irradiance_k ·
//! max(0, n·to_light_k), both in luminance, at a fixed Fibonacci sphere of normals. The error is the
//! relative RMS, √(Σ_n (E_N − E)²) / √(Σ_n E²), which stays defined where E is 0 (normals facing
//! away from a hemisphere domain).
//!
//! Glossy ([`GlossyReference`]): the same relative RMS for a normalised Phong lobe
//! (e + 1)/(2π)·max(0, r·ω)^e around the reflection r of the fixed view direction [`glossy_view`]
//! about each normal that faces the viewer (n·v > 0), ground truth by brute force over the pixels.

use super::light::Light;
use crate::envmap::EnvMap;
use crate::sampling::DomainImage;
use glam::{DVec3, Vec3, Vec4};
use multiversion::multiversion;

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

/// E_N(n) = Σ_k Y_k·max(0, n·to_light_k), in luminance, at each normal (ALGORITHMS.md §8).
pub fn irradiance_at(lights: &[Light], normals: &[DVec3]) -> Vec<f64> {
    normals
        .iter()
        .map(|n| {
            lights
                .iter()
                .map(|l| l.luminance() * n.dot(l.dir()).max(0.0))
                .sum()
        })
        .collect()
}

/// Point emitters (unit direction, luminance energy) in columns, for the brute-force sums
/// Σ e·max(0, n·d): a normal's sum runs over the columns eight at a time in f32 lanes (two SIMD
/// registers), each block of 512 emitters (`Emitters::BLOCK`) added into an f64 total, so that a map's
/// half a million pixels keep the f64 sum's precision.
pub struct Emitters {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    e: Vec<f32>,
}

impl Emitters {
    const LANES: usize = 8;
    const BLOCK: usize = 512;

    pub fn new(emitters: &[(Vec3, f32)]) -> Self {
        let n = emitters.len().next_multiple_of(Self::LANES);
        // Padding emitters carry no energy.
        let column = |f: &dyn Fn(&(Vec3, f32)) -> f32| {
            let mut c: Vec<f32> = emitters.iter().map(f).collect();
            c.resize(n, 0.0);
            c
        };
        Emitters {
            x: column(&|(d, _)| d.x),
            y: column(&|(d, _)| d.y),
            z: column(&|(d, _)| d.z),
            e: column(&|(_, e)| *e),
        }
    }

    /// E(n) = Σ e·max(0, n·d) at each of `normals`.
    pub fn irradiance_at(&self, normals: &[DVec3]) -> Vec<f64> {
        normals
            .iter()
            .map(|n| self.irradiance(n.as_vec3()))
            .collect()
    }

    fn irradiance(&self, n: Vec3) -> f64 {
        emitter_sum(&self.x, &self.y, &self.z, &self.e, n)
    }
}

/// Σ e·max(0, n·d) over emitters in columns (see [`Emitters`]). Compiled twice, the second time
/// for CPUs with AVX2 and FMA (chosen at run time), whose three-operand forms save the copies;
/// the sums and their order are the same, so both give the same bits.
#[multiversion(targets("x86_64+avx2+fma"))]
fn emitter_sum(x: &[f32], y: &[f32], z: &[f32], e: &[f32], n: Vec3) -> f64 {
    const LANES: usize = Emitters::LANES;
    let mut total = 0.0f64;
    let per_block = Emitters::BLOCK / LANES;
    let (nx, ny, nz) = (Vec4::splat(n.x), Vec4::splat(n.y), Vec4::splat(n.z));
    // The eight lanes as two glam `Vec4`s (SIMD registers on x86-64), each lane's arithmetic the
    // scalar one in the same order: written as eight scalar lanes, the compiler split them into
    // 4-, 2- and 1-lane pieces and took twice as long.
    let quads = |v: &[f32; LANES]| {
        (
            Vec4::from_slice(&v[..LANES / 2]),
            Vec4::from_slice(&v[LANES / 2..]),
        )
    };
    for (((x, y), z), e) in x
        .as_chunks::<LANES>()
        .0
        .chunks(per_block)
        .zip(y.as_chunks::<LANES>().0.chunks(per_block))
        .zip(z.as_chunks::<LANES>().0.chunks(per_block))
        .zip(e.as_chunks::<LANES>().0.chunks(per_block))
    {
        let (mut lo, mut hi) = (Vec4::ZERO, Vec4::ZERO);
        for (((x, y), z), e) in x.iter().zip(y).zip(z).zip(e) {
            let (x, y, z, e) = (quads(x), quads(y), quads(z), quads(e));
            lo += e.0 * (nx * x.0 + ny * y.0 + nz * z.0).max(Vec4::ZERO);
            hi += e.1 * (nx * x.1 + ny * y.1 + nz * z.1).max(Vec4::ZERO);
        }
        let lanes = [lo.to_array(), hi.to_array()];
        total += lanes.iter().flatten().map(|&v| v as f64).sum::<f64>();
    }
    total
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
        Self::with_normals(emitters, fibonacci_sphere(ERROR_NORMALS))
    }

    /// Brute force over every pixel of the source map inside the domain (the test oracle).
    pub fn from_map(map: &EnvMap, domain: crate::mapping::Domain) -> Self {
        Self::from_emitters(&map_emitters(map, domain))
    }

    /// From emitters, at the given normals instead of the default [`ERROR_NORMALS`] Fibonacci set.
    pub fn with_normals(emitters: &[(Vec3, f32)], normals: Vec<DVec3>) -> Self {
        let truth = Emitters::new(emitters).irradiance_at(&normals);
        IrradianceReference { normals, truth }
    }

    /// From a reduced copy of the domain square: texels binned into a 64×64 grid, each bin an
    /// emitter at the luminance-weighted mean direction of the source pixels in it (the texels'
    /// first moments summed rather than their centres, so the binning does not move a small source
    /// like the sun: the error is second order). Cheap enough for every `--max-error` request.
    pub fn from_domain_image(image: &DomainImage) -> Self {
        Self::from_domain_image_at(image, REDUCED_SIDE, fibonacci_sphere(ERROR_NORMALS))
    }

    /// As [`from_domain_image`](Self::from_domain_image), binned into a `grid`×`grid` square and
    /// evaluated at `normals`: coarser and cheaper, for choosing between light sets.
    pub fn from_domain_image_at(image: &DomainImage, grid: usize, normals: Vec<DVec3>) -> Self {
        Self::with_normals(&binned_emitters(image, grid), normals)
    }

    /// E_N at every reference normal from a light set.
    pub fn light_irradiance(&self, lights: &[Light]) -> Vec<f64> {
        irradiance_at(lights, &self.normals)
    }

    /// Relative RMS and relative max error of `estimate` (one value per normal).
    pub fn error_of(&self, estimate: &[f64]) -> DiffuseError {
        relative_error(estimate, &self.truth)
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

/// Every pixel of `map` inside `domain` with positive luminance, as an emitter (unit direction,
/// luminance × sr): the brute-force ground truth of ALGORITHMS.md §8.
pub fn map_emitters(map: &EnvMap, domain: crate::mapping::Domain) -> Vec<(Vec3, f32)> {
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
    emitters
}

/// √(Σ(e − t)²)/√(Σt²) and max|e − t| / RMS(t); a zero truth is matched only by a zero estimate.
pub fn relative_error(estimate: &[f64], truth: &[f64]) -> DiffuseError {
    debug_assert_eq!(estimate.len(), truth.len());
    let mut num = 0.0;
    let mut den = 0.0;
    let mut max_abs: f64 = 0.0;
    for (e, t) in estimate.iter().zip(truth) {
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
    let rms_truth = (den / truth.len() as f64).sqrt();
    DiffuseError {
        rel_rms: (num / den).sqrt(),
        rel_max: max_abs / rms_truth,
    }
}

/// Phong exponents of the glossy error (ALGORITHMS.md §8).
pub const GLOSSY_EXPONENTS: [u32; 2] = [32, 128];

/// Normals used for the glossy error; about half face the viewer, so the ≈ 512 reflection
/// directions probe the sphere about every 9° (the e = 128 lobe's half-width at half maximum is 6°).
pub const GLOSSY_NORMALS: usize = 1024;

/// The fixed view direction of the glossy error: unit vector from the surface toward the eye,
/// 30° above the horizon looking along −Z (so the eye is on the +Z side).
pub fn glossy_view() -> DVec3 {
    let e = 30f64.to_radians();
    DVec3::new(0.0, e.sin(), e.cos())
}

/// The normalised Phong lobe (e + 1)/(2π)·max(0, r·ω)^e (it integrates to 1 over the sphere).
fn phong(exponent: u32, cos: f32) -> f32 {
    if cos <= 0.0 {
        return 0.0;
    }
    (exponent as f32 + 1.0) / std::f32::consts::TAU * cos.powi(exponent as i32)
}

/// Ground truth of glossy reflection: G(n) = Σ L·lobe(r(n)·ω)·Δω at the reflection r of
/// [`glossy_view`] about each normal that faces the viewer.
pub struct GlossyReference {
    exponent: u32,
    reflections: Vec<Vec3>,
    truth: Vec<f64>,
}

impl GlossyReference {
    /// From emitters (unit direction, luminance × sr), e.g. [`map_emitters`].
    pub fn from_emitters(emitters: &[(Vec3, f32)], exponent: u32) -> Self {
        let v = glossy_view();
        let reflections: Vec<Vec3> = fibonacci_sphere(GLOSSY_NORMALS)
            .into_iter()
            .filter(|n| n.dot(v) > 0.0)
            .map(|n| (2.0 * n.dot(v) * n - v).normalize().as_vec3())
            .collect();
        let truth = reflections
            .iter()
            .map(|r| {
                emitters
                    .iter()
                    .map(|(d, e)| (*e * phong(exponent, r.dot(*d))) as f64)
                    .sum()
            })
            .collect();
        GlossyReference {
            exponent,
            reflections,
            truth,
        }
    }

    /// Glossy estimate from a light set, one value per reflection direction.
    pub fn estimate(&self, lights: &[Light]) -> Vec<f64> {
        self.reflections
            .iter()
            .map(|r| {
                lights
                    .iter()
                    .map(|l| {
                        l.luminance()
                            * phong(self.exponent, r.dot(Vec3::from_array(l.to_light))) as f64
                    })
                    .sum()
            })
            .collect()
    }

    /// Relative RMS and max error of a light set's glossy reflection.
    pub fn error(&self, lights: &[Light]) -> DiffuseError {
        relative_error(&self.estimate(lights), &self.truth)
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

/// The domain square binned into `grid`×`grid` emitters (luminance × sr), each at the summed first
/// moment of its texels: a small source like the sun stays where it is.
pub fn binned_emitters(image: &DomainImage, grid: usize) -> Vec<(Vec3, f32)> {
    let side = image.side;
    let g = grid.clamp(1, side.max(1));
    let mut bins = vec![(Vec3::ZERO, 0.0f32); g * g];
    let sr = image.texel_solid_angle() as f32;
    let column_bin: Vec<usize> = (0..side).map(|i| i * g / side).collect();
    for j in 0..side {
        let row = &mut bins[(j * g / side) * g..][..g];
        let texels = j * side..(j + 1) * side;
        for ((&y, m), &b) in image.luminance[texels.clone()]
            .iter()
            .zip(&image.moment[texels])
            .zip(&column_bin)
        {
            if y > 0.0 {
                let b = &mut row[b];
                b.0 += Vec3::from_array(*m);
                b.1 += y;
            }
        }
    }
    for b in &mut bins {
        b.0 *= sr;
        b.1 *= sr;
    }
    bins.into_iter()
        .filter(|b| b.1 > 0.0)
        .map(|(d, e)| (d.normalize_or(Vec3::Y), e))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(dir: Vec3, y: f32) -> Light {
        Light {
            id: 0,
            to_light: dir.normalize().to_array(),
            irradiance: [y; 3],
            solid_angle: 0.0,
            angular_radius: 0.0,
            extent: None,
            shadowed: None,
        }
    }

    /// Emitters that are themselves point lights are reproduced exactly; moving one of them by a
    /// few degrees costs more under the narrow lobe than under the wide one.
    #[test]
    fn glossy_error_is_zero_for_the_emitters_themselves_and_grows_with_the_exponent() {
        let dirs = [
            Vec3::new(0.3, 0.8, 0.5),
            Vec3::new(-0.6, 0.2, 0.7),
            Vec3::new(0.1, -0.4, -0.9),
        ];
        let emitters: Vec<(Vec3, f32)> = dirs.iter().map(|d| (d.normalize(), 2.0)).collect();
        let exact: Vec<Light> = dirs.iter().map(|&d| light(d, 2.0)).collect();
        let mut moved = exact.clone();
        let d = Vec3::from_array(moved[0].to_light);
        moved[0].to_light = (d + Vec3::new(0.06, 0.0, -0.04)).normalize().to_array();
        let errs: Vec<f64> = GLOSSY_EXPONENTS
            .iter()
            .map(|&e| {
                let r = GlossyReference::from_emitters(&emitters, e);
                assert!(r.error(&exact).rel_rms < 1e-6, "e = {e}");
                r.error(&moved).rel_rms
            })
            .collect();
        assert!(errs[0] > 0.01 && errs[1] > errs[0], "{errs:?}");
    }

    /// The lobe integrates to 1 over the sphere: a uniform unit sky gives G = 1 everywhere.
    #[test]
    fn phong_lobe_is_normalised() {
        let normals = fibonacci_sphere(200_000);
        let sr = 4.0 * std::f64::consts::PI / normals.len() as f64;
        let emitters: Vec<(Vec3, f32)> = normals.iter().map(|n| (n.as_vec3(), sr as f32)).collect();
        for e in GLOSSY_EXPONENTS {
            let r = GlossyReference::from_emitters(&emitters[..], e);
            let worst = r
                .truth()
                .iter()
                .map(|g| (g - 1.0).abs())
                .fold(0.0, f64::max);
            assert!(worst < 0.02, "e = {e}: {worst}");
        }
    }
}
