//! Environment maps: decoding HDR images and the projections that say where each pixel looks.
//!
//! Input: the bytes of an OpenEXR or Radiance HDR file (or raw frames from a capture source).
//! Output: an [`EnvMap`] — linear RGB f32 pixels with a [`Projection`], every pixel finite and
//! non-negative (bad pixels are clamped to 0 and counted, DESIGN.md). This is the first stage of the
//! DESIGN.md pipeline; `sampling::resample` resamples it into the equal-area square.

use glam::DVec3;
use std::f64::consts::PI;
use std::io::Cursor;

/// Default refusal threshold for decoded images: 64 Mpixel (≈ 800 MB as RGB f32).
pub const DEFAULT_MAX_PIXELS: u64 = 64 * 1024 * 1024;

/// What went wrong reading an environment map. Each variant is a distinct, user-facing cause.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("not an OpenEXR or Radiance HDR file (magic bytes {0})")]
    UnsupportedFormat(String),
    #[error("image of {width}×{height} pixels exceeds the limit of {limit} pixels")]
    TooLarge { width: u64, height: u64, limit: u64 },
    #[error("cannot decode {format} image: {reason}")]
    Corrupt {
        format: &'static str,
        reason: String,
    },
    #[error("{0}")]
    Unusable(String),
}

/// The lens model of a fisheye (angular) image. DESIGN.md "Fisheye".
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lens {
    /// r = θ / θ_max.
    Equidistant,
    /// r = sin(θ/2) / sin(θ_max/2).
    Equisolid,
}

/// Where each pixel of an image looks, in the world frame of DESIGN.md (+Y up, −Z forward).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Equirectangular 2:1, top row = zenith, image centre = −Z on the horizon.
    LatLong,
    /// A camera at the origin looking up: image centre = +Y, image top = −Z, image right = +X.
    Fisheye {
        lens: Lens,
        /// Full field of view in degrees (e.g. 180, 185).
        fov_deg: f64,
        /// Image circle centre in pixels; `None` = the image centre.
        centre: Option<(f64, f64)>,
        /// Image circle radius in pixels; `None` = half the shorter side.
        radius: Option<f64>,
    },
    /// An already-resampled HDS03 hemisphere square (mapping, `Domain::Upper`).
    HemisphereSquare,
}

impl Projection {
    /// The name used on the command line and in documents.
    pub fn name(&self) -> &'static str {
        match self {
            Projection::LatLong => "latlong",
            Projection::Fisheye {
                lens: Lens::Equidistant,
                ..
            } => "fisheye-equidistant",
            Projection::Fisheye {
                lens: Lens::Equisolid,
                ..
            } => "fisheye-equisolid",
            Projection::HemisphereSquare => "hemisphere-square",
        }
    }

    /// Parses a projection name; fisheye parameters take their defaults (180°, centred circle).
    pub fn parse(name: &str) -> Result<Self, String> {
        let fisheye = |lens| Projection::Fisheye {
            lens,
            fov_deg: 180.0,
            centre: None,
            radius: None,
        };
        match name {
            "latlong" | "equirect" | "equirectangular" => Ok(Projection::LatLong),
            "fisheye" | "fisheye-equidistant" | "angular" => Ok(fisheye(Lens::Equidistant)),
            "fisheye-equisolid" => Ok(fisheye(Lens::Equisolid)),
            "hemisphere-square" | "hds03" => Ok(Projection::HemisphereSquare),
            _ => Err(format!(
                "unknown projection '{name}' (expected latlong, fisheye-equidistant, \
                 fisheye-equisolid or hemisphere-square)"
            )),
        }
    }

    /// The projection assumed when none is given: lat-long for 2:1 images, fisheye otherwise.
    pub fn guess(width: usize, height: usize) -> Self {
        if width == 2 * height {
            Projection::LatLong
        } else {
            Projection::parse("fisheye").expect("known name")
        }
    }

    /// Checks that an image of this size can carry this projection.
    pub fn check_size(&self, width: usize, height: usize) -> Result<(), InputError> {
        if width == 0 || height == 0 {
            return Err(InputError::Unusable("the image is empty".into()));
        }
        match self {
            Projection::LatLong if width != 2 * height => Err(InputError::Unusable(format!(
                "a lat-long map must be 2:1, this one is {width}×{height}"
            ))),
            Projection::HemisphereSquare if width != height => Err(InputError::Unusable(format!(
                "a hemisphere square must be square, this one is {width}×{height}"
            ))),
            Projection::Fisheye {
                fov_deg, radius, ..
            } => {
                if !(fov_deg.is_finite() && *fov_deg > 0.0 && *fov_deg <= 360.0) {
                    return Err(InputError::Unusable(format!(
                        "fisheye field of view {fov_deg}° is outside (0, 360]"
                    )));
                }
                if let Some(r) = radius
                    && !(r.is_finite() && *r >= 1.0)
                {
                    return Err(InputError::Unusable(format!(
                        "fisheye image circle radius {r} px is not ≥ 1"
                    )));
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// World direction and solid angle (sr) seen by pixel (i, j) of a `width`×`height` image, or
    /// `None` for a pixel outside the image circle of a fisheye.
    pub fn pixel(&self, i: usize, j: usize, width: usize, height: usize) -> Option<(DVec3, f64)> {
        let (w, h) = (width as f64, height as f64);
        match *self {
            Projection::LatLong => {
                // θ = π·v from +Y, φ = 2π(u − ½); the pixel is a band of latitude, so its solid
                // angle is exact: Δφ·(cos θ₀ − cos θ₁).
                let u = (i as f64 + 0.5) / w;
                let v = (j as f64 + 0.5) / h;
                let theta = PI * v;
                let phi = 2.0 * PI * (u - 0.5);
                let (st, ct) = theta.sin_cos();
                let (sp, cp) = phi.sin_cos();
                let dir = DVec3::new(st * sp, ct, -st * cp);
                let t0 = PI * j as f64 / h;
                let t1 = PI * (j + 1) as f64 / h;
                Some((dir, 2.0 * PI / w * (t0.cos() - t1.cos())))
            }
            Projection::HemisphereSquare => {
                let uv = glam::DVec2::new((i as f64 + 0.5) / w, (j as f64 + 0.5) / h);
                let dir = crate::mapping::Domain::Upper.square_to_dir(uv);
                Some((dir, 2.0 * PI / (w * h)))
            }
            Projection::Fisheye {
                lens,
                fov_deg,
                centre,
                radius,
            } => {
                let (cx, cy, radius) = image_circle(centre, radius, w, h);
                let dx = (i as f64 + 0.5 - cx) / radius;
                let dy = (j as f64 + 0.5 - cy) / radius;
                let r = (dx * dx + dy * dy).sqrt();
                if r > 1.0 {
                    return None;
                }
                let theta_max = 0.5 * fov_deg.to_radians();
                // θ(r) and dθ/dr for the lens model.
                let (theta, dtheta_dr) = match lens {
                    Lens::Equidistant => (r * theta_max, theta_max),
                    Lens::Equisolid => {
                        let s = (0.5 * theta_max).sin();
                        let x = (r * s).min(1.0);
                        (2.0 * x.asin(), 2.0 * s / (1.0 - x * x).max(1e-12).sqrt())
                    }
                };
                let st = theta.sin();
                // Image right → +X, image down → +Z (image top is −Z).
                let (ax, az) = if r > 0.0 {
                    (dx / r, dy / r)
                } else {
                    (0.0, 0.0)
                };
                let dir = DVec3::new(st * ax, theta.cos(), st * az);
                // dω = sin θ dθ dφ and dA = r dr dφ, so dω/dA = sin θ · θ'(r) / r; at r → 0,
                // sin θ / r → θ'(0). Pixel area is 1/radius² in these units.
                let sin_over_r = if r > 1e-9 { st / r } else { dtheta_dr };
                Some((dir, sin_over_r * dtheta_dr / (radius * radius)))
            }
        }
    }
}

/// A fisheye's image circle in pixels, with the defaults filled in: centred, radius half the
/// shorter side.
fn image_circle(
    centre: Option<(f64, f64)>,
    radius: Option<f64>,
    w: f64,
    h: f64,
) -> (f64, f64, f64) {
    let (cx, cy) = centre.unwrap_or((w * 0.5, h * 0.5));
    (cx, cy, radius.unwrap_or(0.5 * w.min(h)))
}

/// Counts of what had to be repaired in the input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InputRepairs {
    /// Pixels with a NaN or infinite channel (set to 0).
    pub non_finite_pixels: u64,
    /// Pixels with a negative channel (clamped to 0).
    pub negative_pixels: u64,
    /// Pixels with a channel above [`MAX_RADIANCE`] (clamped to it).
    pub overbright_pixels: u64,
    /// Pixels changed for any of these reasons (a pixel can have several).
    pub changed_pixels: u64,
}

impl InputRepairs {
    pub fn clamped_pixels(&self) -> u64 {
        self.changed_pixels
    }

    /// Adds the counts of another part of the same map.
    pub fn add(&mut self, other: InputRepairs) {
        self.non_finite_pixels += other.non_finite_pixels;
        self.negative_pixels += other.negative_pixels;
        self.overbright_pixels += other.overbright_pixels;
        self.changed_pixels += other.changed_pixels;
    }
}

/// A decoded environment map: linear RGB radiance, row-major from the top row, with its projection.
#[derive(Debug)]
pub struct EnvMap {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
    pub projection: Projection,
    /// What was clamped while loading.
    pub repairs: InputRepairs,
}

impl Clone for EnvMap {
    fn clone(&self) -> Self {
        EnvMap {
            width: self.width,
            height: self.height,
            pixels: self.pixels.clone(),
            projection: self.projection,
            repairs: self.repairs,
        }
    }

    /// Reuses `self`'s pixel buffer (the derived `clone_from` allocates a new one).
    fn clone_from(&mut self, source: &Self) {
        self.width = source.width;
        self.height = source.height;
        self.pixels.clone_from(&source.pixels);
        self.projection = source.projection;
        self.repairs = source.repairs;
    }
}

impl EnvMap {
    /// Builds a map from raw pixels, clamping bad ones (NaN, ±inf, negative) to 0 and counting them.
    pub fn from_pixels(
        width: usize,
        height: usize,
        mut pixels: Vec<[f32; 3]>,
        projection: Projection,
    ) -> Result<Self, InputError> {
        projection.check_size(width, height)?;
        if pixels.len() != width * height {
            return Err(InputError::Unusable(format!(
                "{} pixels for a {width}×{height} image",
                pixels.len()
            )));
        }
        let repairs = sanitize(&mut pixels);
        Ok(EnvMap {
            width,
            height,
            pixels,
            projection,
            repairs,
        })
    }

    /// Decodes an OpenEXR or Radiance HDR file; `projection = None` guesses from the aspect.
    /// An EXR's chunks are decompressed on a pool of threads, one per core.
    pub fn decode(
        bytes: &[u8],
        projection: Option<Projection>,
        max_pixels: u64,
    ) -> Result<Self, InputError> {
        Self::decode_with(bytes, projection, max_pixels, Decoding::Parallel)
    }

    /// [`decode`](Self::decode), choosing how EXR chunks are decompressed.
    pub fn decode_with(
        bytes: &[u8],
        projection: Option<Projection>,
        max_pixels: u64,
        decoding: Decoding,
    ) -> Result<Self, InputError> {
        let (format, name) = sniff(bytes)?;
        if format == image::ImageFormat::OpenExr {
            return decode_exr(bytes, projection, max_pixels, decoding);
        }
        let dims = image::ImageReader::with_format(Cursor::new(bytes), format)
            .into_dimensions()
            .map_err(|e| corrupt(name, e))?;
        let (width, height) = (dims.0 as u64, dims.1 as u64);
        check_pixel_limit(width, height, max_pixels)?;
        let (w, h) = (width as usize, height as usize);
        let projection = projection.unwrap_or_else(|| Projection::guess(w, h));
        projection.check_size(w, h)?;

        let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(dims.0);
        limits.max_image_height = Some(dims.1);
        limits.max_alloc = Some(max_pixels.saturating_mul(32));
        reader.limits(limits);
        let img = reader.decode().map_err(|e| corrupt(name, e))?;
        let rgb = img.into_rgb32f();
        let pixels: Vec<[f32; 3]> = rgb.pixels().map(|p| p.0).collect();
        Self::from_pixels(w, h, pixels, projection)
    }

    /// Reads and decodes a file.
    pub fn open(
        path: &std::path::Path,
        projection: Option<Projection>,
        max_pixels: u64,
    ) -> anyhow::Result<Self> {
        let bytes = std::fs::read(path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        Self::decode(&bytes, projection, max_pixels)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// The radiance this map sees along a world direction (nearest pixel); 0 outside a fisheye's
    /// circle or below a hemisphere square.
    pub fn radiance_along(&self, dir: DVec3) -> [f32; 3] {
        match self.pixel_along(dir) {
            Some((i, j)) => self.pixels[j * self.width + i],
            None => [0.0; 3],
        }
    }

    /// The pixel (column, row) that sees direction `dir` (nearest pixel), or `None` outside a
    /// fisheye's image circle or below a hemisphere square.
    pub fn pixel_along(&self, dir: DVec3) -> Option<(usize, usize)> {
        let (w, h) = (self.width as f64, self.height as f64);
        let pixel = match self.projection {
            Projection::LatLong => {
                let theta = dir.y.clamp(-1.0, 1.0).acos();
                let phi = dir.x.atan2(-dir.z);
                let u = phi / (2.0 * PI) + 0.5;
                Some(((u * w) as i64, (theta / PI * h) as i64))
            }
            Projection::HemisphereSquare => crate::mapping::Domain::Upper
                .dir_to_square(dir)
                .map(|uv| ((uv.x * w) as i64, (uv.y * h) as i64)),
            Projection::Fisheye {
                lens,
                fov_deg,
                centre,
                radius,
            } => {
                let (cx, cy, radius) = image_circle(centre, radius, w, h);
                let theta = dir.y.clamp(-1.0, 1.0).acos();
                let theta_max = 0.5 * fov_deg.to_radians();
                let r = match lens {
                    Lens::Equidistant => theta / theta_max,
                    Lens::Equisolid => (0.5 * theta).sin() / (0.5 * theta_max).sin(),
                };
                let horizontal = (dir.x * dir.x + dir.z * dir.z).sqrt();
                let (ax, az) = if horizontal > 0.0 {
                    (dir.x / horizontal, dir.z / horizontal)
                } else {
                    (0.0, 0.0)
                };
                (r <= 1.0).then(|| {
                    (
                        (cx + r * ax * radius).floor() as i64,
                        (cy + r * az * radius).floor() as i64,
                    )
                })
            }
        };
        pixel.map(|(i, j)| {
            (
                i.clamp(0, self.width as i64 - 1) as usize,
                j.clamp(0, self.height as i64 - 1) as usize,
            )
        })
    }

    /// This map seen through another projection (nearest-pixel lookup), e.g. a real lat-long map
    /// as a fisheye camera would see it; pixels outside the new image circle are 0.
    pub fn reproject(&self, projection: Projection, width: usize, height: usize) -> Self {
        let mut pixels = Vec::with_capacity(width * height);
        for j in 0..height {
            for i in 0..width {
                pixels.push(match projection.pixel(i, j, width, height) {
                    Some((dir, _)) => self.radiance_along(dir),
                    None => [0.0; 3],
                });
            }
        }
        EnvMap {
            width,
            height,
            pixels,
            projection,
            repairs: self.repairs,
        }
    }

    /// Luminance (Rec. 709 / sRGB primaries) of a linear RGB triple.
    pub fn luminance(rgb: [f32; 3]) -> f32 {
        0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
    }

    /// Brute-force ∫ L dω over the pixels whose direction lies in `domain` (ALGORITHMS.md §8).
    pub fn integral(&self, domain: crate::mapping::Domain) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for j in 0..self.height {
            for i in 0..self.width {
                if let Some((dir, sr)) = self.projection.pixel(i, j, self.width, self.height)
                    && domain.contains(dir)
                {
                    let p = self.pixels[j * self.width + i];
                    for c in 0..3 {
                        sum[c] += p[c] as f64 * sr;
                    }
                }
            }
        }
        sum
    }
}

/// Luminance of a linear RGB triple in f64.
pub fn luminance64(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// The largest radiance kept. No capture comes near it (the sun's disc is about 1.6e9 cd/m²),
/// and sums of its squares over a whole map stay finite in f32; finite values above it (3e38
/// in a corrupt frame) would overflow the sums into infinities and `null`s in the LightSet.
pub const MAX_RADIANCE: f32 = 1e15;

/// Clamps NaN/inf and negative channels to 0 and channels above [`MAX_RADIANCE`] to it, and
/// counts the pixels touched.
///
/// Runs of pixels are first tested as a whole with a comparison that vectorises (NaN fails it),
/// and only a run that fails is repaired pixel by pixel: a clean 1024×512 map took 0.15–0.25 ms
/// against 3.0 ms pixel by pixel.
pub fn sanitize(pixels: &mut [[f32; 3]]) -> InputRepairs {
    let mut r = InputRepairs::default();
    for run in pixels.chunks_mut(256) {
        let clean = run
            .as_flattened()
            .iter()
            .fold(true, |ok, c| ok & (0.0..=MAX_RADIANCE).contains(c));
        if !clean {
            r.add(sanitize_each(run));
        }
    }
    r
}

/// [`sanitize`], pixel by pixel.
fn sanitize_each(pixels: &mut [[f32; 3]]) -> InputRepairs {
    let mut r = InputRepairs::default();
    for p in pixels.iter_mut() {
        let bad = p.iter().any(|c| !(0.0..=MAX_RADIANCE).contains(c));
        r.changed_pixels += bad as u64;
        if p.iter().any(|c| !c.is_finite()) {
            r.non_finite_pixels += 1;
            for c in p.iter_mut() {
                if !c.is_finite() {
                    *c = 0.0;
                }
            }
        }
        if p.iter().any(|&c| c < 0.0) {
            r.negative_pixels += 1;
            for c in p.iter_mut() {
                *c = c.max(0.0);
            }
        }
        if p.iter().any(|&c| c > MAX_RADIANCE) {
            r.overbright_pixels += 1;
            for c in p.iter_mut() {
                *c = c.min(MAX_RADIANCE);
            }
        }
    }
    r
}

/// Decodes an OpenEXR map from the channels [`exr_channels`] picks, after [`check_exr_header`].
fn decode_exr(
    bytes: &[u8],
    projection: Option<Projection>,
    max_pixels: u64,
    decoding: Decoding,
) -> Result<EnvMap, InputError> {
    use exr::prelude::{ReadChannels, ReadLayers, ReadSpecificChannel};
    let meta = check_exr_header(bytes, max_pixels)?;
    let (layer, channels) = exr_channels(&meta)?;
    // The map is the display window (the frame a lat-long or fisheye mapping refers to); the
    // data window's pixels sit in it at their offset, and what lies outside the data window is
    // black (a sky-only file with the ground left out, say).
    let header = &meta.headers[layer];
    let display = header.shared_attributes.display_window;
    let (w, h) = (display.size.width(), display.size.height());
    let offset = header.own_attributes.layer_position - display.position;
    let projection = projection.unwrap_or_else(|| Projection::guess(w, h));
    projection.check_size(w, h)?;
    // The pixels go straight into the map's buffer.
    let create = |_: exr::math::Vec2<usize>| vec![[0.0f32; 3]; w * h];
    let place = move |at: exr::math::Vec2<usize>| {
        let (x, y) = (
            at.x() as i64 + offset.x() as i64,
            at.y() as i64 + offset.y() as i64,
        );
        ((0..w as i64).contains(&x) && (0..h as i64).contains(&y))
            .then(|| y as usize * w + x as usize)
    };
    let read = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .specific_channels();
    // The layer read is the first that has the channels, the one `exr_channels` picked.
    let pixels = match channels {
        ExrChannels::Rgb([r, g, b]) => read_exr_pixels(
            read.required(r.as_str())
                .required(g.as_str())
                .required(b.as_str())
                .collect_pixels(
                    move |size, _| create(size),
                    move |px: &mut Vec<[f32; 3]>, at, (r, g, b): (f32, f32, f32)| {
                        if let Some(i) = place(at) {
                            px[i] = [r, g, b];
                        }
                    },
                )
                .first_valid_layer()
                .all_attributes(),
            decoding,
            bytes,
        ),
        ExrChannels::Luminance(y) => read_exr_pixels(
            read.required(y.as_str())
                .collect_pixels(
                    move |size, _| create(size),
                    move |px: &mut Vec<[f32; 3]>, at, (y,): (f32,)| {
                        if let Some(i) = place(at) {
                            px[i] = [y; 3];
                        }
                    },
                )
                .first_valid_layer()
                .all_attributes(),
            decoding,
            bytes,
        ),
    }
    .map_err(exr_corrupt)?;
    EnvMap::from_pixels(w, h, pixels, projection)
}

/// Runs a prepared exr reader whose pixels are collected into one `Vec<[f32; 3]>`, on a pool
/// of threads or on this one.
fn read_exr_pixels<L, C>(
    reader: exr::image::read::image::ReadImage<fn(f64), L>,
    decoding: Decoding,
    bytes: &[u8],
) -> exr::error::Result<Vec<[f32; 3]>>
where
    for<'s> L: exr::image::read::image::ReadLayers<
            's,
            Layers = exr::image::Layer<exr::image::SpecificChannels<Vec<[f32; 3]>, C>>,
        >,
{
    let reader = match decoding {
        Decoding::Parallel => reader,
        Decoding::OneThread => reader.non_parallel(),
    };
    let image = reader.from_buffered(Cursor::new(bytes))?;
    Ok(image.layer_data.channel_data.pixels)
}

/// How an EXR's chunks are decompressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decoding {
    /// On a pool of threads, one per core, created for the file: fastest for one file.
    Parallel,
    /// On the calling thread: for callers that already decode several files at once (the
    /// daemon's uploads, `--post-workers` at a time), where a pool per file only adds threads
    /// (`cargo bench --bench serve`, 4 clients on 2 cores: POST /v1/lights 70–76 requests/s in
    /// four runs against 57–74 in five).
    OneThread,
}

/// Which channels of an EXR hold the map.
#[derive(Debug, PartialEq)]
enum ExrChannels {
    /// Red, green and blue radiance.
    Rgb([String; 3]),
    /// Luminance only: a grey map.
    Luminance(String),
}

/// Picks the radiance channels and the first layer (part) that has them: `R`, `G`, `B`; else
/// those of a named layer (`diffuse.R` …, as renderers write them), preferring one whose name
/// says "combined" (Blender's beauty pass), then the first by name; else luminance `Y` alone,
/// read as grey. Luminance/chroma files (`Y`, `RY`, `BY`) and files with none of these are
/// refused with the channels they do have.
fn exr_channels(meta: &exr::meta::MetaData) -> Result<(usize, ExrChannels), InputError> {
    let names = |h: &exr::meta::header::Header| -> Vec<String> {
        h.channels.list.iter().map(|c| c.name.to_string()).collect()
    };
    // (layer, prefix) with R, G and B; prefix "" or ending in '.'.
    let mut rgb: Vec<(usize, String)> = Vec::new();
    for (layer, header) in meta.headers.iter().enumerate() {
        let names = names(header);
        for name in &names {
            let Some(prefix) = name.strip_suffix('R') else {
                continue;
            };
            let has = |c: &str| names.iter().any(|n| *n == format!("{prefix}{c}"));
            if (prefix.is_empty() || prefix.ends_with('.')) && has("G") && has("B") {
                rgb.push((layer, prefix.to_string()));
            }
        }
    }
    rgb.sort_by_key(|(layer, prefix)| {
        (
            !prefix.is_empty(),
            !prefix.to_lowercase().contains("combined"),
            prefix.clone(),
            *layer,
        )
    });
    if let Some((layer, p)) = rgb.into_iter().next() {
        return Ok((
            layer,
            ExrChannels::Rgb(["R", "G", "B"].map(|c| format!("{p}{c}"))),
        ));
    }
    for (layer, header) in meta.headers.iter().enumerate() {
        let names = names(header);
        if names.iter().any(|n| n == "Y") {
            if names.iter().any(|n| n == "RY" || n == "BY") {
                return Err(InputError::Unusable(
                    "luminance/chroma OpenEXR (Y, RY, BY) is not supported: convert it to RGB"
                        .into(),
                ));
            }
            return Ok((layer, ExrChannels::Luminance("Y".into())));
        }
    }
    let all: Vec<String> = meta.headers.iter().flat_map(names).collect();
    Err(InputError::Unusable(format!(
        "OpenEXR needs R, G and B channels, or Y (it has: {})",
        if all.is_empty() {
            "none".into()
        } else {
            all.join(", ")
        }
    )))
}

/// Reads only the OpenEXR headers (no offset tables, no pixels) and refuses any layer whose data or display window is larger than
/// `max_pixels`, before a decoder sizes its buffers from a header that may lie; then checks the
/// DWA chunks' counters (see [`check_dwa_chunks`]).
fn check_exr_header(bytes: &[u8], max_pixels: u64) -> Result<exr::meta::MetaData, InputError> {
    // Unvalidated, so an oversized header is reported as too large (413), not as invalid.
    let meta =
        exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(exr_corrupt)?;
    for header in &meta.headers {
        let display = header.shared_attributes.display_window.size;
        for size in [header.layer_size, display] {
            check_pixel_limit(size.width() as u64, size.height() as u64, max_pixels)?;
        }
    }
    if meta.headers.iter().any(|h| is_dwa(h.compression)) {
        check_dwa_chunks(bytes, &meta.headers)?;
    }
    Ok(meta)
}

fn exr_corrupt(e: exr::error::Error) -> InputError {
    InputError::Corrupt {
        format: "OpenEXR",
        reason: e.to_string(),
    }
}

fn is_dwa(c: exr::compression::Compression) -> bool {
    matches!(
        c,
        exr::compression::Compression::DWAA(_) | exr::compression::Compression::DWAB(_)
    )
}

/// Every DWAA/DWAB chunk's leader (eleven little-endian u64 counters: version, unknown raw and
/// packed sizes, AC, DC and RLE packed sizes, RLE unpacked and raw sizes, AC and DC value counts,
/// AC coder) must describe no more data than its block can hold. The exr crate sizes its buffers
/// from these counters, checked only against i64::MAX: one flipped bit in a shared map made it
/// ask for 2^57 bytes, which aborts the process (an allocation failure is not a panic), so a
/// corrupt upload would have stopped the daemon.
fn check_dwa_chunks(bytes: &[u8], headers: &[exr::meta::header::Header]) -> Result<(), InputError> {
    use exr::block::chunk::CompressedBlock;
    let reader = exr::block::reader::Reader::read_from_buffered(Cursor::new(bytes), false)
        .map_err(exr_corrupt)?;
    let refuse = |reason: String| InputError::Corrupt {
        format: "OpenEXR",
        reason,
    };
    for chunk in reader.all_chunks(false).map_err(exr_corrupt)? {
        let chunk = chunk.map_err(exr_corrupt)?;
        let Some(header) = headers.get(chunk.layer_index) else {
            return Err(refuse("a chunk names a missing layer".into()));
        };
        if !is_dwa(header.compression) {
            continue;
        }
        let data = match &chunk.compressed_block {
            CompressedBlock::ScanLine(b) => &b.compressed_pixels_le,
            CompressedBlock::Tile(b) => &b.compressed_pixels_le,
            _ => continue, // deep data: refused later by the decoder
        };
        let section = header
            .get_block_data_indices(&chunk.compressed_block)
            .and_then(|tile| header.get_absolute_block_pixel_coordinates(tile))
            .map_err(exr_corrupt)?;
        let (block_w, block_h) = (section.size.width(), section.size.height());
        if data.len() == block_w * block_h * header.channels.bytes_per_pixel {
            continue; // stored raw: compressing did not make it smaller
        }
        // DCT blocks are 8 × 8 pixels, so a block's lossy channels hold at most this many
        // coefficients; samples are at most 4 bytes.
        let values = (block_w.div_ceil(8) * 8)
            .saturating_mul(block_h.div_ceil(8) * 8)
            .saturating_mul(header.channels.list.len());
        let max_bytes = values.saturating_mul(4) as u64;
        let counter = |k: usize| {
            data.get(8 * k..8 * k + 8)
                .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
        };
        let checks = [
            (1, "unknown-channel size", max_bytes),
            (6, "RLE unpacked size", max_bytes),
            (7, "RLE raw size", max_bytes),
            (8, "AC value count", values as u64),
            (9, "DC value count", values as u64),
        ];
        for (k, what, limit) in checks {
            // A leader cut short is left to the decoder, which reports it.
            if let Some(v) = counter(k)
                && v > limit
            {
                return Err(refuse(format!(
                    "a DWA chunk's {what} is {v}, more than its {block_w}×{block_h} block can hold ({limit})"
                )));
            }
        }
    }
    Ok(())
}

fn corrupt(format: &'static str, e: image::ImageError) -> InputError {
    match e {
        image::ImageError::Limits(l) => InputError::Unusable(format!("{format} image: {l}")),
        other => InputError::Corrupt {
            format,
            reason: other.to_string(),
        },
    }
}

/// An image of `width` × `height` pixels is within `max_pixels` (`--max-pixels`), checked before
/// anything of that size is allocated.
pub fn check_pixel_limit(width: u64, height: u64, max_pixels: u64) -> Result<(), InputError> {
    if width.saturating_mul(height) > max_pixels {
        return Err(InputError::TooLarge {
            width,
            height,
            limit: max_pixels,
        });
    }
    Ok(())
}

/// Bytes [`sniff`] needs to tell a format.
pub const MAGIC_LEN: usize = 4;

/// Identifies the format from the magic bytes, never from a name or content type.
pub fn sniff(bytes: &[u8]) -> Result<(image::ImageFormat, &'static str), InputError> {
    const EXR_MAGIC: [u8; MAGIC_LEN] = [0x76, 0x2f, 0x31, 0x01];
    if bytes.starts_with(&EXR_MAGIC) {
        Ok((image::ImageFormat::OpenExr, "OpenEXR"))
    } else if bytes.starts_with(b"#?") {
        Ok((image::ImageFormat::Hdr, "Radiance HDR"))
    } else {
        let head: Vec<String> = bytes.iter().take(4).map(|b| format!("{b:02x}")).collect();
        Err(InputError::UnsupportedFormat(if head.is_empty() {
            "none: the input is empty".into()
        } else {
            head.join(" ")
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latlong_conventions() {
        let (w, h) = (64, 32);
        let p = Projection::LatLong;
        // Image centre looks along −Z on the horizon; u = ¾ looks along +X; top row is the zenith.
        let (d, _) = p.pixel(w / 2, h / 2, w, h).unwrap();
        assert!((d - DVec3::NEG_Z).length() < 0.1, "{d}");
        let (d, _) = p.pixel(3 * w / 4, h / 2, w, h).unwrap();
        assert!((d - DVec3::X).length() < 0.1, "{d}");
        let (d, _) = p.pixel(0, 0, w, h).unwrap();
        assert!(d.y > 0.99, "{d}");
        let total: f64 = (0..h)
            .flat_map(|j| (0..w).map(move |i| (i, j)))
            .map(|(i, j)| p.pixel(i, j, w, h).unwrap().1)
            .sum();
        assert!((total - 4.0 * PI).abs() < 1e-12, "{total}");
    }

    #[test]
    fn fisheye_conventions_and_solid_angle() {
        for lens in [Lens::Equidistant, Lens::Equisolid] {
            let p = Projection::Fisheye {
                lens,
                fov_deg: 180.0,
                centre: None,
                radius: None,
            };
            let (w, h) = (640, 480);
            // Top of the circle is −Z, right is +X, the centre the zenith.
            let (d, _) = p.pixel(320, 1, w, h).unwrap();
            assert!((d - DVec3::NEG_Z).length() < 0.02, "{d}");
            let (d, _) = p.pixel(558, 240, w, h).unwrap();
            assert!((d - DVec3::X).length() < 0.02, "{d}");
            let (d, _) = p.pixel(320, 240, w, h).unwrap();
            assert!(d.y > 0.9999, "{d}");
            assert!(p.pixel(0, 0, w, h).is_none());
            let total: f64 = (0..h)
                .flat_map(|j| (0..w).map(move |i| (i, j)))
                .filter_map(|(i, j)| p.pixel(i, j, w, h))
                .map(|(_, sr)| sr)
                .sum();
            // The image circle covers the hemisphere: 2π, up to the pixelated rim.
            assert!((total / (2.0 * PI) - 1.0).abs() < 5e-3, "{lens:?}: {total}");
        }
    }

    #[test]
    fn radiance_along_inverts_pixel_directions() {
        let fisheye = Projection::Fisheye {
            lens: Lens::Equisolid,
            fov_deg: 185.0,
            centre: Some((50.0, 40.0)),
            radius: Some(38.0),
        };
        for (proj, w, h) in [
            (Projection::LatLong, 64, 32),
            (fisheye, 100, 80),
            (Projection::HemisphereSquare, 32, 32),
        ] {
            // Each pixel holds its own index; looking along its direction must find it.
            let px: Vec<[f32; 3]> = (0..w * h).map(|k| [k as f32, 0.0, 0.0]).collect();
            let map = EnvMap::from_pixels(w, h, px, proj).unwrap();
            for j in 0..h {
                for i in 0..w {
                    if let Some((d, _)) = proj.pixel(i, j, w, h) {
                        let got = map.radiance_along(d)[0] as usize;
                        assert_eq!(got, j * w + i, "{proj:?} pixel ({i},{j}) -> {d}");
                    }
                }
            }
        }
    }

    /// The run test lets every bad value through to the repair (NaN, ±inf, negative, at any
    /// position in a run and across runs), and leaves −0 and the largest and smallest positive
    /// floats alone, as the pixel-by-pixel pass does.
    #[test]
    fn sanitize_by_runs_matches_pixel_by_pixel() {
        let specials = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -1e-30,
            -0.0,
            f32::MAX,
            3e38,
            MAX_RADIANCE,
            2e15,
            f32::MIN_POSITIVE,
            1e-45,
        ];
        let mut px: Vec<[f32; 3]> = (0..2000).map(|k| [k as f32, 0.5, 1.0]).collect();
        for (n, &v) in specials.iter().cycle().take(40).enumerate() {
            let k = (n * 97 + n * n * 13) % px.len();
            px[k][n % 3] = v;
        }
        let mut each = px.clone();
        let expected = sanitize_each(&mut each);
        let got = sanitize(&mut px);
        assert_eq!(got, expected);
        assert!(expected.changed_pixels >= 20, "{expected:?}");
        assert_eq!(
            px.iter().flatten().map(|c| c.to_bits()).collect::<Vec<_>>(),
            each.iter()
                .flatten()
                .map(|c| c.to_bits())
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn sanitize_counts_and_clamps() {
        let mut px = vec![
            [1.0, 2.0, 3.0],
            [f32::NAN, 1.0, 1.0],
            [-1.0, 1.0, 1.0],
            [f32::INFINITY, -2.0, 0.0],
            [3e38, 1.0, -1.0],
            [MAX_RADIANCE, 1.0, 1.0],
        ];
        let r = sanitize(&mut px);
        assert_eq!(r.non_finite_pixels, 2);
        assert_eq!(r.negative_pixels, 3);
        assert_eq!(r.overbright_pixels, 1);
        // [inf, −2, 0] and [3e38, 1, −1] are both: four pixels changed.
        assert_eq!(r.clamped_pixels(), 4);
        assert!(
            px.iter()
                .flatten()
                .all(|c| (0.0..=MAX_RADIANCE).contains(c))
        );
        assert_eq!(px[0], [1.0, 2.0, 3.0]);
        assert_eq!(px[4], [MAX_RADIANCE, 1.0, 0.0]);
        assert_eq!(px[5], [MAX_RADIANCE, 1.0, 1.0], "the bound itself is kept");
    }

    #[test]
    fn rejects_non_images() {
        assert!(matches!(
            EnvMap::decode(b"GIF89a....", None, DEFAULT_MAX_PIXELS),
            Err(InputError::UnsupportedFormat(_))
        ));
        assert!(matches!(
            EnvMap::decode(b"", None, DEFAULT_MAX_PIXELS),
            Err(InputError::UnsupportedFormat(_))
        ));
    }

    /// An in-memory OpenEXR of 8 × 4 pixels with these (name, constant value) f32 channels in
    /// one part.
    fn exr_with(channels: &[(&str, f32)]) -> Vec<u8> {
        use exr::prelude::*;
        let list = channels
            .iter()
            .map(|&(name, v)| AnyChannel::new(name, FlatSamples::F32(vec![v; 8 * 4])))
            .collect();
        let image = Image::from_channels((8, 4), AnyChannels::sort(list));
        let mut out = Cursor::new(Vec::new());
        image.write().to_buffered(&mut out).expect("writes");
        out.into_inner()
    }

    fn first_pixel(bytes: &[u8]) -> Result<[f32; 3], InputError> {
        EnvMap::decode(bytes, None, DEFAULT_MAX_PIXELS).map(|m| m.pixels[0])
    }

    #[test]
    fn exr_channels_plain_named_and_luminance() {
        let rgb = exr_with(&[("R", 1.0), ("G", 2.0), ("B", 3.0), ("A", 0.5)]);
        assert_eq!(first_pixel(&rgb).unwrap(), [1.0, 2.0, 3.0]);
        // Unprefixed RGB wins over a named layer.
        let both = exr_with(&[("R", 1.0), ("G", 2.0), ("B", 3.0), ("spec.R", 9.0)]);
        assert_eq!(first_pixel(&both).unwrap(), [1.0, 2.0, 3.0]);
        // A renderer's passes: the combined one, whatever its place by name.
        let passes = exr_with(&[
            ("ViewLayer.Combined.R", 4.0),
            ("ViewLayer.Combined.G", 5.0),
            ("ViewLayer.Combined.B", 6.0),
            ("ViewLayer.Alpha.R", 7.0),
            ("ViewLayer.Alpha.G", 7.0),
            ("ViewLayer.Alpha.B", 7.0),
            ("ViewLayer.Depth.Z", 1e9),
        ]);
        assert_eq!(first_pixel(&passes).unwrap(), [4.0, 5.0, 6.0]);
        // No combined pass: the first layer by name.
        let layers = exr_with(&[
            ("specular.R", 7.0),
            ("specular.G", 7.0),
            ("specular.B", 7.0),
            ("diffuse.R", 1.0),
            ("diffuse.G", 2.0),
            ("diffuse.B", 3.0),
        ]);
        assert_eq!(first_pixel(&layers).unwrap(), [1.0, 2.0, 3.0]);
        // Luminance alone: grey.
        assert_eq!(first_pixel(&exr_with(&[("Y", 2.5)])).unwrap(), [2.5; 3]);
        // "xR" is not a layer's red: no R, G, B here.
        let odd = exr_with(&[("xR", 1.0), ("xG", 1.0), ("xB", 1.0)]);
        match first_pixel(&odd) {
            Err(InputError::Unusable(m)) => assert!(m.contains("xB, xG, xR"), "{m}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn exr_without_usable_channels_says_what_it_has() {
        match first_pixel(&exr_with(&[("Z", 1.0), ("A", 1.0)])) {
            Err(InputError::Unusable(m)) => {
                assert!(
                    m.contains("needs R, G and B channels, or Y") && m.contains("A, Z"),
                    "{m}"
                )
            }
            other => panic!("{other:?}"),
        }
        // Two of the three colours are not enough either.
        match first_pixel(&exr_with(&[("R", 1.0), ("G", 1.0)])) {
            Err(InputError::Unusable(m)) => {
                assert!(m.contains("needs R, G and B") && m.contains("G, R"), "{m}")
            }
            other => panic!("{other:?}"),
        }
        match first_pixel(&exr_with(&[("Y", 1.0), ("RY", 0.1), ("BY", 0.1)])) {
            Err(InputError::Unusable(m)) => assert!(m.contains("luminance/chroma"), "{m}"),
            other => panic!("{other:?}"),
        }
    }

    /// The map is the display window: a sky-only file (data window = the upper half of a 2:1
    /// display window) decodes to the whole 2:1 lat-long map with a black ground, and data outside
    /// the display window is cut off.
    #[test]
    fn exr_data_window_sits_in_the_display_window() {
        use exr::prelude::*;
        let write = |data_origin: (i32, i32), data_size: (usize, usize)| {
            let channels =
                SpecificChannels::rgb(|p: Vec2<usize>| (1.0 + p.x() as f32, 2.0f32, 3.0f32));
            let mut layer = Layer::new(
                data_size,
                LayerAttributes::default(),
                Encoding::FAST_LOSSLESS,
                channels,
            );
            layer.attributes.layer_position = Vec2(data_origin.0, data_origin.1);
            let image = Image {
                attributes: ImageAttributes::new(IntegerBounds::new((0, 0), (16, 8))),
                layer_data: layer,
            };
            let mut out = Cursor::new(Vec::new());
            image.write().to_buffered(&mut out).expect("writes");
            EnvMap::decode(&out.into_inner(), None, DEFAULT_MAX_PIXELS).expect("decodes")
        };
        let sky = write((0, 0), (16, 4));
        assert_eq!(
            (sky.width, sky.height, sky.projection),
            (16, 8, Projection::LatLong)
        );
        assert_eq!(sky.pixels[3], [4.0, 2.0, 3.0]);
        assert!(
            sky.pixels[16 * 4..].iter().all(|p| *p == [0.0; 3]),
            "black ground"
        );
        // Shifted 10 right and 2 up: columns 10..16 of rows 0..2 hold data columns 0..6 of rows 2..4.
        let shifted = write((10, -2), (16, 4));
        assert_eq!((shifted.width, shifted.height), (16, 8));
        assert_eq!(shifted.pixels[10], [1.0, 2.0, 3.0]);
        assert_eq!(shifted.pixels[15 + 16], [6.0, 2.0, 3.0]);
        assert_eq!(shifted.pixels[9], [0.0; 3]);
        assert!(shifted.pixels[16 * 2..].iter().all(|p| *p == [0.0; 3]));
    }

    /// Decompressing on one thread or on a pool gives the same map.
    #[test]
    fn exr_decodings_agree() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/sunrise.exr");
        let bytes = std::fs::read(path).unwrap();
        let pool = EnvMap::decode_with(&bytes, None, DEFAULT_MAX_PIXELS, Decoding::Parallel);
        let one = EnvMap::decode_with(&bytes, None, DEFAULT_MAX_PIXELS, Decoding::OneThread);
        let (pool, one) = (pool.unwrap(), one.unwrap());
        assert_eq!((pool.width, pool.height), (one.width, one.height));
        assert!(pool.pixels == one.pixels);
    }
}
