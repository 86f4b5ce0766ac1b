//! Fan-out figures: `cargo bench --bench fanout` (docs/PERFORMANCE.md, "Fan-out: broker vs the
//! daemon's WebSocket"; docs/SCALING.md).
//!
//! Starts a real nats-server and the release `vemlight serve` (synthetic sky, 30 frames/s, 64
//! lights, publishing to the broker as camera `bench`) as child processes. Then, one case at a
//! time, S subscribers in this process on a multi-thread runtime: S NATS connections, each
//! subscribed to `vemlight.v1.bench.lights.64`, or S WebSocket clients on the daemon's own
//! `/v1/stream?lights=64`. After a warm-up each case records for a window: sets received per
//! subscriber against sets produced (the daemon's `seq`), the time from capture to receipt
//! (`t_capture_ns` against this machine's wall clock) and the CPU seconds per second of the
//! daemon, the broker and this process (/proc). It ends with the LightSet's size at 8–256 lights,
//! the figures docs/SCALING.md multiplies out.
//!
//! Knobs: `VEMLIGHT_FANOUT_SUBSCRIBERS=0,100,1000,5000` (0: the daemon and broker alone),
//! `VEMLIGHT_FANOUT_SECONDS=10`, `VEMLIGHT_FANOUT_WARMUP=3`, `VEMLIGHT_FANOUT_MAX_PENDING=1048576`
//! (the broker's per-client backlog in bytes). Without nats-server (on PATH or in /usr/sbin) only
//! the WebSocket cases run.

use anyhow::{Context, bail};
use futures_util::StreamExt;
use std::io::{BufRead, Read, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};
use tokio::sync::Semaphore;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_util::sync::CancellationToken;
use vemlight::lightset::now_ns;
use vemlight::publish::subjects;

const CAMERA: &str = "bench";
const LIGHTS: usize = 64;
const FPS: f64 = 30.0;
/// Connections being opened at once while a case sets up.
const CONNECTING: usize = 100;
/// Bytes the broker holds for one subscriber before cutting it off as a slow consumer, unless
/// `VEMLIGHT_FANOUT_MAX_PENDING` says otherwise: about three seconds of 64-light sets at 30/s. A
/// latest-state viewer further behind than that is better reconnected than fed a backlog (and
/// 5 000 × nats-server's 64 MiB default would not fit in this machine's memory).
const BROKER_MAX_PENDING: u64 = 1024 * 1024;
const BROKER_WRITE_DEADLINE: &str = "2s";

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(default)
}

fn free_port() -> anyhow::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

/// The `nats-server` binary, if installed (Debian puts it in /usr/sbin).
fn nats_server() -> Option<PathBuf> {
    std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .unwrap_or_default()
        .into_iter()
        .chain(["/usr/sbin".into(), "/usr/local/bin".into()])
        .map(|d| d.join("nats-server"))
        .find(|p| p.is_file())
}

/// A child process killed when dropped.
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// nats-server on 127.0.0.1 from a config in a temp dir (as tests/common/broker.rs writes it),
/// with room for every subscriber.
struct Broker {
    proc: Proc,
    port: u16,
    http_port: u16,
    dir: PathBuf,
}

impl Broker {
    fn start(bin: &std::path::Path, max_pending: u64) -> anyhow::Result<Broker> {
        let dir = std::env::temp_dir().join(format!("vemlight-fanout-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        let (port, http_port) = (free_port()?, free_port()?);
        let conf = dir.join("nats.conf");
        // The server refuses a largest message above the per-client backlog.
        let max_payload = max_pending.min(1024 * 1024);
        std::fs::write(
            &conf,
            format!(
                "listen: 127.0.0.1:{port}\nhttp: 127.0.0.1:{http_port}\n\
                 write_deadline: \"{BROKER_WRITE_DEADLINE}\"\nmax_pending: {max_pending}\nmax_payload: {max_payload}\n\
                 max_connections: 100000\n\
                 jetstream {{\n  store_dir: \"{}\"\n  max_memory_store: 268435456\n  max_file_store: 67108864\n}}\n",
                dir.join("js").display()
            ),
        )?;
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("nats.log"))?)
            .spawn()
            .with_context(|| format!("starting {}", bin.display()))?;
        let b = Broker {
            proc: Proc(child),
            port,
            http_port,
            dir,
        };
        let deadline = Instant::now() + Duration::from_secs(15);
        while [port, http_port].iter().any(|p| {
            std::net::TcpStream::connect_timeout(
                &([127, 0, 0, 1], *p).into(),
                Duration::from_millis(200),
            )
            .is_err()
        }) {
            if Instant::now() > deadline {
                bail!(
                    "nats-server did not come up: {}",
                    std::fs::read_to_string(b.dir.join("nats.log")).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        Ok(b)
    }

    fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    /// `/varz` of the monitoring port.
    fn varz(&self) -> anyhow::Result<serde_json::Value> {
        let body = http_get(([127, 0, 0, 1], self.http_port).into(), "/varz")?;
        Ok(serde_json::from_str(&body)?)
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.proc.0.kill();
        let _ = self.proc.0.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A plain HTTP/1.0 GET's body (the monitoring port and the daemon's /metrics; no client
/// runtime needed while subscribers load this process's).
fn http_get(addr: SocketAddr, path: &str) -> anyhow::Result<String> {
    let mut s = std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(5))?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    write!(
        s,
        "GET {path} HTTP/1.0\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )?;
    let mut text = String::new();
    s.read_to_string(&mut text)?;
    let (head, body) = text
        .split_once("\r\n\r\n")
        .with_context(|| format!("GET {path}: no response"))?;
    if !head.starts_with("HTTP/1.1 200") && !head.starts_with("HTTP/1.0 200") {
        bail!("GET {path}: {}", head.lines().next().unwrap_or(""));
    }
    Ok(body.to_string())
}

/// `vemlight serve` (this build's binary), its address read from its log.
struct Daemon {
    proc: Proc,
    addr: SocketAddr,
}

impl Daemon {
    fn start(publish: Option<&str>) -> anyhow::Result<Daemon> {
        let (lights, fps) = (LIGHTS.to_string(), FPS.to_string());
        let mut args = vec![
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--lights",
            &lights,
            "--fps",
            &fps,
        ];
        if let Some(url) = publish {
            args.extend([
                "--publish",
                url,
                "--camera",
                CAMERA,
                "--publish-lights",
                &lights,
            ]);
        }
        let mut child = Command::new(env!("CARGO_BIN_EXE_vemlight"))
            .args(&args)
            .env("RUST_LOG", "info")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .context("starting vemlight serve")?;
        let stderr = child.stderr.take().context("daemon stderr")?;
        let proc = Proc(child);
        let (tx, rx) = std::sync::mpsc::channel();
        // Read on to the end so the daemon never blocks on a full pipe.
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stderr)
                .lines()
                .map_while(Result::ok)
            {
                let _ = tx.send(line);
            }
        });
        let addr = loop {
            let line = rx
                .recv_timeout(Duration::from_secs(30))
                .context("vemlight serve did not say where it listens")?;
            if let Some(rest) = line.split("serving on http://").nth(1) {
                break rest.split_whitespace().next().unwrap_or_default().parse()?;
            }
        };
        Ok(Daemon { proc, addr })
    }

    fn pid(&self) -> u32 {
        self.proc.0.id()
    }

    fn metrics(&self) -> anyhow::Result<String> {
        http_get(self.addr, "/metrics")
    }

    /// The seq of the newest 64-light set: sets produced between two reads.
    fn seq(&self) -> anyhow::Result<u64> {
        let body = http_get(self.addr, &format!("/v1/lights/latest?lights={LIGHTS}"))?;
        let doc: serde_json::Value = serde_json::from_str(&body)?;
        doc["seq"].as_u64().context("latest set has no seq")
    }
}

/// The sum of every line of metric `name` (all its labels) in Prometheus text.
fn metric_sum(text: &str, name: &str) -> f64 {
    text.lines()
        .filter(|l| {
            l.strip_prefix(name)
                .is_some_and(|r| r.starts_with(' ') || r.starts_with('{'))
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

/// utime + stime of a process in seconds, from /proc/PID/stat.
fn cpu_seconds(pid: u32) -> Option<f64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name, which may hold spaces: state is field 3, utime 14, stime 15.
    let f: Vec<&str> = s[s.rfind(')')? + 1..].split_whitespace().collect();
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / clock_ticks())
}

fn clock_ticks() -> f64 {
    // SAFETY: sysconf reads a constant of the system.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 { t as f64 } else { 100.0 }
}

/// The machine's busy and total jiffies from /proc/stat's first line.
fn machine_jiffies() -> Option<(u64, u64)> {
    let s = std::fs::read_to_string("/proc/stat").ok()?;
    let v: Vec<u64> = s
        .lines()
        .next()?
        .split_whitespace()
        .skip(1)
        .filter_map(|x| x.parse().ok())
        .collect();
    let total: u64 = v.iter().take(8).sum();
    let idle = v.get(3)? + v.get(4).unwrap_or(&0);
    Some((total - idle, total))
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

/// "Max open files" of a process, as /proc/PID/limits states it.
fn open_files_limit(pid: u32) -> String {
    std::fs::read_to_string(format!("/proc/{pid}/limits"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Max open files"))
                .map(|l| {
                    l.split_whitespace()
                        .skip(3)
                        .take(2)
                        .collect::<Vec<_>>()
                        .join(" / ")
                })
        })
        .unwrap_or_else(|| "unknown".into())
}

/// Raises the soft limit on open files to the hard one: 5 000 WebSocket clients take 5 000
/// descriptors here and as many in the daemon, which inherits the limit.
fn raise_open_files() -> anyhow::Result<libc::rlim_t> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: both calls read or write the one struct passed.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) != 0 {
            bail!("getrlimit: {}", std::io::Error::last_os_error());
        }
        if lim.rlim_cur < lim.rlim_max {
            lim.rlim_cur = lim.rlim_max;
            if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                bail!("setrlimit: {}", std::io::Error::last_os_error());
            }
        }
    }
    Ok(lim.rlim_cur)
}

/// `t_capture_ns` of a serialised LightSet, read without parsing the document (it is near the
/// start), so that reading costs the subscribers as little as possible.
fn t_capture_ns(doc: &[u8]) -> Option<u64> {
    const KEY: &[u8] = b"\"t_capture_ns\":";
    let head = &doc[..doc.len().min(256)];
    let at = head.windows(KEY.len()).position(|w| w == KEY)? + KEY.len();
    let digits = doc[at..].iter().take_while(|b| b.is_ascii_digit()).count();
    std::str::from_utf8(&doc[at..at + digits])
        .ok()?
        .parse()
        .ok()
}

/// What one subscriber saw inside the window.
#[derive(Default)]
struct Tally {
    received: u64,
    latency_us: Vec<u32>,
    /// Its connection ended before the case did.
    lost: bool,
}

impl Tally {
    fn note(&mut self, doc: &[u8], recording: &AtomicBool) {
        if !recording.load(Relaxed) {
            return;
        }
        let now = now_ns();
        self.received += 1;
        if let Some(t) = t_capture_ns(doc) {
            self.latency_us
                .push((now.saturating_sub(t) / 1000).min(u32::MAX as u64) as u32);
        }
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Via {
    Broker,
    WebSocket,
}

impl Via {
    fn name(self, subscribers: usize) -> &'static str {
        if subscribers == 0 {
            return "no subscribers";
        }
        match self {
            Via::Broker => "nats-server",
            Via::WebSocket => "daemon WebSocket",
        }
    }
}

/// Counters of the broker's client library across all of a case's connections.
#[derive(Default)]
struct ClientEvents {
    disconnected: AtomicU64,
    slow: AtomicU64,
}

/// Tallies a subscriber's sets until `stop`: each item a set's payload, `Ok(None)` another
/// frame, `Err` (or the end) the link lost.
async fn follow<B: AsRef<[u8]>>(
    mut sets: impl futures_util::Stream<Item = Result<Option<B>, ()>> + Unpin,
    recording: Arc<AtomicBool>,
    stop: CancellationToken,
) -> Tally {
    let mut t = Tally::default();
    loop {
        tokio::select! {
            biased;
            _ = stop.cancelled() => break,
            m = sets.next() => match m {
                Some(Ok(Some(doc))) => t.note(doc.as_ref(), &recording),
                Some(Ok(None)) => {}
                _ => { t.lost = true; break }
            }
        }
    }
    t
}

/// One case's figures.
struct Row {
    via: Via,
    subscribers: usize,
    connect_s: f64,
    window_s: f64,
    produced: u64,
    mean_rate: f64,
    lowest_rate: f64,
    fraction: f64,
    p50_ms: f64,
    p99_ms: f64,
    daemon_cpu: Option<f64>,
    broker_cpu: Option<f64>,
    own_cpu: Option<f64>,
    /// CPU s/s of every process on the machine but these three.
    others_cpu: Option<f64>,
    out_mb_s: f64,
    lost: String,
}

fn percentile(sorted: &[u32], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize] as f64 / 1000.0
}

/// Counters read at each end of the window.
struct Snapshot {
    at: Instant,
    seq: u64,
    daemon: Option<f64>,
    broker: Option<f64>,
    own: Option<f64>,
    machine: Option<(u64, u64)>,
    out_bytes: f64,
    slow_consumers: f64,
    publish_dropped: f64,
    ws_stalled: f64,
}

fn snapshot(daemon: &Daemon, broker: Option<&Broker>, via: Via) -> anyhow::Result<Snapshot> {
    let metrics = daemon.metrics()?;
    let varz = broker.map(|b| b.varz()).transpose()?;
    let num = |k: &str| varz.as_ref().and_then(|v| v[k].as_f64()).unwrap_or(0.0);
    Ok(Snapshot {
        at: Instant::now(),
        seq: daemon.seq()?,
        daemon: cpu_seconds(daemon.pid()),
        broker: broker.and_then(|b| cpu_seconds(b.proc.0.id())),
        own: cpu_seconds(std::process::id()),
        machine: machine_jiffies(),
        out_bytes: match via {
            Via::Broker => num("out_bytes"),
            Via::WebSocket => metric_sum(&metrics, "vemlight_ws_bytes_sent_total"),
        },
        slow_consumers: num("slow_consumers"),
        publish_dropped: metric_sum(&metrics, "vemlight_nats_dropped_total"),
        ws_stalled: metric_sum(&metrics, "vemlight_ws_clients_stalled_total"),
    })
}

async fn run_case(
    via: Via,
    subscribers: usize,
    daemon: &Daemon,
    broker: Option<&Broker>,
    warmup: Duration,
    window: Duration,
) -> anyhow::Result<Row> {
    let recording = Arc::new(AtomicBool::new(false));
    let stop = CancellationToken::new();
    let events = Arc::new(ClientEvents::default());
    let gate = Arc::new(Semaphore::new(CONNECTING));
    let started = Instant::now();
    let mut connecting = tokio::task::JoinSet::new();
    for _ in 0..subscribers {
        let (gate, recording, stop, events) = (
            gate.clone(),
            recording.clone(),
            stop.clone(),
            events.clone(),
        );
        let nats_url = broker.map(|b| b.url());
        let ws_url = format!("ws://{}/v1/stream?lights={LIGHTS}", daemon.addr);
        connecting.spawn(async move {
            let _permit = gate.acquire_owned().await?;
            anyhow::Ok(match via {
                Via::Broker => {
                    let url = nats_url.context("no broker")?;
                    let client = async_nats::ConnectOptions::new()
                        // A few seconds of sets; beyond, the client drops and counts them.
                        .subscription_capacity(256)
                        .event_callback(move |e| {
                            let events = events.clone();
                            async move {
                                match e {
                                    async_nats::Event::Disconnected => {
                                        events.disconnected.fetch_add(1, Relaxed);
                                    }
                                    async_nats::Event::SlowConsumer(_) => {
                                        events.slow.fetch_add(1, Relaxed);
                                    }
                                    _ => {}
                                }
                            }
                        })
                        .connect(url)
                        .await?;
                    let sub = client.subscribe(subjects::lights(CAMERA, LIGHTS)).await?;
                    client.flush().await?;
                    tokio::spawn(async move {
                        let t = follow(sub.map(|m| Ok(Some(m.payload))), recording, stop).await;
                        drop(client);
                        t
                    })
                }
                Via::WebSocket => {
                    // tungstenite's 128 KiB default read buffer, zeroed on every poll, would
                    // cost these clients more than the daemon (see benches/serve.rs).
                    let config = WebSocketConfig::default().read_buffer_size(16 * 1024);
                    let (ws, _) =
                        tokio_tungstenite::connect_async_with_config(ws_url, Some(config), true)
                            .await?;
                    let sets = ws.map(|m| match m {
                        Ok(Message::Text(s)) => Ok(Some(s)),
                        Ok(_) => Ok(None),
                        Err(_) => Err(()),
                    });
                    tokio::spawn(follow(sets, recording, stop))
                }
            })
        });
    }
    let mut followers = Vec::with_capacity(subscribers);
    while let Some(r) = connecting.join_next().await {
        followers.push(
            r.context("connect task")?
                .context("connecting a subscriber")?,
        );
    }
    let connect_s = started.elapsed().as_secs_f64();
    tokio::time::sleep(warmup).await;

    let (d, b) = (daemon, broker);
    let before = tokio::task::block_in_place(|| snapshot(d, b, via))?;
    recording.store(true, Relaxed);
    tokio::time::sleep(window).await;
    recording.store(false, Relaxed);
    let after = tokio::task::block_in_place(|| snapshot(d, b, via))?;
    stop.cancel();
    let mut tallies = Vec::with_capacity(subscribers);
    for f in followers {
        tallies.push(f.await?);
    }

    let window_s = (after.at - before.at).as_secs_f64();
    let produced = after.seq.saturating_sub(before.seq);
    let received: Vec<u64> = tallies.iter().map(|t| t.received).collect();
    let total: u64 = received.iter().sum();
    let mean = total as f64 / subscribers.max(1) as f64;
    let lowest = received.iter().copied().min().unwrap_or(0) as f64;
    let mut lat: Vec<u32> = tallies
        .iter_mut()
        .flat_map(|t| std::mem::take(&mut t.latency_us))
        .collect();
    lat.sort_unstable();
    let rate = |a: Option<f64>, b: Option<f64>| Some((b? - a?) / window_s);
    let daemon_cpu = rate(before.daemon, after.daemon);
    let broker_cpu = rate(before.broker, after.broker);
    let own_cpu = rate(before.own, after.own);
    // Busy jiffies over all cores against the window: CPU s/s of the whole machine.
    let machine_cpu = match (before.machine, after.machine) {
        (Some((b0, t0)), Some((b1, t1))) if t1 > t0 => {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
            Some((b1 - b0) as f64 / (t1 - t0) as f64 * cores)
        }
        _ => None,
    };
    let others_cpu = machine_cpu.map(|m| {
        (m - daemon_cpu.unwrap_or(0.0) - broker_cpu.unwrap_or(0.0) - own_cpu.unwrap_or(0.0))
            .max(0.0)
    });
    let ended = tallies.iter().filter(|t| t.lost).count();
    let lost = match via {
        Via::Broker => format!(
            "{} slow consumers, {} reconnects, {} client drops, {} publisher drops",
            after.slow_consumers - before.slow_consumers,
            events.disconnected.load(Relaxed),
            events.slow.load(Relaxed),
            after.publish_dropped - before.publish_dropped,
        ),
        Via::WebSocket => format!(
            "{ended} closed, {} stalled",
            after.ws_stalled - before.ws_stalled
        ),
    };
    Ok(Row {
        via,
        subscribers,
        connect_s,
        window_s,
        produced,
        mean_rate: mean / window_s,
        lowest_rate: lowest / window_s,
        fraction: if produced > 0 {
            mean / produced as f64
        } else {
            f64::NAN
        },
        p50_ms: percentile(&lat, 0.5),
        p99_ms: percentile(&lat, 0.99),
        daemon_cpu,
        broker_cpu: match via {
            Via::Broker => broker_cpu,
            Via::WebSocket => None,
        },
        own_cpu,
        others_cpu,
        out_mb_s: (after.out_bytes - before.out_bytes) / window_s / 1e6,
        lost,
    })
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map(|x| format!("{x:.digits$}"))
        .unwrap_or_else(|| "–".into())
}

fn print_table(rows: &[Row]) {
    println!(
        "\n| path | subscribers | connect s | sets/s per subscriber, mean (lowest) | of sets produced | p50 ms | p99 ms | daemon CPU s/s | daemon CPU ms per set | nats-server CPU s/s | subscribers' CPU s/s | other processes' CPU s/s | fan-out MB/s | lost |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        println!(
            "| {} | {} | {:.1} | {:.1} ({:.1}) | {:.1} % of {} | {:.1} | {:.1} | {} | {} | {} | {} | {} | {:.1} | {} |",
            r.via.name(r.subscribers),
            r.subscribers,
            r.connect_s,
            r.mean_rate,
            r.lowest_rate,
            r.fraction * 100.0,
            r.produced,
            r.p50_ms,
            r.p99_ms,
            opt(r.daemon_cpu, 3),
            opt(
                r.daemon_cpu
                    .filter(|_| r.produced > 0)
                    .map(|c| c * r.window_s / r.produced as f64 * 1e3),
                2
            ),
            opt(r.broker_cpu, 3),
            opt(r.own_cpu, 2),
            opt(r.others_cpu, 2),
            r.out_mb_s,
            r.lost,
        );
    }
    if let Some(r) = rows.first() {
        println!(
            "\nwindow {:.1} s each; sets produced: the daemon's seq over the window; fan-out MB/s: nats-server's out_bytes (all clients) or the daemon's vemlight_ws_bytes_sent_total; other processes: the machine's busy time (/proc/stat) less the three above",
            r.window_s
        );
    }
}

/// The byte count of `,"sh9":[…]` in a serialised LightSet.
fn sh9_bytes(doc: &str) -> usize {
    let Some(start) = doc.find(",\"sh9\":[") else {
        return 0;
    };
    doc[start..].find(']').map(|end| end + 1).unwrap_or(0)
}

/// A WebSocket frame's header from a server (unmasked) for a payload of `len` bytes.
fn ws_header(len: usize) -> usize {
    match len {
        0..=125 => 2,
        126..=65535 => 4,
        _ => 10,
    }
}

/// LightSet sizes as the daemon sends them, at each light count: the mean over 20 sets.
async fn sizes(daemon: &Daemon) -> anyhow::Result<()> {
    println!(
        "\n| lights | LightSet bytes, mean of 20 (min–max) | of which `sh9` | without `sh9` | WebSocket frame header | NATS `MSG` line + CRLF, subject `{}.{CAMERA}.lights.N` |",
        subjects::PREFIX
    );
    println!("|---|---|---|---|---|---|");
    for n in [8usize, 16, 64, 256] {
        let url = format!("ws://{}/v1/stream?lights={n}", daemon.addr);
        let (mut ws, _) = tokio_tungstenite::connect_async(url).await?;
        let mut lens = Vec::new();
        let mut sh = Vec::new();
        // The first set may be one that was waiting; the next 20 are fresh.
        let mut skipped = false;
        while lens.len() < 20 {
            match tokio::time::timeout(Duration::from_secs(10), ws.next()).await {
                Ok(Some(Ok(Message::Text(t)))) => {
                    if skipped {
                        lens.push(t.len());
                        sh.push(sh9_bytes(&t));
                    }
                    skipped = true;
                }
                Ok(Some(Ok(_))) => {}
                other => bail!("stream at {n} lights ended: {other:?}"),
            }
        }
        let mean = |v: &[usize]| v.iter().sum::<usize>() as f64 / v.len() as f64;
        let (len, sh9) = (mean(&lens), mean(&sh));
        let subject = subjects::lights(CAMERA, n);
        // MSG <subject> <sid> <bytes>\r\n<payload>\r\n, sid 1.
        let msg = format!("MSG {subject} 1 {}\r\n", len.round()).len() + 2;
        println!(
            "| {n} | {len:.0} ({}–{}) | {sh9:.0} | {:.0} | {} | {msg} |",
            lens.iter().min().unwrap_or(&0),
            lens.iter().max().unwrap_or(&0),
            len - sh9,
            ws_header(len as usize),
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    // `cargo test` runs benches in test mode with `--bench` absent: do nothing then.
    if !std::env::args().any(|a| a == "--bench") {
        return Ok(());
    }
    let counts: Vec<usize> = std::env::var("VEMLIGHT_FANOUT_SUBSCRIBERS")
        .unwrap_or_else(|_| "0,100,1000,5000".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let window = Duration::from_secs_f64(env_or("VEMLIGHT_FANOUT_SECONDS", 10.0));
    let warmup = Duration::from_secs_f64(env_or("VEMLIGHT_FANOUT_WARMUP", 3.0));
    let max_pending = env_or("VEMLIGHT_FANOUT_MAX_PENDING", BROKER_MAX_PENDING);
    let nofile = raise_open_files()?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "load average at start: {}; {cores} cores shared by the subscribers (this process, {cores} tokio workers), nats-server and the daemon",
        load_average()
    );
    let max = counts.iter().copied().max().unwrap_or(0);
    if (nofile as usize) < max + 200 {
        bail!("open files limited to {nofile}: {max} subscribers need more (raise the hard limit)");
    }

    let server = nats_server();
    let broker = match &server {
        Some(bin) => Some(Broker::start(bin, max_pending)?),
        None => {
            println!(
                "nats-server not found on PATH or in /usr/sbin: only the daemon's WebSocket runs"
            );
            None
        }
    };
    let daemon = Daemon::start(broker.as_ref().map(|b| b.url()).as_deref())?;
    println!(
        "vemlight serve on {} (synthetic sky, {FPS} frames/s, {LIGHTS} lights{}); open files: bench {}, daemon {}{}",
        daemon.addr,
        if broker.is_some() {
            format!(", publishing to {}", subjects::lights(CAMERA, LIGHTS))
        } else {
            String::new()
        },
        open_files_limit(std::process::id()),
        open_files_limit(daemon.pid()),
        broker
            .as_ref()
            .map(|b| format!(
                ", nats-server {} (max_pending {max_pending} B, write_deadline {BROKER_WRITE_DEADLINE})",
                open_files_limit(b.proc.0.id())
            ))
            .unwrap_or_default(),
    );

    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let rows = rt.block_on(async {
        // The pipeline and the publisher settle, and the daemon's CPU alone is measured.
        tokio::time::sleep(warmup).await;
        let mut rows = Vec::new();
        let paths: Vec<Via> = if broker.is_some() {
            vec![Via::Broker, Via::WebSocket]
        } else {
            vec![Via::WebSocket]
        };
        for &s in &counts {
            // With no subscribers both paths are the same: the daemon and broker alone.
            let paths = if s == 0 { &paths[..1] } else { &paths[..] };
            for &via in paths {
                eprintln!("fan-out: {} × {s} …", via.name(s));
                let row = run_case(via, s, &daemon, broker.as_ref(), warmup, window).await?;
                eprintln!(
                    "  {:.1} sets/s per subscriber, p99 {:.1} ms, daemon {} CPU s/s",
                    row.mean_rate,
                    row.p99_ms,
                    opt(row.daemon_cpu, 3)
                );
                rows.push(row);
                // Closed connections go before the next case starts.
                tokio::time::sleep(Duration::from_secs(3)).await;
            }
        }
        print_table(&rows);
        sizes(&daemon).await?;
        anyhow::Ok(rows)
    })?;
    println!(
        "\nload average at the end: {} ({} cases)",
        load_average(),
        rows.len()
    );
    Ok(())
}
