//! The live view's broker mode (`GET /?nats=ws://…`, docs/API.md "Through a NATS broker") in a real
//! browser: a real nats-server with its WebSocket listener and the users and permissions docs/API.md
//! gives (read from the document itself), two daemons publishing as cameras east and west, and
//! headless Chromium driven over the DevTools protocol, opening the page from east's own server.
//! The page lists both cameras, follows the one picked with the light count asked for, draws its
//! lights, drops a stale set and a replayed one that the test publishes by hand, and logs no errors.
//! The permissions hold for async-nats clients too: the viewer reads and asks for last values but
//! cannot publish lights, a camera cannot publish as another. Then the broker's `allowed_origins`
//! refuses the page from west's server, a wrong password is refused, and the token login works
//! against a second broker.
//!
//! Needs `chromium` and `nats-server` (scripts/test.sh installs both and sets
//! `VEMLIGHT_REQUIRE_BROWSER=1` and `VEMLIGHT_REQUIRE_BROKER=1`); a plain `cargo test` without them
//! skips with a note.

mod common;

use common::Killed;
use common::broker::{Broker, Settings, free_port, nats_server};
use common::chromium;
use futures_util::StreamExt;
use serde_json::{Value, json};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const VIEWER_PASSWORD: &str = "viewer-pw-9f2";
const TOKEN: &str = "broker-token-51c";

/// The camera's password in the test broker's config.
fn password(camera: &str) -> String {
    format!("{camera}-pw-3d7")
}

/// docs/API.md's `authorization {}` block, with its `roof` camera user repeated for each of
/// `cameras` and the passwords it reads from the environment defined as config variables: the
/// permissions the test runs are the ones the document gives.
fn documented_authorization(cameras: &[&str]) -> String {
    let doc = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/API.md"),
    )
    .unwrap();
    let block = doc
        .split("```conf\n")
        .skip(1)
        .filter_map(|b| b.split("```").next())
        .find(|b| b.contains("authorization {"))
        .expect("docs/API.md has a ```conf block with an authorization {} block");
    let auth = &block[block.find("authorization {").unwrap()..];
    let auth = &auth[..auth.find("\n}\n").expect("the block ends with a lone }") + 3];
    let start = auth
        .find("    { user: roof,")
        .expect("the documented camera user is roof");
    let end = start + auth[start..].find("    } }\n").expect("roof's entry ends") + 8;
    let roof = &auth[start..end];
    let cameras_text: String = cameras
        .iter()
        .map(|c| {
            roof.replace("roof", c)
                .replace("$ROOF_PASSWORD", &format!("${}_PASSWORD", c.to_uppercase()))
        })
        .collect();
    let mut vars = format!("VIEWER_PASSWORD: \"{VIEWER_PASSWORD}\"\n");
    for c in cameras {
        vars += &format!("{}_PASSWORD: \"{}\"\n", c.to_uppercase(), password(c));
    }
    assert!(auth.contains("{ user: viewer,"), "no viewer user: {auth}");
    format!("{vars}{}{cameras_text}{}", &auth[..start], &auth[end..])
}

/// `vemlight serve` on `bind`, publishing as `camera` with that camera's login (from the
/// environment, as docs/API.md says).
fn spawn_camera(bind: &str, broker: &Broker, camera: &str) -> (Killed, SocketAddr) {
    let password = password(camera);
    let (child, addr) = common::spawn_serve_with_env(
        &[
            "--bind",
            bind,
            "--sky-size",
            "256x128",
            "--publish",
            &broker.url(),
            "--camera",
            camera,
            "--publish-lights",
            "8,16",
        ],
        &[
            ("VEMLIGHT_NATS_USER", camera),
            ("VEMLIGHT_NATS_PASSWORD", &password),
        ],
    );
    (Killed(child), addr)
}

/// Waits until the daemon's broker link is up and its last-value stream made (which needs the
/// documented camera permissions).
async fn wait_for_stream(addr: SocketAddr, camera: &str) {
    let start = Instant::now();
    loop {
        let h: Value = match reqwest::get(format!("http://{addr}/healthz")).await {
            Ok(r) => r.json().await.unwrap_or(Value::Null),
            Err(_) => Value::Null,
        };
        if h["broker"]["state"] == "ok" && h["broker"]["stream"] == format!("vemlight_{camera}") {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "{camera}'s broker link or stream did not come up: {h}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// A NATS client logged in as `user`, keeping the broker's error reports.
async fn login(
    broker: &Broker,
    user: &str,
    password: &str,
) -> (async_nats::Client, Arc<Mutex<Vec<String>>>) {
    let errors = Arc::new(Mutex::new(Vec::new()));
    let e = errors.clone();
    let client = async_nats::ConnectOptions::with_user_and_password(user.into(), password.into())
        .event_callback(move |event| {
            let e = e.clone();
            async move {
                if let async_nats::Event::ServerError(err) = event {
                    e.lock().unwrap().push(err.to_string().to_lowercase());
                }
            }
        })
        .connect(broker.url())
        .await
        .unwrap_or_else(|err| panic!("{user} logs in: {err}"));
    (client, errors)
}

async fn next_set(sub: &mut async_nats::Subscriber) -> Value {
    let m = tokio::time::timeout(Duration::from_secs(5), sub.next())
        .await
        .expect("a set in 5 s")
        .expect("subscription open");
    serde_json::from_slice(&m.payload).expect("a JSON set")
}

/// Waits until the broker has reported a permissions violation to `errors`.
async fn wait_for_violation(errors: &Mutex<Vec<String>>, what: &str) {
    let start = Instant::now();
    while !errors
        .lock()
        .unwrap()
        .iter()
        .any(|e| e.contains("permissions violation"))
    {
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "{what}: no permissions violation reported: {:?}",
            errors.lock().unwrap()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Checks the documented permissions with plain clients: the viewer reads sets and last values,
/// and what it or a camera publishes outside its rights never reaches a subscriber.
async fn check_permissions(broker: &Broker) {
    let (viewer, viewer_errors) = login(broker, "viewer", VIEWER_PASSWORD).await;
    let subject = "vemlight.v1.east.lights.8";
    let mut sub = viewer.subscribe(subject).await.unwrap();
    let mut west_status = viewer.subscribe("vemlight.v1.west.status").await.unwrap();
    viewer.flush().await.unwrap();
    let set = next_set(&mut sub).await;
    assert_eq!(set["lights"].as_array().map(Vec::len), Some(8), "{set}");

    // The last value: the raw direct get docs/API.md describes, and async-nats's own.
    let reply = viewer
        .request(
            format!("$JS.API.DIRECT.GET.vemlight_east.{subject}"),
            "".into(),
        )
        .await
        .expect("the viewer may ask for a last value");
    let headers = reply.headers.clone().expect("a direct get has headers");
    assert_eq!(
        headers.get("Nats-Stream").map(|v| v.as_str()),
        Some("vemlight_east")
    );
    assert_eq!(
        headers.get("Nats-Subject").map(|v| v.as_str()),
        Some(subject)
    );
    for h in ["Nats-Sequence", "Nats-Time-Stamp"] {
        assert!(headers.get(h).is_some(), "the reply lacks {h}: {headers:?}");
    }
    let last: Value = serde_json::from_slice(&reply.payload).expect("the stored set itself");
    assert_eq!(last["lights"].as_array().map(Vec::len), Some(8), "{last}");
    let none = viewer
        .request(
            "$JS.API.DIRECT.GET.vemlight_east.vemlight.v1.east.lights.9",
            "".into(),
        )
        .await
        .expect("an answer for a subject with no message");
    assert_eq!(none.status.map(|s| s.as_u16()), Some(404), "{none:?}");
    let stream = async_nats::jetstream::new(viewer.clone())
        .get_stream_no_info("vemlight_east")
        .await
        .unwrap();
    let m = stream
        .direct_get_last_for_subject(subject)
        .await
        .expect("async-nats's direct get works with a viewer's permissions");
    assert_eq!(m.subject.as_str(), subject);

    // The viewer cannot publish lights: the broker says so and drops the message.
    assert!(
        viewer_errors.lock().unwrap().is_empty(),
        "{viewer_errors:?}"
    );
    let forged = json!({ "forged": true }).to_string();
    viewer
        .publish(subject, forged.clone().into())
        .await
        .unwrap();
    viewer.flush().await.unwrap();
    wait_for_violation(&viewer_errors, "the viewer publishing lights").await;
    // A camera cannot speak for another.
    let (east, east_errors) = login(broker, "east", &password("east")).await;
    east.publish("vemlight.v1.west.status", forged.clone().into())
        .await
        .unwrap();
    east.flush().await.unwrap();
    wait_for_violation(&east_errors, "east publishing as west").await;
    // Neither reached a subscriber (sets and statuses flow meanwhile).
    let until = Instant::now() + Duration::from_secs(1);
    let mut seen = 0;
    while Instant::now() < until {
        for s in [&mut sub, &mut west_status] {
            if let Ok(Some(m)) = tokio::time::timeout(Duration::from_millis(20), s.next()).await {
                assert_ne!(
                    m.payload,
                    forged.as_bytes(),
                    "a forged message was delivered"
                );
                seen += 1;
            }
        }
    }
    assert!(seen > 5, "the subscriptions went quiet ({seen} messages)");
}

/// The pixels under each drawn light's centre, and how many pixels are lit, read in one go (so no
/// redraw comes between): the centre from DESIGN.md's lat-long mapping, worked out here rather than
/// by the page's own function.
const CANVAS_PROBE: &str = r#"(() => {
  const c = document.getElementById("sky"), g = c.getContext("2d");
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let lit = 0;
  for (let i = 0; i < d.length; i += 4) if (Math.max(d[i], d[i + 1], d[i + 2]) > 64) lit++;
  const set = vemlightView.state().drawn;
  const centres = set.to_light.map(([x, y, z]) => {
    const u = 0.5 + Math.atan2(x, -z) / (2 * Math.PI), v = Math.acos(Math.max(-1, Math.min(1, y))) / Math.PI;
    const px = Math.min(c.width - 1, Math.floor(u * c.width)), py = Math.min(c.height - 1, Math.floor(v * c.height));
    const i = 4 * (py * c.width + px);
    return [d[i], d[i + 1], d[i + 2]];
  });
  return JSON.stringify({ seq: set.seq, lit, centres, size: [c.width, c.height] });
})()"#;

fn seqs(state: &Value, camera: &str) -> Vec<u64> {
    state["shown"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s["camera"] == camera)
        .map(|s| s["seq"].as_u64().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_live_view_follows_a_camera_through_the_broker() {
    let Some(browser) = chromium::browser_or_skip() else {
        return;
    };
    if nats_server().is_none() {
        assert!(
            std::env::var_os("VEMLIGHT_REQUIRE_BROKER").is_none(),
            "nats-server is not installed (scripts/test.sh installs it)"
        );
        eprintln!("skipped: nats-server is not installed (scripts/test.sh installs it)");
        return;
    }
    let test_start = Instant::now();
    // East serves the page; only its origin may open the broker's WebSocket listener.
    let east_bind = format!("127.0.0.1:{}", free_port());
    let broker = Broker::start(Settings {
        extra: documented_authorization(&["east", "west"]),
        websocket: format!("  allowed_origins: [\"http://{east_bind}\"]"),
        ..Settings::default()
    });
    let (_east, east) = spawn_camera(&east_bind, &broker, "east");
    let (_west, west) = spawn_camera("127.0.0.1:0", &broker, "west");
    wait_for_stream(east, "east").await;
    wait_for_stream(west, "west").await;
    check_permissions(&broker).await;

    let profile =
        std::env::temp_dir().join(format!("vemlight-nats-chromium-{}", std::process::id()));
    let (_chrome, mut cdp) = chromium::launch(
        browser,
        &profile,
        &["--disable-gpu", "--window-size=1200,900"],
        "JSON.stringify(window.vemlightView ? vemlightView.state() : null)",
    )
    .await;
    let ws = broker.ws_url();
    cdp.open(&format!(
        "http://{east}/?nats={ws}&lights=8&nats_user=viewer&nats_password={VIEWER_PASSWORD}"
    ))
    .await;

    // Both cameras listed, from their status messages; none followed until one is picked.
    let s = cdp
        .wait_for("both cameras listed", Duration::from_secs(20), |s| {
            s["connected"] == true && s["cameras"] == json!(["east", "west"])
        })
        .await;
    assert_eq!(s["mode"], "nats", "{s}");
    assert!(s["camera"].is_null() && s["subject"].is_null(), "{s}");
    let options = cdp
        .eval("JSON.stringify([...document.getElementById('camera').options].map((o) => o.value))")
        .await;
    assert_eq!(options, json!(["", "east", "west"]));
    // The login was taken off the address.
    let href = cdp.eval("JSON.stringify(location.href)").await;
    assert!(
        !href.as_str().unwrap().contains("nats_password"),
        "the password stayed in the address: {href}"
    );

    // Pick west (a camera other than the daemon serving the page), as a user does.
    cdp.eval(
        "{ const c = document.getElementById('camera'); c.value = 'west'; \
         c.dispatchEvent(new Event('change')); 'null' }",
    )
    .await;
    let s = cdp
        .wait_for("sets of west", Duration::from_secs(15), |s| {
            s["camera"] == "west" && seqs(s, "west").len() >= 20
        })
        .await;
    assert_eq!(s["subject"], "vemlight.v1.west.lights.8", "{s}");
    assert_eq!(s["lastValue"], "received", "no last value: {s}");
    let shown = s["shown"].as_array().unwrap();
    assert!(
        shown
            .iter()
            .all(|x| x["camera"] == "west" && x["lights"] == 8),
        "{s}"
    );
    let seq = seqs(&s, "west");
    assert!(
        seq.windows(2).all(|w| w[1] > w[0]),
        "seq not increasing: {seq:?}"
    );
    let title = cdp.eval("JSON.stringify(document.title)").await;
    assert!(
        title
            .as_str()
            .unwrap()
            .starts_with("vemlight — west: 8 lights, seq "),
        "{title}"
    );
    let address = cdp.eval("JSON.stringify(location.search)").await;
    assert_eq!(
        address,
        json!(format!("?nats={ws}&camera=west&lights=8")),
        "the address to bookmark"
    );

    // The lights are drawn: every light's centre is lit, and lit pixels are many.
    let probe = cdp.eval(CANVAS_PROBE).await;
    let centres = probe["centres"].as_array().unwrap();
    assert_eq!(centres.len(), 8, "{probe}");
    for (k, rgb) in centres.iter().enumerate() {
        let peak = (0..3).map(|i| rgb[i].as_u64().unwrap()).max().unwrap();
        assert!(peak > 64, "light {k}'s centre is background: {probe}");
    }
    let lit = probe["lit"].as_u64().unwrap();
    assert!(lit > 8 * 12, "only {lit} pixels lit: {probe}");
    eprintln!("canvas: {lit} pixels lit by set {}", probe["seq"]);

    // A stale set (captured an hour ago, with a larger seq) and a replayed one, published by hand
    // as the camera: both are counted as dropped, neither is shown, and sets keep coming.
    let (west_client, _) = login(&broker, "west", &password("west")).await;
    let (viewer, _) = login(&broker, "viewer", VIEWER_PASSWORD).await;
    let mut sub = viewer.subscribe("vemlight.v1.west.lights.8").await.unwrap();
    let real = next_set(&mut sub).await;
    let real_seq = real["seq"].as_u64().unwrap();
    let hour = 3_600_000_000_000_u64;
    let mut stale = real.clone();
    stale["seq"] = json!(real_seq + 1_000_000);
    for t in ["t_capture_ns", "t_emit_ns"] {
        stale[t] = json!(real[t].as_u64().unwrap() - hour);
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    west_client
        .publish("vemlight.v1.west.lights.8", stale.to_string().into())
        .await
        .unwrap();
    west_client
        .publish("vemlight.v1.west.lights.8", real.to_string().into())
        .await
        .unwrap();
    west_client.flush().await.unwrap();
    let stale_seq = real_seq + 1_000_000;
    let s = cdp
        .wait_for(
            "the stale and the replayed set dropped",
            Duration::from_secs(10),
            |s| {
                let dropped = s["dropped"].as_array().unwrap();
                let has = |seq: u64, why: &str| {
                    dropped.iter().any(|d| d["seq"] == seq && d["why"] == why)
                };
                has(stale_seq, "old") && has(real_seq, "out of order")
            },
        )
        .await;
    let age = s["dropped"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["seq"] == stale_seq)
        .unwrap()["ageMs"]
        .as_f64()
        .unwrap();
    assert!(
        (age - 3.6e6).abs() < 60e3,
        "the stale set's age was {age} ms"
    );
    assert!(s["stats"]["droppedOld"].as_u64() >= Some(1), "{s}");
    assert!(s["stats"]["droppedOutOfOrder"].as_u64() >= Some(1), "{s}");
    let s = cdp
        .wait_for("sets after the stale one", Duration::from_secs(10), |s| {
            seqs(s, "west").last().is_some_and(|&q| q > real_seq + 15)
        })
        .await;
    let seq = seqs(&s, "west");
    assert!(
        !seq.contains(&stale_seq),
        "the stale set was shown: {seq:?}"
    );
    assert!(seq.windows(2).all(|w| w[1] > w[0]), "{seq:?}");
    let table = cdp
        .eval("JSON.stringify(document.getElementById('info').textContent)")
        .await;
    let table = table.as_str().unwrap();
    let old: u64 = table
        .split(" older than 1000 ms")
        .next()
        .and_then(|t| t.rsplit(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no drop counter in the table: {table}"));
    assert!(old >= 1, "{table}");
    assert!(table.contains("west (live)"), "{table}");

    // No errors so far: none the page caught, no exception, no console or log error.
    assert_eq!(s["errors"], json!([]), "the page reported errors: {s}");
    let problems = cdp.problems(|_| false);
    assert!(problems.is_empty(), "the page logged errors: {problems:#?}");

    // The light count is the page's choice: 16 from the select.
    cdp.eval(
        "{ const l = document.getElementById('lights'); l.value = '16'; \
         l.dispatchEvent(new Event('change')); 'null' }",
    )
    .await;
    let s = cdp
        .wait_for("16 lights", Duration::from_secs(10), |s| {
            s["subject"] == "vemlight.v1.west.lights.16"
                && s["shown"].as_array().unwrap().len() >= 3
        })
        .await;
    assert!(
        s["shown"]
            .as_array()
            .unwrap()
            .iter()
            .all(|x| x["lights"] == 16),
        "{s}"
    );

    // allowed_origins: the same page from west's server is refused at the handshake.
    cdp.open(&format!(
        "http://{west}/?nats={ws}&nats_user=viewer&nats_password={VIEWER_PASSWORD}"
    ))
    .await;
    let s = cdp
        .wait_for("the refused origin", Duration::from_secs(15), |s| {
            s["status"]
                .as_str()
                .is_some_and(|t| t.contains("cannot reach the broker"))
        })
        .await;
    assert_eq!(s["connected"], false, "{s}");
    assert!(
        s["status"]
            .as_str()
            .unwrap()
            .contains(&format!("allowed_origins list http://{west}")),
        "{s}"
    );
    // A wrong password is refused, and said so.
    cdp.open(&format!(
        "http://{east}/?nats={ws}&nats_user=viewer&nats_password=wrong"
    ))
    .await;
    let s = cdp
        .wait_for("the refused login", Duration::from_secs(15), |s| {
            s["authFailed"] == true
        })
        .await;
    assert!(
        s["status"].as_str().unwrap().contains("refused the login"),
        "{s}"
    );

    // A token login (`?nats_token=`), against a broker that takes one, and a camera there that
    // published once, ten seconds ago, into its last-value stream (the daemon's own stream
    // config): the page lists it and shows that set at once, saying how old it is.
    let token_broker = Broker::start(Settings {
        extra: format!("authorization {{ token: \"{TOKEN}\" }}"),
        ..Settings::default()
    });
    let lobby = async_nats::ConnectOptions::with_token(TOKEN.into())
        .connect(token_broker.url())
        .await
        .expect("the token logs in");
    let js = async_nats::jetstream::new(lobby.clone());
    js.create_stream(vemlight::publish::stream_config("lobby", 1))
        .await
        .expect("the lobby's stream");
    let mut old_set = real.clone();
    old_set["seq"] = json!(7);
    for t in ["t_capture_ns", "t_emit_ns"] {
        old_set[t] = json!(vemlight::lightset::now_ns() - 10_000_000_000);
    }
    js.publish("vemlight.v1.lobby.lights.8", old_set.to_string().into())
        .await
        .unwrap()
        .await
        .expect("stored");
    cdp.open(&format!(
        "http://{east}/?nats={}&nats_token={TOKEN}&camera=lobby&lights=8",
        token_broker.ws_url()
    ))
    .await;
    let status =
        json!({ "schema": "vemlight.status/1", "camera": "lobby", "healthy": true, "lights": [8] });
    let start = Instant::now();
    let s = loop {
        lobby
            .publish("vemlight.v1.lobby.status", status.to_string().into())
            .await
            .unwrap();
        let s = cdp.state().await;
        if s["cameras"] == json!(["lobby"]) && !s["shown"].as_array().unwrap().is_empty() {
            break s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(15),
            "the token login did not list the camera and its last value: {s}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(s["connected"], true, "{s}");
    assert_eq!(
        s["shown"],
        json!([{ "seq": 7, "lights": 8, "camera": "lobby", "via": "last value" }]),
        "{s}"
    );
    let table = cdp
        .eval("JSON.stringify(document.getElementById('info').textContent)")
        .await;
    let table = table.as_str().unwrap();
    let age: f64 = table
        .split("last value, captured ")
        .nth(1)
        .and_then(|t| t.split(" s ago").next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("the table does not say the last value's age: {table}"));
    assert!((10.0..13.0).contains(&age), "{table}");
    cdp.open(&format!(
        "http://{east}/?nats={}&nats_token=wrong",
        token_broker.ws_url()
    ))
    .await;
    cdp.wait_for("the refused token", Duration::from_secs(15), |s| {
        s["authFailed"] == true
    })
    .await;
    let _ = std::fs::remove_dir_all(&profile);
    eprintln!(
        "nats browser test took {:.1} s",
        test_start.elapsed().as_secs_f64()
    );
}
