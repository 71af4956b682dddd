//! The job routes over the job library ([`skybake_job`]): submit, status (paged artifact list),
//! cancel, and an item's artifact in any of its formats.

use super::super::extract::PathParams as UrlPath;
use super::super::extract::{FormatOnly, JsonObject, NoParams, Page, Query};
use super::super::problem::ApiError;
use super::super::AppState;
use axum::extract::State;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde_json::{json, Value};
use skybake_job::run::Job;
use skybake_product::ProductKind;

/// The status document of `job`, listing artifacts `offset..offset + limit` with their URLs.
fn status_json(state: &AppState, job: &Job, offset: usize, limit: usize) -> Value {
    let st = job.status();
    let items: Vec<Value> = job
        .items(offset, limit, state.jobs().defaults())
        .into_iter()
        .map(|it| {
            json!({"index": it.index, "product": it.product, "cache_key": it.cache_key,
                   "status": it.status, "url": format!("/v1/jobs/{}/artifacts/{}", job.id, it.index)})
        })
        .collect();
    json!({
        "id": job.id, "state": st.state, "done": st.done, "failed": st.failed, "total": st.total,
        "created": st.created, "updated": st.updated, "errors": st.errors,
        "artifacts": {"offset": offset, "limit": limit, "items": items},
    })
}

/// `POST /v1/jobs`: validates every item, stores and queues the job; 202 with its status.
pub async fn submit(
    State(state): State<AppState>,
    Query(NoParams): Query<NoParams>,
    body: JsonObject,
) -> Result<Response, ApiError> {
    let s = state.clone();
    let job = AppState::blocking(move || {
        let settings = s.settings();
        let limits = skybake_job::run::SubmitLimits {
            max_products: settings.jobs.max_products,
            max_live: settings.jobs.max_live,
            disk_bytes: settings.cache.disk_budget_bytes,
            max_cost: settings.server.max_job_cost,
            max_item_memory_bytes: settings.server.max_request_memory_bytes,
        };
        let job = s.jobs().submit(&body.bytes, limits)?;
        s.account_disk(None);
        Ok(job)
    })
    .await?;
    let mut resp = (
        StatusCode::ACCEPTED,
        axum::Json(status_json(&state, &job, 0, 0)),
    )
        .into_response();
    if let Ok(v) = format!("/v1/jobs/{}", job.id).parse() {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}

/// `GET /v1/jobs/{id}?offset=&limit=`.
pub async fn status(
    State(state): State<AppState>,
    UrlPath(id): UrlPath<String>,
    Query(page): Query<Page>,
) -> Result<Response, ApiError> {
    // Listing up to MAX_PAGE artifacts validates and hashes each item, and a shared job's
    // progress is read from the bucket: keep both off the executor.
    let s = state.clone();
    let doc = AppState::blocking(move || {
        let job = s.jobs().find(&id)?;
        Ok(status_json(&s, &job, page.offset, page.limit))
    })
    .await?;
    Ok(axum::Json(doc).into_response())
}

/// `DELETE /v1/jobs/{id}`: stops a queued or running job after its current item; removes a
/// finished one with its files (`"deleted": true`; its products stay in the product cache).
pub async fn cancel(
    State(state): State<AppState>,
    UrlPath(id): UrlPath<String>,
    Query(NoParams): Query<NoParams>,
) -> Result<Response, ApiError> {
    let s = state.clone();
    let (job, deleted) = AppState::blocking(move || {
        let r = s.jobs().delete(&id)?;
        s.account_disk(None);
        Ok(r)
    })
    .await?;
    let mut doc = status_json(&state, &job, 0, 0);
    doc["deleted"] = Value::Bool(deleted);
    Ok(axum::Json(doc).into_response())
}

/// `GET /v1/jobs?offset=&limit=`: every job (oldest first) with its state and progress.
pub async fn list(
    State(state): State<AppState>,
    Query(page): Query<Page>,
) -> Result<Response, ApiError> {
    let s = state.clone();
    // With a bucket, every replica's jobs (read from it).
    let all = AppState::blocking(move || {
        s.jobs().sync()?;
        Ok(s.jobs().list())
    })
    .await?;
    let total = all.len();
    let jobs: Vec<Value> = all
        .iter()
        .skip(page.offset)
        .take(page.limit)
        .map(|job| {
            let st = job.status();
            json!({"id": job.id, "state": st.state, "done": st.done, "failed": st.failed,
                   "total": st.total, "created": st.created, "updated": st.updated,
                   "url": format!("/v1/jobs/{}", job.id)})
        })
        .collect();
    Ok(axum::Json(json!({
        "total": total, "offset": page.offset, "limit": page.limit,
        "live": state.jobs().live(), "max_live": state.settings().jobs.max_live,
        "expire_after_s": state.settings().jobs.expire_after_s,
        "jobs": jobs,
    }))
    .into_response())
}

/// `GET /v1/jobs/{id}/artifacts/{n}?format=`: the item's product (computed if it is not cached).
pub async fn artifact(
    State(state): State<AppState>,
    UrlPath((id, n)): UrlPath<(String, String)>,
    Query(FormatOnly(format)): Query<FormatOnly>,
) -> Result<Response, ApiError> {
    let s = state.clone();
    let job = AppState::blocking(move || Ok(s.jobs().find(&id)?)).await?;
    let n: usize = n
        .parse()
        .map_err(|_| ApiError::NotFound(format!("artifact '{n}' is not an item number")))?;
    if job.spec.item_name(n) == Some("frame") {
        let (s, j) = (state.clone(), job.clone());
        let req = AppState::blocking(move || Ok(j.spec.request(n, s.jobs().defaults())?)).await?;
        let skybake_product::AnyRequest::Frame(frame) = req else {
            return Err(ApiError::Internal(format!("item {n} is not a frame")));
        };
        let format = super::render::frame_format(Some(format.as_deref().unwrap_or("exr")), None)?;
        let mut resp = super::render::frame_response(&state, frame, format).await?;
        resp.headers_mut().insert(
            header::CACHE_CONTROL,
            HeaderValue::from_static(super::products::IMMUTABLE),
        );
        return Ok(resp);
    }
    let (product, mut params, _) = job.spec.item(n).ok_or_else(|| {
        ApiError::NotFound(format!("no artifact {n} (the job has {})", job.spec.len()))
    })?;
    params.format = Some(format.unwrap_or_else(|| {
        if product == ProductKind::Sun {
            "json"
        } else {
            "exr"
        }
        .into()
    }));
    // The job's artifact: every wavelength, whatever the download's format.
    let req = state.request(product, params)?.without_rgb_only()?;
    let (body, source, key) = state.body(&req).await?;
    let mut resp = super::artifact_response(body, req.format.content_type(), source, &key);
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&format!("\"{key}-{}\"", req.format.name())) {
        h.insert(header::ETAG, v);
    }
    // A job's item never changes (its spec is fixed and the engine version is in the key).
    h.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static(super::products::IMMUTABLE),
    );
    Ok(resp)
}
