//! The live view at `GET /` in a real browser: headless Chromium loads the page from the real
//! daemon (`vemlight serve`, the synthetic sky, a token), whose script connects to `/v1/stream`
//! with `access_token`, parses LightSets and fills its table. Catches the page and the document
//! drifting apart (a renamed field leaves the table empty).
//!
//! The page is watched over DevTools in real time: Chromium's virtual time (`--dump-dom` with a
//! budget) does not wait for a WebSocket handshake, so on a slow machine it dumped the page
//! before it had connected.
//!
//! Needs `chromium` (scripts/test.sh installs it and sets `VEMLIGHT_REQUIRE_BROWSER=1`, so CI
//! always runs this); a plain `cargo test` without it skips with a note.

mod common;

use common::{Killed, chromium};
use std::process::Command;
use std::time::{Duration, Instant};

/// What the test reads off the page: the status line, the title and the table's cells (null
/// while the page is still loading).
const PAGE_STATE: &str = "JSON.stringify(document.getElementById('status') && {
    status: document.getElementById('status').textContent,
    title: document.title,
    cells: [...document.querySelectorAll('#info td')].map((td) => td.textContent),
})";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_live_view_shows_streamed_lights() {
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
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let profile = std::env::temp_dir().join(format!("vemlight-chromium-{}", std::process::id()));
    let (chrome, mut cdp) =
        chromium::launch(browser, &profile, &["--disable-gpu"], PAGE_STATE).await;
    cdp.open(&format!("http://{addr}/?access_token=t0k")).await;

    // The script filled the table and the title from real LightSets.
    let s = cdp
        .wait_for("a LightSet on the page", Duration::from_secs(30), |s| {
            s["status"] == "connected"
                && s["title"]
                    .as_str()
                    .is_some_and(|t| t.starts_with("vemlight — 64 lights, seq "))
        })
        .await;
    let cells: Vec<&str> = s["cells"]
        .as_array()
        .expect("cells")
        .iter()
        .filter_map(|c| c.as_str())
        .collect();
    for cell in [
        "64 (voronoi, sphere domain)",
        "synthetic:256x128",
        "binomial, 9 taps, delay 133 ms",
    ] {
        assert!(cells.contains(&cell), "the table lacks {cell}: {s}");
    }
    let problems = cdp.problems(|_| false);
    assert!(
        problems.is_empty(),
        "the page reported errors: {problems:?}"
    );
    drop(chrome);
    let _ = std::fs::remove_dir_all(&profile);
}
