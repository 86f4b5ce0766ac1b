//! The three.js demo at `GET /demo` in a real browser: headless Chromium (software GL) loads the
//! page from the real daemon (`vemlight serve`, the synthetic sky with a fast sun, a token), and
//! the test reads the page's state and pixels over the DevTools protocol: the shadowed-light count
//! is the budget asked for, the ground in an object's shadow is darker than open ground by what
//! the LightSet predicts (DESIGN.md's diffuse formula with the shadowed lights occluded), the
//! shadow moves with the sun, and the page logs no errors. Also runs the client's conversion
//! tests under Node (clients/three/test).
//!
//! Needs `chromium` and `node` (scripts/test.sh installs chromium and sets
//! `VEMLIGHT_REQUIRE_BROWSER=1`, so CI always runs these); a plain `cargo test` without them skips
//! with a note.

mod common;

use common::{Killed, chromium};
use glam::DVec3;
use serde_json::{Value, json};
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};
use vemlight::envmap::luminance64;
use vemlight::lights::sh;

#[test]
fn the_three_js_conversion_passes_its_node_tests() {
    let Some(node) = chromium::found_or_skip(chromium::first_working(&["node", "nodejs"]), "node")
    else {
        return;
    };
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("clients/three");
    let out = Command::new(node)
        .current_dir(&dir)
        .args([
            "--import",
            "./test/register.mjs",
            "--test",
            "test/conversion.test.js",
        ])
        .output()
        .expect("runs node");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "node --test failed:\n{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("# fail 0"), "{text}");
}

fn luminance(rgb: &Value) -> f64 {
    luminance64(vec3(rgb))
}

/// DESIGN.md's diffuse formula on flat ground (n = +Y): Σ lum(E_k)·max(0, y_k)·V_k, with V_k the
/// visibility the page measured for each shadowed light at that point (1 for the rest, which
/// reach the scene unshadowed through the probe).
fn ground_irradiance(set: &Value, visibility: &Value) -> f64 {
    set["lights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| {
            let v = visibility[l["id"].as_u64().unwrap().to_string()]
                .as_f64()
                .unwrap_or(1.0);
            luminance(&l["irradiance"]) * l["to_light"][1].as_f64().unwrap().max(0.0) * v
        })
        .sum()
}

/// A pixel measurement of the demo page of a frame drawn with the smoothing completed (`snap`),
/// checked to draw the sun where the plan puts it (within 1°). Lights are smoothed toward each new
/// set, and on a loaded machine, where SwiftShader draws a frame or two a second and a measurement
/// blocks the page for a second or more, a smoothed frame can lag the moving sun by degrees and
/// would judge the old shadow against the new sun.
async fn measure_as_drawn(cdp: &mut chromium::Cdp, grid: &Value) -> Value {
    let start = Instant::now();
    loop {
        let m = cdp
            .eval(&format!(
                "vemlightDemo.measure({{ at: {grid}, snap: true }}).then(JSON.stringify)"
            ))
            .await;
        let sun = &m["sun"];
        if sun["drawn"].is_null() || angle_deg(&sun["direction"], &sun["drawn"]) < 1.0 {
            return m;
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "the drawn sun did not reach the plan's in 10 s: {m}"
        );
    }
}

fn angle_deg(a: &Value, b: &Value) -> f64 {
    let d: f64 = (0..3)
        .map(|i| a[i].as_f64().unwrap() * b[i].as_f64().unwrap())
        .sum();
    d.clamp(-1.0, 1.0).acos().to_degrees()
}

fn vec3(v: &Value) -> [f64; 3] {
    [0, 1, 2].map(|i| v[i].as_f64().unwrap())
}

/// What the client draws on flat ground: the shadowed lights (occluded as the page measured)
/// plus the irradiance at n = +Y of the remainder's L2 SH (ALGORITHMS.md §7: E = Σ A_l L_lm Y_lm,
/// A = π, 2π/3, π/4: `lights::sh::irradiance`), the remainder being `sh9_unshadowed`, or `sh9` less the shadowed lights'
/// projections E·Y(l).
fn ground_irradiance_model(m: &Value, visibility: &Value) -> f64 {
    let set = &m["set"];
    let shadowed: Vec<u64> = m["shadowed"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["id"].as_u64().unwrap())
        .collect();
    let remainder: Vec<f64> = match set["sh9_unshadowed"].as_array() {
        Some(sh) => sh.iter().map(|v| v.as_f64().unwrap()).collect(),
        None => {
            let mut sh: Vec<f64> = set["sh9"]
                .as_array()
                .expect("the stream sends sh9")
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            for l in set["lights"].as_array().unwrap() {
                if shadowed.contains(&l["id"].as_u64().unwrap()) {
                    let y = sh::basis(DVec3::from_array(vec3(&l["to_light"])));
                    for (i, yi) in y.iter().enumerate() {
                        for c in 0..3 {
                            sh[3 * i + c] -= l["irradiance"][c].as_f64().unwrap() * yi;
                        }
                    }
                }
            }
            sh
        }
    };
    let remainder: [f64; 27] = remainder.try_into().expect("27 coefficients");
    let probe = sh::irradiance(&remainder, DVec3::Y);
    let shadowed_part: f64 = set["lights"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| shadowed.contains(&l["id"].as_u64().unwrap()))
        .map(|l| {
            let v = visibility[l["id"].as_u64().unwrap().to_string()]
                .as_f64()
                .unwrap_or(1.0);
            luminance(&l["irradiance"]) * l["to_light"][1].as_f64().unwrap().max(0.0) * v
        })
        .sum();
    shadowed_part + luminance64(probe)
}

/// Checks each object's shadow on the ground in measurement `m` against open ground, the
/// measured ratio against what the client's model predicts (tightly) and against DESIGN.md's
/// formula with every light (loosely: the remainder's L2 SH lets some of the lights below the
/// horizon through, a few % of open ground). Returns how many points were in the sun's umbra.
fn check_shadows(m: &Value, when: &str) -> usize {
    let open = &m["open"];
    assert!(open.is_object(), "{when}: no open ground in view: {m}");
    let open_r = open["radiance"].as_f64().unwrap();
    let (open_exact, open_model) = (
        ground_irradiance(&m["set"], &open["V"]),
        ground_irradiance_model(m, &open["V"]),
    );
    let mut umbra = 0;
    for o in m["objects"].as_array().unwrap() {
        // The knot's tube is thinner than the soft-shadow filter at the shadow map's texel size,
        // so its umbra point is lightened by the filter as the sun moves; the box, the sphere
        // and the pole cast shadows wide enough to compare.
        if o["usable"] != true || o["name"] == "knot" {
            continue;
        }
        let measured = o["radiance"].as_f64().unwrap() / open_r;
        let model = ground_irradiance_model(m, &o["V"]) / open_model;
        let exact = ground_irradiance(&m["set"], &o["V"]) / open_exact;
        eprintln!(
            "{when}, {}: shadow/open ground measured {measured:.3}; K lights + SH {model:.3}; all lights {exact:.3} ({})",
            o["name"], o["sunlight"]
        );
        // Only a point whose whole pixel window is in the sun's umbra is a clean comparison.
        if o["sunlight"] == "umbra" {
            assert!(model < 0.8, "the sun should dominate the ground: {model}");
            assert!(
                (measured - model).abs() < 0.02 + 0.1 * model,
                "{when}, {}: shadow/open ground measured {measured:.3}, the LightSet predicts {model:.3}: {m}",
                o["name"]
            );
            assert!(
                (measured - exact).abs() < 0.1,
                "{when}, {}: shadow/open ground measured {measured:.3}, all lights {exact:.3}: {m}",
                o["name"]
            );
            umbra += 1;
        }
    }
    umbra
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_page_draws_the_live_lights_with_shadows() {
    let Some(browser) = chromium::browser_or_skip() else {
        return;
    };
    let test_start = Instant::now();
    // A fast sun (6°/s: a 30 s day from sunrise at the daemon's start), no clouds, no lamp.
    let (child, addr) = common::spawn_serve(&[
        "--sky-size",
        "256x128",
        "--token",
        "t0k",
        "--sun-speed",
        "6",
        "--clouds",
        "0",
        "--switch-period",
        "0",
    ]);
    let _daemon = Killed(child);
    // Does this daemon mark shadowed lights itself? (Then the page must use its marks.)
    let http = reqwest::Client::new();
    let marks = loop {
        let r = http
            .get(format!(
                "http://{addr}/v1/lights/latest?lights=16&shadowed=4"
            ))
            .bearer_auth("t0k")
            .send()
            .await
            .expect("GET /v1/lights/latest");
        match r.status().as_u16() {
            200 => break true,
            400 => break false,
            _ => {
                assert!(
                    test_start.elapsed() < Duration::from_secs(20),
                    "the daemon did not come up: {}",
                    r.status()
                );
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    };

    let profile =
        std::env::temp_dir().join(format!("vemlight-demo-chromium-{}", std::process::id()));
    let (_chrome, mut cdp) = chromium::launch(
        browser,
        &profile,
        &[
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--window-size=800,600",
        ],
        "JSON.stringify(window.vemlightDemo ? vemlightDemo.state() : null)",
    )
    .await;
    let url = format!("http://{addr}/demo?access_token=t0k&lights=16&shadowed=4&tonemap=linear");
    cdp.open(&url).await;

    // Frames drawn with the stream's lights, K = 4 of them shadowed.
    let s = cdp
        .wait_for("frames lit by the stream", Duration::from_secs(30), |s| {
            s["frames"].as_u64() >= Some(5)
                && s["stats"]["applied"].as_u64() >= Some(3)
                && s["shadowedCount"].as_u64() == Some(4)
        })
        .await;
    eprintln!("page: {s}");
    assert_eq!(s["directionalLights"], 4, "{s}");
    assert_eq!(s["shadowCasting"], 4, "{s}");
    assert_eq!(s["probes"], 1, "{s}");
    assert_eq!(s["lightsInSet"], 16, "{s}");
    let wire = s["stats"]["wire"].as_str().unwrap().to_string();
    assert_eq!(
        wire,
        if marks { "server" } else { "legacy" },
        "a daemon that marks shadowed lights must be asked to: {s}"
    );

    // The ground in an object's shadow against open ground, as the LightSet predicts.
    // Ground points every 0.25 m around the objects, looked at twice.
    let grid = Value::from(
        (0..=40)
            .flat_map(|i| {
                (0..=32).map(move |j| {
                    json!([-5.0 + 0.25 * f64::from(i), 0.0, -4.5 + 0.25 * f64::from(j)])
                })
            })
            .collect::<Vec<_>>(),
    );
    // Measure once the marks have held still for a second: a light newly marked fades in, and
    // until it has, the scene lags the set the prediction is made from.
    let (mut held_since, mut last_ids) = (Instant::now(), Value::Null);
    let settle = Instant::now();
    while held_since.elapsed() < Duration::from_millis(1200)
        && settle.elapsed() < Duration::from_secs(15)
    {
        let ids = cdp.state().await["shadowedIds"].clone();
        if ids != last_ids {
            (held_since, last_ids) = (Instant::now(), ids);
        }
        tokio::time::sleep(Duration::from_millis(150)).await;
    }
    let m1 = measure_as_drawn(&mut cdp, &grid).await;
    let open = &m1["open"];
    assert!(open.is_object(), "no open ground in view: {m1}");
    assert_eq!(open["clipped"], false, "open ground clipped: {m1}");
    // Open ground's radiance is albedo/π · E (albedo 0.5): the conversion, end to end.
    let open_r = open["radiance"].as_f64().unwrap();
    let rendered = open_r * std::f64::consts::PI / 0.5;
    let (model, exact) = (
        ground_irradiance_model(&m1, &open["V"]),
        ground_irradiance(&m1["set"], &open["V"]),
    );
    eprintln!(
        "open ground: rendered irradiance {rendered:.1}; K lights + SH {model:.1}; all lights {exact:.1}"
    );
    assert!(
        (rendered / model - 1.0).abs() < 0.05,
        "open ground: rendered irradiance {rendered} vs the set's {model}: {m1}"
    );
    assert!(
        (rendered / exact - 1.0).abs() < 0.1,
        "open ground: rendered irradiance {rendered} vs all lights' {exact}: {m1}"
    );
    assert!(
        check_shadows(&m1, "first look") > 0,
        "no shadow point in the sun's umbra: {m1}"
    );
    // The sun moves; the shadow follows: the points that were in the sun's shadow are lit.
    let sun_now =
        "JSON.stringify(vemlightDemo.client.lastPlan.shadowed.find((l) => l.id === SUN).direction)"
            .replace("SUN", &m1["sun"]["id"].to_string());
    let start = Instant::now();
    loop {
        let d = cdp.eval(&sun_now).await;
        if angle_deg(&m1["sun"]["direction"], &d) > 20.0 {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "the sun did not move 20° in 10 s: {d}"
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    let m2 = measure_as_drawn(&mut cdp, &grid).await;
    let moved = angle_deg(&m1["sun"]["direction"], &m2["sun"]["direction"]);
    assert_eq!(m1["sun"]["id"], m2["sun"]["id"], "the sun kept its id");
    assert!(moved > 15.0, "the sun moved only {moved:.1}°: {m2}");
    // Each grid point's pixels agree with where the sun's shadow falls (by ray casting) at both
    // looks, and some points the shadow covered are in the sun now, and dark before.
    // Each look's reference is the median of its sunlit grid points rather than the one open
    // point: a marked sky light's soft shadow may fall on the open point in one look and not
    // the other, and the test judges the sun's shadow.
    let sunlit_median = |m: &Value| {
        let mut r: Vec<f64> = m["at"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|p| p["seen"] == true && p["onScreen"] == true && p["sunlight"] == "sunlit")
            .map(|p| p["radiance"].as_f64().unwrap())
            .collect();
        r.sort_by(f64::total_cmp);
        assert!(
            r.len() > 20,
            "too few sunlit grid points in view: {}",
            r.len()
        );
        r[r.len() / 2]
    };
    let (open_r, open2_r) = (sunlit_median(&m1), sunlit_median(&m2));
    let (mut judged, mut agree, mut uncovered) = (0, 0, 0);
    for (a, b) in m1["at"]
        .as_array()
        .unwrap()
        .iter()
        .zip(m2["at"].as_array().unwrap())
    {
        let in_view = |p: &Value| p["seen"] == true && p["onScreen"] == true;
        if !in_view(a) || !in_view(b) {
            continue;
        }
        let r1 = a["radiance"].as_f64().unwrap() / open_r;
        let r2 = b["radiance"].as_f64().unwrap() / open2_r;
        for (p, r) in [(a, r1), (b, r2)] {
            match p["sunlight"].as_str() {
                Some("umbra") => {
                    judged += 1;
                    agree += usize::from(r < 0.3);
                }
                Some("sunlit") => {
                    judged += 1;
                    agree += usize::from(r > 0.85);
                }
                _ => {}
            }
        }
        if a["sunlight"] == "umbra" && b["sunlight"] == "sunlit" && r1 < 0.3 && r2 > 0.85 {
            uncovered += 1;
        }
    }
    eprintln!(
        "sun moved {moved:.1}°: {agree} of {judged} grid pixels as the shadow geometry says; {uncovered} points left the shadow"
    );
    assert!(judged > 100, "too few grid points in view: {judged}");
    assert!(
        agree as f64 >= 0.95 * judged as f64,
        "pixels and shadow geometry disagree: {agree} of {judged}: {m1} {m2}"
    );
    assert!(
        uncovered >= 3,
        "the shadow did not move off the ground it covered ({uncovered} points): {m1} {m2}"
    );
    check_shadows(&m2, "after the move");

    // The frame rate at K = 4 (software GL), for the record.
    let fps = cdp
        .eval("vemlightDemo.countFrames(3000).then(JSON.stringify)")
        .await;
    let s = cdp.state().await;
    eprintln!(
        "frame rate at K = 4: {fps} frames/s ({}x{} canvas, {})",
        s["canvas"][0], s["canvas"][1], s["renderer"]
    );

    // The budget is selectable: K = 1 from the page's own control.
    // A set applied after the switch comes from the new connection (the switch closes the old
    // socket at once). Its seq says nothing: each stream counts its own from 1, and the K = 1
    // stream starts afresh, so the applied count is what shows a new set arrived.
    let applied = cdp
        .eval("vemlightDemo.setBudget({ shadowed: 1 }), String(vemlightDemo.client.stats.applied)")
        .await
        .as_u64()
        .unwrap();
    let s = cdp
        .wait_for("the budget K = 1", Duration::from_secs(15), |s| {
            s["shadowedCount"].as_u64() == Some(1)
                && s["stats"]["applied"].as_u64() > Some(applied)
                && s["stats"]["connected"] == true
        })
        .await;
    assert_eq!(s["directionalLights"], 1, "{s}");
    assert!(
        s["streamUrl"].as_str().unwrap().contains("lights=16"),
        "{s}"
    );
    if marks {
        assert!(
            s["streamUrl"].as_str().unwrap().contains("shadowed=1"),
            "{s}"
        );
    }

    // No errors: none the page caught, no exception, no console.error, no error log entry but
    // (with a daemon that predates `shadowed`) the refused handshake the client falls back from.
    assert_eq!(s["errors"], json!([]), "the page logged errors: {s}");
    let problems = cdp.problems(|entry| {
        let text = entry["text"].as_str().unwrap_or("");
        wire == "legacy" && text.contains("WebSocket") && text.contains("400")
    });
    assert!(problems.is_empty(), "the page logged errors: {problems:#?}");
    let _ = std::fs::remove_dir_all(&profile);
    eprintln!("demo test took {:.1} s", test_start.elapsed().as_secs_f64());
}
