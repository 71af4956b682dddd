//! The router, built from the route table ([`super::openapi::ROUTES`]): one module per concern
//! (products, texture bundles, render, scenes, plan, jobs, operations), the overload layers (load shedding, concurrency limit,
//! timeout) on `/v1/*`, and the per-route metrics and tracing middleware on all.

mod jobs;
mod lut;
mod ops;
mod plan;
mod products;
pub(super) mod render;
mod scenes;

use super::openapi::{Route, ROUTES};
use super::problem::ApiError;
use super::AppState;
use axum::error_handling::HandleErrorLayer;
use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, post};
use axum::{BoxError, Router};
use skybake_product::ProductKind;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tower::ServiceBuilder;
use tracing::Instrument;

async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::NotFound(format!("no route {}; see /openapi.json", uri.path()))
}

/// Whether `path` matches the route pattern `pattern` (`{name}` matches one segment).
fn matches(pattern: &str, path: &str) -> bool {
    let (p, q): (Vec<&str>, Vec<&str>) = (pattern.split('/').collect(), path.split('/').collect());
    p.len() == q.len()
        && p.iter()
            .zip(&q)
            .all(|(a, b)| a == b || (a.starts_with('{') && !b.is_empty()))
}

/// 405 as problem+json, with the `Allow` header and the methods the path takes.
async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> Response {
    let allowed: Vec<&str> = ROUTES
        .iter()
        .filter(|r| matches(r.path, uri.path()))
        .map(|r| r.method)
        .collect();
    let list = allowed.join(", ");
    let mut resp = ApiError::MethodNotAllowed(format!(
        "{method} is not allowed on {}; allowed: {list}",
        uri.path()
    ))
    .into_response();
    if let Ok(v) = axum::http::HeaderValue::from_str(&list) {
        resp.headers_mut().insert(axum::http::header::ALLOW, v);
    }
    resp
}

async fn handle_overload(state: AppState, err: BoxError) -> ApiError {
    if err.is::<tower::timeout::error::Elapsed>() {
        state.metrics().timeouts.fetch_add(1, Ordering::Relaxed);
        ApiError::Timeout
    } else if err.is::<tower::load_shed::error::Overloaded>() {
        state.metrics().load_shed.fetch_add(1, Ordering::Relaxed);
        ApiError::Overloaded
    } else {
        ApiError::Internal(format!("middleware: {err}"))
    }
}

async fn record(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let start = Instant::now();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_string())
        .unwrap_or_else(|| "unmatched".into());
    let method = req.method().clone();
    let span = tracing::info_span!("request", %method, route = %route, uri = %req.uri());
    let resp = next.run(req).instrument(span.clone()).await;
    let elapsed = start.elapsed();
    tracing::info!(parent: &span, status = resp.status().as_u16(), elapsed_ms = elapsed.as_secs_f64() * 1e3, "done");
    state
        .metrics()
        .observe(&route, method.as_str(), resp.status().as_u16(), elapsed);
    resp
}

fn method_router(route: &Route) -> axum::routing::MethodRouter<AppState> {
    match (route.method, route.path) {
        ("GET", "/v1/sun") => products::route(ProductKind::Sun),
        ("GET", "/v1/sky") => products::route(ProductKind::Sky),
        ("GET", "/v1/ground") => products::route(ProductKind::Ground),
        ("GET", "/v1/aerial") => products::route(ProductKind::Aerial),
        ("POST", "/v1/plan") => post(plan::plan),
        ("POST", "/v1/render") => post(render::render),
        ("GET", "/v1/scenes") => get(scenes::list),
        ("GET", "/v1/scenes/{name}") => get(scenes::scene),
        ("POST", "/v1/jobs") => post(jobs::submit),
        ("GET", "/v1/jobs") => get(jobs::list),
        ("GET", "/v1/atmospheres") => get(ops::atmospheres),
        ("GET", "/v1/lut") => get(lut::manifest),
        ("GET", "/v1/lut/files/{key}") => get(lut::file),
        ("GET", "/v1/jobs/{id}") => get(jobs::status),
        ("DELETE", "/v1/jobs/{id}") => delete(jobs::cancel),
        ("GET", "/v1/jobs/{id}/artifacts/{n}") => get(jobs::artifact),
        ("GET", "/") => get(super::viewer::index),
        ("GET", "/assets/{file}") => get(super::viewer::asset),
        ("GET", "/healthz") => get(ops::healthz),
        ("GET", "/metrics") => get(ops::metrics),
        ("GET", "/openapi.json") => get(ops::openapi),
        // ROUTES and this table are checked against each other by a test.
        _ => get(not_found),
    }
}

/// The size of a request's head as sent: the request line and every header line (`name: value`,
/// the one space clients send after the colon) with their CRLFs, and the empty line.
fn head_bytes(req: &axum::extract::Request) -> usize {
    let line = req.method().as_str().len() + 1 + req.uri().to_string().len() + 1 + 8 + 2;
    let headers: usize = req
        .headers()
        .iter()
        .map(|(k, v)| k.as_str().len() + 2 + v.len() + 2)
        .sum();
    line + headers + 2
}

/// Refuses (431) a request head over [`super::conn::MAX_HEAD_BYTES`]: hyper checks its read
/// buffer's limit only when the buffer is full between two reads, so a head that arrives in a
/// buffer grown past the limit is parsed; this makes the documented limit exact.
async fn head_limit(req: axum::extract::Request, next: Next) -> Response {
    let size = head_bytes(&req);
    if size > super::conn::MAX_HEAD_BYTES {
        return ApiError::from(crate::Error::too_large(
            "headers",
            format!("the request head is {size} bytes"),
            format!("{} bytes", super::conn::MAX_HEAD_BYTES),
        ))
        .into_response();
    }
    next.run(req).await
}

/// The service router: every route of [`ROUTES`], the limits on `/v1/*`, metrics and tracing on all.
pub fn app(state: AppState) -> Router {
    let settings = state.settings().clone();
    let timeout = Duration::from_secs_f64(settings.server.request_timeout_s);
    let mut limited: Router<AppState> = Router::new();
    let mut open: Router<AppState> = Router::new();
    for route in ROUTES {
        if route.limited {
            limited = limited.route(route.path, method_router(route));
        } else {
            open = open.route(route.path, method_router(route));
        }
    }
    let s = state.clone();
    let limited = limited.layer(
        ServiceBuilder::new()
            .layer(HandleErrorLayer::new(move |err: BoxError| {
                handle_overload(s.clone(), err)
            }))
            .load_shed()
            // Global: one semaphore for all limited routes (a per-route limit would multiply it).
            .layer(tower::limit::GlobalConcurrencyLimitLayer::new(
                settings.server.concurrency_limit,
            ))
            .timeout(timeout),
    );
    // Bodies are read whole before a request takes a concurrency slot (a slow upload holds none),
    // and the rate limit answers before a body is read or the shedder counts a request.
    let limited = limited
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            super::body::buffer_body,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            super::limits::rate_limit,
        ));
    limited
        .merge(open)
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(settings.server.body_limit_bytes))
        .layer(axum::Extension(super::extract::BodyLimit(
            settings.server.body_limit_bytes,
        )))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            super::limits::authenticate,
        ))
        // JSON (and text) bodies compressed when the client accepts gzip or br; images are not.
        .layer(tower_http::compression::CompressionLayer::new())
        .layer(axum::middleware::from_fn(head_limit))
        .layer(axum::middleware::from_fn_with_state(state.clone(), record))
        .with_state(state)
}

/// A product body with its content type, where it came from (`x-cache`) and its cache key
/// (`x-skybake-cache-key`); callers add their validators and caching headers.
fn artifact_response(
    body: bytes::Bytes,
    content_type: &'static str,
    source: super::Source,
    key: &str,
) -> Response {
    use axum::http::{header, HeaderValue};
    let mut resp = body.into_response();
    let h = resp.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    h.insert("x-cache", HeaderValue::from_static(source.header()));
    if let Ok(v) = HeaderValue::from_str(key) {
        h.insert("x-skybake-cache-key", v);
    }
    resp
}
