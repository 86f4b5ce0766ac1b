//! Variance-minimising partition (Viriyothai & Debevec 2009, "VMLPS"), a baseline of ALGORITHMS.md §10.
//!
//! Input: a lat-long map (the source when it is lat-long, else a lat-long image pulled from the
//! domain square, as for median cut). Output: one light per region of a recursive partition of
//! the map into rectangles. Where median cut halves a region's energy along its longer side, this
//! cuts on the axis and at the position that minimise the larger of the two halves' variance
//! Σ Y|ω − c|² = 2(P − |M|) (P = Σ Y·Δω, M = Σ Y·Δω·ω); summed-area tables of Y·Δω and Y·Δω·ω make
//! every candidate cut O(1). The region with the largest variance is split next, so any N works
//! (not only powers of two).

use super::light::Light;
use super::median_cut::{LatLong, rescale_to_domain};
use crate::envmap::EnvMap;
use crate::sampling::DomainImage;
use glam::DVec3;

/// A rectangle of lat-long pixels, [x0, x1) × [y0, y1), and its variance 2(P − |M|).
#[derive(Clone, Copy, Debug)]
struct Region {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    variance: f64,
}

/// Reusable buffers.
#[derive(Default)]
pub struct Vmlps {
    grid: LatLong,
    /// Summed-area tables, (w+1)×(rows+1): Y·Δω and the three components of Y·Δω·ω.
    sat: [Vec<f64>; 4],
}

impl Vmlps {
    /// `n` lights (fewer only when the map has fewer pixels).
    pub fn lights(&mut self, map: &EnvMap, image: &DomainImage, n: usize) -> Vec<Light> {
        let view = self.grid.view(map, image);
        let (w, rows) = (view.w, view.rows);
        let stride = w + 1;
        for s in &mut self.sat {
            s.clear();
            s.resize(stride * (rows + 1), 0.0);
        }
        for j in 0..rows {
            let mut acc = [0.0f64; 4];
            for i in 0..w {
                let y = EnvMap::luminance(view.pixels[j * w + i]) as f64 * view.row_sr(j);
                let d = view.dir(i, j);
                let v = [y, y * d.x, y * d.y, y * d.z];
                for k in 0..4 {
                    acc[k] += v[k];
                    self.sat[k][(j + 1) * stride + i + 1] =
                        self.sat[k][j * stride + i + 1] + acc[k];
                }
            }
        }
        let sat = &self.sat;
        let sums = |x0: usize, x1: usize, y0: usize, y1: usize| -> (f64, DVec3) {
            let get = |k: usize| {
                let s = &sat[k];
                s[y1 * stride + x1] - s[y0 * stride + x1] - s[y1 * stride + x0]
                    + s[y0 * stride + x0]
            };
            (get(0), DVec3::new(get(1), get(2), get(3)))
        };
        let variance = |x0, x1, y0, y1| {
            let (p, m) = sums(x0, x1, y0, y1);
            (2.0 * (p - m.length())).max(0.0)
        };
        let mut regions = vec![Region {
            x0: 0,
            x1: w,
            y0: 0,
            y1: rows,
            variance: variance(0, w, 0, rows),
        }];
        while regions.len() < n {
            // The splittable region of largest variance.
            let Some(idx) = (0..regions.len())
                .filter(|&k| regions[k].x1 - regions[k].x0 > 1 || regions[k].y1 - regions[k].y0 > 1)
                .max_by(|&a, &b| regions[a].variance.total_cmp(&regions[b].variance))
            else {
                break;
            };
            let r = regions[idx];
            // Every cut on both axes: the one whose larger half-variance is least.
            let mut best: Option<(f64, Region, Region)> = None;
            let mut consider = |a: Region, b: Region| {
                let (va, vb) = (
                    variance(a.x0, a.x1, a.y0, a.y1),
                    variance(b.x0, b.x1, b.y0, b.y1),
                );
                let worst = va.max(vb);
                if best.as_ref().is_none_or(|b| worst < b.0) {
                    best = Some((
                        worst,
                        Region { variance: va, ..a },
                        Region { variance: vb, ..b },
                    ));
                }
            };
            for c in r.x0 + 1..r.x1 {
                consider(Region { x1: c, ..r }, Region { x0: c, ..r });
            }
            for c in r.y0 + 1..r.y1 {
                consider(Region { y1: c, ..r }, Region { y0: c, ..r });
            }
            let (_, a, b) = best.expect("a splittable region has a cut");
            regions[idx] = a;
            regions.push(b);
        }

        let mut lights: Vec<Light> = regions
            .iter()
            .enumerate()
            .map(|(id, r)| {
                let (p, m) = sums(r.x0, r.x1, r.y0, r.y1);
                let mut rgb = [0.0f64; 3];
                let mut sr = 0.0;
                for j in r.y0..r.y1 {
                    let dw = view.row_sr(j);
                    for i in r.x0..r.x1 {
                        let px = view.pixels[j * w + i];
                        for c in 0..3 {
                            rgb[c] += px[c] as f64 * dw;
                        }
                    }
                    sr += dw * (r.x1 - r.x0) as f64;
                }
                let dir = m
                    .try_normalize()
                    .unwrap_or_else(|| view.dir((r.x0 + r.x1) / 2, (r.y0 + r.y1) / 2));
                Light {
                    id: id as u32,
                    to_light: dir.as_vec3().to_array(),
                    irradiance: rgb.map(|v| v as f32),
                    solid_angle: sr as f32,
                    angular_radius: super::light::angular_radius(p, m.length()),
                    extent: None,
                    shadowed: None,
                }
            })
            .collect();
        if !view.from_source {
            rescale_to_domain(&mut lights, image);
        }
        lights
    }
}
