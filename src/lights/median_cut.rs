//! Median cut (Debevec 2005), the baseline of ALGORITHMS.md §7.
//!
//! Input: a lat-long map (the source itself when it is lat-long; otherwise a lat-long image pulled
//! from the domain square). Output: lights at the energy centroids of 2ⁿ regions of equal energy.
//! Regions are split along their longer side (width scaled by the cosine of latitude) at the point
//! of half energy, found with a summed-area table so each split costs O(log size).

use super::light::Light;
use crate::envmap::{EnvMap, Projection};
use crate::mapping::Domain;
use crate::sampling::DomainImage;
use crate::sampling::resample::LatLongView;
use glam::DVec3;
use multiversion::multiversion;
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

/// The lat-long grid that median cut and VMLPS partition: the source itself when it is lat-long,
/// else a lat-long image pulled from the domain square at about its resolution, with each
/// column's and row's trigonometry cached.
#[derive(Default)]
pub(super) struct LatLong {
    view: LatLongView,
    /// Per column (sin φ, cos φ) and per row (sin θ, cos θ, Δω).
    columns: Vec<(f64, f64)>,
    rows: Vec<(f64, f64, f64)>,
}

/// One frame's lat-long grid (see [`LatLong`]).
pub(super) struct LatLongGrid<'a> {
    pub w: usize,
    pub h: usize,
    /// Rows inside the domain: all for the sphere, the upper half (pixel centre above the
    /// horizon) for the hemisphere.
    pub rows: usize,
    pub pixels: &'a [[f32; 3]],
    /// Whether `pixels` is the source map (else an approximation pulled from the domain square,
    /// whose lights are rescaled to the domain's energy, [`rescale_to_domain`]).
    pub from_source: bool,
    columns: &'a [(f64, f64)],
    trig: &'a [(f64, f64, f64)],
}

impl LatLongGrid<'_> {
    /// Solid angle of a pixel of row `j`.
    pub fn row_sr(&self, j: usize) -> f64 {
        self.trig[j].2
    }

    /// The direction of pixel (i, j)'s centre: (sin θ sin φ, cos θ, −sin θ cos φ), DESIGN.md's
    /// lat-long convention.
    pub fn dir(&self, i: usize, j: usize) -> DVec3 {
        let (sp, cp) = self.columns[i];
        let (st, ct, _) = self.trig[j];
        DVec3::new(st * sp, ct, -st * cp)
    }
}

impl LatLong {
    pub(super) fn view<'a>(&'a mut self, map: &'a EnvMap, image: &DomainImage) -> LatLongGrid<'a> {
        let from_source = map.projection == Projection::LatLong;
        let (w, h, pixels): (usize, usize, &[[f32; 3]]) = if from_source {
            (map.width, map.height, &map.pixels)
        } else {
            self.view.pull(image)
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
        LatLongGrid {
            w,
            h,
            rows: match image.domain {
                Domain::Sphere => h,
                Domain::Upper => h.div_ceil(2),
            },
            pixels,
            from_source,
            columns: &self.columns,
            trig: &self.rows,
        }
    }
}

/// Rescales lights made from a pulled lat-long image so that they carry exactly the domain's
/// energy, as every method must.
pub(super) fn rescale_to_domain(lights: &mut [Light], image: &DomainImage) {
    let want = image.integral();
    let got = super::light::total_irradiance(lights);
    for l in lights {
        for c in 0..3 {
            if got[c] > 0.0 {
                l.irradiance[c] = (l.irradiance[c] as f64 * want[c] / got[c]) as f32;
            }
        }
    }
}

/// Reusable buffers for median cut.
#[derive(Default)]
pub struct MedianCut {
    /// Summed-area table of luminance·Δω, (w+1)×(h+1).
    sat: Vec<f64>,
    grid: LatLong,
}

impl MedianCut {
    /// Up to `n` lights by median cut; with `n` not a power of two the last round splits the
    /// most energetic regions first.
    pub fn lights(&mut self, map: &EnvMap, image: &DomainImage, n: usize) -> Vec<Light> {
        let grid = self.grid.view(map, image);
        let mut lights = cut(&grid, &mut self.sat, n);
        if !grid.from_source {
            rescale_to_domain(&mut lights, image);
        }
        lights
    }
}

/// Median cut over `grid` (`sat` its summed-area table's buffer). Compiled twice, the second
/// time for CPUs with AVX2 and FMA (chosen at run time), as the default method's passes are, so
/// that the two are timed on the same instructions.
#[multiversion(targets("x86_64+avx2+fma"))]
fn cut(grid: &LatLongGrid, sat: &mut Vec<f64>, n: usize) -> Vec<Light> {
    let (w, h, rows, pixels) = (grid.w, grid.h, grid.rows, grid.pixels);
    let row_sr: Vec<f64> = (0..h).map(|j| grid.row_sr(j)).collect();

    // Summed-area table of luminance energy.
    sat.clear();
    sat.resize((w + 1) * (rows + 1), 0.0);
    for j in 0..rows {
        let mut row_acc = 0.0;
        for i in 0..w {
            row_acc += EnvMap::luminance(pixels[j * w + i]) as f64 * row_sr[j];
            sat[(j + 1) * (w + 1) + i + 1] = sat[j * (w + 1) + i + 1] + row_acc;
        }
    }
    let sat = &*sat;
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
    let (columns, row_trig) = (grid.columns, grid.trig);
    regions
        .iter()
        .enumerate()
        .map(|(id, r)| {
            let mut rgb = [0.0f64; 3];
            let mut dir = DVec3::ZERO;
            let mut sr = 0.0;
            let mut lum = 0.0;
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
                lum += sy * dw;
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
                angular_radius: super::light::angular_radius(lum, dir.length()),
                extent: None,
                shadowed: None,
            }
        })
        .collect()
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Resampler;

    fn latlong(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> EnvMap {
        let pixels = (0..w * h).map(|k| [f(k % w, k / w); 3]).collect();
        EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap()
    }

    fn lights(map: &EnvMap, n: usize) -> Vec<Light> {
        let image = Resampler::new(map.projection, map.width, map.height, Domain::Sphere, None)
            .resample(map);
        MedianCut::default().lights(map, &image, n)
    }

    /// 2ⁿ regions of equal energy: on a smooth map every light of a 2ᵏ cut carries 1/2ᵏ of the
    /// energy, within one pixel column or row of the cut (the cut lands on a pixel boundary).
    #[test]
    fn cuts_give_two_to_the_n_regions_of_equal_energy() {
        let map = latlong(256, 128, |i, j| {
            1.0 + 0.5 * ((i as f32) * 0.05).sin() + j as f32 * 0.01
        });
        for k in 0..=5 {
            let n = 1usize << k;
            let ls = lights(&map, n);
            assert_eq!(ls.len(), n, "2^{k}");
            let total: f64 = ls.iter().map(|l| l.luminance()).sum();
            for l in &ls {
                let share = l.luminance() / total;
                // One pixel row or column of a region with ≥ 8 pixels a side: under 1/8 off.
                assert!(
                    (share * n as f64 - 1.0).abs() < 0.15,
                    "2^{k}: share {share} vs {}",
                    1.0 / n as f64
                );
            }
        }
    }

    /// The first cut of a uniform sphere goes across the longer side: the lat-long map is 2π wide
    /// at the equator and π tall, so the cut is vertical (along a meridian) and the two lights lie
    /// on opposite sides of it (±X), both on the equator.
    #[test]
    fn the_first_cut_is_across_the_longest_side() {
        let map = latlong(128, 64, |_, _| 1.0);
        let ls = lights(&map, 2);
        assert_eq!(ls.len(), 2);
        for l in &ls {
            let d = l.dir();
            assert!(d.x.abs() > 0.5 && d.y.abs() < 1e-3, "{d:?}");
        }
        assert!(ls[0].dir().x * ls[1].dir().x < 0.0);
        // A region squeezed toward a pole (a thin band) is cut along its width, not its height:
        // a map lit only in the top 8 rows splits into two halves in φ.
        let band = latlong(128, 64, |_, j| if j < 8 { 1.0 } else { 0.0 });
        let ls = lights(&band, 2);
        let (a, b) = (ls[0].dir(), ls[1].dir());
        assert!(a.y > 0.9 && b.y > 0.9, "{a:?} {b:?}");
        assert!(a.x * b.x < 0.0 || a.z * b.z < 0.0, "{a:?} {b:?}");
    }

    /// The split finds the half-energy boundary: for a map whose left quarter holds half the
    /// energy, the first cut is at the quarter.
    #[test]
    fn the_cut_is_at_half_the_energy() {
        let (w, h) = (128, 64);
        let map = latlong(w, h, |i, _| if i < w / 4 { 3.0 } else { 1.0 });
        let ls = lights(&map, 2);
        let total: f64 = ls.iter().map(|l| l.luminance()).sum();
        for l in &ls {
            assert!(
                (l.luminance() / total - 0.5).abs() < 0.02,
                "{}",
                l.luminance() / total
            );
        }
    }
}
