//! The subscriber's side of the broker, shared by `vemlight cameras` and `vemlight view
//! nats://…`: which cameras publish on a broker (read from their status messages, which come once
//! a second), a camera's last status, the broker URL a viewer names, and how a subscriber logs in
//! (the same environment and files as `serve --publish`, never the command line).
//!
//! A leaf under [`crate::publish`]: the CLI and the viewer import it, it imports neither.

use super::login::{NatsAuth, connect_options};
use super::{STATUS_SCHEMA, subjects};
use anyhow::{Context, bail};
use futures_util::StreamExt;
use std::fmt::Write as _;
use std::time::Duration;

/// How long a listing listens to `vemlight.v1.*.status`: statuses come once a second, so every
/// live camera speaks at least once.
pub const LISTEN: Duration = Duration::from_millis(1500);

/// How long a viewer waits for the broker before giving up on a question it must answer before
/// it can start (which cameras, which counts).
pub const CONNECT_WAIT: Duration = Duration::from_secs(5);

/// One camera as its last status describes it (the `vemlight.status/1` document).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    pub camera: String,
    /// The source delivers frames.
    pub healthy: bool,
    /// The light counts published, each on `vemlight.v1.<camera>.lights.<n>`.
    pub lights: Vec<usize>,
    #[serde(default)]
    pub latest_seq: Option<u64>,
    /// The daemon's own HTTP address.
    #[serde(default)]
    pub http: Option<String>,
    /// When the status was sent, ns since the Unix epoch.
    pub t_ns: u64,
    #[serde(default)]
    pub version: Option<String>,
    /// The daemon's source health, as its `/healthz` reports it.
    #[serde(default)]
    pub source: serde_json::Value,
}

impl Camera {
    /// A status message read from `subject`: `None` unless it is a `vemlight.status/1` document
    /// whose camera is the subject's.
    pub fn from_message(subject: &str, payload: &[u8]) -> Option<Camera> {
        #[derive(serde::Deserialize)]
        struct Schema {
            schema: String,
        }
        let schema: Schema = serde_json::from_slice(payload).ok()?;
        if schema.schema != STATUS_SCHEMA {
            return None;
        }
        let cam: Camera = serde_json::from_slice(payload).ok()?;
        (subjects::camera_of(subject) == Some(cam.camera.as_str())).then_some(cam)
    }

    /// The source's name (`synthetic`, a file name, …).
    pub fn source_name(&self) -> &str {
        self.source
            .get("source")
            .and_then(|s| s.as_str())
            .unwrap_or("")
    }
}

/// The cameras whose statuses arrive within `listen`, by name, each with its newest status.
pub async fn list(client: &async_nats::Client, listen: Duration) -> anyhow::Result<Vec<Camera>> {
    let mut sub = client
        .subscribe(subjects::ALL_STATUS)
        .await
        .context("subscribing to the cameras' statuses")?;
    let mut found = std::collections::BTreeMap::<String, Camera>::new();
    let deadline = tokio::time::Instant::now() + listen;
    while let Ok(Some(m)) = tokio::time::timeout_at(deadline, sub.next()).await {
        if let Some(cam) = Camera::from_message(&m.subject, &m.payload)
            && found
                .get(&cam.camera)
                .is_none_or(|seen| seen.t_ns <= cam.t_ns)
        {
            found.insert(cam.camera.clone(), cam);
        }
    }
    let _ = sub.unsubscribe().await;
    Ok(found.into_values().collect())
}

/// `camera`'s last status: the value the JetStream stream keeps (at once), else the next one
/// published within `wait`.
pub async fn last_status(
    client: &async_nats::Client,
    camera: &str,
    wait: Duration,
) -> anyhow::Result<Option<Camera>> {
    let subject = subjects::status(camera);
    let mut sub = client.subscribe(subject.clone()).await?;
    let js = async_nats::jetstream::new(client.clone());
    let kept = async {
        js.get_stream_no_info(subjects::stream_name(camera))
            .await
            .ok()?
            .direct_get_last_for_subject(subject.clone())
            .await
            .ok()
    };
    if let Ok(Some(m)) = tokio::time::timeout(Duration::from_secs(2), kept).await
        && let Some(cam) = Camera::from_message(&subject, &m.payload)
    {
        return Ok(Some(cam));
    }
    let deadline = tokio::time::Instant::now() + wait;
    while let Ok(Some(m)) = tokio::time::timeout_at(deadline, sub.next()).await {
        if let Some(cam) = Camera::from_message(&m.subject, &m.payload) {
            return Ok(Some(cam));
        }
    }
    Ok(None)
}

/// The cameras as a table: name, health, published counts, latest sequence number, source and
/// the daemon's HTTP address.
pub fn table(cameras: &[Camera]) -> String {
    let rows: Vec<[String; 6]> = cameras
        .iter()
        .map(|c| {
            [
                c.camera.clone(),
                if c.healthy { "yes" } else { "no" }.into(),
                c.lights
                    .iter()
                    .map(usize::to_string)
                    .collect::<Vec<_>>()
                    .join(","),
                c.latest_seq.map(|s| s.to_string()).unwrap_or("-".into()),
                c.source_name().to_string(),
                c.http.clone().unwrap_or("-".into()),
            ]
        })
        .collect();
    let head = ["CAMERA", "HEALTHY", "LIGHTS", "SEQ", "SOURCE", "HTTP"];
    let widths: Vec<usize> = (0..head.len())
        .map(|k| {
            rows.iter()
                .map(|r| r[k].chars().count())
                .chain([head[k].len()])
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for row in std::iter::once(head.map(String::from)).chain(rows) {
        let line: Vec<String> = row
            .iter()
            .zip(&widths)
            .map(|(cell, w)| format!("{cell:w$}"))
            .collect();
        let _ = writeln!(out, "{}", line.join("  ").trim_end());
    }
    out
}

/// A broker URL as a subscriber names it: `nats://HOST:PORT[/CAMERA][?lights=N]` (or `tls://`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BrokerUrl {
    /// `scheme://host:port`, what the client connects to.
    pub server: String,
    pub camera: Option<String>,
    pub lights: Option<usize>,
}

impl BrokerUrl {
    /// Parses and checks `url`. Credentials in it are refused: a command line is seen by every
    /// user of the machine (give them in the environment or a file, `LoginArgs`).
    pub fn parse(url: &str) -> Result<BrokerUrl, String> {
        let (scheme, rest) = url
            .split_once("://")
            .ok_or_else(|| format!("'{url}' is not nats://HOST:PORT[/CAMERA][?lights=N]"))?;
        if !matches!(scheme, "nats" | "tls") {
            return Err(format!(
                "'{url}': a broker URL starts with nats:// or tls://"
            ));
        }
        let (rest, query) = match rest.split_once('?') {
            Some((r, q)) => (r, Some(q)),
            None => (rest, None),
        };
        let (authority, path) = match rest.split_once('/') {
            Some((a, p)) => (a, p.trim_end_matches('/')),
            None => (rest, ""),
        };
        if authority.is_empty() {
            return Err(format!("'{url}' names no host: give {scheme}://HOST:PORT"));
        }
        if authority.contains('@') {
            return Err(
                "the broker URL carries credentials, which every user of this machine can read in \
                 the process list: give VEMLIGHT_NATS_TOKEN, VEMLIGHT_NATS_USER and \
                 VEMLIGHT_NATS_PASSWORD, --nats-token-file or --nats-creds instead"
                    .into(),
            );
        }
        let camera = if path.is_empty() {
            None
        } else {
            subjects::check_camera(path).map_err(|e| format!("'{url}': {e}"))?;
            Some(path.to_string())
        };
        let mut lights = None;
        for pair in query.into_iter().flat_map(|q| q.split('&')) {
            if pair.is_empty() {
                continue;
            }
            match pair.split_once('=') {
                Some(("lights", n)) => match n.parse::<usize>() {
                    Ok(n) if n >= 1 => lights = Some(n),
                    _ => return Err(format!("'{url}': lights={n} is not a light count")),
                },
                _ => {
                    return Err(format!(
                        "'{url}': unknown parameter '{pair}' (the one parameter is lights=N)"
                    ));
                }
            }
        }
        Ok(BrokerUrl {
            server: format!("{scheme}://{authority}"),
            camera,
            lights,
        })
    }
}

/// Connects once (no retry), within [`CONNECT_WAIT`]: for a question asked now.
pub async fn connect_now(server: &str, auth: &NatsAuth) -> anyhow::Result<async_nats::Client> {
    let opts = connect_options(auth)
        .await?
        .name("vemlight cameras")
        .connection_timeout(CONNECT_WAIT);
    match tokio::time::timeout(CONNECT_WAIT * 2, opts.connect(server)).await {
        Ok(Ok(c)) => Ok(c),
        Ok(Err(e)) => bail!("cannot reach the broker at {server}: {e}"),
        Err(_) => bail!("the broker at {server} did not answer within {CONNECT_WAIT:?}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls() {
        let u = BrokerUrl::parse("nats://127.0.0.1:4222/roof?lights=16").unwrap();
        assert_eq!(
            u,
            BrokerUrl {
                server: "nats://127.0.0.1:4222".into(),
                camera: Some("roof".into()),
                lights: Some(16)
            }
        );
        let u = BrokerUrl::parse("nats://broker:4222").unwrap();
        assert_eq!((u.camera, u.lights), (None, None));
        let u = BrokerUrl::parse("tls://broker:4222/?lights=8").unwrap();
        assert_eq!(
            (u.server.as_str(), u.camera, u.lights),
            ("tls://broker:4222", None, Some(8))
        );
        for bad in [
            "nats://",
            "http://broker:4222",
            "broker:4222",
            "nats://me:pw@broker:4222/roof",
            "nats://broker:4222/a.b",
            "nats://broker:4222/roof?lights=0",
            "nats://broker:4222/roof?lights=x",
            "nats://broker:4222/roof?light=8",
        ] {
            assert!(BrokerUrl::parse(bad).is_err(), "{bad}");
        }
        assert!(
            BrokerUrl::parse("nats://me:pw@b:1")
                .unwrap_err()
                .contains("VEMLIGHT_NATS_TOKEN")
        );
    }

    #[test]
    fn statuses_are_read_and_checked_against_their_subject() {
        let doc = serde_json::json!({
            "schema": STATUS_SCHEMA, "camera": "east", "t_ns": 5, "healthy": true,
            "source": {"source": "synthetic", "state": "running"}, "lights": [8, 16],
            "subjects": [], "latest_seq": 12, "http": "http://127.0.0.1:1", "version": "0.1.0"
        })
        .to_string();
        let cam = Camera::from_message("vemlight.v1.east.status", doc.as_bytes()).unwrap();
        assert_eq!(cam.lights, [8, 16]);
        assert_eq!(cam.source_name(), "synthetic");
        assert!(Camera::from_message("vemlight.v1.west.status", doc.as_bytes()).is_none());
        let other = doc.replace(STATUS_SCHEMA, "other/1");
        assert!(Camera::from_message("vemlight.v1.east.status", other.as_bytes()).is_none());
        let t = table(&[cam]);
        let lines: Vec<&str> = t.lines().collect();
        assert!(lines[0].starts_with("CAMERA  HEALTHY  LIGHTS"), "{t}");
        assert!(lines[1].starts_with("east    yes      8,16    12"), "{t}");
    }
}
