//! The one error type of the HTTP API, turned into an RFC 9457 `application/problem+json` response
//! in one place.

use crate::envmap::InputError;
use axum::extract::rejection::QueryRejection;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

/// Every way a request can fail, each with its status code.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// 400: a parameter is missing, malformed or out of range.
    #[error("{0}")]
    BadRequest(String),
    /// 404: no such path (the endpoints are listed in docs/API.md).
    #[error("{0}")]
    NotFound(String),
    /// 405: the path exists, the method does not (the `Allow` header lists those that do).
    #[error("{0}")]
    MethodNotAllowed(String),
    /// 401: the bearer token is missing or wrong.
    #[error("a valid 'Authorization: Bearer' token is required")]
    Unauthorized,
    /// 408: the upload stalled or took too long.
    #[error("{0}")]
    Timeout(String),
    /// 413: the body or the image it holds is larger than allowed.
    #[error("{0}")]
    TooLarge(String),
    /// 415: the body is not an OpenEXR or Radiance HDR file.
    #[error("{0}")]
    UnsupportedMedia(String),
    /// 422: an EXR/HDR that cannot be decoded or used (corrupt, wrong aspect, …).
    #[error("{0}")]
    Unprocessable(String),
    /// 503: nothing to serve yet, or the daemon is busy.
    #[error("{0}")]
    Unavailable(String),
    /// 503 with `Retry-After`: a cap on what the daemon serves at once is reached (WebSocket
    /// clients, light counts asked for only by `/v1/lights/latest`); the same request may succeed
    /// after `retry_after_s`.
    #[error("{detail}")]
    AtCapacity { detail: String, retry_after_s: u32 },
    /// 400, 405 or 426 (as axum's handshake check says): `/v1/stream` asked for without a
    /// WebSocket handshake.
    #[error("{1}")]
    NotWebSocket(StatusCode, String),
    /// 500: a bug; details are logged, not sent.
    #[error("internal error: {0}")]
    Internal(String),
}

impl From<InputError> for ApiError {
    fn from(e: InputError) -> Self {
        match e {
            InputError::UnsupportedFormat(_) => ApiError::UnsupportedMedia(e.to_string()),
            InputError::TooLarge { .. } => ApiError::TooLarge(e.to_string()),
            InputError::Corrupt { .. } | InputError::Unusable(_) => {
                ApiError::Unprocessable(e.to_string())
            }
        }
    }
}

/// A query string that does not fit an endpoint's query struct (src/server/query.rs): 400, with
/// serde's account of it, which starts with the parameter's name (`lights: invalid digit found in
/// string`, ``light: unknown field `light`, expected one of `lights`, `max_hz`…``).
impl From<QueryRejection> for ApiError {
    fn from(rejection: QueryRejection) -> Self {
        let cause = std::error::Error::source(&rejection)
            .map_or_else(|| rejection.body_text(), ToString::to_string);
        ApiError::BadRequest(format!("query parameter {cause}"))
    }
}

impl ApiError {
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ApiError::Unauthorized => StatusCode::UNAUTHORIZED,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::MethodNotAllowed(_) => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::UnsupportedMedia(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ApiError::Unprocessable(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::Unavailable(_) | ApiError::AtCapacity { .. } => {
                StatusCode::SERVICE_UNAVAILABLE
            }
            ApiError::Timeout(_) => StatusCode::REQUEST_TIMEOUT,
            ApiError::NotWebSocket(status, _) => *status,
            ApiError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let detail = match &self {
            ApiError::Internal(d) => {
                tracing::error!("internal error: {d}");
                "Something went wrong".to_string()
            }
            other => other.to_string(),
        };
        let body = serde_json::json!({
            "type": "about:blank",
            "title": status.canonical_reason().unwrap_or("Error"),
            "status": status.as_u16(),
            "detail": detail,
        });
        let mut resp = (status, body.to_string()).into_response();
        resp.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/problem+json"),
        );
        if let ApiError::AtCapacity { retry_after_s, .. } = &self {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(*retry_after_s));
        }
        if matches!(self, ApiError::Unauthorized) {
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"vemlight\""),
            );
        }
        resp
    }
}
