//! The product routes `GET /v1/sun|sky|ground|aerial`: query → request (with the deployment's
//! defaults) → body from the response cache, the product cache or one computation.

use super::super::extract::Query;
use super::super::problem::ApiError;
use super::super::AppState;
use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use skybake_product::params::RequestParams;
use skybake_product::ProductKind;

/// `Cache-Control` of artifacts that never change.
pub const IMMUTABLE: &str = "public, max-age=31536000, immutable";

/// `Cache-Control` of product responses: the same URL gives the same bytes until the deployment's
/// defaults or the engine change (the ETag, the cache key, tells), so a day's freshness and then a
/// conditional request.
pub const PRODUCT: &str = "public, max-age=86400";

/// `GET /v1/{product}`.
pub fn route(kind: ProductKind) -> axum::routing::MethodRouter<AppState> {
    axum::routing::get(
        move |State(state): State<AppState>,
              headers: HeaderMap,
              Query(params): Query<RequestParams>| {
            product(state, kind, params, headers)
        },
    )
}

/// Whether an `If-None-Match` header value matches `etag` (RFC 9110 §13.1.2: weak comparison,
/// a list of tags or `*`).
pub fn none_match(header: &str, etag: &str) -> bool {
    let bare = |t: &str| t.trim().trim_start_matches("W/").to_string();
    header
        .split(',')
        .any(|t| t.trim() == "*" || bare(t) == bare(etag))
}

async fn product(
    state: AppState,
    kind: ProductKind,
    params: RequestParams,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let mut req = state.request(kind, params)?;
    // A PNG is RGB-only (the planner may run fewer wavelengths), unless the spectral artifact
    // of the request is cached already.
    if req.rgb_only.is_some() {
        let spectral = req.clone().without_rgb_only()?;
        if state.cache().contains(&spectral.cache_key()) {
            req = spectral;
        }
    }
    // The ETag is the cache key and the format, known before anything is computed: a client that
    // holds it gets 304 at once.
    let etag = format!("\"{}-{}\"", req.cache_key(), req.format.name());
    if let Some(inm) = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
    {
        if none_match(inm, &etag) {
            let mut resp = StatusCode::NOT_MODIFIED.into_response();
            let h = resp.headers_mut();
            if let Ok(v) = HeaderValue::from_str(&etag) {
                h.insert(header::ETAG, v);
            }
            h.insert(header::CACHE_CONTROL, HeaderValue::from_static(PRODUCT));
            return Ok(resp);
        }
    }
    let (body, source, key) = state.body(&req).await?;
    let mut resp = super::artifact_response(body, req.format.content_type(), source, &key);
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(PRODUCT));
    Ok(resp)
}
