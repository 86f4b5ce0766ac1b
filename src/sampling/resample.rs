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

use crate::envmap::{EnvMap, Projection};
use crate::mapping::Domain;
use glam::{DVec2, Vec3A};
use multiversion::multiversion;

/// Source pixels per domain texel aimed for, where the source is coarsest. Lights take their
/// direction from each texel's first moment, so texels coarser than the source lose almost nothing:
/// on the shared maps the N = 64 diffuse error was the same at 8 as at 4 pixels per texel
/// (0.45–1.6 %), at half the per-frame cost. Eight also leaves no texel without a pixel.
const SOURCE_PIXELS_PER_TEXEL: f64 = 8.0;
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

    /// An image with no texels, to be filled by [`downsample_into`](Self::downsample_into) or a
    /// resampler.
    pub fn empty() -> Self {
        DomainImage {
            domain: Domain::Sphere,
            side: 0,
            radiance: Vec::new(),
            luminance: Vec::new(),
            moment: Vec::new(),
        }
    }

    /// This image at half resolution (the side must be even): each texel the mean radiance of the
    /// 2 × 2 texels it covers (which have equal solid angles, so energy is kept exactly) and the
    /// mean of their first moments (so directions derived from moments are kept too).
    pub fn downsample_into(&self, out: &mut DomainImage) {
        debug_assert!(self.side.is_multiple_of(2));
        let (side, half) = (self.side, self.side / 2);
        out.domain = self.domain;
        out.side = half;
        let mean4 = |a: &[[f32; 3]], t: usize| {
            let (p, q, r, s) = (a[t], a[t + 1], a[t + side], a[t + side + 1]);
            [0, 1, 2].map(|c| 0.25 * (p[c] + q[c] + r[c] + s[c]))
        };
        out.radiance.clear();
        out.moment.clear();
        for j in 0..half {
            for i in 0..half {
                let t = 2 * j * side + 2 * i;
                out.radiance.push(mean4(&self.radiance, t));
                out.moment.push(mean4(&self.moment, t));
            }
        }
        out.luminance.clear();
        out.luminance
            .extend(out.radiance.iter().map(|&p| EnvMap::luminance(p)));
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
/// still receives about `SOURCE_PIXELS_PER_TEXEL` source pixels where the source is coarsest,
/// rounded down to an even number.
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
    // Even, so the voronoi method's Lloyd steps can run on the image at half resolution.
    ((side.floor() as usize) & !1).clamp(MIN_SIDE, MAX_SIDE)
}

/// The precomputed source-pixel → domain-texel table for one (projection, size, domain, side).
///
/// The per-frame pass streams this table and the pixels once, so the table's size is the cost.
/// Lat-long sources get a compact table (see `LatLongTable`); other projections one entry per
/// pixel inside the domain.
///
/// On several threads the square is cut into bands of whole texel rows with about equal pixel
/// counts, and each thread fills one band from the pixels that land in it: the bands are disjoint
/// slices of the output, so the threads need no accumulators of their own and no merge pass (these
/// were a third of the pass's memory traffic at 1024×512).
#[derive(Debug)]
pub struct Resampler {
    pub projection: Projection,
    pub width: usize,
    pub height: usize,
    pub domain: Domain,
    pub side: usize,
    table: Table,
    threads: usize,
}

#[derive(Debug)]
enum Table {
    PerPixel(PixelTable),
    LatLong(LatLongTable),
}

/// Any projection: one entry per source pixel inside the domain, grouped in runs of consecutive
/// pixels (a fisheye's circle is one run per row), directions pre-multiplied by the weight.
#[derive(Debug)]
struct PixelTable {
    /// One entry per source pixel inside the domain, in pixel order.
    entries: Vec<PixelEntry>,
    /// Runs of consecutive pixels with entries: (first pixel, first entry, length): the work of
    /// one thread, and what the bands of several are cut from.
    runs: Vec<(u32, u32, u32)>,
    /// With several threads, per band of texels (one per thread): the runs of consecutive pixels
    /// that land in it. Empty with one thread: `runs` is the one band.
    bands: Vec<Band<Vec<(u32, u32, u32)>>>,
}

/// One thread's share of the pass: the texels `texels` and what to read to fill them.
#[derive(Debug)]
struct Band<W> {
    texels: std::ops::Range<usize>,
    work: W,
}

/// Where one source pixel goes.
#[derive(Clone, Copy, Debug)]
struct PixelEntry {
    /// Texel index it lands in.
    texel: u32,
    /// The pixel's solid angle over the texel's, so texel radiance = Σ weight·L.
    weight: f32,
    /// The pixel's direction times its weight.
    weighted_dir: [f32; 3],
}

/// Lat-long: a pixel's weight depends on its row only and its direction is separable,
/// (sin θ sin φ, cos θ, −sin θ cos φ), and neighbouring pixels of a row mostly fall in the same
/// texel (about 3 at the equator of a map with 8 pixels per texel, hundreds near the poles). So the
/// table holds per-row and per-column factors and, per row, the spans of columns that share a
/// texel: a span's pixels are summed in registers and deposited once. The per-frame pass reads
/// little more than the pixels (the per-pixel table was 20 bytes a pixel, this is about 3).
#[derive(Debug)]
struct LatLongTable {
    /// Per row: (weight w, w·sin θ, w·cos θ), the weight being the pixel's over the texel's solid
    /// angle.
    rows: Vec<[f32; 3]>,
    /// Per column: (sin φ, 1, cos φ), what a pixel's luminance scales into its span's moment
    /// sums (one aligned 16-byte load per pixel).
    cols: Vec<Vec3A>,
    /// Every span: the work of one thread, and what the bands of several are cut from.
    all: SpanList,
    /// With several threads, per band of texels: its spans, the others' pixels merged into
    /// skipped spans. Empty with one thread: `all` is the one band.
    bands: Vec<Band<SpanList>>,
}

/// Spans of one or more rows: row j's are `spans[row_start[j]..row_start[j + 1]]`.
#[derive(Clone, Debug, Default)]
struct SpanList {
    row_start: Vec<u32>,
    /// Consecutive columns landing in one texel, in column order; [`SKIP`] marks pixels outside
    /// the domain (or, in a band, outside the band).
    spans: Vec<Span>,
}

/// The texel of pixels that are not deposited.
const SKIP: u32 = u32::MAX;

#[derive(Clone, Copy, Debug)]
struct Span {
    texel: u32,
    /// One past the span's last column (it starts where the previous span of its row ends).
    end: u32,
}

/// Where the scatter passes deposit: a band of the image's (radiance, moment) arrays, which
/// starts at texel `first`.
struct ImageArrays<'a> {
    radiance: &'a mut [[f32; 3]],
    moment: &'a mut [[f32; 3]],
    first: usize,
}

impl ImageArrays<'_> {
    #[inline(always)]
    fn add(&mut self, texel: usize, radiance: Vec3A, moment: Vec3A) {
        let r = &mut self.radiance[texel - self.first];
        *r = (Vec3A::from_array(*r) + radiance).to_array();
        let m = &mut self.moment[texel - self.first];
        *m = (Vec3A::from_array(*m) + moment).to_array();
    }
}

/// Deposits each pixel of `runs` (in pixel order) that lies in `only` into its texel: radiance ×
/// weight and luminance × weighted direction, in 4-wide f32 registers (energy exact up to f32
/// rounding). Compiled twice, as [`scatter_latlong`].
#[multiversion(targets("x86_64+avx2+fma"))]
fn scatter_pixels(
    runs: &[(u32, u32, u32)],
    entries: &[PixelEntry],
    pixels: &[[f32; 3]],
    only: std::ops::Range<usize>,
    accum: &mut ImageArrays,
) {
    let first = runs.partition_point(|r| (r.0 + r.2) as usize <= only.start);
    for &(first_pixel, first_entry, len) in &runs[first..] {
        let p0 = first_pixel as usize;
        if p0 >= only.end {
            break;
        }
        let (lo, hi) = (p0.max(only.start), (p0 + len as usize).min(only.end));
        let e0 = first_entry as usize + (lo - p0);
        // Neighbouring pixels mostly share a texel (about 3 in a row): their deposits are summed
        // in registers and stored once, which keeps the loop free of a store → load chain.
        let mut texel = SKIP;
        let (mut radiance, mut moment) = (Vec3A::ZERO, Vec3A::ZERO);
        for (e, p) in entries[e0..e0 + (hi - lo)].iter().zip(&pixels[lo..hi]) {
            if e.texel != texel {
                if texel != SKIP {
                    accum.add(texel as usize, radiance, moment);
                }
                (texel, radiance, moment) = (e.texel, Vec3A::ZERO, Vec3A::ZERO);
            }
            let p = Vec3A::from_array(*p);
            radiance += p * e.weight;
            moment += Vec3A::from_array(e.weighted_dir) * p.dot(LUMINANCE);
        }
        if texel != SKIP {
            accum.add(texel as usize, radiance, moment);
        }
    }
}

/// Rec. 709 luminance weights, as [`EnvMap::luminance`].
const LUMINANCE: Vec3A = Vec3A::new(0.2126, 0.7152, 0.0722);

/// The lat-long pass (see `LatLongTable`) over the pixel rows `rows`: per span, Σ L, Σ Y,
/// Σ Y sin φ and Σ Y cos φ in registers, then one deposit scaled by the row's factors. Compiled
/// twice, the second time for CPUs with AVX2 and FMA (chosen at run time): their three-operand
/// forms and broadcasts take about a tenth off the pass.
#[multiversion(targets("x86_64+avx2+fma"))]
fn scatter_latlong(
    t: &LatLongTable,
    list: &SpanList,
    width: usize,
    pixels: &[[f32; 3]],
    rows: std::ops::Range<usize>,
    accum: &mut ImageArrays,
) {
    for j in rows {
        let [w, w_sin_theta, w_cos_theta] = t.rows[j];
        let row = &pixels[j * width..(j + 1) * width];
        let mut col = 0usize;
        let spans = list.row_start[j] as usize..list.row_start[j + 1] as usize;
        for span in &list.spans[spans] {
            let end = span.end as usize;
            if span.texel != SKIP {
                let mut radiance = Vec3A::ZERO;
                // (Σ Y sin φ, Σ Y, Σ Y cos φ)
                let mut moment = Vec3A::ZERO;
                for (p, &phi) in row[col..end].iter().zip(&t.cols[col..end]) {
                    let p = Vec3A::from_array(*p);
                    radiance += p;
                    moment += phi * p.dot(LUMINANCE);
                }
                accum.add(
                    span.texel as usize,
                    radiance * w,
                    moment * Vec3A::new(w_sin_theta, w_cos_theta, -w_sin_theta),
                );
            }
            col = end;
        }
    }
}

impl PixelTable {
    fn new(
        projection: &Projection,
        width: usize,
        height: usize,
        domain: Domain,
        side: usize,
    ) -> Self {
        let texel_sr = domain.solid_angle() / (side * side) as f64;
        let mut entries = Vec::with_capacity(width * height);
        let mut runs: Vec<(u32, u32, u32)> = Vec::new();
        for j in 0..height {
            for i in 0..width {
                let Some((dir, sr)) = projection.pixel(i, j, width, height) else {
                    continue;
                };
                let Some(texel) = texel_of(domain, side, dir) else {
                    continue;
                };
                let pixel = (j * width + i) as u32;
                // Runs end with their row, so that `scatter_pixels`' register sums never join
                // two rows (a frame resampled by rows gets the same sums).
                match runs.last_mut() {
                    Some(run) if run.0 + run.2 == pixel && i > 0 => run.2 += 1,
                    _ => runs.push((pixel, entries.len() as u32, 1)),
                }
                entries.push(PixelEntry {
                    texel,
                    weight: (sr / texel_sr) as f32,
                    weighted_dir: (dir.as_vec3() * (sr / texel_sr) as f32).to_array(),
                });
            }
        }
        PixelTable {
            entries,
            runs,
            bands: Vec::new(),
        }
    }

    /// Re-cuts the runs into `parts` bands of about equal pixel counts.
    fn set_bands(&mut self, side: usize, parts: usize) {
        if parts <= 1 {
            self.bands.clear();
            return;
        }
        let mut per_texel = vec![0usize; side * side];
        for e in &self.entries {
            per_texel[e.texel as usize] += 1;
        }
        self.bands = band_ranges(&per_texel, side, parts)
            .into_iter()
            .map(|texels| {
                let mut runs: Vec<(u32, u32, u32)> = Vec::new();
                for &(p0, e0, len) in &self.runs {
                    let first_run = runs.len();
                    for k in 0..len {
                        let texel = self.entries[(e0 + k) as usize].texel as usize;
                        if !texels.contains(&texel) {
                            continue;
                        }
                        let (pixel, entry) = (p0 + k, e0 + k);
                        let joins = runs.len() > first_run;
                        match runs.last_mut() {
                            Some(run)
                                if joins && run.0 + run.2 == pixel && run.1 + run.2 == entry =>
                            {
                                run.2 += 1
                            }
                            _ => runs.push((pixel, entry, 1)),
                        }
                    }
                }
                Band { texels, work: runs }
            })
            .collect();
    }
}

impl LatLongTable {
    fn new(width: usize, height: usize, domain: Domain, side: usize) -> Self {
        let texel_sr = domain.solid_angle() / (side * side) as f64;
        let mut rows = Vec::with_capacity(height);
        let mut all = SpanList {
            row_start: vec![0],
            spans: Vec::new(),
        };
        for j in 0..height {
            let (dir, sr) = Projection::LatLong
                .pixel(0, j, width, height)
                .expect("lat-long");
            let w = sr / texel_sr;
            let sin_theta = DVec2::new(dir.x, dir.z).length();
            rows.push([w as f32, (w * sin_theta) as f32, (w * dir.y) as f32]);
            let row_first = all.spans.len();
            for i in 0..width {
                let (dir, _) = Projection::LatLong
                    .pixel(i, j, width, height)
                    .expect("lat-long");
                let texel = texel_of(domain, side, dir).unwrap_or(SKIP);
                let in_row = all.spans.len() > row_first;
                match all.spans.last_mut() {
                    Some(s) if in_row && s.texel == texel => s.end += 1,
                    _ => all.spans.push(Span {
                        texel,
                        end: i as u32 + 1,
                    }),
                }
            }
            all.row_start.push(all.spans.len() as u32);
        }
        let cols = (0..width)
            .map(|i| {
                let phi = 2.0 * std::f64::consts::PI * ((i as f64 + 0.5) / width as f64 - 0.5);
                Vec3A::new(phi.sin() as f32, 1.0, phi.cos() as f32)
            })
            .collect();
        LatLongTable {
            rows,
            cols,
            all,
            bands: Vec::new(),
        }
    }

    /// Re-cuts the spans into `parts` bands of about equal pixel counts.
    fn set_bands(&mut self, side: usize, parts: usize) {
        if parts <= 1 {
            self.bands.clear();
            return;
        }
        let mut per_texel = vec![0usize; side * side];
        for row in self.all.row_start.windows(2) {
            let mut col = 0;
            for s in &self.all.spans[row[0] as usize..row[1] as usize] {
                if s.texel != SKIP {
                    per_texel[s.texel as usize] += (s.end - col) as usize;
                }
                col = s.end;
            }
        }
        self.bands = band_ranges(&per_texel, side, parts)
            .into_iter()
            .map(|texels| {
                let mut list = SpanList {
                    row_start: vec![0],
                    spans: Vec::new(),
                };
                for row in self.all.row_start.windows(2) {
                    let row_first = list.spans.len();
                    for s in &self.all.spans[row[0] as usize..row[1] as usize] {
                        let texel = if texels.contains(&(s.texel as usize)) {
                            s.texel
                        } else {
                            SKIP
                        };
                        let in_row = list.spans.len() > row_first;
                        match list.spans.last_mut() {
                            Some(last) if in_row && last.texel == SKIP && texel == SKIP => {
                                last.end = s.end
                            }
                            _ => list.spans.push(Span { texel, end: s.end }),
                        }
                    }
                    list.row_start.push(list.spans.len() as u32);
                }
                Band { texels, work: list }
            })
            .collect();
    }
}

/// The texel of the domain square a direction falls in, if inside the domain.
fn texel_of(domain: Domain, side: usize, dir: glam::DVec3) -> Option<u32> {
    let uv = domain.dir_to_square(dir)?;
    let ti = ((uv.x * side as f64) as usize).min(side - 1);
    let tj = ((uv.y * side as f64) as usize).min(side - 1);
    Some((tj * side + ti) as u32)
}

/// The bands' texels; with no bands (one thread), one band of all `n`.
fn texel_ranges<W>(bands: &[Band<W>], n: usize) -> Vec<std::ops::Range<usize>> {
    if bands.is_empty() {
        return std::iter::once(0..n).collect();
    }
    bands.iter().map(|b| b.texels.clone()).collect()
}

/// One band's share of a [`DomainImage`]: its first texel and its radiance, moment and
/// luminance slices.
struct BandSlice<'a>(usize, &'a mut [[f32; 3]], &'a mut [[f32; 3]], &'a mut [f32]);

/// Splits `out`'s arrays into the bands' slices (sorted, disjoint `ranges`); texels outside
/// every band (rows no pixel reaches) are zeroed here.
fn band_slices<'a>(
    out: &'a mut DomainImage,
    ranges: &[std::ops::Range<usize>],
) -> Vec<BandSlice<'a>> {
    let (mut r, mut m, mut y) = (
        &mut out.radiance[..],
        &mut out.moment[..],
        &mut out.luminance[..],
    );
    let mut offset = 0;
    let mut slices = Vec::with_capacity(ranges.len());
    for range in ranges {
        let gap = range.start - offset;
        r[..gap].fill([0.0; 3]);
        m[..gap].fill([0.0; 3]);
        y[..gap].fill(0.0);
        let (r0, r1) = std::mem::take(&mut r)[gap..].split_at_mut(range.len());
        let (m0, m1) = std::mem::take(&mut m)[gap..].split_at_mut(range.len());
        let (y0, y1) = std::mem::take(&mut y)[gap..].split_at_mut(range.len());
        slices.push(BandSlice(range.start, r0, m0, y0));
        (r, m, y) = (r1, m1, y1);
        offset = range.end;
    }
    r.fill([0.0; 3]);
    m.fill([0.0; 3]);
    y.fill(0.0);
    slices
}

/// Cuts the square into at most `parts` bands of whole texel rows with about equal pixel counts
/// (`per_texel`); empty bands are left out.
fn band_ranges(per_texel: &[usize], side: usize, parts: usize) -> Vec<std::ops::Range<usize>> {
    let row_cost = |r: usize| per_texel[r * side..(r + 1) * side].iter().sum::<usize>();
    let total: usize = (0..side).map(row_cost).sum();
    let per = total.div_ceil(parts.max(1)).max(1);
    let mut bounds = vec![0];
    let mut acc = 0;
    for r in 0..side {
        if acc >= per * bounds.len() && bounds.len() < parts {
            bounds.push(r);
        }
        acc += row_cost(r);
    }
    bounds.push(side);
    bounds
        .windows(2)
        .filter(|b| b[1] > b[0])
        .map(|b| b[0] * side..b[1] * side)
        .collect()
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
        let table = match projection {
            Projection::LatLong => Table::LatLong(LatLongTable::new(width, height, domain, side)),
            _ => Table::PerPixel(PixelTable::new(&projection, width, height, domain, side)),
        };
        Resampler {
            projection,
            width,
            height,
            domain,
            side,
            table,
            threads: 1,
        }
    }

    /// The same resampling through the per-pixel table whatever the projection (to check the
    /// lat-long table against).
    #[cfg(test)]
    fn new_per_pixel(projection: Projection, width: usize, height: usize, domain: Domain) -> Self {
        let mut r = Self::new(projection, width, height, domain, None);
        r.table = Table::PerPixel(PixelTable::new(&projection, width, height, domain, r.side));
        r
    }

    /// The table in `cached` if it fits `map`, else a new one, on `threads` threads, put there: a
    /// stream of same-sized frames builds its table once.
    pub fn reuse<'a>(
        cached: &'a mut Option<Resampler>,
        map: &EnvMap,
        domain: Domain,
        side: Option<usize>,
        threads: usize,
    ) -> &'a mut Resampler {
        if !cached.as_ref().is_some_and(|r| r.fits(map, domain, side)) {
            let mut r = Resampler::new(map.projection, map.width, map.height, domain, side);
            r.set_threads(threads);
            return cached.insert(r);
        }
        cached.as_mut().expect("fits")
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
    pub fn resample_into(&mut self, map: &EnvMap, out: &mut DomainImage) {
        assert_eq!(
            map.pixels.len(),
            self.width * self.height,
            "map does not fit the table"
        );
        let n = self.side * self.side;
        let (width, pixels) = (self.width, &map.pixels[..]);
        out.domain = self.domain;
        out.side = self.side;
        out.radiance.resize(n, [0.0; 3]);
        out.moment.resize(n, [0.0; 3]);
        out.luminance.resize(n, 0.0);
        let table = &self.table;
        let ranges = match table {
            Table::PerPixel(t) => texel_ranges(&t.bands, n),
            Table::LatLong(t) => texel_ranges(&t.bands, n),
        };
        // Each band zeroes and fills its own slice of the image, in its own thread.
        let fill = |band: usize, slice: BandSlice| {
            let BandSlice(first, radiance, moment, luminance) = slice;
            radiance.fill([0.0; 3]);
            moment.fill([0.0; 3]);
            let mut arrays = ImageArrays {
                radiance,
                moment,
                first,
            };
            match table {
                Table::PerPixel(t) => scatter_pixels(
                    t.bands.get(band).map_or(&t.runs, |b| &b.work),
                    &t.entries,
                    pixels,
                    0..pixels.len(),
                    &mut arrays,
                ),
                Table::LatLong(t) => scatter_latlong(
                    t,
                    t.bands.get(band).map_or(&t.all, |b| &b.work),
                    width,
                    pixels,
                    0..t.rows.len(),
                    &mut arrays,
                ),
            }
            for (y, r) in luminance.iter_mut().zip(arrays.radiance.iter()) {
                *y = EnvMap::luminance(*r);
            }
        };
        let mut slices = band_slices(out, &ranges).into_iter();
        let Some(first) = slices.next() else {
            return;
        };
        std::thread::scope(|scope| {
            for (band, slice) in slices.enumerate() {
                let fill = &fill;
                scope.spawn(move || fill(band + 1, slice));
            }
            fill(0, first);
        });
    }

    /// Starts resampling a frame that arrives a few rows at a time (a camera pipe), so that when
    /// its last row arrives only that row's share is left: zeroes `out`; then call
    /// [`add_rows`](Self::add_rows) for each batch of rows as it lands in the map and
    /// [`finish_rows`](Self::finish_rows) after the last. The image is bit-identical to
    /// [`resample_into`](Self::resample_into)'s on any thread count: every texel receives the same
    /// deposits in the same (pixel) order.
    pub fn begin_rows(&self, out: &mut DomainImage) {
        let n = self.side * self.side;
        out.domain = self.domain;
        out.side = self.side;
        for v in [&mut out.radiance, &mut out.moment] {
            v.clear();
            v.resize(n, [0.0; 3]);
        }
        out.luminance.resize(n, 0.0);
    }

    /// Deposits the map's pixel rows `rows` into `out` (on this thread, from the table's full
    /// list); the other rows of the map are not read.
    pub fn add_rows(&self, map: &EnvMap, rows: std::ops::Range<usize>, out: &mut DomainImage) {
        assert!(
            map.pixels.len() == self.width * self.height && rows.end <= self.height,
            "map does not fit the table"
        );
        let mut arrays = ImageArrays {
            radiance: &mut out.radiance,
            moment: &mut out.moment,
            first: 0,
        };
        match &self.table {
            Table::PerPixel(t) => {
                let pixels = rows.start * self.width..rows.end * self.width;
                scatter_pixels(&t.runs, &t.entries, &map.pixels, pixels, &mut arrays)
            }
            Table::LatLong(t) => {
                scatter_latlong(t, &t.all, self.width, &map.pixels, rows, &mut arrays)
            }
        }
    }

    /// Completes a frame resampled by rows: the luminance channel.
    pub fn finish_rows(&self, out: &mut DomainImage) {
        for (y, r) in out.luminance.iter_mut().zip(&out.radiance) {
            *y = EnvMap::luminance(*r);
        }
    }

    /// Threads used by [`resample_into`](Self::resample_into) (1 by default): the square is cut
    /// into that many bands.
    pub fn set_threads(&mut self, threads: usize) {
        let threads = threads.clamp(1, 8);
        if threads == self.threads {
            return;
        }
        self.threads = threads;
        match &mut self.table {
            Table::PerPixel(t) => t.set_bands(self.side, threads),
            Table::LatLong(t) => t.set_bands(self.side, threads),
        }
    }

    /// Resamples into a new image.
    pub fn resample(&mut self, map: &EnvMap) -> DomainImage {
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

/// A lat-long view (2S × S pixels) of a domain square, for the methods defined on lat-long maps
/// (median cut, the inverse-CDF baseline) when the source is not lat-long: each lat-long pixel reads
/// the texel its centre falls in, 0 outside the domain. The lookup table is kept per (domain, S).
#[derive(Default)]
pub struct LatLongView {
    key: Option<(Domain, usize)>,
    table: Vec<u32>,
    pixels: Vec<[f32; 3]>,
}

impl LatLongView {
    /// (width, height, pixels) of the view of `image`.
    pub fn pull(&mut self, image: &DomainImage) -> (usize, usize, &[[f32; 3]]) {
        let (domain, h) = (image.domain, image.side);
        let w = 2 * h;
        if self.key != Some((domain, h)) {
            self.table.clear();
            for j in 0..h {
                for i in 0..w {
                    let (dir, _) = Projection::LatLong.pixel(i, j, w, h).expect("lat-long");
                    self.table
                        .push(texel_of(domain, h, dir).unwrap_or(u32::MAX));
                }
            }
            self.key = Some((domain, h));
        }
        self.pixels.clear();
        self.pixels.extend(self.table.iter().map(|&t| {
            if t == u32::MAX {
                [0.0; 3]
            } else {
                image.radiance[t as usize]
            }
        }));
        (w, h, &self.pixels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Texel by texel, radiance and moment of `b` within `tol` (relative, absolute below 1) of `a`.
    fn assert_close(a: &DomainImage, b: &DomainImage, tol: f32, what: &str) {
        assert_eq!(a.side, b.side, "{what}");
        for (x, y) in a
            .radiance
            .iter()
            .zip(&b.radiance)
            .chain(a.moment.iter().zip(&b.moment))
        {
            for c in 0..3 {
                assert!(
                    (x[c] - y[c]).abs() <= tol * x[c].abs().max(1.0),
                    "{what}: {x:?} vs {y:?}"
                );
            }
        }
    }

    /// A 180° equidistant fisheye, centred.
    fn fisheye_180() -> Projection {
        Projection::Fisheye {
            lens: crate::envmap::Lens::Equidistant,
            fov_deg: 180.0,
            centre: None,
            radius: None,
        }
    }

    /// A w×h map whose channels vary with the pixel at different periods and down the rows.
    fn patterned_map(w: usize, h: usize, projection: Projection) -> EnvMap {
        let pixels = (0..w * h)
            .map(|k| [(k % 13) as f32, 1.0 + (k % 5) as f32, (k / w) as f32 * 0.1])
            .collect();
        EnvMap::from_pixels(w, h, pixels, projection).unwrap()
    }

    #[test]
    fn threads_give_the_same_image() {
        let map = EnvMap::from_pixels(
            128,
            64,
            (0..128 * 64)
                .map(|k| [k as f32 * 0.01, 1.0, (k % 7) as f32])
                .collect(),
            Projection::LatLong,
        )
        .unwrap();
        let mut one = Resampler::new(Projection::LatLong, 128, 64, Domain::Sphere, None);
        let a = one.resample(&map);
        for threads in [2, 3] {
            let mut r = Resampler::new(Projection::LatLong, 128, 64, Domain::Sphere, None);
            r.set_threads(threads);
            let b = r.resample(&map);
            assert_close(&a, &b, 1e-5, &format!("{threads} threads"));
        }
    }

    /// Bands cut from the per-pixel table (any projection but lat-long) fill the same image.
    #[test]
    fn bands_of_the_per_pixel_table_give_the_same_image() {
        let (w, h) = (96, 80);
        let projection = fisheye_180();
        let map = patterned_map(w, h, projection);
        let a = Resampler::new(projection, w, h, Domain::Upper, None).resample(&map);
        for threads in [2, 3, 5, 1] {
            let mut r = Resampler::new(projection, w, h, Domain::Upper, None);
            r.set_threads(3);
            r.set_threads(threads);
            let b = r.resample(&map);
            assert_close(&a, &b, 1e-5, &format!("{threads} threads"));
            assert_eq!(a.luminance, b.luminance);
        }
    }

    /// Resampling by rows, in uneven batches, gives exactly the image of the whole-frame pass
    /// (same deposits in the same order), for the per-pixel and the lat-long table.
    #[test]
    fn resampling_by_rows_matches_the_whole_frame_pass() {
        for (projection, domain, w, h) in [
            (fisheye_180(), Domain::Upper, 96, 80),
            (Projection::LatLong, Domain::Sphere, 160, 80),
            (Projection::LatLong, Domain::Upper, 160, 80),
        ] {
            let map = patterned_map(w, h, projection);
            for threads in [1, 3] {
                let mut r = Resampler::new(projection, w, h, domain, None);
                r.set_threads(threads);
                let whole = r.resample(&map);
                // Start from a dirty image: begin_rows must clear it.
                let mut by_rows = whole.clone();
                by_rows.radiance.iter_mut().for_each(|p| *p = [9.0; 3]);
                r.begin_rows(&mut by_rows);
                let mut row = 0;
                for batch in [1, 7, 16, 3, 40, 13].iter().cycle() {
                    if row == h {
                        break;
                    }
                    let end = (row + batch).min(h);
                    r.add_rows(&map, row..end, &mut by_rows);
                    row = end;
                }
                r.finish_rows(&mut by_rows);
                let what = format!("{projection:?} {domain:?} {threads} threads");
                assert_eq!(whole.radiance, by_rows.radiance, "{what}");
                assert_eq!(whole.moment, by_rows.moment, "{what}");
                assert_eq!(whole.luminance, by_rows.luminance, "{what}");
                assert!(whole.integral()[1] > 0.0, "{what}");
            }
        }
    }

    /// Half resolution keeps the integral and the summed first moment (up to the 4× weight).
    #[test]
    fn downsampling_keeps_energy_and_moments() {
        let map = EnvMap::from_pixels(
            256,
            128,
            (0..256 * 128)
                .map(|k| [(k % 11) as f32, (k % 3) as f32, 0.5])
                .collect(),
            Projection::LatLong,
        )
        .unwrap();
        let img =
            Resampler::new(Projection::LatLong, 256, 128, Domain::Sphere, Some(64)).resample(&map);
        let mut half = DomainImage::empty();
        img.downsample_into(&mut half);
        assert_eq!(half.side * 2, img.side);
        for c in 0..3 {
            let (a, b) = (img.integral()[c], half.integral()[c]);
            assert!((a - b).abs() <= 1e-5 * a.abs(), "channel {c}: {a} vs {b}");
            let m = |im: &DomainImage| im.moment.iter().map(|m| m[c] as f64).sum::<f64>();
            let (ma, mb) = (m(&img), 4.0 * m(&half));
            assert!(
                (ma - mb).abs() <= 1e-4 * ma.abs().max(1.0),
                "moment {c}: {ma} vs {mb}"
            );
        }
    }

    /// The lat-long span table gives the per-pixel table's image (f32 summation order aside).
    #[test]
    fn latlong_table_matches_per_pixel_table() {
        let (w, h) = (256, 128);
        let map = EnvMap::from_pixels(
            w,
            h,
            (0..w * h)
                .map(|k| [(k % 13) as f32, 1.0 + (k % 5) as f32, (k / w) as f32 * 0.1])
                .collect(),
            Projection::LatLong,
        )
        .unwrap();
        for domain in [Domain::Upper, Domain::Sphere] {
            let a = Resampler::new_per_pixel(Projection::LatLong, w, h, domain).resample(&map);
            let mut fast = Resampler::new(Projection::LatLong, w, h, domain, None);
            assert!(matches!(fast.table, Table::LatLong(_)));
            for threads in [1, 2, 3] {
                fast.set_threads(threads);
                let b = fast.resample(&map);
                assert_close(&a, &b, 1e-4, &format!("{domain:?} {threads} threads"));
            }
        }
    }

    #[test]
    fn constant_latlong_fills_every_texel_evenly() {
        let (w, h) = (256, 128);
        let map = EnvMap::from_pixels(w, h, vec![[1.0; 3]; w * h], Projection::LatLong).unwrap();
        for domain in [Domain::Upper, Domain::Sphere] {
            let mut r = Resampler::new(Projection::LatLong, w, h, domain, None);
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
