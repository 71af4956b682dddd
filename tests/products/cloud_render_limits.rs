//! The renderer's voxel limit (`render::MAX_RENDER_VOXELS`, 2²³) for every cloud source, checked
//! as soon as the grid's size is known and before the grid is built: from the file header for
//! `grid` (`.npy` and raw), from the grown or fitted balls for `fractal` and `satellite`, from
//! the sphere hierarchy for `spheres` (metaballs and the automaton are refused when the scene is
//! parsed). Every case here is under the cloud module's own 512³ limit, so before the check they
//! were voxelised in full and refused afterwards. The error is "too large" on
//! `cloud.voxel_size_m`: HTTP 413, CLI exit 2.

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use glam::DVec3;
use serde_json::{json, Value};
use service_support::{settings, Scratch};
use skybake_physics::cloud::import::{to_npy_bytes, to_raw_f32};
use skybake_physics::cloud::scene::{parse_cloud_section, voxelize_within};
use skybake_physics::cloud::DensityGrid;
use skybake_physics::Error;
use skybake_product::frame::FrameRequest;
use skybake_product::frame::{example_file, EXAMPLE_SCENES};
use skybake_render::{Method, MAX_RENDER_VOXELS};
use skybake_service::{app, AppState};
use tower::ServiceExt;

fn example(name: &str) -> Value {
    let text = EXAMPLE_SCENES.iter().find(|(n, _)| *n == name).unwrap().1;
    serde_json::from_str(text).unwrap()
}

/// The validation frame (small, vacuum) with another cloud section.
fn frame_with(cloud: Value) -> Value {
    let mut scene = example("validation-frame");
    scene["camera"]["width"] = json!(16);
    scene["camera"]["height"] = json!(16);
    scene["quality"] = json!("draft");
    scene["cloud"] = cloud;
    scene
}

/// A 16³ grid of 100 m voxels (1.6 km box): 4096 voxels in the file.
fn small_grid() -> DensityGrid {
    DensityGrid::from_fn([16; 3], 100.0, DVec3::new(-800.0, -800.0, 1000.0), |p| {
        (1.0 - p.distance(DVec3::new(0.0, 0.0, 1800.0)) / 800.0).max(0.0) as f32
    })
    .unwrap()
}

/// Files the scenes name.
fn loader(name: &str) -> skybake_physics::Result<Vec<u8>> {
    let grid = small_grid();
    match name {
        "grid.npy" => Ok(to_npy_bytes(&grid)),
        "grid.raw" => Ok(to_raw_f32(&grid)?.1),
        "grid.json" => Ok(to_raw_f32(&grid)?.0),
        other => example_file(other),
    }
}

/// Cloud sections whose grid is over 2²³ voxels but under 512³, one per source checked here.
fn oversized_clouds() -> Vec<(&'static str, Value)> {
    let mut fractal = example("cumulus-fractal")["cloud"].clone();
    fractal["voxel_size_m"] = json!(6.0);
    let mut satellite = example("satellite-field")["cloud"].clone();
    satellite["voxel_size_m"] = json!(20.0);
    let mut spheres = example("sphere-cloud")["cloud"].clone();
    spheres["voxel_size_m"] = json!(5.0);
    vec![
        // 1.6 km at 6 m: 267³ = 1.9e7 voxels.
        (
            "grid npy",
            json!({"voxel_size_m": 6.0, "source": {"type": "grid", "path": "grid.npy",
                   "file_voxel_size_m": 100.0, "origin_m": [-800, -800, 1000]}}),
        ),
        (
            "grid raw",
            json!({"voxel_size_m": 6.0, "source": {"type": "grid", "path": "grid.raw"}}),
        ),
        ("fractal", fractal),
        ("satellite", satellite),
        ("spheres", spheres),
    ]
}

#[test]
fn every_source_is_refused_over_the_render_limit_naming_the_voxel_size() {
    let engine = service_support::shared_engine();
    for (what, cloud) in oversized_clouds() {
        let request = FrameRequest::from_value(&frame_with(cloud), Method::Fast)
            .unwrap_or_else(|e| panic!("{what}: parse: {e}"));
        let err = match request.compute(engine, &loader, &|_| {}, &|| false) {
            Ok(_) => panic!("{what}: rendered a grid over the limit"),
            Err(e) => e,
        };
        match &err {
            Error::TooLarge { field, limit, .. } => {
                assert_eq!(field, "cloud.voxel_size_m", "{what}: {err}");
                assert!(
                    limit.contains(&MAX_RENDER_VOXELS.to_string()),
                    "{what}: {err}"
                );
            }
            other => panic!("{what}: not too large: {other}"),
        }
        // `plan` (skybake plan frame, POST /v1/plan) voxelises too, and is refused the same way.
        match request.plan(service_support::shared_engine(), &loader) {
            Err(Error::TooLarge { field, .. }) => assert_eq!(field, "cloud.voxel_size_m"),
            other => panic!("{what}: plan: {other:?}"),
        }
    }
}

#[test]
fn the_limit_is_checked_before_the_grid_is_built() {
    // With a limit of 4095 voxels the 16³ file is refused from its header (1 voxel over), and
    // at 4096 it is read; the same file resampled to 50 m (32³) is refused from the header too.
    let section = |v: f64, path: &str| {
        parse_cloud_section(
            json!({"voxel_size_m": v, "source": {"type": "grid", "path": path,
                   "file_voxel_size_m": 100.0}})
            .to_string()
            .as_bytes(),
        )
        .unwrap()
    };
    for path in ["grid.npy", "grid.raw"] {
        let s = section(100.0, path);
        match voxelize_within(&s.source, 100.0, &loader, 4095) {
            Err(Error::TooLarge { field, reason, .. }) => {
                assert_eq!(field, "dims");
                assert!(reason.contains("[16, 16, 16]"), "{reason}");
            }
            other => panic!("{path}: {other:?}"),
        }
        let (grid, _) = voxelize_within(&s.source, 100.0, &loader, 4096).unwrap();
        assert_eq!(grid.dims, [16; 3]);
        let s = section(50.0, path);
        match voxelize_within(&s.source, 50.0, &loader, 4096) {
            Err(Error::TooLarge { reason, .. }) => {
                assert!(reason.contains("[32, 32, 32]"), "{reason}")
            }
            other => panic!("{path} at 50 m: {other:?}"),
        }
        assert_eq!(
            voxelize_within(&s.source, 50.0, &loader, 32 * 32 * 32)
                .unwrap()
                .0
                .dims,
            [32; 3]
        );
    }
    // Spheres: the hierarchy's box at the voxel size, before any density is summed.
    let spheres =
        parse_cloud_section(example("sphere-cloud")["cloud"].to_string().as_bytes()).unwrap();
    match voxelize_within(&spheres.source, 40.0, &loader, 1000) {
        Err(Error::TooLarge { field, .. }) => assert_eq!(field, "dims"),
        other => panic!("spheres: {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_answers_413_naming_the_voxel_size() {
    let dir = Scratch::new("render-limits");
    let state = AppState::new(settings(&dir.path().join("cache"))).unwrap();
    let mut spheres = example("sphere-cloud")["cloud"].clone();
    spheres["voxel_size_m"] = json!(5.0);
    let req = Request::builder()
        .method("POST")
        .uri("/v1/render?format=json")
        .body(Body::from(frame_with(spheres).to_string()))
        .unwrap();
    let resp = app(state).oneshot(req).await.unwrap();
    let status = resp.status().as_u16();
    let body = axum::body::to_bytes(resp.into_body(), 1 << 20)
        .await
        .unwrap();
    assert_eq!(status, 413, "{}", String::from_utf8_lossy(&body));
    let problem: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(problem["parameter"], "cloud.voxel_size_m", "{problem}");
}

#[test]
fn cli_exits_2_naming_the_voxel_size() {
    let dir = Scratch::new("render-limits-cli");
    std::fs::write(dir.path().join("grid.npy"), to_npy_bytes(&small_grid())).unwrap();
    let scene = dir.path().join("scene.json");
    let cloud = oversized_clouds().remove(0).1;
    std::fs::write(&scene, frame_with(cloud).to_string()).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(["render", scene.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("cloud.voxel_size_m"), "{stderr}");
    assert!(stderr.contains(&MAX_RENDER_VOXELS.to_string()), "{stderr}");
}
