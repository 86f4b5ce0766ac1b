//! The bicontinuous 2-D inverse transform of ALGORITHMS.md §2.
//!
//! Input: a non-negative density tabulated on a W×H grid over the unit square (here the luminance of
//! the domain square). Output: the warp T⁻¹ from uniform points to points distributed by that density,
//! and its forward map T. Unlike the textbook marginal/conditional warp, the conditional CDF is
//! interpolated between row centres, so a fixed point moves continuously when ξ or the data change —
//! a light that cannot teleport between frames.

use glam::DVec2;

/// Relative floor on texel density (ε·mean), so every row and texel has positive mass and the warp
/// stays a homeomorphism even on black regions. ALGORITHMS.md §2.
pub const DENSITY_FLOOR: f64 = 1e-6;

/// A tabulated density on the unit square with a continuous inverse transform.
///
/// Buffers are kept between [`build`](Self::build) calls so the per-frame rebuild does not allocate.
#[derive(Clone, Debug, Default)]
pub struct Distribution2D {
    w: usize,
    h: usize,
    /// Marginal CDF over rows, `h + 1` entries from 0 to 1.
    marginal_cdf: Vec<f64>,
    /// Per-row conditional CDFs over columns, `h` rows of `w + 1` entries each, 0 to 1.
    conditional_cdf: Vec<f64>,
    /// Sum of the (floored) input values, before normalisation.
    total: f64,
}

impl Distribution2D {
    /// Builds from `values` (row-major, `w` columns, `h` rows); negative or non-finite values count as 0.
    pub fn new(values: &[f32], w: usize, h: usize) -> Self {
        let mut d = Self::default();
        d.build(values, w, h);
        d
    }

    /// Rebuilds in place, reusing the buffers.
    pub fn build(&mut self, values: &[f32], w: usize, h: usize) {
        assert!(
            w > 0 && h > 0 && values.len() == w * h,
            "grid {w}×{h} vs {} values",
            values.len()
        );
        self.w = w;
        self.h = h;
        let raw_total: f64 = values.iter().map(|&v| clean(v)).sum();
        let mean = raw_total / (w * h) as f64;
        // All-black input: floor at an absolute value so the warp degenerates to the identity.
        let floor = if mean > 0.0 {
            DENSITY_FLOOR * mean
        } else {
            1.0
        };

        self.conditional_cdf.resize(h * (w + 1), 0.0);
        self.marginal_cdf.resize(h + 1, 0.0);
        self.marginal_cdf[0] = 0.0;
        let mut total = 0.0;
        for (j, row) in values.chunks_exact(w).enumerate() {
            let cdf = &mut self.conditional_cdf[j * (w + 1)..(j + 1) * (w + 1)];
            cdf[0] = 0.0;
            let mut acc = 0.0;
            for (i, &v) in row.iter().enumerate() {
                acc += clean(v).max(floor);
                cdf[i + 1] = acc;
            }
            let inv = 1.0 / acc;
            for c in cdf.iter_mut() {
                *c *= inv;
            }
            cdf[w] = 1.0;
            total += acc;
            self.marginal_cdf[j + 1] = total;
        }
        let inv = 1.0 / total;
        for c in self.marginal_cdf.iter_mut() {
            *c *= inv;
        }
        self.marginal_cdf[h] = 1.0;
        self.total = total;
    }

    pub fn width(&self) -> usize {
        self.w
    }

    pub fn height(&self) -> usize {
        self.h
    }

    /// The two rows whose conditional CDFs are mixed at height `y`, and the weight of the second:
    /// t = y·H − (j + ½), clamped at the first and last half rows. ALGORITHMS.md §2.
    fn row_mix(&self, y: f64) -> (usize, usize, f64) {
        let s = y * self.h as f64 - 0.5;
        if s <= 0.0 {
            return (0, 0, 0.0);
        }
        let j = s.floor() as usize;
        if j + 1 >= self.h {
            return (self.h - 1, self.h - 1, 0.0);
        }
        (j, j + 1, s - j as f64)
    }

    fn row_cdf(&self, j: usize) -> &[f64] {
        &self.conditional_cdf[j * (self.w + 1)..(j + 1) * (self.w + 1)]
    }

    /// The warp T⁻¹: a uniform point ξ ∈ \[0,1\]² → a point distributed by the density.
    pub fn sample(&self, xi: DVec2) -> DVec2 {
        let (w, h) = (self.w as f64, self.h as f64);
        // y from the marginal: its CDF is piecewise linear and strictly increasing.
        let j = find_segment(&self.marginal_cdf, xi.y);
        let (c0, c1) = (self.marginal_cdf[j], self.marginal_cdf[j + 1]);
        let y = ((j as f64 + (xi.y - c0) / (c1 - c0)) / h).clamp(0.0, 1.0);

        // x from the mixture of the two neighbouring rows' conditional CDFs, also piecewise linear
        // with breakpoints at column edges.
        let (ja, jb, t) = self.row_mix(y);
        let (fa, fb) = (self.row_cdf(ja), self.row_cdf(jb));
        let g = |i: usize| (1.0 - t) * fa[i] + t * fb[i];
        // Binary search for the column i with G(i) ≤ ξ₁ < G(i+1).
        let (mut lo, mut hi) = (0usize, self.w);
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if g(mid) <= xi.x {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let (g0, g1) = (g(lo), g(lo + 1));
        let x = ((lo as f64 + (xi.x - g0) / (g1 - g0)) / w).clamp(0.0, 1.0);
        DVec2::new(x, y)
    }

    /// The forward map T: a point of the square → the uniform point that warps onto it,
    /// T(x, y) = (F(x | y), F_V(y)).
    pub fn forward(&self, p: DVec2) -> DVec2 {
        let y = p.y.clamp(0.0, 1.0);
        let x = p.x.clamp(0.0, 1.0);
        DVec2::new(self.conditional_at(x, y), lerp_cdf(&self.marginal_cdf, y))
    }

    /// F(x | y), the interpolated conditional CDF.
    fn conditional_at(&self, x: f64, y: f64) -> f64 {
        let (ja, jb, t) = self.row_mix(y);
        (1.0 - t) * lerp_cdf(self.row_cdf(ja), x) + t * lerp_cdf(self.row_cdf(jb), x)
    }

    /// The density the warp actually induces, p(x,y) = p_V(y)·[(1−t)p_j(x) + t·p_{j+1}(x)]
    /// (ALGORITHMS.md §2), with respect to area on the unit square.
    pub fn pdf(&self, p: DVec2) -> f64 {
        let (w, h) = (self.w as f64, self.h as f64);
        let y = p.y.clamp(0.0, 1.0);
        let x = p.x.clamp(0.0, 1.0);
        let row = ((y * h) as usize).min(self.h - 1);
        let p_v = (self.marginal_cdf[row + 1] - self.marginal_cdf[row]) * h;
        let col = ((x * w) as usize).min(self.w - 1);
        let (ja, jb, t) = self.row_mix(y);
        let pa = (self.row_cdf(ja)[col + 1] - self.row_cdf(ja)[col]) * w;
        let pb = (self.row_cdf(jb)[col + 1] - self.row_cdf(jb)[col]) * w;
        p_v * ((1.0 - t) * pa + t * pb)
    }

    /// Sum of the floored input values (the unnormalised integral times W·H).
    pub fn total(&self) -> f64 {
        self.total
    }
}

fn clean(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        v as f64
    } else {
        0.0
    }
}

/// Index i with cdf[i] ≤ u < cdf[i+1] (clamped to a valid segment).
fn find_segment(cdf: &[f64], u: f64) -> usize {
    let n = cdf.len() - 1;
    let i = cdf.partition_point(|&c| c <= u);
    i.saturating_sub(1).min(n - 1)
}

/// A piecewise-linear CDF with `n + 1` knots at k/n, evaluated at x ∈ [0,1].
fn lerp_cdf(cdf: &[f64], x: f64) -> f64 {
    let n = cdf.len() - 1;
    let s = x * n as f64;
    let i = (s as usize).min(n - 1);
    let t = s - i as f64;
    cdf[i] + t * (cdf[i + 1] - cdf[i])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::lcg;

    fn random_grid(w: usize, h: usize, seed: u64) -> Vec<f32> {
        let mut s = seed;
        (0..w * h)
            .map(|_| (lcg(&mut s) * 10.0) as f32 + 0.01)
            .collect()
    }

    #[test]
    fn constant_density_is_identity() {
        let d = Distribution2D::new(&vec![3.0; 16 * 8], 16, 8);
        let mut s = 1u64;
        for _ in 0..10_000 {
            let xi = DVec2::new(lcg(&mut s), lcg(&mut s));
            assert!((d.sample(xi) - xi).abs().max_element() < 1e-12, "{xi}");
        }
    }

    #[test]
    fn forward_inverts_sample() {
        let d = Distribution2D::new(&random_grid(13, 9, 3), 13, 9);
        let mut s = 5u64;
        for _ in 0..10_000 {
            let xi = DVec2::new(lcg(&mut s), lcg(&mut s));
            let p = d.sample(xi);
            let back = d.forward(p);
            assert!(
                (back - xi).abs().max_element() < 1e-10,
                "{xi} -> {p} -> {back}"
            );
        }
    }

    /// ALGORITHMS.md §2: crossing any row boundary with Δξ = 1e−7 moves the point by < 1e−5.
    #[test]
    fn continuous_across_row_boundaries() {
        let (w, h) = (8, 8);
        let d = Distribution2D::new(&random_grid(w, h, 9), w, h);
        let mut worst = 0.0f64;
        for j in 1..h {
            let c = d.marginal_cdf[j];
            for k in 0..=200 {
                let x = k as f64 / 200.0;
                let a = d.sample(DVec2::new(x, c - 0.5e-7));
                let b = d.sample(DVec2::new(x, c + 0.5e-7));
                worst = worst.max((a - b).length());
            }
        }
        assert!(worst < 1e-5, "largest jump {worst}");

        // The textbook warp jumps by a large fraction of the width here; check the data can show it.
        let textbook_jump = |j: usize, x: f64| {
            let fa = d.row_cdf(j - 1);
            let fb = d.row_cdf(j);
            let inv = |f: &[f64]| find_segment(f, x) as f64;
            (inv(fa) - inv(fb)).abs() / w as f64
        };
        let biggest: f64 = (1..h)
            .flat_map(|j| (0..50).map(move |k| (j, k as f64 / 50.0)))
            .map(|(j, x)| textbook_jump(j, x))
            .fold(0.0, f64::max);
        assert!(
            biggest >= 0.25,
            "random density should break the textbook warp ({biggest})"
        );
    }

    /// χ² of warped samples against the induced density (integrated exactly per texel).
    #[test]
    fn chi_square_against_density() {
        let (w, h) = (6, 5);
        let d = Distribution2D::new(&random_grid(w, h, 21), w, h);
        let n = 200_000;
        let mut counts = vec![0usize; w * h];
        let mut s = 17u64;
        for _ in 0..n {
            let p = d.sample(DVec2::new(lcg(&mut s), lcg(&mut s)));
            let i = ((p.x * w as f64) as usize).min(w - 1);
            let j = ((p.y * h as f64) as usize).min(h - 1);
            counts[j * w + i] += 1;
        }
        // The density is linear in y on each half row and constant in x per column, so the midpoint
        // rule on half rows integrates it exactly.
        let mut chi2 = 0.0;
        for j in 0..h {
            for i in 0..w {
                let x = (i as f64 + 0.5) / w as f64;
                let mass: f64 = [0.25, 0.75]
                    .iter()
                    .map(|f| d.pdf(DVec2::new(x, (j as f64 + f) / h as f64)) * 0.5)
                    .sum::<f64>()
                    / (w * h) as f64;
                let expected = mass * n as f64;
                let o = counts[j * w + i] as f64;
                chi2 += (o - expected).powi(2) / expected;
            }
        }
        // 29 degrees of freedom: the 99.9th percentile of χ² is 58.3.
        assert!(chi2 < 58.3, "chi² = {chi2}");
    }

    #[test]
    fn zero_rows_stay_defined() {
        let mut v = vec![0.0f32; 8 * 8];
        v[27] = 5.0;
        v[3] = f32::NAN;
        v[4] = -2.0;
        let d = Distribution2D::new(&v, 8, 8);
        let mut s = 3u64;
        let mut hits = 0;
        for _ in 0..10_000 {
            let p = d.sample(DVec2::new(lcg(&mut s), lcg(&mut s)));
            assert!(p.is_finite());
            if (p.x * 8.0) as usize == 3 && (p.y * 8.0) as usize == 3 {
                hits += 1;
            }
        }
        // Nearly all mass is in texel 27 = (3, 3); the conditional mixing spreads some into the
        // neighbouring rows' half, but never more than half.
        assert!(hits > 4_000, "{hits}");
        let all_black = Distribution2D::new(&[0.0; 16], 4, 4);
        assert!((all_black.sample(DVec2::new(0.3, 0.7)) - DVec2::new(0.3, 0.7)).length() < 1e-12);
    }
}
