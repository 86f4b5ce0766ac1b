//! `vemlight view`: the render client's command line — windowed, headless (PNG frames) or `--bench`.
//!
//! Input: [`ViewArgs`]. Output: a window, PNG files, or the benchmark's table on stdout.

use super::adaptive::{LightBudget, prefix_with_energy};
use super::gpu::{Gpu, parse_backends};
use super::overlay::Status;
use super::scene::{Camera, Mesh, Scene};
use super::source::{DEFAULT_STREAM, LightFeed, Source};
use super::{OUTPUT_FORMAT, Options, Renderer};
use crate::lights::Light;
use anyhow::{Context, bail};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `vemlight view [SOURCE]`.
#[derive(clap::Args, Debug, Clone)]
pub struct ViewArgs {
    /// Where the lights come from: a `ws://host:port/v1/stream?lights=N` URL (the daemon's stream),
    /// a LightSet .json file, or an .exr/.hdr environment map (lights extracted here).
    #[arg(default_value = DEFAULT_STREAM)]
    pub source: String,
    /// Render without a window and write PNGs to --out.
    #[arg(long)]
    pub headless: bool,
    /// Frames to render headless (and per path with --bench).
    #[arg(long, default_value_t = 1)]
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
    #[arg(long, default_value_t = 20.0)]
    pub azimuth: f32,
    /// Orbit the camera at this many degrees per second (0 = fixed).
    #[arg(long, default_value_t = 0.0)]
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
    #[arg(long, default_value_t = 3.0)]
    pub cluster_deg: f32,
    /// Reuse a shadow map while its light moved less than ε degrees.
    #[arg(long, default_value_t = 0.5)]
    pub reuse_deg: f32,
    /// Redraw every shadow map every frame.
    #[arg(long)]
    pub no_reuse: bool,
    /// Adapt the light count (a prefix of the progressive set) to reach this frame rate.
    #[arg(long)]
    pub target_fps: Option<f32>,
    /// Side of each shadow map, texels (default: the largest power of two not above the frame's
    /// longer side, 256–2048: 256 at 320×240, 512 at 960×540).
    #[arg(long)]
    pub shadow_size: Option<u32>,
    /// PCF taps per shadow lookup: 1 (bilinear 2×2) or 4 (3×3 tent); 0 turns shadows off.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(0..=4))]
    pub pcf: u32,
    /// Fixed exposure (default: from the lights).
    #[arg(long)]
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
    #[arg(long, default_value_t = 1.0)]
    pub bench_turn_deg: f32,
    /// With --bench: which paths to time (naive, steady, turning), comma-separated.
    #[arg(long, default_value = "naive,steady,turning", value_delimiter = ',')]
    pub bench_paths: Vec<String>,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let w: u32 = w.trim().parse().map_err(|e| format!("width: {e}"))?;
    let h: u32 = h.trim().parse().map_err(|e| format!("height: {e}"))?;
    if !(1..=8192).contains(&w) || !(1..=8192).contains(&h) {
        return Err(format!("size out of range: {w}x{h}"));
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
            o.cluster_deg = self.cluster_deg.max(0.0);
            o.reuse_deg = (!self.no_reuse).then_some(self.reuse_deg.max(0.0));
        }
        o.shadow_size = self.shadow_size(size);
        o.pcf_taps = match self.pcf {
            0 => 0,
            1..=3 => 1,
            _ => 4,
        };
        o.exposure = self.exposure;
        o.overlay = !self.no_overlay;
        o
    }

    /// `--shadow-size`, or the default for frames of `size` pixels.
    fn shadow_size(&self, size: (u32, u32)) -> u32 {
        self.shadow_size
            .unwrap_or_else(|| super::shadow::shadow_size_for(size.0, size.1))
            .clamp(16, 8192)
    }

    fn scene(&self) -> anyhow::Result<Scene> {
        let mesh = match &self.mesh {
            Some(p) => Mesh::load_obj(p)?,
            None => Mesh::builtin_bunny(),
        };
        Ok(Scene::showcase(&mesh))
    }
}

/// Runs `vemlight view`.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    if args.bench {
        return bench(&args);
    }
    if args.headless {
        return headless(&args);
    }
    super::window::run(args)
}

/// The camera at time `t` seconds.
pub fn camera_at(args: &ViewArgs, scene: &Scene, t: f32) -> Camera {
    Camera::framing(&scene.bounds, args.azimuth + args.orbit * t)
}

/// Applies a new set, through the light budget when one is set.
pub(crate) struct LightState {
    all: Vec<Light>,
    drawn: Vec<Light>,
    budget: Option<LightBudget>,
}

impl LightState {
    pub(crate) fn new(target_fps: Option<f32>, lights: usize) -> Self {
        LightState {
            all: Vec::new(),
            drawn: Vec::new(),
            budget: target_fps.map(|f| LightBudget::new(f, lights)),
        }
    }

    /// A new set arrived.
    pub(crate) fn set(&mut self, renderer: &mut Renderer, lights: &[Light]) {
        self.all.clear();
        self.all.extend_from_slice(lights);
        self.apply(renderer);
    }

    fn apply(&mut self, renderer: &mut Renderer) {
        let n = self.budget.as_ref().map_or(self.all.len(), |b| b.count());
        prefix_with_energy(&self.all, n, &mut self.drawn);
        renderer.set_lights(&self.drawn);
    }

    /// A frame took `ms`: maybe change the count.
    pub(crate) fn frame_time(&mut self, renderer: &mut Renderer, ms: f32) {
        let available = self.all.len();
        if let Some(b) = &mut self.budget {
            let before = b.count().min(available);
            if b.update(ms, available) != before {
                self.apply(renderer);
            }
        }
    }
}

/// `--headless`: render `--frames` frames to PNGs.
fn headless(args: &ViewArgs) -> anyhow::Result<()> {
    let size = args.size.unwrap_or((320, 240));
    let mut feed = LightFeed::open(&Source::parse(&args.source), args.lights)?;
    let scene = args.scene()?;
    let gpu = Gpu::new(Gpu::backends(args.backend))?;
    eprintln!("vemlight view: {}", gpu.describe());
    let mut renderer = Renderer::new(&gpu, &scene, size, OUTPUT_FORMAT, args.options(size));
    let mut lights = LightState::new(args.target_fps, args.lights);
    let first = feed.wait_first(Duration::from_secs(10))?;
    lights.set(&mut renderer, &first.lights);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let start = Instant::now();
    let mut last = start;
    let mut fps = None;
    for frame in 0..args.frames {
        if let Some(set) = feed.poll() {
            lights.set(&mut renderer, &set.lights);
        }
        let t = if args.orbit != 0.0 {
            frame as f32 / 30.0 // orbiting headless frames are spaced as at 30 frames/s
        } else {
            0.0
        };
        let status = Status {
            fps,
            stale: feed.is_stale(),
            ..Status::default()
        };
        let stats = renderer.render_headless(&camera_at(args, &scene, t), &status);
        renderer.wait();
        let now = Instant::now();
        let ms = (now - last).as_secs_f32() * 1e3;
        last = now;
        fps = Some(1e3 / ms.max(1e-3));
        lights.frame_time(&mut renderer, ms);
        let path = args.out.join(format!("frame_{frame:04}.png"));
        renderer
            .read_rgba8()
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!(
            "{}: {} lights, {} shadow maps ({} drawn), {ms:.1} ms",
            path.display(),
            stats.lights,
            stats.groups,
            stats.maps_drawn
        );
    }
    Ok(())
}

/// CPU time this process has used, all threads (lavapipe renders on worker threads), in ms;
/// `None` off Linux. On a shared machine it is a steadier measure than wall time.
fn cpu_ms() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces) start at the last ')'.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split(' ').collect();
    // utime and stime are fields 14 and 15 of stat(5), 12 and 13 after the name; clock ticks of
    // 1/100 s on Linux.
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks * 10.0)
}

/// Median of a list of milliseconds.
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Rotates a light set about +Y.
fn turned(lights: &[Light], deg: f32, out: &mut Vec<Light>) {
    let q = glam::Quat::from_rotation_y(deg.to_radians());
    out.clear();
    out.extend(lights.iter().map(|l| Light {
        to_light: (q * glam::Vec3::from_array(l.to_light)).to_array(),
        ..*l
    }));
}

/// `--bench`: the naive and the optimised path on the same scene and lights, same run.
fn bench(args: &ViewArgs) -> anyhow::Result<()> {
    let size = args.size.unwrap_or((320, 240));
    let source = Source::parse(&args.source);
    let mut feed = LightFeed::open(&source, args.lights)?;
    let set = feed.wait_first(Duration::from_secs(10))?;
    let scene = args.scene()?;
    let gpu = Gpu::new(Gpu::backends(args.backend))?;
    let frames = args.frames.max(3);
    const WARMUP: u32 = 3;
    println!("vemlight view --bench");
    println!("device: {}", gpu.describe());
    if set.lights.len() > super::shading::MAX_LIGHTS {
        bail!("at most {} lights", super::shading::MAX_LIGHTS);
    }
    println!(
        "scene: {} triangles ({} casting shadows); {}x{}; lights: {} from {} ({}); shadow maps {}²",
        scene.triangle_count(),
        scene.caster_indices / 3,
        size.0,
        size.1,
        set.lights.len(),
        args.source,
        set.source,
        args.shadow_size(size)
    );
    println!(
        "{WARMUP} warm-up frames, then {frames} timed frames per path; each frame waits for the device"
    );
    let camera = camera_at(args, &scene, 0.0);
    let mut naive_opts = Options::naive();
    naive_opts.shadow_size = args.shadow_size(size);
    naive_opts.overlay = !args.no_overlay;
    let mut opt = args.options(size);
    if args.naive {
        bail!("--bench measures both paths; leave out --naive");
    }
    opt.overlay = !args.no_overlay;
    let mut renderer = Renderer::new(&gpu, &scene, size, OUTPUT_FORMAT, naive_opts);
    let mut rows: Vec<(String, f64, FrameSummary)> = Vec::new();
    let mut scratch = Vec::new();
    // (--bench-paths key, label, options, degrees the lights turn per frame)
    let paths: [(&str, &str, Options, f32); 3] = [
        ("naive", "naive", naive_opts, 0.0),
        ("steady", "optimised, steady lights", opt, 0.0),
        (
            "turning",
            "optimised, lights turning",
            opt,
            args.bench_turn_deg,
        ),
    ];
    for (key, name, options, turn) in paths {
        if (key == "turning" && turn == 0.0) || !args.bench_paths.iter().any(|p| p == key) {
            continue;
        }
        renderer.set_options(options);
        renderer.set_lights(&set.lights);
        let mut times = Vec::with_capacity(frames as usize);
        let mut summary = FrameSummary::default();
        let mut cpu_start = None;
        for i in 0..WARMUP + frames {
            if turn != 0.0 {
                turned(&set.lights, turn * i as f32, &mut scratch);
                renderer.set_lights(&scratch);
            }
            if i == WARMUP {
                cpu_start = cpu_ms();
            }
            let t0 = Instant::now();
            let stats = renderer.render_headless(&camera, &Status::default());
            renderer.wait();
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            if i >= WARMUP {
                times.push(ms);
                summary.add(&stats);
            }
        }
        let cpu_per_frame = match (cpu_start, cpu_ms()) {
            (Some(a), Some(b)) => format!("{:.1} ms", (b - a) / frames as f64),
            _ => "n/a".into(),
        };
        let med = median(&mut times);
        println!(
            "{name:>26}: median {med:7.2} ms = {:6.2} frames/s  (min {:.2}, max {:.2} ms; CPU {cpu_per_frame}/frame; {:.1} shadow maps in use, {:.1} drawn per frame)",
            1e3 / med,
            times.first().copied().unwrap_or(f64::NAN),
            times.last().copied().unwrap_or(f64::NAN),
            summary.groups as f64 / summary.frames.max(1) as f64,
            summary.drawn as f64 / summary.frames.max(1) as f64,
        );
        rows.push((name.to_owned(), med, summary));
    }
    if let Some(naive) = rows.iter().find(|r| r.0 == "naive").map(|r| r.1) {
        for (name, med, _) in rows.iter().filter(|r| r.0 != "naive") {
            println!("speed-up, {name}: {:.2}x the naive path", naive / med);
        }
    }
    Ok(())
}

#[derive(Default, Clone, Copy)]
struct FrameSummary {
    frames: u32,
    groups: u64,
    drawn: u64,
}

impl FrameSummary {
    fn add(&mut self, s: &super::FrameStats) {
        self.frames += 1;
        self.groups += s.groups as u64;
        self.drawn += s.maps_drawn as u64;
    }
}
