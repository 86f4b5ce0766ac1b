//! The viewer's broker client: `vemlight view nats://HOST:PORT[/CAMERA][?lights=N]` follows one
//! camera's sets on `vemlight.v1.<camera>.lights.<n>` (docs/RENDER.md, "Through a NATS broker").
//!
//! Input: the broker URL and [`NatsOptions`]. Output: [`LightSet`]s through
//! [`NatsFeed::take_latest`], with the semantics of the WebSocket stream client: latest state (the
//! render loop takes the newest set and never waits on the network), the last set kept and marked
//! stale when the link drops, reconnection with backoff (the NATS client's own). async-nats runs
//! on a background thread with a tokio runtime of its own.
//!
//! On every (re)connection the feed asks the camera's JetStream stream for the subject's last
//! value (a direct get), after subscribing, so the current set shows at once rather than a frame
//! period later; without a stream it waits for the next set. A set older than `max_age` (its
//! `t_capture_ns` against this machine's clock), or not newer than the last shown, is dropped and
//! counted. With no camera named, the cameras are listed from their statuses and the only one is
//! taken; with no count named, the camera's first published count.

use crate::lightset::{LightSet, now_ns};
use crate::publish::NatsAuth;
use crate::publish::cameras::{self, BrokerUrl, Camera};
use crate::publish::subjects;
use anyhow::{Context, bail};
use futures_util::StreamExt;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

/// Sets whose capture is older than this are dropped by default (`--max-age-ms`).
pub const DEFAULT_MAX_AGE: Duration = Duration::from_millis(1000);

/// With the link up but no set shown for this long, the lights on screen are called stale: the
/// daemon behind a broker can go away while the broker stays.
pub const SILENT_AFTER: Duration = Duration::from_secs(5);

/// How long the last-value request may take before the feed just waits for the next set.
const LAST_VALUE_TIMEOUT: Duration = Duration::from_secs(2);

/// How long a camera named without a count is waited for to say (in a status) what it publishes.
const STATUS_WAIT: Duration = Duration::from_millis(2500);

/// How often the drop counts are reported at most.
const REPORT_EVERY: Duration = Duration::from_secs(2);

/// What the NATS source needs besides its URL.
#[derive(Clone, Debug)]
pub struct NatsOptions {
    /// The camera, when the URL names none (`--camera`).
    pub camera: Option<String>,
    /// Sets captured longer ago than this are dropped; `None`: no age check.
    pub max_age: Option<Duration>,
    pub auth: NatsAuth,
    /// How long to listen for statuses when the camera must be found.
    pub listen: Duration,
}

impl NatsOptions {
    /// The defaults, logging in as the environment says (`VEMLIGHT_NATS_TOKEN`,
    /// `VEMLIGHT_NATS_USER` and `VEMLIGHT_NATS_PASSWORD`, `VEMLIGHT_NATS_CREDS`, …).
    pub fn from_env() -> anyhow::Result<NatsOptions> {
        Ok(NatsOptions {
            camera: None,
            max_age: Some(DEFAULT_MAX_AGE),
            auth: crate::publish::login::LoginArgs::default().auth()?,
            listen: cameras::LISTEN,
        })
    }
}

/// What the feed has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NatsStats {
    /// LightSets that arrived, either way.
    pub received: u64,
    /// Sets handed to the render loop.
    pub shown: u64,
    /// Of those, the ones read from the stream's last value.
    pub last_values: u64,
    /// Dropped: captured longer ago than `max_age`.
    pub too_old: u64,
    /// Dropped: not newer than the last shown (a repeat, or out of order).
    pub not_newer: u64,
    /// Messages that were not LightSets.
    pub invalid: u64,
    /// Connections made, the first included.
    pub connections: u64,
}

/// Which sets are shown: none older than `max_age`, and none that is not newer than the last
/// shown. "Newer" is a higher `seq`, or a later capture (a restarted daemon counts `seq` anew).
#[derive(Clone, Debug, Default)]
pub struct Gate {
    max_age: Option<Duration>,
    /// `seq` and `t_capture_ns` of the last set shown.
    last: Option<(u64, u64)>,
}

/// What the [`Gate`] makes of a set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Show,
    /// Captured this long ago, beyond the bound.
    TooOld(Duration),
    NotNewer,
}

impl Gate {
    pub fn new(max_age: Option<Duration>) -> Gate {
        Gate {
            max_age,
            last: None,
        }
    }

    /// Judges a set by its `seq` and `t_capture_ns` at wall-clock time `now_ns`; a set shown
    /// becomes the last.
    pub fn judge(&mut self, seq: u64, t_capture_ns: u64, now_ns: u64) -> Verdict {
        let age = Duration::from_nanos(now_ns.saturating_sub(t_capture_ns));
        if self.max_age.is_some_and(|max| age > max) {
            return Verdict::TooOld(age);
        }
        if let Some((s, t)) = self.last
            && seq <= s
            && t_capture_ns <= t
        {
            return Verdict::NotNewer;
        }
        self.last = Some((seq, t_capture_ns));
        Verdict::Show
    }
}

/// What the client thread shares with the render loop.
#[derive(Default)]
struct Shared {
    latest: Option<LightSet>,
    connected: bool,
    /// Subscribed on the current connection, and its last value asked for.
    following: bool,
    last_error: String,
    stats: NatsStats,
    last_shown: Option<Instant>,
    /// How old the last set dropped for its age was.
    last_too_old: Option<Duration>,
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(|e| e.into_inner())
}

/// The background NATS client of one camera and count.
pub struct NatsFeed {
    shared: Arc<Mutex<Shared>>,
    stop: CancellationToken,
    thread: Option<JoinHandle<()>>,
    server: String,
    camera: String,
    lights: usize,
    max_age: Option<Duration>,
    /// The drop counts last reported, and when.
    reported: Mutex<(u64, u64, Option<Instant>)>,
}

impl NatsFeed {
    /// Starts the client thread. It returns once the camera and count are known: at once when
    /// the URL names both (the broker may even be down: it is retried like a lost one), else after
    /// asking the broker (a listing takes `opts.listen`). Fails on a bad URL, no camera or more
    /// than one to choose from, a count the camera does not publish, or an unreachable broker
    /// when it had to be asked.
    pub fn start(url: &str, opts: NatsOptions) -> anyhow::Result<NatsFeed> {
        let parsed = BrokerUrl::parse(url).map_err(anyhow::Error::msg)?;
        if let Some(c) = &opts.camera {
            subjects::check_camera(c).map_err(|e| anyhow::anyhow!("--camera: {e}"))?;
        }
        let shared = Arc::new(Mutex::new(Shared::default()));
        let stop = CancellationToken::new();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let max_age = opts.max_age;
        let thread = {
            let (shared, stop, parsed) = (shared.clone(), stop.clone(), parsed.clone());
            std::thread::Builder::new()
                .name("vemlight-nats".into())
                .spawn(move || {
                    match tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build()
                    {
                        Ok(rt) => rt.block_on(run(parsed, opts, shared, stop, ready_tx)),
                        Err(e) => {
                            let _ = ready_tx.send(Err(anyhow::Error::new(e)
                                .context("cannot start the NATS client's runtime")));
                        }
                    }
                })?
        };
        let resolved = ready_rx
            .recv()
            .map_err(|_| anyhow::anyhow!("the NATS client thread ended"))
            .and_then(|r| r);
        match resolved {
            Ok((camera, lights)) => Ok(NatsFeed {
                shared,
                stop,
                thread: Some(thread),
                server: parsed.server,
                camera,
                lights,
                max_age,
                reported: Mutex::new((0, 0, None)),
            }),
            Err(e) => {
                stop.cancel();
                let _ = thread.join();
                Err(e)
            }
        }
    }

    /// The camera followed.
    pub fn camera(&self) -> &str {
        &self.camera
    }

    /// The light count followed.
    pub fn lights(&self) -> usize {
        self.lights
    }

    /// The subject followed.
    pub fn subject(&self) -> String {
        subjects::lights(&self.camera, self.lights)
    }

    /// The broker, `scheme://host:port`.
    pub fn server(&self) -> &str {
        &self.server
    }

    /// The newest set shown since the last call.
    pub fn take_latest(&self) -> Option<LightSet> {
        lock(&self.shared).latest.take()
    }

    pub fn is_connected(&self) -> bool {
        lock(&self.shared).connected
    }

    /// Subscribed on the current connection, its last value asked for: a set published from now
    /// on reaches the feed.
    pub fn is_following(&self) -> bool {
        let s = lock(&self.shared);
        s.connected && s.following
    }

    /// The lights on screen may be out of date: the link is down, or nothing came for
    /// [`SILENT_AFTER`].
    pub fn is_stale(&self) -> bool {
        let s = lock(&self.shared);
        !s.connected || s.last_shown.is_some_and(|t| t.elapsed() > SILENT_AFTER)
    }

    pub fn stats(&self) -> NatsStats {
        lock(&self.shared).stats
    }

    pub fn last_error(&self) -> String {
        lock(&self.shared).last_error.clone()
    }

    /// A line for the log when sets were dropped since the last report (at most every
    /// `REPORT_EVERY`).
    pub fn drop_report(&self) -> Option<String> {
        let (stats, last_too_old) = {
            let s = lock(&self.shared);
            (s.stats, s.last_too_old)
        };
        let mut r = self.reported.lock().unwrap_or_else(|e| e.into_inner());
        if (stats.too_old, stats.not_newer) == (r.0, r.1)
            || r.2.is_some_and(|t| t.elapsed() < REPORT_EVERY)
        {
            return None;
        }
        *r = (stats.too_old, stats.not_newer, Some(Instant::now()));
        Some(format!(
            "camera {}: sets dropped so far: {}",
            self.camera,
            self.drops(&stats, last_too_old)
        ))
    }

    /// Why no set has come, for an error: the link's last error and what was dropped.
    pub fn why_nothing(&self) -> String {
        let (stats, last_too_old, error) = {
            let s = lock(&self.shared);
            (s.stats, s.last_too_old, s.last_error.clone())
        };
        let mut why = format!("on {} from {}", self.subject(), self.server);
        if !self.is_connected() {
            why.push_str(" (not connected)");
        }
        if !error.is_empty() {
            why.push(' ');
            why.push_str(&error);
        }
        if stats.too_old + stats.not_newer > 0 {
            why.push_str(&format!("; dropped {}", self.drops(&stats, last_too_old)));
        }
        why
    }

    fn drops(&self, stats: &NatsStats, last_too_old: Option<Duration>) -> String {
        let mut line = format!("{} too old", stats.too_old);
        if let (Some(max), Some(age)) = (self.max_age, last_too_old) {
            line.push_str(&format!(
                " (the last {:.0} ms old, over --max-age-ms {}: clocks apart? 0 turns the check off)",
                age.as_secs_f64() * 1e3,
                max.as_millis()
            ));
        }
        line.push_str(&format!(
            ", {} not newer than the one shown",
            stats.not_newer
        ));
        line
    }
}

impl Drop for NatsFeed {
    fn drop(&mut self) {
        self.stop.cancel();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The client thread: connect, settle the camera and count (answered on `ready`), then follow.
async fn run(
    url: BrokerUrl,
    opts: NatsOptions,
    shared: Arc<Mutex<Shared>>,
    stop: CancellationToken,
    ready: std::sync::mpsc::Sender<anyhow::Result<(String, usize)>>,
) {
    let connected = Arc::new(Notify::new());
    let client = match connect(&url.server, &opts.auth, &shared, &connected).await {
        Ok(c) => c,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    let resolved = tokio::select! {
        r = resolve(&client, &url, &opts, &shared) => r,
        () = stop.cancelled() => return,
    };
    let (camera, lights) = match resolved {
        Ok(r) => r,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    let _ = ready.send(Ok((camera.clone(), lights)));
    follow(
        &client,
        &camera,
        lights,
        opts.max_age,
        &shared,
        &connected,
        &stop,
    )
    .await;
}

/// The client, connecting in the background and reconnecting for ever with the client's backoff;
/// its events keep `shared`'s link state, and each connection is told on `connected`.
async fn connect(
    server: &str,
    auth: &NatsAuth,
    shared: &Arc<Mutex<Shared>>,
    connected: &Arc<Notify>,
) -> anyhow::Result<async_nats::Client> {
    let (shared, connected) = (shared.clone(), connected.clone());
    let opts = crate::publish::login::connect_options(auth)
        .await?
        .name("vemlight view")
        .retry_on_initial_connect()
        .max_reconnects(None)
        .event_callback(move |event| {
            let (shared, connected) = (shared.clone(), connected.clone());
            async move {
                let mut s = lock(&shared);
                match event {
                    async_nats::Event::Connected => {
                        s.connected = true;
                        s.stats.connections += 1;
                        connected.notify_one();
                    }
                    async_nats::Event::Disconnected => {
                        s.connected = false;
                        s.following = false;
                    }
                    async_nats::Event::ServerError(e) => s.last_error = format!("({e})"),
                    async_nats::Event::ClientError(e) => s.last_error = format!("({e})"),
                    _ => {}
                }
            }
        });
    opts.connect(server)
        .await
        .with_context(|| format!("broker {server}"))
}

/// The camera and count: from the URL and `--camera`, else asked of the broker.
async fn resolve(
    client: &async_nats::Client,
    url: &BrokerUrl,
    opts: &NatsOptions,
    shared: &Mutex<Shared>,
) -> anyhow::Result<(String, usize)> {
    let named = match (&url.camera, &opts.camera) {
        (Some(a), Some(b)) if a != b => {
            bail!("the URL names camera '{a}' and --camera '{b}': name one")
        }
        (a, b) => a.clone().or_else(|| b.clone()),
    };
    if let (Some(camera), Some(n)) = (&named, url.lights) {
        return Ok((camera.clone(), n)); // nothing to ask: the broker may come later
    }
    wait_connected(client, &url.server, shared).await?;
    let status: Camera = match &named {
        None => {
            let mut found = cameras::list(client, opts.listen).await?;
            match found.len() {
                0 => bail!(
                    "no camera publishes on {}: no status on {} within {:.1} s",
                    url.server,
                    subjects::ALL_STATUS,
                    opts.listen.as_secs_f64()
                ),
                1 => found.remove(0),
                n => bail!(
                    "{n} cameras publish on {}; name one, as {}/CAMERA or with --camera CAMERA:\n{}",
                    url.server,
                    url.server,
                    cameras::table(&found).trim_end()
                ),
            }
        }
        Some(camera) => cameras::last_status(client, camera, STATUS_WAIT)
            .await?
            .with_context(|| {
                format!(
                    "camera '{camera}' sent no status on {} within {:.1} s: is it publishing? \
                     (give ?lights=N to wait for its sets all the same)",
                    url.server,
                    STATUS_WAIT.as_secs_f64()
                )
            })?,
    };
    let list = |l: &[usize]| {
        l.iter()
            .map(usize::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    };
    let lights = match url.lights {
        Some(n) if !status.lights.contains(&n) => bail!(
            "camera '{}' publishes {} lights, not {n}",
            status.camera,
            list(&status.lights)
        ),
        Some(n) => n,
        None => *status
            .lights
            .first()
            .with_context(|| format!("camera '{}' publishes no light count", status.camera))?,
    };
    Ok((status.camera, lights))
}

/// Waits up to [`cameras::CONNECT_WAIT`] for the first connection.
async fn wait_connected(
    client: &async_nats::Client,
    server: &str,
    shared: &Mutex<Shared>,
) -> anyhow::Result<()> {
    let deadline = Instant::now() + cameras::CONNECT_WAIT;
    while client.connection_state() != async_nats::connection::State::Connected {
        if Instant::now() > deadline {
            bail!(
                "cannot reach the broker at {server} within {:?} {}",
                cameras::CONNECT_WAIT,
                lock(shared).last_error
            );
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Ok(())
}

/// Subscribes, and on every connection asks for the last value; takes sets until `stop`.
async fn follow(
    client: &async_nats::Client,
    camera: &str,
    lights: usize,
    max_age: Option<Duration>,
    shared: &Mutex<Shared>,
    connected: &Notify,
    stop: &CancellationToken,
) {
    let subject = subjects::lights(camera, lights);
    let mut sub = match client.subscribe(subject.clone()).await {
        Ok(s) => s,
        Err(e) => {
            lock(shared).last_error = format!("(cannot subscribe to {subject}: {e})");
            return;
        }
    };
    let js = async_nats::jetstream::new(client.clone());
    let stream = subjects::stream_name(camera);
    let mut gate = Gate::new(max_age);
    let mut count_checked = false;
    loop {
        tokio::select! {
            () = stop.cancelled() => break,
            () = connected.notified() => {
                // The subscription is on the server once a flush returns (the client sends it
                // again on each connection before anything else); then the last value, which the
                // gate drops if a newer set came meanwhile.
                if tokio::time::timeout(LAST_VALUE_TIMEOUT, client.flush()).await.is_err() {
                    continue;
                }
                let last = tokio::time::timeout(LAST_VALUE_TIMEOUT, async {
                    js.get_stream_no_info(&stream)
                        .await
                        .ok()?
                        .direct_get_last_for_subject(subject.clone())
                        .await
                        .ok()
                })
                .await;
                if let Ok(Some(m)) = last {
                    take(&m.payload, true, &mut gate, shared);
                }
                lock(shared).following = true;
                // A count named in the URL was not checked at start (the broker may have been
                // down): a camera that does not publish it is told in the error when nothing comes.
                if !count_checked
                    && let Ok(Some(st)) =
                        cameras::last_status(client, camera, Duration::from_millis(100)).await
                {
                    count_checked = true;
                    if !st.lights.contains(&lights) {
                        lock(shared).last_error = format!(
                            "(camera '{camera}' publishes {:?} lights, not {lights})",
                            st.lights
                        );
                    }
                }
            }
            m = sub.next() => match m {
                Some(m) => take(&m.payload, false, &mut gate, shared),
                None => break,
            },
        }
    }
}

/// One message: a LightSet shown, or dropped and counted.
fn take(payload: &[u8], last_value: bool, gate: &mut Gate, shared: &Mutex<Shared>) {
    let parsed = serde_json::from_slice::<LightSet>(payload);
    let mut s = lock(shared);
    let set = match parsed {
        Ok(set) => set,
        Err(e) => {
            s.stats.invalid += 1;
            s.last_error = format!("(a message was not a LightSet: {e})");
            return;
        }
    };
    s.stats.received += 1;
    match gate.judge(set.seq, set.t_capture_ns, now_ns()) {
        Verdict::Show => {
            s.stats.shown += 1;
            if last_value {
                s.stats.last_values += 1;
            }
            s.latest = Some(set); // latest state: an unread older set is replaced
            s.last_shown = Some(Instant::now());
        }
        Verdict::TooOld(age) => {
            s.stats.too_old += 1;
            s.last_too_old = Some(age);
        }
        Verdict::NotNewer => s.stats.not_newer += 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gate_drops_old_and_not_newer_sets_and_follows_a_restart() {
        const S: u64 = 1_000_000_000;
        let now = 1_000 * S;
        let mut g = Gate::new(Some(Duration::from_secs(1)));
        assert_eq!(
            g.judge(5, now - 3 * S, now),
            Verdict::TooOld(Duration::from_secs(3))
        );
        assert_eq!(g.judge(6, now - S / 10, now), Verdict::Show);
        assert_eq!(g.judge(6, now - S / 10, now), Verdict::NotNewer, "a repeat");
        assert_eq!(
            g.judge(4, now - S / 5, now),
            Verdict::NotNewer,
            "out of order"
        );
        assert_eq!(g.judge(7, now, now), Verdict::Show);
        // A restarted daemon counts from 1 again, with later captures.
        assert_eq!(g.judge(1, now + S / 100, now + S / 50), Verdict::Show);
        // A clock ahead of ours is not "old".
        assert_eq!(g.judge(2, now + 5 * S, now), Verdict::Show);
        // No bound: any age.
        let mut g = Gate::new(None);
        assert_eq!(g.judge(1, 0, now), Verdict::Show);
    }
}
