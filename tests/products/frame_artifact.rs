//! One frame artifact, whoever asks: `skybake render SCENE -o frame.exr`, `POST /v1/render` with
//! `format=exr` and a bake's frame of the same scene are the same file apart from the values of
//! their timings, byte for byte: the compute time and the file checksum (fixed-width attributes)
//! and the per-stage times inside `skybakeFrameMeta`, which are written at a fixed width
//! (`render::product::frame_meta_json`) so that no other byte moves.

use crate::service_support;

use serde_json::{json, Value};
use service_support::{bake_single_exr, call, settings, skybake_ok, tiny_frame_scene, Scratch};
use skybake_engine::engine::Stages;
use skybake_physics::image::layout::{ATTR_COMPUTE_TIME_MS, ATTR_FILE_CHECKSUM};
use skybake_product::artifact::{frame_meta_json, ATTR_FRAME_META};
use skybake_render::{FrameError, FrameMeta, Method, ERROR_BASIS};
use skybake_service::AppState;

/// Byte range of the value of string attribute `name` in an EXR header.
fn attribute_range(bytes: &[u8], name: &str) -> std::ops::Range<usize> {
    // An OpenEXR attribute: name, NUL, type name, NUL, i32 size, value.
    let prefix = [name.as_bytes(), b"\0string\0"].concat();
    let at = bytes
        .windows(prefix.len())
        .position(|w| w == prefix.as_slice())
        .unwrap_or_else(|| panic!("{name} missing"));
    let size_at = at + prefix.len();
    let size = i32::from_le_bytes(bytes[size_at..size_at + 4].try_into().unwrap()) as usize;
    size_at + 4..size_at + 4 + size
}

/// The file with its timing values overwritten by `#`: the compute time and the checksum whole,
/// and in the frame metadata the digits, points and padding of the `timing_ms` list (the stage
/// names stay).
fn without_timing(bytes: &[u8]) -> Vec<u8> {
    let mut masked = bytes.to_vec();
    for name in [ATTR_COMPUTE_TIME_MS, ATTR_FILE_CHECKSUM] {
        masked[attribute_range(bytes, name)].fill(b'#');
    }
    let meta = attribute_range(bytes, ATTR_FRAME_META);
    let text = std::str::from_utf8(&bytes[meta.clone()]).unwrap();
    let start = text
        .find("\"timing_ms\":[")
        .expect("timing_ms in the metadata");
    let end = start + text[start..].find("]]").expect("end of timing_ms") + 2;
    for (i, c) in text[start..end].char_indices() {
        if c.is_ascii_digit() || c == '.' || c == ' ' {
            masked[meta.start + start + i] = b'#';
        }
    }
    masked
}

/// Where two files first differ, with the bytes around it in each.
fn first_difference(a: &[u8], b: &[u8]) -> Option<(usize, String, String)> {
    let i = (0..a.len().max(b.len())).find(|&i| a.get(i) != b.get(i))?;
    let around = |x: &[u8]| {
        String::from_utf8_lossy(&x[i.saturating_sub(60).min(x.len())..(i + 60).min(x.len())])
            .into_owned()
    };
    Some((i, around(a), around(b)))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cli_http_and_bake_write_the_same_frame_artifact() {
    let dir = Scratch::new("frame-artifact");
    let scene = tiny_frame_scene(24, 16);
    let scene_path = dir.path().join("scene.json");
    std::fs::write(&scene_path, scene.to_string()).unwrap();
    // CLI.
    let cli_path = dir.path().join("cli.exr");
    skybake_ok([
        "render",
        scene_path.to_str().unwrap(),
        "-o",
        cli_path.to_str().unwrap(),
    ]);
    let cli = std::fs::read(&cli_path).unwrap();
    // HTTP.
    let state = AppState::new(settings(&dir.path().join("cache"))).unwrap();
    let resp = call(&state, "POST", "/v1/render?format=exr", scene.to_string()).await;
    assert_eq!(resp.status, 200);
    let http = resp.body;
    // Bake.
    let job = json!({"frames": [{"scene": scene}]});
    let baked = dir.path().join("baked");
    let bake = bake_single_exr(&job, &baked);

    assert_eq!(
        cli.len(),
        http.len(),
        "CLI and HTTP artifacts differ in size"
    );
    let reference = without_timing(&cli);
    assert!(
        reference == without_timing(&http),
        "CLI and HTTP artifacts differ (first at byte {:?})",
        first_difference(&reference, &without_timing(&http))
    );
    assert!(
        reference == without_timing(&bake),
        "CLI and bake artifacts differ (first at byte {:?})",
        first_difference(&reference, &without_timing(&bake))
    );
    // The timings are still there and still JSON numbers (the summary reads them).
    let img = skybake_store::decode_exr(&cli).unwrap();
    let summary = skybake_product::artifact::frame_summary(&img);
    let stages = summary["timing_ms_by_stage"].as_array().unwrap();
    assert!(stages.iter().any(|s| s["stage"] == "pixels"), "{summary}");
    assert!(
        stages.iter().all(|s| s["ms"].as_f64().is_some()),
        "{summary}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_baked_frame_with_a_target_is_the_render_with_that_target() {
    let dir = Scratch::new("frame-artifact-target");
    let scene = tiny_frame_scene(24, 16);
    // HTTP with the target.
    let state = AppState::new(settings(&dir.path().join("cache"))).unwrap();
    let uri = "/v1/render?format=exr&max_rel_error=0.3";
    let resp = call(&state, "POST", uri, scene.to_string()).await;
    assert_eq!(resp.status, 200);
    let key = resp.header("x-skybake-cache-key").map(str::to_string);
    let http = resp.body;
    // Bake of a frame entry with the same target.
    let job = json!({"frames": [{"scene": scene, "max_rel_error": 0.3}]});
    let baked = dir.path().join("baked");
    let bake = bake_single_exr(&job, &baked);
    assert_eq!(
        http.len(),
        bake.len(),
        "HTTP and bake artifacts differ in size"
    );
    let reference = without_timing(&http);
    assert!(
        reference == without_timing(&bake),
        "HTTP and bake artifacts differ (first at byte {:?})",
        first_difference(&reference, &without_timing(&bake))
    );
    // The bake's manifest names the render's cache key; the artifact carries the target's plan.
    let manifest: Value =
        serde_json::from_slice(&std::fs::read(baked.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(
        manifest["artifacts"][0]["cache_key"].as_str(),
        key.as_deref()
    );
    let img = skybake_store::decode_exr(&bake).unwrap();
    let meta: Value = serde_json::from_str(img.attribute(ATTR_FRAME_META).unwrap()).unwrap();
    assert_eq!(
        meta["plan"]["budget"]["relative_error"],
        json!(0.3),
        "{meta}"
    );
    // Without the target the bake is another product.
    let plain = bake_single_exr(
        &json!({"frames": [{"scene": scene}]}),
        &dir.path().join("plain"),
    );
    assert!(without_timing(&plain) != reference);
}

#[test]
fn frame_metadata_timings_have_a_fixed_width() {
    let mut meta = FrameMeta {
        method: Method::Fast,
        stages: Stages {
            ran: vec!["sun_paths".into(), "pixels".into()],
            skipped: vec!["aerial: vacuum".into()],
        },
        timing_ms: ["voxelize", "plan", "lighting", "sun_paths", "ms", "pixels"]
            .iter()
            .map(|s| (s.to_string(), 1.5))
            .collect(),
        error_estimate: FrameError {
            path_tracer_relative_noise: Some(0.01),
            basis: ERROR_BASIS,
        },
        lighting_notes: vec!["note with \"timing_ms\":[] inside".into()],
        plan: Some(json!({"timing_ms": [], "budget": 3})),
    };
    let a = frame_meta_json(&meta).unwrap();
    // Everything as serde writes it, the timings included (values to the microsecond).
    assert_eq!(
        serde_json::from_str::<Value>(&a).unwrap(),
        serde_json::to_value(&meta).unwrap()
    );
    assert!(a.contains(r#"["pixels",       1.500]"#), "{a}");
    for (i, t) in meta.timing_ms.iter_mut().enumerate() {
        t.1 = [0.0, 0.0004, 99_999_999.999, 1e12, f64::NAN, 12.3456789][i];
    }
    let b = frame_meta_json(&meta).unwrap();
    assert_eq!(a.len(), b.len(), "{a}\n{b}");
    let parsed: Value = serde_json::from_str(&b).unwrap();
    let ms: Vec<f64> = (0..6)
        .map(|i| parsed["timing_ms"][i][1].as_f64().unwrap())
        .collect();
    assert_eq!(ms, [0.0, 0.0, 99_999_999.999, 99_999_999.999, 0.0, 12.346]);
    // The free text that happens to look like the field is left alone.
    assert_eq!(
        parsed["lighting_notes"],
        json!(["note with \"timing_ms\":[] inside"])
    );
    assert_eq!(parsed["plan"]["timing_ms"], json!([]));
}
