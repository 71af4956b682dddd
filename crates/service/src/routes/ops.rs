//! Operations routes: liveness, Prometheus metrics, the OpenAPI document, the atmosphere presets.

use super::super::metrics::{counter, gauge};
use super::super::openapi::openapi_json;
use super::super::AppState;
use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use serde_json::json;

pub async fn healthz(State(state): State<AppState>) -> Response {
    axum::Json(json!({
        "status": "ok",
        "engine_version": skybake_engine::engine::ENGINE_VERSION,
        "cache_entries": state.cache().stats().entries_on_disk,
    }))
    .into_response()
}

pub async fn metrics(State(state): State<AppState>) -> Response {
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
            "skybake_cache_bucket_hits_total",
            "Product cache lookups answered from the shared bucket (cache.url).",
            c.bucket_hits,
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
    if let Some(bucket) = state.cache().bucket() {
        let b = bucket.stats();
        for (name, help, v) in [
            (
                "skybake_bucket_gets_total",
                "Object reads from the bucket.",
                b.gets,
            ),
            (
                "skybake_bucket_puts_total",
                "Object writes to the bucket.",
                b.puts,
            ),
            (
                "skybake_bucket_retries_total",
                "Bucket requests repeated after a failure.",
                b.retries,
            ),
            (
                "skybake_bucket_failures_total",
                "Bucket operations that failed after every retry (answered 503).",
                b.failures,
            ),
            (
                "skybake_lease_waits_total",
                "Polls while another replica held the lease on a product.",
                state
                    .metrics()
                    .lease_waits
                    .load(std::sync::atomic::Ordering::Relaxed),
            ),
        ] {
            counter(&mut out, name, help, v);
        }
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
    for table in skybake_engine::engine::Table::ALL {
        out.push_str(&format!(
            "skybake_engine_table_builds_total{{table=\"{}\"}} {}\n",
            table.name(),
            state.engine().table_builds(table)
        ));
    }
    let (loaded, rejected) = state.engine().table_loads();
    let (d_loaded, d_rejected) = state.engine().density_table_loads();
    out.push_str(&format!(
        "# HELP skybake_engine_table_loads_total Shared engine tables loaded from the cache directory instead of built.\n# TYPE skybake_engine_table_loads_total counter\nskybake_engine_table_loads_total{{table=\"precise\"}} {loaded}\nskybake_engine_table_loads_total{{table=\"density\"}} {d_loaded}\n# HELP skybake_engine_table_rejected_total Stored shared tables refused (not matching the medium and settings) and rebuilt.\n# TYPE skybake_engine_table_rejected_total counter\nskybake_engine_table_rejected_total{{table=\"precise\"}} {rejected}\nskybake_engine_table_rejected_total{{table=\"density\"}} {d_rejected}\n"
    ));
    let mut resp = out.into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
    );
    resp
}

pub async fn openapi() -> Response {
    let mut resp = openapi_json().into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    resp
}

/// `GET /v1/atmospheres`: the built-in atmosphere presets (names for `atmosphere=`), each with its
/// parameters as an inline atmosphere would give them.
pub async fn atmospheres() -> Result<Response, super::super::problem::ApiError> {
    let mut list = Vec::new();
    for name in skybake_physics::atmosphere::presets::preset_names() {
        let params = skybake_physics::atmosphere::presets::preset(name)?;
        list.push(json!({"name": name, "parameters": params}));
    }
    let mut resp = axum::Json(json!({ "atmospheres": list })).into_response();
    resp.headers_mut().insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("public, max-age=3600"),
    );
    Ok(resp)
}
