//! The small handlers: `GET /` (the live view) and the NATS client its broker mode loads
//! (`GET /vendor/{file}`), `GET /healthz`, `GET /metrics` and `GET /v1/lights/latest` (DESIGN.md
//! "Processes and endpoints").

use super::demo;
use super::error::ApiError;
use super::query::{LatestQuery, Params};
use super::state::AppState;
use crate::daemon::hub::{Interest, SubscribeError};
use crate::daemon::{SourceState, StreamKey};
use crate::metrics::Metrics;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use std::time::Duration;

/// `GET /`: the live view (src/server/viewer.html), a browser client of `/v1/stream`. A static
/// page, so it needs no token; it passes its own `?access_token=` on to the stream.
pub(super) async fn viewer() -> Response {
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

/// The vendored NATS client's version (clients/nats/vendor/VERSION): the `?v=` of its cacheable
/// URL, which the live view names.
pub const NATS_CLIENT_VERSION: &str = include_str!("../../clients/nats/vendor/VERSION");

/// The files under `/vendor/`: the NATS JavaScript client as one ES module (clients/nats/vendor.sh)
/// and the licences of what it bundles. Embedded, so the broker mode needs no CDN.
const VENDOR: [(&str, &str, &str); 2] = [
    (
        "nats-core.min.js",
        "text/javascript; charset=utf-8",
        include_str!("../../clients/nats/vendor/nats-core.min.js"),
    ),
    (
        "NATS-LICENSE.txt",
        "text/plain; charset=utf-8",
        include_str!("../../clients/nats/vendor/LICENSE"),
    ),
];

/// `GET /vendor/{file}`: one of [`VENDOR`], or 404. Static, so no token. The client asked for under
/// its version never changes under that URL and is cached for good.
pub(super) async fn vendor(
    Path(file): Path<String>,
    Query(q): Query<demo::AssetQuery>,
) -> Response {
    let Some(&(_, content_type, body)) = VENDOR.iter().find(|(name, _, _)| *name == file) else {
        return StatusCode::NOT_FOUND.into_response();
    };
    let versioned = q.v.as_deref() == Some(NATS_CLIENT_VERSION.trim());
    let cache = if file == "nats-core.min.js" && versioned {
        demo::FOREVER
    } else {
        demo::NO_CACHE
    };
    demo::respond(content_type, cache, body)
}

/// `GET /healthz`: 200 while the daemon can serve a light set (status "degraded" when the source
/// has failed, ended or stalled and the last good set is being served), 503 before the first one
/// ("starting", or "failed" when the source ended or failed before giving one). It also gives the
/// WebSocket clients and connections against their caps.
pub(super) async fn healthz(State(state): State<AppState>) -> Response {
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
        "ws_clients": state.limits.ws_clients(),
        "max_ws_clients": state.limits.max_ws_clients(),
        "connections": state.hub.metrics.connections_open.load(std::sync::atomic::Ordering::Relaxed),
        "max_connections": state.limits.max_connections(),
        "uptime_s": state.started.elapsed().as_secs_f64(),
        // The broker link's state does not change the status: the daemon's own clients are
        // served either way.
        "broker": state.broker.as_ref().map(|b| b.health()),
    });
    let code = if latest.is_some() {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (code, axum::Json(body)).into_response()
}

/// `GET /metrics`: Prometheus text format: the counters and histograms, the caps on clients and
/// connections, then two gauges from the source's health, for alerts on a source that has
/// stopped.
pub(super) async fn metrics(State(state): State<AppState>) -> Response {
    use std::fmt::Write;
    let mut text = state.hub.metrics.render();
    let _ = writeln!(
        text,
        "# HELP vemlight_ws_clients_max WebSocket clients taken at once (--max-clients).\n\
         # TYPE vemlight_ws_clients_max gauge\nvemlight_ws_clients_max {}\n\
         # HELP vemlight_connections_max Connections open at once (--max-connections).\n\
         # TYPE vemlight_connections_max gauge\nvemlight_connections_max {}",
        state.limits.max_ws_clients(),
        state.limits.max_connections()
    );
    let source = state.hub.health();
    let _ = writeln!(
        text,
        "# HELP vemlight_source_up Whether the source delivers frames (0: starting, failed, ended or stalled).\n\
         # TYPE vemlight_source_up gauge\nvemlight_source_up {}",
        u8::from(source.delivering())
    );
    if let Some(b) = &state.broker {
        b.render_metrics(&mut text);
    }
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

/// How long a `/v1/lights/latest` request refused for its light count is told to wait: about the
/// longest another such request holds its count.
const LATEST_RETRY_AFTER_S: u32 = 2;

/// `GET /v1/lights/latest[?lights=N]`: the newest published set (default light count, or N,
/// waiting up to 2 s for a count not yet being computed). A count no stream has is computed
/// only within the share of the hub's keys such requests may hold (see
/// [`Interest`](crate::daemon::hub::Interest)), so a burst of distinct counts cannot crowd out
/// streams; beyond it, 503 at once.
pub(super) async fn latest(
    Params(q): Params<LatestQuery>,
    State(state): State<AppState>,
) -> Result<Response, ApiError> {
    let default = StreamKey::from(state.hub.default_lights());
    let key = StreamKey::new(q.lights.unwrap_or(default.lights), q.max_error, q.shadowed)
        .map_err(ApiError::BadRequest)?;
    let published = if key == default {
        state.hub.latest()
    } else {
        let mut sub = state
            .hub
            .subscribe_as(key, Interest::Once)
            .map_err(|e| match e {
                SubscribeError::Invalid(e) => ApiError::BadRequest(e),
                SubscribeError::Full(detail) => {
                    Metrics::inc(&state.hub.metrics.latest_refused);
                    ApiError::AtCapacity {
                        detail,
                        retry_after_s: LATEST_RETRY_AFTER_S,
                    }
                }
            })?;
        let wait = tokio::time::timeout(Duration::from_secs(2), sub.rx.wait_for(Option::is_some));
        match wait.await {
            Ok(Ok(v)) => v.clone(),
            _ => None,
        }
    };
    let p = published.ok_or_else(|| ApiError::Unavailable("no light set yet".into()))?;
    Ok(json_response(p.json.clone()))
}

/// A LightSet document, already serialized, as the answer.
pub(super) fn json_response(body: impl Into<axum::body::Body>) -> Response {
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

#[cfg(test)]
mod tests {
    use super::*;

    const PAGE: &str = include_str!("viewer.html");

    /// The live view loads the vendored client under the version that makes it cacheable, and
    /// the vendored files are the version package.json pins.
    #[test]
    fn the_live_view_names_the_vendored_nats_client() {
        let version = NATS_CLIENT_VERSION.trim();
        assert!(
            PAGE.contains(&format!("\"/vendor/nats-core.min.js?v={version}\"")),
            "viewer.html must load /vendor/nats-core.min.js?v={version} (clients/nats/vendor/VERSION)"
        );
        let package: serde_json::Value =
            serde_json::from_str(include_str!("../../clients/nats/package.json")).unwrap();
        assert_eq!(
            package["devDependencies"]["@nats-io/nats-core"], version,
            "package.json pins another NATS client than vendor/ holds: run clients/nats/vendor.sh"
        );
        assert!(
            VENDOR[0].2.contains("wsconnect"),
            "the bundle exports wsconnect"
        );
        for pkg in [
            "@nats-io/nats-core",
            "@nats-io/nkeys",
            "@nats-io/nuid",
            "tweetnacl",
        ] {
            assert!(VENDOR[1].2.contains(pkg), "the licence file lacks {pkg}");
        }
    }

    #[tokio::test]
    async fn vendored_files_have_their_types_and_cache_headers() {
        let get = |file: &str, v: Option<&str>| {
            vendor(
                Path(file.to_string()),
                Query(demo::AssetQuery {
                    v: v.map(Into::into),
                }),
            )
        };
        let header = |r: &Response, h| r.headers()[h].to_str().unwrap().to_string();
        let client = get("nats-core.min.js", Some(NATS_CLIENT_VERSION.trim())).await;
        assert_eq!(client.status(), StatusCode::OK);
        assert_eq!(
            header(&client, header::CONTENT_TYPE),
            "text/javascript; charset=utf-8"
        );
        assert_eq!(header(&client, header::CACHE_CONTROL), demo::FOREVER);
        let stale = get("nats-core.min.js", Some("0.0.1")).await;
        assert_eq!(header(&stale, header::CACHE_CONTROL), demo::NO_CACHE);
        let licence = get("NATS-LICENSE.txt", None).await;
        assert_eq!(
            header(&licence, header::CONTENT_TYPE),
            "text/plain; charset=utf-8"
        );
        for missing in ["../Cargo.toml", "three.module.min.js", "VERSION"] {
            assert_eq!(get(missing, None).await.status(), StatusCode::NOT_FOUND);
        }
    }
}
