//! The hub between the pipeline and the server: the latest serialised LightSet per light count,
//! who asks for which count, the source's health, the metrics, and the daemon's one shutdown token.
//!
//! Latest-state semantics (DESIGN.md, "Processes and endpoints"): each light count has a `watch`
//! channel holding the newest set, so a slow reader skips sets and never holds up the pipeline.
//! The hub holds plain bytes; the server turns them into WebSocket text frames.

use crate::metrics::Metrics;
use crate::sampling::N_MAX;
use bytes::Bytes;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

/// One published LightSet, serialised once for every reader.
#[derive(Debug)]
pub struct Published {
    pub seq: u64,
    pub frame: u64,
    pub t_capture_ns: u64,
    /// When the frame entered the pipeline (for latency measurements in this process).
    pub captured_at: Instant,
    /// The LightSet document as UTF-8 JSON, shared by every reader without copying.
    pub json: Bytes,
}

/// Where the frame source is in its life, as `/healthz` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceState {
    /// No good frame yet.
    Starting,
    /// Frames are coming (or were, see [`SourceHealth::stalled`]).
    Running,
    /// The source ended normally (a sequence that does not loop, stdin closed): the last good set
    /// is still served.
    Ended,
    /// The source cannot go on: the last good set, if any, is still served.
    Failed,
}

/// The source's state as `/healthz` reports it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SourceHealth {
    pub source: String,
    pub state: SourceState,
    pub last_error: Option<String>,
    pub frames_captured: u64,
    /// Seconds since the last good frame; `None` before the first.
    pub last_frame_age_s: Option<f64>,
    /// Running, but no good frame for `stall_after_s`: a camera pipe that froze without closing,
    /// say. The last good set is still served, as when the source fails.
    pub stalled: bool,
    /// See [`stall_after`].
    pub stall_after_s: f64,
}

impl SourceHealth {
    /// Running and not stalled: frames are coming.
    pub fn delivering(&self) -> bool {
        self.state == SourceState::Running && !self.stalled
    }
}

/// How long a running source may go without a good frame before `/healthz` calls it stalled: ten
/// frame periods, at least 2 s; 5 s for a source with no nominal rate (stdin).
pub fn stall_after(nominal_fps: f64) -> Duration {
    if nominal_fps > 0.0 && nominal_fps.is_finite() {
        Duration::from_secs_f64((10.0 / nominal_fps).max(2.0))
    } else {
        Duration::from_secs(5)
    }
}

pub(super) struct HealthState {
    source: String,
    pub(super) state: SourceState,
    pub(super) last_error: Option<String>,
    pub(super) frames: u64,
    pub(super) last_frame: Option<Instant>,
    pub(super) stall_after: Duration,
}

/// What a client subscribes to (docs/API.md, "The stream"): at most `lights` lights — the fewest
/// whose estimated diffuse error meets `max_error` when one is given — with `shadowed` of them
/// marked as worth a shadow map and the rest also given as L2 SH.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StreamKey {
    /// The most lights; exactly this many without `max_error`.
    pub lights: usize,
    /// The error target in parts per million (a key must be `Eq` and `Ord`).
    max_error_ppm: Option<u32>,
    /// How many lights to mark for shadow maps; no marking and no remainder SH when `None`.
    pub shadowed: Option<usize>,
}

impl StreamKey {
    /// A checked key: 1 ≤ `lights` ≤ 1024, 0 < `max_error` ≤ 1, `shadowed` ≤ `lights`.
    pub fn new(
        lights: usize,
        max_error: Option<f64>,
        shadowed: Option<usize>,
    ) -> Result<Self, String> {
        if !(1..=N_MAX).contains(&lights) {
            return Err(format!(
                "lights must be between 1 and {N_MAX}, got {lights}"
            ));
        }
        let max_error_ppm = match max_error {
            None => None,
            Some(e) => {
                crate::lightset::check_max_error(e)?;
                Some(((e * 1e6).round() as u32).max(1))
            }
        };
        if let Some(k) = shadowed
            && k > lights
        {
            return Err(format!(
                "shadowed must be at most lights ({lights}), got {k}"
            ));
        }
        Ok(StreamKey {
            lights,
            max_error_ppm,
            shadowed,
        })
    }

    /// The relative diffuse error target, if any.
    pub fn max_error(&self) -> Option<f64> {
        self.max_error_ppm.map(|p| p as f64 * 1e-6)
    }

    /// Whether the light count adapts to an error target.
    pub fn is_adaptive(&self) -> bool {
        self.max_error_ppm.is_some()
    }
}

impl From<usize> for StreamKey {
    /// Exactly `lights` lights, none marked (checked when subscribed).
    fn from(lights: usize) -> Self {
        StreamKey {
            lights,
            max_error_ppm: None,
            shadowed: None,
        }
    }
}

/// One stream key's channel and who wants it.
struct Channel {
    /// Streams (WebSocket clients), each holding the key for as long as it lives.
    streams: usize,
    /// One-off requests (`/v1/lights/latest`) waiting for the key's next set.
    once: usize,
    tx: watch::Sender<Option<Arc<Published>>>,
}

impl Channel {
    fn new() -> Self {
        Channel {
            streams: 0,
            once: 0,
            tx: watch::channel(None).0,
        }
    }

    fn count(&mut self, interest: Interest) -> &mut usize {
        match interest {
            Interest::Stream => &mut self.streams,
            Interest::Once => &mut self.once,
        }
    }
}

/// Who subscribes: a stream, or a one-off request for a key's set.
///
/// Each distinct key costs the pipeline assignment passes every frame, so the hub serves at most
/// `max_light_counts` of them. One-off requests (`/v1/lights/latest?lights=N`) are cheap to send
/// in bursts of distinct counts, and each would hold a key for up to the request's wait: unchecked,
/// a burst takes every key and a stream asking for a new count is refused. So keys asked for by
/// nothing but one-off requests may hold at most a quarter of the key slots
/// ([`Hub::once_only_budget`]); the rest are left to streams, and a one-off request beyond its
/// share is refused at once ([`SubscribeError::Full`], which the server answers 503). A one-off
/// request for a key a stream already has costs nothing and is always taken. (The alternative,
/// a one-off extraction from the last frame on the server's side, would need the frame and an
/// extractor outside the pipeline and would cost a whole extraction a request.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interest {
    Stream,
    Once,
}

/// Why a subscription was refused.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum SubscribeError {
    /// The key is out of range.
    #[error("{0}")]
    Invalid(String),
    /// Taking the key would exceed the distinct keys served at once (or, for a one-off request,
    /// the share of them one-off requests may hold): a retry may succeed once others have gone.
    #[error("{0}")]
    Full(String),
}

/// Shared between the pipeline threads and the server: the latest LightSet per light count,
/// metrics, health and shutdown.
pub struct Hub {
    channels: Mutex<BTreeMap<StreamKey, Channel>>,
    default_lights: usize,
    max_light_counts: usize,
    pub metrics: Arc<Metrics>,
    health: Mutex<HealthState>,
    /// Cancelled once, when the daemon shuts down: the pipeline threads stop and every client
    /// loop closes.
    shutdown: CancellationToken,
}

/// A client's interest in one light count; dropping it tells the pipeline.
pub struct Subscription {
    hub: Arc<Hub>,
    interest: Interest,
    pub key: StreamKey,
    pub rx: watch::Receiver<Option<Arc<Published>>>,
}

impl Drop for Subscription {
    fn drop(&mut self) {
        let mut ch = self.hub.channels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = ch.get_mut(&self.key) {
            let n = c.count(self.interest);
            *n = n.saturating_sub(1);
            if c.streams + c.once == 0 && self.key != StreamKey::from(self.hub.default_lights) {
                ch.remove(&self.key);
            }
        }
    }
}

impl Hub {
    /// A hub that always publishes `default_lights` (served by `/v1/lights/latest` even with no
    /// client) and serves at most `max_light_counts` distinct streams at once (each costs up to
    /// two assignment passes per frame).
    pub fn new(default_lights: usize, max_light_counts: usize, source: &str) -> Arc<Self> {
        let mut channels = BTreeMap::new();
        channels.insert(StreamKey::from(default_lights), Channel::new());
        Arc::new(Hub {
            channels: Mutex::new(channels),
            default_lights,
            max_light_counts: max_light_counts.max(1),
            metrics: Arc::new(Metrics::default()),
            health: Mutex::new(HealthState {
                source: source.into(),
                state: SourceState::Starting,
                last_error: None,
                frames: 0,
                last_frame: None,
                stall_after: stall_after(0.0),
            }),
            shutdown: CancellationToken::new(),
        })
    }

    pub fn default_lights(&self) -> usize {
        self.default_lights
    }

    /// Subscribes a stream to the sets of `key` (a light count, or a [`StreamKey`] with an error
    /// target and a shadow budget); refused when the key is out of range or would exceed the
    /// number of distinct keys served at once.
    pub fn subscribe(self: &Arc<Self>, key: impl Into<StreamKey>) -> Result<Subscription, String> {
        self.subscribe_as(key, Interest::Stream)
            .map_err(|e| e.to_string())
    }

    /// Subscribes `interest` to the sets of `key`: as [`Hub::subscribe`], and a one-off request
    /// for a key no stream has is refused beyond [`Hub::once_only_budget`] (see [`Interest`]).
    pub fn subscribe_as(
        self: &Arc<Self>,
        key: impl Into<StreamKey>,
        interest: Interest,
    ) -> Result<Subscription, SubscribeError> {
        let key = key.into();
        let key = StreamKey::new(key.lights, key.max_error(), key.shadowed)
            .map_err(SubscribeError::Invalid)?;
        let mut ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        if !ch.contains_key(&key) {
            let counts = || {
                ch.keys()
                    .map(|k| k.lights.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            if ch.len() >= self.max_light_counts {
                return Err(SubscribeError::Full(format!(
                    "the daemon already serves {} distinct streams (light counts {}); ask for one of them",
                    ch.len(),
                    counts()
                )));
            }
            let default = StreamKey::from(self.default_lights);
            let once_only = ch
                .iter()
                .filter(|&(k, c)| *k != default && c.streams == 0)
                .count();
            if interest == Interest::Once && once_only >= self.once_only_budget() {
                return Err(SubscribeError::Full(format!(
                    "{once_only} light counts no stream asks for are being computed for other \
                     requests, the most at once; ask for one a stream has (light counts {}) or \
                     retry shortly",
                    counts()
                )));
            }
        }
        let c = ch.entry(key).or_insert_with(Channel::new);
        *c.count(interest) += 1;
        Ok(Subscription {
            hub: self.clone(),
            interest,
            key,
            rx: c.tx.subscribe(),
        })
    }

    /// How many keys that no stream has one-off requests may hold at once: a quarter of the
    /// distinct keys served, at least 1 (4 of [`MAX_LIGHT_COUNTS`](super::MAX_LIGHT_COUNTS)).
    pub fn once_only_budget(&self) -> usize {
        (self.max_light_counts / 4).max(1)
    }

    /// The latest set for the default light count.
    pub fn latest(&self) -> Option<Arc<Published>> {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        ch.get(&StreamKey::from(self.default_lights))
            .and_then(|c| c.tx.borrow().clone())
    }

    /// Every stream asked for (the default count included).
    pub(super) fn keys(&self) -> Vec<StreamKey> {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        ch.keys().copied().collect()
    }

    /// The streams asked for that have no set yet.
    pub(super) fn unserved_keys(&self) -> Vec<StreamKey> {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        ch.iter()
            .filter(|(_, c)| c.tx.borrow().is_none())
            .map(|(&k, _)| k)
            .collect()
    }

    pub(super) fn publish(&self, key: StreamKey, p: Arc<Published>) {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = ch.get(&key) {
            c.tx.send_replace(Some(p));
        }
    }

    pub fn health(&self) -> SourceHealth {
        let h = self.health.lock().unwrap_or_else(|e| e.into_inner());
        SourceHealth {
            source: h.source.clone(),
            state: h.state,
            last_error: h.last_error.clone(),
            frames_captured: h.frames,
            last_frame_age_s: h.last_frame.map(|t| t.elapsed().as_secs_f64()),
            stalled: h.state == SourceState::Running
                && h.last_frame.is_some_and(|t| t.elapsed() > h.stall_after),
            stall_after_s: h.stall_after.as_secs_f64(),
        }
    }

    pub(super) fn set_health(&self, f: impl FnOnce(&mut HealthState)) {
        f(&mut self.health.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// Stops the pipeline threads and tells every client loop to close.
    pub fn shutdown(&self) {
        self.shutdown.cancel();
    }

    pub fn is_shut_down(&self) -> bool {
        self.shutdown.is_cancelled()
    }

    /// The daemon's shutdown token: `cancelled().await` on it to end with the daemon.
    pub fn shutdown_token(&self) -> CancellationToken {
        self.shutdown.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_off_requests_hold_at_most_their_share_of_keys() {
        let hub = Hub::new(64, 16, "test");
        assert_eq!(hub.once_only_budget(), 4);
        let once: Vec<_> = (1..=4)
            .map(|n| hub.subscribe_as(n, Interest::Once).unwrap())
            .collect();
        assert!(matches!(
            hub.subscribe_as(5, Interest::Once),
            Err(SubscribeError::Full(_))
        ));
        // A count a stream has, or the default, is free for one-off requests.
        let stream = hub.subscribe(8).unwrap();
        let _a = hub.subscribe_as(8, Interest::Once).unwrap();
        let _b = hub.subscribe_as(64, Interest::Once).unwrap();
        // Streams get every remaining key: 16 less the default and the four one-off keys.
        let streams: Vec<_> = (100..110).map(|n| hub.subscribe(n).unwrap()).collect();
        assert_eq!(hub.keys().len(), 16);
        let Err(full) = hub.subscribe(200) else {
            panic!("a 17th key was taken");
        };
        assert!(full.contains("16 distinct streams"), "{full}");
        // A stream joining a one-off key makes it a stream key: a one-off slot is free again.
        drop(streams);
        let _s1 = hub.subscribe(1).unwrap();
        let extra = hub.subscribe_as(5, Interest::Once).unwrap();
        // Keys go when their last subscriber does, whichever kind.
        drop((once, extra, stream));
        assert_eq!(
            hub.keys(),
            vec![StreamKey::from(1), StreamKey::from(8), StreamKey::from(64)]
        );
        assert!(matches!(
            hub.subscribe_as(0, Interest::Once),
            Err(SubscribeError::Invalid(_))
        ));
    }
}
