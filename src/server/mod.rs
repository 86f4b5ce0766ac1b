//! The HTTP and WebSocket server of `vemlight serve` (axum).
//!
//! Input: the [`Hub`] the capture pipeline publishes into, and uploaded maps. Output: LightSet
//! documents over `GET /v1/stream` (WebSocket), `GET /v1/lights/latest` and `POST /v1/lights`,
//! plus `GET /healthz` and `GET /metrics`. [`app`] builds the router, so the binary and the tests
//! serve the same thing.

pub mod error;
pub mod stream;

pub use error::ApiError;

use crate::daemon::{Hub, SourceState};
use crate::envmap::{Decoding, EnvMap, Projection};
use crate::lights::{Extractor, Method};
use crate::lightset::{LightRequest, lightset_for_map, now_ns};
use crate::metrics::Metrics;
use crate::sampling::Domain;
use axum::Router;
use axum::body::Body;
use axum::extract::{Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use futures_util::StreamExt;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::Semaphore;

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

/// Limits of `POST /v1/lights` and the extractors that serve it.
pub struct Uploads {
    /// Largest accepted body in bytes (checked from Content-Length, then while reading).
    pub max_body: usize,
    /// Largest accepted image in pixels (checked from the image header before decoding).
    pub max_pixels: u64,
    /// Decoding and extraction run on blocking threads, this many at once.
    permits: Semaphore,
    /// Bytes of request bodies held at once, in KiB: each upload reserves its declared length
    /// (`max_body` when it declares none) before reading, so that many large uploads arriving
    /// together (or stalling) cannot hold more memory than this between them.
    buffered_kib: Semaphore,
    /// An upload that sends nothing for this long is answered 408; one that waits this long for
    /// room in the buffer budget, 503.
    pub idle_timeout: Duration,
    /// An upload that is not in after this long in all is answered 408.
    pub total_timeout: Duration,
    /// Idle extractors, whose cached tables make repeated same-size uploads cheap.
    extractors: Mutex<Vec<Extractor>>,
}

impl Uploads {
    /// Limits for bodies of up to `max_body` bytes holding up to `max_pixels` pixels, decoded
    /// `concurrency` at a time; bodies of twice that many uploads at their largest may be held
    /// at once.
    pub fn new(max_body: usize, max_pixels: u64, concurrency: usize) -> Self {
        let concurrency = concurrency.max(1);
        let budget_kib = kib(max_body).saturating_mul(2 * concurrency);
        Uploads {
            max_body,
            max_pixels,
            permits: Semaphore::new(concurrency),
            buffered_kib: Semaphore::new(budget_kib.min(Semaphore::MAX_PERMITS)),
            idle_timeout: Duration::from_secs(10),
            total_timeout: Duration::from_secs(120),
            extractors: Mutex::new(Vec::new()),
        }
    }

    /// Room for a body of `bytes` in the buffer budget, waiting up to `idle_timeout` for it.
    async fn reserve(&self, bytes: usize) -> Result<tokio::sync::SemaphorePermit<'_>, ApiError> {
        let n = u32::try_from(kib(bytes)).unwrap_or(u32::MAX);
        match tokio::time::timeout(self.idle_timeout, self.buffered_kib.acquire_many(n)).await {
            Ok(Ok(permit)) => Ok(permit),
            Ok(Err(_)) => Err(ApiError::Unavailable("shutting down".into())),
            Err(_) => Err(ApiError::Unavailable(
                "too many uploads are being received at once; retry shortly".into(),
            )),
        }
    }
}

/// Bytes in KiB, rounded up.
fn kib(bytes: usize) -> usize {
    bytes.div_ceil(1024)
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
        .route("/v1/lights", post(post_lights))
        .route("/v1/lights/latest", get(latest))
        .route("/metrics", get(metrics))
        .route_layer(middleware::from_fn_with_state(state.clone(), require_token));
    let cors = state.cors.layer();
    let router = Router::new()
        .route("/", get(viewer))
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

/// How long open requests and WebSocket clients get to finish once shutdown has begun.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// A connection must send a request's whole header within this time (and an idle kept-alive
/// connection is closed after it), so that connections that trickle in headers or say nothing
/// cannot pile up ([`AppState::header_read_timeout`]).
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);

/// Serves [`app`] on `listener` over HTTP/1.1 (with WebSocket upgrades) until `shutdown`
/// resolves, then shuts the hub down (streams get a close frame, the pipeline stops) and returns
/// once open requests have finished and every WebSocket client has gone, or after
/// [`SHUTDOWN_GRACE`]: a client that stalls mid-upload does not hold the daemon up.
///
/// The accept loop is hyper's own rather than `axum::serve`, which sets no timer and so no
/// [`HEADER_READ_TIMEOUT`]. Every connection gets TCP_NODELAY: a LightSet is written as a few
/// small frames, and Nagle's algorithm would hold them back for the peer's delayed ACK
/// (measured: p99 delivery 9 ms on loopback without it).
pub async fn run(
    listener: tokio::net::TcpListener,
    state: AppState,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    use hyper_util::rt::{TokioIo, TokioTimer};
    let hub = state.hub.clone();
    let header_read_timeout = state.header_read_timeout;
    let service = hyper_util::service::TowerToHyperService::new(app(state));
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let mut connections = tokio::task::JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        let (tcp, _) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors, say: let open connections finish some.
                    tracing::warn!("cannot accept a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            Some(_) = connections.join_next(), if !connections.is_empty() => continue,
            () = &mut shutdown => break,
        };
        if let Err(e) = tcp.set_nodelay(true) {
            tracing::debug!("cannot set TCP_NODELAY: {e}");
        }
        let service = service.clone();
        let mut stop = stop_rx.clone();
        connections.spawn(async move {
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(header_read_timeout)
                // A client that sends its request and then shuts its side (`nc -N`) still gets
                // the answer.
                .half_close(true)
                .serve_connection(TokioIo::new(tcp), service)
                .with_upgrades();
            tokio::pin!(conn);
            tokio::select! {
                _ = conn.as_mut() => return,
                _ = stop.wait_for(|s| *s) => {}
            }
            // Finish the request in hand, then close.
            conn.as_mut().graceful_shutdown();
            let _ = conn.await;
        });
    }
    drop(listener);
    hub.shutdown();
    let _ = stop_tx.send(true);
    let deadline = tokio::time::Instant::now() + SHUTDOWN_GRACE;
    let finished = tokio::time::timeout_at(deadline, async {
        while connections.join_next().await.is_some() {}
    });
    if finished.await.is_err() {
        tracing::warn!(
            "{} connections still open {SHUTDOWN_GRACE:?} after shutdown began: closing them",
            connections.len()
        );
        connections.abort_all();
    }
    // Upgraded connections are no longer hyper's: wait for the clients' loops, which send their
    // close frame and end.
    while hub
        .metrics
        .ws_clients
        .load(std::sync::atomic::Ordering::Relaxed)
        > 0
        && tokio::time::Instant::now() < deadline
    {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    Ok(())
}

/// The token of an `Authorization: Bearer <token>` value; the scheme name is case-insensitive
/// (RFC 9110 §11.1).
fn bearer_credentials(value: &str) -> Option<&str> {
    let (scheme, token) = value.split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then(|| token.trim_start_matches(' '))
}

/// Rejects requests without the configured bearer token (constant-time comparison). A browser's
/// WebSocket cannot send headers, so `GET /v1/stream` also takes the token as the `access_token`
/// query parameter (RFC 6750 §2.3); nowhere else, as URLs end up in logs.
async fn require_token(State(state): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(token) = &state.token {
        let from_header = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(bearer_credentials);
        let from_query = || {
            if req.uri().path() != "/v1/stream" {
                return None;
            }
            Query::<HashMap<String, String>>::try_from_uri(req.uri())
                .ok()?
                .0
                .remove("access_token")
        };
        let given = match from_header {
            Some(t) => t.to_string(),
            None => from_query().unwrap_or_default(),
        };
        if !constant_time_eq(given.as_bytes(), token.as_bytes()) {
            return ApiError::Unauthorized.into_response();
        }
    }
    next.run(req).await
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Parses an optional query parameter, with a 400 naming it when malformed.
pub fn parse_param<T: std::str::FromStr>(
    q: &HashMap<String, String>,
    name: &str,
) -> Result<Option<T>, ApiError>
where
    T::Err: std::fmt::Display,
{
    q.get(name)
        .map(|v| {
            v.parse::<T>()
                .map_err(|e| ApiError::BadRequest(format!("query parameter {name}='{v}': {e}")))
        })
        .transpose()
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
    Query(q): Query<HashMap<String, String>>,
    State(state): State<AppState>,
) -> Result<Response, ApiError> {
    let lights = parse_param::<usize>(&q, "lights")?;
    let published = match lights {
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

/// Content types an upload may declare (or none).
fn acceptable_content_type(headers: &HeaderMap) -> Result<(), ApiError> {
    let Some(ct) = headers.get(header::CONTENT_TYPE) else {
        return Ok(());
    };
    let ct = ct.to_str().unwrap_or("").to_ascii_lowercase();
    let essence = ct.split(';').next().unwrap_or("").trim();
    if essence.is_empty()
        || essence == "application/octet-stream"
        || essence.starts_with("image/")
        || essence == "application/x-exr"
    {
        Ok(())
    } else {
        Err(ApiError::UnsupportedMedia(format!(
            "content type '{essence}' is not an image; send the raw EXR or HDR file \
             (application/octet-stream or image/x-exr)"
        )))
    }
}

/// `POST /v1/lights`: a raw EXR or Radiance HDR body → the same LightSet `vemlight lights` gives.
async fn post_lights(
    Query(q): Query<HashMap<String, String>>,
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let metrics = state.hub.metrics.clone();
    Metrics::inc(&metrics.http_lights_requests);
    let result = post_lights_inner(q, &state, &headers, body).await;
    if result.is_err() {
        Metrics::inc(&metrics.http_lights_errors);
    }
    result
}

async fn post_lights_inner(
    q: HashMap<String, String>,
    state: &AppState,
    headers: &HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let t = Instant::now();
    let mut stream = body.into_data_stream();
    // Parameters first: a bad request is refused without reading its body (the drain only lets
    // a client that is still sending read the answer).
    let (req, projection) = match upload_request(&q, headers) {
        Ok(r) => r,
        Err(e) => {
            drain_unless_waiting(headers, &mut stream).await;
            return Err(e);
        }
    };
    let limits = &state.uploads;
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if let Some(len) = declared
        && len > limits.max_body as u64
    {
        drain_unless_waiting(headers, &mut stream).await;
        return Err(ApiError::TooLarge(format!(
            "body of {len} bytes exceeds the limit of {} bytes",
            limits.max_body
        )));
    }
    // Room for the body first (an upload without a length may be as large as allowed).
    let _buffered = limits
        .reserve(declared.map_or(limits.max_body, |len| len as usize))
        .await?;
    let deadline = tokio::time::Instant::now() + limits.total_timeout;
    let mut bytes = Vec::with_capacity(declared.unwrap_or(0) as usize);
    let mut sniffed = false;
    loop {
        let idle = (tokio::time::Instant::now() + limits.idle_timeout).min(deadline);
        let chunk = match tokio::time::timeout_at(idle, stream.next()).await {
            Ok(Some(chunk)) => {
                chunk.map_err(|e| ApiError::BadRequest(format!("the upload broke off: {e}")))?
            }
            Ok(None) => break,
            Err(_) => {
                return Err(ApiError::Timeout(format!(
                    "the upload stalled: nothing arrived for {:?}, or it took over {:?} in all",
                    limits.idle_timeout, limits.total_timeout
                )));
            }
        };
        if bytes.len() + chunk.len() > limits.max_body {
            drain(&mut stream).await;
            return Err(ApiError::TooLarge(format!(
                "body exceeds the limit of {} bytes",
                limits.max_body
            )));
        }
        bytes.extend_from_slice(&chunk);
        // Not an EXR or HDR: say so from the first bytes, not after reading the rest.
        if !sniffed && bytes.len() >= crate::envmap::MAGIC_LEN {
            sniffed = true;
            if let Err(e) = crate::envmap::sniff(&bytes) {
                drain(&mut stream).await;
                return Err(e.into());
            }
        }
    }
    if bytes.is_empty() {
        return Err(ApiError::UnsupportedMedia(
            "empty body: send the raw EXR or HDR file".into(),
        ));
    }
    let read_ms = t.elapsed().as_secs_f64() * 1e3;

    let _permit = limits
        .permits
        .acquire()
        .await
        .map_err(|_| ApiError::Unavailable("shutting down".into()))?;
    let uploads = state.uploads.clone();
    let max_pixels = uploads.max_pixels;
    let set = tokio::task::spawn_blocking(move || -> Result<_, ApiError> {
        let t = Instant::now();
        // Uploads run `--post-workers` at a time already: one thread each (see `Decoding`).
        let map = EnvMap::decode_with(&bytes, projection, max_pixels, Decoding::OneThread)?;
        let decode_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut ex = uploads
            .extractors
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default();
        let mut set = lightset_for_map(&mut ex, &map, &req, "upload");
        uploads
            .extractors
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(ex);
        set.diagnostics.timings_ms.decode = decode_ms;
        set.diagnostics.timings_ms.total += decode_ms + read_ms;
        set.t_emit_ns = now_ns();
        Ok(set)
    })
    .await
    .map_err(|e| ApiError::Internal(format!("extraction task failed: {e}")))??;
    let json = serde_json::to_string(&set).map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok(json_response(json))
}

/// The query and headers of an upload, checked.
fn upload_request(
    q: &HashMap<String, String>,
    headers: &HeaderMap,
) -> Result<(LightRequest, Option<Projection>), ApiError> {
    let req = LightRequest {
        lights: parse_param(q, "lights")?.unwrap_or(64),
        domain: parse_param::<Domain>(q, "domain")?,
        method: parse_param::<Method>(q, "method")?.unwrap_or_default(),
        max_error: parse_param(q, "max_error")?,
        estimate_error: true,
        sh9: true,
    };
    req.validate().map_err(ApiError::BadRequest)?;
    let projection = q
        .get("projection")
        .map(|p| Projection::parse(p).map_err(ApiError::BadRequest))
        .transpose()?;
    acceptable_content_type(headers)?;
    Ok((req, projection))
}

/// At most this much of a refused upload is read and discarded — for at most [`DRAIN_TIME`], and
/// only while data keeps arriving ([`DRAIN_IDLE`]) — so that a client still sending sees the error
/// instead of a reset connection; beyond that the connection is closed.
const DRAIN_BYTES: usize = 16 << 20;
const DRAIN_TIME: Duration = Duration::from_secs(2);
const DRAIN_IDLE: Duration = Duration::from_millis(100);

/// [`drain`]s a body refused before any of it was read, unless the client sent
/// `Expect: 100-continue`: it waits for this answer before sending the body, and reading would
/// tell it to go ahead (curl then sent 5 MB to be told 413).
async fn drain_unless_waiting(headers: &HeaderMap, stream: &mut axum::body::BodyDataStream) {
    let waiting = headers
        .get(header::EXPECT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.trim().eq_ignore_ascii_case("100-continue"));
    if !waiting {
        drain(stream).await;
    }
}

async fn drain(stream: &mut axum::body::BodyDataStream) {
    let deadline = tokio::time::Instant::now() + DRAIN_TIME;
    let mut seen = 0usize;
    while seen < DRAIN_BYTES {
        let idle = (tokio::time::Instant::now() + DRAIN_IDLE).min(deadline);
        match tokio::time::timeout_at(idle, stream.next()).await {
            Ok(Some(Ok(chunk))) => seen += chunk.len(),
            _ => break,
        }
    }
}

/// Resolves when SIGINT or SIGTERM arrives.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = terminate => {},
    }
}
