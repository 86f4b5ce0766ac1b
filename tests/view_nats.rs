//! `vemlight view nats://…` and `vemlight cameras`: the viewer's broker feed against a real
//! `nats-server` (tests/common/broker.rs) and real daemons (`vemlight serve --publish`, children),
//! and hand-made sets published with async-nats. The feed is driven as a library type (no
//! window); one short headless run renders through lavapipe.
#![cfg(feature = "render")]

mod common;

use common::broker::{Broker, broker_or_skip};
use futures_util::StreamExt;
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};
use vemlight::lightset::{LightSet, now_ns};
use vemlight::publish::NatsAuth;
use vemlight::publish::cameras::LISTEN;
use vemlight::render::view::nats::{NatsFeed, NatsOptions};
use vemlight::render::view::source::{LightFeed, Source, lights_from_map};

/// A `vemlight serve --publish` child, killed when dropped.
struct Daemon(Child);

impl Daemon {
    fn start(broker: &Broker, camera: &str, args: &[&str]) -> Daemon {
        let url = broker.url();
        let mut all = vec!["--publish", &url, "--camera", camera];
        all.extend_from_slice(args);
        Daemon(common::spawn_serve(&all).0)
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

/// Waits until every camera of `cameras` has sent a status (a listing from now on finds them).
fn wait_statuses(broker: &Broker, cameras: &[&str]) {
    runtime().block_on(async {
        let nc = async_nats::connect(broker.url()).await.unwrap();
        let mut sub = nc.subscribe("vemlight.v1.*.status").await.unwrap();
        let mut seen = std::collections::BTreeSet::new();
        while !cameras.iter().all(|c| seen.contains(*c)) {
            let m = tokio::time::timeout(Duration::from_secs(20), sub.next())
                .await
                .expect("a status within 20 s")
                .unwrap();
            let st: serde_json::Value = serde_json::from_slice(&m.payload).unwrap();
            seen.insert(st["camera"].as_str().unwrap().to_string());
        }
    });
}

fn options(max_age: Option<Duration>) -> NatsOptions {
    NatsOptions {
        camera: None,
        max_age,
        auth: NatsAuth::None,
        listen: LISTEN,
    }
}

/// Polls `f` every 10 ms until it gives a value or `within` passes.
fn wait_for<T>(within: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let deadline = Instant::now() + within;
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if Instant::now() > deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn the_feed_finds_the_only_camera_and_follows_its_sets_in_order() {
    let Some(broker) = broker_or_skip("nats feed") else {
        return;
    };
    let _d = Daemon::start(
        &broker,
        "roof",
        &["--lights", "16", "--publish-lights", "8,16", "--fps", "10"],
    );
    wait_statuses(&broker, &["roof"]);
    // No camera and no count named: the only camera, its first published count.
    let feed = NatsFeed::start(&broker.url(), options(Some(Duration::from_secs(1)))).unwrap();
    assert_eq!(feed.camera(), "roof");
    assert_eq!(feed.lights(), 8);
    assert_eq!(feed.subject(), "vemlight.v1.roof.lights.8");
    let mut seqs = Vec::new();
    let start = Instant::now();
    while seqs.len() < 8 {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "sets {seqs:?}, {:?} {}",
            feed.stats(),
            feed.why_nothing()
        );
        if let Some(set) = feed.take_latest() {
            assert_eq!(set.lights.len(), 8);
            seqs.push(set.seq);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(
        seqs.windows(2).all(|w| w[1] > w[0]),
        "seq increases: {seqs:?}"
    );
    let stats = feed.stats();
    assert!(stats.shown >= 8 && stats.connections == 1, "{stats:?}");
    assert!(feed.is_connected() && !feed.is_stale());
    drop(feed);

    // --shadowed K through the broker: the sets come without marks and are marked here.
    let url = format!("{}/roof?lights=16", broker.url());
    let mut feed = LightFeed::open_with_budget(&Source::parse(&url), 0, Some(3)).unwrap();
    let set = feed.wait_first(Duration::from_secs(10)).unwrap();
    assert_eq!(set.lights.len(), 16);
    assert!(set.lights.iter().all(|l| l.shadowed.is_some()));
    let marked = set
        .lights
        .iter()
        .filter(|l| l.shadowed == Some(true))
        .count();
    assert_eq!(marked, 3, "K lights marked");
}

#[test]
fn a_late_feed_shows_the_last_value_at_once() {
    let Some(broker) = broker_or_skip("nats last value") else {
        return;
    };
    // One set every 2 s: a feed that waited for the next publication would wait up to 2 s.
    let _d = Daemon::start(&broker, "roof", &["--lights", "8", "--fps", "0.5"]);
    let kept_seq = runtime().block_on(async {
        let js = async_nats::jetstream::new(async_nats::connect(broker.url()).await.unwrap());
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            if let Ok(s) = js.get_stream("vemlight_roof").await
                && let Ok(m) = s
                    .direct_get_last_for_subject("vemlight.v1.roof.lights.8")
                    .await
            {
                let set: LightSet = serde_json::from_slice(&m.payload).unwrap();
                break set.seq;
            }
            assert!(Instant::now() < deadline, "the stream never held a set");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    let joined_ns = now_ns();
    let start = Instant::now();
    let url = format!("{}/roof?lights=8", broker.url());
    // The kept set may be up to 2 s old at this rate: the age bound is widened to match.
    let feed = NatsFeed::start(&url, options(Some(Duration::from_secs(10)))).unwrap();
    let set = wait_for(Duration::from_secs(5), || feed.take_latest()).expect("a set");
    let took = start.elapsed();
    eprintln!(
        "late join at 0.5 sets/s: first set after {took:?} (seq {}, kept seq {kept_seq})",
        set.seq
    );
    assert!(
        took < Duration::from_millis(500),
        "first set after {took:?}"
    );
    assert!(
        set.t_capture_ns < joined_ns,
        "the set shown was captured before the feed joined: the last value, not a new one"
    );
    assert!(set.seq >= kept_seq);
    assert_eq!(feed.stats().last_values, 1, "{:?}", feed.stats());
}

/// A LightSet to publish by hand, with this `seq` and capture time.
fn hand_made(template: &LightSet, seq: u64, t_capture_ns: u64) -> Vec<u8> {
    let mut set = template.clone();
    set.seq = seq;
    set.t_capture_ns = t_capture_ns;
    set.t_emit_ns = t_capture_ns;
    serde_json::to_vec(&set).unwrap()
}

#[test]
fn sets_too_old_or_not_newer_are_dropped() {
    let Some(broker) = broker_or_skip("nats stale sets") else {
        return;
    };
    // No daemon: no stream, no status; the feed starts at once since the URL names camera and
    // count, and waits for sets.
    let url = format!("{}/roof?lights=4", broker.url());
    let feed = NatsFeed::start(&url, options(Some(Duration::from_secs(1)))).unwrap();
    wait_for(Duration::from_secs(10), || {
        feed.is_following().then_some(())
    })
    .expect("the feed subscribes");
    let template = lights_from_map("tests/data/overcast-plaza.exr".as_ref(), 4).unwrap();
    let rt = runtime();
    let nc = rt.block_on(async { async_nats::connect(broker.url()).await.unwrap() });
    let publish = |payload: Vec<u8>| {
        rt.block_on(async {
            nc.publish("vemlight.v1.roof.lights.4", payload.into())
                .await
                .unwrap();
            nc.flush().await.unwrap();
        })
    };
    let stats_reach = |f: &dyn Fn(vemlight::render::view::nats::NatsStats) -> bool| {
        wait_for(Duration::from_secs(5), || f(feed.stats()).then_some(()))
            .unwrap_or_else(|| panic!("{:?}", feed.stats()))
    };

    // Captured 10 s ago: dropped.
    publish(hand_made(&template, 5, now_ns() - 10_000_000_000));
    stats_reach(&|s| s.too_old == 1);
    assert!(feed.take_latest().is_none(), "the old set is not shown");
    let report = feed.drop_report().expect("a report of the drop");
    assert!(report.contains("1 too old"), "{report}");

    // A fresh one after it: shown.
    let fresh_t = now_ns();
    publish(hand_made(&template, 6, fresh_t));
    let set = wait_for(Duration::from_secs(5), || feed.take_latest()).expect("the fresh set");
    assert_eq!((set.seq, set.t_capture_ns), (6, fresh_t));
    assert_eq!(set.lights.len(), 4);

    // Out of order (an older seq, captured earlier) and a repeat: dropped.
    publish(hand_made(&template, 4, fresh_t - 1_000_000));
    publish(hand_made(&template, 6, fresh_t));
    stats_reach(&|s| s.not_newer == 2);
    assert!(feed.take_latest().is_none());
    let stats = feed.stats();
    assert_eq!(
        (
            stats.received,
            stats.shown,
            stats.too_old,
            stats.last_values
        ),
        (4, 1, 1, 0),
        "{stats:?}"
    );
}

fn vemlight(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap()
}

#[test]
fn cameras_lists_two_daemons_and_view_asks_which_one() {
    let Some(broker) = broker_or_skip("nats cameras") else {
        return;
    };
    let _east = Daemon::start(&broker, "east", &["--lights", "8", "--fps", "5"]);
    let _west = Daemon::start(
        &broker,
        "west",
        &["--lights", "8", "--publish-lights", "8,16", "--fps", "5"],
    );
    wait_statuses(&broker, &["east", "west"]);
    let url = broker.url();

    let out = vemlight(&["cameras", &url]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    let rows: Vec<Vec<&str>> = stdout
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(rows[0][..3], ["CAMERA", "HEALTHY", "LIGHTS"], "{stdout}");
    assert_eq!(rows[1][..3], ["east", "yes", "8"], "{stdout}");
    assert_eq!(rows[2][..3], ["west", "yes", "8,16"], "{stdout}");

    let out = vemlight(&["cameras", &url, "--json"]);
    assert!(out.status.success(), "{out:?}");
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let names: Vec<&str> = doc
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["camera"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["east", "west"]);
    assert_eq!(doc[1]["lights"], serde_json::json!([8, 16]));
    assert!(
        doc[0]["http"]
            .as_str()
            .unwrap()
            .starts_with("http://127.0.0.1:")
    );

    // Two cameras and none named: a clear error that lists both and says how to pick.
    let dir = std::env::temp_dir().join(format!("vemlight-view-nats-{}", std::process::id()));
    let out = vemlight(&["view", &url, "--headless", "--out", dir.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("2 cameras publish"), "{stderr}");
    assert!(
        stderr.contains("--camera") && stderr.contains(&format!("{url}/CAMERA")),
        "{stderr}"
    );
    assert!(
        stderr.lines().any(|l| l.starts_with("east "))
            && stderr.lines().any(|l| l.starts_with("west ")),
        "{stderr}"
    );
    assert!(!dir.exists(), "nothing rendered");
}

#[test]
fn headless_view_renders_a_camera_through_the_broker() {
    let Some(broker) = broker_or_skip("nats headless view") else {
        return;
    };
    let _d = Daemon::start(&broker, "roof", &["--lights", "8", "--fps", "10"]);
    let dir = std::env::temp_dir().join(format!("vemlight-view-nats-hl-{}", std::process::id()));
    let url = format!("{}/roof?lights=8", broker.url());
    let out = vemlight(&[
        "view",
        &url,
        "--headless",
        "--frames",
        "2",
        "--size",
        "96x64",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("camera roof, 8 lights"), "{stderr}");
    for k in 0..2 {
        let line = format!("frame_{k:04}.png: 8 lights");
        assert!(stderr.contains(&line), "{line} in {stderr}");
        let img = image::open(dir.join(format!("frame_{k:04}.png")))
            .unwrap()
            .to_rgba8();
        assert_eq!(img.dimensions(), (96, 64));
        // Lit: the frame is not one flat colour.
        let lum: Vec<u32> = img
            .pixels()
            .map(|p| p[0] as u32 + p[1] as u32 + p[2] as u32)
            .collect();
        let (lo, hi) = (lum.iter().min().unwrap(), lum.iter().max().unwrap());
        assert!(hi - lo > 60, "flat frame {k}: {lo}..{hi}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
