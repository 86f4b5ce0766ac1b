//! `vemlight view --bench`: frames/s of the naive and the optimised paths (steady and turning
//! lights) on the same scene, lights and device in one run (ALGORITHMS.md §6: each cost saver
//! against none).
//!
//! Input: [`ViewArgs`] (the source, `--frames`, `--size`, `--bench-paths`, `--bench-turn-deg`).
//! Output: a table on stdout, one row per path, and the speed-ups over the naive path. Each frame
//! waits for the device, so a row is the latency of a frame, not the throughput of a queue.

use super::args::{BenchPath, ViewArgs, camera_at};
use crate::lights::Light;
use crate::render::gpu::Gpu;
use crate::render::overlay::Status;
use crate::render::renderer::{FrameStats, OUTPUT_FORMAT, Options, Renderer, TARGET_FORMATS};
use crate::render::shading::MAX_LIGHTS;
use anyhow::bail;
use std::time::{Duration, Instant};

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
pub(super) fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let size = args.size.unwrap_or((320, 240));
    let mut feed = args.feed()?;
    let set = feed.wait_first(Duration::from_secs(10))?;
    let scene = args.scene()?;
    let gpu = Gpu::new(Gpu::backends(args.backend), &TARGET_FORMATS)?;
    let frames = args.frames.max(3);
    const WARMUP: u32 = 3;
    println!("vemlight view --bench");
    println!("device: {}", gpu.describe());
    if set.lights.len() > MAX_LIGHTS {
        bail!("at most {} lights", MAX_LIGHTS);
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
    let paths: [(BenchPath, &str, Options, f32); 3] = [
        (BenchPath::Naive, "naive", naive_opts, 0.0),
        (BenchPath::Steady, "optimised, steady lights", opt, 0.0),
        (
            BenchPath::Turning,
            "optimised, lights turning",
            opt,
            args.bench_turn_deg,
        ),
    ];
    for (key, name, options, turn) in paths {
        if (key == BenchPath::Turning && turn == 0.0) || !args.bench_paths.contains(&key) {
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
    fn add(&mut self, s: &FrameStats) {
        self.frames += 1;
        self.groups += s.groups as u64;
        self.drawn += s.maps_drawn as u64;
    }
}
