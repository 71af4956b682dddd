//! `POST /v1/plan`: the canonical request, its cache key, and the stages that would run and
//! those left out (and why), without computing the product.

use super::super::extract::{JsonObject, NoParams, Query};
use super::super::problem::ApiError;
use super::super::AppState;
use crate::product::ProductRequest;
use axum::extract::State;
use axum::response::{IntoResponse, Response};
use serde_json::{json, Value};

pub async fn plan(
    State(state): State<AppState>,
    Query(NoParams): Query<NoParams>,
    body: JsonObject,
) -> Result<Response, ApiError> {
    let req = ProductRequest::from_object(&body.object, &[], "", state.jobs().defaults())?;
    let key = req.cache_key();
    let cached = state.cache().contains(&key);
    // The plan depends on the resolved medium only: no tables are built.
    let plan = req.plan()?;
    let canonical: Value = serde_json::from_str(&req.canonical_json()).unwrap_or(Value::Null);
    Ok(axum::Json(json!({
        "product": req.kind().name(),
        "cache_key": key,
        "cached": cached,
        "engine_version": crate::engine::ENGINE_VERSION,
        "plan": plan,
        "work_cells": req.work_cells(),
        "request": canonical,
    }))
    .into_response())
}
