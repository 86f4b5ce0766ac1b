//! The live view at `GET /` in a real browser: headless Chromium loads the page from the real
//! daemon (`vemlight serve`, the synthetic sky, a token), whose script connects to `/v1/stream`
//! with `access_token`, parses LightSets and fills its table. Catches the page and the document
//! drifting apart (a renamed field leaves the table empty).
//!
//! Needs `chromium` (scripts/test.sh installs it and sets `VEMLIGHT_REQUIRE_BROWSER=1`, so CI
//! always runs this); a plain `cargo test` without it skips with a note.

mod common;

use common::{Killed, chromium};
use std::process::Command;
use std::time::{Duration, Instant};

#[test]
fn the_live_view_shows_streamed_lights() {
    let Some(browser) = chromium::browser_or_skip() else {
        return;
    };
    let (child, addr) = common::spawn_serve(&["--sky-size", "256x128", "--token", "t0k"]);
    let _daemon = Killed(child);
    // Wait for the first light set: `vemlight healthcheck` passes once /healthz says 200.
    let start = Instant::now();
    while !Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(["healthcheck", &addr.to_string()])
        .output()
        .is_ok_and(|o| o.status.success())
    {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the daemon did not come up"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let profile = std::env::temp_dir().join(format!("vemlight-chromium-{}", std::process::id()));
    let out = Command::new(browser)
        .args(chromium::headless_args(&profile))
        .args([
            "--disable-gpu",
            "--virtual-time-budget=5000",
            "--dump-dom",
            &format!("http://{addr}/?access_token=t0k"),
        ])
        .output()
        .expect("runs chromium");
    let _ = std::fs::remove_dir_all(&profile);
    let dom = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The script filled the table and the title from real LightSets.
    assert!(dom.contains(">connected<"), "not connected: {dom}");
    assert!(
        dom.contains("<title>vemlight — 64 lights, seq "),
        "no LightSet reached the page: {dom}"
    );
    for cell in [
        "<td>64 (voronoi, sphere domain)</td>",
        "<td>synthetic:256x128</td>",
        "<td>binomial, 9 taps, delay 133 ms</td>",
    ] {
        assert!(dom.contains(cell), "the table lacks {cell}: {dom}");
    }
}
