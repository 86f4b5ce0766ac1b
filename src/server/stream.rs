//! `GET /v1/stream`: the WebSocket feed of LightSets, latest-state semantics.
//!
//! Each client reads its own `watch` channel: a client that reads slowly simply sees fewer
//! frames, never a queue, and never holds up the capture loop or another client. A client that
//! stops reading for longer than the send timeout is disconnected.

use super::{ApiError, AppState, parse_param};
use crate::capture::pipeline::Subscription;
use crate::metrics::Metrics;
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade, close_code};
use axum::extract::{Query, State};
use axum::response::Response;
use futures_util::{SinkExt, StreamExt};
use std::collections::HashMap;
use std::sync::atomic::Ordering::Relaxed;
use std::time::Duration;
use tokio::time::{Instant, MissedTickBehavior};

/// The WebSocket subprotocol of this wire format.
pub const SUBPROTOCOL: &str = "vemlight.v1";

/// Largest message a client may send (bytes).
const CLIENT_MESSAGE_LIMIT: usize = 64 * 1024;

/// Bytes tungstenite reads from a client socket at a time. Its default, 128 KiB, is zeroed on
/// every poll of the read half, which this loop does each time a LightSet goes out: with 100
/// clients that memset was 0.9 ms of every frame's fan-out (perf, `cargo bench --bench serve`).
/// Clients send only pongs and close frames.
const CLIENT_READ_BUFFER: usize = 4 * 1024;

/// Upgrade handler: checks the query, subscribes, hands off.
pub async fn stream(
    ws: WebSocketUpgrade,
    Query(q): Query<HashMap<String, String>>,
    State(state): State<AppState>,
) -> Result<Response, ApiError> {
    let lights = parse_param::<usize>(&q, "lights")?.unwrap_or(state.hub.default_lights());
    let max_hz = parse_param::<f64>(&q, "max_hz")?;
    if let Some(hz) = max_hz
        && !(hz.is_finite() && hz > 0.0)
    {
        return Err(ApiError::BadRequest(format!(
            "max_hz must be a positive number, got {hz}"
        )));
    }
    let sub = state.hub.subscribe(lights).map_err(ApiError::BadRequest)?;
    let min_interval = max_hz.map(|hz| Duration::from_secs_f64(1.0 / hz));
    Ok(ws
        .protocols([SUBPROTOCOL])
        // Clients have nothing to send but pongs and close frames: refuse anything big.
        .max_message_size(CLIENT_MESSAGE_LIMIT)
        .max_frame_size(CLIENT_MESSAGE_LIMIT)
        .read_buffer_size(CLIENT_READ_BUFFER)
        .on_upgrade(move |socket| client_loop(socket, sub, min_interval, state)))
}

/// One client's loop: send each new set (at most every `min_interval`), ping, answer close,
/// close cleanly on shutdown.
async fn client_loop(
    socket: WebSocket,
    mut sub: Subscription,
    min_interval: Option<Duration>,
    state: AppState,
) {
    let metrics = state.hub.metrics.clone();
    metrics.ws_clients.fetch_add(1, Relaxed);
    Metrics::inc(&metrics.ws_connections_total);
    let (mut tx, mut rx) = socket.split();
    let mut shutdown = state.hub.shutdown_tx.subscribe();
    let mut ping = tokio::time::interval_at(
        Instant::now() + state.ws.ping_interval,
        state.ws.ping_interval,
    );
    ping.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let mut next_allowed = Instant::now();
    // The current set, if any, goes out at once. It may be a frame old, so it is not a delivery
    // latency sample; nor are the sets of a client that asked for `max_hz`.
    sub.rx.mark_changed();
    let mut timed = false;
    loop {
        tokio::select! {
            changed = sub.rx.changed() => {
                if changed.is_err() {
                    break; // the pipeline is gone
                }
                if let Some(interval) = min_interval {
                    tokio::time::sleep_until(next_allowed).await;
                    next_allowed = Instant::now() + interval;
                }
                let Some(set) = sub.rx.borrow_and_update().clone() else { continue };
                let len = set.json.len() as u64;
                let msg = Message::Text(set.json.clone());
                match tokio::time::timeout(state.ws.send_timeout, tx.send(msg)).await {
                    Ok(Ok(())) => {
                        if timed {
                            metrics.ws_delivery.observe(set.captured_at.elapsed());
                        }
                        timed = min_interval.is_none();
                        Metrics::inc(&metrics.ws_messages_sent);
                        metrics.ws_bytes_sent.fetch_add(len, Relaxed);
                    }
                    Ok(Err(_)) => break, // a peer that hung up is a normal end
                    Err(_) => {
                        tracing::info!("dropping a client that stopped reading");
                        Metrics::inc(&metrics.ws_clients_stalled);
                        break;
                    }
                }
            }
            _ = ping.tick() => {
                let sent = tokio::time::timeout(state.ws.send_timeout, tx.send(Message::Ping(Default::default()))).await;
                if !matches!(sent, Ok(Ok(()))) {
                    break;
                }
            }
            incoming = rx.next() => match incoming {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => break,
                Some(Ok(_)) => {} // pongs and anything a client says are ignored
            },
            _ = shutdown.changed() => {
                let close = Message::Close(Some(CloseFrame {
                    code: close_code::AWAY,
                    reason: "vemlight is shutting down".into(),
                }));
                let _ = tokio::time::timeout(Duration::from_secs(1), tx.send(close)).await;
                break;
            }
        }
    }
    metrics.ws_clients.fetch_sub(1, Relaxed);
}
