//! The query parameters of every endpoint that takes them, one typed struct each (DESIGN.md
//! "Processes and endpoints"; README.md "The capture daemon" lists them).
//!
//! Each struct denies unknown fields, so a typo (`?light=16`) is a 400 naming it rather than a
//! parameter silently ignored; a value of the wrong type (`?lights=abc`) is a 400 naming the
//! parameter too. Both come through [`Params`], whose rejection is the API's one error type
//! (`From<QueryRejection> for ApiError`, src/server/error.rs). Ranges (light counts, `max_hz`,
//! `max_error`) are checked by the handlers, which know the limits.
//!
//! No struct may use `#[serde(flatten)]`: serde does not deny unknown fields through it.

use super::error::ApiError;
use crate::envmap::Projection;
use crate::lights::Method;
use crate::mapping::Domain;
use axum::extract::{FromRequestParts, Query};
use serde::Deserialize;
use serde::de::{Deserializer, IgnoredAny};

/// The query string of a request as `T`; refused with a 400 problem document that names the
/// unknown or malformed parameter.
#[derive(Debug, FromRequestParts)]
#[from_request(via(Query), rejection(ApiError))]
pub struct Params<T>(pub T);

/// `GET /v1/stream`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StreamQuery {
    /// Lights per set (1 to `N_MAX`); the daemon's `--lights` when absent.
    pub lights: Option<usize>,
    /// The most sets a second this client is sent (at least `MIN_MAX_HZ`); every set when absent.
    pub max_hz: Option<f64>,
    /// The fewest lights (at most `lights`) whose estimated diffuse error is at most this.
    pub max_error: Option<f64>,
    /// The client's shadow budget: this many lights marked `shadowed`, the rest also as SH.
    pub shadowed: Option<usize>,
    /// The bearer token of a browser client, whose WebSocket cannot send headers: checked by
    /// `auth::require_token` before the handler runs, declared here so that it is not refused.
    #[serde(rename = "access_token")]
    _access_token: Option<IgnoredAny>,
}

/// `GET /v1/lights/latest`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LatestQuery {
    /// Lights per set; the daemon's `--lights` when absent.
    pub lights: Option<usize>,
    /// As on the stream ([`StreamQuery::max_error`]).
    pub max_error: Option<f64>,
    /// As on the stream ([`StreamQuery::shadowed`]).
    pub shadowed: Option<usize>,
}

/// `POST /v1/lights`: the options of `vemlight lights`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadQuery {
    /// Lights in the answer (1 to `N_MAX`); 64 when absent.
    pub lights: Option<usize>,
    /// How the uploaded map is laid out; guessed from its aspect when absent.
    #[serde(default, deserialize_with = "projection")]
    pub projection: Option<Projection>,
    /// `upper` (or `hemisphere`) or `sphere`; from the projection when absent.
    #[serde(default, deserialize_with = "from_str")]
    pub domain: Option<Domain>,
    /// The extraction method (`voronoi`, `median-cut`, …); the default method when absent.
    #[serde(default, deserialize_with = "from_str")]
    pub method: Option<Method>,
    /// Fewest lights whose estimated diffuse error is at most this, up to `lights`.
    pub max_error: Option<f64>,
}

/// A parameter read by its type's `FromStr`, so that the query takes the names and aliases the
/// CLI takes (`hemisphere` for `upper`, `kmeans` for `k-means`) and says what it expected.
fn from_str<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: std::str::FromStr,
    T::Err: std::fmt::Display,
{
    let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
    s.parse().map(Some).map_err(serde::de::Error::custom)
}

/// A projection by the names `Projection::parse` takes.
fn projection<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Projection>, D::Error> {
    let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
    Projection::parse(&s)
        .map(Some)
        .map_err(serde::de::Error::custom)
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::{StatusCode, Uri};

    fn parse<T: serde::de::DeserializeOwned>(query: &str) -> Result<T, ApiError> {
        let uri: Uri = format!("/x?{query}").parse().unwrap();
        Ok(Query::<T>::try_from_uri(&uri)?.0)
    }

    /// The 400's detail for `query` read as `T`.
    fn refusal<T: serde::de::DeserializeOwned + std::fmt::Debug>(query: &str) -> String {
        let e = parse::<T>(query).unwrap_err();
        assert_eq!(e.status(), StatusCode::BAD_REQUEST, "{query}: {e}");
        e.to_string()
    }

    #[test]
    fn known_parameters_are_read() {
        let q: StreamQuery = parse("lights=8&max_hz=0.5&access_token=t").unwrap();
        assert_eq!((q.lights, q.max_hz), (Some(8), Some(0.5)));
        let q: UploadQuery =
            parse("lights=32&domain=hemisphere&method=kmeans&projection=latlong&max_error=0.1")
                .unwrap();
        assert_eq!(q.lights, Some(32));
        assert_eq!(q.domain, Some(Domain::Upper));
        assert_eq!(q.method, Some(Method::KMeans));
        assert_eq!(q.projection, Some(Projection::LatLong));
        assert_eq!(q.max_error, Some(0.1));
        let q: UploadQuery = parse("").unwrap();
        assert!(q.lights.is_none() && q.domain.is_none() && q.projection.is_none());
        let q: LatestQuery = parse("lights=9").unwrap();
        assert_eq!(q.lights, Some(9));
    }

    #[test]
    fn unknown_and_malformed_parameters_are_named() {
        for detail in [
            refusal::<StreamQuery>("light=16"),
            refusal::<LatestQuery>("light=16"),
            refusal::<UploadQuery>("light=16"),
        ] {
            assert!(detail.contains("light`"), "{detail}");
            assert!(detail.starts_with("query parameter light:"), "{detail}");
        }
        // The stream's token is the stream's alone.
        assert!(refusal::<LatestQuery>("access_token=t").contains("access_token"));
        for detail in [
            refusal::<StreamQuery>("lights=abc"),
            refusal::<LatestQuery>("lights=abc"),
            refusal::<UploadQuery>("lights=abc"),
            refusal::<UploadQuery>("lights=-1"),
        ] {
            assert!(detail.starts_with("query parameter lights:"), "{detail}");
        }
        assert!(refusal::<StreamQuery>("max_hz=fast").starts_with("query parameter max_hz:"));
        let detail = refusal::<UploadQuery>("method=magic");
        assert!(
            detail.contains("method") && detail.contains("'magic'"),
            "{detail}"
        );
        let detail = refusal::<UploadQuery>("domain=left");
        assert!(
            detail.contains("domain") && detail.contains("'left'"),
            "{detail}"
        );
        let detail = refusal::<UploadQuery>("projection=cube");
        assert!(
            detail.starts_with("query parameter projection:"),
            "{detail}"
        );
    }
}
