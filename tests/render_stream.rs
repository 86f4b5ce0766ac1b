//! The viewer's WebSocket client against a real server on loopback: it asks for the `vemlight.v1`
//! subprotocol, takes each text message as a LightSet, keeps the last set when the connection drops,
//! and reconnects. (No GPU needed.)
#![cfg(feature = "render")]

use std::net::TcpListener;
use std::time::{Duration, Instant};
use vemlight::lightset::{LightSet, SUBPROTOCOL};
use vemlight::render::view::source::{LightFeed, Source};

fn a_lightset(seq: u64) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args([
            "lights",
            "tests/data/overcast-plaza.exr",
            "-n",
            "4",
            "--no-sh",
        ])
        .output()
        .unwrap();
    let mut set: LightSet = serde_json::from_slice(&out.stdout).unwrap();
    set.seq = seq;
    serde_json::to_string(&set).unwrap()
}

/// What a connecting client asked of the fake daemon: the request's path and query, and the
/// subprotocol it named.
struct Asked {
    uri: String,
    protocol: Option<String>,
}

/// A fake daemon on loopback that answers one connection per message: the handshake (with the
/// `vemlight.v1` subprotocol), that one set, then it hangs up. Returns its port and what each
/// connection asked.
// tungstenite's handshake callback returns its (large) HTTP error response by value.
#[allow(clippy::result_large_err)]
fn fake_daemon(messages: Vec<String>) -> (u16, std::thread::JoinHandle<Vec<Asked>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let server = std::thread::spawn(move || {
        let mut asked = Vec::new();
        for msg in messages {
            let (tcp, _) = listener.accept().unwrap();
            let mut ws = tungstenite::accept_hdr(
                tcp,
                |req: &tungstenite::handshake::server::Request,
                 mut resp: tungstenite::handshake::server::Response| {
                    asked.push(Asked {
                        uri: req.uri().to_string(),
                        protocol: req
                            .headers()
                            .get("Sec-WebSocket-Protocol")
                            .map(|v| v.to_str().unwrap().to_owned()),
                    });
                    resp.headers_mut()
                        .insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().unwrap());
                    Ok(resp)
                },
            )
            .unwrap();
            ws.send(tungstenite::Message::text(msg)).unwrap();
            ws.close(None).unwrap();
            // Let the close handshake finish.
            let deadline = Instant::now() + Duration::from_secs(2);
            while Instant::now() < deadline && ws.read().is_ok() {}
        }
        asked
    });
    (port, server)
}

#[test]
fn the_stream_client_reconnects_and_keeps_the_latest_set() {
    // Two connections: each gets one set, then the server hangs up.
    let (port, server) = fake_daemon(vec![a_lightset(1), a_lightset(2)]);
    let url = format!("ws://127.0.0.1:{port}/v1/stream?lights=4");
    let mut feed = LightFeed::open(&Source::parse(&url), 4).unwrap();
    let first = feed.wait_first(Duration::from_secs(10)).unwrap();
    assert_eq!(first.seq, 1);
    // The second connection comes after the backoff; its set replaces the first.
    let second = feed.wait_first(Duration::from_secs(10)).unwrap();
    assert_eq!(second.seq, 2);
    assert_eq!(second.lights.len(), 4);
    let protocols: Vec<Option<String>> = server
        .join()
        .unwrap()
        .into_iter()
        .map(|a| a.protocol)
        .collect();
    assert_eq!(protocols, vec![Some(SUBPROTOCOL.to_owned()); 2]);
    let LightFeed::Stream(client) = &feed else {
        unreachable!()
    };
    assert_eq!(client.connections(), 2);
    drop(feed); // stops the thread promptly
}

/// `vemlight view --shadowed K` on a stream: the URL asks the daemon for `shadowed=K`; a set that
/// comes with marks is drawn as marked, and one without (a daemon that ignores the parameter) is
/// marked by the client, K lights.
#[test]
fn a_shadow_budget_is_asked_of_the_stream_and_kept_by_the_client() {
    let unmarked = a_lightset(1);
    let mut marked: LightSet = serde_json::from_str(&a_lightset(2)).unwrap();
    for (i, l) in marked.lights.iter_mut().enumerate() {
        l.shadowed = Some(i == 3); // the daemon's choice, whatever it is, is kept
    }
    let (port, server) = fake_daemon(vec![unmarked, serde_json::to_string(&marked).unwrap()]);
    let url = format!("ws://127.0.0.1:{port}/v1/stream?lights=4");
    let mut feed = LightFeed::open_with_budget(&Source::parse(&url), 4, Some(2)).unwrap();
    let shadowed = |set: &LightSet| -> Vec<u32> {
        assert!(
            set.lights.iter().all(|l| l.shadowed.is_some()),
            "every light marked"
        );
        set.lights
            .iter()
            .filter(|l| l.shadowed == Some(true))
            .map(|l| l.id)
            .collect()
    };
    let first = feed.wait_first(Duration::from_secs(10)).unwrap();
    assert_eq!(first.seq, 1);
    assert_eq!(shadowed(&first).len(), 2, "marked by the client");
    let second = feed.wait_first(Duration::from_secs(10)).unwrap();
    assert_eq!(second.seq, 2);
    assert_eq!(
        shadowed(&second),
        [marked.lights[3].id],
        "the daemon's marks"
    );
    let uris: Vec<String> = server.join().unwrap().into_iter().map(|a| a.uri).collect();
    assert_eq!(uris, vec!["/v1/stream?lights=4&shadowed=2".to_owned(); 2]);
    drop(feed);
}

/// A daemon that closes the stream with a reason (1011: its pipeline stopped) before any set: the
/// client's "no LightSet received" says that reason, not only that nothing came.
#[allow(clippy::result_large_err)]
#[test]
fn a_close_with_a_reason_is_said() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    // Every connection for 2 s is answered so, as a daemon whose pipeline stopped would.
    listener.set_nonblocking(true).unwrap();
    let server = std::thread::spawn(move || {
        let until = Instant::now() + Duration::from_secs(2);
        while Instant::now() < until {
            let Ok((tcp, _)) = listener.accept() else {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            };
            tcp.set_nonblocking(false).unwrap();
            let mut ws = tungstenite::accept_hdr(
                tcp,
                |_: &tungstenite::handshake::server::Request,
                 mut resp: tungstenite::handshake::server::Response| {
                    resp.headers_mut()
                        .insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().unwrap());
                    Ok(resp)
                },
            )
            .unwrap();
            ws.close(Some(tungstenite::protocol::CloseFrame {
                code: tungstenite::protocol::frame::coding::CloseCode::Error,
                reason: "the pipeline stopped".into(),
            }))
            .unwrap();
            let deadline = Instant::now() + Duration::from_millis(500);
            while Instant::now() < deadline && ws.read().is_ok() {}
        }
    });
    let url = format!("ws://127.0.0.1:{port}/v1/stream?lights=4");
    let mut feed = LightFeed::open(&Source::parse(&url), 4).unwrap();
    let err = feed
        .wait_first(Duration::from_secs(1))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("1011") && err.contains("the pipeline stopped"),
        "{err}"
    );
    server.join().unwrap();
    drop(feed);
}
