//! The HTTP service end to end: a real server on an ephemeral port, spoken to over TCP.

use crate::service_support;

use service_support::{metric, settings, Scratch, TestServer, FAST};
use skybake_service::openapi::ROUTES;
use std::time::Duration;

const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_endpoint_answers_in_its_documented_form() {
    let dir = Scratch::new("endpoints");
    let srv = TestServer::start(settings(dir.path())).await;

    let sun = srv
        .get("/v1/sun?sun_elevation_deg=20&method=fast&quality=draft&wavelengths=440,550,680")
        .await;
    assert_eq!(sun.status, 200, "{}", sun.text());
    let v = sun.json();
    for field in [
        "wavelengths_nm",
        "solar_irradiance_w_m2_nm",
        "transmittance",
        "direct_normal_irradiance_w_m2_nm",
        "diffuse_horizontal_irradiance_w_m2_nm",
        "global_horizontal_irradiance_w_m2_nm",
    ] {
        assert_eq!(v[field].as_array().map(Vec::len), Some(3), "{field}");
    }
    assert!(v["error_estimate"].is_object() && v["timing_ms"].is_number());

    let sky = srv.get(&format!("/v1/sky?{FAST}")).await;
    assert_eq!(sky.status, 200, "{}", sky.text());
    assert_eq!(sky.header("content-type"), Some("application/json"));
    let v = sky.json();
    let rows = v["radiance_w_m2_sr_nm"].as_array().unwrap();
    assert_eq!(rows.len(), 9);
    assert_eq!(rows[0].as_array().unwrap().len(), 8);
    assert_eq!(rows[0][0].as_array().unwrap().len(), 3);
    assert_eq!(v["elevation_deg"].as_array().unwrap().len(), 9);

    let exr = srv.get(&format!("/v1/sky?{FAST}&format=exr")).await;
    assert_eq!(exr.status, 200);
    assert_eq!(exr.header("content-type"), Some("image/x-exr"));
    assert_eq!(exr.body[..4], EXR_MAGIC);
    let png = srv.get(&format!("/v1/sky?{FAST}&format=png")).await;
    assert_eq!(png.status, 200);
    assert_eq!(&png.body[1..4], b"PNG");

    let ground = srv
        .get("/v1/ground?method=fast&quality=draft&wavelengths=550&observer_altitude_m=3000&probe=120:0,180:0")
        .await;
    assert_eq!(ground.status, 200, "{}", ground.text());
    let probes = ground.json()["probes"].as_array().unwrap().clone();
    assert_eq!(probes.len(), 2);
    assert_eq!(probes[1]["view_zenith_deg"], 180.0);
    assert!(probes[0]["radiance_w_m2_sr_nm"][0].as_f64().unwrap() > 0.0);

    let aerial = srv
        .get("/v1/aerial?method=fast&quality=draft&wavelengths=550&elevation_count=3&azimuth_count=2&distance_count=4&max_distance_m=20000")
        .await;
    assert_eq!(aerial.status, 200, "{}", aerial.text());
    let v = aerial.json();
    assert_eq!(v["distance_m"].as_array().unwrap().len(), 4);
    let t = v["transmittance"][1][0][3][0].as_f64().unwrap();
    assert!(t > 0.0 && t < 1.0, "transmittance over 20 km: {t}");
    assert_eq!(v["transmittance"][1][0][0][0].as_f64(), Some(1.0));
    let aerial_exr = srv
        .get("/v1/aerial?method=fast&quality=draft&wavelengths=550&elevation_count=3&azimuth_count=2&distance_count=4&format=exr")
        .await;
    assert_eq!(aerial_exr.body[..4], EXR_MAGIC);

    let plan = srv
        .post("/v1/plan", r#"{"product": "sky", "sun_elevation_deg": -5, "ground_albedo": 0, "method": "fast", "wavelengths": [440, 550]}"#)
        .await;
    assert_eq!(plan.status, 200, "{}", plan.text());
    let v = plan.json();
    assert_eq!(v["cached"], false);
    assert_eq!(v["cache_key"].as_str().unwrap().len(), 64);
    assert_eq!(
        v["plan"]["left_out"][0],
        serde_json::json!({"stage": "ground_bounce", "reason": "zero_ground_albedo",
                            "detail": "the ground albedo is 0 at every wavelength"})
    );
    // Fast is retired: the precise tables at draft run, and the plan says why.
    assert_eq!(v["plan"]["method"], "precise", "{v}");
    assert_eq!(
        v["plan"]["method_substitution"]["reason"], "fast_retired",
        "{v}"
    );
    assert_eq!(v["plan"]["quality"], "draft", "{v}");
    let stages = v["plan"]["stages"].to_string();
    assert!(stages.contains("multiple_scattering"), "{stages}");
    // Direct sun: the same geometric test as the transmittance, observer altitude included.
    for (altitude, runs) in [(0, false), (400_000, true)] {
        let body = format!(
            r#"{{"product": "sun", "sun_elevation_deg": -10, "observer_altitude_m": {altitude}}}"#
        );
        let v = srv.post("/v1/plan", &body).await.json();
        let stages = v["plan"]["stages"].to_string();
        assert_eq!(stages.contains("direct_sun"), runs, "{altitude} m: {v}");
        let left_out = v["plan"]["left_out"].to_string();
        assert_eq!(
            left_out.contains("sun_below_horizon"),
            !runs,
            "{altitude} m: {v}"
        );
    }
    // A cloud frame's plan: the cloud is measured, nothing is lit or rendered.
    let scene: serde_json::Value =
        serde_json::from_str(include_str!("../../config/scenes/validation-frame.json")).unwrap();
    let body = serde_json::json!({"product": "frame", "scene": scene, "method": "fast"});
    let v = srv.post("/v1/plan", &body.to_string()).await.json();
    assert_eq!(v["product"], "frame", "{v}");
    let stages = v["plan"]["stages"].to_string();
    assert!(
        stages.contains("cloud_light") && stages.contains("multiple_scattering"),
        "{v}"
    );
    assert!(
        v["plan"]["budget"]["allowance"].as_f64().unwrap() > 0.0,
        "{v}"
    );
    let bad = srv
        .post("/v1/plan", r#"{"product": "frame", "scene": {}, "fov": 1}"#)
        .await;
    assert!((400..500).contains(&bad.status), "{}", bad.text());
    assert_eq!(
        srv.state.metrics().computations("sky"),
        1,
        "plan computes nothing"
    );

    let health = srv.get("/healthz").await;
    assert_eq!(
        (health.status, health.json()["status"].as_str()),
        (200, Some("ok"))
    );
    let metrics = srv.get("/metrics").await.text();
    for series in [
        "skybake_http_requests_total{route=\"/v1/sky\",method=\"GET\",status=\"200\"} 3",
        "skybake_computations_total{product=\"sky\"} 1",
        "skybake_cache_bytes_on_disk",
        "skybake_cache_evictions_total 0",
        "skybake_jobs_queue_depth 0",
        "skybake_engine_table_builds_total{table=\"fast\"}",
        "skybake_http_request_duration_seconds_bucket{route=\"/v1/sun\",le=\"+Inf\"} 1",
    ] {
        assert!(metrics.contains(series), "missing {series} in\n{metrics}");
    }
    let doc = srv.get("/openapi.json").await.json();
    assert_eq!(doc["openapi"], "3.1.0");
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_is_a_problem_naming_the_parameter() {
    let dir = Scratch::new("problems");
    let srv = TestServer::start(settings(dir.path())).await;
    let cases: [(&str, u16, &str); 14] = [
        ("/v1/sky?colour=blue&sun_elevation_deg=3", 400, "colour"),
        ("/v1/sky?sun_elevation_deg=95", 400, "sun_elevation_deg"),
        ("/v1/sun?sun_elevation_deg=-90.5", 400, "sun_elevation_deg"),
        ("/v1/sky?sun_elevation_deg=abc", 422, "sun_elevation_deg"),
        ("/v1/sky?method=magic", 422, "method"),
        ("/v1/sun?format=exr", 422, "format"),
        ("/v1/aerial?format=png", 422, "format"),
        (
            "/v1/sky?elevation_count=4096&azimuth_count=4096",
            413,
            "elevation_count",
        ),
        ("/v1/sky?wavelengths=100", 400, "wavelengths"),
        ("/v1/sky?quality=draft&quality=high", 422, "quality"),
        ("/v1/ground?probe=30:0", 400, "probe"),
        ("/v1/sky?visibility_km=0.5", 400, "visibility_km"),
        ("/v1/sky?aerosol_type=continental", 422, "aerosol_type"),
        (
            "/v1/sky?visibility_km=5&aerosol_type=volcanic",
            400,
            "aerosol_type",
        ),
    ];
    for (path, status, parameter) in cases {
        let r = srv.get(path).await;
        assert_eq!(r.status, status, "{path}: {}", r.text());
        assert_eq!(
            r.header("content-type"),
            Some("application/problem+json"),
            "{path}"
        );
        let v = r.json();
        assert_eq!(v["parameter"], parameter, "{path}: {v}");
        assert_eq!(v["status"], status);
        assert!(v["title"].is_string() && v["type"].is_string());
        assert!(
            v["detail"].as_str().unwrap().contains(parameter),
            "{path}: {v}"
        );
    }
    let r = srv
        .post("/v1/plan?product=sky", r#"{"product": "sky"}"#)
        .await;
    assert_eq!(
        (r.status, r.json()["parameter"].as_str()),
        (400, Some("product"))
    );
    let r = srv.post("/v1/plan", "{not json").await;
    assert_eq!(
        (r.status, r.json()["parameter"].as_str()),
        (400, Some("body"))
    );
    let r = srv
        .post(
            "/v1/plan",
            r#"{"product": "sky", "sun_elevation_deg": true}"#,
        )
        .await;
    assert_eq!(
        (r.status, r.json()["parameter"].as_str()),
        (422, Some("sun_elevation_deg"))
    );
    let r = srv.post("/v1/plan", r#"{"sun_elevation_deg": 3}"#).await;
    assert_eq!(
        (r.status, r.json()["parameter"].as_str()),
        (422, Some("product"))
    );
    let big = format!(
        r#"{{"product": "sky", "atmosphere": "{}"}}"#,
        "x".repeat(2 << 20)
    );
    let r = srv.post("/v1/plan", &big).await;
    assert_eq!(r.status, 413, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("application/problem+json"));
    let r = srv.get("/v1/nothing").await;
    assert_eq!(r.status, 404);
    assert_eq!(r.header("content-type"), Some("application/problem+json"));
    // POST /v1/render exists; GET does not.
    assert_eq!(srv.get("/v1/render").await.status, 405);
    assert_eq!(srv.get("/v1/jobs/00000000000000ff").await.status, 404);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn second_request_is_a_cache_hit_with_the_same_bytes() {
    let dir = Scratch::new("hit");
    let srv = TestServer::start(settings(dir.path())).await;
    let path = format!("/v1/sky?{FAST}&sun_elevation_deg=12&format=exr");
    let a = srv.get(&path).await;
    let b = srv.get(&path).await;
    assert_eq!((a.status, b.status), (200, 200));
    assert_eq!(a.header("x-cache"), Some("miss"));
    assert_eq!(b.header("x-cache"), Some("hit"));
    assert_eq!(a.body, b.body);
    // Another format of the same product comes from the product cache, not the engine.
    let c = srv.get(&path.replace("format=exr", "format=json")).await;
    assert_eq!(c.header("x-cache"), Some("hit"));
    let m = srv.get("/metrics").await.text();
    assert_eq!(
        metric(&m, "skybake_computations_total{product=\"sky\"}"),
        Some(1.0)
    );
    assert_eq!(metric(&m, "skybake_response_cache_hits_total"), Some(1.0));
    assert_eq!(metric(&m, "skybake_cache_hits_total"), Some(1.0));
    srv.stop().await;

    // Reused after a restart: served from disk, nothing recomputed.
    let srv = TestServer::start(settings(dir.path())).await;
    let d = srv.get(&path).await;
    assert_eq!(d.header("x-cache"), Some("hit"));
    assert_eq!(d.body, a.body);
    assert_eq!(srv.state.metrics().computations("sky"), 0);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn corrupted_cache_file_is_recomputed_not_served() {
    let dir = Scratch::new("corrupt");
    let mut s = settings(dir.path());
    s.cache.memory_budget_bytes = 0;
    s.cache.response_budget_bytes = 0;
    let srv = TestServer::start(s).await;
    let path = format!("/v1/sky?{FAST}&sun_elevation_deg=7&format=exr");
    let a = srv.get(&path).await;
    assert_eq!(a.status, 200);
    let key = a.header("x-skybake-cache-key").unwrap().to_string();
    let file = srv.state.cache().path_for(&key).unwrap();
    let mut bytes = std::fs::read(&file).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x5a;
    std::fs::write(&file, &bytes).unwrap();

    let b = srv.get(&path).await;
    assert_eq!(b.status, 200);
    assert_eq!(
        b.header("x-cache"),
        Some("miss"),
        "corrupt file must not be served"
    );
    assert_ne!(b.body, bytes);
    let (ia, ib) = (
        skybake_store::decode_exr(&a.body).unwrap(),
        skybake_store::decode_exr(&b.body).unwrap(),
    );
    assert_eq!(
        ia.layers(),
        ib.layers(),
        "recomputed values equal the first"
    );
    assert_eq!(srv.state.cache().stats().corrupt_detected, 1);
    assert_eq!(srv.state.metrics().computations("sky"), 2);
    // Truncation is caught too.
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 3]).unwrap();
    let c = srv.get(&path).await;
    assert_eq!((c.status, c.header("x-cache")), (200, Some("miss")));
    assert_eq!(srv.state.cache().stats().corrupt_detected, 2);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identical_concurrent_requests_compute_once() {
    let dir = Scratch::new("flight");
    let srv = TestServer::start(settings(dir.path())).await;
    let path = "/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=129&azimuth_count=64&sun_elevation_deg=4&format=exr";
    let n = 16;
    let tasks: Vec<_> = (0..n)
        .map(|_| {
            let addr = srv.addr;
            tokio::spawn(async move { service_support::request(addr, "GET", path, None).await })
        })
        .collect();
    let mut bodies = Vec::new();
    for t in tasks {
        let r = t.await.unwrap();
        assert_eq!(r.status, 200);
        bodies.push(r.body);
    }
    assert!(bodies.iter().all(|b| *b == bodies[0]));
    assert_eq!(srv.state.metrics().computations("sky"), 1);
    let joined = srv
        .state
        .metrics()
        .single_flight_joins
        .load(std::sync::atomic::Ordering::Relaxed);
    assert!(
        joined >= 1,
        "some requests should have joined the flight (joined {joined})"
    );
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disk_cache_keeps_to_a_small_budget() {
    let dir = Scratch::new("evict");
    let mut s = settings(dir.path());
    s.cache.disk_budget_bytes = 40_000;
    s.cache.response_budget_bytes = 0;
    let srv = TestServer::start(s).await;
    let paths: Vec<String> = (0..6)
        .map(|i| format!("/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=33&azimuth_count=32&sun_elevation_deg={}&format=exr", 10 + i))
        .collect();
    let mut size = 0;
    for p in &paths {
        let r = srv.get(p).await;
        assert_eq!(r.status, 200);
        size = r.body.len();
    }
    assert!(size > 5_000 && size < 40_000, "entry size {size}");
    let stats = srv.state.cache().stats();
    assert!(stats.evictions >= 1, "{stats:?}");
    assert!(stats.bytes_on_disk <= 40_000, "{stats:?}");
    let m = srv.get("/metrics").await.text();
    assert_eq!(
        metric(&m, "skybake_cache_evictions_total"),
        Some(stats.evictions as f64)
    );
    // The oldest entry was evicted: asking again computes it again.
    let r = srv.get(&paths[0]).await;
    assert_eq!(r.header("x-cache"), Some("miss"));
    assert_eq!(srv.state.metrics().computations("sky"), 7);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn excess_load_is_shed_and_slow_requests_time_out() {
    let dir = Scratch::new("shed");
    let mut s = settings(dir.path());
    s.server.concurrency_limit = 1;
    s.server.request_timeout_s = 0.3;
    // The cache policy that keeps an abandoned computation running (tests/service/service_cancel.rs
    // covers the default, cancelling it).
    s.server.finish_abandoned = true;
    let srv = TestServer::start(s).await;
    // A cold request slow enough to exceed the timeout (precise tables at standard, a large
    // table).
    let slow = "/v1/sky?method=precise&quality=standard&elevation_count=257&azimuth_count=128&sun_elevation_deg=33";
    let addr = srv.addr;
    let first =
        tokio::spawn(async move { service_support::request(addr, "GET", slow, None).await });
    tokio::time::sleep(Duration::from_millis(100)).await;
    let shed = srv.get("/v1/sun?method=fast&wavelengths=550").await;
    assert_eq!(shed.status, 503, "{}", shed.text());
    assert_eq!(shed.header("retry-after"), Some("1"));
    assert_eq!(shed.json()["type"], "urn:skybake:problem:overloaded");
    let first = first.await.unwrap();
    assert_eq!(first.status, 503, "{}", first.text());
    assert_eq!(first.json()["type"], "urn:skybake:problem:timeout");
    // Health checks are not limited.
    assert_eq!(srv.get("/healthz").await.status, 200);
    // A retry while the computation runs joins it instead of starting another.
    let retry = srv.get(slow).await;
    assert_eq!(retry.status, 503, "{}", retry.text());
    // The timed-out computation still finishes and lands in the cache.
    let key = {
        let pairs =
            skybake_service::extract::query_pairs(Some(&slow[slow.find('?').unwrap() + 1..]))
                .unwrap();
        let p = skybake_product::params::RequestParams::from_pairs(pairs).unwrap();
        srv.state
            .request(skybake_product::ProductKind::Sky, p)
            .unwrap()
            .cache_key()
    };
    let mut cached = false;
    for _ in 0..1800 {
        if srv.state.cache().contains(&key) {
            cached = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(cached, "detached computation should land in the cache");
    assert_eq!(srv.state.metrics().computations("sky"), 1);
    let joins = srv
        .state
        .metrics()
        .single_flight_joins
        .load(std::sync::atomic::Ordering::Relaxed);
    assert_eq!(joins, 1, "the retry joined the computation in flight");
    let m = srv.get("/metrics").await.text();
    assert!(metric(&m, "skybake_load_shed_total").unwrap() >= 1.0);
    assert!(metric(&m, "skybake_request_timeouts_total").unwrap() >= 1.0);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graceful_shutdown_finishes_requests_in_flight() {
    let dir = Scratch::new("graceful");
    let srv = TestServer::start(settings(dir.path())).await;
    let addr = srv.addr;
    let path = "/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=129&azimuth_count=64&sun_elevation_deg=21&format=exr";
    let pending =
        tokio::spawn(async move { service_support::request(addr, "GET", path, None).await });
    tokio::time::sleep(Duration::from_millis(50)).await;
    srv.stop().await;
    let r = pending.await.unwrap();
    assert_eq!(r.status, 200);
    assert_eq!(r.body[..4], EXR_MAGIC);
    assert!(
        tokio::net::TcpStream::connect(addr).await.is_err(),
        "listener closed"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_run_list_artifacts_and_refuse_oversized_grids() {
    let dir = Scratch::new("jobs");
    let srv = TestServer::start(settings(dir.path())).await;
    let body = r#"{"products": [{"product": "sun", "method": "fast", "wavelengths": "550"}],
        "grids": [{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "550",
                   "elevation_count": 9, "azimuth_count": 4,
                   "sweep": {"sun_elevation_deg": {"from": -6, "to": 0, "step": 3}}}]}"#;
    let r = srv.post("/v1/jobs", body).await;
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(r.json()["total"], 4);
    let mut status = serde_json::Value::Null;
    for _ in 0..3600 {
        status = srv.get(&format!("/v1/jobs/{id}")).await.json();
        if status["state"] == "completed" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(status["state"], "completed", "{status}");
    assert_eq!(
        (status["done"].as_u64(), status["failed"].as_u64()),
        (Some(4), Some(0))
    );
    let items = status["artifacts"]["items"].as_array().unwrap();
    assert_eq!(items.len(), 4);
    assert!(items.iter().all(|a| a["status"] == "done"));
    let key = items[2]["cache_key"].as_str().unwrap();
    assert!(srv.state.cache().contains(key));
    let exr = srv.get(items[2]["url"].as_str().unwrap()).await;
    assert_eq!((exr.status, exr.header("x-cache")), (200, Some("hit")));
    assert_eq!(exr.body[..4], EXR_MAGIC);
    // The same product by the ordinary route is the cached one.
    let direct = srv
        .get("/v1/sky?method=fast&quality=draft&wavelengths=550&elevation_count=9&azimuth_count=4&sun_elevation_deg=-3&format=exr")
        .await;
    assert_eq!(direct.header("x-skybake-cache-key"), Some(key));
    let sun = srv.get(&format!("/v1/jobs/{id}/artifacts/0")).await;
    assert_eq!(sun.json()["transmittance"].as_array().unwrap().len(), 1);
    assert_eq!(
        srv.get(&format!("/v1/jobs/{id}/artifacts/4")).await.status,
        404
    );
    assert_eq!(srv.state.metrics().computations("sky"), 3);

    let huge = r#"{"grids": [{"product": "sun", "sweep": {"sun_elevation_deg": {"from": -10, "to": 90, "step": 0.001}}}]}"#;
    let r = srv.post("/v1/jobs", huge).await;
    assert_eq!(r.status, 413, "{}", r.text());
    assert_eq!(r.json()["parameter"], "products", "{}", r.text());
    assert!(r.json()["detail"].as_str().unwrap().contains("100000"));
    let bad = r#"{"products": [{"product": "sky", "sun_elevation_deg": 120}]}"#;
    let r = srv.post("/v1/jobs", bad).await;
    assert_eq!(
        (r.status, r.json()["parameter"].as_str()),
        (400, Some("products[0].sun_elevation_deg"))
    );

    // Cancel: a queued job behind a long one stops before computing anything.
    let long = r#"{"grids": [{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "550",
        "elevation_count": 9, "azimuth_count": 4, "sweep": {"sun_elevation_deg": {"from": 30, "to": 89, "step": 1}}}]}"#;
    let a = srv.post("/v1/jobs", long).await.json()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let r = srv.delete(&format!("/v1/jobs/{a}")).await;
    assert_eq!(r.status, 200);
    let mut state = serde_json::Value::Null;
    for _ in 0..2000 {
        state = srv.get(&format!("/v1/jobs/{a}")).await.json();
        if state["state"] == "cancelled" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    assert_eq!(state["state"], "cancelled", "{state}");
    assert!(state["done"].as_u64().unwrap() < 60);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn openapi_lists_exactly_the_routes_served() {
    let dir = Scratch::new("openapi");
    let srv = TestServer::start(settings(dir.path())).await;
    let doc = srv.get("/openapi.json").await.json();
    let mut documented: Vec<(String, String)> = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for method in ops.as_object().unwrap().keys() {
            documented.push((method.to_uppercase(), path.clone()));
        }
    }
    let mut table: Vec<(String, String)> = ROUTES
        .iter()
        .map(|r| (r.method.to_string(), r.path.to_string()))
        .collect();
    documented.sort();
    table.sort();
    assert_eq!(documented, table);
    // Every documented route is served (not the router's fallback, not 405)...
    for (method, path) in &table {
        // An unknown parameter keeps product routes from computing (400, still routed).
        let concrete = path.replace("{id}", "00000000000000ff").replace("{n}", "0")
            + if path.starts_with("/v1/") {
                "?routed=1"
            } else {
                ""
            };
        let body = (method == "POST").then_some(&b"{}"[..]);
        let r = service_support::request(srv.addr, method, &concrete, body).await;
        assert_ne!(r.status, 405, "{method} {path}");
        let fallback = r.status == 404 && r.text().contains("no route");
        assert!(!fallback, "{method} {path} is documented but not routed");
    }
    // ...and routes outside the table are not.
    for (method, path) in [("GET", "/v1/render"), ("GET", "/v1"), ("PUT", "/v1/jobs")] {
        let r = service_support::request(srv.addr, method, path, None).await;
        assert!(
            r.status == 404 || r.status == 405,
            "{method} {path}: {}",
            r.status
        );
    }
    srv.stop().await;
}
