//! The shadow budget in the viewer (`vemlight view --shadowed K`, docs/RENDER.md): a slab over a
//! ground plane lit by two directional lights, one marked `shadowed` and one not. The marked light
//! gets a shadow map, so the ground in its shadow loses exactly its share of DESIGN.md's diffuse
//! sum L = ρ/π · Σ_k E_k · max(0, n·l_k) · V_k; the unmarked light is drawn unoccluded (V = 1), so
//! the ground where its shadow would fall is as bright as the open ground. Rendered headless
//! (lavapipe in CI) and read back from the linear HDR target, at a small size to keep it quick.
#![cfg(feature = "render")]

use glam::Vec3;
use std::f32::consts::PI;
use vemlight::lights::Light;
use vemlight::render::gpu::Gpu;
use vemlight::render::overlay::Status;
use vemlight::render::scene::{Camera, Material, Scene};
use vemlight::render::{FrameStats, OUTPUT_FORMAT, Options, Renderer};

const SIZE: (u32, u32) = (160, 120);
const ALBEDO: f32 = 0.5;
/// Relative tolerance: the samples sit well inside the shadows and the open (PCF and the normal
/// offset do not reach them) and the targets are floats, as in render_shadow_ratio.rs.
const TOLERANCE: f32 = 0.002;

fn scene() -> Scene {
    let mut s = Scene::default();
    // The slab floats from y = 1 to 1.2 over the ground.
    s.add_box(
        Vec3::new(-0.5, 1.0, -0.5),
        Vec3::new(0.5, 1.2, 0.5),
        Material::diffuse([0.7; 3]),
    );
    s.add_ground(0.0, 4.0, Material::diffuse([ALBEDO; 3]));
    s
}

fn camera() -> Camera {
    Camera {
        eye: Vec3::new(0.0, 4.0, 6.0),
        target: Vec3::ZERO,
        fov_y: 50f32.to_radians(),
        near: 0.1,
        far: 30.0,
    }
}

fn light(id: u32, to_light: Vec3, e: f32, shadowed: Option<bool>) -> Light {
    Light {
        id,
        to_light: to_light.normalize().to_array(),
        irradiance: [e; 3],
        solid_angle: 0.01,
        angular_radius: 0.0,
        shadowed,
    }
}

/// Renders `lights` and returns the HDR radiance (red channel) at each world point (checking that
/// the pixels around agree, i.e. the point is not on a shadow's edge) and the frame's stats.
fn radiance_at(gpu: &Gpu, lights: &[Light], points: &[Vec3]) -> (Vec<f32>, FrameStats) {
    let options = Options {
        exposure: Some(1.0),
        overlay: false,
        pcf_taps: 4,
        ..Options::optimised()
    };
    let mut r = Renderer::new(gpu, &scene(), SIZE, OUTPUT_FORMAT, options);
    r.set_lights(lights);
    let stats = r.render_headless(&camera(), &Status::default());
    let hdr = r.read_hdr();
    let view_proj = camera().view_proj(SIZE.0 as f32 / SIZE.1 as f32);
    let at = |x: usize, y: usize| hdr[y * SIZE.0 as usize + x][0];
    let values = points
        .iter()
        .map(|&p| {
            let ndc = view_proj.project_point3(p);
            let x = ((ndc.x + 1.0) * 0.5 * SIZE.0 as f32) as usize;
            let y = ((1.0 - ndc.y) * 0.5 * SIZE.1 as f32) as usize;
            let c = at(x, y);
            for (dx, dy) in [(0, 1), (2, 1), (1, 0), (1, 2)] {
                let v = at(x + dx - 1, y + dy - 1);
                assert!(
                    (v - c).abs() <= TOLERANCE * c.max(1e-3),
                    "{p}: neighbour {v} vs {c}"
                );
            }
            c
        })
        .collect();
    (values, stats)
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= TOLERANCE * b.abs().max(1e-6)
}

#[test]
fn only_the_marked_light_casts_a_shadow() {
    let gpu = Gpu::new(Gpu::backends(None)).expect("a graphics adapter (CI installs lavapipe)");
    // Light 0 straight above (E1), light 1 at 60° from the zenith toward +X (E2, n·l = 0.5); the
    // slab's shadow from light 0 covers the origin, from light 1 the ground 1.73–2.08 toward −X.
    let (e1, e2) = (3.0, 2.0);
    let l2 = Vec3::new(60f32.to_radians().sin(), 60f32.to_radians().cos(), 0.0);
    let under = Vec3::new(0.0, 0.0, 0.0); // behind the slab for light 0
    let beside = Vec3::new(-1.9, 0.0, 0.0); // behind the slab for light 1
    let open = Vec3::new(1.5, 0.0, 1.5); // neither
    let points = [under, beside, open];
    let k = ALBEDO / PI;
    let expect_open = k * (e1 + 0.5 * e2);

    // The budget: light 0 shadowed, light 1 not.
    let budget = [
        light(0, Vec3::Y, e1, Some(true)),
        light(1, l2, e2, Some(false)),
    ];
    let (l, stats) = radiance_at(&gpu, &budget, &points);
    println!(
        "budget: under {} beside {} open {} (open expected {expect_open}); {stats:?}",
        l[0], l[1], l[2]
    );
    assert!(close(l[2], expect_open), "open {} vs {expect_open}", l[2]);
    // Behind the slab for the shadowed light: darker by its share, E1 / (E1 + E2/2) = 0.75.
    assert!(
        close(l[0] / l[2], 0.25),
        "under/open = {} (light 0's share is 0.75)",
        l[0] / l[2]
    );
    // Where the unshadowed light's shadow would fall: not darker at all.
    assert!(
        close(l[1] / l[2], 1.0),
        "beside/open = {}: the unmarked light must not be shadowed",
        l[1] / l[2]
    );
    assert_eq!(stats.lights, 2);
    assert_eq!(stats.groups, 1, "one shadow map in use: the marked light's");

    // The same lights without marks: both shadowed, as before the budget (beside/open = 0.75).
    let plain = budget.map(|l| Light {
        shadowed: None,
        ..l
    });
    let (p, stats) = radiance_at(&gpu, &plain, &points);
    println!(
        "no marks: under {} beside {} open {}; {stats:?}",
        p[0], p[1], p[2]
    );
    assert!(close(p[2], expect_open), "open {} vs {expect_open}", p[2]);
    assert!(close(p[0] / p[2], 0.25), "under/open = {}", p[0] / p[2]);
    assert!(close(p[1] / p[2], 0.75), "beside/open = {}", p[1] / p[2]);
    assert_eq!(stats.groups, 2);
}
