//! Headless Chromium for the browser tests: finding it (or skipping without it), and a
//! DevTools-protocol (remote debugging) client to drive one page.

use super::{Killed, stderr_lines};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

/// The first of `candidates` that runs `--version`.
pub fn first_working(candidates: &[&'static str]) -> Option<&'static str> {
    candidates.iter().copied().find(|b| {
        Command::new(b)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// `tool` if found; otherwise skips (None) with a note, unless `VEMLIGHT_REQUIRE_BROWSER` says
/// the browser tests must run (scripts/test.sh sets it).
pub fn found_or_skip(tool: Option<&'static str>, what: &str) -> Option<&'static str> {
    if tool.is_none() {
        assert!(
            std::env::var_os("VEMLIGHT_REQUIRE_BROWSER").is_none(),
            "VEMLIGHT_REQUIRE_BROWSER is set but no {what} is installed"
        );
        eprintln!("skipped: no {what} on PATH (scripts/test.sh installs it)");
    }
    tool
}

/// The Chromium binary, or None (after the note) where the test is to be skipped.
pub fn browser_or_skip() -> Option<&'static str> {
    found_or_skip(
        first_working(&["chromium", "chromium-browser", "google-chrome"]),
        "chromium",
    )
}

/// The flags every test's Chromium runs with: headless, no sandbox (tests may run as root), no
/// first-run prompts, its profile in `profile`.
pub fn headless_args(profile: &std::path::Path) -> Vec<String> {
    vec![
        "--headless".into(),
        "--no-sandbox".into(),
        "--no-first-run".into(),
        format!("--user-data-dir={}", profile.display()),
    ]
}

/// Headless Chromium (with `flags` as well) on a blank page, and a DevTools session attached to
/// a page of its own, whose state `state_expr` reads (a JSON string, see [`Cdp::state`]).
pub async fn launch(
    browser: &str,
    profile: &std::path::Path,
    flags: &[&str],
    state_expr: &str,
) -> (Killed, Cdp) {
    let mut chrome = Command::new(browser)
        .args(headless_args(profile))
        .args(flags)
        .args(["--remote-debugging-port=0", "about:blank"])
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .expect("runs chromium");
    let rx = stderr_lines(chrome.stderr.take().unwrap());
    let chrome = Killed(chrome);
    let devtools = loop {
        let line = rx
            .recv_timeout(Duration::from_secs(20))
            .expect("chromium prints its DevTools address");
        if let Some(url) = line.strip_prefix("DevTools listening on ") {
            break url.trim().to_string();
        }
    };
    let (ws, _) = tokio_tungstenite::connect_async(devtools.as_str())
        .await
        .expect("DevTools socket");
    let mut cdp = Cdp {
        ws,
        next_id: 0,
        session: None,
        events: Vec::new(),
        state_expr: state_expr.to_string(),
    };
    let target = cdp
        .call("Target.createTarget", json!({ "url": "about:blank" }))
        .await;
    let session = cdp
        .call(
            "Target.attachToTarget",
            json!({ "targetId": target["targetId"], "flatten": true }),
        )
        .await;
    cdp.session = Some(session["sessionId"].as_str().unwrap().to_string());
    cdp.call("Runtime.enable", json!({})).await;
    cdp.call("Log.enable", json!({})).await;
    (chrome, cdp)
}

/// A DevTools-protocol connection to one page (a flattened session of the browser socket).
pub struct Cdp {
    ws: tokio_tungstenite::WebSocketStream<
        tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
    >,
    next_id: u64,
    session: Option<String>,
    /// The events received so far (exceptions, console calls, log entries).
    events: Vec<Value>,
    state_expr: String,
}

impl Cdp {
    /// Calls `method` and waits for its result, keeping the events that come meanwhile.
    pub async fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let mut msg = json!({ "id": id, "method": method, "params": params });
        if let Some(s) = &self.session {
            msg["sessionId"] = json!(s);
        }
        self.ws
            .send(Message::text(msg.to_string()))
            .await
            .expect("send to chromium");
        loop {
            let reply = tokio::time::timeout(Duration::from_secs(30), self.ws.next())
                .await
                .unwrap_or_else(|_| panic!("chromium did not answer {method}"))
                .expect("chromium closed the DevTools socket")
                .expect("DevTools socket");
            let Message::Text(text) = reply else { continue };
            let v: Value = serde_json::from_str(&text).expect("DevTools JSON");
            if v["id"] == id {
                assert!(v["error"].is_null(), "{method} failed: {v}");
                return v["result"].clone();
            }
            if v["method"].is_string() {
                self.events.push(v);
            }
        }
    }

    /// Evaluates `expr` in the page (awaiting a promise) and returns its value, which the
    /// expression gives as a JSON string.
    pub async fn eval(&mut self, expr: &str) -> Value {
        let r = self
            .call(
                "Runtime.evaluate",
                json!({ "expression": expr, "awaitPromise": true, "returnByValue": true }),
            )
            .await;
        assert!(
            r["exceptionDetails"].is_null(),
            "{expr} threw: {}",
            r["exceptionDetails"]
        );
        match r["result"]["value"].as_str() {
            Some(s) => serde_json::from_str(s).expect("the page answers JSON"),
            None => Value::Null,
        }
    }

    /// The page's state, as the expression given at launch reads it.
    pub async fn state(&mut self) -> Value {
        let expr = self.state_expr.clone();
        self.eval(&expr).await
    }

    /// Waits until `ok(state)`, polling; panics with the last state after `limit`.
    pub async fn wait_for(
        &mut self,
        what: &str,
        limit: Duration,
        ok: impl Fn(&Value) -> bool,
    ) -> Value {
        let start = Instant::now();
        loop {
            let s = self.state().await;
            if ok(&s) {
                return s;
            }
            assert!(start.elapsed() < limit, "timed out waiting for {what}: {s}");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }

    /// Navigates the page to `url`.
    pub async fn open(&mut self, url: &str) {
        self.call("Page.navigate", json!({ "url": url })).await;
    }

    /// Errors the page reported: exceptions, console errors, error log entries but those
    /// `expected` accepts.
    pub fn problems(&self, expected: impl Fn(&Value) -> bool) -> Vec<&Value> {
        self.events
            .iter()
            .filter(|e| match e["method"].as_str() {
                Some("Runtime.exceptionThrown") => true,
                Some("Runtime.consoleAPICalled") => {
                    matches!(e["params"]["type"].as_str(), Some("error" | "assert"))
                }
                Some("Log.entryAdded") => {
                    let entry = &e["params"]["entry"];
                    entry["level"] == "error" && !expected(entry)
                }
                _ => false,
            })
            .collect()
    }
}
