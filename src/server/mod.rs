//! The HTTP and WebSocket server of `vemlight serve` (axum).
//!
//! Input: the [`Hub`] the capture pipeline publishes into, and uploaded maps. Output: LightSet
//! documents over `GET /v1/stream` (WebSocket), `GET /v1/lights/latest` and `POST /v1/lights`,
//! plus `GET /`, `GET /healthz` and `GET /metrics` (DESIGN.md "Processes and endpoints"). [`app`]
//! builds the router, so the binary and the tests serve the same thing.
//!
//! This file holds the shared state, the router and the small handlers; the rest is one concern a
//! file: `accept` (the accept loop and graceful shutdown), `auth` (the bearer token), `query` (the
//! typed query parameters), `stream` (the WebSocket feed), `uploads` (`POST /v1/lights`) and
//! `error` (the one error type, a problem document).

mod accept;
mod auth;
mod demo;
pub mod error;
pub mod query;
pub mod stream;
mod uploads;

pub use accept::{HEADER_READ_TIMEOUT, SHUTDOWN_GRACE, run, shutdown_signal};
pub use error::ApiError;
pub use uploads::Uploads;

use crate::daemon::{Hub, SourceState};
use axum::Router;
use axum::extract::State;
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use query::{LatestQuery, Params};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_util::task::TaskTracker;

/// Everything the handlers share; cheap to clone.
#[derive(Clone)]
pub struct AppState {
    /// Latest sets per light count, metrics and source health, fed by the pipeline.
    pub hub: Arc<Hub>,
    /// Bearer token required by every endpoint but `/healthz`; `None` leaves them open.
    pub token: Option<Arc<str>>,
    /// Limits and workers for `POST /v1/lights`.
    pub uploads: Arc<Uploads>,
    /// WebSocket timing.
    pub ws: Arc<WsConfig>,
    /// Web pages allowed to call the API from their origin (CORS); none by default.
    pub cors: CorsOrigins,
    /// See [`HEADER_READ_TIMEOUT`], the default.
    pub header_read_timeout: Duration,
    /// The WebSocket client loops, which shutdown waits for (an upgraded connection is no
    /// longer hyper's, so the accept loop's connection set does not hold it).
    pub ws_clients: TaskTracker,
    started: Instant,
}

/// Which web origins may read the API's answers from a browser (CORS): the daemon's endpoints
/// then answer preflight requests and carry `Access-Control-Allow-Origin`.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum CorsOrigins {
    /// No CORS headers: only same-origin pages and non-browser clients.
    #[default]
    None,
    /// Any origin (`*`).
    Any,
    /// These origins exactly (`https://app.example.com`).
    List(Vec<HeaderValue>),
}

impl CorsOrigins {
    /// From `--cors-origin` values: `*` alone, or origins `scheme://host[:port]`.
    pub fn parse(values: &[String]) -> Result<Self, String> {
        if values.is_empty() {
            return Ok(CorsOrigins::None);
        }
        if values.iter().any(|v| v == "*") {
            return if values.len() == 1 {
                Ok(CorsOrigins::Any)
            } else {
                Err("--cors-origin '*' allows every origin: give it alone".into())
            };
        }
        values
            .iter()
            .map(|v| {
                let (scheme, host) = v.split_once("://").unwrap_or(("", ""));
                let ok = matches!(scheme, "http" | "https")
                    && !host.is_empty()
                    && !host.contains(['/', '?', '#', ' ']);
                match HeaderValue::from_str(v) {
                    Ok(h) if ok => Ok(h),
                    _ => Err(format!(
                        "--cors-origin '{v}' is not an origin like https://app.example.com (scheme, host, optional port; no path)"
                    )),
                }
            })
            .collect::<Result<_, _>>()
            .map(CorsOrigins::List)
    }

    fn layer(&self) -> Option<tower_http::cors::CorsLayer> {
        use tower_http::cors::{AllowOrigin, CorsLayer};
        let origin = match self {
            CorsOrigins::None => return None,
            CorsOrigins::Any => AllowOrigin::any(),
            CorsOrigins::List(list) => AllowOrigin::list(list.clone()),
        };
        Some(
            CorsLayer::new()
                .allow_origin(origin)
                .allow_methods([axum::http::Method::GET, axum::http::Method::POST])
                .allow_headers([header::AUTHORIZATION, header::CONTENT_TYPE])
                .max_age(Duration::from_secs(600)),
        )
    }
}

/// WebSocket timing.
pub struct WsConfig {
    pub ping_interval: Duration,
    /// A client whose socket does not accept a message within this time is disconnected.
    pub send_timeout: Duration,
}

impl Default for WsConfig {
    fn default() -> Self {
        WsConfig {
            ping_interval: Duration::from_secs(30),
            send_timeout: Duration::from_secs(10),
        }
    }
}

impl AppState {
    pub fn new(hub: Arc<Hub>, token: Option<String>, uploads: Uploads, ws: WsConfig) -> Self {
        AppState {
            hub,
            token: token.filter(|t| !t.is_empty()).map(Into::into),
            uploads: Arc::new(uploads),
            ws: Arc::new(ws),
            cors: CorsOrigins::None,
            header_read_timeout: HEADER_READ_TIMEOUT,
            ws_clients: TaskTracker::new(),
            started: Instant::now(),
        }
    }

    /// Lets web pages from `origins` call the API (see [`CorsOrigins`]).
    pub fn with_cors(mut self, origins: CorsOrigins) -> Self {
        self.cors = origins;
        self
    }
}

/// The router. Having it as a function lets the tests serve exactly what the binary serves.
pub fn app(state: AppState) -> Router {
    let protected = Router::new()
        .route("/v1/stream", get(stream::stream))
        .route("/v1/lights", post(uploads::post_lights))
        .route("/v1/lights/latest", get(latest))
        .route("/metrics", get(metrics))
        .route_layer(middleware::from_fn_with_state(
            state.clone(),
            auth::require_token,
        ));
    let cors = state.cors.layer();
    let router = Router::new()
        .route("/", get(viewer))
        .route("/demo", get(demo::page))
        .route("/demo/{file}", get(demo::asset))
        .route("/healthz", get(healthz))
        .merge(protected)
        // Uploads are limited by `Uploads::max_body`, checked in the handler.
        .layer(axum::extract::DefaultBodyLimit::disable())
        .with_state(state);
    // Outermost, so preflight requests are answered before the token check and error
    // documents carry the headers too (a page can then read why it was refused).
    match cors {
        Some(cors) => router.layer(cors),
        None => router,
    }
}

/// `GET /`: the live view (src/server/viewer.html), a browser client of `/v1/stream`. A static
/// page, so it needs no token; it passes its own `?access_token=` on to the stream.
async fn viewer() -> Response {
    (
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("text/html; charset=utf-8"),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        include_str!("viewer.html"),
    )
        .into_response()
}

/// `GET /healthz`: 200 while the daemon can serve a light set (status "degraded" when the source
/// has failed, ended or stalled and the last good set is being served), 503 before the first one
/// ("starting", or "failed" when the source ended or failed before giving one).
async fn healthz(State(state): State<AppState>) -> Response {
    let source = state.hub.health();
    let latest = state.hub.latest();
    let status = match (latest.is_some(), source.delivering()) {
        // The source ended or failed before its first good frame: nothing will come.
        (false, _) if matches!(source.state, SourceState::Ended | SourceState::Failed) => "failed",
        (false, _) => "starting",
        (true, true) => "ok",
        (true, false) => "degraded",
    };
    let body = serde_json::json!({
        "status": status,
        "serving_last_good_lightset": latest.is_some() && status == "degraded",
        "latest_seq": latest.as_ref().map(|p| p.seq),
        "latest_frame": latest.as_ref().map(|p| p.frame),
        "latest_age_s": latest.as_ref().map(|p| p.captured_at.elapsed().as_secs_f64()),
        "source": source,
        "uptime_s": state.started.elapsed().as_secs_f64(),
    });
    let code = if latest.is_some() {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (code, axum::Json(body)).into_response()
}

/// `GET /metrics`: Prometheus text format: the counters and histograms, then two gauges from
/// the source's health, for alerts on a source that has stopped.
async fn metrics(State(state): State<AppState>) -> Response {
    use std::fmt::Write;
    let mut text = state.hub.metrics.render();
    let source = state.hub.health();
    let _ = writeln!(
        text,
        "# HELP vemlight_source_up Whether the source delivers frames (0: starting, failed, ended or stalled).\n\
         # TYPE vemlight_source_up gauge\nvemlight_source_up {}",
        u8::from(source.delivering())
    );
    if let Some(p) = state.hub.latest() {
        let _ = writeln!(
            text,
            "# HELP vemlight_lightset_age_seconds Age of the newest LightSet's frame.\n\
             # TYPE vemlight_lightset_age_seconds gauge\nvemlight_lightset_age_seconds {:.6}",
            p.captured_at.elapsed().as_secs_f64()
        );
    }
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4"),
        )],
        text,
    )
        .into_response()
}

/// `GET /v1/lights/latest[?lights=N]`: the newest published set (default light count, or N,
/// waiting up to two frames' worth of time for a count not yet being computed).
async fn latest(
    Params(q): Params<LatestQuery>,
    State(state): State<AppState>,
) -> Result<Response, ApiError> {
    let published = match q.lights {
        None => state.hub.latest(),
        Some(n) if n == state.hub.default_lights() => state.hub.latest(),
        Some(n) => {
            let mut sub = state.hub.subscribe(n).map_err(ApiError::BadRequest)?;
            let wait =
                tokio::time::timeout(Duration::from_secs(2), sub.rx.wait_for(Option::is_some));
            match wait.await {
                Ok(Ok(v)) => v.clone(),
                _ => None,
            }
        }
    };
    let p = published.ok_or_else(|| ApiError::Unavailable("no light set yet".into()))?;
    Ok(json_response(p.json.clone()))
}

/// A LightSet document, already serialized, as the answer.
fn json_response(body: impl Into<axum::body::Body>) -> Response {
    let body: axum::body::Body = body.into();
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}
