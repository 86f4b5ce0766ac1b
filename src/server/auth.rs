//! The bearer token check of `vemlight serve --token` (README.md "The capture daemon"): with a
//! token set, every endpoint but `GET /` (a static page) and `GET /healthz` (for probes) asks for
//! `Authorization: Bearer <token>`; without one they are open.
//!
//! A middleware rather than an extractor, so that no handler can forget it: [`super::app`] puts
//! it on the protected routes as one `route_layer`.

use super::error::ApiError;
use super::state::AppState;
use axum::extract::{Query, Request, State};
use axum::http::header;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::collections::HashMap;

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
pub(super) async fn require_token(
    State(state): State<AppState>,
    req: Request,
    next: Next,
) -> Response {
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

/// Whether `a == b`, in a time that depends on their lengths only, not on where they differ.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}
