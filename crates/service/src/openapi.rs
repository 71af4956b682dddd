//! The route table (the router is built from it) and the OpenAPI 3.1 document generated from it, so
//! `/openapi.json` lists exactly the routes the router serves (a test checks both directions).

use serde_json::{json, Map, Value};
use skybake_engine::spec::ProductKind;
use skybake_product::params::{Parameter, Range, PARAMETERS};

/// One route of the service.
#[derive(Debug, Clone, Copy)]
pub struct Route {
    /// HTTP method (upper case).
    pub method: &'static str,
    /// Path in axum syntax (`{id}` captures), identical to OpenAPI path templating.
    pub path: &'static str,
    pub summary: &'static str,
    /// Behind the load-shedding, concurrency and timeout layers.
    pub limited: bool,
    /// Takes the product query parameters (which products' formats apply).
    pub product: Option<&'static str>,
    /// Takes a JSON body.
    pub body: Option<&'static str>,
    /// Media types of a success response.
    pub produces: &'static [&'static str],
}

const JSON: &[&str] = &["application/json"];

/// Every route the router serves.
pub const ROUTES: &[Route] = &[
    Route { method: "GET", path: "/v1/sun", summary: "Sun attenuation: spectral transmittance, direct normal, diffuse and global horizontal irradiance", limited: true, product: Some("sun"), body: None, produces: JSON },
    Route { method: "GET", path: "/v1/sky", summary: "Sky-dome radiance table (view elevation −90…90°, azimuth 0…180° from the sun) or probes", limited: true, product: Some("sky"), body: None, produces: &["application/json", "image/x-exr", "image/png"] },
    Route { method: "GET", path: "/v1/ground", summary: "Ground-reflected upward skylight at the observer (view zenith 90…180°) or probes", limited: true, product: Some("ground"), body: None, produces: &["application/json", "image/x-exr", "image/png"] },
    Route { method: "GET", path: "/v1/aerial", summary: "Aerial perspective: transmittance and in-scattered radiance against distance", limited: true, product: Some("aerial"), body: None, produces: &["application/json", "image/x-exr"] },
    Route { method: "POST", path: "/v1/render", summary: "A lit cloud frame of the scene in the body (format=json|exr|png or Accept; method=fast|reference); cached, rendered and stored tile by tile so an interrupted render resumes", limited: true, product: None, body: Some("FrameScene"), produces: &["application/json", "image/x-exr", "image/png"] },
    Route { method: "GET", path: "/v1/scenes", summary: "The example scenes (name, description, whether it is a frame scene)", limited: false, product: None, body: None, produces: JSON },
    Route { method: "GET", path: "/v1/scenes/{name}", summary: "An example scene's JSON (frame scenes can be posted to /v1/render as they are)", limited: false, product: None, body: None, produces: JSON },
    Route { method: "POST", path: "/v1/plan", summary: "What would run for a product (stages run and left out, cache key), without computing it", limited: true, product: None, body: Some("PlanRequest"), produces: JSON },
    Route { method: "POST", path: "/v1/jobs", summary: "Submit a bake job (product list and/or grids); 202 with the job id", limited: true, product: None, body: Some("JobRequest"), produces: JSON },
    Route { method: "GET", path: "/v1/jobs", summary: "Every job (oldest first) with state and progress (offset/limit page the list)", limited: true, product: None, body: None, produces: JSON },
    Route { method: "GET", path: "/v1/jobs/{id}", summary: "Job state, progress, errors and artifacts (offset/limit page the artifact list)", limited: true, product: None, body: None, produces: JSON },
    Route { method: "DELETE", path: "/v1/jobs/{id}", summary: "Cancel a queued or running job; remove a finished one and its files (its products stay cached)", limited: true, product: None, body: None, produces: JSON },
    Route { method: "GET", path: "/v1/jobs/{id}/artifacts/{n}", summary: "The n-th product of a job (format=exr default, json, png)", limited: true, product: None, body: None, produces: &["image/x-exr", "application/json", "image/png"] },
    Route { method: "GET", path: "/v1/lut", summary: "The real-time texture bundle of an atmosphere (Bruneton 2017's layout, or skybake's sky-view layout with layout=skyview; RGB form, or spectral with wavelengths): its manifest with a link to each texture; computed once and cached", limited: true, product: None, body: None, produces: JSON },
    Route { method: "GET", path: "/v1/lut/files/{key}", summary: "A texture (OpenEXR) of a bundle whose manifest was requested (the manifest's links)", limited: true, product: None, body: None, produces: &["image/x-exr"] },
    Route { method: "GET", path: "/v1/atmospheres", summary: "The built-in atmosphere presets with their parameters", limited: true, product: None, body: None, produces: JSON },
    Route { method: "GET", path: "/", summary: "The web viewer (HTML page; uses this API)", limited: false, product: None, body: None, produces: &["text/html"] },
    Route { method: "GET", path: "/assets/{file}", summary: "The viewer's scripts, style sheet and live-sky shader", limited: false, product: None, body: None, produces: &["text/javascript", "text/css", "text/plain"] },
    Route { method: "GET", path: "/healthz", summary: "Liveness", limited: false, product: None, body: None, produces: JSON },
    Route { method: "GET", path: "/metrics", summary: "Prometheus metrics", limited: false, product: None, body: None, produces: &["text/plain"] },
    Route { method: "GET", path: "/openapi.json", summary: "This document", limited: false, product: None, body: None, produces: JSON },
];

/// The OpenAPI description and schema of a row of the product parameter table
/// (`product::params::PARAMETERS`, the same table the CLI flags and the query parser use).
fn parameter_doc(p: &Parameter) -> (String, Value) {
    let unit = if p.unit.is_empty() {
        String::new()
    } else {
        format!(", {}", p.unit)
    };
    let description = format!(
        "{}{unit}; {}; default {}",
        p.doc,
        p.range.describe(),
        p.default
    );
    let schema = match p.range {
        Range::Real { lo, hi } => json!({"type": "number", "minimum": lo, "maximum": hi}),
        Range::Whole { lo, hi } => json!({"type": "integer", "minimum": lo, "maximum": hi}),
        Range::OneOf(words) => json!({"type": "string", "enum": words}),
        Range::Text(_) => json!({"type": "string"}),
    };
    (description, schema)
}

fn problem_response(description: &str) -> Value {
    json!({
        "description": description,
        "content": {"application/problem+json": {"schema": {"$ref": "#/components/schemas/Problem"}}}
    })
}

fn operation(route: &Route) -> Value {
    let mut op = Map::new();
    op.insert("summary".into(), json!(route.summary));
    let mut parameters = Vec::new();
    for seg in route.path.split('/') {
        if let Some(name) = seg.strip_prefix('{').and_then(|s| s.strip_suffix('}')) {
            parameters.push(
                json!({"name": name, "in": "path", "required": true, "schema": {"type": "string"}}),
            );
        }
    }
    if let Some(product) = route.product.and_then(|p| ProductKind::parse(p).ok()) {
        for p in PARAMETERS.iter().filter(|p| p.applies_to(product)) {
            let (description, schema) = parameter_doc(p);
            parameters.push(json!({"name": p.name, "in": "query", "required": false, "description": description, "schema": schema}));
        }
    }
    if route.path == "/v1/lut" {
        for p in PARAMETERS
            .iter()
            .filter(|p| skybake_product::lut::takes(p.name))
        {
            let (description, schema) = parameter_doc(p);
            parameters.push(json!({"name": p.name, "in": "query", "required": false, "description": description, "schema": schema}));
        }
    }
    if (route.path == "/v1/jobs/{id}" || route.path == "/v1/jobs") && route.method == "GET" {
        for name in ["offset", "limit"] {
            parameters.push(json!({"name": name, "in": "query", "required": false, "schema": {"type": "integer", "minimum": 0}}));
        }
    }
    if route.path == "/v1/render" {
        parameters.push(json!({"name": "format", "in": "query", "required": false, "description": "body format; when absent the Accept header picks (image/x-exr, image/png), else json. png is an RGB-only request: the planner may run it at fewer wavelengths (its own cache key) unless the scene's spectral frame is cached", "schema": {"type": "string", "enum": ["json", "exr", "png"]}}));
        parameters.push(json!({"name": "method", "in": "query", "required": false, "description": "fast (per-voxel light, multiple-scattering field, ray march) or reference (path tracer); default fast", "schema": {"type": "string", "enum": ["fast", "reference"]}}));
        parameters.push(json!({"name": "max_rel_error", "in": "query", "required": false, "description": "target relative error of the frame (method fast), 0.081 to 1: what it leaves over the fast method's measured 8.1 % is the planner's budget; below 0.081 a 400 names the best achievable error", "schema": {"type": "number", "minimum": 0.0001, "maximum": 1}}));
    }
    if route.path.ends_with("/artifacts/{n}") {
        parameters.push(json!({"name": "format", "in": "query", "required": false, "schema": {"type": "string", "enum": ["exr", "json", "png", "png_latlong"]}}));
    }
    if !parameters.is_empty() {
        op.insert("parameters".into(), Value::Array(parameters));
    }
    if let Some(schema) = route.body {
        op.insert(
            "requestBody".into(),
            json!({"required": true, "content": {"application/json": {"schema": {"$ref": format!("#/components/schemas/{schema}")}}}}),
        );
    }
    let content: Map<String, Value> = route
        .produces
        .iter()
        .map(|t| (t.to_string(), json!({})))
        .collect();
    let ok = if route.path == "/v1/jobs" && route.method == "POST" {
        "202"
    } else {
        "200"
    };
    let mut responses = Map::new();
    responses.insert(
        ok.into(),
        json!({"description": "success", "content": content}),
    );
    if route.limited {
        responses.insert(
            "400".into(),
            problem_response("parameter out of range or unknown parameter"),
        );
        responses.insert("404".into(), problem_response("no such job or artifact"));
        responses.insert(
            "413".into(),
            problem_response("request exceeds a size limit (named)"),
        );
        responses.insert("422".into(), problem_response("invalid parameter (named)"));
        responses.insert(
            "503".into(),
            problem_response("overloaded or timed out; see Retry-After"),
        );
    }
    op.insert("responses".into(), Value::Object(responses));
    Value::Object(op)
}

/// The OpenAPI 3.1 document of [`ROUTES`].
pub fn openapi_json() -> String {
    let mut paths: Map<String, Value> = Map::new();
    for route in ROUTES {
        let entry = paths
            .entry(route.path.to_string())
            .or_insert_with(|| json!({}));
        if let Value::Object(m) = entry {
            m.insert(route.method.to_ascii_lowercase(), operation(route));
        }
    }
    // JSON bodies accept numbers or the query's text for every parameter.
    let params: Map<String, Value> = PARAMETERS
        .iter()
        .map(|p| {
            let (description, _) = parameter_doc(p);
            (
                p.name.to_string(),
                json!({"type": ["string", "number"], "description": description}),
            )
        })
        .collect();
    let mut plan_props = params.clone();
    plan_props.insert(
        "product".into(),
        json!({"type": "string", "enum": ["sun", "sky", "ground", "aerial", "frame"]}),
    );
    plan_props.insert(
        "scene".into(),
        json!({"$ref": "#/components/schemas/FrameScene", "description": "product frame: the scene to plan (with method fast|reference and max_rel_error)"}),
    );
    plan_props.insert(
        "output".into(),
        json!({"type": "string", "enum": ["spectral", "rgb"], "description": "product frame: spectral (the EXR, default) or rgb (the PNG of POST /v1/render?format=png: an RGB-only request, which the planner may run at fewer wavelengths, its own cache key)"}),
    );
    let doc = json!({
        "openapi": "3.1.0",
        "info": {"title": "skybake", "version": env!("CARGO_PKG_VERSION"),
                 "description": "Spectral atmosphere and sky precomputation service"},
        "paths": paths,
        "components": {"schemas": {
            "Problem": {"type": "object", "required": ["type", "title", "status", "detail"], "properties": {
                "type": {"type": "string"}, "title": {"type": "string"}, "status": {"type": "integer"},
                "detail": {"type": "string"}, "parameter": {"type": "string"}}},
            "PlanRequest": {"type": "object", "required": ["product"], "properties": plan_props, "additionalProperties": false},
            "FrameScene": {"type": "object", "required": ["cloud", "optics", "camera", "sun"],
                "description": "A frame scene (see GET /v1/scenes/cumulus-frame): cloud (any cloud source, grids .npy, raw or OpenVDB .vdb included; files only those of the example scenes: satellite-field.png, vdb-cloud.vdb), optics (extinction_per_density_m, single_scattering_albedo, phase with g in (-1, 1)), camera (pinhole | orthographic | fisheye, width x height up to 16 Mi pixels), sun (elevation_deg + azimuth_deg from +y towards +x, latitude_deg + longitude_deg + time, or collimated), atmosphere (preset, inline or null), sky, ground, wavelengths_nm, quality, lighting switches",
                "properties": {"cloud": {"type": "object"}, "optics": {"type": "object"}, "camera": {"type": "object"},
                    "sun": {"type": "object"}, "atmosphere": {"type": ["string", "object", "null"]},
                    "sky": {"type": ["string", "object", "null"]}, "ground": {"type": ["object", "null"]},
                    "wavelengths_nm": {"type": "array", "items": {"type": "number"}},
                    "quality": {"type": "string", "enum": ["draft", "standard", "high", "reference"]},
                    "lighting": {"type": "object"}, "name": {"type": "string"}, "description": {"type": "string"}, "doc": {"type": "object"}}},
            "FrameEntry": {"type": "object", "additionalProperties": false,
                "description": "Frames of one scene: exactly one of scene or example; sweep axes (each a list or {from, to, step}) combine in alphabetical order, the last varying fastest",
                "properties": {"scene": {"$ref": "#/components/schemas/FrameScene"},
                    "example": {"type": "string", "description": "name of an example scene (GET /v1/scenes)"},
                    "method": {"type": "string", "enum": ["fast", "reference"]},
                    "max_rel_error": {"type": "number", "minimum": 0.0001, "maximum": 1, "description": "target relative error of every frame of the entry (method fast), as POST /v1/render's max_rel_error: 0.081 to 1, below 0.081 a 400 naming frames[i].max_rel_error and the best achievable error"},
                    "sweep": {"type": "object", "additionalProperties": false, "properties": {
                        "sun_elevation_deg": {}, "sun_azimuth_deg": {}, "time": {"description": "RFC 3339 times (a sun given by place and time)"},
                        "frame_time_steps": {"description": "automaton frames (a cloud whose source is an automaton)"}}}}},
            "JobRequest": {"type": "object", "additionalProperties": false, "properties": {
                "frames": {"type": "array", "items": {"$ref": "#/components/schemas/FrameEntry"}},
                "bundles": {"type": "array", "description": "Texture-bundle items (atmosphere parameters and an optional sweep over them): baked offline by `skybake bake` only; a job with bundles is refused here (422 naming bundles); GET /v1/lut serves one bundle", "items": {"type": "object"}},
                "cloud_lights": {"type": "array", "description": "Pre-lit cloud volume items ({scene} or {example}; docs/cloud-light.md): baked offline by `skybake bake` only; a job with them is refused here (422 naming cloud_lights)", "items": {"type": "object"}},
                "products": {"type": "array", "items": {"$ref": "#/components/schemas/PlanRequest"}},
                "grids": {"type": "array", "items": {"type": "object", "required": ["product", "sweep"],
                    "description": "A product with base parameters and a sweep: each sweep member is a list of values or {from, to, step}",
                    "properties": {"product": {"type": "string"}, "sweep": {"type": "object"}}}}}}
        }}
    });
    doc.to_string()
}
