//! `GET /v1/scenes` and `GET /v1/scenes/{name}`: the example scenes of `config/scenes/`, embedded
//! in the binary ([`skybake_product::frame::EXAMPLE_SCENES`]). Frame scenes (`"frame": true`)
//! can be sent as they are to `POST /v1/render` or named in a frame job (`"example": name`).

use super::super::extract::{NoParams, PathParams as Path, Query};
use super::super::problem::ApiError;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde_json::{json, Value};
use skybake_product::frame::{example_scene, EXAMPLE_SCENES};

/// The list entry of one example scene: name, description, whether it is a frame scene (has a
/// camera; the others are cloud sections for `skybake clouds`), its URL.
fn entry(name: &str, text: &str) -> Value {
    let scene: Value = serde_json::from_str(text).unwrap_or(Value::Null);
    json!({
        "name": name,
        "description": scene.get("description").and_then(Value::as_str).unwrap_or(""),
        "frame": scene.get("camera").is_some(),
        "cloud_source": scene.pointer("/cloud/source/type"),
        "url": format!("/v1/scenes/{name}"),
    })
}

/// `GET /v1/scenes`: `{"scenes": [{"name", "description", "frame", "cloud_source", "url"}]}`.
pub async fn list(Query(NoParams): Query<NoParams>) -> Response {
    let scenes: Vec<Value> = EXAMPLE_SCENES
        .iter()
        .map(|(name, text)| entry(name, text))
        .collect();
    axum::Json(json!({ "scenes": scenes })).into_response()
}

/// `GET /v1/scenes/{name}`: the scene JSON as stored in `config/scenes/{name}.json`.
pub async fn scene(
    Path(name): Path<String>,
    Query(NoParams): Query<NoParams>,
) -> Result<Response, ApiError> {
    let name = name.strip_suffix(".json").unwrap_or(&name);
    let text = example_scene(name).ok_or_else(|| {
        let names: Vec<&str> = EXAMPLE_SCENES.iter().map(|(n, _)| *n).collect();
        ApiError::NotFound(format!(
            "no example scene '{name}' (known: {})",
            names.join(", ")
        ))
    })?;
    Ok(([(header::CONTENT_TYPE, "application/json")], text).into_response())
}
