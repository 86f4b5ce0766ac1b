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
            Some(e) if e.is_finite() && e > 0.0 && e <= 1.0 => {
                Some(((e * 1e6).round() as u32).max(1))
            }
            Some(e) => {
                return Err(format!(
                    "max_error must be a relative error in (0, 1] (0.02 for 2 %), got {e}"
                ));
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

/// One stream key's channel and how many subscribers want it.
struct Channel {
    subscribers: usize,
    tx: watch::Sender<Option<Arc<Published>>>,
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
    pub key: StreamKey,
    pub rx: watch::Receiver<Option<Arc<Published>>>,
}

impl Drop for Subscription {
    fn drop(&mut self) {
        let mut ch = self.hub.channels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = ch.get_mut(&self.key) {
            c.subscribers = c.subscribers.saturating_sub(1);
            if c.subscribers == 0 && self.key != StreamKey::from(self.hub.default_lights) {
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
        channels.insert(
            StreamKey::from(default_lights),
            Channel {
                subscribers: 0,
                tx: watch::channel(None).0,
            },
        );
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

    /// Subscribes to the sets of `key` (a light count, or a [`StreamKey`] with an error target
    /// and a shadow budget); refused when the key is out of range or would exceed the number of
    /// distinct keys served at once.
    pub fn subscribe(self: &Arc<Self>, key: impl Into<StreamKey>) -> Result<Subscription, String> {
        let key = key.into();
        let key = StreamKey::new(key.lights, key.max_error(), key.shadowed)?;
        let mut ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        if !ch.contains_key(&key) && ch.len() >= self.max_light_counts {
            return Err(format!(
                "the daemon already serves {} distinct streams (light counts {}); ask for one of them",
                ch.len(),
                ch.keys()
                    .map(|k| k.lights.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        let c = ch.entry(key).or_insert_with(|| Channel {
            subscribers: 0,
            tx: watch::channel(None).0,
        });
        c.subscribers += 1;
        Ok(Subscription {
            hub: self.clone(),
            key,
            rx: c.tx.subscribe(),
        })
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
