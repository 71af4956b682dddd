//! Cloud frames through the service: `POST /v1/render` in its three
//! formats, cached under the frame request's key, rendered and stored tile by tile so that an
//! interrupted render resumes from its stored tiles (and gives the frame an uninterrupted render
//! gives), stopped at the next tile when its client hangs up; bad scenes refused with
//! problem+json naming the field; the example scenes at `/v1/scenes`.

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use serde_json::{json, Value};
use service_support::{settings, tiny_frame_scene, Scratch, TestServer};
use skybake_engine::engine::Engine;
use skybake_product::frame::FrameRequest;
use skybake_product::frame::{example_file, TileProgress};
use skybake_render::Method;
use skybake_service::{app, AppState};
use skybake_store::{decode_exr, TileStore};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;
use tower::ServiceExt;

async fn post(
    state: &AppState,
    uri: &str,
    body: Vec<u8>,
    accept: Option<&str>,
) -> (u16, Vec<(String, String)>, Vec<u8>) {
    let mut req = Request::builder().method("POST").uri(uri);
    if let Some(a) = accept {
        req = req.header("accept", a);
    }
    let r = service_support::send(state, req.body(Body::from(body)).unwrap()).await;
    (r.status, r.headers, r.body)
}

fn header<'a>(headers: &'a [(String, String)], name: &str) -> Option<&'a str> {
    headers
        .iter()
        .find(|(k, _)| k.eq_ignore_ascii_case(name))
        .map(|(_, v)| v.as_str())
}

/// The pixels of an artifact: every layer's planes and the RGB, as bits.
fn pixels(bytes: &[u8]) -> Vec<Vec<u32>> {
    let img = decode_exr(bytes).unwrap();
    let mut planes: Vec<Vec<u32>> = img
        .layers()
        .iter()
        .flat_map(|l| {
            l.planes()
                .iter()
                .map(|p| p.iter().map(|v| v.to_bits()).collect())
        })
        .collect();
    for p in img.rgb().unwrap() {
        planes.push(p.iter().map(|v| v.to_bits()).collect());
    }
    planes
}

#[test]
fn an_interrupted_render_resumes_from_its_tiles_and_matches_an_uninterrupted_one() {
    let dir = Scratch::new("render-resume");
    let store = TileStore::open(&dir.path().join("tiles")).unwrap();
    let engine = Engine::new();
    for (method, (w, h)) in [(Method::Fast, (150, 100)), (Method::Reference, (160, 8))] {
        let req = FrameRequest::from_value(&tiny_frame_scene(w, h), method).unwrap();
        let total = req.tile_count();
        assert_eq!(total, w.div_ceil(64) * h.div_ceil(64));
        let tiles = store.frame(&req.cache_key()).unwrap();
        // First run: cancelled once two tiles are done (as a kill or a hung-up client would).
        let done = AtomicUsize::new(0);
        let progress = |p: TileProgress| done.store(p.done, Ordering::SeqCst);
        let cancel = || done.load(Ordering::SeqCst) >= 2;
        let first = req.compute_tiled(&engine, &example_file, &tiles, &progress, &cancel);
        assert!(
            first.is_err(),
            "{method:?}: the cancelled render must not finish"
        );
        assert_eq!(tiles.count(), 2, "{method:?}");
        // Second run: takes the two stored tiles, computes only the others.
        let computed = AtomicUsize::new(0);
        let progress = |p: TileProgress| {
            assert_eq!(p.reused, 2);
            computed.store(p.done - p.reused, Ordering::SeqCst);
        };
        let resumed = req
            .compute_tiled(&engine, &example_file, &tiles, &progress, &|| false)
            .unwrap();
        assert_eq!(computed.load(Ordering::SeqCst), total - 2, "{method:?}");
        let tiles_attr: Value =
            serde_json::from_str(resumed.attribute("skybakeFrameTiles").unwrap()).unwrap();
        assert_eq!(
            tiles_attr,
            json!({"tile_size": 64, "total": total, "computed": total - 2, "reused": 2})
        );
        // The same frame, bit for bit, as one uninterrupted render (and the same noise estimate).
        let whole = req
            .compute(&engine, &example_file, &|_| {}, &|| false)
            .unwrap();
        let enc = |i: &skybake_physics::image::SpectralImage| skybake_store::encode_exr(i).unwrap();
        assert_eq!(pixels(&enc(&resumed)), pixels(&enc(&whole)), "{method:?}");
        let noise = |i: &skybake_physics::image::SpectralImage| -> Value {
            serde_json::from_str::<Value>(i.attribute("skybakeFrameMeta").unwrap()).unwrap()
                ["error_estimate"]
                .clone()
        };
        assert_eq!(noise(&resumed), noise(&whole));
        if method == Method::Reference {
            assert!(
                noise(&whole)["path_tracer_relative_noise"]
                    .as_f64()
                    .unwrap()
                    > 0.0
            );
        }
        // A run that finds every tile renders nothing (not even the light: a fresh engine builds
        // no table) and gives the same frame.
        let fresh = Engine::new();
        let again = req
            .compute_tiled(
                &fresh,
                &example_file,
                &tiles,
                &|p| assert_eq!(p.done, p.reused),
                &|| false,
            )
            .unwrap();
        assert_eq!(pixels(&enc(&again)), pixels(&enc(&whole)));
        assert_eq!(
            fresh.table_builds(skybake_engine::engine::Table::Density),
            0
        );
        tiles.remove_all().unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn render_answers_json_exr_and_png_from_one_cached_artifact() {
    let dir = Scratch::new("render-formats");
    let state = AppState::new(settings(dir.path())).unwrap();
    let scene = serde_json::to_vec(&tiny_frame_scene(80, 60)).unwrap();

    let (status, h, body) = post(&state, "/v1/render?format=json", scene.clone(), None).await;
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    assert_eq!(header(&h, "content-type"), Some("application/json"));
    assert_eq!(header(&h, "x-cache"), Some("miss"));
    let key = header(&h, "x-skybake-cache-key").unwrap().to_string();
    assert_eq!(header(&h, "etag"), Some(format!("\"{key}-json\"").as_str()));
    let doc: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(
        (doc["width"].clone(), doc["height"].clone()),
        (json!(80), json!(60))
    );
    assert_eq!(doc["cache_key"], json!(key));
    assert_eq!(doc["tiles"]["total"], 2);
    assert!(doc["stages"]["ran"]
        .as_array()
        .is_some_and(|r| !r.is_empty()));
    assert!(doc["timing_ms_by_stage"]
        .as_array()
        .is_some_and(|r| r.len() >= 3));
    assert!(doc["error_estimate"].is_object());
    assert_eq!(
        header(&h, "cache-control"),
        Some("public, max-age=86400"),
        "frames are cacheable like products"
    );
    // The ETag is known before anything is computed: If-None-Match gets 304 at once.
    let conditional = Request::builder()
        .method("POST")
        .uri("/v1/render?format=json")
        .header("if-none-match", format!("\"{key}-json\""))
        .body(Body::from(scene.clone()))
        .unwrap();
    let r = service_support::send(&state, conditional).await;
    assert_eq!(r.status, 304);
    assert!(r.body.is_empty());
    let other = Request::builder()
        .method("POST")
        .uri("/v1/render?format=exr")
        .header("if-none-match", format!("\"{key}-json\""))
        .body(Body::from(scene.clone()))
        .unwrap();
    assert_eq!(
        service_support::send(&state, other).await.status,
        200,
        "another format's tag"
    );
    // The key is the frame request's (method included; name and description excluded).
    let req = FrameRequest::parse(&scene, Method::Fast).unwrap();
    assert_eq!(key, req.cache_key());

    let (status, h, exr) = post(&state, "/v1/render?format=exr", scene.clone(), None).await;
    assert_eq!(status, 200);
    assert_eq!(header(&h, "content-type"), Some("image/x-exr"));
    assert_eq!(header(&h, "x-cache"), Some("hit"));
    assert_eq!(header(&h, "etag"), Some(format!("\"{key}-exr\"").as_str()));
    let image = decode_exr(&exr).unwrap();
    assert_eq!((image.width(), image.height()), (80, 60));
    assert_eq!(image.attribute("skybakeCacheKey"), Some(key.as_str()));
    assert_eq!(state.metrics().computations("frame"), 1);
    // The finished frame's tiles are gone; the artifact is in the cache.
    assert_eq!(
        TileStore::open(&dir.path().join("tiles"))
            .unwrap()
            .frame(&key)
            .unwrap()
            .count(),
        0
    );

    // Accept picks the format when the query does not.
    let (status, h, png) = post(&state, "/v1/render", scene.clone(), Some("image/png")).await;
    assert_eq!(status, 200);
    assert_eq!(header(&h, "content-type"), Some("image/png"));
    assert_eq!(&png[1..4], b"PNG");
    // Another method is another product.
    let (status, h, _) = post(
        &state,
        "/v1/render?format=json&method=reference",
        scene,
        None,
    )
    .await;
    assert_eq!(status, 200);
    assert_ne!(header(&h, "x-skybake-cache-key"), Some(key.as_str()));
    assert_eq!(state.metrics().computations("frame"), 2);
}

/// (what, how the scene is spoiled, status, the field the problem names).
type Case = (&'static str, Box<dyn Fn(&mut Value)>, u16, &'static str);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_scenes_are_refused_naming_the_field_and_the_limit() {
    let dir = Scratch::new("render-bad");
    let mut s = settings(dir.path());
    s.server.body_limit_bytes = 16 * 1024;
    let state = AppState::new(s).unwrap();
    let base = tiny_frame_scene(32, 24);
    let cases: Vec<Case> = vec![
        (
            "zero fov",
            Box::new(|v: &mut Value| v["camera"]["fov_deg"] = json!(0)),
            400,
            "camera.fov_deg",
        ),
        (
            "looking nowhere",
            Box::new(|v: &mut Value| v["camera"]["look_at_m"] = v["camera"]["position_m"].clone()),
            422,
            "camera",
        ),
        (
            "g outside (-1, 1)",
            Box::new(|v: &mut Value| {
                v["optics"]["phase"] = json!({"henyey_greenstein": {"g": 1.5}})
            }),
            400,
            "optics.phase.g",
        ),
        (
            "NaN optics",
            Box::new(|v: &mut Value| v["optics"]["extinction_per_density_m"] = json!("NaN")),
            422,
            "optics",
        ),
        (
            "negative optics",
            Box::new(|v: &mut Value| v["optics"]["single_scattering_albedo"] = json!(-0.5)),
            400,
            "optics.single_scattering_albedo",
        ),
        (
            "too many pixels",
            Box::new(|v: &mut Value| {
                v["camera"]["width"] = json!(16384);
                v["camera"]["height"] = json!(16384);
            }),
            413,
            "camera.width",
        ),
        (
            "grid over the limit",
            Box::new(|v: &mut Value| v["cloud"]["voxel_size_m"] = json!(2.0)),
            413,
            "voxel_size_m",
        ),
        (
            // Under the cloud module's 512³ but over the renderer's 2²³ voxels: refused from the
            // balls' box before anything is voxelised (it used to build 6.4e7 voxels first).
            "grid over the render limit",
            Box::new(|v: &mut Value| v["cloud"]["voxel_size_m"] = json!(5.0)),
            413,
            "cloud.voxel_size_m",
        ),
        (
            "a file of the server",
            Box::new(|v: &mut Value| {
                v["cloud"]["source"] = json!({"type": "grid", "path": "/etc/passwd"})
            }),
            422,
            "path",
        ),
        (
            "a sun given both by direction and by place and time",
            Box::new(|v: &mut Value| {
                v["sun"] = json!({"elevation_deg": 30, "azimuth_deg": 0, "latitude_deg": 45,
                                  "longitude_deg": 0, "time": "2026-06-21T12:00:00Z"})
            }),
            422,
            "sun",
        ),
    ];
    for (what, change, status, field) in cases {
        let mut scene = base.clone();
        change(&mut scene);
        let (got, h, body) = post(
            &state,
            "/v1/render?format=json",
            serde_json::to_vec(&scene).unwrap(),
            None,
        )
        .await;
        let text = String::from_utf8_lossy(&body);
        assert_eq!(got, status, "{what}: {text}");
        assert_eq!(
            header(&h, "content-type"),
            Some("application/problem+json"),
            "{what}"
        );
        let problem: Value = serde_json::from_slice(&body).unwrap();
        assert!(
            problem["parameter"]
                .as_str()
                .is_some_and(|p| p.contains(field)),
            "{what}: parameter {} does not name {field}",
            problem["parameter"]
        );
    }
    // The body limit is stated.
    let mut big = base.clone();
    big["doc"] = json!({"padding": "x".repeat(20_000)});
    let (got, _, body) = post(
        &state,
        "/v1/render",
        serde_json::to_vec(&big).unwrap(),
        None,
    )
    .await;
    assert_eq!(got, 413, "{}", String::from_utf8_lossy(&body));
    let problem: Value = serde_json::from_slice(&body).unwrap();
    assert!(
        problem["detail"].as_str().unwrap().contains("16384 bytes"),
        "{problem}"
    );
    // Not JSON, unknown parameter, unknown format or method.
    let (got, _, _) = post(&state, "/v1/render", b"{not json".to_vec(), None).await;
    assert_eq!(got, 422);
    let ok = serde_json::to_vec(&base).unwrap();
    for (uri, status, name) in [
        ("/v1/render?colour=red", 400, "colour"),
        ("/v1/render?format=tiff", 422, "format"),
        ("/v1/render?method=magic", 422, "method"),
    ] {
        let (got, _, body) = post(&state, uri, ok.clone(), None).await;
        assert_eq!(got, status, "{uri}");
        let problem: Value = serde_json::from_slice(&body).unwrap();
        assert_eq!(problem["parameter"], json!(name), "{uri}");
    }
    // Nothing reached the computation: the grids over the limits and the server's file were
    // refused when the request was read.
    assert_eq!(state.metrics().computations("frame"), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_render_whose_client_hangs_up_stops_at_the_next_tile_and_a_retry_resumes() {
    let dir = Scratch::new("render-hangup");
    let srv = TestServer::start(settings(dir.path())).await;
    // The path tracer on 8 tiles of 64 × 8: slow enough per cloud tile that the client leaves mid-render.
    let scene = tiny_frame_scene(512, 8).to_string();
    let uri = "/v1/render?format=json&method=reference";
    let m = srv.state.metrics();
    let addr = srv.addr;
    let (body, u) = (scene.clone(), uri.to_string());
    let client = tokio::spawn(async move {
        service_support::request(addr, "POST", &u, Some(body.as_bytes())).await
    });
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    while m.frame_tiles_computed.load(Ordering::SeqCst) < 1 {
        assert!(tokio::time::Instant::now() < deadline, "no tile finished");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    client.abort(); // the client hangs up (its socket is closed)
    while m.frames_abandoned.load(Ordering::SeqCst) < 1 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the render did not stop"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let stored = m.frame_tiles_computed.load(Ordering::SeqCst) as usize;
    let key = FrameRequest::parse(scene.as_bytes(), Method::Reference)
        .unwrap()
        .cache_key();
    let tiles = TileStore::open(&dir.path().join("tiles"))
        .unwrap()
        .frame(&key)
        .unwrap();
    assert_eq!(tiles.count(), stored);
    assert!((1..8).contains(&stored), "{stored} tiles stored");
    assert!(!srv.state.cache().contains(&key));
    // The retry computes only the tiles that were not stored.
    let resp = srv.post(uri, &scene).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let doc = resp.json();
    assert_eq!(
        doc["tiles"],
        json!({"tile_size": 64, "total": 8, "computed": 8 - stored, "reused": stored})
    );
    assert_eq!(m.frame_tiles_computed.load(Ordering::SeqCst), 8);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn example_scenes_are_listed_served_and_render() {
    let dir = Scratch::new("scenes");
    let state = AppState::new(settings(dir.path())).unwrap();
    let get = |uri: &str| {
        let req = Request::builder().uri(uri).body(Body::empty()).unwrap();
        let state = state.clone();
        async move {
            let resp = app(state).oneshot(req).await.unwrap();
            let status = resp.status().as_u16();
            (
                status,
                axum::body::to_bytes(resp.into_body(), 1 << 24)
                    .await
                    .unwrap()
                    .to_vec(),
            )
        }
    };
    let (status, body) = get("/v1/scenes").await;
    assert_eq!(status, 200);
    let list: Value = serde_json::from_slice(&body).unwrap();
    let scenes = list["scenes"].as_array().unwrap();
    // Every file of config/scenes/ is listed.
    let on_disk = std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "json")
        })
        .count();
    assert_eq!(scenes.len(), on_disk);
    let mut frames = 0;
    for s in scenes {
        let name = s["name"].as_str().unwrap();
        assert!(!s["description"].as_str().unwrap().is_empty(), "{name}");
        let (status, body) = get(&format!("/v1/scenes/{name}")).await;
        assert_eq!(status, 200, "{name}");
        let on_disk = std::fs::read(format!(
            "{}/config/scenes/{name}.json",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap();
        assert_eq!(body, on_disk, "{name}: served as stored");
        // A frame scene is what /v1/render takes, as it is.
        let parsed = FrameRequest::parse(&body, Method::Fast);
        assert_eq!(
            parsed.is_ok(),
            s["frame"] == json!(true),
            "{name}: {parsed:?}"
        );
        frames += usize::from(parsed.is_ok());
    }
    assert!(frames >= 2);
    let (status, body) = get("/v1/scenes/no-such-scene").await;
    assert_eq!(status, 404);
    assert!(String::from_utf8_lossy(&body).contains("cumulus-frame"));
    // The OpenAPI document lists the new routes.
    let (_, body) = get("/openapi.json").await;
    let doc: Value = serde_json::from_slice(&body).unwrap();
    assert!(doc["paths"]["/v1/render"]["post"]["requestBody"].is_object());
    assert!(doc["paths"]["/v1/scenes"]["get"].is_object());
    assert!(doc["paths"]["/v1/scenes/{name}"]["get"].is_object());
    assert!(doc["components"]["schemas"]["JobRequest"]["properties"]["frames"].is_object());
    // The satellite example names its PNG; the service has it embedded.
    let sat = get("/v1/scenes/satellite-field").await.1;
    let section = skybake_physics::cloud::scene::parse_scene_file(&sat).unwrap();
    assert!(section.voxelize(&example_file).is_ok());
}

/// Render tiles count in the cache's disk budget: tiles left by three interrupted
/// renders that together exceed the budget are evicted at start-up, the least recently written
/// frame first, until they fit.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn render_tiles_count_in_the_disk_budget_and_are_evicted_oldest_first() {
    use skybake_physics::image::layout::EMISSIVE_LAYER;
    use skybake_store::{encode_exr, SpectralImage};
    let dir = Scratch::new("render-tile-budget");
    let keys: Vec<String> = ["a1", "b2", "c3"].iter().map(|k| k.repeat(32)).collect();
    let store = TileStore::open(&dir.path().join("tiles")).unwrap();
    let mut size = 0;
    for (i, key) in keys.iter().enumerate() {
        let tiles = store.frame(key).unwrap();
        // Incompressible values, so each tile file has about the same size.
        let values: Vec<f32> = (0..64 * 64)
            .map(|k| f32::from_bits(0x3f80_0000 | ((k as u32 * 2_654_435_761 + i as u32) >> 9)))
            .collect();
        let mut img = SpectralImage::new(64, 64, &[550.0]).unwrap();
        img.add_layer(EMISSIVE_LAYER, vec![values]).unwrap();
        img.set_attribute(skybake_store::tiles::ATTR_TILE_OF, tiles.binding(0))
            .unwrap();
        let bytes = encode_exr(&img).unwrap();
        size = size.max(bytes.len() as u64);
        tiles.put(0, &bytes).unwrap();
        std::thread::sleep(Duration::from_millis(30));
    }
    let mut s = settings(dir.path());
    s.cache.disk_budget_bytes = 2 * size + size / 4;
    let state = AppState::new(s).unwrap();
    let left: Vec<usize> = keys
        .iter()
        .map(|k| store.frame(k).unwrap().count())
        .collect();
    assert_eq!(left, [0, 1, 1], "the oldest frame's tiles go first");
    drop(state);
}
