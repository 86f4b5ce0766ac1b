//! Median cut (Debevec 2005), the baseline of ALGORITHMS.md §7.
//!
//! Input: a lat-long map (the source itself when it is lat-long; otherwise a lat-long image pulled
//! from the domain square). Output: lights at the energy centroids of 2ⁿ regions of equal energy.
//! Regions are split along their longer side (width scaled by the cosine of latitude) at the point
//! of half energy, found with a summed-area table so each split costs O(log size).

use super::Light;
use crate::envmap::{EnvMap, Projection};
use crate::sampling::domain::LatLongView;
use crate::sampling::{Domain, DomainImage};
use glam::DVec3;
use std::f64::consts::PI;

/// A rectangle of lat-long pixels, [x0, x1) × [y0, y1).
#[derive(Clone, Copy, Debug)]
struct Region {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    energy: f64,
}

/// Reusable buffers for median cut.
#[derive(Default)]
pub struct MedianCut {
    /// Summed-area table of luminance·Δω, (w+1)×(h+1).
    sat: Vec<f64>,
    /// The lat-long view used when the source is not lat-long.
    view: LatLongView,
    /// Per column (sin φ, cos φ) and per row (sin θ, cos θ, Δω) of the lat-long grid.
    columns: Vec<(f64, f64)>,
    rows: Vec<(f64, f64, f64)>,
}

impl MedianCut {
    /// Up to `n` lights by median cut; with `n` not a power of two the last round splits the
    /// most energetic regions first.
    pub fn lights(&mut self, map: &EnvMap, image: &DomainImage, n: usize) -> Vec<Light> {
        let domain = image.domain;
        let from_source = map.projection == Projection::LatLong;
        let (w, h, pixels): (usize, usize, &[[f32; 3]]) = if from_source {
            (map.width, map.height, &map.pixels)
        } else {
            // A lat-long image pulled from the domain square at about its resolution.
            self.view.pull(image)
        };
        // Rows inside the domain: all for the sphere, the upper half (pixel centre above the
        // horizon) for the hemisphere.
        let rows = match domain {
            Domain::Sphere => h,
            Domain::Upper => h.div_ceil(2),
        };
        if self.columns.len() != w || self.rows.len() != h {
            self.columns = (0..w)
                .map(|i| (2.0 * PI * ((i as f64 + 0.5) / w as f64 - 0.5)).sin_cos())
                .collect();
            self.rows = (0..h)
                .map(|j| {
                    let (st, ct) = (PI * (j as f64 + 0.5) / h as f64).sin_cos();
                    let sr = Projection::LatLong.pixel(0, j, w, h).expect("lat-long").1;
                    (st, ct, sr)
                })
                .collect();
        }
        let row_sr: Vec<f64> = self.rows.iter().map(|r| r.2).collect();

        // Summed-area table of luminance energy.
        self.sat.clear();
        self.sat.resize((w + 1) * (rows + 1), 0.0);
        for j in 0..rows {
            let mut row_acc = 0.0;
            for i in 0..w {
                row_acc += EnvMap::luminance(pixels[j * w + i]) as f64 * row_sr[j];
                self.sat[(j + 1) * (w + 1) + i + 1] = self.sat[j * (w + 1) + i + 1] + row_acc;
            }
        }
        let sat = &self.sat;
        let energy = |x0: usize, x1: usize, y0: usize, y1: usize| {
            sat[y1 * (w + 1) + x1] - sat[y0 * (w + 1) + x1] - sat[y1 * (w + 1) + x0]
                + sat[y0 * (w + 1) + x0]
        };

        let mut regions = vec![Region {
            x0: 0,
            x1: w,
            y0: 0,
            y1: rows,
            energy: energy(0, w, 0, rows),
        }];
        while regions.len() < n {
            // One round: split every region (most energetic first) while there is budget.
            let mut order: Vec<usize> = (0..regions.len()).collect();
            order.sort_by(|&a, &b| regions[b].energy.total_cmp(&regions[a].energy));
            let mut next = Vec::with_capacity(regions.len() * 2);
            let mut budget = n - regions.len();
            let mut split_any = false;
            for idx in order {
                let r = regions[idx];
                if budget > 0
                    && let Some((a, b)) = split(r, h, w, &energy)
                {
                    next.push(a);
                    next.push(b);
                    budget -= 1;
                    split_any = true;
                } else {
                    next.push(r);
                }
            }
            regions = next;
            if !split_any {
                break;
            }
        }

        // Each region's light: RGB energy and the luminance-weighted mean direction.
        let (columns, row_trig) = (&self.columns, &self.rows);
        let mut lights: Vec<Light> = regions
            .iter()
            .enumerate()
            .map(|(id, r)| {
                let mut rgb = [0.0f64; 3];
                let mut dir = DVec3::ZERO;
                let mut sr = 0.0;
                for j in r.y0..r.y1 {
                    // d = (sin θ sin φ, cos θ, −sin θ cos φ), DESIGN.md's lat-long convention.
                    let (st, ct, dw) = row_trig[j];
                    let mut row_rgb = [0.0f64; 3];
                    let (mut sx, mut sz, mut sy) = (0.0f64, 0.0f64, 0.0f64);
                    for i in r.x0..r.x1 {
                        let p = pixels[j * w + i];
                        for c in 0..3 {
                            row_rgb[c] += p[c] as f64;
                        }
                        let y = EnvMap::luminance(p) as f64;
                        let (sp, cp) = columns[i];
                        sx += y * sp;
                        sz -= y * cp;
                        sy += y;
                    }
                    for c in 0..3 {
                        rgb[c] += row_rgb[c] * dw;
                    }
                    dir += DVec3::new(sx * st, sy * ct, sz * st) * dw;
                    sr += dw * (r.x1 - r.x0) as f64;
                }
                let centre = || {
                    let (d, _) = Projection::LatLong
                        .pixel((r.x0 + r.x1) / 2, (r.y0 + r.y1) / 2, w, h)
                        .expect("lat-long");
                    d
                };
                Light {
                    id: id as u32,
                    to_light: dir
                        .try_normalize()
                        .unwrap_or_else(centre)
                        .as_vec3()
                        .to_array(),
                    irradiance: rgb.map(|v| v as f32),
                    solid_angle: sr as f32,
                }
            })
            .collect();
        if !from_source {
            // The pulled lat-long image approximates the domain square; rescale so the lights
            // carry exactly the domain's energy, as every method must.
            let want = image.integral();
            let got = super::total_irradiance(&lights);
            for l in &mut lights {
                for c in 0..3 {
                    if got[c] > 0.0 {
                        l.irradiance[c] = (l.irradiance[c] as f64 * want[c] / got[c]) as f32;
                    }
                }
            }
        }
        lights
    }
}

/// Splits a region across its longer side (width measured at the region's central latitude) at the
/// pixel boundary closest to half its energy; `None` for a single pixel.
fn split(
    r: Region,
    h: usize,
    w: usize,
    energy: &impl Fn(usize, usize, usize, usize) -> f64,
) -> Option<(Region, Region)> {
    let (nx, ny) = (r.x1 - r.x0, r.y1 - r.y0);
    if nx < 2 && ny < 2 {
        return None;
    }
    let lat_centre = PI * (0.5 - (r.y0 + r.y1) as f64 / (2.0 * h as f64));
    let width_angle = nx as f64 * 2.0 * PI / w as f64 * lat_centre.cos();
    let height_angle = ny as f64 * PI / h as f64;
    let along_x = if nx < 2 {
        false
    } else if ny < 2 {
        true
    } else {
        width_angle >= height_angle
    };
    let half = r.energy * 0.5;
    // Binary search the first cut position c with energy(before c) ≥ half, then take c or c − 1,
    // whichever is closer to half, keeping both sides non-empty.
    let (lo, hi) = if along_x { (r.x0, r.x1) } else { (r.y0, r.y1) };
    let before = |c: usize| {
        if along_x {
            energy(r.x0, c, r.y0, r.y1)
        } else {
            energy(r.x0, r.x1, r.y0, c)
        }
    };
    let (mut a, mut b) = (lo + 1, hi - 1);
    while a < b {
        let mid = (a + b) / 2;
        if before(mid) >= half {
            b = mid;
        } else {
            a = mid + 1;
        }
    }
    let mut cut = a;
    if cut > lo + 1 && (before(cut - 1) - half).abs() < (before(cut) - half).abs() {
        cut -= 1;
    }
    let e_first = before(cut);
    let (first, second) = if along_x {
        (Region { x1: cut, ..r }, Region { x0: cut, ..r })
    } else {
        (Region { y1: cut, ..r }, Region { y0: cut, ..r })
    };
    Some((
        Region {
            energy: e_first,
            ..first
        },
        Region {
            energy: r.energy - e_first,
            ..second
        },
    ))
}
