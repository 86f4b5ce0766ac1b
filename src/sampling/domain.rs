//! Resampling an [`EnvMap`] into the equal-area domain square.
//!
//! Input: an environment map in any projection. Output: a [`DomainImage`], an S×S grid over the
//! domain's unit square in which every texel covers the same solid angle (Ω/S²), holding radiance.
//!
//! Filtering is area-correct by construction: each source pixel's energy L·Δω is deposited into the
//! domain texel its direction falls in, so ∫L dω of the square equals the input's up to float
//! rounding. The resolution is chosen so that every domain texel receives several source pixels
//! (no holes), and the pixel → texel table is computed once per (projection, size, domain) and reused
//! every frame: the per-frame cost is one pass of gathers-by-scatter over the source pixels.

use super::mapping::Domain;
use crate::envmap::{EnvMap, Projection};
use glam::{DVec2, Vec3};

/// Source pixels per domain texel aimed for, at the coarsest part of the source (see module doc).
const SOURCE_PIXELS_PER_TEXEL: f64 = 4.0;
/// Bounds on the automatic square side.
const MIN_SIDE: usize = 16;
const MAX_SIDE: usize = 512;

/// The domain square: S×S texels of equal solid angle, radiance in linear RGB.
#[derive(Clone, Debug)]
pub struct DomainImage {
    pub domain: Domain,
    pub side: usize,
    /// Radiance per texel, row-major, row 0 at v = 0.
    pub radiance: Vec<[f32; 3]>,
    /// Luminance per texel (the sampling density).
    pub luminance: Vec<f32>,
    /// Σ luminance·direction over the source pixels that fell in each texel (weighted like the
    /// radiance): the first moment, so a light can be centred on a sub-texel source like the sun
    /// instead of on texel centres.
    pub moment: Vec<[f32; 3]>,
}

impl DomainImage {
    /// Solid angle of one texel, Ω/S².
    pub fn texel_solid_angle(&self) -> f64 {
        self.domain.solid_angle() / (self.side * self.side) as f64
    }

    /// ∫ L dω over the domain, per channel.
    pub fn integral(&self) -> [f64; 3] {
        let mut s = [0.0f64; 3];
        for p in &self.radiance {
            for c in 0..3 {
                s[c] += p[c] as f64;
            }
        }
        s.map(|v| v * self.texel_solid_angle())
    }

    /// The centre of texel (i, j) in the unit square.
    pub fn texel_centre(side: usize, i: usize, j: usize) -> DVec2 {
        DVec2::new(
            (i as f64 + 0.5) / side as f64,
            (j as f64 + 0.5) / side as f64,
        )
    }

    /// A domain image from a closure giving radiance per direction, sampled at texel centres
    /// (used for synthetic skies and tests).
    pub fn from_fn(domain: Domain, side: usize, f: impl Fn(glam::DVec3) -> [f32; 3]) -> Self {
        let mut radiance = Vec::with_capacity(side * side);
        for j in 0..side {
            for i in 0..side {
                radiance.push(f(domain.square_to_dir(Self::texel_centre(side, i, j))));
            }
        }
        let luminance: Vec<f32> = radiance.iter().map(|&p| EnvMap::luminance(p)).collect();
        let moment = (0..side * side)
            .map(|t| {
                let d = domain.square_to_dir(Self::texel_centre(side, t % side, t / side));
                (d.as_vec3() * luminance[t]).to_array()
            })
            .collect();
        DomainImage {
            domain,
            side,
            radiance,
            luminance,
            moment,
        }
    }
}

/// The side of the domain square for a source of this size: as fine as possible while every texel
/// still receives about [`SOURCE_PIXELS_PER_TEXEL`] source pixels where the source is coarsest.
pub fn auto_side(projection: &Projection, width: usize, height: usize, domain: Domain) -> usize {
    // The largest pixel solid angle: scan a cross through the image (lat-long: the equator row;
    // fisheye: the row through the circle's centre holds the extremes of a radial profile).
    let mut largest: f64 = 0.0;
    let (mid_i, mid_j) = (width / 2, height / 2);
    for i in 0..width {
        if let Some((_, sr)) = projection.pixel(i, mid_j, width, height) {
            largest = largest.max(sr);
        }
    }
    for j in 0..height {
        if let Some((_, sr)) = projection.pixel(mid_i, j, width, height) {
            largest = largest.max(sr);
        }
    }
    if largest <= 0.0 {
        return MIN_SIDE;
    }
    let side = (domain.solid_angle() / (SOURCE_PIXELS_PER_TEXEL * largest)).sqrt();
    (side.floor() as usize).clamp(MIN_SIDE, MAX_SIDE)
}

/// The precomputed source-pixel → domain-texel table for one (projection, size, domain, side).
#[derive(Clone, Debug)]
pub struct Resampler {
    pub projection: Projection,
    pub width: usize,
    pub height: usize,
    pub domain: Domain,
    pub side: usize,
    /// One entry per source pixel.
    table: Vec<PixelEntry>,
}

/// Where one source pixel goes.
#[derive(Clone, Copy, Debug)]
struct PixelEntry {
    /// Texel index it lands in; `u32::MAX` = outside the domain.
    texel: u32,
    /// The pixel's solid angle over the texel's, so texel radiance = Σ weight·L.
    weight: f32,
    /// The pixel's direction.
    dir: [f32; 3],
}

impl Resampler {
    /// Builds the table; `side = None` picks [`auto_side`].
    pub fn new(
        projection: Projection,
        width: usize,
        height: usize,
        domain: Domain,
        side: Option<usize>,
    ) -> Self {
        let side = side.unwrap_or_else(|| auto_side(&projection, width, height, domain));
        let texel_sr = domain.solid_angle() / (side * side) as f64;
        let mut table = Vec::with_capacity(width * height);
        for j in 0..height {
            for i in 0..width {
                let entry = projection
                    .pixel(i, j, width, height)
                    .and_then(|(dir, sr)| {
                        let uv = domain.dir_to_square(dir)?;
                        let ti = ((uv.x * side as f64) as usize).min(side - 1);
                        let tj = ((uv.y * side as f64) as usize).min(side - 1);
                        Some(PixelEntry {
                            texel: (tj * side + ti) as u32,
                            weight: (sr / texel_sr) as f32,
                            dir: dir.as_vec3().to_array(),
                        })
                    })
                    .unwrap_or(PixelEntry {
                        texel: u32::MAX,
                        weight: 0.0,
                        dir: [0.0; 3],
                    });
                table.push(entry);
            }
        }
        Resampler {
            projection,
            width,
            height,
            domain,
            side,
            table,
        }
    }

    /// Whether this table fits a map (same projection and size).
    pub fn fits(&self, map: &EnvMap, domain: Domain, side: Option<usize>) -> bool {
        self.projection == map.projection
            && self.width == map.width
            && self.height == map.height
            && self.domain == domain
            && side.is_none_or(|s| s == self.side)
    }

    /// Resamples `map` into `out`, reusing its buffers.
    pub fn resample_into(&self, map: &EnvMap, out: &mut DomainImage) {
        debug_assert_eq!(map.pixels.len(), self.table.len());
        let n = self.side * self.side;
        out.domain = self.domain;
        out.side = self.side;
        out.radiance.clear();
        out.radiance.resize(n, [0.0; 3]);
        out.moment.clear();
        out.moment.resize(n, [0.0; 3]);
        // Accumulate in f32 (a Vec3 multiply-add per pixel): energy is exact up to f32 rounding.
        for (e, p) in self.table.iter().zip(&map.pixels) {
            if e.texel != u32::MAX {
                let t = e.texel as usize;
                let l = Vec3::from_array(*p) * e.weight;
                out.radiance[t] = (Vec3::from_array(out.radiance[t]) + l).to_array();
                let y = EnvMap::luminance(l.to_array());
                out.moment[t] =
                    (Vec3::from_array(out.moment[t]) + Vec3::from_array(e.dir) * y).to_array();
            }
        }
        out.luminance.clear();
        out.luminance
            .extend(out.radiance.iter().map(|&p| EnvMap::luminance(p)));
    }

    /// Resamples into a new image.
    pub fn resample(&self, map: &EnvMap) -> DomainImage {
        let mut out = DomainImage {
            domain: self.domain,
            side: self.side,
            radiance: Vec::new(),
            luminance: Vec::new(),
            moment: Vec::new(),
        };
        self.resample_into(map, &mut out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn constant_latlong_fills_every_texel_evenly() {
        let (w, h) = (256, 128);
        let map = EnvMap::from_pixels(w, h, vec![[1.0; 3]; w * h], Projection::LatLong).unwrap();
        for domain in [Domain::Upper, Domain::Sphere] {
            let r = Resampler::new(Projection::LatLong, w, h, domain, None);
            let img = r.resample(&map);
            let total = img.integral()[0];
            assert!(
                (total / domain.solid_angle() - 1.0).abs() < 2e-3,
                "{domain:?}: {total}"
            );
            // No holes: a constant map stays roughly constant texel by texel (box-filter noise).
            let worst = img
                .radiance
                .iter()
                .map(|p| (p[0] - 1.0).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 0.6, "{domain:?}: texel off by {worst}");
        }
        assert!((map.integral(Domain::Sphere)[0] - 4.0 * PI).abs() < 1e-9);
    }
}
