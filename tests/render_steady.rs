//! A static scene under steady lights renders identical consecutive frames, whether the shadow maps
//! are redrawn every frame (naive) or reused (optimised), and the two paths agree closely.
#![cfg(feature = "render")]

use vemlight::render::gpu::Gpu;
use vemlight::render::overlay::Status;
use vemlight::render::scene::{Camera, Mesh, Scene};
use vemlight::render::view::source::lights_from_map;
use vemlight::render::{OUTPUT_FORMAT, Options, Renderer};

#[test]
fn consecutive_frames_of_a_steady_scene_are_identical() {
    let set = lights_from_map("tests/data/sunrise.exr".as_ref(), 72).unwrap();
    let scene = Scene::showcase(&Mesh::builtin_bunny());
    let camera = Camera::framing(&scene.bounds, 20.0);
    let gpu = Gpu::new(Gpu::backends(None), &vemlight::render::TARGET_FORMATS)
        .expect("a graphics adapter (CI installs lavapipe)");
    let mut frames = Vec::new();
    for options in [Options::naive(), Options::optimised()] {
        // No overlay: its status line counts the shadow maps drawn, which the first frame does.
        let options = Options {
            overlay: false,
            ..options
        };
        let mut r = Renderer::new(&gpu, &scene, (320, 240), OUTPUT_FORMAT, options);
        r.set_lights(&set.lights);
        let stats: Vec<_> = (0..3)
            .map(|_| {
                let s = r.render_headless(&camera, &Status::default());
                frames.push(r.read_rgba8().into_raw());
                s
            })
            .collect();
        println!("{options:?}: {stats:?}");
        let n = frames.len();
        for (a, b) in [(n - 3, n - 2), (n - 2, n - 1)] {
            let diff: Vec<usize> = (0..frames[a].len())
                .filter(|&i| frames[a][i] != frames[b][i])
                .collect();
            let first = diff.first().map(|i| (i / 4 % 320, i / 4 / 320));
            assert!(
                diff.is_empty(),
                "frames {a} and {b}: {} bytes differ, first at pixel {first:?}",
                diff.len()
            );
        }
        if options.reuse_deg.is_some() {
            assert!(
                stats[1].maps_drawn == 0 && stats[2].maps_drawn == 0,
                "maps were reused"
            );
        }
    }
    // Naive and optimised: the same lights, one shadow map per cluster instead of per light, and
    // culling and glossy refinement that are exact up to the 1 % lobe cut-off.
    let (a, b) = (&frames[0], &frames[3]);
    let differing = a.iter().zip(b).filter(|(x, y)| x.abs_diff(**y) > 8).count();
    let fraction = differing as f64 / a.len() as f64;
    println!(
        "naive vs optimised: {:.2} % of channels differ by more than 8/255",
        100.0 * fraction
    );
    assert!(fraction < 0.02, "{fraction}");
}
