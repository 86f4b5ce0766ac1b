//! `vemlight serve --publish`: the daemon (the real binary) publishing through a real
//! `nats-server` (tests/common/broker.rs) to real NATS clients (async-nats), beside its own
//! WebSocket stream (docs/API.md, "Through a NATS broker").

mod common;

use common::broker::{Broker, Settings, broker_or_skip, have_broker};
use futures_util::StreamExt;
use serde_json::Value;
use std::time::{Duration, Instant};

/// A `vemlight serve` child, killed when dropped.
struct Daemon {
    child: std::process::Child,
    addr: std::net::SocketAddr,
}

impl Daemon {
    fn start(broker: &Broker, camera: &str, args: &[&str]) -> Daemon {
        let url = broker.url();
        let mut all = vec!["--publish", &url, "--camera", camera];
        all.extend_from_slice(args);
        let (child, addr) = common::spawn_serve(&all);
        Daemon { child, addr }
    }

    /// A daemon given only `args` and the environment `env` (the broker's URL among them, say).
    fn start_with_env(args: &[&str], env: &[(&str, &str)]) -> Daemon {
        let (child, addr) = common::spawn_serve_with_env(args, env);
        Daemon { child, addr }
    }

    async fn get_json(&self, path: &str) -> (u16, Value) {
        let r = reqwest::get(format!("http://{}{path}", self.addr))
            .await
            .unwrap();
        (r.status().as_u16(), r.json().await.unwrap())
    }

    async fn metrics(&self) -> String {
        reqwest::get(format!("http://{}/metrics", self.addr))
            .await
            .unwrap()
            .text()
            .await
            .unwrap()
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The value of one metric line (`name` with its labels) in Prometheus text.
fn metric(text: &str, name: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
        .unwrap_or_else(|| panic!("no metric {name}"))
}

async fn next_json(sub: &mut async_nats::Subscriber, within: Duration) -> Value {
    let m = tokio::time::timeout(within, sub.next())
        .await
        .expect("a message in time")
        .expect("subscription open");
    serde_json::from_slice(&m.payload).expect("JSON payload")
}

/// Arrival times of the daemon's own WebSocket stream, recorded until the task is aborted.
fn record_ws(
    addr: std::net::SocketAddr,
    query: &str,
) -> (
    tokio::task::JoinHandle<()>,
    std::sync::Arc<std::sync::Mutex<Vec<Instant>>>,
) {
    let times = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let t = times.clone();
    let url = format!("ws://{addr}/v1/stream?{query}");
    let task = tokio::spawn(async move {
        let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
        while let Some(Ok(m)) = ws.next().await {
            if m.is_text() {
                t.lock().unwrap().push(Instant::now());
            }
        }
    });
    (task, times)
}

/// The longest wait between two arrivals.
fn max_gap(times: &[Instant]) -> Duration {
    times
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(Duration::MAX)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sets_on_their_subjects_validate_and_the_last_value_waits_for_late_subscribers() {
    let Some(broker) = broker_or_skip("nats publish") else {
        return;
    };
    let d = Daemon::start(
        &broker,
        "roof",
        &["--lights", "16", "--publish-lights", "8,16"],
    );
    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut sub8 = nc.subscribe("vemlight.v1.roof.lights.8").await.unwrap();
    let mut status = nc.subscribe("vemlight.v1.roof.status").await.unwrap();
    let validator = common::lightset_validator();
    let mut last_seq = 0;
    for _ in 0..10 {
        let doc = next_json(&mut sub8, Duration::from_secs(20)).await;
        common::assert_valid(&validator, &doc);
        assert_eq!(doc["lights"].as_array().unwrap().len(), 8);
        let seq = doc["seq"].as_u64().unwrap();
        assert!(seq > last_seq, "seq {seq} after {last_seq}");
        last_seq = seq;
    }
    let st = next_json(&mut status, Duration::from_secs(3)).await;
    assert_eq!(st["schema"], "vemlight.status/1");
    assert_eq!(st["camera"], "roof");
    assert_eq!(st["healthy"], true);
    assert_eq!(st["lights"], serde_json::json!([8, 16]));
    assert_eq!(st["http"], format!("http://{}", d.addr));

    // A viewer that joins now gets the current set at once from the stream, not a frame later.
    let late = async_nats::connect(broker.url()).await.unwrap();
    let js = async_nats::jetstream::new(late);
    let stream = js.get_stream("vemlight_roof").await.unwrap();
    let m = stream
        .direct_get_last_for_subject("vemlight.v1.roof.lights.16")
        .await
        .unwrap();
    let doc: Value = serde_json::from_slice(&m.payload).unwrap();
    common::assert_valid(&validator, &doc);
    assert_eq!(doc["lights"].as_array().unwrap().len(), 16);
    let age_s =
        (vemlight::lightset::now_ns() - doc["t_capture_ns"].as_u64().unwrap()) as f64 * 1e-9;
    assert!(age_s < 2.0, "the kept set is {age_s} s old");
    // One message per subject: the stream holds the two counts and the status, no history.
    let info = js
        .get_stream("vemlight_roof")
        .await
        .unwrap()
        .info()
        .await
        .unwrap()
        .clone();
    assert_eq!(info.state.messages, 3, "{:?}", info.state);

    let (code, h) = d.get_json("/healthz").await;
    assert_eq!(code, 200);
    assert_eq!(h["broker"]["state"], "ok", "{h}");
    assert_eq!(h["broker"]["stream"], "vemlight_roof", "{h}");
    assert_eq!(h["broker"]["camera"], "roof");
    let text = d.metrics().await;
    assert!(metric(&text, "vemlight_nats_published_total") >= 10.0);
    assert_eq!(metric(&text, "vemlight_nats_connected"), 1.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_that_goes_away_never_pauses_the_daemon_and_publishing_resumes() {
    let Some(mut broker) = broker_or_skip("broker outage") else {
        return;
    };
    let d = Daemon::start(&broker, "yard", &["--lights", "8", "--fps", "30"]);
    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut sub = nc.subscribe("vemlight.v1.yard.lights.8").await.unwrap();
    next_json(&mut sub, Duration::from_secs(20)).await;
    drop(sub);
    drop(nc);
    let (ws_task, ws_times) = record_ws(d.addr, "lights=8");
    tokio::time::sleep(Duration::from_secs(1)).await;

    let outage = Instant::now();
    broker.kill();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let (code, h) = d.get_json("/healthz").await;
    assert_eq!(
        code, 200,
        "a lost broker does not make the daemon unhealthy: {h}"
    );
    assert_eq!(h["status"], "ok", "{h}");
    assert_eq!(h["broker"]["state"], "reconnecting", "{h}");
    let text = d.metrics().await;
    let dropped = metric(
        &text,
        "vemlight_nats_dropped_total{reason=\"disconnected\"}",
    );
    // 30 sets/s and a status a second for about 3 s, less what went out before the loss was seen.
    assert!(
        dropped >= 45.0,
        "dropped {dropped} while the broker was down"
    );
    assert_eq!(metric(&text, "vemlight_nats_connected"), 0.0);

    broker.restart();
    let back = Instant::now();
    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut sub = nc.subscribe("vemlight.v1.yard.lights.8").await.unwrap();
    let doc = next_json(&mut sub, Duration::from_secs(15)).await;
    let resumed_after = back.elapsed();
    assert_eq!(doc["lights"].as_array().unwrap().len(), 8);
    // The restarted broker lost the memory stream: the daemon makes it again.
    let js = async_nats::jetstream::new(nc.clone());
    let deadline = Instant::now() + Duration::from_secs(10);
    let last = loop {
        if let Ok(s) = js.get_stream("vemlight_yard").await
            && let Ok(m) = s
                .direct_get_last_for_subject("vemlight.v1.yard.lights.8")
                .await
        {
            break m;
        }
        assert!(Instant::now() < deadline, "the stream was not made again");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert!(!last.payload.is_empty());
    let (_, h) = d.get_json("/healthz").await;
    assert_eq!(h["broker"]["state"], "ok", "{h}");
    assert!(h["broker"]["reconnects"].as_u64().unwrap() >= 1, "{h}");
    tokio::time::sleep(Duration::from_millis(500)).await;
    ws_task.abort();

    // The daemon's own stream went on through the outage at its rate.
    let times = ws_times.lock().unwrap().clone();
    let span = outage.elapsed().as_secs_f64() + 1.0;
    let gap = max_gap(&times);
    assert!(
        gap < Duration::from_millis(300),
        "the WebSocket stream paused {gap:?}"
    );
    assert!(
        times.len() as f64 >= 0.8 * 30.0 * span,
        "{} sets in {span:.1} s",
        times.len()
    );
    eprintln!(
        "outage: {} WebSocket sets in {span:.1} s, longest gap {gap:?}; {dropped} publishes dropped; \
         publishing resumed {resumed_after:?} after the broker came back",
        times.len()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscriber_that_stops_reading_does_not_slow_the_daemon() {
    use std::io::{BufRead, Write};
    if !have_broker("slow subscriber") {
        return;
    }
    // The broker cuts off a client that leaves 256 KiB unread for a second.
    let broker = Broker::start(Settings {
        write_deadline: "1s",
        max_pending: 256 * 1024,
        max_payload: 128 * 1024,
        ..Settings::default()
    });
    let d = Daemon::start(
        &broker,
        "dock",
        &["--lights", "256", "--publish-lights", "256", "--fps", "30"],
    );
    // A raw NATS connection that subscribes to everything and then never reads.
    let raw = std::net::TcpStream::connect(("127.0.0.1", broker.port)).unwrap();
    let mut reader = std::io::BufReader::new(raw.try_clone().unwrap());
    let mut info = String::new();
    reader.read_line(&mut info).unwrap();
    assert!(info.starts_with("INFO"), "{info}");
    (&raw)
        .write_all(
            b"CONNECT {\"verbose\":false,\"pedantic\":false}\r\nSUB vemlight.v1.> 1\r\nPING\r\n",
        )
        .unwrap();

    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut sub = nc.subscribe("vemlight.v1.dock.lights.256").await.unwrap();
    next_json(&mut sub, Duration::from_secs(30)).await;
    let (ws_task, ws_times) = record_ws(d.addr, "lights=256");
    let start = Instant::now();
    let mut received = 0usize;
    let mut cut_off = false;
    while start.elapsed() < Duration::from_secs(8) || !cut_off {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the broker never cut the silent subscriber off"
        );
        next_json(&mut sub, Duration::from_secs(2)).await;
        received += 1;
        if !cut_off {
            cut_off = broker.monitor("varz")["slow_consumers"]
                .as_u64()
                .unwrap_or(0)
                >= 1;
        }
    }
    let span = start.elapsed().as_secs_f64();
    ws_task.abort();
    let times = ws_times.lock().unwrap().clone();
    let gap = max_gap(&times);
    assert!(
        gap < Duration::from_millis(300),
        "the daemon's stream paused {gap:?}"
    );
    assert!(times.len() as f64 >= 0.8 * 30.0 * span);
    assert!(
        received as f64 >= 0.8 * 30.0 * span,
        "a reading subscriber got {received} sets in {span:.1} s"
    );
    // While the broker waits on the silent subscriber's socket (up to its write deadline) it
    // reads no more from the daemon, so a few sets are superseded in the daemon's queue: the
    // broker is slowed for a moment, the daemon is not, and no publish is lost otherwise.
    let text = d.metrics().await;
    let reason = |r: &str| {
        metric(
            &text,
            &format!("vemlight_nats_dropped_total{{reason=\"{r}\"}}"),
        )
    };
    eprintln!(
        "silent subscriber: {} published, dropped: {} superseded, {} queue full, {} disconnected, {} timeout",
        metric(&text, "vemlight_nats_published_total"),
        reason("superseded"),
        reason("queue_full"),
        reason("disconnected"),
        reason("timeout")
    );
    // (A status may go before the first connection is up: "disconnected" is not counted here.)
    assert_eq!(reason("queue_full"), 0.0);
    assert!(reason("timeout") <= 5.0);
    drop(raw);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_cameras_on_one_broker_are_told_apart() {
    let Some(broker) = broker_or_skip("two cameras") else {
        return;
    };
    let map = common::data_path(common::MAPS[0]);
    let east = Daemon::start(&broker, "east", &["--lights", "8"]);
    let west = Daemon::start(
        &broker,
        "west",
        &["--lights", "8", "--source", map.to_str().unwrap()],
    );
    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut statuses = nc.subscribe("vemlight.v1.*.status").await.unwrap();
    let mut cameras = std::collections::BTreeMap::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    while cameras.len() < 2 && Instant::now() < deadline {
        let m = tokio::time::timeout(Duration::from_secs(3), statuses.next())
            .await
            .unwrap()
            .unwrap();
        let st: Value = serde_json::from_slice(&m.payload).unwrap();
        assert_eq!(
            Some(st["camera"].as_str().unwrap()),
            vemlight::publish::subjects::camera_of(&m.subject)
        );
        cameras.insert(st["camera"].as_str().unwrap().to_string(), st);
    }
    assert_eq!(
        cameras.keys().collect::<Vec<_>>(),
        ["east", "west"],
        "cameras listed"
    );
    assert_eq!(cameras["east"]["http"], format!("http://{}", east.addr));
    assert_eq!(cameras["west"]["http"], format!("http://{}", west.addr));
    for (camera, needle) in [("east", "synthetic"), ("west", common::MAPS[0])] {
        let mut sub = nc
            .subscribe(format!("vemlight.v1.{camera}.lights.8"))
            .await
            .unwrap();
        for _ in 0..3 {
            let doc = next_json(&mut sub, Duration::from_secs(20)).await;
            let source = doc["source"].as_str().unwrap();
            assert!(source.contains(needle), "{camera}: source {source}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_subscribers_all_receive_sets() {
    let Some(broker) = broker_or_skip("1000 subscribers") else {
        return;
    };
    let _d = Daemon::start(&broker, "hall", &["--lights", "8", "--fps", "30"]);
    const SUBSCRIBERS: usize = 1000;
    let mut clients = Vec::with_capacity(SUBSCRIBERS);
    for chunk in 0..SUBSCRIBERS / 50 {
        let batch = futures_util::future::join_all((0..50).map(|k| {
            let url = broker.url();
            async move {
                let nc = async_nats::ConnectOptions::new()
                    .name(format!("viewer {}", chunk * 50 + k))
                    .connect(url)
                    .await
                    .unwrap();
                let sub = nc.subscribe("vemlight.v1.hall.lights.8").await.unwrap();
                (nc, sub)
            }
        }))
        .await;
        clients.extend(batch);
    }
    let conns = broker.monitor("varz")["connections"].as_u64().unwrap();
    assert!(conns >= SUBSCRIBERS as u64, "{conns} connections");
    let tasks: Vec<_> = clients
        .into_iter()
        .map(|(nc, mut sub)| {
            tokio::spawn(async move {
                let mut seqs = Vec::new();
                while seqs.len() < 3 {
                    let doc = next_json(&mut sub, Duration::from_secs(20)).await;
                    seqs.push(doc["seq"].as_u64().unwrap());
                }
                drop(nc);
                seqs
            })
        })
        .collect();
    for t in tasks {
        let seqs = t.await.unwrap();
        assert!(seqs.windows(2).all(|w| w[1] > w[0]), "{seqs:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_jetstream_sets_still_go_out_and_healthz_says_why_there_is_no_last_value() {
    if !have_broker("no JetStream") {
        return;
    }
    let broker = Broker::start(Settings {
        jetstream: false,
        ..Settings::default()
    });
    let d = Daemon::start(&broker, "shed", &["--lights", "8"]);
    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut sub = nc.subscribe("vemlight.v1.shed.lights.8").await.unwrap();
    let doc = next_json(&mut sub, Duration::from_secs(20)).await;
    assert_eq!(doc["lights"].as_array().unwrap().len(), 8);
    let deadline = Instant::now() + Duration::from_secs(10);
    let h = loop {
        let (code, h) = d.get_json("/healthz").await;
        assert_eq!(code, 200, "{h}");
        if !h["broker"]["stream_error"].is_null() {
            break h;
        }
        assert!(Instant::now() < deadline, "no stream error reported: {h}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(h["status"], "ok", "{h}");
    assert_eq!(h["broker"]["state"], "ok", "{h}");
    assert!(h["broker"]["stream"].is_null(), "{h}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn credentials_come_from_the_environment_and_a_refused_login_leaves_the_daemon_healthy() {
    if !have_broker("broker credentials") {
        return;
    }
    let broker = Broker::start(Settings {
        extra:
            "authorization {\n  users = [\n    { user: \"cam\", password: \"s3cret-pw\" }\n  ]\n}\n"
                .into(),
        ..Settings::default()
    });
    let with_user = format!("nats://cam:s3cret-pw@127.0.0.1:{}", broker.port);
    // The whole URL in VEMLIGHT_NATS; and the user and password in their own variables.
    let by_url = Daemon::start_with_env(
        &["--camera", "gate", "--lights", "8"],
        &[("VEMLIGHT_NATS", &with_user)],
    );
    let url = broker.url();
    let by_vars = Daemon::start_with_env(
        &["--publish", &url, "--camera", "door", "--lights", "8"],
        &[
            ("VEMLIGHT_NATS_USER", "cam"),
            ("VEMLIGHT_NATS_PASSWORD", "s3cret-pw"),
        ],
    );
    let refused = Daemon::start_with_env(
        &["--publish", &url, "--camera", "side", "--lights", "8"],
        &[
            ("VEMLIGHT_NATS_USER", "cam"),
            ("VEMLIGHT_NATS_PASSWORD", "wrong"),
        ],
    );
    let nc = async_nats::ConnectOptions::with_user_and_password("cam".into(), "s3cret-pw".into())
        .connect(broker.url())
        .await
        .unwrap();
    for camera in ["gate", "door"] {
        let mut sub = nc
            .subscribe(format!("vemlight.v1.{camera}.lights.8"))
            .await
            .unwrap();
        next_json(&mut sub, Duration::from_secs(20)).await;
    }
    let (_, h) = by_url.get_json("/healthz").await;
    assert_eq!(
        h["broker"]["url"],
        format!("nats://***@127.0.0.1:{}", broker.port)
    );
    assert!(!h.to_string().contains("s3cret"), "{h}");
    let deadline = Instant::now() + Duration::from_secs(20);
    let h = loop {
        let (code, h) = refused.get_json("/healthz").await;
        if code == 200 {
            break h;
        }
        assert!(Instant::now() < deadline, "{h}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    // Refused by the broker, serving its own clients all the same.
    assert_eq!(h["status"], "ok", "{h}");
    assert_eq!(h["broker"]["state"], "connecting", "{h}");
    let why = h["broker"]["last_error"].as_str().unwrap_or_default();
    assert!(why.contains("authorization"), "{h}");
    assert!(!by_vars.metrics().await.contains("s3cret"));
}

/// A TCP proxy to `upstream` that passes what the client writes at `bytes_per_s` at most (and
/// the other way at full speed): a broker link that takes sets slower than the daemon makes them.
async fn throttling_proxy(upstream: u16, bytes_per_s: usize) -> u16 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    tokio::spawn(async move {
        while let Ok((client, _)) = listener.accept().await {
            let Ok(server) = tokio::net::TcpStream::connect(("127.0.0.1", upstream)).await else {
                continue;
            };
            let (mut cr, mut cw) = client.into_split();
            let (mut sr, mut sw) = server.into_split();
            tokio::spawn(async move {
                let _ = tokio::io::copy(&mut sr, &mut cw).await;
            });
            tokio::spawn(async move {
                let mut buf = vec![0u8; 4096];
                loop {
                    let n = match cr.read(&mut buf).await {
                        Ok(0) | Err(_) => return,
                        Ok(n) => n,
                    };
                    if sw.write_all(&buf[..n]).await.is_err() {
                        return;
                    }
                    tokio::time::sleep(Duration::from_secs_f64(n as f64 / bytes_per_s as f64))
                        .await;
                }
            });
        }
    });
    port
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_link_slower_than_the_sets_costs_dropped_sets_not_latency() {
    let Some(broker) = broker_or_skip("slow broker link") else {
        return;
    };
    // 64 lights at 30 sets/s is about 330 KB/s; the link passes 100 KB/s.
    let port = throttling_proxy(broker.port, 100_000).await;
    let url = format!("nats://127.0.0.1:{port}");
    let d = Daemon::start_with_env(
        &[
            "--publish",
            &url,
            "--camera",
            "mast",
            "--lights",
            "64",
            "--fps",
            "30",
        ],
        &[],
    );
    let nc = async_nats::connect(broker.url()).await.unwrap();
    let mut sub = nc.subscribe("vemlight.v1.mast.lights.64").await.unwrap();
    next_json(&mut sub, Duration::from_secs(20)).await;
    let start = Instant::now();
    let mut ages_s = Vec::new();
    while start.elapsed() < Duration::from_secs(6) {
        let doc = next_json(&mut sub, Duration::from_secs(3)).await;
        let now = vemlight::lightset::now_ns();
        ages_s.push((now - doc["t_capture_ns"].as_u64().unwrap()) as f64 * 1e-9);
    }
    let rate = ages_s.len() as f64 / start.elapsed().as_secs_f64();
    let worst = ages_s.iter().copied().fold(0.0, f64::max);
    let late: Vec<f64> = ages_s[ages_s.len() / 2..].to_vec();
    let late_worst = late.iter().copied().fold(0.0, f64::max);
    let text = d.metrics().await;
    let superseded = metric(&text, "vemlight_nats_dropped_total{reason=\"superseded\"}");
    eprintln!(
        "slow link: {rate:.1} sets/s delivered, set age worst {worst:.2} s (second half {late_worst:.2} s), {superseded} superseded"
    );
    // Fewer sets get through, the rest are superseded in the daemon's queue …
    assert!(rate < 20.0, "{rate} sets/s through a 100 KB/s link");
    assert!(superseded > 30.0, "{superseded} superseded");
    // … and what arrives stays fresh: no backlog builds up between the daemon and the broker.
    assert!(
        late_worst < 0.6,
        "sets {late_worst:.2} s old at the end: a backlog is building"
    );
}
