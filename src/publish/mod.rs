//! Publishing the light stream through a NATS broker (`vemlight serve --publish nats://…`), so
//! that many viewers and many cameras meet at a broker instead of at each daemon (docs/API.md,
//! "Through a NATS broker"; DESIGN.md, "Processes and endpoints").
//!
//! Input: the [`Hub`]'s latest sets, one subscription per published light count, as a WebSocket
//! client takes them. Output: each set on `vemlight.v1.<camera>.lights.<n>` and the daemon's
//! health once a second on `vemlight.v1.<camera>.status` ([`subjects`]), plus a JetStream stream
//! in memory with one message per subject, so that a viewer who joins gets the last value at
//! once.
//!
//! A broker never holds up capture: the hub is latest-state (a watcher skips sets, it never
//! blocks the pipeline), the watchers hand sets to a bounded queue that drops its oldest entry
//! when full, and one task publishes from it. A set that cannot go out — the broker is down, or
//! does not take it within [`PUBLISH_TIMEOUT`] — is dropped and counted, never retried: the next
//! set supersedes it. The client reconnects with backoff and the stream is made again after each
//! reconnect (a broker restarted with a memory store has lost it).

pub mod cameras;
pub mod login;
pub mod subjects;

pub use login::NatsAuth;

use crate::daemon::{Hub, StreamKey, Subscription};
use crate::lightset::now_ns;
use bytes::Bytes;
use std::collections::VecDeque;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

/// How long one publish may wait for room in the client's buffer before the set is dropped (a
/// slow or stalled broker connection).
pub const PUBLISH_TIMEOUT: Duration = Duration::from_millis(500);

/// How often the status subject is published.
pub const STATUS_INTERVAL: Duration = Duration::from_secs(1);

/// Sets waiting for the publisher at most; beyond, the oldest is dropped. A few frames of every
/// count: latest state matters, a backlog does not.
pub const QUEUE_CAPACITY: usize = 64;

/// Messages the NATS client buffers while writing (its default, 2048, would hold a minute of
/// stale sets for a slow broker).
const CLIENT_CAPACITY: usize = 128;

/// What `serve --publish` asks for.
#[derive(Clone, Debug)]
pub struct PublishConfig {
    /// `nats://host:port` (or `tls://`); credentials in it (only from `VEMLIGHT_NATS`, see
    /// [`check_url`]) become the login when connecting.
    pub url: String,
    pub camera: String,
    /// The light counts published, each on its own subject.
    pub counts: Vec<usize>,
    pub auth: NatsAuth,
    /// The daemon's own HTTP address, told in the status (a viewer may fall back to it).
    pub http: Option<String>,
    /// Replicas of the camera's JetStream stream (1 on a single broker; 3 on a cluster, so that
    /// the last values survive a node).
    pub replicas: usize,
}

/// The broker link's state, as `/healthz` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LinkState {
    /// Not connected yet since the daemon started.
    Connecting,
    Ok,
    /// Lost, reconnecting with backoff.
    Reconnecting,
}

/// Why a set was not published.
#[derive(Clone, Copy, Debug)]
enum Dropped {
    /// The queue was full; its oldest set went.
    QueueFull,
    /// A newer message of the same subject came before it went out (the broker is behind).
    Superseded,
    /// The broker was not connected.
    Disconnected,
    /// The broker did not take it within [`PUBLISH_TIMEOUT`] (or the client refused it).
    Timeout,
}

/// The broker link, shared with the server (`/healthz`, `/metrics`).
pub struct Link {
    url: String,
    camera: String,
    counts: Vec<usize>,
    inner: Mutex<LinkInner>,
    published: AtomicU64,
    dropped_queue_full: AtomicU64,
    dropped_superseded: AtomicU64,
    dropped_disconnected: AtomicU64,
    dropped_timeout: AtomicU64,
    /// Connections made (the first included), counted by the client's events.
    connects: AtomicU64,
}

struct LinkInner {
    state: LinkState,
    /// The JetStream stream, once made on this connection.
    stream: Option<String>,
    stream_error: Option<String>,
    /// The broker's or the client's last complaint since the link was last up (an authorization
    /// violation, say).
    last_error: Option<String>,
}

/// The broker link as `/healthz` reports it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LinkHealth {
    pub url: String,
    pub camera: String,
    pub state: LinkState,
    /// The JetStream stream holding the last values, when made; `None` with `stream_error`.
    pub stream: Option<String>,
    pub stream_error: Option<String>,
    /// Why the link is not up, when the broker or the client said.
    pub last_error: Option<String>,
    pub subjects: Vec<String>,
    pub published: u64,
    pub dropped: u64,
    pub reconnects: u64,
}

impl Link {
    fn new(cfg: &PublishConfig) -> Self {
        Link {
            url: cfg.url.clone(),
            camera: cfg.camera.clone(),
            counts: cfg.counts.clone(),
            inner: Mutex::new(LinkInner {
                state: LinkState::Connecting,
                stream: None,
                stream_error: None,
                last_error: None,
            }),
            published: AtomicU64::new(0),
            dropped_queue_full: AtomicU64::new(0),
            dropped_superseded: AtomicU64::new(0),
            dropped_disconnected: AtomicU64::new(0),
            dropped_timeout: AtomicU64::new(0),
            connects: AtomicU64::new(0),
        }
    }

    fn inner(&self) -> std::sync::MutexGuard<'_, LinkInner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn drop_one(&self, why: Dropped) {
        let counter = match why {
            Dropped::QueueFull => &self.dropped_queue_full,
            Dropped::Superseded => &self.dropped_superseded,
            Dropped::Disconnected => &self.dropped_disconnected,
            Dropped::Timeout => &self.dropped_timeout,
        };
        counter.fetch_add(1, Relaxed);
    }

    /// Messages published (sets and statuses).
    pub fn published(&self) -> u64 {
        self.published.load(Relaxed)
    }

    /// Messages dropped, whatever the reason.
    pub fn dropped(&self) -> u64 {
        self.dropped_queue_full.load(Relaxed)
            + self.dropped_superseded.load(Relaxed)
            + self.dropped_disconnected.load(Relaxed)
            + self.dropped_timeout.load(Relaxed)
    }

    pub fn health(&self) -> LinkHealth {
        let inner = self.inner();
        LinkHealth {
            url: self.url.clone(),
            camera: self.camera.clone(),
            state: inner.state,
            stream: inner.stream.clone(),
            stream_error: inner.stream_error.clone(),
            last_error: inner.last_error.clone(),
            subjects: self
                .counts
                .iter()
                .map(|&n| subjects::lights(&self.camera, n))
                .chain([subjects::status(&self.camera)])
                .collect(),
            published: self.published(),
            dropped: self.dropped(),
            reconnects: self.connects.load(Relaxed).saturating_sub(1),
        }
    }

    /// The link's lines in the Prometheus text format, for `GET /metrics`.
    pub fn render_metrics(&self, s: &mut String) {
        let _ = writeln!(
            s,
            "# HELP vemlight_nats_published_total Messages published to the broker (sets and statuses).\n\
             # TYPE vemlight_nats_published_total counter\nvemlight_nats_published_total {}",
            self.published()
        );
        let _ = writeln!(
            s,
            "# HELP vemlight_nats_dropped_total Messages not published: queue full (the publisher fell behind), \
             superseded (a newer one of the same subject came while the broker was behind), disconnected \
             (broker down), timeout (broker too slow).\n# TYPE vemlight_nats_dropped_total counter"
        );
        for (reason, c) in [
            ("queue_full", &self.dropped_queue_full),
            ("superseded", &self.dropped_superseded),
            ("disconnected", &self.dropped_disconnected),
            ("timeout", &self.dropped_timeout),
        ] {
            let _ = writeln!(
                s,
                "vemlight_nats_dropped_total{{reason=\"{reason}\"}} {}",
                c.load(Relaxed)
            );
        }
        let h = self.health();
        let _ = writeln!(
            s,
            "# HELP vemlight_nats_reconnects_total Times the broker link was made again after a loss.\n\
             # TYPE vemlight_nats_reconnects_total counter\nvemlight_nats_reconnects_total {}\n\
             # HELP vemlight_nats_connected Whether the broker link is up.\n\
             # TYPE vemlight_nats_connected gauge\nvemlight_nats_connected {}",
            h.reconnects,
            u8::from(h.state == LinkState::Ok)
        );
    }
}

/// One message for the broker.
struct Outgoing {
    subject: String,
    payload: Bytes,
}

/// The bounded, drop-oldest queue between the hub's watchers and the publisher. Latest state per
/// subject: a message replaces a waiting one of its subject, so a broker that is behind gets the
/// newest set of each count, not a backlog.
struct Queue {
    items: Mutex<VecDeque<Outgoing>>,
    ready: Notify,
    capacity: usize,
}

impl Queue {
    fn push(&self, link: &Link, m: Outgoing) {
        {
            let mut q = self.items.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(waiting) = q.iter_mut().find(|w| w.subject == m.subject) {
                *waiting = m;
                link.drop_one(Dropped::Superseded);
                drop(q);
                self.ready.notify_one();
                return;
            }
            if q.len() >= self.capacity {
                q.pop_front();
                link.drop_one(Dropped::QueueFull);
            }
            q.push_back(m);
        }
        self.ready.notify_one();
    }

    fn pop(&self) -> Option<Outgoing> {
        self.items
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop_front()
    }
}

/// The broker's URL checked: `nats://`, `tls://`, `ws://` or `wss://` (or a bare `host:port`),
/// with credentials only when `from_env` (a URL on the command line is seen by every user of the
/// machine in the process list).
pub fn check_url(url: &str, from_env: bool) -> Result<(), String> {
    let shown = redact_url(url);
    let rest = match url.split_once("://") {
        Some((scheme, rest)) => {
            if !matches!(scheme, "nats" | "tls" | "ws" | "wss") {
                return Err(format!(
                    "--publish '{shown}': the scheme must be nats://, tls://, ws:// or wss://"
                ));
            }
            rest
        }
        None => url,
    };
    let authority = rest.split(['/', '?', '#']).next().unwrap_or("");
    if authority.is_empty() {
        return Err(format!(
            "--publish '{shown}' names no host: give nats://HOST:PORT"
        ));
    }
    if authority.contains('@') && !from_env {
        return Err(
            "--publish carries credentials in its URL, which every user of this machine can read \
             in the process list: put the URL in VEMLIGHT_NATS instead, or give VEMLIGHT_NATS_TOKEN, \
             VEMLIGHT_NATS_USER and VEMLIGHT_NATS_PASSWORD, --nats-token-file or --nats-creds"
                .into(),
        );
    }
    Ok(())
}

/// `url` without the credentials it may carry, for logs and `/healthz`.
pub fn redact_url(url: &str) -> String {
    match url.split_once("://") {
        Some((scheme, rest)) => match rest.split_once('@') {
            Some((_, host)) if !rest.split(['/', '?']).next().unwrap_or("").is_empty() => {
                format!("{scheme}://***@{host}")
            }
            _ => url.to_string(),
        },
        None => match url.split_once('@') {
            Some((_, host)) => format!("***@{host}"),
            None => url.to_string(),
        },
    }
}

/// Connects (in the background: a broker that is down at start-up is retried like a lost one),
/// subscribes to the hub for each published count and starts the watcher, status, stream and
/// publisher tasks on the current tokio runtime; they end with the hub's shutdown. Fails only on
/// configuration (a light count the hub refuses, a credentials file that cannot be read).
pub async fn start(cfg: PublishConfig, hub: Arc<Hub>) -> anyhow::Result<Arc<Link>> {
    let subs: Vec<Subscription> = cfg
        .counts
        .iter()
        .map(|&n| {
            hub.subscribe(StreamKey::from(n))
                .map_err(|e| anyhow::anyhow!("--publish-lights {n}: {e}"))
        })
        .collect::<anyhow::Result<_>>()?;
    let link = Arc::new(Link::new(&PublishConfig {
        url: redact_url(&cfg.url),
        ..cfg.clone()
    }));
    let client = connect(&cfg, link.clone()).await?;
    let queue = Arc::new(Queue {
        items: Mutex::new(VecDeque::new()),
        ready: Notify::new(),
        capacity: QUEUE_CAPACITY,
    });
    let stop = hub.shutdown_token();

    for sub in subs {
        let subject = subjects::lights(&cfg.camera, sub.key.lights);
        tokio::spawn(watch_sets(
            sub,
            subject,
            queue.clone(),
            link.clone(),
            stop.clone(),
        ));
    }
    tokio::spawn(publish_status(
        hub.clone(),
        cfg.clone(),
        queue.clone(),
        link.clone(),
    ));
    tokio::spawn(keep_stream(
        client.clone(),
        stream_config(&cfg.camera, cfg.replicas),
        link.clone(),
        stop.clone(),
    ));
    tokio::spawn(publisher(client, queue, link.clone(), stop));
    tracing::info!(
        "publishing camera '{}' to {} on {} and {}",
        cfg.camera,
        link.url,
        subjects::lights(&cfg.camera, cfg.counts.first().copied().unwrap_or(0))
            + if cfg.counts.len() > 1 { " …" } else { "" },
        subjects::status(&cfg.camera)
    );
    Ok(link)
}

/// The client, connecting in the background and reconnecting for ever with the client's own
/// backoff (0 ms, then doubling up to 4 s); its events keep `link`'s state.
async fn connect(cfg: &PublishConfig, link: Arc<Link>) -> anyhow::Result<async_nats::Client> {
    use anyhow::Context;
    let (url, auth) = split_credentials(&cfg.url, &cfg.auth)?;
    let mut opts = login::connect_options(&auth).await?;
    opts = opts
        .name(format!("vemlight {}", cfg.camera))
        .retry_on_initial_connect()
        .max_reconnects(None)
        .client_capacity(CLIENT_CAPACITY)
        .event_callback(move |event| {
            let link = link.clone();
            async move {
                match event {
                    async_nats::Event::Connected => {
                        let n = link.connects.fetch_add(1, Relaxed);
                        let mut inner = link.inner();
                        inner.state = LinkState::Ok;
                        inner.last_error = None;
                        drop(inner);
                        if n > 0 {
                            tracing::info!("broker link {} is back", link.url);
                        }
                    }
                    async_nats::Event::Disconnected => {
                        let mut inner = link.inner();
                        inner.state = LinkState::Reconnecting;
                        // A restarted broker may have lost a memory stream: made again on
                        // reconnect.
                        inner.stream = None;
                        drop(inner);
                        tracing::warn!(
                            "broker link {} lost: reconnecting; sets are dropped meanwhile",
                            link.url
                        );
                    }
                    async_nats::Event::ServerError(e) => {
                        link.inner().last_error = Some(format!("server: {e}"));
                    }
                    async_nats::Event::ClientError(e) => {
                        link.inner().last_error = Some(format!("client: {e}"));
                    }
                    other => tracing::debug!("broker: {other}"),
                }
            }
        });
    opts.connect(url.as_str())
        .await
        .with_context(|| format!("--publish '{}'", redact_url(&cfg.url)))
}

/// The broker's address without credentials, and the login: the URL's own (`nats://user:pass@…`,
/// or `nats://token@…`, as given in VEMLIGHT_NATS) when it carries one, which the NATS client would
/// otherwise ignore; `auth` otherwise. Both at once is an error.
fn split_credentials(url: &str, auth: &NatsAuth) -> anyhow::Result<(String, NatsAuth)> {
    let addr: async_nats::ServerAddr = url
        .parse()
        .map_err(|e| anyhow::anyhow!("--publish '{}': {e}", redact_url(url)))?;
    let Some(user) = addr.username().filter(|u| !u.is_empty()).map(str::to_owned) else {
        return Ok((url.to_string(), auth.clone()));
    };
    if !matches!(auth, NatsAuth::None) {
        anyhow::bail!(
            "the broker URL carries credentials and {auth:?} is given too: give one login"
        );
    }
    let password = addr.password().map(str::to_owned);
    let mut bare = addr.into_inner();
    // Setting an empty user and no password on a URL with a host cannot fail.
    let _ = bare.set_password(None);
    let _ = bare.set_username("");
    let auth = match password {
        Some(p) => NatsAuth::UserPassword(user, p),
        None => NatsAuth::Token(user),
    };
    Ok((bare.to_string(), auth))
}

/// Hands each new set of one count to the queue.
async fn watch_sets(
    mut sub: Subscription,
    subject: String,
    queue: Arc<Queue>,
    link: Arc<Link>,
    stop: CancellationToken,
) {
    loop {
        tokio::select! {
            changed = sub.rx.changed() => {
                if changed.is_err() {
                    return;
                }
                let Some(set) = sub.rx.borrow_and_update().clone() else { continue };
                queue.push(&link, Outgoing { subject: subject.clone(), payload: set.json.clone() });
            }
            () = stop.cancelled() => return,
        }
    }
}

/// The status message: who this camera is, what it publishes, and the source's health.
#[derive(serde::Serialize)]
struct Status<'a> {
    schema: &'static str,
    camera: &'a str,
    t_ns: u64,
    /// The source delivers frames (not starting, ended, failed or stalled).
    healthy: bool,
    source: crate::daemon::SourceHealth,
    lights: &'a [usize],
    subjects: Vec<String>,
    latest_seq: Option<u64>,
    http: Option<&'a str>,
    version: &'static str,
}

/// The schema id of the status messages.
pub const STATUS_SCHEMA: &str = "vemlight.status/1";

/// Publishes the status once a second until shutdown.
async fn publish_status(hub: Arc<Hub>, cfg: PublishConfig, queue: Arc<Queue>, link: Arc<Link>) {
    let stop = hub.shutdown_token();
    let subject = subjects::status(&cfg.camera);
    let mut tick = tokio::time::interval(STATUS_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            () = stop.cancelled() => return,
        }
        let source = hub.health();
        let status = Status {
            schema: STATUS_SCHEMA,
            camera: &cfg.camera,
            t_ns: now_ns(),
            healthy: source.delivering(),
            source,
            lights: &cfg.counts,
            subjects: cfg
                .counts
                .iter()
                .map(|&n| subjects::lights(&cfg.camera, n))
                .collect(),
            latest_seq: hub.latest().map(|p| p.seq),
            http: cfg.http.as_deref(),
            version: env!("CARGO_PKG_VERSION"),
        };
        match serde_json::to_vec(&status) {
            Ok(json) => queue.push(
                &link,
                Outgoing {
                    subject: subject.clone(),
                    payload: json.into(),
                },
            ),
            Err(e) => tracing::error!("cannot serialise the status: {e}"),
        }
    }
}

/// The JetStream stream of one camera: memory, one message per subject (the last value), old
/// ones discarded, direct gets allowed (a viewer reads the last value from any replica).
pub fn stream_config(camera: &str, replicas: usize) -> async_nats::jetstream::stream::Config {
    use async_nats::jetstream::stream::{Config, DiscardPolicy, StorageType};
    Config {
        name: subjects::stream_name(camera),
        description: Some(format!(
            "vemlight: the last LightSet of each light count and the last status of camera {camera}"
        )),
        subjects: vec![subjects::camera_all(camera)],
        storage: StorageType::Memory,
        max_messages_per_subject: 1,
        discard: DiscardPolicy::Old,
        allow_direct: true,
        num_replicas: replicas.max(1),
        ..Default::default()
    }
}

/// Makes (or updates) the camera's stream on every connection: at start-up, and again after a
/// reconnect, since a restarted broker with a memory store has lost it. A broker without
/// JetStream, or one where another stream already takes these subjects, is reported in
/// `/healthz` and tried again every few seconds; sets are published all the same.
async fn keep_stream(
    client: async_nats::Client,
    config: async_nats::jetstream::stream::Config,
    link: Arc<Link>,
    stop: CancellationToken,
) {
    const RETRY: Duration = Duration::from_secs(3);
    let js = async_nats::jetstream::new(client);
    let name = config.name.clone();
    let replicas = config.num_replicas;
    let mut made_on: Option<u64> = None;
    let mut last_try: Option<Instant> = None;
    loop {
        tokio::select! {
            () = tokio::time::sleep(Duration::from_millis(100)) => {}
            () = stop.cancelled() => return,
        }
        let connects = link.connects.load(Relaxed);
        let up = link.inner().state == LinkState::Ok;
        if !up || made_on == Some(connects) || last_try.is_some_and(|t| t.elapsed() < RETRY) {
            continue;
        }
        last_try = Some(Instant::now());
        let made = tokio::time::timeout(
            Duration::from_secs(5),
            js.create_or_update_stream(config.clone()),
        )
        .await;
        let mut inner = link.inner();
        match made {
            Ok(Ok(_)) => {
                made_on = Some(connects);
                if inner.stream.is_none() {
                    tracing::info!(
                        "JetStream stream {name} keeps the last value of each subject (memory, one message per subject, {replicas} replica(s))"
                    );
                }
                inner.stream = Some(name.clone());
                inner.stream_error = None;
            }
            Ok(Err(e)) => {
                if inner.stream_error.is_none() {
                    tracing::warn!(
                        "cannot make the JetStream stream {name} ({e}): sets are published, but a viewer that joins waits for the next one"
                    );
                }
                inner.stream_error = Some(e.to_string());
            }
            Err(_) => {
                inner.stream_error = Some("the broker did not answer in 5 s".into());
            }
        }
    }
}

/// Messages published and not yet acknowledged by the broker, at most. Each set goes out as a
/// JetStream publish, whose acknowledgement comes back once the broker has read it (and stored
/// it as the subject's last value). A broker that reads slowly — thousands of subscribers on too
/// few cores, say — then holds at most this many of the daemon's messages, not the megabytes a
/// socket's send buffer takes, and the queue keeps only the newest set of each count meanwhile.
/// Measured: with plain publishes, such a broker left seconds of sets queued in the daemon's
/// socket, each delivered late (docs/PERFORMANCE.md, "Fan-out").
pub const ACK_WINDOW: usize = 4;

/// How long an acknowledgement may take before the message counts as lost (`timeout`).
pub const ACK_TIMEOUT: Duration = Duration::from_secs(2);

/// Publishes what the queue holds, at most [`ACK_WINDOW`] messages ahead of the broker, dropping
/// what cannot go out now.
async fn publisher(
    client: async_nats::Client,
    queue: Arc<Queue>,
    link: Arc<Link>,
    stop: CancellationToken,
) {
    use async_nats::connection::State;
    use async_nats::jetstream::context::PublishErrorKind;
    use futures_util::StreamExt;
    use futures_util::stream::FuturesUnordered;
    let mut js = async_nats::jetstream::new(client.clone());
    js.set_timeout(ACK_TIMEOUT);
    let mut in_flight = FuturesUnordered::new();
    loop {
        while in_flight.len() < ACK_WINDOW {
            let Some(m) = queue.pop() else { break };
            if client.connection_state() != State::Connected {
                link.drop_one(Dropped::Disconnected);
                continue;
            }
            match tokio::time::timeout(PUBLISH_TIMEOUT, js.publish(m.subject, m.payload)).await {
                Ok(Ok(ack)) => in_flight.push(std::future::IntoFuture::into_future(ack)),
                _ => link.drop_one(Dropped::Timeout),
            }
        }
        tokio::select! {
            Some(ack) = in_flight.next(), if !in_flight.is_empty() => match ack {
                // No stream takes the subject (a broker without JetStream, or before the stream
                // is made): the broker answered "no responders", so it has read the message and
                // passed it to the subscribers.
                Ok(_) => { link.published.fetch_add(1, Relaxed); }
                Err(e) if e.kind() == PublishErrorKind::StreamNotFound => {
                    link.published.fetch_add(1, Relaxed);
                }
                Err(e) if e.kind() == PublishErrorKind::BrokenPipe => {
                    link.drop_one(Dropped::Disconnected);
                }
                Err(_) => link.drop_one(Dropped::Timeout),
            },
            () = queue.ready.notified(), if in_flight.len() < ACK_WINDOW => {}
            () = stop.cancelled() => break,
        }
    }
    // The last sets out before the process ends.
    let _ = tokio::time::timeout(Duration::from_secs(1), client.flush()).await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls() {
        assert!(check_url("nats://127.0.0.1:4222", false).is_ok());
        assert!(check_url("127.0.0.1:4222", false).is_ok());
        assert!(check_url("tls://broker.example:4222", false).is_ok());
        assert!(check_url("http://broker:4222", false).is_err());
        assert!(check_url("nats://", false).is_err());
        let err = check_url("nats://me:secret@broker:4222", false).unwrap_err();
        assert!(err.contains("VEMLIGHT_NATS"), "{err}");
        assert!(check_url("nats://me:secret@broker:4222", true).is_ok());
        assert_eq!(
            redact_url("nats://me:secret@broker:4222"),
            "nats://***@broker:4222"
        );
        assert_eq!(redact_url("nats://broker:4222"), "nats://broker:4222");
        assert_eq!(redact_url("tok@broker:4222"), "***@broker:4222");
    }

    #[test]
    fn credentials_in_the_url_become_the_login() {
        let (url, auth) = split_credentials("nats://me:pw@broker:4222", &NatsAuth::None).unwrap();
        assert_eq!(url, "nats://broker:4222");
        assert!(matches!(auth, NatsAuth::UserPassword(u, p) if u == "me" && p == "pw"));
        let (url, auth) = split_credentials("nats://tok@broker:4222", &NatsAuth::None).unwrap();
        assert_eq!(url, "nats://broker:4222");
        assert!(matches!(auth, NatsAuth::Token(t) if t == "tok"));
        let (url, auth) =
            split_credentials("nats://broker:4222", &NatsAuth::Token("t".into())).unwrap();
        assert_eq!(url, "nats://broker:4222");
        assert!(matches!(auth, NatsAuth::Token(_)));
        assert!(
            split_credentials("nats://me:pw@broker:4222", &NatsAuth::Token("t".into())).is_err()
        );
    }

    #[test]
    fn the_queue_keeps_the_newest_of_each_subject_and_drops_its_oldest() {
        let link = Link::new(&PublishConfig {
            url: "nats://x:1".into(),
            camera: "c".into(),
            counts: vec![8],
            auth: NatsAuth::None,
            http: None,
            replicas: 1,
        });
        let q = Queue {
            items: Mutex::new(VecDeque::new()),
            ready: Notify::new(),
            capacity: 3,
        };
        let push = |subject: &str, k: u8| {
            q.push(
                &link,
                Outgoing {
                    subject: subject.into(),
                    payload: Bytes::from(vec![k]),
                },
            )
        };
        for k in 0..5u8 {
            push(&format!("s{k}"), k);
        }
        assert_eq!(link.dropped_queue_full.load(Relaxed), 2);
        // A newer set of a waiting subject takes its place.
        push("s3", 30);
        assert_eq!(link.dropped_superseded.load(Relaxed), 1);
        assert_eq!(link.dropped(), 3);
        let left: Vec<(String, u8)> = std::iter::from_fn(|| q.pop())
            .map(|m| (m.subject, m.payload[0]))
            .collect();
        assert_eq!(
            left,
            [("s2".into(), 2), ("s3".into(), 30), ("s4".into(), 4)]
        );
    }
}
