//! The OpenVDB grid source through the user's paths: a frame of the reference library's `.vdb`
//! renders as the frame of the `.npy` of the same voxels (library and CLI), the CLI reads a
//! `.vdb` relative to the scene, and the service renders the example `.vdb` scene but no file of
//! its machine, refusing a wrong grid name as a 4xx naming the parameter.

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use serde_json::{json, Value};
use service_support::{settings, Scratch};
use skybake_physics::cloud::import;
use skybake_physics::Error;
use skybake_product::frame::{example_scene, FrameRequest};
use skybake_render::Method;
use skybake_service::{app, AppState};
use tower::ServiceExt;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");

fn fixtures() -> Value {
    serde_json::from_str(include_str!("../data/cloud_vdb_fixtures.json")).unwrap()
}

fn files(path: &str) -> skybake_physics::Result<Vec<u8>> {
    std::fs::read(std::path::Path::new(DATA).join(path)).map_err(|e| Error::invalid("path", e))
}

/// The validation frame (vacuum, constant sky), small, looking at the fixture's cloud.
fn frame_with(source: Value) -> Value {
    let mut scene: Value =
        serde_json::from_str(example_scene("validation-frame").unwrap()).unwrap();
    scene["camera"]["width"] = json!(40);
    scene["camera"]["height"] = json!(30);
    scene["camera"]["position_m"] = json!([-925, -1500, 1650]);
    scene["camera"]["look_at_m"] = json!([-925, 875, 1740]);
    scene["quality"] = json!("draft");
    scene["cloud"] = json!({"voxel_size_m": 25.0, "source": source});
    scene
}

fn npy_source() -> Value {
    let meta = &fixtures()["density_npy"];
    json!({"type": "grid", "path": "cloud_vdb_density.npy",
           "file_voxel_size_m": meta["voxel_size_m"], "origin_m": meta["origin_m"]})
}

#[test]
fn a_vdb_frame_renders_as_the_npy_frame_of_the_same_voxels() {
    let engine = skybake_engine::engine::Engine::new();
    let render = |source: Value| {
        FrameRequest::from_value(&frame_with(source), Method::Fast)
            .unwrap()
            .compute(&engine, &files, &|_| {}, &|| false)
            .unwrap()
    };
    let npy = render(npy_source());
    let vdb = render(json!({"type": "grid", "path": "cloud_vdb_density.vdb"}));
    let multi = render(json!({"type": "grid", "path": "cloud_vdb_multi.vdb"}));
    // The cloud is in the picture: some pixels see through less than half of it.
    let t = npy.layer("T").expect("a transmittance layer");
    assert!(t.planes()[0].iter().any(|&v| v < 0.5));
    for (what, frame) in [("density", &vdb), ("multi", &multi)] {
        assert_eq!(frame.layers(), npy.layers(), "{what}: the frames differ");
    }
}

#[test]
fn the_cli_reads_a_vdb_relative_to_the_scene() {
    let dir = Scratch::new("cli-vdb");
    std::fs::create_dir_all(dir.path().join("scenes/data")).unwrap();
    std::fs::copy(
        format!("{DATA}/cloud_vdb_multi.vdb"),
        dir.path().join("scenes/data/c.vdb"),
    )
    .unwrap();
    let scene = json!({"cloud": {"voxel_size_m": 25.0, "source":
        {"type": "grid", "path": "data/c.vdb", "grid_name": "density"}}});
    std::fs::write(dir.path().join("scenes/vdb.json"), scene.to_string()).unwrap();
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
            .args(args)
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    let out = run(&["clouds", "scenes/vdb.json", "--voxels", "out.npy"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: Value = serde_json::from_slice(&out.stdout).unwrap();
    let meta = &fixtures()["density_npy"];
    assert_eq!(summary["dims"], meta["dims_xyz"]);
    assert_eq!(summary["origin_m"], meta["origin_m"]);
    let written = std::fs::read(dir.path().join("out.npy")).unwrap();
    let expected = import::from_npy_bytes(
        &files("cloud_vdb_density.npy").unwrap(),
        25.0,
        glam::DVec3::ZERO,
    )
    .unwrap();
    assert_eq!(written, import::to_npy_bytes(&expected));
    // A grid that is not a density: exit 2 naming the parameter.
    let bad = json!({"cloud": {"voxel_size_m": 25.0, "source":
        {"type": "grid", "path": "data/c.vdb", "grid_name": "vel"}}});
    std::fs::write(dir.path().join("scenes/bad.json"), bad.to_string()).unwrap();
    let out = run(&["clouds", "scenes/bad.json"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("grid_name") && stderr.contains("vec3s"),
        "{stderr}"
    );
}

async fn post_render(state: AppState, scene: &Value) -> (u16, Value) {
    let req = Request::builder()
        .method("POST")
        .uri("/v1/render?format=json")
        .body(Body::from(scene.to_string()))
        .unwrap();
    let resp = app(state).oneshot(req).await.unwrap();
    let status = resp.status().as_u16();
    let body = axum::body::to_bytes(resp.into_body(), 64 << 20)
        .await
        .unwrap();
    (status, serde_json::from_slice(&body).unwrap_or(Value::Null))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_service_renders_the_example_vdb_and_no_file_of_its_machine() {
    let dir = Scratch::new("http-vdb");
    let state = AppState::new(settings(&dir.path().join("cache"))).unwrap();
    // The example's cloud and camera in the validation frame's vacuum light (cheap to render).
    let example: Value = serde_json::from_str(example_scene("vdb-cloud").unwrap()).unwrap();
    let mut scene: Value =
        serde_json::from_str(example_scene("validation-frame").unwrap()).unwrap();
    scene["cloud"] = example["cloud"].clone();
    scene["camera"] = example["camera"].clone();
    scene["camera"]["width"] = json!(24);
    scene["camera"]["height"] = json!(18);
    scene["quality"] = json!("draft");
    let (status, body) = post_render(state.clone(), &scene).await;
    assert_eq!(status, 200, "{body}");
    // A wrong grid name: a 4xx naming it, with the file's grids.
    let mut wrong = scene.clone();
    wrong["cloud"]["source"]["grid_name"] = json!("smoke");
    let (status, problem) = post_render(state.clone(), &wrong).await;
    assert!((400..500).contains(&status), "{status} {problem}");
    assert!(
        problem["parameter"]
            .as_str()
            .unwrap()
            .ends_with("grid_name"),
        "{problem}"
    );
    assert!(
        problem["detail"].as_str().unwrap().contains("'density'"),
        "{problem}"
    );
    // A .vdb of the server's disk is never read.
    let mut outside = scene.clone();
    outside["cloud"]["source"]["path"] = json!(format!("{DATA}/cloud_vdb_density.vdb"));
    let (status, problem) = post_render(state, &outside).await;
    assert!((400..500).contains(&status), "{status} {problem}");
    assert!(
        problem["parameter"].as_str().unwrap().ends_with("path"),
        "{problem}"
    );
}
