//! The state every handler shares: [`AppState`] (the hub, the token, the upload limits and
//! extractor pool, WebSocket timing, CORS origins) and its parts. The handlers and the router
//! import it; it imports only the error type and the accept loop's default timeout, so nothing
//! it serves imports it back.

use super::accept::HEADER_READ_TIMEOUT;
use super::error::ApiError;
use crate::daemon::Hub;
use crate::lights::Extractor;
use axum::http::{HeaderValue, header};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::Semaphore;
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
    /// The NATS broker link, when the daemon publishes through one (reported, never a reason
    /// to be unhealthy).
    pub broker: Option<Arc<crate::publish::Link>>,
    pub(super) started: Instant,
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

    pub(super) fn layer(&self) -> Option<tower_http::cors::CorsLayer> {
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
            broker: None,
            started: Instant::now(),
        }
    }

    /// Reports `link` in `/healthz` and `/metrics`.
    pub fn with_broker(mut self, link: Arc<crate::publish::Link>) -> Self {
        self.broker = Some(link);
        self
    }

    /// Lets web pages from `origins` call the API (see [`CorsOrigins`]).
    pub fn with_cors(mut self, origins: CorsOrigins) -> Self {
        self.cors = origins;
        self
    }
}

/// Limits of `POST /v1/lights` and the extractors that serve it.
pub struct Uploads {
    /// Largest accepted body in bytes (checked from Content-Length, then while reading).
    pub max_body: usize,
    /// Largest accepted image in pixels (checked from the image header before decoding).
    pub max_pixels: u64,
    /// Decoding and extraction run on blocking threads, this many at once.
    pub(super) permits: Semaphore,
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
    pub(super) extractors: Mutex<Vec<Extractor>>,
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
    pub(super) async fn reserve(
        &self,
        bytes: usize,
    ) -> Result<tokio::sync::SemaphorePermit<'_>, ApiError> {
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
