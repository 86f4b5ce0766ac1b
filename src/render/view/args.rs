//! The arguments of `vemlight view` and what follows from them alone: the renderer's [`Options`],
//! the scene, the camera.
//!
//! Input: the command line. Output: [`ViewArgs`], which every mode (headless, window, bench) reads.

use super::nats::NatsOptions;
use super::source::{DEFAULT_STREAM, LightFeed, Source};
use crate::publish::cameras::LISTEN;
use crate::publish::login::LoginArgs;
use crate::render::gpu::parse_backends;
use crate::render::renderer::Options;
use crate::render::scene::{Camera, Mesh, Scene};
use crate::render::shadow::shadow_size_for;
use std::path::PathBuf;
use std::time::Duration;

/// `vemlight view [SOURCE]`.
#[derive(clap::Args, Debug, Clone)]
pub struct ViewArgs {
    /// Where the lights come from: a `ws://host:port/v1/stream?lights=N` URL (the daemon's stream),
    /// a `nats://host:port/CAMERA?lights=N` URL (a camera through a NATS broker; without CAMERA
    /// the only one publishing, without lights= its first count), a LightSet .json file, or an
    /// .exr/.hdr environment map (lights extracted here).
    #[arg(default_value = DEFAULT_STREAM)]
    pub source: String,
    /// With a nats:// source that names no camera: the camera to follow.
    #[arg(long)]
    pub camera: Option<String>,
    /// With a nats:// source: drop sets captured longer ago than this (by this machine's clock;
    /// 0 = no check). A camera slower than one set a second needs more.
    #[arg(long, default_value_t = 1000, value_name = "MS")]
    pub max_age_ms: u64,
    #[command(flatten)]
    pub login: LoginArgs,
    /// Render without a window and write PNGs to --out.
    #[arg(long)]
    pub headless: bool,
    /// Frames to render headless (and per path with --bench).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Directory for the PNGs (frame_0000.png, …).
    #[arg(long, default_value = "frames")]
    pub out: PathBuf,
    /// Frame size, WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// The mesh (OBJ); default the built-in low-resolution Stanford bunny.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// Light count to extract from a map source.
    #[arg(long, short = 'n', default_value_t = 72)]
    pub lights: usize,
    /// Camera azimuth in degrees (0 looks from +Z toward −Z).
    #[arg(long, default_value_t = 20.0, value_parser = finite, allow_negative_numbers = true)]
    pub azimuth: f32,
    /// Orbit the camera at this many degrees per second (0 = fixed).
    #[arg(long, default_value_t = 0.0, value_parser = finite, allow_negative_numbers = true)]
    pub orbit: f32,
    /// Every cost saver off (each light its own map, every map every frame, full BRDF everywhere).
    #[arg(long)]
    pub naive: bool,
    /// No culling of lights by normal bin.
    #[arg(long)]
    pub no_cull: bool,
    /// No glossy refinement (full BRDF for every light).
    #[arg(long)]
    pub no_glossy_refine: bool,
    /// Clustering radius δ in degrees: lights closer share a shadow map (0 = off).
    #[arg(long, default_value_t = 3.0, value_parser = non_negative)]
    pub cluster_deg: f32,
    /// Reuse a shadow map while its light moved less than ε degrees.
    #[arg(long, default_value_t = 0.5, value_parser = non_negative)]
    pub reuse_deg: f32,
    /// Redraw every shadow map every frame.
    #[arg(long)]
    pub no_reuse: bool,
    /// Adapt the light count (a prefix of the progressive set) to reach this frame rate.
    #[arg(long, value_parser = positive)]
    pub target_fps: Option<f32>,
    /// Shadow budget: only K lights get shadow maps (the K most worth one, marked as the
    /// daemon's `shadowed=K` marks them), the rest are drawn unoccluded. A stream is asked for
    /// `shadowed=K` (unless its URL has it); a file's, a map's or a broker's lights are marked
    /// here.
    #[arg(long, value_name = "K")]
    pub shadowed: Option<usize>,
    /// Side of each shadow map, texels (default: the largest power of two not above the frame's
    /// longer side, 256–2048: 256 at 320×240, 512 at 960×540).
    #[arg(long, value_parser = clap::value_parser!(u32).range(16..=8192))]
    pub shadow_size: Option<u32>,
    /// PCF taps per shadow lookup: 1 (bilinear 2×2) or 4 (3×3 tent); 0 turns shadows off.
    #[arg(long, default_value_t = 1, value_parser = parse_pcf)]
    pub pcf: u32,
    /// Fixed exposure (default: from the lights).
    #[arg(long, value_parser = positive)]
    pub exposure: Option<f32>,
    /// No overlay.
    #[arg(long)]
    pub no_overlay: bool,
    /// Graphics backends to try: vulkan, gl, metal, dx12 (comma-separated) or all; default
    /// WGPU_BACKEND, else all.
    #[arg(long, value_parser = parse_backends)]
    pub backend: Option<wgpu::Backends>,
    /// Measure frames/s of the naive and the optimised paths in the same run (headless, no PNGs).
    #[arg(long)]
    pub bench: bool,
    /// With --bench: also measure the optimised path with the lights turning about +Y by this many
    /// degrees per frame (every shadow map goes stale; 0 = skip).
    #[arg(long, default_value_t = 1.0, value_parser = finite, allow_negative_numbers = true)]
    pub bench_turn_deg: f32,
    /// With --bench: which paths to time (naive, steady, turning), comma-separated.
    #[arg(
        long,
        value_enum,
        default_value = "naive,steady,turning",
        value_delimiter = ','
    )]
    pub bench_paths: Vec<BenchPath>,
}

/// A path `--bench` times.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BenchPath {
    /// Every cost saver off.
    Naive,
    /// The optimised path, the lights still.
    Steady,
    /// The optimised path, the lights turning (`--bench-turn-deg`).
    Turning,
}

/// A finite number of degrees.
fn finite(s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("must be a finite number, got {s}"))
    }
}

/// A finite number ≥ 0.
fn non_negative(s: &str) -> Result<f32, String> {
    let v = finite(s)?;
    if v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("must be at least 0, got {s}"))
    }
}

/// A finite number > 0.
fn positive(s: &str) -> Result<f32, String> {
    let v = finite(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("must be greater than 0, got {s}"))
    }
}

/// PCF taps: 0, 1 or 4 (the kernels the shading pass has).
fn parse_pcf(s: &str) -> Result<u32, String> {
    match s.trim() {
        "0" => Ok(0),
        "1" => Ok(1),
        "4" => Ok(4),
        _ => Err(format!("must be 0 (no shadows), 1 or 4, got {s}")),
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let w: u32 = w.trim().parse().map_err(|e| format!("width: {e}"))?;
    let h: u32 = h.trim().parse().map_err(|e| format!("height: {e}"))?;
    if !(1..=8192).contains(&w) || !(1..=8192).contains(&h) {
        return Err(format!("size out of range: {w}x{h} (each side 1 to 8192)"));
    }
    Ok((w, h))
}

impl ViewArgs {
    /// The renderer options the flags ask for, for frames of `size` pixels.
    pub fn options(&self, size: (u32, u32)) -> Options {
        let mut o = if self.naive {
            Options::naive()
        } else {
            Options::optimised()
        };
        if !self.naive {
            o.cull = !self.no_cull;
            if self.no_glossy_refine {
                o.glossy_threshold = None;
            }
            o.cluster_deg = self.cluster_deg;
            // Neither is negative: `non_negative` parsed them.
            o.reuse_deg = (!self.no_reuse).then_some(self.reuse_deg);
        }
        o.shadow_size = self.shadow_size(size);
        o.pcf_taps = self.pcf; // 0, 1 or 4: `parse_pcf` admits no other
        o.exposure = self.exposure;
        o.overlay = !self.no_overlay;
        o
    }

    /// `--shadow-size`, or the default for frames of `size` pixels.
    pub(super) fn shadow_size(&self, size: (u32, u32)) -> u32 {
        self.shadow_size
            .unwrap_or_else(|| shadow_size_for(size.0, size.1))
            .clamp(16, 8192)
    }

    /// Opens SOURCE with the shadow budget.
    pub(super) fn feed(&self) -> anyhow::Result<LightFeed> {
        let source = Source::parse(&self.source);
        let Source::Nats(url) = &source else {
            if self.camera.is_some() {
                anyhow::bail!("--camera is for a nats:// source");
            }
            return LightFeed::open_with_budget(&source, self.lights, self.shadowed);
        };
        let opts = NatsOptions {
            camera: self.camera.clone(),
            max_age: (self.max_age_ms > 0).then(|| Duration::from_millis(self.max_age_ms)),
            auth: self.login.auth()?,
            listen: LISTEN,
        };
        let feed = LightFeed::open_nats(url, opts, self.shadowed)?;
        if let LightFeed::Nats { feed, .. } = &feed {
            eprintln!(
                "vemlight view: camera {}, {} lights, on {} ({})",
                feed.camera(),
                feed.lights(),
                feed.server(),
                feed.subject()
            );
        }
        Ok(feed)
    }

    /// The showcase scene around `--mesh` (or the built-in bunny).
    pub(super) fn scene(&self) -> anyhow::Result<Scene> {
        let mesh = match &self.mesh {
            Some(p) => Mesh::load_obj(p)?,
            None => Mesh::builtin_bunny(),
        };
        Ok(Scene::showcase(&mesh))
    }
}

/// The camera at time `t` seconds.
pub fn camera_at(args: &ViewArgs, scene: &Scene, t: f32) -> Camera {
    Camera::framing(&scene.bounds, args.azimuth + args.orbit * t)
}
