//! Light extraction on the real shared maps: energy, resampling, accuracy, directions, schema.

mod common;

use common::{MAPS, assert_valid, every_map, lightset_validator, load};
use glam::DVec3;
use vemlight::envmap::{EnvMap, Lens, Projection};
use vemlight::lights::error::{IrradianceReference, relative_error};
use vemlight::lights::{ExtractOptions, Extractor, FrameRequest, Light, Method, total_irradiance};
use vemlight::lightset::{LightRequest, lightset_for_map};
use vemlight::mapping::Domain;
use vemlight::sampling::Resampler;

const METHODS: [Method; 6] = Method::ALL;

/// One of the eval's synthetic hard skies (`vemlight::eval::scenes::hard_skies`) by name.
fn hard_sky(name: &str) -> EnvMap {
    vemlight::eval::scenes::hard_skies(1024)
        .into_iter()
        .find(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("no hard sky {name}"))
        .1
}

fn opts(lights: usize, domain: Domain, method: Method) -> ExtractOptions {
    ExtractOptions {
        lights,
        domain,
        method,
        side: None,
    }
}

/// The light carrying the most luminance.
fn brightest(lights: &[Light]) -> &Light {
    lights
        .iter()
        .max_by(|a, b| a.luminance().total_cmp(&b.luminance()))
        .expect("at least one light")
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-30)
}

/// The domain square's ∫L dω matches the input's within 0.5 % on every map.
#[test]
fn resampling_preserves_the_integral_on_every_map() {
    for name in MAPS {
        let map = load(name);
        for domain in [Domain::Upper, Domain::Sphere] {
            let truth = map.integral(domain);
            let img =
                Resampler::new(map.projection, map.width, map.height, domain, None).resample(&map);
            let got = img.integral();
            for c in 0..3 {
                assert!(
                    rel(got[c], truth[c]) < 5e-3,
                    "{name} {domain:?} channel {c}: {} vs {}",
                    got[c],
                    truth[c]
                );
            }
        }
    }
}

/// The streamed `sh9` (half-resolution square, basis at each texel's moment direction) against a
/// per-pixel projection of the source: within 1.5e-3 (relative L2 over the 27 coefficients; the
/// measured worst is 9.8e-4) on every shared map, and a worst case over the maps below that of
/// projecting the full square at texel centres (1.3e-2; figures in `sh::project_at_moments`).
#[test]
fn streamed_sh_matches_a_per_pixel_projection() {
    use vemlight::lights::sh;
    let mut worst = (0.0f64, 0.0f64);
    for name in MAPS {
        let map = load(name);
        let (w, h) = (map.width, map.height);
        let mut exact = [0.0f64; 27];
        for j in 0..h {
            for i in 0..w {
                let (d, sr) = map.projection.pixel(i, j, w, h).expect("lat-long");
                let y = sh::basis(d);
                let p = map.pixels[j * w + i];
                for k in 0..9 {
                    for c in 0..3 {
                        exact[3 * k + c] += p[c] as f64 * y[k] * sr;
                    }
                }
            }
        }
        let off = |c: &[f64]| {
            let e: f64 = c.iter().zip(&exact).map(|(a, b)| (a - b).powi(2)).sum();
            (e / exact.iter().map(|a| a * a).sum::<f64>()).sqrt()
        };
        let with_sh = |refine: usize| {
            let mut ex = Extractor::new();
            ex.set_refine(refine);
            let image = ex.resample(&map, Domain::Sphere, None);
            let frame = ex.extract_frame(
                &map,
                &image,
                &FrameRequest {
                    method: Method::Voronoi,
                    counts: &[64],
                    sh9: true,
                },
            );
            let sh9: Vec<f64> = frame.sh9.unwrap().iter().map(|&c| c as f64).collect();
            (image, sh9)
        };
        let (image, streamed) = with_sh(vemlight::lights::DEFAULT_REFINE);
        assert!(
            image.side.is_multiple_of(2),
            "{name}: the half-resolution path"
        );
        let centres = sh::project(&image);
        let (a, b) = (off(&streamed), off(&centres));
        assert!(a < 1.5e-3, "{name}: sh9 {a:.2e} off");
        worst = (worst.0.max(a), worst.1.max(b));
        // Made here when no Lloyd step made it: the same coefficients.
        let (_, again) = with_sh(0);
        assert_eq!(streamed, again, "{name}");
    }
    assert!(
        worst.0 < worst.1,
        "worst over the maps: sh9 {:.2e}, centres {:.2e}",
        worst.0,
        worst.1
    );
}

/// Energy conservation: Σ irradiance = ∫ L dω of the input (1e−4 relative), every method.
#[test]
fn energy_is_conserved_on_every_map_and_method() {
    let mut ex = Extractor::new();
    for name in MAPS {
        let map = load(name);
        for domain in [Domain::Upper, Domain::Sphere] {
            let truth = map.integral(domain);
            for method in METHODS {
                for n in [1, 7, 64, 256] {
                    let out = ex.extract(&map, &opts(n, domain, method));
                    let sum = total_irradiance(&out.lights);
                    for c in 0..3 {
                        assert!(
                            rel(sum[c], truth[c]) < 1e-4,
                            "{name} {domain:?} {method:?} N={n} channel {c}: {} vs {}",
                            sum[c],
                            truth[c]
                        );
                    }
                    for l in &out.lights {
                        let d = l.dir();
                        assert!((d.length() - 1.0).abs() < 1e-5, "{name}: light not unit");
                        assert!(
                            domain.contains(d) || d.y > -1e-5,
                            "{name}: light below horizon"
                        );
                        assert!(l.irradiance.iter().all(|c| c.is_finite() && *c >= 0.0));
                    }
                    if method.ids_are_stable() {
                        assert_eq!(out.lights.len(), n);
                        assert!(out.lights.iter().enumerate().all(|(k, l)| l.id == k as u32));
                    }
                }
            }
        }
    }
}

/// Diffuse irradiance error against brute force over the full-resolution map falls with N and is
/// ≤ 2 % at N = 64 on every map for the default method.
#[test]
fn default_method_error_falls_with_n_and_meets_two_percent_at_64() {
    let mut ex = Extractor::new();
    let mut report = Vec::new();
    for name in MAPS {
        let map = load(name);
        let domain = Domain::Sphere;
        let reference = IrradianceReference::from_map(&map, domain);
        let errors: Vec<f64> = [4, 16, 64, 256]
            .iter()
            .map(|&n| {
                let out = ex.extract(&map, &opts(n, domain, Method::Voronoi));
                reference.error(&out.lights).rel_rms
            })
            .collect();
        report.push(format!("{name}: {errors:.4?}"));
        assert!(errors[2] <= 0.02, "{name}: {errors:?}");
        assert!(
            errors[3] < errors[1] && errors[2] < errors[0],
            "{name}: error does not fall with N: {errors:?}"
        );
    }
    eprintln!("{}", report.join("\n"));
}

/// The default method beats the paper variant at 64 lights, in the median over maps (ALGORITHMS.md
/// §4 measured 0.9 % against 5.6 %).
#[test]
fn default_beats_paper_variant_at_64() {
    let mut ex = Extractor::new();
    let mut ratios = Vec::new();
    for name in MAPS {
        let map = load(name);
        let reference = IrradianceReference::from_map(&map, Domain::Sphere);
        let err = |ex: &mut Extractor, m| {
            let out = ex.extract(&map, &opts(64, Domain::Sphere, m));
            reference.error(&out.lights).rel_rms
        };
        let d = err(&mut ex, Method::Voronoi);
        let p = err(&mut ex, Method::Paper);
        let m = err(&mut ex, Method::MedianCut);
        eprintln!("{name}: N=64 voronoi {d:.4} paper {p:.4} median-cut {m:.4}");
        ratios.push(d / p);
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    assert!(median < 0.6, "default/paper error ratios {ratios:?}");
}

/// A single hot pixel at a known (u, v) gives a light pointing where DESIGN.md's lat-long convention
/// says, within one texel.
#[test]
fn hot_pixel_latlong_direction() {
    let (w, h) = (512, 256);
    let mut ex = Extractor::new();
    for &(i, j) in &[
        (384, 128),
        (0, 100),
        (511, 30),
        (200, 250),
        (256, 5),
        (100, 140),
    ] {
        let mut px = vec![[0.001f32; 3]; w * h];
        px[j * w + i] = [1.0e4, 2.0e4, 3.0e4];
        let map = EnvMap::from_pixels(w, h, px, Projection::LatLong).unwrap();
        // The convention, written out independently: θ = π v, φ = 2π(u − ½).
        let (u, v) = ((i as f64 + 0.5) / w as f64, (j as f64 + 0.5) / h as f64);
        let (theta, phi) = (
            std::f64::consts::PI * v,
            2.0 * std::f64::consts::PI * (u - 0.5),
        );
        let want = DVec3::new(
            theta.sin() * phi.sin(),
            theta.cos(),
            -theta.sin() * phi.cos(),
        );
        // One texel of the lat-long map in angle (the larger of its two sides).
        let texel = std::f64::consts::PI / h as f64;
        for method in METHODS {
            let out = ex.extract(&map, &opts(16, Domain::Sphere, method));
            let best = brightest(&out.lights);
            let angle = best.dir().dot(want).clamp(-1.0, 1.0).acos();
            // Median cut and Voronoi centre the light on the pixel's energy (first moment), so
            // they are within a source texel. The paper variant's light sits at a warped point: in
            // the domain square's hot texel, give or take the half row over which the continuous
            // warp blends neighbouring rows (ALGORITHMS.md §2), i.e. 1.5 domain texels.
            let domain_texel = (4.0 * std::f64::consts::PI).sqrt() / out.side as f64;
            // The inverse CDF has no density floor (pbrt-v3), so most of the 16 points land inside
            // the hot pixel itself: the lights' spherical cells become wedges around it, and the
            // brightest light's centroid takes in the dim background of its whole wedge. Near the
            // pole (pixel (200, 250)) that pulls it 0.73° away, just over one texel (0.70°): a
            // real weakness of the baseline, allowed two texels here and reported in
            // docs/EVALUATION.md.
            let tolerance = match method {
                Method::Paper => 1.5 * domain_texel,
                Method::InverseCdf => 2.0 * texel,
                _ => texel,
            };
            assert!(
                angle <= tolerance,
                "{method:?} pixel ({i},{j}): light {:?} is {:.3}° from {want}",
                best.to_light,
                angle.to_degrees()
            );
        }
    }
}

/// Fisheye input: a hot pixel at image top looks along −Z, at the right along +X.
#[test]
fn hot_pixel_fisheye_direction() {
    let (w, h) = (640, 480);
    let mut ex = Extractor::new();
    for lens in [Lens::Equidistant, Lens::Equisolid] {
        let proj = Projection::Fisheye {
            lens,
            fov_deg: 180.0,
            centre: None,
            radius: None,
        };
        for (i, j, want) in [
            (320usize, 60usize, DVec3::new(0.0, 0.0, -1.0)),
            (500, 240, DVec3::X),
            (320, 240, DVec3::Y),
        ] {
            let mut px = vec![[0.001f32; 3]; w * h];
            px[j * w + i] = [1.0e4; 3];
            let map = EnvMap::from_pixels(w, h, px, proj).unwrap();
            let (dir, _) = proj.pixel(i, j, w, h).unwrap();
            // The pixel's own direction, by the projection, must be on the expected side.
            assert!(
                dir.dot(want) > 0.5,
                "{lens:?}: pixel ({i},{j}) looks along {dir}"
            );
            let out = ex.extract(&map, &opts(16, Domain::Upper, Method::Voronoi));
            let best = brightest(&out.lights);
            let angle = best.dir().dot(dir).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(
                angle < 0.4,
                "{lens:?} ({i},{j}): {angle}° off (a pixel is 0.375°)"
            );
        }
    }
}

/// Every LightSet document produced for the shared maps validates against the schema.
#[test]
fn lightsets_validate_against_the_schema() {
    let validator = lightset_validator();
    let mut ex = Extractor::new();
    for name in MAPS {
        let map = load(name);
        for method in METHODS {
            let req = LightRequest {
                lights: 32,
                method,
                ..LightRequest::default()
            };
            let set = lightset_for_map(&mut ex, &map, &req, name);
            let doc = serde_json::to_value(&set).unwrap();
            assert_valid(&validator, &doc);
        }
    }
}

/// `max_error` picks the fewest lights meeting the target: n lights meet it, n − 1 do not, and
/// n is at most the smallest power of two that meets it (what the ladder alone gave).
#[test]
fn max_error_picks_the_fewest_lights_meeting_the_target() {
    let mut ex = Extractor::new();
    for (name, target) in [
        ("sunrise.exr", 0.01),
        ("overcast-plaza.exr", 0.01),
        ("interior.exr", 0.005),
    ] {
        let map = load(name);
        let req = LightRequest {
            lights: 1024,
            max_error: Some(target),
            ..LightRequest::default()
        };
        let set = lightset_for_map(&mut ex, &map, &req, name);
        let n = set.lights.len();
        assert_eq!(set.diagnostics.max_error_met, Some(true), "{name}");
        let error = set.diagnostics.estimated_error.unwrap();
        assert!(error <= target, "{name}: {error} at {n}");
        let mut error_at = |lights: usize| {
            let req = LightRequest {
                lights,
                max_error: None,
                ..LightRequest::default()
            };
            let s = lightset_for_map(&mut ex, &map, &req, name);
            assert_eq!(s.lights.len(), lights, "{name}");
            s.diagnostics.estimated_error.unwrap()
        };
        // The same lights as asking for n outright.
        assert_eq!(error_at(n), error, "{name}");
        if n > 1 {
            let fewer = error_at(n - 1);
            assert!(
                fewer > target,
                "{name}: {} lights would have done ({fewer})",
                n - 1
            );
        }
        let power = n.next_power_of_two();
        assert!(error_at(power) <= target, "{name}: the ladder's {power}");
        if power > 1 {
            assert!(error_at(power / 2) > target, "{name}: {}", power / 2);
        }
        eprintln!("{name}: {n} lights meet {target} ({error:.5}), the ladder gave {power}");
    }
}

/// The cheap error estimate behind `max_error` and `diagnostics.estimated_error` (a 64×64 binning
/// of the domain square) tracks the brute-force error over every pixel on every shared map. It
/// cannot be closer than the bins' own error ε = ‖T_b − T‖/‖T‖ (their irradiance T_b against the
/// brute force T): by the triangle inequality the estimate lies within ε(1 + e)/(1 − ε) of the
/// exact error e, at every N (measured ε: 1–5·10⁻⁴, beside errors of 0.03–1.9 %). (With bins at
/// texel centres instead of the texels' first moments it was 28 % high on sunrise.exr at 64
/// lights: the sun moved to a texel centre.)
#[test]
fn estimated_error_tracks_the_brute_force_error() {
    let mut ex = Extractor::new();
    for name in MAPS {
        let map = load(name);
        let truth = IrradianceReference::from_map(&map, Domain::Sphere);
        let bins = IrradianceReference::from_domain_image(&ex.resample(&map, Domain::Sphere, None));
        let eps = relative_error(bins.truth(), truth.truth()).rel_rms;
        assert!(eps < 0.01, "{name}: the bins' own error {eps:.5}");
        for n in [16, 64, 256] {
            let req = LightRequest {
                lights: n,
                domain: Some(Domain::Sphere),
                estimate_error: true,
                ..LightRequest::default()
            };
            let set = lightset_for_map(&mut ex, &map, &req, name);
            let estimate = set.diagnostics.estimated_error.unwrap();
            let exact = truth.error(&set.lights).rel_rms;
            let bound = eps * (1.0 + exact) / (1.0 - eps) + 1e-7;
            assert!(
                (estimate - exact).abs() <= bound,
                "{name} N={n}: estimate {estimate:.5}, brute force {exact:.5}, bound {bound:.5}"
            );
            eprintln!(
                "{name} N={n}: estimate {estimate:.5}, brute force {exact:.5}, bins' own {eps:.5}"
            );
        }
    }
}

/// An all-black map gives a valid LightSet with zero energy and no NaN.
#[test]
fn black_map_gives_zero_energy_and_no_nan() {
    let validator = lightset_validator();
    let map = EnvMap::from_pixels(64, 32, vec![[0.0; 3]; 64 * 32], Projection::LatLong).unwrap();
    let mut ex = Extractor::new();
    for method in METHODS {
        let req = LightRequest {
            lights: 16,
            method,
            ..LightRequest::default()
        };
        let set = lightset_for_map(&mut ex, &map, &req, "black");
        assert_eq!(set.total_irradiance, [0.0; 3]);
        assert!(set.primary.is_none());
        let doc = serde_json::to_value(&set).unwrap();
        assert!(!doc.to_string().contains("null,") || set.primary.is_none());
        assert_valid(&validator, &doc);
        assert_eq!(set.diagnostics.estimated_error, Some(0.0));
    }
}

/// NaN, infinite and negative pixels are clamped, counted, and never reach the output.
#[test]
fn bad_pixels_are_clamped_and_counted() {
    let map = load("cumulus-sky-f16.exr");
    assert!(
        map.repairs.negative_pixels > 0,
        "this map has lossy negative ringing"
    );
    let (w, h) = (64, 32);
    let mut px = vec![[1.0f32; 3]; w * h];
    px[5] = [f32::NAN, 1.0, 1.0];
    px[6] = [f32::INFINITY, 1.0, 1.0];
    px[7] = [-5.0, 1.0, 1.0];
    let map = EnvMap::from_pixels(w, h, px, Projection::LatLong).unwrap();
    assert_eq!(map.repairs.clamped_pixels(), 3);
    let set = lightset_for_map(&mut Extractor::new(), &map, &LightRequest::default(), "bad");
    assert_eq!(set.diagnostics.clamped_pixels, 3);
    assert!(set.total_irradiance.iter().all(|c| c.is_finite()));

    // A frame of huge finite values (a corrupt camera frame): before the clamp its sums
    // overflowed to infinity and the document carried nulls. For every method, every light
    // and the totals are finite, and the document is valid.
    let px = vec![[3e38f32, 3e38, 3e38]; w * h];
    let map = EnvMap::from_pixels(w, h, px, Projection::LatLong).unwrap();
    assert_eq!(map.repairs.overbright_pixels, (w * h) as u64);
    let validator = lightset_validator();
    for method in METHODS {
        let req = LightRequest {
            method,
            ..LightRequest::default()
        };
        let set = lightset_for_map(&mut Extractor::new(), &map, &req, "overbright");
        assert_eq!(set.diagnostics.overbright_pixels, (w * h) as u64);
        let doc = serde_json::to_value(&set).unwrap();
        assert_valid(&validator, &doc);
        let e = set.total_irradiance[1];
        assert!(e.is_finite() && e > 0.0, "{method:?}: total irradiance {e}");
        for l in &set.lights {
            assert!(
                l.irradiance.iter().all(|c| c.is_finite()),
                "{method:?}: {l:?}"
            );
        }
    }
}

/// Several light counts from one pass give exactly what separate extractions give.
#[test]
fn extract_many_matches_separate_extractions() {
    let map = load("city.exr");
    for method in METHODS {
        let mut shared = Extractor::new();
        let many = shared.extract_many(&map, Domain::Sphere, method, &[8, 64, 16]);
        for (ex, n) in many.iter().zip([8, 64, 16]) {
            let alone = Extractor::new().extract(&map, &opts(n, Domain::Sphere, method));
            assert_eq!(ex.lights, alone.lights, "{method:?} N={n}");
        }
    }
}

/// Extra Lloyd steps keep energy exact and lower the diffuse error on every map.
#[test]
fn refinement_steps_lower_the_error_and_keep_energy() {
    for name in ["sunrise.exr", "interior.exr", "overcast-plaza.exr"] {
        let map = load(name);
        let reference = IrradianceReference::from_map(&map, Domain::Sphere);
        let truth = map.integral(Domain::Sphere);
        let errors: Vec<f64> = [0, 2]
            .iter()
            .map(|&steps| {
                let mut ex = Extractor::new();
                ex.set_refine(steps);
                let out = ex.extract(&map, &opts(64, Domain::Sphere, Method::Voronoi));
                let sum = total_irradiance(&out.lights);
                for c in 0..3 {
                    assert!(
                        rel(sum[c], truth[c]) < 1e-4,
                        "{name}: energy with {steps} steps"
                    );
                }
                reference.error(&out.lights).rel_rms
            })
            .collect();
        assert!(errors[1] < errors[0], "{name}: {errors:?}");
    }
}

/// Fisheye input (methods defined on lat-long maps read a lat-long view of the domain square):
/// energy is still exact for every method.
#[test]
fn energy_is_conserved_for_fisheye_input() {
    let fisheye = load("city.exr").reproject(
        Projection::Fisheye {
            lens: Lens::Equisolid,
            fov_deg: 185.0,
            centre: None,
            radius: None,
        },
        400,
        300,
    );
    let mut ex = Extractor::new();
    for domain in [Domain::Upper, Domain::Sphere] {
        let truth = fisheye.integral(domain);
        for method in METHODS {
            let out = ex.extract(&fisheye, &opts(32, domain, method));
            let sum = total_irradiance(&out.lights);
            for c in 0..3 {
                assert!(
                    rel(sum[c], truth[c]) < 1e-4,
                    "{domain:?} {method:?} channel {c}: {} vs {}",
                    sum[c],
                    truth[c]
                );
            }
        }
    }
}

/// Every light carries energy, and N lights asked for are N distinct lights, on every
/// map (the sunny skies are where seeds used to pile onto the sun and leave lights dead), every
/// count and both domains.
#[test]
fn every_light_carries_energy_on_every_map_and_count() {
    let mut ex = Extractor::new();
    for (name, map) in every_map() {
        for domain in [Domain::Sphere, Domain::Upper] {
            for n in [1, 7, 16, 64, 256, 1024] {
                let out = ex.extract(&map, &opts(n, domain, Method::Voronoi));
                assert_eq!(out.lights.len(), n, "{name} {domain:?} N={n}");
                let dead: Vec<u32> = out
                    .lights
                    .iter()
                    .filter(|l| !l.carries_energy())
                    .map(|l| l.id)
                    .collect();
                assert!(
                    dead.is_empty(),
                    "{name} {domain:?} N={n}: dead lights {dead:?}"
                );
                let mut dirs: Vec<[u32; 3]> = out
                    .lights
                    .iter()
                    .map(|l| l.to_light.map(f32::to_bits))
                    .collect();
                dirs.sort();
                dirs.dedup();
                assert_eq!(dirs.len(), n, "{name} {domain:?} N={n}: coincident lights");
            }
        }
    }
}

/// A map with fewer lit texels than lights asked for gives fewer lights, and says so.
#[test]
fn a_map_with_few_lit_texels_gives_fewer_lights_and_says_so() {
    let (w, h) = (256, 128);
    let mut pixels = vec![[0.0f32; 3]; w * h];
    for &(i, j) in &[(10, 20), (100, 40), (200, 90)] {
        pixels[j * w + i] = [50.0; 3];
    }
    let map = EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap();
    let mut ex = Extractor::new();
    let req = LightRequest {
        lights: 16,
        ..LightRequest::default()
    };
    let set = lightset_for_map(&mut ex, &map, &req, "test");
    assert!(set.lights.iter().all(|l| l.carries_energy()));
    assert!(
        (3..16).contains(&set.lights.len()),
        "{} lights",
        set.lights.len()
    );
    assert_eq!(
        set.diagnostics.lights_short,
        Some(16 - set.lights.len()),
        "{:?}",
        set.diagnostics
    );
    let sum = total_irradiance(&set.lights);
    let truth = map.integral(Domain::Sphere);
    assert!(rel(sum[0], truth[0]) < 1e-4);
}

/// The default's diffuse error is at most median cut's on every map of tests/data at
/// every N from 16 to 256 (per map, not in the median), at the powers of two and between them.
#[test]
fn default_diffuse_is_at_most_median_cuts_on_every_map() {
    let mut ex = Extractor::new();
    let mut report = Vec::new();
    for name in MAPS {
        let map = load(name);
        let reference = IrradianceReference::from_map(&map, Domain::Sphere);
        for n in [16, 24, 32, 48, 64, 96, 128, 192, 256] {
            let err = |ex: &mut Extractor, m| {
                reference
                    .error(&ex.extract(&map, &opts(n, Domain::Sphere, m)).lights)
                    .rel_rms
            };
            let (v, mc) = (
                err(&mut ex, Method::Voronoi),
                err(&mut ex, Method::MedianCut),
            );
            report.push(format!("{name} N={n}: {v:.5} vs median cut {mc:.5}"));
            assert!(v <= mc, "{name} N={n}: default {v} > median cut {mc}");
        }
    }
    eprintln!("{}", report.join("\n"));
}

/// ALGORITHMS.md §12: a uniform disc of known radius gives a light of about that radius (the
/// uniform disc is the model the radius is defined by), centred on the disc, and a sub-texel sun
/// (the synthetic sky's 0.265°) keeps its own scale although the domain's texel is about 1°.
#[test]
fn a_disc_source_gives_a_light_of_its_radius() {
    let (w, h) = (1024, 512);
    let centre = DVec3::new(0.2, 0.7, -0.5).normalize();
    for radius_deg in [3.0f64, 8.0] {
        let r = radius_deg.to_radians();
        let mut pixels = vec![[0.01f32; 3]; w * h];
        for j in 0..h {
            for i in 0..w {
                let (d, _) = Projection::LatLong.pixel(i, j, w, h).unwrap();
                if d.dot(centre) >= r.cos() {
                    pixels[j * w + i] = [200.0; 3];
                }
            }
        }
        let map = EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap();
        // One light: its cell is the whole sphere, its core the disc (the dim background is
        // under a quarter of the disc's radiance).
        let out = Extractor::new().extract(&map, &opts(1, Domain::Sphere, Method::Voronoi));
        let light = brightest(&out.lights);
        let got = (light.angular_radius as f64).to_degrees();
        assert!(
            (got - radius_deg).abs() < 0.15 * radius_deg,
            "disc of {radius_deg}°: light radius {got}°"
        );
        assert!(light.dir().angle_between(centre).to_degrees() < 0.2);
    }
    let sky = hard_sky("sky-high-clear");
    for n in [16, 64, 256] {
        let out = Extractor::new().extract(&sky, &opts(n, Domain::Sphere, Method::Voronoi));
        let sun = brightest(&out.lights);
        let got = (sun.angular_radius as f64).to_degrees();
        assert!(
            (0.15..0.6).contains(&got),
            "N={n}: the sun's light has radius {got}° (the sun's is 0.265°)"
        );
    }
}

/// Uniform discs about `centre`: the sun (radius `sun_r`) holds 30 % of the light, the glare
/// around it (the rest of its `glare_r` disc) 70 %, and the background nothing.
fn sun_in_glare(centre: DVec3, sun_r: f64, glare_r: f64) -> EnvMap {
    let (sun_sr, glare_sr) = (
        std::f64::consts::TAU * (1.0 - sun_r.cos()),
        std::f64::consts::TAU * (sun_r.cos() - glare_r.cos()),
    );
    let (sun_l, glare_l) = ((0.3 / sun_sr) as f32, (0.7 / glare_sr) as f32);
    vemlight::eval::scenes::LatLongDirs::new(1024, 512).map(|d| {
        let c = d.dot(centre);
        if c >= sun_r.cos() {
            [sun_l; 3]
        } else if c >= glare_r.cos() {
            [glare_l; 3]
        } else {
            [0.0; 3]
        }
    })
}

/// ALGORITHMS.md §12, "Core and rest": a sun in a glare that holds most of its light (a sun
/// through haze or leaves) gives a light whose disc has the pair's half-energy radius, not the
/// sun's own: evaluated as the sun's 0.5° disc, its shadow would be hard where the true one is
/// mostly the glare's soft one (a held-out sunny park at 16 lights: 1.19 × median cut's shadowed
/// error with the core's radius, 0.96 × with this one).
#[test]
fn a_sun_in_a_bright_glare_gives_the_half_energy_disc() {
    let centre = DVec3::new(-0.3, 0.6, 0.4).normalize();
    let (sun_r, glare_r) = (0.5f64.to_radians(), 4f64.to_radians());
    let map = sun_in_glare(centre, sun_r, glare_r);
    // The half-energy radius ρ of the pair: 0.3 + 0.7·(ρ² − r_s²)/(r_g² − r_s²) = ½; the disc
    // with that median has radius √2·ρ (about 3.0°).
    let rho = (sun_r.powi(2) + (0.2 / 0.7) * (glare_r.powi(2) - sun_r.powi(2))).sqrt();
    let expected = (std::f64::consts::SQRT_2 * rho).to_degrees();
    let out = Extractor::new().extract(&map, &opts(1, Domain::Sphere, Method::Voronoi));
    let light = &out.lights[0];
    let got = (light.angular_radius as f64).to_degrees();
    assert!(
        (got - expected).abs() < 0.15 * expected,
        "sun in glare: light radius {got}°, the half-energy disc's {expected}°"
    );
    assert!(light.dir().angle_between(centre).to_degrees() < 0.2);
}

/// ALGORITHMS.md §12, "Two-part extent": the same sun in its glare gives a light whose extent
/// is the sun's disc with its share and the glare's disc with the rest, and the shadow drawn from
/// the two discs is nearer the map's own (the evaluation's ground probes, §9) than the one disc
/// of the half-energy radius, which draws neither the sun's hard shadow nor the glare's soft one.
#[test]
fn a_sun_in_a_bright_glare_gets_a_two_part_extent() {
    use vemlight::eval::accuracy::Truth;
    let centre = DVec3::new(-0.3, 0.6, 0.4).normalize();
    let (sun_r, glare_r) = (0.5f64.to_radians(), 4f64.to_radians());
    let map = sun_in_glare(centre, sun_r, glare_r);
    let out = Extractor::new().extract(&map, &opts(1, Domain::Sphere, Method::Voronoi));
    let light = out.lights[0];
    let extent = light
        .extent
        .expect("a sun in a glare has a two-part extent");
    // The glare's annulus holds half its light within ρ² = r_s² + ½(r_g² − r_s²); its disc is
    // √2·ρ. The texels (about 0.7° here) blur the sun's disc and the annulus's inner edge.
    let rest = (sun_r.powi(2) + glare_r.powi(2)).sqrt().to_degrees();
    let (share, core, got_rest) = (
        f64::from(extent.core_share),
        f64::from(extent.core_radius).to_degrees(),
        f64::from(extent.rest_radius).to_degrees(),
    );
    eprintln!("core {share:.3} of the light in {core:.3}°, the rest in {got_rest:.3}°");
    assert!(
        (share - 0.3).abs() < 0.1,
        "core share {share}, the sun's 0.3"
    );
    assert!(core < 1.0, "core radius {core}°, the sun's 0.5°");
    assert!(
        (got_rest - rest).abs() < 0.15 * rest,
        "rest radius {got_rest}°, the glare's {rest:.2}°"
    );
    let truth = Truth::new(&map, Domain::Sphere);
    let one_disc = Light {
        extent: None,
        ..light
    };
    let (two, one) = (
        truth.shadowed_mean(&[light]),
        truth.shadowed_mean(&[one_disc]),
    );
    eprintln!("shadowed error: two-part extent {two:.4}, one disc {one:.4}");
    assert!(two < 0.7 * one, "two-part extent {two}, one disc {one}");
}

/// ALGORITHMS.md §12, "Two-part extent": a sun (60 %) in a glare off to one side (a 4° disc
/// centred 3° away, 40 %) gives one light at the pair's centroid, aside of the sun, whose
/// extent's core points at the sun itself, so that the sun's hard shadow is drawn where it falls.
#[test]
fn a_suns_core_keeps_its_own_direction_beside_a_lopsided_glare() {
    let sun = DVec3::new(-0.3, 0.6, 0.4).normalize();
    let glare =
        glam::DQuat::from_axis_angle(DVec3::Y, 3f64.to_radians() / (1.0 - sun.y * sun.y).sqrt())
            * sun;
    let (sun_r, glare_r) = (0.5f64.to_radians(), 4f64.to_radians());
    let (sun_sr, glare_sr) = (
        std::f64::consts::TAU * (1.0 - sun_r.cos()),
        std::f64::consts::TAU * (1.0 - glare_r.cos()),
    );
    let (sun_l, glare_l) = ((0.6 / sun_sr) as f32, (0.4 / glare_sr) as f32);
    let map = vemlight::eval::scenes::LatLongDirs::new(1024, 512).map(|d| {
        if d.dot(sun) >= sun_r.cos() {
            [sun_l; 3]
        } else if d.dot(glare) >= glare_r.cos() {
            [glare_l; 3]
        } else {
            [0.0; 3]
        }
    });
    let out = Extractor::new().extract(&map, &opts(1, Domain::Sphere, Method::Voronoi));
    let light = out.lights[0];
    let core = light
        .extent
        .and_then(|e| e.core_to_light)
        .expect("a sun in a wider glare has a two-part extent with the core's direction");
    let core = DVec3::from_array(core.map(f64::from));
    let (aside, off) = (
        light.dir().angle_between(sun).to_degrees(),
        core.angle_between(sun).to_degrees(),
    );
    eprintln!("the light {aside:.3}° from the sun, its core {off:.3}°");
    assert!(
        aside > 0.5,
        "the light {aside}° from the sun: the glare pulls it aside"
    );
    assert!(off < 0.2, "the core {off}° from the sun");
}

/// ALGORITHMS.md §12, "Core and rest" in a stream: city.exr's sun (0.53°, in texels of about
/// 1°) turning 0.25° a frame slides across the texels, its share of each of the 2 × 2 it lies on
/// changing frame by frame. The stream's brightest light keeps its two-part extent (the glow's
/// soft shadow beside the sun's hard one) on every frame, with its core's share steady. With a
/// quarter of the peak as the core's threshold (a single map's), the sun's spill into a texel
/// under it fell into the rest on frames 0, 4 and 7: the share went 0.62–0.88, the rest's
/// half-energy radius collapsed onto the spill (0.7° against 3–7.5°), and the extent was gone.
#[test]
fn a_streams_sun_keeps_its_two_part_extent_as_it_crosses_the_texels() {
    use glam::DQuat;
    use vemlight::eval::scenes::LatLongDirs;
    let map = load("city.exr");
    let dirs = LatLongDirs::new(map.width, map.height);
    let mut ex = Extractor::new();
    ex.set_video(true);
    let mut shares = Vec::new();
    for t in 0..9 {
        let frame = dirs.rotated(&map, DQuat::from_rotation_y((0.25 * t as f64).to_radians()));
        let lights = ex
            .extract(&frame, &opts(64, Domain::Sphere, Method::Voronoi))
            .lights;
        let sun = brightest(&lights);
        let extent = sun
            .extent
            .unwrap_or_else(|| panic!("frame {t}: the sun's light lost its two-part extent"));
        assert!(
            extent.rest_radius >= 4.0 * extent.core_radius,
            "frame {t}: the rest's disc {}° beside the core's {}°",
            extent.rest_radius.to_degrees(),
            extent.core_radius.to_degrees()
        );
        shares.push(f64::from(extent.core_share));
    }
    let (lo, hi) = shares
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &s| (lo.min(s), hi.max(s)));
    eprintln!("the core's share {lo:.3}–{hi:.3} over 9 frames");
    assert!(hi - lo < 0.1, "the core's share swung {lo:.3}–{hi:.3}");
}

/// ALGORITHMS.md §12, "Core and rest": the rest of a cell is binned by angle, so the sky that a
/// sun's cell also holds far from the sun does not widen its disc. A 0.27° sun (35 %) in a 2°
/// glare (60 %) over a dim sky, at 16 lights: the sun's cell holds about a tenth of its light in
/// sky tens of degrees away, and the light's disc stays inside the glare (the rest taken as one
/// disc of its RMS spread, the rule before, gave a 2° glare's light 4.3° with 3 % of sky). The
/// sky does move the cell's true median out: uniform sun and glare put it 17 % farther with this
/// sky than with one a hundred times dimmer; the disc may move by half.
#[test]
fn far_sky_in_a_suns_cell_does_not_widen_its_disc() {
    use vemlight::eval::scenes::LatLongDirs;
    let centre = DVec3::new(0.4, 0.7, -0.3).normalize();
    let (sun_r, glare_r) = (0.27f64.to_radians(), 2f64.to_radians());
    let cap = |r: f64| std::f64::consts::TAU * (1.0 - r.cos());
    let (sun_l, glare_l) = (0.35 / cap(sun_r), 0.6 / (cap(glare_r) - cap(sun_r)));
    let radius = |sky: f64| {
        let sky_l = sky / (4.0 * std::f64::consts::PI);
        let map = LatLongDirs::new(1024, 512).map(|d| {
            let c = d.dot(centre);
            let y = sky_l
                + if c >= sun_r.cos() {
                    sun_l
                } else if c >= glare_r.cos() {
                    glare_l
                } else {
                    0.0
                };
            [y as f32; 3]
        });
        let out = Extractor::new().extract(&map, &opts(16, Domain::Sphere, Method::Voronoi));
        let light = brightest(&out.lights);
        let total: f64 = out.lights.iter().map(|l| l.luminance()).sum();
        (
            (light.angular_radius as f64).to_degrees(),
            light.luminance() / total,
        )
    };
    // The whole sky as bright as sun and glare together, and a hundredth of that.
    let ((with_sky, share), (alone, _)) = (radius(0.95), radius(0.0095));
    assert!(
        with_sky < glare_r.to_degrees() && (with_sky / alone - 1.0).abs() < 0.5,
        "sun in glare: radius {with_sky}° over a sky (the light holds {share:.3} of the map), \
         {alone}° over a dim one"
    );
}

/// ALGORITHMS.md §4.2, "Core azimuth": a 60° sun through haze and cloud, whose cell at 16 lights
/// also holds a few per cent of the sky beside it, gets a light on the sun's azimuth; at its
/// cell's centroid (the turn off) that light sits 0.1–0.2° to the side, a third of the sun's disc,
/// and its shadow with it. The turn keeps the elevation, so the floor it gives is unchanged.
#[test]
fn a_suns_light_lies_on_the_suns_azimuth() {
    let mut sky = vemlight::eval::scenes::still_sky_model(1024, 60.0, 9.0, 0.3);
    let map = sky.render(0.0);
    let sun = sky.sun_direction(0.0);
    // The angle between two directions' azimuths, as an arc at the sun's elevation (degrees).
    let across = |d: DVec3| {
        let h = |v: DVec3| DVec3::new(v.x, 0.0, v.z).normalize();
        h(d).angle_between(h(sun)).to_degrees() * sun.y.asin().cos()
    };
    let light = |turn: bool| {
        let mut ex = Extractor::new();
        ex.set_core_azimuth(turn);
        *brightest(
            &ex.extract(&map, &opts(16, Domain::Sphere, Method::Voronoi))
                .lights,
        )
    };
    let (turned, centroid) = (light(true), light(false));
    assert!(
        across(turned.dir()) < 0.03 && across(centroid.dir()) > 0.1,
        "the sun's light is {:.3}° across from the sun's azimuth, {:.3}° at its cell's centroid",
        across(turned.dir()),
        across(centroid.dir())
    );
    assert!(
        (turned.to_light[1] - centroid.to_light[1]).abs() < 1e-6
            && turned.luminance() == centroid.luminance(),
        "the turn keeps the elevation and the energy: y {} against {}",
        turned.to_light[1],
        centroid.to_light[1]
    );
}

/// ALGORITHMS.md §12, "Core aside": a 35° sun through haze and cloud, turned 37° about the
/// vertical, at 16 lights. Its cell holds 7 % of its light in sky spread over tens of degrees,
/// which pulls the cell's centroid, and a light there, farther off the sun than the sun's core is
/// wide; the core split off gives the sun a light of its own within the sun's disc, and the
/// energy is kept.
#[test]
fn a_sun_aside_of_its_cells_centroid_gets_a_light_of_its_own() {
    let still = vemlight::eval::scenes::still_sky_model(1024, 35.0, 9.0, 0.7).render(0.0);
    let turn = glam::DQuat::from_rotation_y(37f64.to_radians());
    let map =
        vemlight::eval::scenes::LatLongDirs::new(still.width, still.height).rotated(&still, turn);
    // The sun as the map draws it: the centroid of the pixels of at least a quarter of the
    // brightest (the sun's disc, 0.27° in radius).
    let peak = map
        .pixels
        .iter()
        .map(|&p| EnvMap::luminance(p))
        .fold(0.0, f32::max);
    let mut sun = DVec3::ZERO;
    for j in 0..map.height {
        for i in 0..map.width {
            let y = EnvMap::luminance(map.pixels[j * map.width + i]);
            if y >= 0.25 * peak {
                let (d, sr) = map.projection.pixel(i, j, map.width, map.height).unwrap();
                sun += d * (f64::from(y) * sr);
            }
        }
    }
    let sun = sun.normalize();
    // The split alone: the lights made without the swap rounds, which the default keeps here
    // for their lower diffuse error (1.22 against 1.36 × k-means), are off in both.
    let lights = |split: bool| {
        let mut ex = Extractor::new();
        ex.set_core_split(split);
        ex.set_unswapped_check(false);
        ex.extract(&map, &opts(16, Domain::Sphere, Method::Voronoi))
            .lights
    };
    let (split, whole) = (lights(true), lights(false));
    let off = |l: &Light| l.dir().angle_between(sun).to_degrees();
    let (near, centroid) = (off(brightest(&split)), off(brightest(&whole)));
    eprintln!("the sun's light {near:.3}° off the sun, {centroid:.3}° at its cell's centroid");
    assert!(
        near < 0.27 && centroid > 0.36,
        "the sun's light is {near:.3}° off the sun with the split, {centroid:.3}° without"
    );
    assert_eq!(split.len(), 16);
    let (a, b) = (total_irradiance(&split), total_irradiance(&whole));
    for c in 0..3 {
        assert!(
            (a[c] - b[c]).abs() <= 1e-4 * b[c],
            "energy {a:?} with the split, {b:?} without"
        );
    }
}

/// ALGORITHMS.md §4.2, "Split": the model's 60° sun through haze and cloud lies on the lat-long
/// seam, and at 256 lights the Lloyd steps cut it into two equal halves. The split leaves it so
/// (a third light taken from one half left that half's disc lopsided, and the shadow drawn on
/// §9's ground 1.6 × median cut's error); two lights on the sun, within a tenth of each other's
/// energy, and the shadowed error at most median cut's.
#[test]
fn a_sun_already_cut_in_two_is_not_split_again() {
    let mut sky = vemlight::eval::scenes::still_sky_model(1024, 60.0, 9.0, 0.3);
    let map = sky.render(0.0);
    let sun = sky.sun_direction(0.0);
    let lights = Extractor::new()
        .extract(&map, &opts(256, Domain::Sphere, Method::Voronoi))
        .lights;
    let peak = brightest(&lights).luminance();
    let on_sun: Vec<f64> = lights
        .iter()
        .filter(|l| l.dir().angle_between(sun).to_degrees() < 0.6 && l.luminance() > 0.05 * peak)
        .map(|l| l.luminance())
        .collect();
    assert!(
        on_sun.len() == 2 && rel(on_sun[0], on_sun[1]) < 0.1,
        "lights on the sun: {on_sun:?}"
    );
    let truth = vemlight::eval::accuracy::Truth::new(&map, Domain::Sphere);
    let median_cut = Extractor::new()
        .extract(&map, &opts(256, Domain::Sphere, Method::MedianCut))
        .lights;
    let (ours, theirs) = (
        truth.shadowed_mean(&lights),
        truth.shadowed_mean(&median_cut),
    );
    assert!(
        ours <= theirs,
        "shadowed error {ours:.5} against median cut's {theirs:.5}"
    );
}

/// ALGORITHMS.md §12, "Not across the horizon": no light's disc crosses the horizon, on every
/// map and on a sky that is brightest in a wide band just above it (where a cell's core spreads
/// over tens of degrees and the unclamped disc would reach below the horizon). That a light high
/// above the horizon keeps the spread of its core is `a_disc_source_gives_a_light_of_its_radius`.
#[test]
fn no_light_disc_crosses_the_horizon() {
    let (w, h) = (1024, 512);
    let mut pixels = vec![[0.0f32; 3]; w * h];
    for j in 0..h {
        for i in 0..w {
            let (d, _) = Projection::LatLong.pixel(i, j, w, h).unwrap();
            let elev = d.y.asin().to_degrees();
            // A glow band peaking 4° above the horizon, 15° wide, over a dim ground.
            let y = if elev > 0.0 {
                1.0 + 20.0 * (-((elev - 4.0) / 15.0).powi(2)).exp()
            } else {
                0.2
            };
            pixels[j * w + i] = [y as f32; 3];
        }
    }
    let band = EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap();
    let mut maps: Vec<(String, EnvMap)> = vec![("band".into(), band)];
    maps.extend(MAPS.iter().map(|m| (m.to_string(), load(m))));
    let mut clamped = 0;
    for (name, map) in &maps {
        for n in [16, 64] {
            let out = Extractor::new().extract(map, &opts(n, Domain::Sphere, Method::Voronoi));
            for l in &out.lights {
                let gap = l.dir().y.abs().clamp(0.0, 1.0).asin();
                assert!(
                    l.angular_radius as f64 <= gap + 1e-6,
                    "{name} N={n}: light {} at {:.2}° elevation has radius {:.2}°",
                    l.id,
                    gap.to_degrees(),
                    (l.angular_radius as f64).to_degrees()
                );
                if name == "band" && l.dir().y > 0.0 && l.dir().y < 0.2 {
                    clamped += (l.angular_radius as f64 >= gap - 1e-6) as usize;
                }
            }
        }
    }
    // The band's low lights are the ones the rule holds back (their cores are wider than their
    // height above the horizon); without the rule the assertion above fails on them.
    assert!(
        clamped >= 4,
        "only {clamped} low band lights were at the horizon bound"
    );
}

/// Video mode (`Extractor::set_video`): on a steady scene each frame takes one more Lloyd step from
/// the last, so the lights settle (under half a degree a frame after 16 frames, and falling: Lloyd
/// converges linearly) at an error within 5 % of a single frame's (whose swap rounds may find a
/// slightly better basin than the stream's Lloyd fixed point) and near the k-means floor, with
/// energy exact in every frame.
#[test]
fn video_mode_settles_on_a_steady_scene() {
    for name in ["sunrise.exr", "studio.exr", "interior.exr"] {
        let map = load(name);
        let reference = IrradianceReference::from_map(&map, Domain::Sphere);
        let o = opts(32, Domain::Sphere, Method::Voronoi);
        let single = reference
            .error(&Extractor::new().extract(&map, &o).lights)
            .rel_rms;
        let floor = reference
            .error(
                &Extractor::new()
                    .extract(&map, &opts(32, Domain::Sphere, Method::KMeans))
                    .lights,
            )
            .rel_rms;
        let mut ex = Extractor::new();
        ex.set_video(true);
        let truth = map.integral(Domain::Sphere);
        let mut prev: Option<Vec<vemlight::lights::Light>> = None;
        let mut last_move = f64::INFINITY;
        let mut err = f64::NAN;
        for _ in 0..16 {
            let lights = ex.extract(&map, &o).lights;
            let sum = total_irradiance(&lights);
            assert!(rel(sum[1], truth[1]) < 1e-4, "{name}: energy");
            if let Some(p) = &prev {
                last_move = p
                    .iter()
                    .zip(&lights)
                    .map(|(a, b)| a.dir().angle_between(b.dir()).to_degrees())
                    .fold(0.0, f64::max);
            }
            err = reference.error(&lights).rel_rms;
            prev = Some(lights);
        }
        eprintln!(
            "{name}: single frame {single:.5}, settled {err:.5}, k-means {floor:.5}, last move {last_move:.3}°"
        );
        assert!(last_move < 0.5, "{name}: still moving {last_move}°");
        assert!(
            err <= single * 1.05,
            "{name}: settled {err} vs single frame {single}"
        );
        assert!(
            err <= 1.25 * floor,
            "{name}: settled {err} vs k-means {floor}"
        );
    }
}

/// ALGORITHMS.md §4.2, "Swaps": at 32 and 64 lights the default's diffuse error is within
/// 1.25 × converged k-means (the floor) on every map of tests/data, and at 16 within 1.45 × (the
/// gap left on night.exr, docs/EVALUATION.md). Without the swap rounds night.exr at 32 lights is
/// 1.9 × (a Lloyd fixed point with several lights on one lamp), which this catches; the rounds
/// never raise a map's k-means energy, by construction, so the error with them is checked against
/// the floor rather than against the error without them.
#[test]
fn the_default_is_near_the_k_means_floor_on_every_map() {
    let mut report = Vec::new();
    let mut worst: (f64, String) = (0.0, String::new());
    for name in MAPS {
        let map = load(name);
        let reference = IrradianceReference::from_map(&map, Domain::Sphere);
        for n in [16, 32, 64] {
            let err = |m| {
                reference
                    .error(
                        &Extractor::new()
                            .extract(&map, &opts(n, Domain::Sphere, m))
                            .lights,
                    )
                    .rel_rms
            };
            let ratio = err(Method::Voronoi) / err(Method::KMeans);
            report.push(format!("{name} N={n}: {ratio:.2} × k-means"));
            let bound = if n == 16 { 1.45 } else { 1.25 };
            assert!(
                ratio <= bound,
                "{name} N={n}: {ratio:.3} × k-means (bound {bound})"
            );
            if ratio > worst.0 {
                worst = (ratio, format!("{name} N={n}"));
            }
        }
    }
    eprintln!("{}\nworst {:.2} ({})", report.join("\n"), worst.0, worst.1);
}

/// ALGORITHMS.md §4.2, "Split": on a clear sky with a low sun, at 256 lights, the default's
/// diffuse error is within 1.25 × converged k-means. k-means spends two lights on the sun's disc;
/// one light there errs along the sun's terminator, which at this count is most of the error
/// that is left: 1.11 × without the split, 0.84 × with it.
#[test]
fn a_low_clear_sun_at_256_lights_is_near_the_k_means_floor() {
    let sky = hard_sky("sky-low-clear");
    let (with, without) = default_over_floor(&sky, 256, |ex| ex.set_swap_rounds(0));
    eprintln!("sky-low-clear N=256: {with:.3} × k-means, {without:.3} × without the split");
    assert!(with <= 1.25, "{with:.3} × k-means");
    assert!(
        with < 0.85 * without,
        "{with:.3} × k-means with the split, {without:.3} × without"
    );
}

/// Steps until the energy settles (ALGORITHMS.md §4.2, "Steps"): on a studio of large, even
/// softboxes the warp's Y^⅞ crowds the boxes, and two Lloyd steps leave 256 lights far from
/// their fixed point (1.7 × converged k-means' diffuse error). The steps that follow while the
/// energy still falls bring them within 1.25 × k-means, and without them the case is over it, so
/// that it keeps testing them.
#[test]
fn a_softbox_studio_at_256_lights_takes_the_steps_it_needs() {
    use vemlight::eval::scenes::{LampScene, lamp_scene};
    let map = lamp_scene(LampScene::Softboxes, 3, 1024);
    let (with, without) = default_over_floor(&map, 256, |ex| ex.set_converge(false));
    eprintln!("softbox studio N=256: {with:.3} × k-means, {without:.3} × with two steps");
    assert!(with <= 1.25, "{with:.3} × k-means");
    assert!(
        without > 1.25,
        "with two steps {without:.3} × k-means: the case no longer tests the further steps"
    );
}

/// The lights made without the swap rounds (ALGORITHMS.md §4.2, "Swaps"): a swap is kept when
/// the k-means energy falls, which is not the diffuse error. On overcast-plaza.exr at 20 lights
/// the swapped lights are 1.03 × converged k-means; the lights made without the swaps are
/// estimated better by more than the margin, kept, and better in truth too. Without the check the
/// case is over the floor, so that it keeps testing it.
#[test]
fn a_single_map_keeps_its_unswapped_lights_where_they_are_clearly_better() {
    let map = load("overcast-plaza.exr");
    let (with, without) = default_over_floor(&map, 20, |ex| ex.set_unswapped_check(false));
    eprintln!("overcast-plaza N=20: {with:.3} × k-means, {without:.3} × with the swaps kept");
    assert!(
        with < 0.9 * without,
        "{with:.3} × k-means with the check, {without:.3} × without"
    );
    assert!(
        without > 1.0,
        "without the check {without:.3} × k-means: the case no longer tests it"
    );
}

/// The default's diffuse error at `n` lights over converged k-means's (the floor, ALGORITHMS.md
/// §10): as it is, and with `without` switching a rule of the default off.
fn default_over_floor(map: &EnvMap, n: usize, without: impl FnOnce(&mut Extractor)) -> (f64, f64) {
    let reference = IrradianceReference::from_map(map, Domain::Sphere);
    let error = |ex: &mut Extractor, m| {
        reference
            .error(&ex.extract(map, &opts(n, Domain::Sphere, m)).lights)
            .rel_rms
    };
    let floor = error(&mut Extractor::new(), Method::KMeans);
    let with = error(&mut Extractor::new(), Method::Voronoi) / floor;
    let mut off = Extractor::new();
    without(&mut off);
    (with, error(&mut off, Method::Voronoi) / floor)
}

/// [`default_over_floor`] with the starts of a single map, and from the count's own start alone.
fn starts_over_floor(map: &EnvMap, n: usize) -> (f64, f64) {
    default_over_floor(map, n, |ex| ex.set_other_starts(false))
}

/// Two starts (ALGORITHMS.md §4.2): at 16 lights the default's own start leaves night.exr and the
/// high hazy, cloudy sky in poor Lloyd fixed points (1.39 and 1.27 × converged k-means), which the
/// swap rounds do not leave; the start by Y^½ reaches better ones, and the estimated diffuse error
/// picks it. Both maps within 1.25 × k-means, and without the second start at least one over it,
/// so that the case keeps testing it.
#[test]
fn two_starts_keep_16_lights_near_the_k_means_floor() {
    let sky = hard_sky("sky-high-hazy-clouds");
    let mut worst_without = 0.0f64;
    for (name, map) in [
        ("night.exr", load("night.exr")),
        ("sky-high-hazy-clouds", sky),
    ] {
        let (with, without) = starts_over_floor(&map, 16);
        eprintln!("{name} N=16: {with:.3} × k-means, {without:.3} × with one start");
        assert!(with <= 1.25, "{name}: {with:.3} × k-means");
        assert!(
            with <= without * 1.001,
            "{name}: two starts {with:.3}, one {without:.3}"
        );
        worst_without = worst_without.max(without);
    }
    assert!(
        worst_without > 1.25,
        "with one start the worst is {worst_without:.3} × k-means: the case no longer tests the second"
    );
}

/// The third start at 33–64 lights (ALGORITHMS.md §4.2, "Starts"): on city.exr, a bright sky with
/// no sun, the lights of the Y¹ start have the shadows under occluders (§9) at most median cut's,
/// where the two other starts' lights are a third over it; the start is chosen on the diffuse
/// estimate, so its diffuse error stays near the k-means floor too.
#[test]
fn the_wide_start_keeps_city_shadows_at_64_lights_within_median_cuts() {
    use vemlight::eval::accuracy::Truth;
    let map = load("city.exr");
    let truth = Truth::new(&map, Domain::Sphere);
    let shadowed = |lights: &[vemlight::lights::Light]| truth.shadowed_mean(lights);
    let lights = |m| {
        Extractor::new()
            .extract(&map, &opts(64, Domain::Sphere, m))
            .lights
    };
    let default = lights(Method::Voronoi);
    let median_cut = shadowed(&lights(Method::MedianCut));
    let floor = truth.diffuse.error(&lights(Method::KMeans)).rel_rms;
    let ratio = shadowed(&default) / median_cut;
    let diffuse = truth.diffuse.error(&default).rel_rms / floor;
    let mut own_start = Extractor::new();
    let placement = vemlight::lights::Placement::for_lights(64);
    own_start.set_other_starts(false);
    own_start.set_placement(placement);
    let without = shadowed(
        &own_start
            .extract(&map, &opts(64, Domain::Sphere, Method::Voronoi))
            .lights,
    ) / median_cut;
    eprintln!(
        "city.exr N=64: shadowed {ratio:.3} × median cut's ({without:.3} from Y^{} alone), diffuse {diffuse:.3} × k-means",
        placement.exponent
    );
    assert!(ratio <= 1.0, "shadowed {ratio:.3} × median cut's");
    assert!(diffuse <= 1.25, "diffuse {diffuse:.3} × k-means");
    assert!(
        without > 1.1,
        "the count's own start alone gives {without:.3} × median cut's: the case no longer tests the third start"
    );
}

/// The two starts at 65–128 lights (ALGORITHMS.md §4.2, "Starts"): on studio.exr, two lamps
/// holding 88 % of the light in 1 % of the pixels, the Y^¾ start alone ends in a fixed point over
/// the k-means floor by more than a tenth at 128 lights; chosen among Y^⅝, Y^¾ and Y^⅞ on the
/// diffuse estimate, the lights are within the floor's 1.25 and under the lone start's error.
#[test]
fn the_steps_starts_keep_studio_at_128_lights_near_the_floor() {
    let (default, without) = starts_over_floor(&load("studio.exr"), 128);
    eprintln!("studio.exr N=128: {default:.3} × k-means ({without:.3} from Y^¾ alone)");
    assert!(default <= 1.25, "diffuse {default:.3} × k-means");
    assert!(
        default < without,
        "the starts chose {default:.3}, the lone start gives {without:.3}"
    );
    assert!(
        without > 1.1,
        "the count's own start alone gives {without:.3} × k-means: the case no longer tests the starts"
    );
}

/// The starts and steps of 65 to 192 lights (ALGORITHMS.md §4.2, "Starts"): studio.exr, whose
/// two lamps hold 88 % of its light, was 1.60 × the k-means floor at 129 lights and 1.45 × at 192
/// when those counts took one start by Y^⅞; with the three starts it is within the floor's 1.25.
#[test]
fn the_steps_starts_keep_studio_near_the_floor_between_128_and_192_lights() {
    let map = load("studio.exr");
    for n in [129, 192] {
        let (default, without) = starts_over_floor(&map, n);
        eprintln!("studio.exr N={n}: {default:.3} × k-means ({without:.3} from Y^¾ alone)");
        assert!(default <= 1.25, "N={n}: diffuse {default:.3} × k-means");
    }
}

/// The baselines of ALGORITHMS.md §10. Converged k-means is the floor of the diffuse error: at
/// most median cut's and VMLPS's on every map at N = 16 and 64; and VMLPS's variance-minimising
/// cut puts two lights on two separated lamps where it matters.
#[test]
fn k_means_is_the_floor_and_vmlps_cuts_between_sources() {
    let mut ex = Extractor::new();
    for name in MAPS {
        let map = load(name);
        let reference = IrradianceReference::from_map(&map, Domain::Sphere);
        for n in [16, 64] {
            let err = |ex: &mut Extractor, m| {
                reference
                    .error(&ex.extract(&map, &opts(n, Domain::Sphere, m)).lights)
                    .rel_rms
            };
            let k = err(&mut ex, Method::KMeans);
            let mc = err(&mut ex, Method::MedianCut);
            let vm = err(&mut ex, Method::Vmlps);
            assert!(
                k <= mc && k <= vm,
                "{name} N={n}: k-means {k}, median cut {mc}, vmlps {vm}"
            );
        }
    }
    // Two 2° lamps 90° apart on a dim sky: two VMLPS lights, one on each lamp.
    let (w, h) = (512, 256);
    let lamps = [
        DVec3::new(0.6, 0.5, -0.6).normalize(),
        DVec3::new(-0.6, 0.5, -0.6).normalize(),
    ];
    let mut pixels = vec![[0.01f32; 3]; w * h];
    for j in 0..h {
        for i in 0..w {
            let (d, _) = Projection::LatLong.pixel(i, j, w, h).unwrap();
            if lamps.iter().any(|l| d.dot(*l) >= 2f64.to_radians().cos()) {
                pixels[j * w + i] = [500.0; 3];
            }
        }
    }
    let map = EnvMap::from_pixels(w, h, pixels, Projection::LatLong).unwrap();
    let lights = ex
        .extract(&map, &opts(2, Domain::Sphere, Method::Vmlps))
        .lights;
    for lamp in lamps {
        let nearest = lights
            .iter()
            .map(|l| l.dir().angle_between(lamp).to_degrees())
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest < 3.0,
            "no VMLPS light within 3° of the lamp at {lamp:?}: {lights:?}"
        );
    }
}

/// The lights' floor irradiance Σ P·max(0, sin e) over the map's ∫ L·max(0, ω_y) dω, less one.
fn floor_excess(map: &EnvMap, lights: &[vemlight::lights::Light]) -> f64 {
    let truth: f64 = vemlight::lights::error::map_emitters(map, Domain::Sphere)
        .iter()
        .map(|(d, e)| (*e as f64) * (d.y as f64).max(0.0))
        .sum();
    let lit: f64 = lights
        .iter()
        .map(|l| l.luminance() * (l.to_light[1] as f64).max(0.0))
        .sum();
    lit / truth - 1.0
}

/// The tilt toward the horizon (ALGORITHMS.md §4.2, "Tilt"). On the overcast plaza at 32 lights
/// each light of power P at its cell's centroid gives the open ground P/|M| of its cell's share,
/// and the excesses add up (+1.2 %); the tilt takes nearly all of it off the floor, without
/// overshooting to a deficit, and here the diffuse error over the sphere falls too (the tilt may
/// raise it by 10 % on the estimate). On the low clear sun the sun's own light (a compact core,
/// P ≈ |M|) does not move. Energy and ids are never touched.
#[test]
fn the_tilt_takes_the_point_lights_excess_off_the_floor() {
    // The tilt alone: the core's turn in azimuth that follows it, and the choice of the lights
    // made without the swap rounds (which sees the tilt), are off in both.
    let (mut plain, mut tilted) = (Extractor::new(), Extractor::new());
    plain.set_tilt(false);
    plain.set_core_azimuth(false);
    tilted.set_core_azimuth(false);
    plain.set_unswapped_check(false);
    tilted.set_unswapped_check(false);
    let map = load("overcast-plaza.exr");
    let reference = IrradianceReference::from_map(&map, Domain::Sphere);
    let o = opts(32, Domain::Sphere, Method::Voronoi);
    let without = plain.extract(&map, &o).lights;
    let with = tilted.extract(&map, &o).lights;
    let (ew, eo) = (floor_excess(&map, &with), floor_excess(&map, &without));
    let (dw, dn) = (
        reference.error(&with).rel_rms,
        reference.error(&without).rel_rms,
    );
    eprintln!("overcast N=32: floor excess {eo:+.4} → {ew:+.4}, diffuse {dn:.5} → {dw:.5}");
    assert!(
        eo > 0.005,
        "the untilted excess is {eo:+.4}: the case no longer tests the tilt"
    );
    assert!(
        ew.abs() < 0.25 * eo,
        "tilted excess {ew:+.4} against {eo:+.4}"
    );
    assert!(dw < dn, "diffuse {dw:.5} with the tilt, {dn:.5} without");
    for (a, b) in with.iter().zip(&without) {
        assert_eq!(
            (a.id, a.irradiance),
            (b.id, b.irradiance),
            "energy or id moved"
        );
        assert!((a.dir().length() - 1.0).abs() < 1e-6);
        // Only lights above the horizon tilt, and only down toward it.
        if b.to_light[1] <= 0.0 {
            assert_eq!(a.to_light, b.to_light);
        } else {
            assert!(a.to_light[1] <= b.to_light[1] + 1e-6 && a.to_light[1] >= 0.0);
        }
    }

    let sun = hard_sky("sky-low-clear");
    let (with, without) = (
        tilted.extract(&sun, &o).lights,
        plain.extract(&sun, &o).lights,
    );
    let brightest = (0..without.len())
        .max_by(|&a, &b| without[a].luminance().total_cmp(&without[b].luminance()))
        .expect("lights");
    assert_eq!(with[brightest], without[brightest], "the sun's light moved");
}

/// The rise (ALGORITHMS.md §4.2, "Tilt"): on the low clear sun at 16 lights the lights give the
/// open ground too little (cells across the horizon have their centroids low, their floor from
/// higher up); those lights rise, the deficit shrinks by more than half without turning into an
/// excess, and the diffuse error stays within the rise's allowance. Only lights above the
/// horizon move, only up; energy and ids are never touched.
#[test]
fn the_tilt_raises_lights_where_the_floor_falls_short() {
    let sun = hard_sky("sky-low-clear");
    let o = opts(16, Domain::Sphere, Method::Voronoi);
    // The tilt alone, as above.
    let (mut plain, mut tilted) = (Extractor::new(), Extractor::new());
    plain.set_tilt(false);
    plain.set_core_azimuth(false);
    tilted.set_core_azimuth(false);
    let without = plain.extract(&sun, &o).lights;
    let with = tilted.extract(&sun, &o).lights;
    let (ew, eo) = (floor_excess(&sun, &with), floor_excess(&sun, &without));
    let reference = IrradianceReference::from_map(&sun, Domain::Sphere);
    let (dw, dn) = (
        reference.error(&with).rel_rms,
        reference.error(&without).rel_rms,
    );
    eprintln!("low clear sun N=16: floor excess {eo:+.4} → {ew:+.4}, diffuse {dn:.5} → {dw:.5}");
    assert!(
        eo < -0.005,
        "the untilted deficit is {eo:+.4}: the case no longer tests the rise"
    );
    assert!(
        ew > 0.5 * eo && ew < 0.1 * eo.abs(),
        "risen excess {ew:+.4} against {eo:+.4}"
    );
    assert!(
        dw < 1.1 * dn,
        "diffuse {dw:.5} with the rise, {dn:.5} without"
    );
    for (a, b) in with.iter().zip(&without) {
        assert_eq!(
            (a.id, a.irradiance),
            (b.id, b.irradiance),
            "energy or id moved"
        );
        if b.to_light[1] <= 0.0 {
            assert_eq!(a.to_light, b.to_light);
        } else {
            assert!(a.to_light[1] >= b.to_light[1] - 1e-6, "a light went down");
        }
    }
}

/// ALGORITHMS.md §12, "Core split": a sun in a wide glare is one light for the sun at its own
/// size and one for the rest of its cell, the light cheapest to merge giving way: still N
/// distinct lights, each with energy, and the same total energy as without the split.
#[test]
fn a_sun_in_a_wide_glare_is_split_from_it() {
    use vemlight::eval::scenes::LatLongDirs;
    let centre = DVec3::new(-0.5, 0.45, 0.2).normalize();
    let (sun_r, glare_r) = (0.27f64.to_radians(), 5f64.to_radians());
    let cap = |r: f64| std::f64::consts::TAU * (1.0 - r.cos());
    // Shares of the map's energy: sun 0.2, glare 0.4, the upper sky 0.4.
    let (sun_l, glare_l) = (0.2 / cap(sun_r), 0.4 / (cap(glare_r) - cap(sun_r)));
    let sky_l = 0.4 / std::f64::consts::TAU;
    let map = LatLongDirs::new(1024, 512).map(|d| {
        let c = d.dot(centre);
        let y = if c >= sun_r.cos() {
            sun_l
        } else if c >= glare_r.cos() {
            glare_l
        } else {
            0.0
        } + if d.y > 0.0 { sky_l } else { 0.0 };
        [y as f32; 3]
    });
    let n = 64;
    let run = |split: bool| {
        let mut ex = Extractor::new();
        ex.set_core_split(split);
        ex.extract(&map, &opts(n, Domain::Sphere, Method::Voronoi))
            .lights
    };
    let (split, whole) = (run(true), run(false));
    let total = |ls: &[Light]| ls.iter().map(|l| l.luminance()).sum::<f64>();
    assert_eq!(split.len(), n);
    let mut ids: Vec<u32> = split.iter().map(|l| l.id).collect();
    ids.sort_unstable();
    assert_eq!(ids, (0..n as u32).collect::<Vec<_>>());
    assert!(split.iter().all(|l| l.carries_energy()));
    assert!(rel(total(&split), total(&whole)) < 1e-4, "energy changed");
    let deg = |l: &Light| (l.angular_radius as f64).to_degrees();
    let off = |l: &Light| l.dir().angle_between(centre).to_degrees();
    // The sun's light: on the sun, at its size, with about its energy (0.2 of the map; its
    // texels hold a little glare too).
    let sun = brightest(&split);
    let share = sun.luminance() / total(&split);
    assert!(
        off(sun) < 0.3 && deg(sun) < 0.6 && (0.15..0.3).contains(&share),
        "sun's light {:.2}° off, radius {:.2}°, share {share:.3}",
        off(sun),
        deg(sun)
    );
    // The rest of its cell, a glare even about the sun: a second light on the sun, wider. Without
    // the split the sun has one light there.
    let on_sun = |ls: &[Light]| ls.iter().filter(|l| off(l) < 1.0).count();
    assert!(
        split
            .iter()
            .any(|l| l.id != sun.id && off(l) < 1.0 && deg(l) > 4.0 * deg(sun)),
        "no light for the glare around the sun"
    );
    assert_eq!((on_sun(&split), on_sun(&whole)), (2, 1));
}
