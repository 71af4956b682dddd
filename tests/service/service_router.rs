//! The router driven in-process, without a socket (`app(state).oneshot(request)`, tower's
//! `ServiceExt`), one test per route family: products (EXR and JSON, problem+json naming the
//! parameter), plan, jobs (create, list, get, delete; the job cost cap), render, scenes, ops
//! (healthz, metrics, openapi), and the unknown route (404) and method (405).

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use serde_json::{json, Value};
use service_support::{settings, Scratch, FAST};
use skybake_service::AppState;

/// An answer: status, headers (lower-case names), body.
struct Answer {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Answer {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }
    /// Asserts a problem+json answer with `status` naming `parameter` (when given).
    fn assert_problem(&self, status: u16, parameter: Option<&str>) -> Value {
        assert_eq!(
            self.status,
            status,
            "{}",
            String::from_utf8_lossy(&self.body)
        );
        assert_eq!(
            self.header("content-type"),
            Some("application/problem+json")
        );
        let p = self.json();
        assert_eq!(p["status"], json!(status), "{p}");
        if let Some(name) = parameter {
            assert_eq!(p["parameter"], json!(name), "{p}");
        }
        p
    }
}

async fn call(state: &AppState, method: &str, uri: &str, body: Option<Value>) -> Answer {
    let mut req = Request::builder().method(method).uri(uri);
    let body = match body {
        Some(v) => {
            req = req.header("content-type", "application/json");
            Body::from(serde_json::to_vec(&v).unwrap())
        }
        None => Body::empty(),
    };
    let r = service_support::send(state, req.body(body).unwrap()).await;
    Answer {
        status: r.status,
        headers: r.headers,
        body: r.body,
    }
}

fn state(dir: &Scratch) -> AppState {
    AppState::new(settings(dir.path())).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn products_answer_json_and_exr_and_name_a_bad_parameter() {
    let dir = Scratch::new("router-products");
    let state = state(&dir);
    let sun = call(
        &state,
        "GET",
        "/v1/sun?method=fast&quality=draft&wavelengths=440,550,680&sun_elevation_deg=30",
        None,
    )
    .await;
    assert_eq!(sun.status, 200, "{}", String::from_utf8_lossy(&sun.body));
    assert_eq!(sun.header("content-type"), Some("application/json"));
    let v = sun.json();
    assert_eq!(v["wavelengths_nm"], json!([440.0, 550.0, 680.0]), "{v}");
    assert!(v["direct_normal_irradiance_w_m2_nm"][1].as_f64().unwrap() > 0.0);

    let sky = call(&state, "GET", &format!("/v1/sky?{FAST}&format=exr"), None).await;
    assert_eq!(sky.status, 200);
    assert_eq!(sky.header("content-type"), Some("image/x-exr"));
    // OpenEXR magic number 20000630, little-endian.
    assert_eq!(&sky.body[..4], &[0x76, 0x2f, 0x31, 0x01]);
    assert!(sky.header("etag").is_some());

    for (query, status, name) in [
        ("sun_elevation_deg=95", 400, "sun_elevation_deg"),
        ("sun_elevation_deg=abc", 422, "sun_elevation_deg"),
        ("wavelengths=100", 400, "wavelengths"),
        ("colour=red", 400, "colour"),
    ] {
        let a = call(&state, "GET", &format!("/v1/sky?{query}"), None).await;
        a.assert_problem(status, Some(name));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plan_lists_the_stages_without_computing() {
    let dir = Scratch::new("router-plan");
    let state = state(&dir);
    let a = call(
        &state,
        "POST",
        "/v1/plan",
        Some(json!({"product": "sky", "method": "fast", "sun_elevation_deg": 20})),
    )
    .await;
    assert_eq!(a.status, 200, "{}", String::from_utf8_lossy(&a.body));
    let v = a.json();
    assert_eq!(v["product"], "sky");
    assert_eq!(v["cached"], false);
    assert!(
        v["plan"]["stages"]
            .as_array()
            .is_some_and(|s| !s.is_empty()),
        "{v}"
    );
    assert_eq!(state.metrics().computations("sky"), 0);
    call(
        &state,
        "POST",
        "/v1/plan",
        Some(json!({"product": "sky", "quality": "best"})),
    )
    .await
    .assert_problem(422, Some("quality"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_are_created_listed_read_and_deleted() {
    let dir = Scratch::new("router-jobs");
    let state = state(&dir);
    // No workers run in this test (the accept loop starts them): the job stays queued.
    let body = json!({"products": [{"product": "sun", "method": "fast", "quality": "draft",
                                    "wavelengths": "440,550", "sun_elevation_deg": 10}]});
    let created = call(&state, "POST", "/v1/jobs", Some(body)).await;
    assert_eq!(
        created.status,
        202,
        "{}",
        String::from_utf8_lossy(&created.body)
    );
    let id = created.json()["id"].as_str().unwrap().to_string();
    assert_eq!(
        created.header("location"),
        Some(format!("/v1/jobs/{id}").as_str())
    );

    let list = call(&state, "GET", "/v1/jobs", None).await.json();
    assert_eq!(list["total"], 1, "{list}");
    assert_eq!(list["jobs"][0]["id"], json!(id));

    let status = call(&state, "GET", &format!("/v1/jobs/{id}"), None).await;
    assert_eq!(status.status, 200);
    assert_eq!(status.json()["state"], "queued");

    // Deleting a queued job cancels it; deleting the cancelled job removes it.
    let first = call(&state, "DELETE", &format!("/v1/jobs/{id}"), None)
        .await
        .json();
    assert_eq!(
        (first["state"].as_str(), first["deleted"].as_bool()),
        (Some("cancelled"), Some(false)),
        "{first}"
    );
    let second = call(&state, "DELETE", &format!("/v1/jobs/{id}"), None)
        .await
        .json();
    assert_eq!(second["deleted"], true, "{second}");
    call(&state, "GET", &format!("/v1/jobs/{id}"), None)
        .await
        .assert_problem(404, None);
    call(
        &state,
        "POST",
        "/v1/jobs",
        Some(json!({"products": [{"product": "sky", "sun_elevation_deg": 200}]})),
    )
    .await
    .assert_problem(400, Some("products[0].sun_elevation_deg"));
    // Pre-lit cloud volumes are baked offline only.
    call(
        &state,
        "POST",
        "/v1/jobs",
        Some(json!({"cloud_lights": [{"example": "cumulus-frame"}]})),
    )
    .await
    .assert_problem(422, Some("cloud_lights"));
}

/// A job whose estimated cost is over `server.max_job_cost` is refused at submission (413 naming
/// `job_cost` and stating the limit); the same job under a larger budget is accepted. A sweep of
/// one atmosphere counts its table once: 200 skies cost far less than 200 times one sky.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_over_the_cost_budget_are_refused_at_submission() {
    let dir = Scratch::new("router-job-cost");
    let sweep = |n: usize| {
        let values: Vec<f64> = (0..n).map(|k| k as f64 * 0.25).collect();
        json!({"grids": [{"product": "sky", "quality": "high", "method": "precise",
                          "sweep": {"sun_elevation_deg": values}}]})
    };
    let frame = |width: usize| {
        let mut scene: Value = serde_json::from_str(
            skybake_product::frame::example_scene("validation-frame").unwrap(),
        )
        .unwrap();
        scene["camera"]["width"] = json!(width);
        scene["camera"]["height"] = json!(width * 3 / 4);
        json!({"frames": [{"scene": scene, "method": "reference"}]})
    };
    let cost = |body: &Value| {
        skybake_job::spec::JobSpec::parse_body(body.to_string().as_bytes(), 100_000)
            .unwrap()
            .validate_and_cost(&Default::default())
            .unwrap()
    };
    let (one, many) = (cost(&sweep(1)), cost(&sweep(200)));
    assert!(
        many * 10 < 200 * one,
        "200 skies of one atmosphere cost {many}, one {one}"
    );
    let big_frame = cost(&frame(640));
    assert!(big_frame > 10 * cost(&frame(160)));

    let mut s = settings(dir.path());
    s.server.max_job_cost = big_frame - 1;
    let state = AppState::new(s).unwrap();
    let p = call(&state, "POST", "/v1/jobs", Some(frame(640)))
        .await
        .assert_problem(413, Some("job_cost"));
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains(&(big_frame - 1).to_string()), "{detail}");
    assert!(detail.contains("server.max_job_cost"), "{detail}");
    assert_eq!(
        call(&state, "GET", "/v1/jobs", None).await.json()["total"],
        0
    );
    let ok = call(&state, "POST", "/v1/jobs", Some(frame(160))).await;
    assert_eq!(ok.status, 202, "{}", String::from_utf8_lossy(&ok.body));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_router_lists_serves_and_renders_scenes_and_refuses_a_bad_camera() {
    let dir = Scratch::new("router-render");
    let state = state(&dir);
    let list = call(&state, "GET", "/v1/scenes", None).await;
    assert_eq!(list.status, 200);
    let names: Vec<String> = list.json()["scenes"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|s| s["name"].as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    assert!(names.iter().any(|n| n == "validation-frame"), "{names:?}");
    let scene = call(&state, "GET", "/v1/scenes/validation-frame", None).await;
    assert_eq!(scene.status, 200);
    let mut scene = scene.json();
    call(&state, "GET", "/v1/scenes/nope", None)
        .await
        .assert_problem(404, None);

    scene["camera"]["width"] = json!(16);
    scene["camera"]["height"] = json!(12);
    scene["quality"] = json!("draft");
    scene["cloud"]["voxel_size_m"] = json!(100.0);
    let frame = call(
        &state,
        "POST",
        "/v1/render?format=json",
        Some(scene.clone()),
    )
    .await;
    assert_eq!(
        frame.status,
        200,
        "{}",
        String::from_utf8_lossy(&frame.body)
    );
    let v = frame.json();
    assert_eq!(
        (v["product"].as_str(), v["width"].as_u64()),
        (Some("frame"), Some(16)),
        "{v}"
    );
    scene["camera"]["fov_deg"] = json!(0);
    call(&state, "POST", "/v1/render", Some(scene))
        .await
        .assert_problem(400, Some("camera.fov_deg"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ops_routes_and_unknown_routes_and_methods() {
    let dir = Scratch::new("router-ops");
    let state = state(&dir);
    let health = call(&state, "GET", "/healthz", None).await;
    assert_eq!(health.status, 200);
    let metrics = call(&state, "GET", "/metrics", None).await;
    assert_eq!(metrics.status, 200);
    assert!(String::from_utf8_lossy(&metrics.body).contains("skybake_"));
    let openapi = call(&state, "GET", "/openapi.json", None).await.json();
    for path in ["/v1/sky", "/v1/jobs", "/v1/render", "/v1/plan"] {
        assert!(
            openapi["paths"][path].is_object(),
            "{path} missing from /openapi.json"
        );
    }
    call(&state, "GET", "/v1/nope", None)
        .await
        .assert_problem(404, None);
    let wrong = call(&state, "DELETE", "/v1/sky", None).await;
    wrong.assert_problem(405, None);
    assert!(
        wrong.header("allow").is_some_and(|a| a.contains("GET")),
        "{:?}",
        wrong.headers
    );
}

/// Job admission is atomic: 200 concurrent submissions against `jobs.max_live` = 64 leave exactly
/// 64 live jobs (no workers run here, so every accepted job stays queued), the others 503 naming
/// the limit.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_job_submissions_never_exceed_max_live() {
    let dir = Scratch::new("router-job-race");
    let state = state(&dir);
    assert_eq!(state.settings().jobs.max_live, 64);
    let body = json!({"products": [{"product": "sun", "method": "fast", "quality": "draft",
                                    "wavelengths": "550"}]});
    let tasks: Vec<_> = (0..200)
        .map(|_| {
            let (state, body) = (state.clone(), body.clone());
            tokio::spawn(async move { call(&state, "POST", "/v1/jobs", Some(body)).await })
        })
        .collect();
    let mut accepted = 0;
    for t in tasks {
        let a = t.await.unwrap();
        match a.status {
            202 => accepted += 1,
            _ => {
                let p = a.assert_problem(503, None);
                assert!(
                    p["detail"].as_str().unwrap().contains("jobs.max_live"),
                    "{p}"
                );
            }
        }
    }
    assert_eq!(accepted, 64);
    assert_eq!(state.jobs().live(), 64);
}

/// A job's frame is validated at submission like the same scene posted to `/v1/render`: a
/// scene naming a file of the server is refused at once, naming the item and the field.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_frame_naming_a_server_file_is_refused_at_submission() {
    let dir = Scratch::new("router-job-files");
    let state = state(&dir);
    let mut scene: Value =
        serde_json::from_str(skybake_product::frame::example_scene("validation-frame").unwrap())
            .unwrap();
    scene["cloud"]["source"] = json!({"type": "grid", "path": "/etc/passwd"});
    let p = call(
        &state,
        "POST",
        "/v1/jobs",
        Some(json!({"frames": [{"scene": scene, "method": "fast"}]})),
    )
    .await
    .assert_problem(422, Some("frames[0][0].cloud.source.path"));
    assert!(p["detail"].as_str().unwrap().contains("/etc/passwd"), "{p}");
    assert_eq!(state.jobs().live(), 0);
}
