//! Daemon figures: `cargo bench --bench serve` (docs/PERFORMANCE.md).
//!
//! 1. End-to-end latency from a frame entering the pipeline to a WebSocket client receiving its
//!    LightSet, on loopback, p50 and p99, with 1 and 100 clients, frames at 30/s, for three
//!    feeds: sunrise.exr re-emitted whole, the same as raw frames through a pipe (a camera
//!    pipeline) and the synthetic sky; the last two are resampled by rows as they arrive, and a
//!    frame enters when its last rows are in. The temporal filter's signal delay is not part of
//!    it (it is (taps−1)/2 frames, stated in each LightSet).
//! 2. Sustained frames/s of the synthetic source at 1024×512 → 256 lights on one core (render,
//!    extract, filter, serialise, in one thread).
//! 3. POST /v1/lights requests/s for a 1024×512 EXR with 4 concurrent clients.
//!
//! Beside 1, the floor under its delivery part on the same machine: a bare tokio-tungstenite
//! broadcast of a message of the same size to the same clients (`VEMLIGHT_BENCH_FLOOR_LENS=500,8760`
//! runs only that, at the sizes given). `VEMLIGHT_BENCH_ROUNDS=3` runs 1 and the floor three times
//! over and ends with each line's median over the rounds, how many rounds met the 5 ms target, and
//! the ratio to the floor's p99 from the same rounds: on a shared host the rounds show the noise.

use futures_util::StreamExt;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use vemlight::capture::files::FileSource;
use vemlight::capture::stdin::{RawPixel, RawSource};
use vemlight::capture::synthetic::SyntheticSource;
use vemlight::capture::{FrameSource, pace};
use vemlight::daemon::{self, Hub, PipelineConfig};
use vemlight::envmap::{DEFAULT_MAX_PIXELS, EnvMap};
use vemlight::eval::speed::median;
use vemlight::lights::{Extractor, Method};
use vemlight::lightset::{LightSet, now_ns};
use vemlight::mapping::Domain;
use vemlight::metrics::HistogramCounts;
use vemlight::server::{AppState, Uploads, WsConfig, run};
use vemlight::sky::{SyntheticConfig, SyntheticSky};
use vemlight::temporal::{FilterSpec, TemporalFilter};

const MAP: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/sunrise.exr");

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let k = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[k]
}

/// Where the benchmarked daemon's frames come from.
#[derive(Clone, Copy, PartialEq)]
enum Feed {
    /// sunrise.exr re-emitted at the frame rate: each frame lands whole.
    File,
    /// The same map as raw rgbf32le frames written into a pipe at the frame rate by another
    /// thread, as a camera pipeline (`ffmpeg … | vemlight serve --source stdin`) feeds the
    /// daemon: each frame is read and resampled a batch of rows at a time as it arrives.
    Pipe,
    /// The built-in synthetic sky (`vemlight serve` with no arguments), 1024×512: each frame is
    /// rendered and resampled a batch of rows at a time.
    Synthetic,
}

/// Writes `map` as raw rgbf32le frames into `pipe` at `fps` until the reader goes away.
fn write_frames(mut pipe: std::io::PipeWriter, map: &EnvMap, fps: f64) {
    use std::io::Write;
    let bytes: Vec<u8> = map
        .pixels
        .iter()
        .flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes()))
        .collect();
    let mut next = Instant::now();
    loop {
        pace(&mut next, fps);
        if pipe.write_all(&bytes).is_err() {
            return;
        }
    }
}

async fn start_server(
    fps: f64,
    cfg: PipelineConfig,
    feed: Feed,
) -> (std::net::SocketAddr, Arc<Hub>) {
    let path = std::path::Path::new(MAP);
    let source: Box<dyn FrameSource> = match feed {
        Feed::File => Box::new(
            FileSource::open(path, None, DEFAULT_MAX_PIXELS, fps).expect("tests/data/sunrise.exr"),
        ),
        Feed::Synthetic => Box::new(SyntheticSource::new(SyntheticConfig::default(), fps)),
        Feed::Pipe => {
            let map = EnvMap::open(path, None, DEFAULT_MAX_PIXELS).expect("tests/data/sunrise.exr");
            let (reader, writer) = std::io::pipe().unwrap();
            let (w, h, projection) = (map.width, map.height, map.projection);
            std::thread::spawn(move || write_frames(writer, &map, fps));
            Box::new(RawSource::new(reader, w, h, RawPixel::Rgbf32le, projection, "pipe").unwrap())
        }
    };
    let hub = Hub::new(64, 16, &source.describe());
    daemon::spawn(source, hub.clone(), cfg).unwrap();
    let state = AppState::new(
        hub.clone(),
        None,
        Uploads::new(64 << 20, DEFAULT_MAX_PIXELS, 4),
        WsConfig::default(),
    );
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { run(listener, state, std::future::pending()).await.unwrap() });
    (addr, hub)
}

/// An integer field of a LightSet document, read without parsing the rest.
fn int_field(json: &str, name: &str) -> u64 {
    let key = format!("\"{name}\":");
    let at = json.find(&key).expect("the field") + key.len();
    json[at..]
        .trim_start()
        .chars()
        .take_while(|c| c.is_ascii_digit())
        .collect::<String>()
        .parse()
        .expect("an integer")
}

/// (end-to-end, of which in the pipeline) latencies in ms seen by `clients` clients over `secs`
/// seconds.
async fn latency(addr: std::net::SocketAddr, clients: usize, secs: f64) -> Vec<(f64, f64)> {
    let mut tasks = Vec::new();
    for _ in 0..clients {
        let url = format!("ws://{addr}/v1/stream");
        tasks.push(tokio::spawn(async move {
            // A LightSet is ~10 KB: tungstenite's default 128 KiB read buffer would be zeroed on
            // every read, loading the machine being measured (docs/API.md, "Writing a client").
            let config = WebSocketConfig::default().read_buffer_size(16 * 1024);
            let (mut ws, _) = tokio_tungstenite::connect_async_with_config(url, Some(config), true)
                .await
                .unwrap();
            let mut out = Vec::new();
            let start = Instant::now();
            // Skip the first message: it may be an older set sent on connect.
            let mut first = true;
            while start.elapsed().as_secs_f64() < secs {
                let Ok(Some(Ok(msg))) =
                    tokio::time::timeout(Duration::from_secs(2), ws.next()).await
                else {
                    break;
                };
                let received = now_ns();
                if let Message::Text(t) = msg {
                    // Read only the timestamp: parsing 100 documents per frame would load the
                    // machine that is being measured.
                    let captured = int_field(t.as_str(), "t_capture_ns");
                    let emitted = int_field(t.as_str(), "t_emit_ns");
                    if !first {
                        out.push((
                            received.saturating_sub(captured) as f64 * 1e-6,
                            emitted.saturating_sub(captured) as f64 * 1e-6,
                        ));
                    }
                    first = false;
                }
            }
            out
        }));
    }
    let mut all = Vec::new();
    for t in tasks {
        all.extend(t.await.unwrap());
    }
    all
}

fn sustained_synthetic(frames: usize) -> (f64, f64) {
    let mut sky = SyntheticSky::new(SyntheticConfig::default());
    let mut map = sky.render(0.0);
    let mut ex = Extractor::new(); // resamples on this thread: one core
    ex.set_video(true);
    let mut filter = TemporalFilter::new(&FilterSpec::default());
    let mut render_s = 0.0;
    let start = Instant::now();
    for k in 0..frames {
        let t = Instant::now();
        sky.render_into(k as f64 / 30.0, &mut map);
        render_s += t.elapsed().as_secs_f64();
        let exs = ex.extract_many(&map, Domain::Sphere, Method::Voronoi, &[256]);
        let lights = filter.filter(&exs[0].lights);
        let set = LightSet::new(
            lights,
            &map,
            Method::Voronoi,
            Domain::Sphere,
            "synthetic",
            256,
            exs[0].side,
        );
        std::hint::black_box(serde_json::to_string(&set).unwrap());
    }
    let total = start.elapsed().as_secs_f64();
    (frames as f64 / total, render_s / frames as f64)
}

async fn post_throughput(
    addr: std::net::SocketAddr,
    concurrency: usize,
    secs: f64,
) -> (f64, Vec<f64>) {
    let body = std::fs::read(MAP).unwrap();
    let client = reqwest::Client::new();
    let start = Instant::now();
    let mut tasks = Vec::new();
    for _ in 0..concurrency {
        let (c, b) = (client.clone(), body.clone());
        let url = format!("http://{addr}/v1/lights?lights=64");
        tasks.push(tokio::spawn(async move {
            let mut times = Vec::new();
            while start.elapsed().as_secs_f64() < secs {
                let t = Instant::now();
                let r = c.post(&url).body(b.clone()).send().await.unwrap();
                assert_eq!(r.status(), 200);
                r.bytes().await.unwrap();
                times.push(t.elapsed().as_secs_f64() * 1e3);
            }
            times
        }));
    }
    let mut times = Vec::new();
    for t in tasks {
        times.extend(t.await.unwrap());
    }
    (times.len() as f64 / start.elapsed().as_secs_f64(), times)
}

/// The floor under the daemon's fan-out on the same host: a bare tokio-tungstenite server with
/// no pipeline and no HTTP routing that, from a thread of its own, publishes a message of
/// `len` bytes every `1/fps` s on a `watch` channel, each client's task sending it on (the
/// daemon's stream loop without pings, limits or metrics). The message carries the same two
/// timestamp fields, both set when it is published, so the same clients measure it. Dropping the
/// returned [`BareBroadcast`] stops it.
fn start_bare_broadcast(fps: f64, len: usize) -> BareBroadcast {
    use futures_util::SinkExt;
    let (tx, rx) =
        tokio::sync::watch::channel::<Option<tokio_tungstenite::tungstenite::Utf8Bytes>>(None);
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    listener.set_nonblocking(true).unwrap();
    let accept = tokio::spawn(async move {
        let listener = tokio::net::TcpListener::from_std(listener).unwrap();
        loop {
            let (stream, _) = listener.accept().await.unwrap();
            stream.set_nodelay(true).unwrap();
            let mut rx = rx.clone();
            tokio::spawn(async move {
                let config = WebSocketConfig::default().read_buffer_size(4 * 1024);
                let Ok(mut ws) =
                    tokio_tungstenite::accept_async_with_config(stream, Some(config)).await
                else {
                    return;
                };
                while rx.changed().await.is_ok() {
                    let Some(msg) = rx.borrow_and_update().clone() else {
                        continue;
                    };
                    if ws.send(Message::Text(msg)).await.is_err() {
                        return;
                    }
                }
            });
        }
    });
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stopped = stop.clone();
    // Returning drops `tx`, which ends every client's task.
    std::thread::spawn(move || {
        let period = Duration::from_secs_f64(1.0 / fps);
        let mut next = Instant::now();
        while !stopped.load(std::sync::atomic::Ordering::Relaxed) {
            next += period;
            std::thread::sleep(next.saturating_duration_since(Instant::now()));
            let t = now_ns();
            let head = format!("{{\"t_capture_ns\":{t},\"t_emit_ns\":{t},\"pad\":\"");
            let mut msg = head.clone();
            msg.extend(std::iter::repeat_n('x', len.saturating_sub(head.len() + 2)));
            msg.push_str("\"}");
            if tx.send(Some(msg.into())).is_err() {
                return;
            }
        }
    });
    BareBroadcast { addr, stop, accept }
}

/// A running [`start_bare_broadcast`] server; dropping it stops the publisher and the listener.
struct BareBroadcast {
    addr: std::net::SocketAddr,
    stop: Arc<std::sync::atomic::AtomicBool>,
    accept: tokio::task::JoinHandle<()>,
}

impl Drop for BareBroadcast {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        self.accept.abort();
    }
}

/// Message sizes in bytes, comma-separated: run only the floor (see [`start_bare_broadcast`]),
/// once per size.
const FLOOR_LENS_ENV: &str = "VEMLIGHT_BENCH_FLOOR_LENS";

/// Set in the child process that runs the clients apart from the server:
/// "ADDR CLIENTS SECONDS THREADS" (THREADS 1: a current-thread runtime; 0: one worker per core).
const CLIENTS_ENV: &str = "VEMLIGHT_BENCH_CLIENTS";

/// The clients of [`latency`] in a second process (this executable again, with [`CLIENTS_ENV`]), as
/// a deployment has them: the server's runtime then schedules only the server's tasks.
async fn latency_from_another_process(
    addr: std::net::SocketAddr,
    clients: usize,
    secs: f64,
    threads: usize,
) -> Vec<(f64, f64)> {
    let out = tokio::process::Command::new(std::env::current_exe().unwrap())
        .arg("--bench")
        .env(CLIENTS_ENV, format!("{addr} {clients} {secs} {threads}"))
        .output()
        .await
        .expect("the client process");
    assert!(out.status.success(), "client process failed");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let (a, b) = l.split_once(' ')?;
            Some((a.parse().ok()?, b.parse().ok()?))
        })
        .collect()
}

/// Prints one latency line; `server` is what the daemon's own delivery histogram (`/metrics`,
/// `vemlight_ws_delivery_seconds`) saw over the same messages: frame → handed to the socket.
fn report(label: &str, samples: &[(f64, f64)], server: Option<&HistogramCounts>) -> (f64, f64) {
    let sorted = |f: fn(&(f64, f64)) -> f64| {
        let mut v: Vec<f64> = samples.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let total = sorted(|s| s.0);
    let pipeline = sorted(|s| s.1);
    let delivery = sorted(|s| s.0 - s.1);
    println!(
        "  {label}: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms over {} messages",
        percentile(&total, 0.5),
        percentile(&total, 0.99),
        total.last().copied().unwrap_or(f64::NAN),
        total.len(),
    );
    println!(
        "    in the pipeline (capture → document): p50 {:.2} ms, p99 {:.2} ms; \
         delivery (document → received): p50 {:.2} ms, p99 {:.2} ms",
        percentile(&pipeline, 0.5),
        percentile(&pipeline, 0.99),
        percentile(&delivery, 0.5),
        percentile(&delivery, 0.99),
    );
    if let Some(server) = server {
        println!(
            "    the daemon's delivery histogram: {:.1} % written to the socket within 5 ms, p99 ≤ {} ms",
            100.0 * server.fraction_within(0.005),
            server.quantile_bound(0.99) * 1e3,
        );
    }
    (percentile(&total, 0.5), percentile(&total, 0.99))
}

/// Rounds of the latency part (`VEMLIGHT_BENCH_ROUNDS`, default 1): each runs every feed and the
/// floor again, and the end prints each line's median over the rounds beside the floor's.
const ROUNDS_ENV: &str = "VEMLIGHT_BENCH_ROUNDS";

/// Each latency line's (p50, p99) in ms per round, in the order first measured.
#[derive(Default)]
struct Rounds(Vec<(String, Vec<(f64, f64)>)>);

impl Rounds {
    fn add(&mut self, label: String, p: (f64, f64)) {
        match self.0.iter_mut().find(|(l, _)| *l == label) {
            Some((_, v)) => v.push(p),
            None => self.0.push((label, vec![p])),
        }
    }

    fn get(&self, label: &str) -> Option<&[(f64, f64)]> {
        self.0
            .iter()
            .find(|(l, _)| l == label)
            .map(|(_, v)| v.as_slice())
    }

    /// The median over rounds of each line's p50 and p99, the p99's range, how many rounds
    /// were under `target_ms` at p99, and the ratio of the median p99 to the floor's (the line
    /// named `floor_of(label)`, measured in the same rounds with the same clients).
    fn print(&self, target_ms: f64, floor_of: impl Fn(&str) -> Option<String>) {
        let med = |mut v: Vec<f64>| median(&mut v);
        for (label, v) in &self.0 {
            let p50 = med(v.iter().map(|p| p.0).collect());
            let p99s: Vec<f64> = v.iter().map(|p| p.1).collect();
            let p99 = med(p99s.clone());
            let (lo, hi) = p99s
                .iter()
                .fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
            let under = p99s.iter().filter(|&&x| x < target_ms).count();
            let floor = floor_of(label)
                .and_then(|f| self.get(&f))
                .map(|f| med(f.iter().map(|p| p.1).collect()));
            let ratio = floor.map_or(String::new(), |f| {
                format!(", {:.2} × the floor's p99", p99 / f)
            });
            println!(
                "  {label}: p50 {p50:.2} ms, p99 {p99:.2} ms ({lo:.2}–{hi:.2}), p99 < {target_ms} ms in {under} of {} rounds{ratio}",
                v.len()
            );
        }
    }
}

/// One round of the latency figures: every feed, then the floor at the LightSet's size. Records
/// each line's (p50, p99) in `lines` and returns the LightSet's size.
async fn latency_round(lines: &mut Rounds, mut message_len: usize) -> usize {
    // The default pipeline, then without the Lloyd steps (`serve --refine 0`), then fed by
    // a camera pipe.
    let default_refine = PipelineConfig::default().refine;
    for (refine, feed) in [
        (default_refine, Feed::File),
        (0, Feed::File),
        (default_refine, Feed::Pipe),
        (default_refine, Feed::Synthetic),
    ] {
        let cfg = PipelineConfig {
            refine,
            ..PipelineConfig::default()
        };
        let (addr, hub) = start_server(30.0, cfg, feed).await;
        tokio::time::sleep(Duration::from_secs(1)).await;
        message_len = hub.latest().map_or(message_len, |p| p.json.len());
        let fed = match feed {
            Feed::File => "sunrise.exr, whole frames",
            Feed::Pipe => "sunrise.exr as raw rgbf32le frames through a pipe, by rows",
            Feed::Synthetic => "the synthetic sky, 1024×512, by rows",
        };
        let short = match (feed, refine) {
            (Feed::File, 0) => "whole file, 0 Lloyd steps",
            (Feed::File, _) => "whole file",
            (Feed::Pipe, _) => "pipe",
            (Feed::Synthetic, _) => "synthetic",
        };
        println!(
            "end-to-end latency, frame captured → LightSet received (64 lights, 30 frames/s, loopback, {refine} Lloyd steps; {fed})"
        );
        for clients in [1, 100] {
            let before = hub.metrics.ws_delivery.snapshot();
            let samples = latency(addr, clients, 8.0).await;
            let server = hub.metrics.ws_delivery.snapshot().since(&before);
            let label = format!("{clients:>3} client(s)");
            let p = report(&label, &samples, Some(&server));
            lines.add(format!("{short}: {}", label.trim()), p);
        }
        for (threads, label) in [
            (0, "100 client(s) in a second process"),
            (1, "100 client(s) in a second process, one thread"),
        ] {
            let before = hub.metrics.ws_delivery.snapshot();
            let samples = latency_from_another_process(addr, 100, 8.0, threads).await;
            let server = hub.metrics.ws_delivery.snapshot().since(&before);
            let p = report(label, &samples, Some(&server));
            lines.add(format!("{short}: {label}"), p);
        }
        let m = &hub.metrics;
        println!(
            "  frames captured {}, processed {}, dropped {}",
            m.frames_captured.load(std::sync::atomic::Ordering::Relaxed),
            m.frames_processed
                .load(std::sync::atomic::Ordering::Relaxed),
            m.frames_dropped.load(std::sync::atomic::Ordering::Relaxed)
        );
        println!(
            "  mean stage times: resample {:.2} ms, warp {:.2} ms, assign {:.2} ms, sh {:.2} ms, \
                 filter {:.3} ms, document {:.3} ms",
            m.stage_resample.mean_ms(),
            m.stage_warp.mean_ms(),
            m.stage_assign.mean_ms(),
            m.stage_sh.mean_ms(),
            m.stage_filter.mean_ms(),
            m.stage_publish.mean_ms(),
        );
        hub.shutdown();
    }

    // The machine's floor for the fan-out (see start_bare_broadcast).
    let bare = start_bare_broadcast(30.0, message_len);
    println!(
        "the floor: a bare tokio-tungstenite server broadcasting a {message_len}-byte message 30 times/s (no pipeline)"
    );
    for (threads, label) in [
        (0, "100 client(s) in a second process"),
        (1, "100 client(s) in a second process, one thread"),
    ] {
        let samples = latency_from_another_process(bare.addr, 100, 8.0, threads).await;
        let p = report(label, &samples, None);
        lines.add(format!("the floor: {label}"), p);
    }
    drop(bare);

    message_len
}

fn main() {
    // `cargo test` runs benches in test mode with `--bench` absent: do nothing then.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    if let Ok(spec) = std::env::var(CLIENTS_ENV) {
        // The client process: print "total pipeline" per message.
        let mut it = spec.split(' ');
        let addr = it.next().unwrap().parse().unwrap();
        let clients = it.next().unwrap().parse().unwrap();
        let secs = it.next().unwrap().parse().unwrap();
        let rt = match it.next() {
            Some("1") => tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap(),
            _ => tokio::runtime::Runtime::new().unwrap(),
        };
        for (t, p) in rt.block_on(latency(addr, clients, secs)) {
            println!("{t} {p}");
        }
        return;
    }
    if let Ok(lens) = std::env::var(FLOOR_LENS_ENV) {
        // Only the floor, at each message size given: what the fan-out costs per byte.
        let rt = tokio::runtime::Runtime::new().unwrap();
        rt.block_on(async {
            for len in lens
                .split(',')
                .filter_map(|l| l.trim().parse::<usize>().ok())
            {
                let bare = start_bare_broadcast(30.0, len);
                let samples = latency_from_another_process(bare.addr, 100, 8.0, 0).await;
                report(
                    &format!("the floor, {len}-byte messages, 100 clients in a second process"),
                    &samples,
                    None,
                );
            }
        });
        return;
    }
    let rounds: usize = std::env::var(ROUNDS_ENV)
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(1)
        .max(1);
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let mut lines = Rounds::default();
        let mut message_len = 0;
        for round in 1..=rounds {
            if rounds > 1 {
                println!("round {round} of {rounds}");
            }
            message_len = latency_round(&mut lines, message_len).await;
        }
        if rounds > 1 {
            println!("over {rounds} rounds, the median of each line:");
            lines.print(5.0, |label| {
                let clients = label.split_once(": ")?.1;
                (!label.starts_with("the floor")).then(|| format!("the floor: {clients}"))
            });
        }

        let (addr, hub) = start_server(1.0, PipelineConfig::default(), Feed::File).await;
        let (rps, mut times) = post_throughput(addr, 4, 10.0).await;
        println!(
            "POST /v1/lights, 1024x512 DWAB EXR, 64 lights, 4 concurrent clients: {rps:.1} requests/s, median {:.1} ms per request",
            median(&mut times)
        );
        hub.shutdown();
    });
    let (fps, render) = sustained_synthetic(300);
    println!(
        "synthetic source 1024x512 → 256 lights, one thread (render + extract + filter + JSON): {fps:.1} frames/s (sky render {:.2} ms/frame)",
        render * 1e3
    );
}
