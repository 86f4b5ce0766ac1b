//! `vemlight view --headless`: `--frames` frames to PNG files, with no window.
//!
//! Input: [`ViewArgs`] (the source, `--frames`, `--out`, `--size`). Output: `frame_0000.png`, …
//! in `--out`, and one line per frame on stderr (lights, shadow maps in use and drawn, time).

use super::adaptive::LightState;
use super::args::{ViewArgs, camera_at};
use crate::render::gpu::Gpu;
use crate::render::overlay::Status;
use crate::render::renderer::{OUTPUT_FORMAT, Renderer, TARGET_FORMATS};
use anyhow::Context;
use std::time::{Duration, Instant};

/// `--headless`: render `--frames` frames to PNGs.
pub(super) fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let size = args.size.unwrap_or((320, 240));
    let mut feed = args.feed()?;
    let scene = args.scene()?;
    let gpu = Gpu::new(Gpu::backends(args.backend), &TARGET_FORMATS)?;
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
        if let Some(line) = feed.drop_report() {
            eprintln!("vemlight view: {line}");
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
