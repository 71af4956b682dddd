//! The router and its handlers: query/body parsing at the edge (unknown parameters refused), product
//! routes, plan, health, metrics and the OpenAPI document; the overload layers (load shedding,
//! concurrency limit, timeout) and the per-route metrics middleware.

use super::metrics::{counter, gauge};
use super::openapi::{openapi_json, Route, ROUTES};
use super::problem::ApiError;
use super::products::ProductKind;
use super::{jobs, AppState};
use crate::spec::RequestParams;
use axum::error_handling::HandleErrorLayer;
use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, post};
use axum::{BoxError, Router};
use serde_json::{json, Map, Value};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tower::ServiceBuilder;
use tracing::Instrument;

fn slot<'a>(p: &'a mut RequestParams, name: &str) -> Option<&'a mut Option<String>> {
    Some(match name {
        "sun_elevation_deg" => &mut p.sun_elevation_deg,
        "latitude_deg" => &mut p.latitude_deg,
        "longitude_deg" => &mut p.longitude_deg,
        "time" => &mut p.time,
        "observer_altitude_m" => &mut p.observer_altitude_m,
        "wavelengths" => &mut p.wavelengths,
        "atmosphere" => &mut p.atmosphere,
        "ground_albedo" => &mut p.ground_albedo,
        "method" => &mut p.method,
        "quality" => &mut p.quality,
        "elevation_count" => &mut p.elevation_count,
        "azimuth_count" => &mut p.azimuth_count,
        "distance_count" => &mut p.distance_count,
        "max_distance_m" => &mut p.max_distance_m,
        "probe" => &mut p.probe,
        "format" => &mut p.format,
        _ => return None,
    })
}

/// Most bytes of a query string.
const MAX_QUERY_BYTES: usize = 64 * 1024;

/// Parses a query string into request parameters; unknown or repeated names are refused.
pub fn parse_query(query: Option<&str>) -> Result<RequestParams, ApiError> {
    let mut p = RequestParams::default();
    let q = query.unwrap_or("");
    if q.len() > MAX_QUERY_BYTES {
        return Err(crate::Error::too_large(
            "query",
            format!("{} bytes", q.len()),
            MAX_QUERY_BYTES,
        )
        .into());
    }
    let mut unknown = Vec::new();
    for (k, v) in form_urlencoded::parse(q.as_bytes()) {
        match slot(&mut p, &k) {
            Some(s) if s.is_some() => {
                return Err(crate::Error::invalid(&k, "given more than once").into())
            }
            Some(s) => *s = Some(v.into_owned()),
            None => unknown.push(k.into_owned()),
        }
    }
    if unknown.is_empty() {
        Ok(p)
    } else {
        Err(ApiError::UnknownParameters(unknown))
    }
}

/// Request parameters from a JSON object (plan and job bodies): strings as given, numbers in their
/// JSON spelling, `wavelengths` also as an array of numbers, `atmosphere` also as an inline object.
/// Members named in `skip` are left for the caller; `prefix` goes in front of field names in errors.
pub fn params_from_object(
    obj: &Map<String, Value>,
    skip: &[&str],
    prefix: &str,
) -> Result<RequestParams, ApiError> {
    let mut p = RequestParams::default();
    let mut unknown = Vec::new();
    for (k, v) in obj {
        if skip.contains(&k.as_str()) {
            continue;
        }
        let field = format!("{prefix}{k}");
        let text = match (k.as_str(), v) {
            (_, Value::Null) => continue,
            (_, Value::String(s)) => s.clone(),
            (_, Value::Number(n)) => n.to_string(),
            ("atmosphere", Value::Object(_)) => v.to_string(),
            ("wavelengths", Value::Array(a)) if a.iter().all(Value::is_number) => a
                .iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(","),
            _ if slot(&mut RequestParams::default(), k).is_none() => {
                unknown.push(field);
                continue;
            }
            _ => return Err(crate::Error::invalid(&field, "must be a string or a number").into()),
        };
        match slot(&mut p, k) {
            Some(s) => *s = Some(text),
            None => unknown.push(field),
        }
    }
    if unknown.is_empty() {
        Ok(p)
    } else {
        Err(ApiError::UnknownParameters(unknown))
    }
}

/// Refuses any query parameter (routes that take none).
pub fn no_query(query: Option<&str>) -> Result<(), ApiError> {
    let names: Vec<String> = form_urlencoded::parse(query.unwrap_or("").as_bytes())
        .map(|(k, _)| k.into_owned())
        .collect();
    if names.is_empty() {
        Ok(())
    } else {
        Err(ApiError::UnknownParameters(names))
    }
}

/// Parses a JSON object body.
pub fn json_object(body: &[u8]) -> Result<Map<String, Value>, ApiError> {
    match serde_json::from_slice::<Value>(body) {
        Ok(Value::Object(m)) => Ok(m),
        Ok(_) => Err(ApiError::Body {
            status: StatusCode::UNPROCESSABLE_ENTITY,
            detail: "the body must be a JSON object".into(),
        }),
        Err(e) => Err(ApiError::Body {
            status: StatusCode::BAD_REQUEST,
            detail: format!("the body is not valid JSON: {e}"),
        }),
    }
}

/// Reads a body extractor's result (over-long bodies → 413 problem).
pub fn body_bytes(
    body: Result<bytes::Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<bytes::Bytes, ApiError> {
    body.map_err(|e| ApiError::Body {
        status: e.status(),
        detail: e.body_text(),
    })
}

async fn product(
    state: AppState,
    kind: ProductKind,
    query: Option<String>,
) -> Result<Response, ApiError> {
    let req = state.request(kind, parse_query(query.as_deref())?)?;
    let (body, source, key) = state.body(&req).await?;
    let mut resp = body.into_response();
    let h = resp.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(req.format.content_type()),
    );
    h.insert("x-cache", HeaderValue::from_static(source.header()));
    if let Ok(v) = HeaderValue::from_str(&key) {
        h.insert("x-skybake-cache-key", v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!("\"{key}-{}\"", req.format.name())) {
        h.insert(header::ETAG, v);
    }
    Ok(resp)
}

fn product_route(kind: ProductKind) -> axum::routing::MethodRouter<AppState> {
    get(
        move |State(s): State<AppState>, axum::extract::RawQuery(q): axum::extract::RawQuery| {
            product(s, kind, q)
        },
    )
}

/// `POST /v1/plan`: the canonical spec, cache key, and the stages that would run (and those left
/// out, and why), without computing the product.
async fn plan(
    State(state): State<AppState>,
    axum::extract::RawQuery(q): axum::extract::RawQuery,
    body: Result<bytes::Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<Response, ApiError> {
    no_query(q.as_deref())?;
    let obj = json_object(&body_bytes(body)?)?;
    let kind = match obj.get("product") {
        Some(Value::String(s)) => ProductKind::parse(s)?,
        Some(_) => return Err(crate::Error::invalid("product", "must be a string").into()),
        None => {
            return Err(crate::Error::invalid(
                "product",
                "missing: one of sun, sky, ground, aerial",
            )
            .into())
        }
    };
    let req = state.request(kind, params_from_object(&obj, &["product"], "")?)?;
    let key = req.cache_key();
    let cached = state.cache().contains(&key);
    // The stages depend on the resolved medium only: no tables are built.
    let spec = &req.spec;
    let medium =
        crate::atmosphere::Medium::new(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo)?;
    let stages = crate::engine::Engine::plan(spec, &medium);
    let canonical: Value = serde_json::from_str(&req.canonical_json()).unwrap_or(Value::Null);
    Ok(axum::Json(json!({
        "product": kind.name(),
        "cache_key": key,
        "cached": cached,
        "engine_version": crate::engine::ENGINE_VERSION,
        "stages": stages,
        "work_cells": req.work_cells(),
        "request": canonical,
    }))
    .into_response())
}

async fn healthz(State(state): State<AppState>) -> Response {
    axum::Json(json!({
        "status": "ok",
        "engine_version": crate::engine::ENGINE_VERSION,
        "cache_entries": state.cache().stats().entries_on_disk,
    }))
    .into_response()
}

async fn metrics(State(state): State<AppState>) -> Response {
    let mut out = String::with_capacity(8192);
    state.metrics().render(&mut out);
    let c = state.cache().stats();
    for (name, help, v) in [
        (
            "skybake_cache_hits_total",
            "Product cache lookups answered (memory or disk).",
            c.hits,
        ),
        (
            "skybake_cache_memory_hits_total",
            "Product cache lookups answered from memory.",
            c.memory_hits,
        ),
        (
            "skybake_cache_disk_hits_total",
            "Product cache lookups answered from disk.",
            c.disk_hits,
        ),
        (
            "skybake_cache_misses_total",
            "Product cache lookups not answered.",
            c.misses,
        ),
        ("skybake_cache_puts_total", "Products stored.", c.puts),
        (
            "skybake_cache_evictions_total",
            "Cache files deleted to keep to the disk budget.",
            c.evictions,
        ),
        (
            "skybake_cache_memory_evictions_total",
            "Entries dropped from memory to keep to its budget.",
            c.memory_evictions,
        ),
        (
            "skybake_cache_corrupt_total",
            "Cache files that failed verification (deleted, recomputed).",
            c.corrupt_detected,
        ),
        (
            "skybake_cache_key_mismatches_total",
            "Valid cache files found under a key they do not carry (deleted, recomputed).",
            c.key_mismatches,
        ),
        (
            "skybake_cache_not_stored_total",
            "Products served but not stored (larger than the disk budget, or unwritable path).",
            c.not_stored,
        ),
    ] {
        counter(&mut out, name, help, v);
    }
    for (name, help, v) in [
        (
            "skybake_cache_bytes_on_disk",
            "Bytes of cache files on disk.",
            c.bytes_on_disk,
        ),
        (
            "skybake_cache_entries_on_disk",
            "Cache files on disk.",
            c.entries_on_disk,
        ),
        (
            "skybake_cache_bytes_in_memory",
            "Bytes of cache files held in memory.",
            c.bytes_in_memory,
        ),
        (
            "skybake_cache_disk_budget_bytes",
            "Disk budget of the cache.",
            state.settings().cache.disk_budget_bytes,
        ),
        (
            "skybake_jobs_queue_depth",
            "Jobs waiting for a worker.",
            state.jobs().queue_depth(),
        ),
        (
            "skybake_jobs_running",
            "Jobs running now.",
            state.jobs().running(),
        ),
    ] {
        gauge(&mut out, name, help, v);
    }
    out.push_str("# HELP skybake_engine_table_builds_total Shared engine tables built, by kind.\n# TYPE skybake_engine_table_builds_total counter\n");
    for kind in ["density", "fast", "precise"] {
        out.push_str(&format!(
            "skybake_engine_table_builds_total{{table=\"{kind}\"}} {}\n",
            state.engine().build_count(kind)
        ));
    }
    let (loaded, rejected) = state.engine().table_loads();
    out.push_str(&format!(
        "# HELP skybake_engine_table_loads_total Shared engine tables loaded from the cache directory instead of built.\n# TYPE skybake_engine_table_loads_total counter\nskybake_engine_table_loads_total{{table=\"precise\"}} {loaded}\n# HELP skybake_engine_table_rejected_total Stored shared tables refused (corrupt or not matching) and rebuilt.\n# TYPE skybake_engine_table_rejected_total counter\nskybake_engine_table_rejected_total{{table=\"precise\"}} {rejected}\n"
    ));
    let mut resp = out.into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
    );
    resp
}

async fn openapi() -> Response {
    let mut resp = openapi_json().into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    resp
}

async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::NotFound(format!("no route {}; see /openapi.json", uri.path()))
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
        ("GET", "/v1/sun") => product_route(ProductKind::Sun),
        ("GET", "/v1/sky") => product_route(ProductKind::Sky),
        ("GET", "/v1/ground") => product_route(ProductKind::Ground),
        ("GET", "/v1/aerial") => product_route(ProductKind::Aerial),
        ("POST", "/v1/plan") => post(plan),
        ("POST", "/v1/jobs") => post(jobs::submit),
        ("GET", "/v1/jobs/{id}") => get(jobs::status),
        ("DELETE", "/v1/jobs/{id}") => delete(jobs::cancel),
        ("GET", "/v1/jobs/{id}/artifacts/{n}") => get(jobs::artifact),
        ("GET", "/healthz") => get(healthz),
        ("GET", "/metrics") => get(metrics),
        ("GET", "/openapi.json") => get(openapi),
        // ROUTES and this table are checked against each other by a test.
        _ => get(not_found),
    }
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
    limited
        .merge(open)
        .fallback(not_found)
        .layer(DefaultBodyLimit::max(settings.server.body_limit_bytes))
        .layer(axum::middleware::from_fn_with_state(state.clone(), record))
        .with_state(state)
}
