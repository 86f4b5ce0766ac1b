//! The HTTP and WebSocket server of `vemlight serve` (axum).
//!
//! Input: the [`Hub`](crate::daemon::Hub) the capture pipeline publishes into, and uploaded maps. Output: LightSet
//! documents over `GET /v1/stream` (WebSocket), `GET /v1/lights/latest` and `POST /v1/lights`,
//! plus `GET /`, `GET /healthz` and `GET /metrics` (DESIGN.md "Processes and endpoints"). [`app`]
//! builds the router, so the binary and the tests serve the same thing.
//!
//! This file holds the router and [`run`]; the rest is one concern a file, each importing only
//! what lies below it: `state` (what the handlers share), `handlers` (the small endpoints),
//! `accept` (the accept loop and graceful shutdown), `auth` (the bearer token), `query` (the typed
//! query parameters), `stream` (the WebSocket feed), `uploads` (`POST /v1/lights`) and `error`
//! (the one error type, a problem document).

mod accept;
mod auth;
mod demo;
pub mod error;
mod handlers;
pub mod query;
mod state;
pub mod stream;
mod uploads;

pub use accept::{HEADER_READ_TIMEOUT, SHUTDOWN_GRACE, shutdown_signal};
pub use error::ApiError;
pub use state::{AppState, CorsOrigins, FD_RESERVE, HTTP_MARGIN, Limits, Uploads, WsConfig};

use axum::Router;
use axum::middleware;
use axum::routing::{get, post};

/// The router. Having it as a function lets the tests serve exactly what the binary serves.
pub fn app(state: AppState) -> Router {
    let protected = Router::new()
        .route("/v1/stream", get(stream::stream))
        .route("/v1/lights", post(uploads::post_lights))
        .route("/v1/lights/latest", get(handlers::latest))
        .route("/metrics", get(handlers::metrics))
        .route_layer(middleware::from_fn_with_state(
            state.clone(),
            auth::require_token,
        ));
    let cors = state.cors.layer();
    let router = Router::new()
        .route("/", get(handlers::viewer))
        .route("/demo", get(demo::page))
        .route("/demo/{file}", get(demo::asset))
        .route("/vendor/{file}", get(handlers::vendor))
        .route("/healthz", get(handlers::healthz))
        .merge(protected)
        // Every error is a problem document (docs/API.md), a wrong path or method too.
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
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

/// Any path that is not an endpoint.
async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::NotFound(format!(
        "no endpoint at {} (docs/API.md lists them)",
        uri.path()
    ))
}

/// An endpoint asked for with a method it does not take.
async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> ApiError {
    ApiError::MethodNotAllowed(format!(
        "{} does not take {method} (the Allow header lists what it takes)",
        uri.path()
    ))
}

/// Serves [`app`] on `listener` over HTTP/1.1 (with WebSocket upgrades) until `shutdown`
/// resolves, then shuts the hub down (streams get a close frame, the pipeline stops) and returns
/// once open requests have finished and every WebSocket client has gone, or after
/// [`SHUTDOWN_GRACE`]: a client that stalls mid-upload does not hold the daemon up. The loop
/// itself is `accept::serve`.
pub async fn run(
    listener: tokio::net::TcpListener,
    state: AppState,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let hub = state.hub.clone();
    let header_read_timeout = state.header_read_timeout;
    let ws_clients = state.ws_clients.clone();
    let slots = state.limits.connection_slots();
    accept::serve(
        listener,
        app(state),
        hub,
        ws_clients,
        slots,
        header_read_timeout,
        shutdown,
    )
    .await
}
