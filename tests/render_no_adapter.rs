//! No graphics adapter: `vemlight view` says so clearly and exits non-zero, without a panic. A
//! backend that cannot exist on this platform (Metal off Apple; Vulkan/GL elsewhere) stands in for a
//! machine without a driver.
#![cfg(feature = "render")]

use std::process::Command;

fn missing_backend() -> &'static str {
    if cfg!(target_vendor = "apple") {
        "dx12"
    } else {
        "metal"
    }
}

/// A light set written to a file named for `test`: the two tests run in parallel in one process, so
/// a shared name would let one remove the file the other is about to read.
fn lightset_file(test: &str) -> std::path::PathBuf {
    let out = Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args([
            "lights",
            "tests/data/overcast-plaza.exr",
            "-n",
            "4",
            "--no-sh",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let path = std::env::temp_dir().join(format!("vemlight-{test}-{}.json", std::process::id()));
    std::fs::write(&path, out.stdout).unwrap();
    path
}

fn check(out: std::process::Output) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("exit {:?}, stderr:\n{stderr}", out.status.code());
    assert!(!out.status.success(), "must fail");
    assert_ne!(
        out.status.code(),
        Some(101),
        "101 is Rust's panic exit code"
    );
    assert!(!stderr.contains("panicked"), "no panic: {stderr}");
    assert!(stderr.contains("no graphics adapter found"), "{stderr}");
    assert!(
        stderr.contains("mesa-vulkan-drivers"),
        "says what to install: {stderr}"
    );
}

#[test]
fn no_adapter_through_wgpu_backend_is_a_clear_error() {
    let json = lightset_file("no-adapter");
    let dir = std::env::temp_dir().join(format!("vemlight-no-adapter-out-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(["view", "--headless", "--frames", "1", "--out"])
        .arg(&dir)
        .arg(&json)
        .env("WGPU_BACKEND", missing_backend())
        .output()
        .unwrap();
    check(out);
    // And through --backend, in --bench mode.
    let out = Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(["view", "--bench", "--backend", missing_backend()])
        .arg(&json)
        .output()
        .unwrap();
    check(out);
    let _ = std::fs::remove_file(json);
}

/// An adapter that cannot render to one of the renderer's formats (Mesa's GL driver has no
/// 32-bit float colour targets) is a clear error, not a wgpu validation panic; an adapter that
/// can draws the frame.
#[test]
fn an_adapter_without_the_renderers_formats_is_a_clear_error() {
    let json = lightset_file("gl");
    let dir = std::env::temp_dir().join(format!("vemlight-gl-out-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(["view", "--headless", "--frames", "1", "--backend", "gl"])
        .arg("--out")
        .arg(&dir)
        .arg(&json)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("exit {:?}, stderr:\n{stderr}", out.status.code());
    assert!(!stderr.contains("panicked"), "no panic: {stderr}");
    if out.status.success() {
        let frames = std::fs::read_dir(&dir).map_or(0, |d| d.count());
        assert!(frames >= 1, "a GL adapter that can draw wrote no frame");
    } else {
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains("cannot render to") || stderr.contains("no graphics adapter found"),
            "{stderr}"
        );
        assert!(
            stderr.contains("mesa-vulkan-drivers"),
            "says what to install: {stderr}"
        );
    }
    let _ = std::fs::remove_dir_all(dir);
    let _ = std::fs::remove_file(json);
}
