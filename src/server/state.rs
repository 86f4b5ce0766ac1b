//! The state every handler shares: [`AppState`] (the hub, the token, the upload limits and
//! extractor pool, WebSocket timing, CORS origins, the client and connection caps) and its parts. The handlers and the router
//! import it; it imports only the error type and the accept loop's default timeout, so nothing
//! it serves imports it back.

use super::accept::HEADER_READ_TIMEOUT;
use super::error::ApiError;
use crate::daemon::Hub;
use crate::lights::Extractor;
use axum::http::{HeaderValue, header};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
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
    /// How many WebSocket clients and connections are taken at once.
    pub limits: Arc<Limits>,
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
            limits: Arc::new(Limits::default()),
            started: Instant::now(),
        }
    }

    /// Reports `link` in `/healthz` and `/metrics`.
    pub fn with_broker(mut self, link: Arc<crate::publish::Link>) -> Self {
        self.broker = Some(link);
        self
    }

    /// Caps WebSocket clients and connections at `limits` (default: [`Limits::resolve`] with
    /// neither given).
    pub fn with_limits(mut self, limits: Limits) -> Self {
        self.limits = Arc::new(limits);
        self
    }

    /// Lets web pages from `origins` call the API (see [`CorsOrigins`]).
    pub fn with_cors(mut self, origins: CorsOrigins) -> Self {
        self.cors = origins;
        self
    }
}

/// Descriptors kept back from connections by the default caps, for everything else the daemon
/// opens: the listener, stdin, the runtime's epoll and wakers, log output, the frames a directory
/// source reads.
pub const FD_RESERVE: u64 = 256;

/// Connections beyond the WebSocket clients in the default caps, so that health checks, metrics
/// scrapes, uploads and `/v1/lights/latest` are still served when every client slot is taken.
pub const HTTP_MARGIN: usize = 64;

/// The connection cap when the descriptor limit cannot be read, or is unlimited.
const UNKNOWN_FD_CONNECTIONS: usize = 65_536;

/// How many WebSocket clients (`--max-clients`) and open connections (`--max-connections`) the
/// daemon takes at once, and the slots that count them. A slot is a semaphore permit held for as
/// long as its client or connection lives, so a count can never pass its cap, however many
/// arrive together.
pub struct Limits {
    max_ws_clients: usize,
    max_connections: usize,
    ws_slots: Arc<Semaphore>,
    connection_slots: Arc<Semaphore>,
}

impl Default for Limits {
    /// [`Limits::resolve`] with neither cap given.
    fn default() -> Self {
        Limits::resolve(None, None).unwrap_or_else(|_| {
            Limits::new(UNKNOWN_FD_CONNECTIONS - HTTP_MARGIN, UNKNOWN_FD_CONNECTIONS)
                .expect("valid caps")
        })
    }
}

impl Limits {
    /// At most `max_ws_clients` WebSocket clients and `max_connections` connections (upgraded
    /// ones included), each at least 1.
    pub fn new(max_ws_clients: usize, max_connections: usize) -> Result<Self, String> {
        for (name, v) in [
            ("--max-clients", max_ws_clients),
            ("--max-connections", max_connections),
        ] {
            if !(1..=Semaphore::MAX_PERMITS).contains(&v) {
                return Err(format!(
                    "{name} must be between 1 and {}, got {v}",
                    Semaphore::MAX_PERMITS
                ));
            }
        }
        if max_ws_clients > max_connections {
            return Err(format!(
                "--max-clients {max_ws_clients} is more than --max-connections {max_connections}: \
                 every WebSocket client holds a connection"
            ));
        }
        Ok(Limits {
            max_ws_clients,
            max_connections,
            ws_slots: Arc::new(Semaphore::new(max_ws_clients)),
            connection_slots: Arc::new(Semaphore::new(max_connections)),
        })
    }

    /// The caps `--max-clients` and `--max-connections` give, a missing one from the other and
    /// from the soft descriptor limit (RLIMIT_NOFILE), one descriptor a connection:
    ///
    /// - connections: `max_clients + HTTP_MARGIN` when only the clients are given, else
    ///   `nofile − FD_RESERVE` (at least 2; 65 536 when the limit is unknown or unlimited);
    /// - clients: `max_connections − HTTP_MARGIN` (half of them when fewer than twice the
    ///   margin), at least 1.
    ///
    /// With the common soft limit of 1024: 704 clients, 768 connections. A cap beyond what the
    /// descriptor limit allows is taken, with a warning: raise the limit (`ulimit -n`) instead.
    pub fn resolve(
        max_ws_clients: Option<usize>,
        max_connections: Option<usize>,
    ) -> Result<Self, String> {
        let nofile = nofile_soft_limit();
        let limits = Self::resolve_with(max_ws_clients, max_connections, nofile)?;
        if let Some(n) = nofile
            && limits.max_connections as u64 > n.saturating_sub(FD_RESERVE)
        {
            tracing::warn!(
                "up to {} connections, but the descriptor limit is {n} (ulimit -n): accepting \
                 may fail before the cap is reached",
                limits.max_connections
            );
        }
        Ok(limits)
    }

    /// [`Limits::resolve`] under a soft descriptor limit of `nofile` (`None`: unknown).
    fn resolve_with(
        max_ws_clients: Option<usize>,
        max_connections: Option<usize>,
        nofile: Option<u64>,
    ) -> Result<Self, String> {
        let from_fds = || {
            nofile
                .map_or(UNKNOWN_FD_CONNECTIONS, |n| {
                    usize::try_from(n.saturating_sub(FD_RESERVE)).unwrap_or(usize::MAX)
                })
                .clamp(2, Semaphore::MAX_PERMITS)
        };
        let connections = match (max_connections, max_ws_clients) {
            (Some(c), _) => c,
            (None, Some(w)) => w.saturating_add(HTTP_MARGIN),
            (None, None) => from_fds(),
        };
        let margin = HTTP_MARGIN.min(connections / 2);
        let clients = max_ws_clients.unwrap_or_else(|| connections.saturating_sub(margin).max(1));
        Limits::new(clients, connections)
    }

    pub fn max_ws_clients(&self) -> usize {
        self.max_ws_clients
    }

    pub fn max_connections(&self) -> usize {
        self.max_connections
    }

    /// WebSocket clients connected now (and handshakes answered, not yet upgraded).
    pub fn ws_clients(&self) -> usize {
        self.max_ws_clients - self.ws_slots.available_permits()
    }

    /// A WebSocket client's slot, if one is free.
    pub(super) fn try_ws_slot(&self) -> Option<OwnedSemaphorePermit> {
        self.ws_slots.clone().try_acquire_owned().ok()
    }

    /// The connection slots, which the accept loop takes one of before each accept.
    pub(super) fn connection_slots(&self) -> Arc<Semaphore> {
        self.connection_slots.clone()
    }
}

/// The soft RLIMIT_NOFILE; `None` where it cannot be read or is unlimited.
#[cfg(unix)]
fn nofile_soft_limit() -> Option<u64> {
    let mut rl = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given, which lives for the call.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut rl) } == 0;
    // `rlim_t` is not u64 on every Unix.
    #[allow(clippy::unnecessary_cast)]
    (ok && rl.rlim_cur != libc::RLIM_INFINITY).then_some(rl.rlim_cur as u64)
}

#[cfg(not(unix))]
fn nofile_soft_limit() -> Option<u64> {
    None
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caps_follow_the_descriptor_limit_and_each_other() {
        let caps = |c, n, fds| {
            Limits::resolve_with(c, n, fds).map(|l| (l.max_ws_clients(), l.max_connections()))
        };
        assert_eq!(caps(None, None, Some(1024)), Ok((704, 768)));
        assert_eq!(caps(None, None, None), Ok((65_472, 65_536)));
        // A limit below the reserve still serves a client.
        assert_eq!(caps(None, None, Some(100)), Ok((1, 2)));
        assert_eq!(caps(None, None, Some(356)), Ok((50, 100)));
        assert_eq!(caps(Some(3), None, Some(1024)), Ok((3, 67)));
        assert_eq!(caps(None, Some(10), Some(1024)), Ok((5, 10)));
        assert_eq!(caps(None, Some(1), Some(1024)), Ok((1, 1)));
        assert_eq!(caps(None, Some(500), Some(1024)), Ok((436, 500)));
        assert_eq!(caps(Some(5), Some(5), Some(1024)), Ok((5, 5)));
        assert!(
            caps(Some(6), Some(5), None)
                .unwrap_err()
                .contains("--max-connections 5")
        );
        assert!(
            caps(Some(0), None, None)
                .unwrap_err()
                .contains("--max-clients")
        );
        assert!(
            caps(None, Some(0), None)
                .unwrap_err()
                .contains("--max-connections")
        );
        assert!(nofile_soft_limit().is_none_or(|n| n > 0));
    }

    #[test]
    fn a_slot_is_held_until_dropped() {
        let l = Limits::new(2, 4).unwrap();
        let a = l.try_ws_slot().unwrap();
        let b = l.try_ws_slot().unwrap();
        assert!(l.try_ws_slot().is_none());
        assert_eq!(l.ws_clients(), 2);
        drop(a);
        assert_eq!(l.ws_clients(), 1);
        assert!(l.try_ws_slot().is_some());
        drop(b);
        assert_eq!(l.ws_clients(), 0);
    }
}
