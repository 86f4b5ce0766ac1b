//! Convergence: renders of a real map with N = 8, 32, 128 lights approach the render with 1 024
//! lights, the error falling as N grows. Exact path (no clustering), so the error is the light
//! set's, not the renderer's shortcuts'.
#![cfg(feature = "render")]

use vemlight::render::gpu::Gpu;
use vemlight::render::overlay::Status;
use vemlight::render::scene::{Camera, Mesh, Scene};
use vemlight::render::view::source::lights_from_map;
use vemlight::render::{OUTPUT_FORMAT, Options, Renderer, auto_exposure};

const SIZE: (u32, u32) = (160, 120);

fn luminance(p: &[f32; 4]) -> f64 {
    0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64
}

#[test]
fn more_lights_converge_to_the_1024_light_render() {
    let map = "tests/data/city.exr";
    let scene = Scene::showcase(&Mesh::builtin_bunny());
    let camera = Camera::framing(&scene.bounds, 20.0);
    let gpu = Gpu::new(Gpu::backends(None), &vemlight::render::TARGET_FORMATS)
        .expect("a graphics adapter (CI installs lavapipe)");
    let reference_set = lights_from_map(map.as_ref(), 1024).unwrap();
    let options = Options {
        // Every light its own shadow map, all of them drawn: 1 024 layers of 256².
        shadow_size: 256,
        exposure: Some(auto_exposure(&reference_set.lights)),
        overlay: false,
        ..Options::naive()
    };
    let mut r = Renderer::new(&gpu, &scene, SIZE, OUTPUT_FORMAT, options);
    let mut render = |lights: &[vemlight::lights::Light]| {
        r.set_lights(lights);
        r.render_headless(&camera, &Status::default());
        r.read_hdr()
    };
    let reference = render(&reference_set.lights);
    let mut errors = Vec::new();
    for n in [8, 32, 128] {
        let image = render(&lights_from_map(map.as_ref(), n).unwrap().lights);
        // Relative RMS error of the luminance over the pixels that see the scene.
        let (mut num, mut den) = (0.0, 0.0);
        for (a, b) in image.iter().zip(&reference) {
            let (la, lb) = (luminance(a), luminance(b));
            num += (la - lb) * (la - lb);
            den += lb * lb;
        }
        let e = (num / den).sqrt();
        println!("N = {n:4}: relative RMS error against N = 1024: {e:.4}");
        errors.push(e);
    }
    assert!(errors[0] > errors[1] && errors[1] > errors[2], "{errors:?}");
    assert!(
        errors[2] < 0.1,
        "128 lights within 10 % RMS of 1 024: {errors:?}"
    );
}
