//! What one daemon takes at once, as clients see it: the WebSocket client cap (`--max-clients`),
//! the connection cap of the accept loop (`--max-connections`) and the share of light counts
//! `/v1/lights/latest` may take from streams. The real server on 127.0.0.1 (port 0), real
//! WebSocket and TCP clients, the real pipeline on a small synthetic sky.

mod common;

use common::{Ws, get_json, status_line, stream_request};
use futures_util::{SinkExt, StreamExt};
use std::net::SocketAddr;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};
use vemlight::capture::synthetic::SyntheticSource;
use vemlight::capture::{FrameSource, SourceError};
use vemlight::daemon::{self, Hub, PipelineConfig};
use vemlight::envmap::EnvMap;
use vemlight::server::{AppState, Limits, Uploads, WsConfig, run};
use vemlight::sky::SyntheticConfig;

/// A small synthetic sky at 20 frames/s, held back until `gate` says go (or its sender is gone).
struct GatedSky {
    gate: Option<mpsc::Receiver<()>>,
    sky: SyntheticSource,
}

impl FrameSource for GatedSky {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, SourceError> {
        if let Some(gate) = self.gate.take() {
            let _ = gate.recv();
        }
        self.sky.next_frame(out)
    }

    fn describe(&self) -> String {
        "gated synthetic".into()
    }

    fn nominal_fps(&self) -> f64 {
        20.0
    }
}

/// Serves a daemon with `limits` whose frames start when `gate` opens (at once without one).
async fn start(limits: Limits, gate: Option<mpsc::Receiver<()>>) -> SocketAddr {
    let sky = SyntheticSource::new(
        SyntheticConfig {
            width: 128,
            height: 64,
            ..SyntheticConfig::default()
        },
        20.0,
    );
    let hub = Hub::new(64, daemon::MAX_LIGHT_COUNTS, "gated synthetic");
    daemon::spawn(
        Box::new(GatedSky { gate, sky }),
        hub.clone(),
        PipelineConfig::default(),
    )
    .unwrap();
    let mut state = AppState::new(
        hub,
        None,
        Uploads::new(1 << 20, 1 << 20, 1),
        WsConfig::default(),
    )
    .with_limits(limits);
    // Long enough that the idle sockets of a test are not closed under it.
    state.header_read_timeout = Duration::from_secs(5);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { run(listener, state, std::future::pending()).await.unwrap() });
    addr
}

/// A WebSocket handshake for `/v1/stream{query}` with the vemlight subprotocol.
async fn connect(addr: SocketAddr, query: &str) -> Result<Ws, WsError> {
    tokio_tungstenite::connect_async(stream_request(addr, query))
        .await
        .map(|(ws, _)| ws)
}

/// The next LightSet from a stream, within 5 s.
async fn next_set(ws: &mut Ws) -> serde_json::Value {
    common::next_set(ws, Duration::from_secs(5)).await
}

/// A refused handshake's problem document, checked to be a 503 problem+json telling the client
/// when to retry.
fn refused_handshake(attempt: Result<Ws, WsError>) -> serde_json::Value {
    let resp = match attempt {
        Err(WsError::Http(resp)) => resp,
        Err(e) => panic!("refused without an HTTP answer: {e}"),
        Ok(_) => panic!("a handshake past the cap was accepted"),
    };
    assert_eq!(resp.status(), 503);
    assert_eq!(
        resp.headers().get("content-type").unwrap(),
        "application/problem+json"
    );
    assert_eq!(resp.headers().get("retry-after").unwrap(), "5");
    let body = resp.body().as_deref().expect("a body");
    let doc: serde_json::Value = serde_json::from_slice(body).expect("a JSON body");
    assert_eq!(doc["status"], 503);
    doc
}

/// The value of the metric line `name` in `GET /metrics`.
async fn metric(c: &reqwest::Client, addr: SocketAddr, name: &str) -> u64 {
    let text = c
        .get(format!("http://{addr}/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
        .unwrap_or_else(|| panic!("{name} in\n{text}"))
}

/// Polls `/healthz` until `field` is `want`, for up to 5 s.
async fn wait_health(c: &reqwest::Client, addr: SocketAddr, field: &str, want: u64) {
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let h = get_json(c, &format!("http://{addr}/healthz")).await;
        if h[field] == want {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "{field} never became {want}: {h}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// With `--max-clients 3`, three clients stream and a fourth handshake is answered 503 with a
/// problem document before any upgrade, counted in /metrics; the three go on receiving. Once one
/// leaves, handshakes racing for its slot get exactly one client in.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_client_cap_refuses_one_more_and_frees_a_slot_when_a_client_leaves() {
    let addr = start(Limits::new(3, 32).unwrap(), None).await;
    let c = reqwest::Client::new();
    let mut clients = Vec::new();
    for _ in 0..3 {
        clients.push(connect(addr, "?lights=8").await.expect("within the cap"));
    }
    for ws in &mut clients {
        next_set(ws).await;
    }
    let doc = refused_handshake(connect(addr, "?lights=8").await);
    let detail = doc["detail"].as_str().unwrap();
    assert!(detail.contains("at most 3 WebSocket clients"), "{detail}");

    // The three keep streaming.
    for ws in &mut clients {
        let mut last = 0;
        for _ in 0..3 {
            let doc = next_set(ws).await;
            assert_eq!(doc["lights"].as_array().unwrap().len(), 8);
            let seq = doc["seq"].as_u64().unwrap();
            assert!(seq > last, "seq {seq} after {last}");
            last = seq;
        }
    }
    let health = get_json(&c, &format!("http://{addr}/healthz")).await;
    assert_eq!(health["ws_clients"], 3, "{health}");
    assert_eq!(health["max_ws_clients"], 3, "{health}");
    assert_eq!(health["max_connections"], 32, "{health}");
    // The three clients and this request's connection at least.
    assert!(health["connections"].as_u64().unwrap() >= 4, "{health}");
    assert_eq!(
        metric(&c, addr, "vemlight_ws_clients_refused_total").await,
        1
    );
    assert_eq!(metric(&c, addr, "vemlight_ws_clients").await, 3);
    assert_eq!(metric(&c, addr, "vemlight_ws_clients_max").await, 3);

    // One leaves; its slot frees when its loop ends.
    let mut gone = clients.pop().unwrap();
    gone.close(None).await.unwrap();
    while let Some(Ok(_)) = gone.next().await {}
    wait_health(&c, addr, "ws_clients", 2).await;
    let attempts = futures_util::future::join_all((0..5).map(|_| connect(addr, "?lights=8"))).await;
    let (admitted, refused): (Vec<_>, Vec<_>) = attempts.into_iter().partition(Result::is_ok);
    assert_eq!((admitted.len(), refused.len()), (1, 4));
    for r in refused {
        refused_handshake(r);
    }
    let mut newcomer = admitted.into_iter().next().unwrap().unwrap();
    assert_eq!(
        next_set(&mut newcomer).await["lights"]
            .as_array()
            .unwrap()
            .len(),
        8
    );
    for ws in &mut clients {
        next_set(ws).await;
    }
    assert_eq!(
        metric(&c, addr, "vemlight_ws_clients_refused_total").await,
        5
    );
    assert_eq!(metric(&c, addr, "vemlight_ws_clients").await, 3);
}

/// With `--max-connections 3`, a WebSocket client and two idle sockets fill the cap: a further
/// request is left in the listen backlog, unanswered, until a connection ends — here the
/// WebSocket's, which counts until it ends — and is then served. The pause and the open
/// connections are in /metrics.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_connection_cap_leaves_more_connections_waiting_until_one_closes() {
    let addr = start(Limits::new(2, 3).unwrap(), None).await;
    let mut ws = connect(addr, "").await.unwrap();
    next_set(&mut ws).await;
    let idle = [
        TcpStream::connect(addr).await.unwrap(),
        TcpStream::connect(addr).await.unwrap(),
    ];
    // The kernel completes the TCP handshake; the daemon does not take the connection.
    let mut waiting = TcpStream::connect(addr).await.unwrap();
    waiting
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut buf = [0u8; 256];
    let early = tokio::time::timeout(Duration::from_millis(1500), waiting.read(&mut buf)).await;
    assert!(
        early.is_err(),
        "answered past the cap: {:?}",
        early.map(|n| String::from_utf8_lossy(&buf[..n.unwrap_or(0)]).to_string())
    );
    // The WebSocket client leaves: its connection's slot goes to the waiting request.
    ws.close(None).await.unwrap();
    while let Some(Ok(_)) = ws.next().await {}
    let line = status_line(&mut waiting, Duration::from_secs(3)).await;
    assert!(line.starts_with("HTTP/1.1 200"), "'{line}'");
    drop(idle);
    drop(waiting);

    let c = reqwest::Client::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    // Only the metrics request's own connection is left.
    while metric(&c, addr, "vemlight_connections_open").await != 1 {
        assert!(Instant::now() < deadline, "connections never closed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(metric(&c, addr, "vemlight_accept_paused_total").await >= 1);
    assert_eq!(metric(&c, addr, "vemlight_connections_max").await, 3);
}

/// A `/v1/lights/latest` answer: the light count asked for, the status, the content type, the
/// Retry-After header and the document.
type Answer = (
    usize,
    u16,
    Option<String>,
    Option<String>,
    serde_json::Value,
);

/// The next answer, within 1.5 s (less than the 2 s an admitted request waits for its set).
async fn next_answer(answers: &mut tokio::sync::mpsc::UnboundedReceiver<Answer>) -> Answer {
    tokio::time::timeout(Duration::from_millis(1500), answers.recv())
        .await
        .expect("an answer in time")
        .expect("an answer")
}

/// A burst of 20 `/v1/lights/latest` requests for distinct light counts no stream has, before
/// any frame (so each admitted one holds its count for the whole wait): four take a count, the
/// rest are answered 503 at once; a stream asking for yet another count meanwhile gets in. Once
/// frames come, the four and the stream get their sets.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_latest_counts_does_not_crowd_out_streams() {
    let (open, gate) = mpsc::channel();
    let addr = start(Limits::new(8, 64).unwrap(), Some(gate)).await;
    let c = reqwest::Client::new();
    let (tx, mut answers) = tokio::sync::mpsc::unbounded_channel();
    for lights in 2..22 {
        let (c, tx) = (c.clone(), tx.clone());
        tokio::spawn(async move {
            let resp = c
                .get(format!("http://{addr}/v1/lights/latest?lights={lights}"))
                .send()
                .await
                .unwrap();
            let status = resp.status().as_u16();
            let header = |name| {
                resp.headers()
                    .get(name)
                    .map(|v| v.to_str().unwrap().to_string())
            };
            let (content_type, retry_after) = (header("content-type"), header("retry-after"));
            let doc: serde_json::Value = resp.json().await.unwrap();
            let _ = tx.send((lights, status, content_type, retry_after, doc));
        });
    }
    drop(tx);
    let mut refused = Vec::new();
    for _ in 0..16 {
        let (lights, status, content_type, retry_after, doc) = next_answer(&mut answers).await;
        assert_eq!(status, 503, "lights={lights}: {doc}");
        assert_eq!(content_type.unwrap(), "application/problem+json");
        assert_eq!(retry_after.unwrap(), "2", "lights={lights}: {doc}");
        refused.push(lights);
    }
    // Four counts are held by the requests still waiting; a stream takes a fifth.
    let mut ws = connect(addr, "?lights=40")
        .await
        .expect("a stream gets a light count after the burst");
    open.send(()).unwrap();
    for _ in 0..4 {
        let (lights, status, _, _, doc) = next_answer(&mut answers).await;
        assert_eq!(status, 200, "lights={lights}: {doc}");
        assert!(!refused.contains(&lights));
        assert_eq!(doc["lights"].as_array().unwrap().len(), lights);
    }
    assert_eq!(
        next_set(&mut ws).await["lights"].as_array().unwrap().len(),
        40
    );
    // The stream's count is free for /latest, whatever the share.
    let doc = get_json(&c, &format!("http://{addr}/v1/lights/latest?lights=40")).await;
    assert_eq!(doc["lights"].as_array().unwrap().len(), 40);
    assert_eq!(metric(&c, addr, "vemlight_latest_refused_total").await, 16);
    ws.send(Message::Close(None)).await.unwrap();
}

/// Starts the binary, `vemlight serve --bind 127.0.0.1:0 ARGS` with `env`, under a soft
/// descriptor limit of `nofile` (`ulimit -n`); its address once it listens, or its exit and
/// standard error if it does not start.
fn serve_under_ulimit(
    nofile: u32,
    args: &[&str],
    env: &[(&str, &str)],
) -> Result<(std::process::Child, SocketAddr), String> {
    let mut sh = std::process::Command::new("sh");
    sh.arg("-c")
        .arg(format!("ulimit -n {nofile} && exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_vemlight"));
    common::try_spawn_serve(sh, &[&["--sky-size", "64x32"], args].concat(), env)
}

/// The binary's caps: by default from the descriptor limit (1024: 704 clients, 768
/// connections), from `--max-clients` (connections 64 more), `VEMLIGHT_MAX_CLIENTS` and
/// `--max-connections`; more clients than connections is a configuration error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_sizes_its_caps_from_flags_and_the_descriptor_limit() {
    let c = reqwest::Client::new();
    for (args, env, want) in [
        (&[][..], &[][..], (704, 768)),
        (&["--max-clients", "2"][..], &[][..], (2, 66)),
        (
            &["--max-connections", "9"][..],
            &[("VEMLIGHT_MAX_CLIENTS", "3")][..],
            (3, 9),
        ),
    ] {
        let (mut child, addr) = serve_under_ulimit(1024, args, env).unwrap();
        // Before the first set /healthz is 503, with the same document.
        let h = get_json(&c, &format!("http://{addr}/healthz")).await;
        child.kill().unwrap();
        child.wait().unwrap();
        assert_eq!(
            (h["max_ws_clients"].as_u64(), h["max_connections"].as_u64()),
            (Some(want.0), Some(want.1)),
            "{args:?} {env:?}: {h}"
        );
    }
    let err = serve_under_ulimit(1024, &["--max-clients", "5", "--max-connections", "4"], &[])
        .map(|_| ())
        .unwrap_err();
    assert!(
        err.contains("--max-clients 5 is more than --max-connections 4"),
        "{err}"
    );
}
