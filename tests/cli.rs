//! The `vemlight lights` command as a user runs it: outputs, formats and bad input.

mod common;

use common::{assert_valid, data_path, lightset_validator, write_exr};
use glam::{Quat, Vec3};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn vemlight(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(args)
        .output()
        .expect("run vemlight")
}

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vemlight-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn stdout_json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

/// A failing run: non-zero exit, no panic, and stderr says `needle`.
fn assert_fails_with(out: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail; stderr: {err}");
    assert!(!err.contains("panicked"), "panicked: {err}");
    assert!(
        err.to_lowercase().contains(&needle.to_lowercase()),
        "stderr lacks '{needle}': {err}"
    );
    assert!(out.stdout.is_empty(), "nothing on stdout on failure");
}

#[test]
fn lights_prints_a_valid_lightset() {
    let out = vemlight(&[
        "lights",
        data_path("sunrise.exr").to_str().unwrap(),
        "--lights",
        "64",
    ]);
    let doc = stdout_json(&out);
    assert_valid(&lightset_validator(), &doc);
    assert_eq!(doc["lights"].as_array().unwrap().len(), 64);
    assert_eq!(doc["domain"], "sphere");
    assert_eq!(doc["method"], "voronoi");
    assert_eq!(doc["sh9"].as_array().unwrap().len(), 27);
    // The sun of sunrise.exr is 8° above the horizon: the primary light says so.
    let p = &doc["primary"]["to_light"];
    let elevation = p[1].as_f64().unwrap().asin().to_degrees();
    assert!((elevation - 8.0).abs() < 3.0, "sun elevation {elevation}°");
}

#[test]
fn max_error_reports_the_chosen_count() {
    let out = vemlight(&[
        "lights",
        data_path("city.exr").to_str().unwrap(),
        "--domain",
        "upper",
        "--max-error",
        "0.01",
    ]);
    let doc = stdout_json(&out);
    assert_valid(&lightset_validator(), &doc);
    let n = doc["lights"].as_array().unwrap().len();
    assert!((1..=64).contains(&n), "{n}");
    // The count chosen is not a shortfall of the map's.
    assert_eq!(doc["diagnostics"]["lights_requested"], 64);
    assert_eq!(doc["diagnostics"]["lights_chosen"], n);
    assert!(doc["diagnostics"]["lights_short"].is_null(), "{doc}");
    assert!(doc["diagnostics"]["estimated_error"].as_f64().unwrap() <= 0.01);
    assert_eq!(doc["diagnostics"]["max_error_met"], true);
    assert_eq!(doc["domain"], "upper");
}

#[test]
fn median_cut_method_runs_from_the_cli() {
    let out = vemlight(&[
        "lights",
        data_path("studio.exr").to_str().unwrap(),
        "--method",
        "median-cut",
        "-n",
        "16",
    ]);
    let doc = stdout_json(&out);
    assert_valid(&lightset_validator(), &doc);
    assert_eq!(doc["method"], "median-cut");
    assert_eq!(doc["lights"].as_array().unwrap().len(), 16);
    // The baselines of ALGORITHMS.md §10 from the CLI too; k-means is refused for a stream.
    for (method, n) in [("vmlps", 24), ("k-means", 16)] {
        let out = vemlight(&[
            "lights",
            data_path("studio.exr").to_str().unwrap(),
            "--method",
            method,
            "-n",
            &n.to_string(),
        ]);
        let doc = stdout_json(&out);
        assert_valid(&lightset_validator(), &doc);
        assert_eq!(doc["method"], method);
        assert_eq!(doc["lights"].as_array().unwrap().len(), n);
    }
    assert_fails_with(
        &vemlight(&["serve", "--method", "k-means", "--bind", "127.0.0.1:0"]),
        "single maps",
    );
}

/// glTF: one directional light and node per light, node rotation maps −Z onto −to_light.
#[test]
fn gltf_output_rotates_minus_z_onto_the_travel_direction() {
    let file = data_path("interior.exr");
    let json = stdout_json(&vemlight(&["lights", file.to_str().unwrap(), "-n", "8"]));
    let gltf = stdout_json(&vemlight(&[
        "lights",
        file.to_str().unwrap(),
        "-n",
        "8",
        "--format",
        "gltf",
    ]));
    assert_eq!(gltf["asset"]["version"], "2.0");
    let lights = gltf["extensions"]["KHR_lights_punctual"]["lights"]
        .as_array()
        .unwrap();
    let nodes = gltf["nodes"].as_array().unwrap();
    assert_eq!(lights.len(), 8);
    assert_eq!(nodes.len(), 8);
    for (k, node) in nodes.iter().enumerate() {
        let r: Vec<f32> = node["rotation"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() as f32)
            .collect();
        let q = Quat::from_xyzw(r[0], r[1], r[2], r[3]);
        let travel = q * Vec3::NEG_Z;
        let to_light: Vec<f32> = json["lights"][k]["to_light"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() as f32)
            .collect();
        let want = -Vec3::new(to_light[0], to_light[1], to_light[2]);
        assert!(
            (travel - want).length() < 1e-4,
            "node {k}: {travel} vs {want}"
        );
        let light = &lights[node["extensions"]["KHR_lights_punctual"]["light"]
            .as_u64()
            .unwrap() as usize];
        assert_eq!(light["type"], "directional");
        let color = light["color"].as_array().unwrap();
        assert!(
            color
                .iter()
                .all(|c| (0.0..=1.0).contains(&c.as_f64().unwrap()))
        );
        // colour × intensity gives back the irradiance.
        let irr = &json["lights"][k]["irradiance"];
        let i = light["intensity"].as_f64().unwrap();
        for c in 0..3 {
            let back = color[c].as_f64().unwrap() * i;
            let want = irr[c].as_f64().unwrap();
            assert!(
                (back - want).abs() <= 1e-5 * want.max(1e-3),
                "{back} vs {want}"
            );
        }
    }
}

#[test]
fn fisheye_options_apply() {
    let dir = tmp_dir("fisheye");
    let (w, h) = (320, 240);
    // A bright spot right of centre: to the +X side.
    let mut px = vec![[0.01f32; 3]; w * h];
    for j in 115..125 {
        for i in 220..230 {
            px[j * w + i] = [50.0; 3];
        }
    }
    let path = dir.join("fisheye.exr");
    write_exr(&path, w, h, &px);
    let doc = stdout_json(&vemlight(&[
        "lights",
        path.to_str().unwrap(),
        "--projection",
        "fisheye-equisolid",
        "--fov",
        "185",
        "--circle",
        "160,120,118",
        "-n",
        "16",
    ]));
    assert_valid(&lightset_validator(), &doc);
    assert_eq!(doc["domain"], "upper");
    assert_eq!(doc["diagnostics"]["projection"], "fisheye-equisolid");
    let p = &doc["primary"]["to_light"];
    assert!(p[0].as_f64().unwrap() > 0.5, "primary {p}");
}

// ---- bad input ----

fn truncated(dir: &Path) -> PathBuf {
    let bytes = std::fs::read(data_path("night.exr")).unwrap();
    let p = dir.join("truncated.exr");
    std::fs::write(&p, &bytes[..bytes.len() / 3]).unwrap();
    p
}

#[test]
fn truncated_exr_is_a_clear_error() {
    let dir = tmp_dir("truncated");
    let out = vemlight(&["lights", truncated(&dir).to_str().unwrap()]);
    assert_fails_with(&out, "cannot decode OpenEXR");
}

/// A DWA chunk whose counters claim more than its block holds is refused before decoding (the
/// decoder would have aborted the process).
#[test]
fn dwa_chunk_with_a_huge_counter_is_a_clear_error() {
    let dir = tmp_dir("dwa");
    let p = dir.join("huge-ac.exr");
    std::fs::write(&p, common::dwa_with_a_huge_ac_count()).unwrap();
    let out = vemlight(&["lights", p.to_str().unwrap()]);
    assert_fails_with(&out, "AC value count is 144115188075855872");
}

#[test]
fn not_an_image_is_a_clear_error() {
    let dir = tmp_dir("notimage");
    let p = dir.join("notes.exr");
    std::fs::write(&p, "just some text, named .exr").unwrap();
    assert_fails_with(
        &vemlight(&["lights", p.to_str().unwrap()]),
        "not an OpenEXR or Radiance HDR",
    );
    let empty = dir.join("empty.hdr");
    std::fs::write(&empty, b"").unwrap();
    assert_fails_with(&vemlight(&["lights", empty.to_str().unwrap()]), "empty");
    assert_fails_with(
        &vemlight(&["lights", dir.join("missing.exr").to_str().unwrap()]),
        "cannot read",
    );
}

/// A header claiming 100 000 × 100 000 pixels is refused before any pixel buffer is allocated.
#[test]
fn huge_headers_are_refused() {
    let dir = tmp_dir("huge");
    // EXR: write a tiny valid file, then rewrite both windows to 100 000 × 100 000.
    let small = dir.join("small.exr");
    write_exr(&small, 4, 2, &[[1.0; 3]; 8]);
    let mut bytes = std::fs::read(&small).unwrap();
    for name in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
        let at = bytes
            .windows(name.len())
            .position(|w| w == name)
            .expect("window attribute")
            + name.len()
            + 4;
        for (k, v) in [0i32, 0, 99_999, 99_999].iter().enumerate() {
            bytes[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
    }
    let huge_exr = dir.join("huge.exr");
    std::fs::write(&huge_exr, &bytes).unwrap();
    let out = vemlight(&["lights", huge_exr.to_str().unwrap()]);
    assert_fails_with(&out, "100000×100000");

    let huge_hdr = dir.join("huge.hdr");
    let mut hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n".to_vec();
    hdr.extend_from_slice(&[1, 1, 1, 128].repeat(16));
    std::fs::write(&huge_hdr, &hdr).unwrap();
    let out = vemlight(&["lights", huge_hdr.to_str().unwrap()]);
    assert_fails_with(&out, "100000×100000");
}

#[test]
fn wrong_aspect_for_the_projection_is_refused() {
    let dir = tmp_dir("aspect");
    let p = dir.join("square.exr");
    write_exr(&p, 64, 64, &vec![[1.0; 3]; 64 * 64]);
    assert_fails_with(
        &vemlight(&["lights", p.to_str().unwrap(), "--projection", "latlong"]),
        "must be 2:1",
    );
    let q = dir.join("wide.exr");
    write_exr(&q, 64, 16, &vec![[1.0; 3]; 64 * 16]);
    assert_fails_with(
        &vemlight(&[
            "lights",
            q.to_str().unwrap(),
            "--projection",
            "hemisphere-square",
        ]),
        "must be square",
    );
}

#[test]
fn bad_arguments_are_refused() {
    let f = data_path("night.exr");
    let f = f.to_str().unwrap();
    assert_fails_with(
        &vemlight(&["lights", f, "--lights", "0"]),
        "between 1 and 1024",
    );
    assert_fails_with(
        &vemlight(&["lights", f, "--lights", "5000"]),
        "between 1 and 1024",
    );
    // Values the help rules out are refused by name, not accepted and ignored.
    for (args, says) in [
        (&["bench", "--rounds", "0"][..], "--rounds"),
        (&["bench", "--lights", "0"][..], "--lights"),
        (&["view", f, "--pcf", "2"][..], "1 or 4"),
        (&["view", f, "--exposure", "NaN"][..], "finite"),
        (&["view", f, "--cluster-deg=-1"][..], "at least 0"),
        (&["view", f, "--target-fps", "0"][..], "greater than 0"),
        (&["view", f, "--shadow-size", "0"][..], "--shadow-size"),
        (&["view", f, "--frames", "0"][..], "--frames"),
        (
            &["view", f, "--bench", "--bench-paths", "bogus"][..],
            "naive, steady, turning",
        ),
    ] {
        assert_fails_with(&vemlight(args), says);
    }
    for e in ["-1", "0", "2"] {
        assert_fails_with(
            &vemlight(&["lights", f, &format!("--max-error={e}")]),
            "relative error in (0, 1]",
        );
    }
    assert_fails_with(
        &vemlight(&["lights", f, "--method", "magic"]),
        "invalid value 'magic' for '--method <METHOD>'",
    );
    assert_fails_with(
        &vemlight(&["lights", f, "--domain", "left"]),
        "invalid value 'left' for '--domain <DOMAIN>'",
    );
    assert_fails_with(
        &vemlight(&["lights", f, "--projection", "latlong", "--fov", "180"]),
        "apply to fisheye",
    );
}

#[test]
fn all_black_map_gives_a_valid_zero_energy_lightset() {
    let dir = tmp_dir("black");
    let p = dir.join("black.exr");
    write_exr(&p, 128, 64, &vec![[0.0; 3]; 128 * 64]);
    let doc = stdout_json(&vemlight(&["lights", p.to_str().unwrap(), "-n", "32"]));
    assert_valid(&lightset_validator(), &doc);
    assert_eq!(doc["total_irradiance"], serde_json::json!([0.0, 0.0, 0.0]));
    assert!(doc["primary"].is_null());
    assert!(!String::from_utf8_lossy(&stdout_json_bytes(&doc)).contains("NaN"));
}

fn stdout_json_bytes(doc: &serde_json::Value) -> Vec<u8> {
    serde_json::to_vec(doc).unwrap()
}

#[test]
fn radiance_hdr_input_works() {
    let dir = tmp_dir("hdr");
    let (w, h) = (64usize, 32usize);
    let px: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|k| {
            let j = k / w;
            // Bright sky above, dark ground below.
            image::Rgb(if j < h / 2 {
                [2.0, 2.0, 3.0]
            } else {
                [0.1, 0.1, 0.1]
            })
        })
        .collect();
    let p = dir.join("sky.hdr");
    let f = std::fs::File::create(&p).unwrap();
    image::codecs::hdr::HdrEncoder::new(f)
        .encode(&px, w, h)
        .unwrap();
    let doc = stdout_json(&vemlight(&["lights", p.to_str().unwrap(), "-n", "8"]));
    assert_valid(&lightset_validator(), &doc);
    // ∫ over the upper half of L = (2,2,3) is 2π·(2,2,3); the ground adds 2π·0.1.
    let total = doc["total_irradiance"][2].as_f64().unwrap();
    let want = 2.0 * std::f64::consts::PI * (3.0 + 0.1);
    assert!((total - want).abs() / want < 1e-3, "{total} vs {want}");
}

#[test]
fn serve_configuration_errors_exit_with_a_message() {
    for (args, needle) in [
        (vec!["serve", "--bind", "nonsense"], "not an address"),
        (
            vec!["serve", "--source", "/no/such/frames"],
            "expected synthetic, stdin",
        ),
        (
            vec!["serve", "--source", "stdin"],
            "needs --width and --height",
        ),
        (vec!["serve", "--fps", "0"], "--fps must be between"),
        // A rate too slow for a clock to add its period.
        (vec!["serve", "--fps", "1e-30"], "--fps must be between"),
        (
            vec!["serve", "--sky-size", "2000000x1000000"],
            "is over --max-pixels",
        ),
        (vec!["serve", "--token", ""], "set but empty"),
        (
            vec!["serve", "--clouds", "-5"],
            "--clouds must be between 0 and 1",
        ),
        (
            vec!["serve", "--sun-speed", "nan"],
            "must be a finite number",
        ),
        (
            vec!["serve", "--switch-period=-1"],
            "--switch-period must be at least 0",
        ),
        (
            vec![
                "serve",
                "--source",
                "stdin",
                "--width",
                "16384",
                "--height",
                "8192",
                "--max-pixels",
                "1000",
            ],
            "is over --max-pixels",
        ),
        (
            vec!["serve", "--lights", "0"],
            "--lights must be between 1 and 1024",
        ),
        (
            vec!["serve", "--filter", "sinc", "--cutoff-hz", "20"],
            "cut-off",
        ),
        (vec!["serve", "--sky-size", "100x100"], "2:1"),
        (
            vec!["serve", "--filter", "kalman"],
            "invalid value 'kalman' for '--filter <FILTER>'",
        ),
        (
            vec!["serve", "--cors-origin", "app.example.com"],
            "is not an origin",
        ),
    ] {
        let out = vemlight(&args);
        assert_fails_with(&out, needle);
    }
    // From the environment: the address (the container image sets it), and an empty token,
    // a mistake rather than a request for an open daemon.
    for (var, value, needle) in [
        ("VEMLIGHT_BIND", "nonsense", "not an address"),
        ("VEMLIGHT_TOKEN", "", "set but empty"),
    ] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_vemlight"))
            .args(["serve", "--sky-size", "64x32"])
            .env(var, value)
            .output()
            .unwrap();
        assert_fails_with(&out, needle);
    }
    // A port already taken is a clear error too.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let out = vemlight(&["serve", "--bind", &addr, "--sky-size", "64x32"]);
    assert_fails_with(&out, "cannot listen on");
}

/// The commands' `--help` lists the values of every enumerated flag (methods, domains, filters,
/// pixel formats, sources), and a wrong value is answered with them.
#[test]
fn help_lists_the_values_of_enumerated_flags() {
    let help = |cmd: &str| {
        let out = vemlight(&[cmd, "--help"]);
        assert!(out.status.success(), "{cmd} --help");
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let lights = help("lights");
    for value in [
        "voronoi",
        "paper",
        "median-cut",
        "inverse-cdf",
        "k-means",
        "vmlps",
        "upper",
        "sphere",
        "json",
        "gltf",
    ] {
        assert!(lights.contains(value), "lights --help lacks {value}");
    }
    let serve = help("serve");
    for value in [
        "voronoi",
        "binomial",
        "sinc",
        "none",
        "rgbf32le",
        "rgbf16le",
        "rgb48le",
        "synthetic",
        "stdin",
    ] {
        assert!(serve.contains(value), "serve --help lacks {value}");
    }
    let out = vemlight(&["serve", "--pixel", "rgb24"]);
    assert_fails_with(&out, "possible values: rgbf32le, rgbf16le, rgb48le");
    // The old spellings are still taken.
    let f = data_path("night.exr");
    let out = vemlight(&[
        "lights",
        f.to_str().unwrap(),
        "-n",
        "4",
        "--method",
        "kmeans",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `serve --publish`: a broker URL with credentials on the command line, a camera name that is
/// not a subject token, a bad count list or half a login are refused before anything starts.
#[test]
fn serve_publish_configuration_errors_exit_with_a_message() {
    let url = "nats://127.0.0.1:1";
    for (args, env, needle) in [
        (
            vec!["--publish", "nats://me:secret@127.0.0.1:4222"],
            None,
            "put the URL in VEMLIGHT_NATS",
        ),
        (
            vec!["--publish", "http://me:secret@127.0.0.1:4222"],
            None,
            "scheme must be",
        ),
        (
            vec!["--publish", url, "--camera", "roof.east"],
            None,
            "NATS subject token",
        ),
        (
            vec!["--publish", url, "--publish-lights", "8,0"],
            None,
            "--publish-lights: 0",
        ),
        (
            vec!["--publish", url, "--publish-lights", "1,2,3,4,5,6,7,8,9"],
            None,
            "at most 8",
        ),
        (
            vec!["--publish", url],
            Some(("VEMLIGHT_NATS_USER", "viewer")),
            "without VEMLIGHT_NATS_PASSWORD",
        ),
        (
            vec!["--publish", url, "--nats-token-file", "/no/such/token"],
            None,
            "--nats-token-file '/no/such/token'",
        ),
        (
            vec!["--publish", url, "--nats-creds", "/no/such/creds"],
            None,
            "--nats-creds '/no/such/creds'",
        ),
    ] {
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_vemlight"));
        cmd.args(["serve", "--bind", "127.0.0.1:0", "--sky-size", "64x32"])
            .args(&args)
            .env_remove("VEMLIGHT_NATS_USER");
        if let Some((k, v)) = env {
            cmd.env(k, v);
        }
        let out = cmd.output().unwrap();
        assert_fails_with(&out, needle);
        // The secret is not echoed back.
        assert!(!String::from_utf8_lossy(&out.stderr).contains("secret"));
    }
}
