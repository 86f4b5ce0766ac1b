//! A floating slab over a ground plane, lit by directional lights: the radiance of the ground in the
//! slab's shadows and in the open must be what DESIGN.md's diffuse formula predicts,
//! L = ρ/π · Σ_k E_k · max(0, n·l_k) · V_k, here with n = +Y and V_k ∈ {0, 1}.
//! Rendered headless through wgpu (lavapipe in CI); read back from the linear HDR target.
#![cfg(feature = "render")]

use glam::Vec3;
use std::f32::consts::PI;
use vemlight::lights::{Light, LightExtent};
use vemlight::render::gpu::Gpu;
use vemlight::render::overlay::Status;
use vemlight::render::scene::{Camera, Material, Scene};
use vemlight::render::{FrameStats, OUTPUT_FORMAT, Options, Renderer};

const SIZE: (u32, u32) = (320, 240);
const ALBEDO: f32 = 0.5;
/// Relative tolerance on radiances and ratios: the samples sit well inside the shadows and the open,
/// so PCF and the normal offset do not reach them, and the HDR target and G-buffer are floats; what
/// is left is float rounding (lavapipe: within 1e-6). 0.2 % leaves room for other drivers.
const TOLERANCE: f32 = 0.002;

fn scene() -> Scene {
    let mut s = Scene::default();
    // The slab floats from y = 1 to 1.2, so the shadow of a light straight above is visible.
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

fn light(id: u32, to_light: Vec3, e: f32) -> Light {
    Light {
        id,
        to_light: to_light.normalize().to_array(),
        irradiance: [e; 3],
        solid_angle: 0.01,
        angular_radius: 0.0,
        extent: None,
        shadowed: None,
    }
}

/// Renders the lights and returns the HDR radiance (red channel), the pixel of each world point
/// and the frame's stats.
fn render(lights: &[Light], points: &[Vec3]) -> (Vec<[f32; 4]>, Vec<(usize, usize)>, FrameStats) {
    let gpu = Gpu::new(Gpu::backends(None), &vemlight::render::TARGET_FORMATS)
        .expect("a graphics adapter (CI installs lavapipe)");
    let options = Options {
        exposure: Some(1.0),
        overlay: false,
        pcf_taps: 4,
        ..Options::optimised()
    };
    let mut r = Renderer::new(&gpu, &scene(), SIZE, OUTPUT_FORMAT, options);
    r.set_lights(lights);
    let stats = r.render_headless(&camera(), &Status::default());
    let view_proj = camera().view_proj(SIZE.0 as f32 / SIZE.1 as f32);
    let pixels = points
        .iter()
        .map(|&p| {
            let ndc = view_proj.project_point3(p);
            let x = ((ndc.x + 1.0) * 0.5 * SIZE.0 as f32) as usize;
            let y = ((1.0 - ndc.y) * 0.5 * SIZE.1 as f32) as usize;
            (x, y)
        })
        .collect();
    (r.read_hdr(), pixels, stats)
}

/// The radiance at the pixels of world points, with no check of the neighbourhood (for points
/// inside a penumbra).
fn raw_radiance_at(lights: &[Light], points: &[Vec3]) -> Vec<f32> {
    let (hdr, pixels, _) = render(lights, points);
    pixels
        .iter()
        .map(|&(x, y)| hdr[y * SIZE.0 as usize + x][0])
        .collect()
}

/// Renders and returns the HDR radiance (red channel) at the pixels of world points.
fn radiance_at(lights: &[Light], points: &[Vec3]) -> Vec<f32> {
    radiance_and_stats(lights, points).0
}

/// [`radiance_at`] and the frame's stats.
fn radiance_and_stats(lights: &[Light], points: &[Vec3]) -> (Vec<f32>, FrameStats) {
    let (hdr, pixels, stats) = render(lights, points);
    let values = pixels
        .iter()
        .zip(points)
        .map(|(&(x, y), p)| {
            // The 3 × 3 pixels around must agree (the point is not on an edge).
            let at = |x: usize, y: usize| hdr[y * SIZE.0 as usize + x][0];
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
fn one_light_straight_above_leaves_the_shadow_black_and_the_open_at_rho_over_pi_e() {
    let e = 3.0;
    let under = Vec3::new(0.0, 0.0, 0.0); // below the slab
    let open = Vec3::new(1.5, 0.0, 1.5);
    let l = radiance_at(&[light(0, Vec3::Y, e)], &[under, open]);
    let expected_open = ALBEDO / PI * e;
    println!(
        "shadow {} open {} (expected 0 and {expected_open})",
        l[0], l[1]
    );
    assert!(
        close(l[1], expected_open),
        "open ground {} vs ρ/π·E = {expected_open}",
        l[1]
    );
    // Shadowed / lit = 0 / (ρ/π·E): no light, and no ambient term.
    assert!(
        l[0] <= 1e-4 * expected_open,
        "shadow {} should be black",
        l[0]
    );
}

#[test]
fn a_second_light_at_60_degrees_gives_the_ratios_of_the_diffuse_formula() {
    // E1 straight above; E2 at 60° from the zenith toward +X, so n·l2 = cos 60° = 0.5. The slab's
    // shadow from light 2 falls 1.73–2.08 units toward −X (heights 1–1.2 × tan 60°).
    let (e1, e2) = (3.0, 2.0);
    let l2 = Vec3::new(60f32.to_radians().sin(), 60f32.to_radians().cos(), 0.0);
    let under = Vec3::new(0.0, 0.0, 0.0); // light 1 blocked
    let beside = Vec3::new(-1.9, 0.0, 0.0); // light 2 blocked
    let open = Vec3::new(1.5, 0.0, 1.5); // neither
    let l = radiance_at(
        &[light(0, Vec3::Y, e1), light(1, l2, e2)],
        &[under, beside, open],
    );
    let k = ALBEDO / PI;
    let (expect_under, expect_beside, expect_open) = (k * e2 * 0.5, k * e1, k * (e1 + e2 * 0.5));
    println!(
        "under {} beside {} open {}; expected {expect_under} {expect_beside} {expect_open}",
        l[0], l[1], l[2]
    );
    assert!(close(l[2], expect_open), "open {} vs {expect_open}", l[2]);
    // The ratios: (E2/2) / (E1 + E2/2) = 0.25 and E1 / (E1 + E2/2) = 0.75.
    assert!(close(l[0] / l[2], 0.25), "under/open = {}", l[0] / l[2]);
    assert!(close(l[1] / l[2], 0.75), "beside/open = {}", l[1] / l[2]);
}

/// ALGORITHMS.md §12 in the viewer: a light with an angular radius casts a penumbra about the
/// slab's edge (1 unit above the ground, so half a width of about tan(radius)), a point light a
/// hard edge; deep in the shadow and far in the open both stay as the formula says.
#[test]
fn a_light_with_an_angular_radius_casts_a_penumbra() {
    let e = 3.0;
    let open = ALBEDO / PI * e;
    // Across the slab's edge at x = 0.5, on the z = 0 line.
    let xs = [0.2f32, 0.44, 0.56, 0.9];
    let points: Vec<Vec3> = xs.iter().map(|&x| Vec3::new(x, 0.0, 0.0)).collect();
    let hard = raw_radiance_at(&[light(0, Vec3::Y, e)], &points);
    let mut soft_light = light(0, Vec3::Y, e);
    soft_light.angular_radius = 8f32.to_radians();
    let soft = raw_radiance_at(&[soft_light], &points);
    println!("hard {hard:?} soft {soft:?} open {open}");
    // Far from the edge: black under, open outside, for both.
    for v in [&hard, &soft] {
        assert!(v[0] <= 0.02 * open, "deep shadow {}", v[0]);
        assert!((v[3] - open).abs() <= 0.02 * open, "open {}", v[3]);
    }
    // Near the edge (0.06 from it, inside the soft light's penumbra of about ±0.14): the point
    // light's shadow is hard, the disc light's partial on both sides.
    assert!(
        hard[1] <= 0.05 * open && hard[2] >= 0.95 * open,
        "hard edge {hard:?}"
    );
    assert!(
        soft[1] >= 0.1 * open,
        "inside the penumbra, under the slab: {}",
        soft[1]
    );
    assert!(
        soft[2] <= 0.9 * open,
        "inside the penumbra, outside the slab: {}",
        soft[2]
    );
}

/// At every point x, `drawn` is the core's and the rest's one-disc renders mixed by the core's
/// share (the shading is linear in visibility), within the render's tolerance.
fn assert_mixed_by_share(
    xs: &[f32],
    drawn: &[f32],
    (core, rest): (&[f32], &[f32]),
    share: f32,
    open: f32,
) {
    for (i, x) in xs.iter().enumerate() {
        let expected = share * core[i] + (1.0 - share) * rest[i];
        assert!(
            (drawn[i] - expected).abs() <= TOLERANCE * open,
            "x = {x}: drawn {} vs {share}·core + {}·rest = {expected}",
            drawn[i],
            1.0 - share
        );
    }
}

/// ALGORITHMS.md §12, "Two-part extent", in the viewer: a light with a compact core and a wider
/// rest draws the core's share of the core disc's shadow plus the rest of the rest disc's, so at
/// every point across the slab's edge the render is the two one-disc renders mixed by the share
/// (the shading is linear in visibility), and not what its one `angular_radius` disc draws.
#[test]
fn a_two_part_extent_draws_its_two_discs_weighed_by_share() {
    let e = 3.0;
    let open = ALBEDO / PI * e;
    let xs = [0.2f32, 0.3, 0.4, 0.44, 0.48, 0.52, 0.56, 0.62, 0.7, 0.9];
    let points: Vec<Vec3> = xs.iter().map(|&x| Vec3::new(x, 0.0, 0.0)).collect();
    let (core_radius, rest_radius, share) = (0.5f32.to_radians(), 8f32.to_radians(), 0.6);
    let one_disc = |radius: f32| {
        let mut l = light(0, Vec3::Y, e);
        l.angular_radius = radius;
        raw_radiance_at(&[l], &points)
    };
    let (core, rest, median) = (
        one_disc(core_radius),
        one_disc(rest_radius),
        one_disc(3f32.to_radians()),
    );
    let mut two = light(0, Vec3::Y, e);
    two.angular_radius = 3f32.to_radians();
    two.extent = Some(LightExtent {
        core_share: share,
        core_radius,
        rest_radius,
        core_to_light: None,
    });
    let drawn = raw_radiance_at(&[two], &points);
    println!("core {core:?}\nrest {rest:?}\none disc {median:?}\ntwo-part {drawn:?}");
    assert_mixed_by_share(&xs, &drawn, (&core, &rest), share, open);
    // Where the core's hard edge and the rest's soft one differ, so does the two-part light
    // from its one disc.
    let apart = (0..xs.len())
        .map(|i| (drawn[i] - median[i]).abs())
        .fold(0.0f32, f32::max);
    assert!(
        apart >= 0.05 * open,
        "two-part vs one disc: at most {apart}"
    );
}

/// ALGORITHMS.md §12, "Two-part extent", in the viewer: a light whose core lies 2° aside of it
/// (a sun beside its glow) draws its shadow from the core's direction, so the slab's shadow edge
/// moves with the core (1.0 × tan 2° = 3.5 cm), while its shading stays the light's own: the
/// render is the two one-disc renders from the core's direction mixed by the share.
#[test]
fn a_two_part_extent_draws_its_shadow_from_its_cores_direction() {
    let e = 3.0;
    let open = ALBEDO / PI * e;
    let xs = [0.4f32, 0.44, 0.46, 0.48, 0.5, 0.52, 0.54, 0.58];
    let points: Vec<Vec3> = xs.iter().map(|&x| Vec3::new(x, 0.0, 0.0)).collect();
    let (core_radius, rest_radius, share) = (0.25f32.to_radians(), 4f32.to_radians(), 0.7);
    let aside = 2f32.to_radians();
    let core_dir = Vec3::new(aside.sin(), aside.cos(), 0.0);
    // From the core's direction, with the light's shading (n·l = 1 from +Y).
    let one_disc = |radius: f32| {
        let mut l = light(0, core_dir, e / aside.cos());
        l.angular_radius = radius;
        raw_radiance_at(&[l], &points)
    };
    let (core, rest) = (one_disc(core_radius), one_disc(rest_radius));
    let mut two = light(0, Vec3::Y, e);
    two.angular_radius = 1f32.to_radians();
    let extent = LightExtent {
        core_share: share,
        core_radius,
        rest_radius,
        core_to_light: None,
    };
    two.extent = Some(extent);
    let about_light = raw_radiance_at(&[two], &points);
    two.extent = Some(LightExtent {
        core_to_light: Some(core_dir.to_array()),
        ..extent
    });
    let drawn = raw_radiance_at(&[two], &points);
    println!("about the light {about_light:?}\ntoward the core {drawn:?}");
    assert_mixed_by_share(&xs, &drawn, (&core, &rest), share, open);
    // The edge moved: across it, the core's direction lights what the light's shades.
    let moved = (0..xs.len())
        .map(|i| drawn[i] - about_light[i])
        .fold(0.0f32, f32::max);
    assert!(moved >= 0.3 * open, "the edge moved by at most {moved}");
}

/// The shadow budget (`vemlight view --shadowed K`, docs/RENDER.md): of two lights, one marked
/// `shadowed` and one not, only the marked one gets a shadow map, so the ground in its shadow
/// loses exactly its share of the diffuse sum, while the unmarked light is drawn unoccluded
/// (V = 1) and the ground where its shadow would fall is as bright as the open ground.
#[test]
fn only_the_marked_light_casts_a_shadow() {
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
        Light {
            shadowed: Some(true),
            ..light(0, Vec3::Y, e1)
        },
        Light {
            shadowed: Some(false),
            ..light(1, l2, e2)
        },
    ];
    let (l, stats) = radiance_and_stats(&budget, &points);
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
    let (p, stats) = radiance_and_stats(&plain, &points);
    println!(
        "no marks: under {} beside {} open {}; {stats:?}",
        p[0], p[1], p[2]
    );
    assert!(close(p[2], expect_open), "open {} vs {expect_open}", p[2]);
    assert!(close(p[0] / p[2], 0.25), "under/open = {}", p[0] / p[2]);
    assert!(close(p[1] / p[2], 0.75), "beside/open = {}", p[1] / p[2]);
    assert_eq!(stats.groups, 2);
}
