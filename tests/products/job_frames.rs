//! Frame bake jobs: a scene over a sun sweep or over automaton steps, as a job
//! entry (`"frames"`) of `POST /v1/jobs` and `skybake bake`; items named in errors; a killed bake
//! resumes from its finished frames and from the stored tiles of the frame in flight; a service
//! job's frames are the same cached products `POST /v1/render` serves.

use crate::service_support;

use serde_json::{json, Value};
use service_support::{settings, Scratch, TestServer};
use skybake_job::bake::{bake, bake_with_cancel};
use skybake_job::spec::JobSpec;
use skybake_job::JobError;
use skybake_product::frame::EXAMPLE_SCENES;
use skybake_product::params::Defaults;
use skybake_product::AnyRequest;
use skybake_store::{read_exr_file, TileStore};
use std::time::Duration;

fn example(name: &str) -> Value {
    let text = EXAMPLE_SCENES.iter().find(|(n, _)| *n == name).unwrap().1;
    serde_json::from_str(text).unwrap()
}

/// The validation scene, `w` × `h` pixels, draft quality, 100 m voxels.
fn tiny_scene(w: usize, h: usize) -> Value {
    let mut scene = example("validation-frame");
    scene["camera"]["width"] = json!(w);
    scene["camera"]["height"] = json!(h);
    scene["quality"] = json!("draft");
    scene["cloud"]["voxel_size_m"] = json!(100.0);
    scene
}

/// A small automaton field (48 × 32 × 12 cells of 100 m) seen from the side.
fn automaton_scene() -> Value {
    let mut scene = tiny_scene(48, 32);
    let mut cloud = example("automaton-field")["cloud"].clone();
    let p = &mut cloud["source"]["params"];
    p["dims"] = json!([48, 32, 12]);
    p["origin_m"] = json!([-2400.0, -1600.0, 500.0]);
    p["ellipsoids"] = json!([]);
    p["obstacle"] = Value::Null;
    p["wind"] = json!([{"height_cells": 0.0, "velocity_cells_per_step": 0.5}]);
    p["random_ellipsoids"]["count"] = json!(6);
    p["random_ellipsoids"]["semi_axes_min_cells"] = json!([4.0, 4.0, 2.0]);
    p["random_ellipsoids"]["semi_axes_max_cells"] = json!([8.0, 8.0, 3.0]);
    p["random_ellipsoids"]["centre_height_range_cells"] = json!([5.0, 7.0]);
    cloud["source"]["frame_time_steps"] = json!(0);
    scene["cloud"] = cloud;
    scene["camera"]["position_m"] = json!([0.0, -9000.0, 1100.0]);
    scene["camera"]["look_at_m"] = json!([0.0, 0.0, 1100.0]);
    scene
}

fn spec(body: Value) -> Result<JobSpec, JobError> {
    JobSpec::parse(body.as_object().unwrap(), 1000)
}

fn frame(spec: &JobSpec, i: usize) -> std::sync::Arc<skybake_product::frame::FrameRequest> {
    match spec.request(i, &Defaults::default()).unwrap() {
        AnyRequest::Frame(f) => f,
        AnyRequest::Atmosphere(_) => panic!("item {i} is not a frame"),
    }
}

#[test]
fn frame_entries_expand_sun_and_automaton_sweeps() {
    // Axes in name order, the last (sun_elevation_deg) fastest; products come first.
    let s = spec(json!({
        "products": [{"product": "sun", "sun_elevation_deg": 10}],
        "frames": [{"example": "cumulus-frame", "method": "reference",
                    "sweep": {"sun_elevation_deg": [10, 30], "sun_azimuth_deg": {"from": 0, "to": 90, "step": 90}}},
                   {"scene": automaton_scene(), "sweep": {"frame_time_steps": [20, 20.5]}}]
    }))
    .unwrap();
    assert_eq!(s.len(), 1 + 4 + 2);
    assert_eq!(s.item_name(0), Some("sun"));
    let suns: Vec<(f64, f64)> = (1..5)
        .map(|i| {
            let f = frame(&s, i);
            assert_eq!(f.method, skybake_render::Method::Reference);
            let sun = &f.scene_json()["sun"];
            (
                sun["azimuth_deg"].as_f64().unwrap(),
                sun["elevation_deg"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        suns,
        vec![(0.0, 10.0), (0.0, 30.0), (90.0, 10.0), (90.0, 30.0)]
    );
    // Different frames, different products.
    assert_ne!(frame(&s, 1).cache_key(), frame(&s, 2).cache_key());
    let steps: Vec<f64> = (5..7)
        .map(|i| {
            frame(&s, i).scene_json()["cloud"]["source"]["frame_time_steps"]
                .as_f64()
                .unwrap()
        })
        .collect();
    assert_eq!(steps, vec![20.0, 20.5]);
    // A place-and-time sun sweeps its time; a collimated sun its elevation.
    let mut timed = tiny_scene(32, 24);
    timed["sun"] =
        json!({"latitude_deg": 47.0, "longitude_deg": 8.0, "time": "2024-06-21T06:00:00Z"});
    timed["atmosphere"] = json!("earth");
    let s = spec(json!({"frames": [{"scene": timed, "sweep": {"time": ["2024-06-21T08:00:00Z", "2024-06-21T12:00:00Z"]}},
                                    {"scene": tiny_scene(32, 24), "sweep": {"sun_elevation_deg": [5]}}]}))
    .unwrap();
    assert_eq!(
        frame(&s, 1).scene_json()["sun"]["time"],
        json!("2024-06-21T12:00:00Z")
    );
    assert_eq!(
        frame(&s, 2).scene_json()["sun"]["collimated"]["elevation_deg"],
        json!(5)
    );
}

#[test]
fn frame_entry_mistakes_are_named() {
    let field = |body: Value| -> String {
        let e = match spec(body) {
            Err(e) => e,
            Ok(s) => s.validate(&Defaults::default()).unwrap_err(),
        };
        assert!(e.is_input(), "{e}");
        e.parameter().unwrap_or_default()
    };
    let tiny = tiny_scene(32, 24);
    assert_eq!(
        field(json!({"frames": [{"example": "nothing"}]})),
        "frames[0].example"
    );
    assert_eq!(
        field(json!({"frames": [{"example": "cumulus-frame", "scene": tiny}]})),
        "frames[0].scene"
    );
    assert_eq!(
        field(json!({"frames": [{"scene": tiny, "method": "magic"}]})),
        "frames[0].method"
    );
    assert_eq!(
        field(json!({"frames": [{"scene": tiny, "sweep": {"colour": [1]}}]})),
        "frames[0].sweep.colour"
    );
    assert_eq!(
        field(json!({"frames": [{"scene": tiny, "sweep": {"time": ["2024-06-21T08:00:00Z"]}}]})),
        "frames[0][0].time"
    );
    assert_eq!(
        field(json!({"frames": [{"scene": tiny, "sweep": {"frame_time_steps": [1]}}]})),
        "frames[0][0].frame_time_steps"
    );
    // The second frame's elevation is out of range: the item and the scene field are named.
    let f = field(json!({"frames": [{"scene": tiny, "sweep": {"sun_elevation_deg": [10, 200]}}]}));
    assert!(f.starts_with("frames[0][1].sun"), "{f}");
    let mut bad = tiny.clone();
    bad["optics"]["phase"] = json!({"henyey_greenstein": {"g": -1.0}});
    assert_eq!(
        field(json!({"frames": [{"scene": bad}]})),
        "frames[0][0].optics.phase.g"
    );
    // The job size limit counts frames.
    let e = spec(json!({"frames": [{"scene": tiny, "sweep": {"sun_elevation_deg": {"from": 0, "to": 90, "step": 0.01}}}]})).unwrap_err();
    assert!(
        matches!(&e, JobError::Param(skybake_physics::Error::TooLarge { .. })),
        "{e}"
    );
}

/// The error of a job body (at parsing or at validation, as a submission checks it).
fn job_error(body: Value) -> JobError {
    let e = match spec(body) {
        Err(e) => e,
        Ok(s) => s.validate(&Defaults::default()).unwrap_err(),
    };
    assert!(e.is_input(), "{e}");
    e
}

#[test]
fn a_frame_entry_target_sets_every_frame_s_key_and_budget() {
    use skybake_engine::plan::FRAME_MEASURED_ERROR;
    use skybake_product::frame::FrameRequest;
    use skybake_render::Method;
    let tiny = tiny_scene(32, 24);
    let sweep = json!({"sun_elevation_deg": [20, 40]});
    let targeted =
        spec(json!({"frames": [{"scene": tiny, "max_rel_error": 0.3, "sweep": sweep}]})).unwrap();
    let plain = spec(json!({"frames": [{"scene": tiny, "sweep": sweep}]})).unwrap();
    // As a string holding the number (as the parameter table's members of product items).
    let text =
        spec(json!({"frames": [{"scene": tiny, "max_rel_error": "0.3", "sweep": sweep}]})).unwrap();
    targeted.validate(&Defaults::default()).unwrap();
    let engine = service_support::shared_engine();
    let files = skybake_product::frame::example_file;
    for (k, elevation) in [(0, 20), (1, 40)] {
        let f = frame(&targeted, k);
        assert_eq!(f.max_rel_error, Some(0.3));
        assert_eq!(frame(&plain, k).max_rel_error, None);
        // The frame is the render request of the same scene with the same target: same key.
        let mut scene = tiny.clone();
        scene["sun"]["collimated"]["elevation_deg"] = json!(elevation);
        let render = FrameRequest::from_value(&scene, Method::Fast)
            .unwrap()
            .with_max_rel_error(Some("0.3"))
            .unwrap();
        assert_eq!(f.cache_key(), render.cache_key());
        assert_eq!(f.canonical_json(), render.canonical_json());
        assert_eq!(frame(&text, k).cache_key(), render.cache_key());
        // The target is part of the key; without one the key is the untargeted render's.
        assert_ne!(f.cache_key(), frame(&plain, k).cache_key());
        let untargeted = FrameRequest::from_value(&scene, Method::Fast).unwrap();
        assert_eq!(frame(&plain, k).cache_key(), untargeted.cache_key());
        // The target is the frame plan's budget: the cost rules may spend what it leaves over
        // the fast method's measured error.
        let plan = f.plan(engine, &files).unwrap();
        assert!((plan.budget.relative_error - 0.3).abs() < 1e-12, "{plan:?}");
        assert!(
            (plan.budget.allowance - (0.3 - FRAME_MEASURED_ERROR)).abs() < 1e-12,
            "{plan:?}"
        );
        let default = frame(&plain, k).plan(engine, &files).unwrap();
        assert!(
            default.budget.allowance < plan.budget.allowance,
            "{default:?}"
        );
    }
}

#[test]
fn a_bad_frame_entry_target_is_refused_naming_the_entry_s_field() {
    let tiny = tiny_scene(32, 24);
    let sweep = json!({"sun_elevation_deg": [20, 40]});
    let refused = |target: Value, method: &str| -> String {
        let e = job_error(json!({"products": [{"product": "sun"}],
            "frames": [{"scene": tiny, "method": method, "max_rel_error": target, "sweep": sweep}]}));
        assert_eq!(
            e.parameter().as_deref(),
            Some("frames[0].max_rel_error"),
            "{e}"
        );
        e.to_string()
    };
    // Under the fast method's measured error: the allowed range starts at the best achievable.
    let e = refused(json!(0.01), "fast");
    assert!(e.contains("0.0810 to 1"), "{e}");
    // Not a number; above 1 (the parameter table's range).
    let e = refused(json!("x"), "fast");
    assert!(e.contains("'x' is not a number"), "{e}");
    let e = refused(json!(2), "fast");
    assert!(e.contains("to 1"), "{e}");
    let e = refused(json!(true), "fast");
    assert!(e.contains("must be a number"), "{e}");
    let e = refused(json!([0.3]), "fast");
    assert!(e.contains("must be a number"), "{e}");
    // The reference method takes no target.
    let e = refused(json!(0.3), "reference");
    assert!(e.contains("only for method fast"), "{e}");
    // The second entry is named by its own index.
    let e = job_error(json!({"frames": [{"scene": tiny}, {"scene": tiny, "max_rel_error": 0.05}]}));
    assert_eq!(e.parameter().as_deref(), Some("frames[1].max_rel_error"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_frame_entry_target_is_a_400_and_a_cli_input_error() {
    let dir = Scratch::new("job-frames-target");
    let job = json!({"frames": [{"scene": tiny_scene(24, 16), "max_rel_error": 0.01,
                                 "sweep": {"sun_elevation_deg": [20, 40]}}]});
    // HTTP: a problem naming the entry's field and the allowed range; no job is made.
    let srv = TestServer::start(settings(&dir.path().join("cache"))).await;
    let r = srv.post("/v1/jobs", &job.to_string()).await;
    assert_eq!(r.status, 400, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("application/problem+json"));
    let problem = r.json();
    assert_eq!(problem["parameter"], "frames[0].max_rel_error", "{problem}");
    assert!(
        problem["detail"].as_str().unwrap().contains("0.0810 to 1"),
        "{problem}"
    );
    assert_eq!(srv.get("/v1/jobs").await.json()["total"], 0);
    srv.stop().await;
    // CLI: exit 2 (bad input), the message naming the field; nothing baked.
    let path = dir.path().join("job.json");
    std::fs::write(&path, job.to_string()).unwrap();
    let out = dir.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(["--no-table-cache", "bake"])
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("frames[0].max_rel_error") && stderr.contains("0.0810"),
        "{stderr}"
    );
}

#[test]
fn a_killed_frame_bake_resumes_from_its_frames_and_tiles() {
    let dir = Scratch::new("bake-frames");
    let out = dir.path().join("out");
    // Two frames of 3 tiles each.
    let job = json!({"frames": [{"scene": tiny_scene(130, 40), "sweep": {"sun_elevation_deg": [20, 60]}}]});
    let body = job.to_string();
    let s = spec(job).unwrap();
    let key1 = frame(&s, 1).cache_key();
    let tiles1 = TileStore::open(&out.join("tiles"))
        .unwrap()
        .frame(&key1)
        .unwrap();
    // Killed once the second frame has stored one tile.
    let cancel = || tiles1.count() >= 1;
    let e = bake_with_cancel(
        body.as_bytes(),
        &out,
        &Defaults::default(),
        1000,
        service_support::shared_engine(),
        |_, _, _| {},
        &cancel,
    )
    .unwrap_err();
    assert!(!e.is_input(), "{e}");
    let exrs = |dir: &std::path::Path| -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".exr"))
            .collect();
        names.sort();
        names
    };
    assert_eq!(exrs(&out).len(), 1, "the first frame is finished");
    assert_eq!(tiles1.count(), 1, "the second frame kept its finished tile");
    // The rerun reuses the first frame and renders only the second frame's missing tiles.
    let summary = bake(
        body.as_bytes(),
        &out,
        &Defaults::default(),
        1000,
        service_support::shared_engine(),
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!(
        (summary.reused, summary.computed, summary.failed),
        (1, 1, 0)
    );
    let names = exrs(&out);
    assert_eq!(names.len(), 2);
    assert!(names[1].starts_with("000001-frame-"), "{names:?}");
    let second = read_exr_file(&out.join(&names[1])).unwrap();
    let tiles_attr: Value =
        serde_json::from_str(second.attribute("skybakeFrameTiles").unwrap()).unwrap();
    assert_eq!(
        tiles_attr,
        json!({"tile_size": 64, "total": 3, "computed": 2, "reused": 1})
    );
    assert_eq!(tiles1.count(), 0, "a finished frame's tiles are removed");
    // The sweep changes the light: the frames differ.
    let first = read_exr_file(&out.join(&names[0])).unwrap();
    assert_ne!(
        first.layer("S0").unwrap().planes(),
        second.layer("S0").unwrap().planes()
    );
    let manifest: Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["artifacts"][1]["product"], "frame");
    assert_eq!(manifest["artifacts"][1]["cache_key"], json!(key1));
}

#[test]
fn an_automaton_animation_bakes_frames_that_change() {
    let dir = Scratch::new("bake-automaton");
    let out = dir.path().join("out");
    let job =
        json!({"frames": [{"scene": automaton_scene(), "sweep": {"frame_time_steps": [30, 40]}}]});
    let summary = bake(
        job.to_string().as_bytes(),
        &out,
        &Defaults::default(),
        1000,
        service_support::shared_engine(),
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!(
        (summary.computed, summary.failed),
        (2, 0),
        "{:?}",
        summary.errors
    );
    let mut names: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .collect();
    names.sort();
    let t: Vec<Vec<f32>> = names
        .iter()
        .map(|p| read_exr_file(p).unwrap().layer("T").unwrap().planes()[0].clone())
        .collect();
    // Cloud is in view in both frames, and it moved or grew between them.
    assert!(
        t.iter().all(|t| t.iter().any(|&v| v < 0.9)),
        "no cloud in view"
    );
    assert_ne!(t[0], t[1]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_service_frame_job_fills_the_render_cache() {
    let dir = Scratch::new("job-frames");
    let srv = TestServer::start(settings(dir.path())).await;
    let scene = tiny_scene(40, 30);
    let job = json!({"frames": [{"scene": scene, "sweep": {"sun_elevation_deg": [15, 45]}}]});
    let r = srv.post("/v1/jobs", &job.to_string()).await;
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(120);
    let status = loop {
        let s = srv.get(&format!("/v1/jobs/{id}")).await.json();
        if s["state"] == "completed" {
            break s;
        }
        assert!(tokio::time::Instant::now() < deadline, "{s}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(
        (status["done"].clone(), status["failed"].clone()),
        (json!(2), json!(0)),
        "{status}"
    );
    let items = status["artifacts"]["items"].as_array().unwrap();
    assert!(items
        .iter()
        .all(|it| it["product"] == "frame" && it["status"] == "done"));
    // The job's artifacts in each format.
    let a = srv
        .get(&format!("/v1/jobs/{id}/artifacts/1?format=json"))
        .await;
    assert_eq!(a.status, 200, "{}", a.text());
    assert_eq!(a.json()["tiles"]["total"], 1);
    let exr = srv.get(&format!("/v1/jobs/{id}/artifacts/1")).await;
    assert_eq!(exr.header("content-type"), Some("image/x-exr"));
    // Rendering the second frame's scene is a cache hit: the job's product.
    let mut second = scene.clone();
    second["sun"]["collimated"]["elevation_deg"] = json!(45);
    let r = srv.post("/v1/render?format=exr", &second.to_string()).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.header("x-cache"), Some("hit"));
    assert_eq!(
        r.header("x-skybake-cache-key"),
        items[1]["cache_key"].as_str()
    );
    assert_eq!(r.body, exr.body);
    srv.stop().await;
}
