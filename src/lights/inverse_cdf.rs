//! The discontinuous textbook inverse CDF on the lat-long map: the baseline of ALGORITHMS.md §7 that
//! shows what the bicontinuous warp of §2 buys.
//!
//! Input: an [`EnvMap`] (its own pixels when it is lat-long; otherwise a lat-long image pulled from the
//! domain square) and the domain image. Output: the warped progressive points, one direction per
//! point, which [`Extractor`](super::Extractor) then turns into lights exactly as the default method
//! does (each texel's energy to the nearest light on the sphere, the light moved to its cell's
//! luminance-weighted centroid). So the **only** difference from [`Method::Voronoi`](super::Method)
//! is the warp: this one is pbrt-v3's `Distribution2D` (marginal CDF over rows, then the chosen row's
//! conditional CDF, linear inside a bin and no interpolation between rows), whose points jump when
//! they cross a row boundary of the marginal.
//!
//! The density is the pixel luminance × sin θ of its row centre (pbrt-v3 `InfiniteAreaLight`), so
//! pdf_ω = pdf_uv / (2π² sin θ). Zero rows and all-black maps follow pbrt-v3: a distribution whose
//! integral is 0 becomes uniform.

use crate::envmap::{EnvMap, Projection};
use crate::mapping::Domain;
use crate::sampling::DomainImage;
use crate::sampling::resample::LatLongView;
use glam::{DVec2, DVec3, Vec3};
use std::f64::consts::PI;

/// pbrt-v3's `Distribution1D`: a piecewise-constant function and its CDF.
#[derive(Clone, Debug, Default)]
struct Distribution1D {
    /// n + 1 entries, from 0 to 1.
    cdf: Vec<f64>,
    /// ∫ f over [0, 1] (the mean of the values).
    integral: f64,
}

impl Distribution1D {
    fn build(&mut self, values: impl ExactSizeIterator<Item = f64>) {
        let n = values.len();
        self.cdf.clear();
        self.cdf.push(0.0);
        let mut acc = 0.0;
        for v in values {
            acc += v / n as f64;
            self.cdf.push(acc);
        }
        self.integral = acc;
        if acc > 0.0 {
            for c in &mut self.cdf {
                *c /= acc;
            }
        } else {
            // pbrt-v3: a zero function samples uniformly.
            for (i, c) in self.cdf.iter_mut().enumerate() {
                *c = i as f64 / n as f64;
            }
        }
    }

    /// `SampleContinuous`: the largest i with cdf[i] ≤ u, then linear inside that bin.
    fn sample(&self, u: f64) -> f64 {
        let n = self.cdf.len() - 1;
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .saturating_sub(1)
            .min(n - 1);
        let width = self.cdf[i + 1] - self.cdf[i];
        let du = if width > 0.0 {
            (u - self.cdf[i]) / width
        } else {
            0.0
        };
        ((i as f64 + du) / n as f64).clamp(0.0, 1.0)
    }
}

/// pbrt-v3's `Distribution2D` over a W×H grid: marginal over rows, conditional per row.
#[derive(Clone, Debug, Default)]
pub struct PiecewiseConstant2D {
    conditional: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl PiecewiseConstant2D {
    /// Rebuilds from row-major `values` (W columns, H rows), reusing the buffers; negative and
    /// non-finite values count as 0.
    pub fn build(&mut self, values: &[f32], w: usize, h: usize) {
        assert!(w > 0 && h > 0 && values.len() == w * h, "grid {w}×{h}");
        self.conditional.resize_with(h, Distribution1D::default);
        for (row, d) in values.chunks_exact(w).zip(&mut self.conditional) {
            d.build(row.iter().map(|&v| clean(v)));
        }
        let integrals: Vec<f64> = self.conditional.iter().map(|d| d.integral).collect();
        self.marginal.build(integrals.into_iter());
    }

    /// The discontinuous warp: ξ ∈ \[0,1\]² → (u, v) ∈ \[0,1\]², v from the marginal with ξ.y, then u
    /// from row ⌊v·H⌋'s conditional with ξ.x.
    pub fn sample(&self, xi: DVec2) -> DVec2 {
        let v = self.marginal.sample(xi.y);
        let h = self.conditional.len();
        let row = ((v * h as f64) as usize).min(h - 1);
        DVec2::new(self.conditional[row].sample(xi.x), v)
    }
}

fn clean(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        v as f64
    } else {
        0.0
    }
}

/// Reusable state of the inverse-CDF seeding.
#[derive(Default)]
pub struct InverseCdf {
    dist: PiecewiseConstant2D,
    /// Luminance × sin θ of the lat-long rows inside the domain.
    density: Vec<f32>,
    /// For non-lat-long sources: a lat-long view of the domain square.
    view: LatLongView,
}

impl InverseCdf {
    /// Pushes the first `n` of `points` through the discontinuous lat-long warp, writing one
    /// direction per point into `out`.
    pub fn seeds(
        &mut self,
        map: &EnvMap,
        image: &DomainImage,
        points: &[DVec2],
        out: &mut Vec<Vec3>,
    ) {
        let domain = image.domain;
        let (w, h) = if map.projection == Projection::LatLong {
            (map.width, map.height)
        } else {
            (2 * image.side, image.side)
        };
        // Rows inside the domain, as median cut counts them: every row for the sphere, rows whose
        // centre is above the horizon for the hemisphere.
        let rows = match domain {
            Domain::Sphere => h,
            Domain::Upper => h.div_ceil(2),
        };
        let pixels: &[[f32; 3]] = if map.projection == Projection::LatLong {
            &map.pixels
        } else {
            self.view.pull(image).2
        };
        self.density.clear();
        for j in 0..rows {
            let s = (PI * (j as f64 + 0.5) / h as f64).sin() as f32;
            self.density.extend(
                pixels[j * w..(j + 1) * w]
                    .iter()
                    .map(|&p| EnvMap::luminance(p) * s),
            );
        }
        self.dist.build(&self.density, w, rows);
        let v_scale = rows as f64 / h as f64;
        out.clear();
        out.extend(points.iter().map(|&p| {
            let uv = self.dist.sample(p);
            // DESIGN.md lat-long convention: θ = π·v from +Y, φ = 2π(u − ½).
            let theta = PI * uv.y * v_scale;
            let phi = 2.0 * PI * (uv.x - 0.5);
            let (st, ct) = theta.sin_cos();
            let (sp, cp) = phi.sin_cos();
            DVec3::new(st * sp, ct, -st * cp).as_vec3()
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_density_is_identity() {
        let mut d = PiecewiseConstant2D::default();
        d.build(&[2.0; 8 * 4], 8, 4);
        for xi in [
            DVec2::new(0.1, 0.9),
            DVec2::new(0.55, 0.3),
            DVec2::new(0.0, 0.0),
        ] {
            assert!((d.sample(xi) - xi).length() < 1e-12, "{xi}");
        }
    }

    /// The point of this baseline: crossing a marginal row boundary makes u jump.
    #[test]
    fn jumps_across_row_boundaries() {
        // Row 0: all mass in column 0; row 1: all mass in column 3.
        let mut v = vec![0.0f32; 4 * 2];
        v[0] = 1.0;
        v[4 + 3] = 1.0;
        let mut d = PiecewiseConstant2D::default();
        d.build(&v, 4, 2);
        let a = d.sample(DVec2::new(0.5, 0.5 - 1e-9));
        let b = d.sample(DVec2::new(0.5, 0.5 + 1e-9));
        assert!((a.x - b.x).abs() > 0.5, "{a} -> {b}");
    }

    #[test]
    fn zero_function_is_uniform_and_finite() {
        let mut d = PiecewiseConstant2D::default();
        d.build(&[0.0, f32::NAN, -1.0, 0.0], 2, 2);
        let p = d.sample(DVec2::new(0.25, 0.75));
        assert!((p - DVec2::new(0.25, 0.75)).length() < 1e-12, "{p}");
    }
}
