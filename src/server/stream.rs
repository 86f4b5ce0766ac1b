//! `GET /v1/stream`: the WebSocket feed of LightSets, latest-state semantics.
//!
//! Each client reads its own `watch` channel: a client that reads slowly simply sees fewer
//! frames, never a queue, and never holds up the capture loop or another client. A client that
//! stops reading for longer than the send timeout is disconnected.
//!
//! At most `--max-clients` clients at once ([`Limits`](super::Limits)): the handler takes a slot
//! before it answers the handshake and the client's loop holds it until it ends, so no burst of
//! handshakes gets more in; one more is answered 503 before the upgrade.

use super::error::ApiError;
use super::query::{Params, StreamQuery};
use super::state::AppState;
use crate::daemon::{StreamKey, Subscription};
use crate::lightset::SUBPROTOCOL;
use crate::metrics::Metrics;
use axum::extract::State;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, WebSocketUpgrade, close_code};
use axum::response::Response;
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;
use std::time::Duration;
use tokio::sync::OwnedSemaphorePermit;
use tokio::time::{Instant, MissedTickBehavior};

/// Largest message a client may send (bytes).
const CLIENT_MESSAGE_LIMIT: usize = 64 * 1024;

/// The slowest rate a client may ask for: one set every 1000 s. (A rate much closer to zero
/// would make an interval no clock can add.)
const MIN_MAX_HZ: f64 = 0.001;

/// Bytes tungstenite reads from a client socket at a time. Its default, 128 KiB, is zeroed on
/// every poll of the read half, which this loop does each time a LightSet goes out: with 100
/// clients that memset was 0.9 ms of every frame's fan-out (perf, `cargo bench --bench serve`).
/// Clients send only pongs and close frames.
const CLIENT_READ_BUFFER: usize = 4 * 1024;

/// How long a client refused at `--max-clients` is told to wait (`Retry-After`).
const FULL_RETRY_AFTER_S: u32 = 5;

/// Upgrade handler: checks the query, takes a client slot, subscribes, hands off. Both
/// extractors are taken as `Result`s so that a request without a handshake is told so first,
/// whatever its query.
pub async fn stream(
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
    query: Result<Params<StreamQuery>, ApiError>,
    State(state): State<AppState>,
) -> Result<Response, ApiError> {
    // A plain GET gets a problem document like every other error, not axum's text.
    let ws = ws.map_err(|e| {
        ApiError::NotWebSocket(
            e.status(),
            format!(
                "{}: /v1/stream is a WebSocket endpoint (subprotocol {SUBPROTOCOL})",
                e.body_text()
            ),
        )
    })?;
    let Params(q) = query?;
    let lights = q.lights.unwrap_or(state.hub.default_lights());
    let max_hz = q.max_hz;
    if let Some(hz) = max_hz
        && !(hz.is_finite() && hz >= MIN_MAX_HZ)
    {
        return Err(ApiError::BadRequest(format!(
            "max_hz must be a number of at least {MIN_MAX_HZ} (one set in {} s), got {hz}",
            1.0 / MIN_MAX_HZ
        )));
    }
    let key = StreamKey::new(lights, q.max_error, q.shadowed).map_err(ApiError::BadRequest)?;
    let Some(slot) = state.limits.try_ws_slot() else {
        Metrics::inc(&state.hub.metrics.ws_clients_refused);
        return Err(ApiError::AtCapacity {
            detail: format!(
                "the daemon serves at most {} WebSocket clients at once (--max-clients) and all \
                 are connected; retry later",
                state.limits.max_ws_clients()
            ),
            retry_after_s: FULL_RETRY_AFTER_S,
        });
    };
    let sub = state.hub.subscribe(key).map_err(ApiError::BadRequest)?;
    let min_interval = max_hz.map(|hz| Duration::from_secs_f64(1.0 / hz));
    Ok(ws
        .protocols([SUBPROTOCOL])
        // Clients have nothing to send but pongs and close frames: refuse anything big.
        .max_message_size(CLIENT_MESSAGE_LIMIT)
        .max_frame_size(CLIENT_MESSAGE_LIMIT)
        .read_buffer_size(CLIENT_READ_BUFFER)
        .on_upgrade(move |socket| {
            let clients = state.ws_clients.clone();
            clients.track_future(client_loop(socket, sub, min_interval, state, slot))
        }))
}

/// One client's loop: send each new set (at most every `min_interval`), ping, answer close,
/// close cleanly on shutdown. It holds the client's `slot` until it ends, however it ends.
async fn client_loop(
    socket: WebSocket,
    mut sub: Subscription,
    min_interval: Option<Duration>,
    state: AppState,
    slot: OwnedSemaphorePermit,
) {
    let _slot = slot;
    let metrics = state.hub.metrics.clone();
    let _connected = ConnectedClient::count(&metrics);
    let (tx, mut rx) = socket.split();
    let mut out = Sender {
        tx,
        metrics: &metrics,
        send_timeout: state.ws.send_timeout,
        timed: false,
    };
    let shutdown = state.hub.shutdown_token();
    let mut ping = tokio::time::interval_at(
        Instant::now() + state.ws.ping_interval,
        state.ws.ping_interval,
    );
    ping.set_missed_tick_behavior(MissedTickBehavior::Delay);
    // A client that asked for `max_hz`: the earliest its next set may go, and whether a newer
    // set is held until then. The loop keeps answering pings, close and shutdown meanwhile.
    let mut next_allowed = Instant::now();
    let mut held = false;
    let release = tokio::time::sleep_until(next_allowed);
    tokio::pin!(release);
    // The current set, if any, goes out at once. It may be a frame old, so it is not a delivery
    // latency sample; nor are the sets of a client that asked for `max_hz`.
    sub.rx.mark_changed();
    loop {
        let sent = tokio::select! {
            changed = sub.rx.changed(), if !held => {
                if changed.is_err() {
                    break; // the pipeline is gone
                }
                if min_interval.is_some() && Instant::now() < next_allowed {
                    held = true;
                    release.as_mut().reset(next_allowed);
                    continue;
                }
                out.send_latest(&mut sub).await
            }
            () = &mut release, if held => {
                held = false;
                out.send_latest(&mut sub).await
            }
            _ = ping.tick() => {
                let sent = tokio::time::timeout(state.ws.send_timeout, out.tx.send(Message::Ping(Default::default()))).await;
                if !matches!(sent, Ok(Ok(()))) {
                    break;
                }
                continue;
            }
            incoming = rx.next() => match incoming {
                None | Some(Err(_)) => break,
                Some(Ok(Message::Close(_))) => {
                    // tungstenite has queued the reply that completes the close handshake.
                    let _ = tokio::time::timeout(Duration::from_secs(1), out.tx.flush()).await;
                    break;
                }
                Some(Ok(_)) => continue, // pongs and anything a client says are ignored
            },
            () = shutdown.cancelled() => {
                let close = Message::Close(Some(CloseFrame {
                    code: close_code::AWAY,
                    reason: "vemlight is shutting down".into(),
                }));
                let _ = tokio::time::timeout(Duration::from_secs(1), out.tx.send(close)).await;
                break;
            }
        };
        match sent {
            Sent::Yes => {
                if let Some(interval) = min_interval {
                    next_allowed = Instant::now() + interval;
                } else {
                    out.timed = true;
                }
            }
            Sent::Nothing => {}
            Sent::Gone => break,
        }
    }
}

/// Counts a client in `vemlight_ws_clients` for as long as it lives, however its loop ends.
struct ConnectedClient(Arc<Metrics>);

impl ConnectedClient {
    fn count(metrics: &Arc<Metrics>) -> Self {
        metrics.ws_clients.fetch_add(1, Relaxed);
        Metrics::inc(&metrics.ws_connections_total);
        ConnectedClient(metrics.clone())
    }
}

impl Drop for ConnectedClient {
    fn drop(&mut self) {
        self.0.ws_clients.fetch_sub(1, Relaxed);
    }
}

/// What became of a set meant for a client.
enum Sent {
    Yes,
    /// Nothing is published yet.
    Nothing,
    /// The client hung up or stopped reading: end its loop.
    Gone,
}

/// A client's sending half and what its sends are counted in.
struct Sender<'a> {
    tx: SplitSink<WebSocket, Message>,
    metrics: &'a Metrics,
    send_timeout: Duration,
    /// Whether the sets sent are delivery-latency samples (not the first, not under `max_hz`).
    timed: bool,
}

impl Sender<'_> {
    /// Sends the newest set, counting it; a client whose socket does not take it within the send
    /// timeout is dropped.
    async fn send_latest(&mut self, sub: &mut Subscription) -> Sent {
        let Some(set) = sub.rx.borrow_and_update().clone() else {
            return Sent::Nothing;
        };
        let len = set.json.len() as u64;
        // The hub's bytes are the UTF-8 JSON the pipeline serialised; the check is a cheap scan.
        let Ok(text) = Utf8Bytes::try_from(set.json.clone()) else {
            tracing::error!("a published light set is not UTF-8");
            return Sent::Nothing;
        };
        let msg = Message::Text(text);
        match tokio::time::timeout(self.send_timeout, self.tx.send(msg)).await {
            Ok(Ok(())) => {
                if self.timed {
                    self.metrics.ws_delivery.observe(set.captured_at.elapsed());
                }
                Metrics::inc(&self.metrics.ws_messages_sent);
                self.metrics.ws_bytes_sent.fetch_add(len, Relaxed);
                Sent::Yes
            }
            Ok(Err(_)) => Sent::Gone, // a peer that hung up is a normal end
            Err(_) => {
                tracing::info!("dropping a client that stopped reading");
                Metrics::inc(&self.metrics.ws_clients_stalled);
                Sent::Gone
            }
        }
    }
}
