//! The web viewer (`GET /` and its assets): static files from `web/`, embedded in the binary so the
//! page works offline and without a CDN. The page talks to the public API only.

use axum::extract::Path;
use axum::http::header::{CACHE_CONTROL, CONTENT_TYPE};
use axum::response::{IntoResponse, Response};

use super::problem::ApiError;

const INDEX_HTML: &str = include_str!("../../../web/index.html");
const APP_JS: &str = include_str!("../../../web/app.js");
const STYLE_CSS: &str = include_str!("../../../web/style.css");
/// The live sky's client (docs/lut.md): the bundle's OpenEXR decoder, the WebGL2 renderer,
/// Bruneton's functions as a GLSL ES 3.0 shader and the `skyview` layout's versions of them.
const LUT_EXR_JS: &str = include_str!("../../../web/lut/exr.js");
const LUT_SKY_JS: &str = include_str!("../../../web/lut/sky.js");
const LUT_ATMOSPHERE_GLSL: &str = include_str!("../../../web/lut/atmosphere.glsl");
const LUT_SKYVIEW_GLSL: &str = include_str!("../../../web/lut/skyview.glsl");

/// `GET /`: the viewer page.
pub async fn index() -> Response {
    asset_response("text/html; charset=utf-8", INDEX_HTML)
}

/// `GET /assets/{file}`: the page's scripts, style sheet and shader (`lut-*`: web/lut/*).
pub async fn asset(Path(file): Path<String>) -> Result<Response, ApiError> {
    match file.as_str() {
        "app.js" => Ok(asset_response("text/javascript; charset=utf-8", APP_JS)),
        "style.css" => Ok(asset_response("text/css; charset=utf-8", STYLE_CSS)),
        "lut-exr.js" => Ok(asset_response("text/javascript; charset=utf-8", LUT_EXR_JS)),
        "lut-sky.js" => Ok(asset_response("text/javascript; charset=utf-8", LUT_SKY_JS)),
        "lut-atmosphere.glsl" => Ok(asset_response(
            "text/plain; charset=utf-8",
            LUT_ATMOSPHERE_GLSL,
        )),
        "lut-skyview.glsl" => Ok(asset_response(
            "text/plain; charset=utf-8",
            LUT_SKYVIEW_GLSL,
        )),
        _ => Err(ApiError::NotFound(format!("no asset '{file}'"))),
    }
}

fn asset_response(content_type: &'static str, body: &'static str) -> Response {
    (
        [(CONTENT_TYPE, content_type), (CACHE_CONTROL, "no-cache")],
        body,
    )
        .into_response()
}
