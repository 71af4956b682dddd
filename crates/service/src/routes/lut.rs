//! `GET /v1/lut?…`: the real-time texture bundle of an atmosphere (docs/lut.md) as its
//! manifest with a link to each texture, and `GET /v1/lut/files/{key}`: one texture (OpenEXR)
//! of a bundle whose manifest was requested. Both from the product cache as blob entries (the
//! bundle is computed once, in a compute slot, and its files stored); ETag = cache key, 304 on
//! `If-None-Match`; the manifest is compressed like other JSON, the textures are ZIP-compressed
//! EXR.

use super::super::extract::{NoParams, Query};
use super::super::problem::ApiError;
use super::super::AppState;
use super::products::{none_match, IMMUTABLE, PRODUCT};
use axum::extract::{Path as UrlPath, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use skybake_product::lut::LutRequest;
use skybake_product::params::RequestParams;

/// `304 Not Modified` with the validator and caching headers, when `headers` hold `etag`.
fn not_modified(headers: &HeaderMap, etag: &str, cache_control: &'static str) -> Option<Response> {
    let inm = headers.get(header::IF_NONE_MATCH)?.to_str().ok()?;
    if !none_match(inm, etag) {
        return None;
    }
    let mut resp = StatusCode::NOT_MODIFIED.into_response();
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static(cache_control),
    );
    Some(resp)
}

/// `GET /v1/lut`: the manifest (with `links`), computing and storing the bundle on a miss.
pub async fn manifest(
    State(state): State<AppState>,
    headers: HeaderMap,
    Query(params): Query<RequestParams>,
) -> Result<Response, ApiError> {
    let req = LutRequest::from_params(&state.lut_params(params))?;
    let key = req.cache_key();
    let etag = format!("\"{key}\"");
    if let Some(resp) = not_modified(&headers, &etag, PRODUCT) {
        return Ok(resp);
    }
    let (bytes, source) = state.lut(req).await?;
    let mut resp = super::artifact_response(
        bytes::Bytes::copy_from_slice(&bytes),
        "application/json",
        source,
        &key,
    );
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(PRODUCT));
    Ok(resp)
}

/// `GET /v1/lut/files/{key}`: a texture of a bundle (its key is in the manifest's `links`).
pub async fn file(
    State(state): State<AppState>,
    headers: HeaderMap,
    UrlPath(key): UrlPath<String>,
    Query(NoParams): Query<NoParams>,
) -> Result<Response, ApiError> {
    let etag = format!("\"{key}\"");
    if !skybake_store::cache::is_valid_key(&key) {
        return Err(ApiError::NotFound(format!(
            "no texture {key}: keys come from the links of GET /v1/lut"
        )));
    }
    if let Some(resp) = not_modified(&headers, &etag, IMMUTABLE) {
        return Ok(resp);
    }
    let (s, k) = (state.clone(), key.clone());
    let bytes = AppState::blocking(move || Ok(s.cache().get_blob(&k)?)).await?;
    let Some(bytes) = bytes else {
        return Err(ApiError::NotFound(format!(
            "no texture {key} in the cache: request its bundle's manifest (GET /v1/lut) first"
        )));
    };
    let mut resp = super::artifact_response(
        bytes::Bytes::copy_from_slice(&bytes),
        "image/x-exr",
        super::super::Source::Cache,
        &key,
    );
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(IMMUTABLE));
    Ok(resp)
}
