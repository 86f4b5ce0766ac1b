//! Where the viewer's lights come from: a LightSet JSON file, an environment map (lights extracted
//! in-process), the daemon's WebSocket stream, or a camera through a NATS broker ([`super::nats`]).
//!
//! Input: the `SOURCE` argument of `vemlight view`. Output: [`LightSet`]s through [`LightFeed::poll`].
//! The stream runs a blocking `tungstenite` client on a background thread with latest-state
//! semantics: the render loop takes the newest set and never waits on the network. When the
//! connection drops the feed keeps the last set (the viewer goes on drawing it, marked stale) and
//! reconnects with exponential backoff. The wire format (the document, its subprotocol) comes from
//! [`crate::lightset`]; the client imports nothing of the server (DESIGN.md, "The wire format").

use super::nats::{NatsFeed, NatsOptions};
use crate::envmap::{DEFAULT_MAX_PIXELS, EnvMap};
use crate::lights::Extractor;
use crate::lightset::{LightRequest, LightSet, SUBPROTOCOL, lightset_for_map};
use anyhow::{Context, bail};
use std::io::ErrorKind;
use std::net::TcpStream;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use tungstenite::protocol::frame::coding::CloseCode;

/// Where `vemlight serve` listens by default.
pub const DEFAULT_STREAM: &str = "ws://127.0.0.1:7878/v1/stream";

/// A parsed `SOURCE`.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// `ws://host:port/v1/stream?lights=N`.
    Stream(String),
    /// A LightSet document (`.json`).
    LightSetFile(PathBuf),
    /// An environment map (`.exr`, `.hdr`): lights extracted here with `lightset_for_map`.
    Map(PathBuf),
    /// `nats://host:port[/camera][?lights=N]` (or `tls://`): a camera's sets through a broker,
    /// the URL checked when the feed opens.
    Nats(String),
}

impl Source {
    pub fn parse(s: &str) -> Source {
        if s.starts_with("ws://") || s.starts_with("wss://") {
            Source::Stream(s.to_owned())
        } else if s.starts_with("nats://") || s.starts_with("tls://") {
            Source::Nats(s.to_owned())
        } else if s.to_ascii_lowercase().ends_with(".json") {
            Source::LightSetFile(s.into())
        } else {
            Source::Map(s.into())
        }
    }
}

/// Reads a LightSet document.
pub fn read_lightset(path: &std::path::Path) -> anyhow::Result<LightSet> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let set: LightSet = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a LightSet", path.display()))?;
    if set.lights.len() > crate::render::shading::MAX_LIGHTS {
        eprintln!(
            "vemlight view: {} holds {} lights; the renderer draws the first {} (a prefix of the \
             progressive order)",
            path.display(),
            set.lights.len(),
            crate::render::shading::MAX_LIGHTS
        );
    }
    Ok(set)
}

/// Extracts `lights` lights from a map file (the CLI's defaults otherwise).
pub fn lights_from_map(path: &std::path::Path, lights: usize) -> anyhow::Result<LightSet> {
    extract_from_map(path, lights, false)
}

/// [`lights_from_map`], with the map's L2 SH when `sh9` (for a shadow budget's remainder).
fn extract_from_map(path: &std::path::Path, lights: usize, sh9: bool) -> anyhow::Result<LightSet> {
    let req = LightRequest {
        lights,
        estimate_error: false,
        sh9,
        ..LightRequest::default()
    };
    req.validate().map_err(anyhow::Error::msg)?;
    let map = EnvMap::open(path, None, DEFAULT_MAX_PIXELS)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(lightset_for_map(&mut Extractor::new(), &map, &req, &name))
}

/// `url` asking the daemon for a shadow budget of `k` lights (docs/API.md, `GET /v1/stream`):
/// `shadowed=k` appended to its query, unless the query already has a `shadowed` parameter (then
/// the URL says what the user asked for and is left as it is).
pub fn stream_url_with_shadowed(url: &str, k: usize) -> String {
    let (rest, fragment) = match url.split_once('#') {
        Some((r, f)) => (r, Some(f)),
        None => (url, None),
    };
    let has = rest.split_once('?').is_some_and(|(_, q)| {
        q.split('&')
            .any(|p| p.split('=').next() == Some("shadowed"))
    });
    let mut out = rest.to_owned();
    if !has {
        out.push(if rest.contains('?') { '&' } else { '?' });
        out.push_str(&format!("shadowed={k}"));
    }
    if let Some(f) = fragment {
        out.push('#');
        out.push_str(f);
    }
    out
}

/// Marks `k` of `set`'s lights as the daemon's `shadowed=K` does (`budget::mark`, the marks of
/// `previous` kept where they still apply), and when the set has the map's SH, gives the remainder
/// as `sh9_unshadowed` (`budget::remainder_sh`). Returns the ids marked.
pub fn mark_shadow_budget(set: &mut LightSet, k: usize, previous: &[u32]) -> Vec<u32> {
    let ids = crate::lights::budget::mark(&mut set.lights, k, previous);
    if let Some(sh9) = &set.sh9 {
        set.sh9_unshadowed = Some(crate::lights::budget::remainder_sh(sh9, &set.lights));
    }
    ids
}

/// Lights for the render loop.
pub enum LightFeed {
    /// A set read once; `poll` hands it out the first time.
    Static(Option<Box<LightSet>>),
    Stream(StreamClient),
    /// A camera through a broker; `budget`: the shadow budget K and the ids marked last, for the
    /// sets that arrive without marks (the broker's, unless the daemon marks them).
    Nats {
        feed: NatsFeed,
        budget: Option<(usize, Vec<u32>)>,
    },
}

impl LightFeed {
    /// Opens a source: reads the file or extracts the lights now; starts the stream's thread.
    pub fn open(source: &Source, lights: usize) -> anyhow::Result<LightFeed> {
        Self::open_with_budget(source, lights, None)
    }

    /// [`open`](Self::open) with a shadow budget of `shadowed` lights (`vemlight view
    /// --shadowed K`): a stream is asked for `shadowed=K` (the daemon marks the lights); a file's
    /// or a map's lights are marked here, the same way, and so are a broker's sets that come
    /// without marks. Without it, a file's own marks are kept. A NATS source logs in as the
    /// environment says ([`NatsOptions::from_env`]; [`open_nats`](Self::open_nats) for more).
    pub fn open_with_budget(
        source: &Source,
        lights: usize,
        shadowed: Option<usize>,
    ) -> anyhow::Result<LightFeed> {
        let marked = |mut set: LightSet| {
            if let Some(k) = shadowed {
                mark_shadow_budget(&mut set, k, &[]);
            }
            LightFeed::Static(Some(Box::new(set)))
        };
        Ok(match source {
            Source::LightSetFile(p) => marked(read_lightset(p)?),
            Source::Map(p) => marked(extract_from_map(p, lights, shadowed.is_some())?),
            Source::Stream(url) => {
                let url = match shadowed {
                    Some(k) => stream_url_with_shadowed(url, k),
                    None => url.clone(),
                };
                LightFeed::Stream(StreamClient::start_with_budget(&url, shadowed)?)
            }
            Source::Nats(url) => Self::open_nats(url, NatsOptions::from_env()?, shadowed)?,
        })
    }

    /// A camera through a broker ([`NatsFeed::start`]), its sets marked here for a shadow budget
    /// of `shadowed` lights when they come without marks.
    pub fn open_nats(
        url: &str,
        opts: NatsOptions,
        shadowed: Option<usize>,
    ) -> anyhow::Result<LightFeed> {
        Ok(LightFeed::Nats {
            feed: NatsFeed::start(url, opts)?,
            budget: shadowed.map(|k| (k, Vec::new())),
        })
    }

    /// A new set, if one arrived since the last call.
    pub fn poll(&mut self) -> Option<LightSet> {
        match self {
            LightFeed::Static(set) => set.take().map(|s| *s),
            LightFeed::Stream(client) => client.take_latest(),
            LightFeed::Nats { feed, budget } => {
                let mut set = feed.take_latest()?;
                if let Some((k, marked)) = budget
                    && set.lights.iter().all(|l| l.shadowed.is_none())
                {
                    *marked = mark_shadow_budget(&mut set, *k, marked);
                }
                Some(set)
            }
        }
    }

    /// Whether the lights on screen may be out of date (the stream is down).
    pub fn is_stale(&self) -> bool {
        match self {
            LightFeed::Static(_) => false,
            LightFeed::Stream(client) => !client.is_connected(),
            LightFeed::Nats { feed, .. } => feed.is_stale(),
        }
    }

    /// A line for the log when a broker's sets were dropped (too old, or not newer) since the
    /// last report.
    pub fn drop_report(&self) -> Option<String> {
        match self {
            LightFeed::Nats { feed, .. } => feed.drop_report(),
            _ => None,
        }
    }

    /// Waits up to `timeout` for a first set (headless runs need lights before the first frame).
    pub fn wait_first(&mut self, timeout: Duration) -> anyhow::Result<LightSet> {
        let start = std::time::Instant::now();
        loop {
            if let Some(set) = self.poll() {
                return Ok(set);
            }
            if start.elapsed() > timeout {
                let why = match self {
                    LightFeed::Stream(c) => c.last_error(),
                    LightFeed::Nats { feed, .. } => feed.why_nothing(),
                    LightFeed::Static(_) => String::new(),
                };
                bail!("no LightSet received within {timeout:?} {why}");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// What the stream thread shares with the render loop.
#[derive(Default)]
struct Shared {
    latest: Option<LightSet>,
    connected: bool,
    last_error: String,
    /// Connections made so far (for tests and the log).
    connections: u32,
}

/// The background WebSocket client.
pub struct StreamClient {
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl StreamClient {
    /// Starts the client thread (it connects, and reconnects, on its own).
    pub fn start(url: &str) -> anyhow::Result<StreamClient> {
        Self::start_with_budget(url, None)
    }

    /// [`start`](Self::start) with a shadow budget of `shadowed` lights: a set that arrives
    /// without marks (from a daemon that does not know `shadowed=K`) is marked on the client's
    /// thread, with the ids it marked last time for hysteresis, as the daemon would.
    pub fn start_with_budget(url: &str, shadowed: Option<usize>) -> anyhow::Result<StreamClient> {
        if url.starts_with("wss://") {
            bail!("wss:// is not supported (the client is built without TLS); use ws://");
        }
        // Check the URL now, so that a typo is an error rather than an endless reconnect.
        tungstenite::client::IntoClientRequest::into_client_request(url)
            .with_context(|| format!("bad stream URL {url}"))?;
        let shared = Arc::new(Mutex::new(Shared::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop, url) = (shared.clone(), stop.clone(), url.to_owned());
            std::thread::Builder::new()
                .name("vemlight-stream".into())
                .spawn(move || stream_loop(&url, shadowed, &shared, &stop))?
        };
        Ok(StreamClient {
            shared,
            stop,
            thread: Some(thread),
        })
    }

    pub fn take_latest(&self) -> Option<LightSet> {
        self.shared.lock().ok()?.latest.take()
    }

    pub fn is_connected(&self) -> bool {
        self.shared.lock().map(|s| s.connected).unwrap_or(false)
    }

    pub fn connections(&self) -> u32 {
        self.shared.lock().map(|s| s.connections).unwrap_or(0)
    }

    pub fn last_error(&self) -> String {
        self.shared
            .lock()
            .map(|s| s.last_error.clone())
            .unwrap_or_default()
    }
}

impl Drop for StreamClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Connect, read until the connection ends, back off, repeat — until `stop`.
fn stream_loop(url: &str, shadowed: Option<usize>, shared: &Mutex<Shared>, stop: &AtomicBool) {
    const FIRST_BACKOFF: Duration = Duration::from_millis(250);
    const MAX_BACKOFF: Duration = Duration::from_secs(5);
    let mut backoff = FIRST_BACKOFF;
    let mut budget = shadowed.map(|k| (k, Vec::new()));
    while !stop.load(Ordering::Relaxed) {
        let result = connect_and_read(url, &mut budget, shared, stop, &mut backoff);
        if let Ok(mut s) = shared.lock() {
            s.connected = false;
            if let Err(e) = result {
                s.last_error = format!("({e:#})");
            }
        }
        // Sleep in short steps so that dropping the client is prompt.
        let until = std::time::Instant::now() + backoff;
        while std::time::Instant::now() < until && !stop.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(20));
        }
        backoff = (backoff * 2).min(MAX_BACKOFF);
    }
}

/// One connection's life. Resets `backoff` once connected.
/// `budget`: the shadow budget K and the ids marked last, for sets that arrive without marks.
fn connect_and_read(
    url: &str,
    budget: &mut Option<(usize, Vec<u32>)>,
    shared: &Mutex<Shared>,
    stop: &AtomicBool,
    backoff: &mut Duration,
) -> anyhow::Result<()> {
    use tungstenite::client::IntoClientRequest;
    let mut request = url.into_client_request()?;
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        tungstenite::http::HeaderValue::from_static(SUBPROTOCOL),
    );
    let uri = request.uri().clone();
    let host = uri.host().context("the URL has no host")?;
    let port = uri.port_u16().unwrap_or(80);
    let addr = std::net::ToSocketAddrs::to_socket_addrs(&(host, port))?
        .next()
        .context("the host does not resolve")?;
    let tcp = TcpStream::connect_timeout(&addr, Duration::from_secs(3))?;
    // A LightSet is ~10 KB; tungstenite's default 128 KiB read buffer is zeroed on every read.
    let config = tungstenite::protocol::WebSocketConfig::default().read_buffer_size(16 * 1024);
    let (mut ws, _response) =
        tungstenite::client::client_with_config(request, tcp, Some(config))
            .map_err(|e| anyhow::anyhow!("WebSocket handshake with {url} failed: {e}"))?;
    // Short read timeouts let the thread notice `stop`; a timeout is not a dropped connection.
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_millis(200)))?;
    *backoff = Duration::from_millis(250);
    if let Ok(mut s) = shared.lock() {
        s.connected = true;
        s.connections += 1;
    }
    while !stop.load(Ordering::Relaxed) {
        match ws.read() {
            Ok(tungstenite::Message::Text(text)) => match serde_json::from_str::<LightSet>(&text) {
                Ok(mut set) => {
                    if let Some((k, marked)) = budget
                        && set.lights.iter().all(|l| l.shadowed.is_none())
                    {
                        *marked = mark_shadow_budget(&mut set, *k, marked);
                    }
                    if let Ok(mut s) = shared.lock() {
                        s.latest = Some(set); // latest state: an unread older set is replaced
                    }
                }
                Err(e) => {
                    if let Ok(mut s) = shared.lock() {
                        s.last_error = format!("(a message was not a LightSet: {e})");
                    }
                }
            },
            // The daemon says why it closes (1008 at capacity, 1011 its pipeline stopped…):
            // kept for the "no LightSet received" message and the reconnect log.
            Ok(tungstenite::Message::Close(frame)) => {
                if let Some(f) = frame.filter(|f| f.code != CloseCode::Normal) {
                    anyhow::bail!("the stream closed: {} {}", u16::from(f.code), f.reason);
                }
                return Ok(());
            }
            Ok(_) => {} // pings are answered by tungstenite; binary messages are not ours
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed) => {
                return Ok(());
            }
            Err(e) => return Err(e.into()),
        }
    }
    let _ = ws.close(None);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shadow_budget_is_asked_of_the_stream_unless_the_url_asks_already() {
        let base = "ws://127.0.0.1:7878/v1/stream";
        assert_eq!(
            stream_url_with_shadowed(base, 4),
            format!("{base}?shadowed=4")
        );
        assert_eq!(
            stream_url_with_shadowed(&format!("{base}?lights=64"), 4),
            format!("{base}?lights=64&shadowed=4")
        );
        let asked = format!("{base}?lights=64&shadowed=2");
        assert_eq!(stream_url_with_shadowed(&asked, 4), asked);
        // A parameter that merely ends in "shadowed" is not it.
        assert_eq!(
            stream_url_with_shadowed(&format!("{base}?unshadowed=1"), 4),
            format!("{base}?unshadowed=1&shadowed=4")
        );
    }

    #[test]
    fn a_map_or_file_source_with_a_budget_marks_k_lights_and_without_keeps_its_marks() {
        let count = |set: &LightSet| {
            assert!(set.lights.iter().all(|l| l.shadowed.is_some()));
            set.lights
                .iter()
                .filter(|l| l.shadowed == Some(true))
                .count()
        };
        let map = Source::Map("tests/data/studio.exr".into());
        let marked = LightFeed::open_with_budget(&map, 8, Some(2))
            .unwrap()
            .poll()
            .unwrap();
        assert_eq!(count(&marked), 2);
        assert_eq!(marked.sh9_unshadowed.as_ref().map(Vec::len), Some(27));
        // A file: its own marks are kept without --shadowed, and replaced with it.
        let dir = std::env::temp_dir().join(format!("vemlight-budget-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("set.json");
        std::fs::write(&path, serde_json::to_string(&marked).unwrap()).unwrap();
        let file = Source::LightSetFile(path);
        let kept = LightFeed::open(&file, 0).unwrap().poll().unwrap();
        assert_eq!(count(&kept), 2);
        let more = LightFeed::open_with_budget(&file, 0, Some(3))
            .unwrap()
            .poll()
            .unwrap();
        assert_eq!(count(&more), 3);
        std::fs::remove_dir_all(&dir).unwrap();
        // Without a budget a map's lights carry no marks (the viewer shadows them all).
        let plain = LightFeed::open(&map, 8).unwrap().poll().unwrap();
        assert!(plain.lights.iter().all(|l| l.shadowed.is_none()));
    }

    #[test]
    fn sources_are_told_apart_by_scheme_and_extension() {
        assert_eq!(
            Source::parse("ws://127.0.0.1:7878/v1/stream?lights=72"),
            Source::Stream("ws://127.0.0.1:7878/v1/stream?lights=72".into())
        );
        assert_eq!(
            Source::parse("nats://127.0.0.1:4222/roof?lights=8"),
            Source::Nats("nats://127.0.0.1:4222/roof?lights=8".into())
        );
        assert_eq!(
            Source::parse("a/b.JSON"),
            Source::LightSetFile("a/b.JSON".into())
        );
        assert_eq!(
            Source::parse("tests/data/city.exr"),
            Source::Map("tests/data/city.exr".into())
        );
    }
}
