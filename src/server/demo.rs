//! `GET /demo` and `GET /demo/{file}`: the three.js demo page (clients/three/demo), the client
//! module it runs (clients/three/vemlight-three.js) and three.js itself, vendored by
//! clients/three/vendor.sh.
//!
//! The files are embedded in the binary, so the daemon serves the page with no network and no
//! npm at build time (DESIGN.md "Processes and endpoints"). Static pages need no token; the page
//! passes its own `?access_token=` on to the stream, as the live view at `/` does. The page and
//! the module change with the daemon and carry `no-cache`; three.js is asked for under its version
//! (`?v=`), so that URL is cached for good.

use axum::extract::{Path, Query};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

const PAGE: &str = include_str!("../../clients/three/demo/index.html");

/// The vendored three.js version (clients/three/vendor/VERSION), the `?v=` of its cacheable URL.
pub const THREE_VERSION: &str = include_str!("../../clients/three/vendor/VERSION");

/// The files under `/demo/`: name, content type, body.
const ASSETS: [(&str, &str, &str); 4] = [
    (
        "demo.js",
        "text/javascript; charset=utf-8",
        include_str!("../../clients/three/demo/demo.js"),
    ),
    (
        "vemlight-three.js",
        "text/javascript; charset=utf-8",
        include_str!("../../clients/three/vemlight-three.js"),
    ),
    (
        "three.module.min.js",
        "text/javascript; charset=utf-8",
        include_str!("../../clients/three/vendor/three.module.min.js"),
    ),
    (
        "THREE-LICENSE.txt",
        "text/plain; charset=utf-8",
        include_str!("../../clients/three/vendor/LICENSE"),
    ),
];

pub(super) const NO_CACHE: &str = "no-cache";
pub(super) const FOREVER: &str = "public, max-age=31536000, immutable";

/// `GET /demo`.
pub async fn page() -> Response {
    respond("text/html; charset=utf-8", NO_CACHE, PAGE)
}

/// The query of `/demo/{file}` and `/vendor/{file}`: only `?v=`, a vendored library's version,
/// matters.
#[derive(Debug, Deserialize)]
pub struct AssetQuery {
    pub(super) v: Option<String>,
}

/// `GET /demo/{file}`: one of [`ASSETS`], or 404.
pub async fn asset(Path(file): Path<String>, Query(q): Query<AssetQuery>) -> Response {
    let Some(&(_, content_type, body)) = ASSETS.iter().find(|(name, _, _)| *name == file) else {
        return StatusCode::NOT_FOUND.into_response();
    };
    // Versioned three.js never changes under its URL; anything else may change with the daemon.
    let cache = if file == "three.module.min.js" && q.v.as_deref() == Some(THREE_VERSION.trim()) {
        FOREVER
    } else {
        NO_CACHE
    };
    respond(content_type, cache, body)
}

pub(super) fn respond(
    content_type: &'static str,
    cache: &'static str,
    body: &'static str,
) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
            (header::CACHE_CONTROL, HeaderValue::from_static(cache)),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
        ],
        body,
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every `/demo/…` URL the page and its script load is served, and the page asks for the
    /// vendored three.js under the version that makes it cacheable.
    #[test]
    fn the_page_loads_only_what_is_served() {
        let version = THREE_VERSION.trim();
        assert!(
            PAGE.contains(&format!("/demo/three.module.min.js?v={version}")),
            "index.html's import map must name three.js {version} (clients/three/vendor/VERSION)"
        );
        let mut referenced = 0;
        for text in [PAGE, ASSETS[0].2] {
            for (at, _) in text.match_indices("/demo/") {
                let name: String = text[at + 6..]
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'))
                    .collect();
                if name.is_empty() {
                    continue;
                }
                assert!(
                    ASSETS.iter().any(|(n, _, _)| *n == name),
                    "/demo/{name} is loaded but not served"
                );
                referenced += 1;
            }
        }
        assert!(referenced >= 3, "{referenced}");
        let package: serde_json::Value =
            serde_json::from_str(include_str!("../../clients/three/package.json")).unwrap();
        assert_eq!(
            package["devDependencies"]["three"], version,
            "package.json pins another three.js than vendor/ holds: run clients/three/vendor.sh"
        );
    }

    #[tokio::test]
    async fn assets_have_their_types_and_cache_headers() {
        let get = |file: &str, v: Option<&str>| {
            asset(
                Path(file.to_string()),
                Query(AssetQuery {
                    v: v.map(Into::into),
                }),
            )
        };
        let header = |r: &Response, h| r.headers()[h].to_str().unwrap().to_string();
        let page = page().await;
        assert_eq!(
            header(&page, header::CONTENT_TYPE),
            "text/html; charset=utf-8"
        );
        assert_eq!(header(&page, header::CACHE_CONTROL), NO_CACHE);
        let three = get("three.module.min.js", Some(THREE_VERSION.trim())).await;
        assert_eq!(three.status(), StatusCode::OK);
        assert_eq!(
            header(&three, header::CONTENT_TYPE),
            "text/javascript; charset=utf-8"
        );
        assert_eq!(header(&three, header::CACHE_CONTROL), FOREVER);
        let unversioned = get("three.module.min.js", None).await;
        assert_eq!(header(&unversioned, header::CACHE_CONTROL), NO_CACHE);
        let module = get("vemlight-three.js", Some(THREE_VERSION.trim())).await;
        assert_eq!(header(&module, header::CACHE_CONTROL), NO_CACHE);
        assert_eq!(
            get("../Cargo.toml", None).await.status(),
            StatusCode::NOT_FOUND
        );
        assert_eq!(
            get("index.html", None).await.status(),
            StatusCode::NOT_FOUND
        );
    }
}
