//! `POST /v1/render`: a frame scene in the body → the cloud frame, as EXR (the
//! artifact), PNG (tone-mapped preview; an RGB-only request, which the planner may run at fewer
//! wavelengths) or JSON (stages, timings, error estimate). Cached like
//! every product under the frame request's cache key, computed through the same single flight and
//! compute slots, and rendered tile by tile into the tile store, so an interrupted render resumes
//! (see [`AppState::artifact_of`]).

use super::super::extract::{FromQuery, Query};
use super::super::problem::ApiError;
use super::super::AppState;
use axum::body::{Body, Bytes, HttpBody};
use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use skybake_physics::cloud::scene::MAX_SCENE_FILE_BYTES;
use skybake_product::frame::FrameRequest;
use skybake_product::{AnyRequest, Format};
use skybake_render::Method;
use std::sync::Arc;

/// The formats of a frame.
pub const FRAME_FORMATS: &[Format] = &[Format::Json, Format::Exr, Format::Png];

/// `format` and `method` of a render.
pub struct RenderQuery {
    pub format: Option<String>,
    pub method: Option<String>,
    /// The frame's target relative error (`FrameRequest::with_max_rel_error`).
    pub max_rel_error: Option<String>,
}

impl FromQuery for RenderQuery {
    fn from_pairs(pairs: Vec<(String, String)>) -> Result<Self, ApiError> {
        let mut q = RenderQuery {
            format: None,
            method: None,
            max_rel_error: None,
        };
        let mut unknown = Vec::new();
        for (k, v) in pairs {
            let slot = match k.as_str() {
                "format" => &mut q.format,
                "method" => &mut q.method,
                "max_rel_error" => &mut q.max_rel_error,
                _ => {
                    unknown.push(k);
                    continue;
                }
            };
            if slot.replace(v).is_some() {
                return Err(crate::Error::invalid(&k, "given more than once").into());
            }
        }
        if unknown.is_empty() {
            Ok(q)
        } else {
            Err(ApiError::UnknownParameters(unknown))
        }
    }
}

/// The body format: `format=` if given, else the first of EXR, PNG, JSON the `Accept` header
/// names, else JSON.
pub fn frame_format(query: Option<&str>, accept: Option<&str>) -> Result<Format, ApiError> {
    if let Some(text) = query {
        return FRAME_FORMATS
            .iter()
            .copied()
            .find(|f| f.name() == text.trim())
            .ok_or_else(|| {
                crate::Error::invalid(
                    "format",
                    format!(
                        "'{text}' is not a format of the frame product (allowed: json, exr, png)"
                    ),
                )
                .into()
            });
    }
    let accept = accept.unwrap_or("");
    Ok(if accept.contains("image/x-exr") {
        Format::Exr
    } else if accept.contains("image/png") {
        Format::Png
    } else {
        Format::Json
    })
}

/// Most bytes of a scene body: the smaller of the server's body limit and the scene file limit.
fn body_limit(state: &AppState) -> usize {
    state
        .settings()
        .server
        .body_limit_bytes
        .min(MAX_SCENE_FILE_BYTES)
}

fn too_large(limit: usize, what: String) -> ApiError {
    crate::Error::too_large(
        "body",
        format!("the scene is {what}"),
        format!("{limit} bytes"),
    )
    .into()
}

/// Reads the body, refusing (413, stating the limit) more than `limit` bytes before buffering
/// them: a declared length is checked first, then the bytes as they arrive.
async fn read_body(headers: &HeaderMap, mut body: Body, limit: usize) -> Result<Bytes, ApiError> {
    if let Some(len) = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
    {
        if len > limit as u64 {
            return Err(too_large(limit, format!("{len} bytes (content-length)")));
        }
    }
    let mut buf = Vec::new();
    while let Some(frame) =
        std::future::poll_fn(|cx| std::pin::Pin::new(&mut body).poll_frame(cx)).await
    {
        let frame = frame.map_err(|e| ApiError::Body {
            status: StatusCode::BAD_REQUEST,
            detail: format!("reading the body failed: {e}"),
        })?;
        if let Ok(data) = frame.into_data() {
            if buf.len() + data.len() > limit {
                return Err(too_large(limit, format!("over {limit} bytes")));
            }
            buf.extend_from_slice(&data);
        }
    }
    Ok(Bytes::from(buf))
}

/// `POST /v1/render?format=exr|png|json&method=fast|reference&max_rel_error=E` with the scene
/// JSON as the body.
pub async fn render(
    State(state): State<AppState>,
    Query(q): Query<RenderQuery>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let format = frame_format(
        q.format.as_deref(),
        headers.get(header::ACCEPT).and_then(|v| v.to_str().ok()),
    )?;
    let method = Method::parse(q.method.as_deref().unwrap_or("fast"))?;
    let bytes = read_body(&headers, body, body_limit(&state)).await?;
    // Parsing validates every limit of the scene before anything is allocated for it.
    let target = q.max_rel_error;
    let req = AppState::blocking(move || {
        let req = FrameRequest::parse(&bytes, method)?.with_max_rel_error(target.as_deref())?;
        // A scene may name only the example scenes' files: refused before anything is computed.
        req.check_files(&skybake_product::frame::example_file)?;
        Ok(req)
    })
    .await?;
    // A PNG is RGB-only: the planner may run fewer wavelengths (its own cache key), unless the
    // spectral frame of the request is cached already (its RGB is at every wavelength).
    let rgb_only = format == Format::Png && !state.cache().contains(&req.cache_key());
    // Held to the frame caps again once a cloud whose size only voxelising tells is voxelised.
    let req = req
        .with_rgb_only(rgb_only)
        .with_caps(Some(state.frame_caps()));
    // The ETag (cache key and format) is known before anything is computed: a client that holds
    // it gets 304 at once, as for the GET products.
    let etag = frame_etag(&req.cache_key(), format);
    if let Some(inm) = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
    {
        if super::products::none_match(inm, &etag) {
            let mut resp = StatusCode::NOT_MODIFIED.into_response();
            let h = resp.headers_mut();
            if let Ok(v) = HeaderValue::from_str(&etag) {
                h.insert(header::ETAG, v);
            }
            h.insert(
                header::CACHE_CONTROL,
                HeaderValue::from_static(super::products::PRODUCT),
            );
            return Ok(resp);
        }
    }
    frame_response(&state, Arc::new(req), format).await
}

/// The ETag of a frame body: its cache key and format.
fn frame_etag(key: &str, format: Format) -> String {
    format!("\"{key}-{}\"", format.name())
}

/// The response of a frame request in `format` (through the one response path of every
/// product, [`AppState::respond`]).
pub async fn frame_response(
    state: &AppState,
    req: Arc<FrameRequest>,
    format: Format,
) -> Result<Response, ApiError> {
    let (body, source, key) = state.respond(&AnyRequest::Frame(req), format).await?;
    let mut resp = body.into_response();
    let h = resp.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(format.content_type()),
    );
    h.insert("x-cache", HeaderValue::from_static(source.header()));
    if let Ok(v) = HeaderValue::from_str(&key) {
        h.insert("x-skybake-cache-key", v);
    }
    if let Ok(v) = HeaderValue::from_str(&frame_etag(&key, format)) {
        h.insert(header::ETAG, v);
    }
    // The same scene and method give the same bytes until the engine changes (the key tells).
    h.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static(super::products::PRODUCT),
    );
    Ok(resp)
}
