//! `POST /v1/plan`: the canonical request, its cache key, and the stages that would run and
//! those left out (and why), without computing the product.

use super::super::extract::{JsonObject, NoParams, Query};
use super::super::problem::ApiError;
use super::super::AppState;
use axum::extract::State;
use axum::response::{IntoResponse, Response};
use serde_json::{json, Value};
use skybake_product::ProductRequest;

pub async fn plan(
    State(state): State<AppState>,
    Query(NoParams): Query<NoParams>,
    body: JsonObject,
) -> Result<Response, ApiError> {
    if body.object.get("product").and_then(Value::as_str) == Some("frame") {
        return frame_plan(state, body).await;
    }
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
        "engine_version": skybake_engine::engine::ENGINE_VERSION,
        "plan": plan,
        "work_cells": req.work_cells(),
        "request": canonical,
    }))
    .into_response())
}

/// `{"product": "frame", "scene": {…}, "method": "fast"|"reference", "max_rel_error": E, "output":
/// "spectral"|"rgb"}`: the frame's plan (the
/// cloud is voxelised to measure it, on a blocking thread; nothing is lit or rendered).
async fn frame_plan(state: AppState, body: JsonObject) -> Result<Response, ApiError> {
    use skybake_product::frame::example_file;
    use skybake_product::frame::FrameRequest;
    use skybake_render::Method;
    let obj = body.object;
    if let Some(k) = obj.keys().find(|k| {
        !matches!(
            k.as_str(),
            "product" | "scene" | "method" | "max_rel_error" | "output"
        )
    }) {
        return Err(crate::Error::invalid(
            k,
            "not a member of a frame plan request (product, scene, method, max_rel_error, output)",
        )
        .into());
    }
    // `"output": "rgb"`: plan the frame as `POST /v1/render?format=png` runs it (RGB-only).
    let rgb_only =
        match obj.get("output") {
            None | Some(Value::Null) => false,
            Some(Value::String(o)) if o == "rgb" => true,
            Some(Value::String(o)) if o == "spectral" => false,
            Some(_) => return Err(crate::Error::invalid(
                "output",
                "\"spectral\" (the EXR's spectral image, the default) or \"rgb\" (a PNG: RGB only)",
            )
            .into()),
        };
    let target = match obj.get("max_rel_error") {
        None | Some(Value::Null) => None,
        Some(Value::Number(n)) => Some(n.to_string()),
        Some(Value::String(t)) => Some(t.clone()),
        Some(_) => return Err(crate::Error::invalid("max_rel_error", "a number").into()),
    };
    let method = match obj.get("method") {
        None => Method::Fast,
        Some(Value::String(m)) => Method::parse(m)?,
        Some(_) => {
            return Err(crate::Error::invalid("method", "a string: fast or reference").into())
        }
    };
    let scene = obj
        .get("scene")
        .cloned()
        .ok_or_else(|| crate::Error::invalid("scene", "a frame plan needs the scene"))?;
    let req = AppState::blocking(move || {
        let req = FrameRequest::from_value(&scene, method)?
            .with_max_rel_error(target.as_deref())?
            .with_rgb_only(rgb_only);
        // A scene may name only the example scenes' files, as for a render.
        req.check_files(&example_file)?;
        Ok(req)
    })
    .await?;
    // Planning voxelises the cloud (running an automaton's steps) and computes the light at the
    // cloud: charged to the frame cost cap, then run like a computation (a compute slot, the
    // bounded queue, cancelled when the client goes).
    state.check_frame_cost(&req.planning_cost())?;
    let key = req.cache_key();
    let s = state.clone();
    let plan = state
        .run_computation(move |cancel| Ok(req.plan_unless(s.engine(), &example_file, cancel)?))
        .await?;
    Ok(axum::Json(json!({
        "product": "frame",
        "cache_key": key,
        "engine_version": skybake_engine::engine::ENGINE_VERSION,
        "method": method,
        "plan": plan,
    }))
    .into_response())
}
