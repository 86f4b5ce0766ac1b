//! `POST /v1/lights`: a raw EXR or Radiance HDR body in, the LightSet `vemlight lights` prints
//! for that file out (DESIGN.md "Processes and endpoints"; README.md "The capture daemon" has the
//! status codes).
//!
//! An upload is untrusted input arriving over a socket, so each step is bounded before it costs
//! anything: parameters are checked before the body is read; the declared length against
//! `--max-body`, and room in a shared buffer budget is reserved, before a byte is buffered; a body
//! that stalls or trickles is answered 408; one that is not an EXR or HDR is refused 415 from its
//! first bytes; the image header's size is checked before decoding. Decoding and extraction run on
//! blocking threads, `--post-workers` at a time, with a pool of extractors whose cached tables make
//! repeated same-size uploads cheap. A refused body is drained a little (unless the client sent
//! `Expect: 100-continue`), so that a client still sending reads the answer.

use super::error::ApiError;
use super::handlers::json_response;
use super::query::{Params, UploadQuery};
use super::state::AppState;
use crate::envmap::{Decoding, EnvMap, Projection};
use crate::lightset::{LightRequest, lightset_for_map, now_ns};
use crate::metrics::Metrics;
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, header};
use axum::response::Response;
use futures_util::StreamExt;
use std::time::{Duration, Instant};

/// `POST /v1/lights`: a raw EXR or Radiance HDR body → the same LightSet `vemlight lights` gives.
///
/// The query is taken as a `Result` so that a bad one is counted in
/// `vemlight_http_lights_errors_total` and its body drained, like every other refusal.
pub(super) async fn post_lights(
    query: Result<Params<UploadQuery>, ApiError>,
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let metrics = state.hub.metrics.clone();
    Metrics::inc(&metrics.http_lights_requests);
    let result = post_lights_inner(query, &state, &headers, body).await;
    if result.is_err() {
        Metrics::inc(&metrics.http_lights_errors);
    }
    result
}

async fn post_lights_inner(
    query: Result<Params<UploadQuery>, ApiError>,
    state: &AppState,
    headers: &HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let t = Instant::now();
    let mut stream = body.into_data_stream();
    // Parameters first: a bad request is refused without reading its body (the drain only lets
    // a client that is still sending read the answer).
    let (req, projection) = match upload_request(query, headers) {
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
    query: Result<Params<UploadQuery>, ApiError>,
    headers: &HeaderMap,
) -> Result<(LightRequest, Option<Projection>), ApiError> {
    let Params(q) = query?;
    let req = LightRequest {
        lights: q.lights.unwrap_or(64),
        domain: q.domain,
        method: q.method.unwrap_or_default(),
        max_error: q.max_error,
        estimate_error: true,
        sh9: true,
    };
    req.validate().map_err(ApiError::BadRequest)?;
    acceptable_content_type(headers)?;
    Ok((req, q.projection))
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
