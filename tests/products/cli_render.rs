//! `skybake render`: a frame scene rendered through the frame product to EXR (the artifact: spectral
//! radiance, transmittance, RGB, cache key and metadata) and to PNG, and bad input refused with
//! exit code 2 naming the field.

use skybake_physics::image::layout::{ATTR_CACHE_KEY, ATTR_PLAN_JSON, ATTR_SPEC_JSON};
use std::path::PathBuf;
use std::process::{Command, Output};

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("skybake-cli-render-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The cache directory of this test binary's CLI calls, under the target directory (precise
/// tables persist between calls and runs, keyed by engine version like every cache entry).
fn table_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(concat!(module_path!(), "-tables"))
}

fn skybake(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(args)
        // Stored tables go to this test's own directory, not ./skybake-cache.
        .env("SKYBAKE_CACHE_DIR", table_dir())
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

#[test]
fn validation_frame_renders_to_exr_and_png() {
    let dir = scratch("ok");
    let exr = dir.join("frame.exr");
    let png = dir.join("frame.png");
    let scene = "config/scenes/validation-frame.json";
    let o = skybake(&["render", scene, "-o", exr.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["width"], 160);
    assert_eq!(summary["height"], 120);
    assert!(summary["stages"]["ran"]
        .as_array()
        .is_some_and(|r| !r.is_empty()));
    assert!(summary["stages"]["skipped"].is_array());
    // Timings per stage, the tiles and the error estimate.
    let stages: Vec<&str> = summary["timing_ms_by_stage"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["stage"].as_str().unwrap())
        .collect();
    for stage in ["voxelize", "lighting", "pixels"] {
        assert!(stages.contains(&stage), "{stage} missing from {stages:?}");
    }
    assert!(summary["timing_ms"].as_f64().unwrap() > 0.0);
    assert!(summary["error_estimate"]["basis"].is_string());
    // 160 × 120 in 64-pixel tiles: 3 × 2.
    assert_eq!(summary["tiles"]["total"], 6);
    assert_eq!(summary["tiles"]["computed"], 6);

    let image = skybake_store::read_exr_file(&exr).unwrap();
    assert_eq!((image.width(), image.height()), (160, 120));
    assert_eq!(image.wavelengths_nm(), &[550.0]);
    assert_eq!(
        image.attribute(ATTR_CACHE_KEY),
        summary["cache_key"].as_str()
    );
    assert!(image
        .attribute(ATTR_SPEC_JSON)
        .is_some_and(|s| s.contains("\"frame\"")));
    assert!(image.attribute(ATTR_PLAN_JSON).is_some());
    let radiance = image.layer("S0").unwrap().planes()[0].clone();
    let transmittance = image.layer("T").unwrap().planes()[0].clone();
    assert!(radiance.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(transmittance.iter().all(|t| (0.0..=1.0).contains(t)));
    // The cloud is in view: some pixel is mostly blocked, some sees past it.
    assert!(transmittance.iter().any(|&t| t < 0.1));
    assert!(transmittance.iter().any(|&t| t > 0.99));
    assert!(image.rgb().is_some());

    let o = skybake(&[
        "render",
        scene,
        "-o",
        png.to_str().unwrap(),
        "--format",
        "text",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let decoded = image::open(&png).unwrap();
    assert_eq!((decoded.width(), decoded.height()), (160, 120));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_render_requests_exit_2_naming_the_problem() {
    let dir = scratch("bad");
    let scene = dir.join("bad.json");
    let mut json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/validation-frame.json"),
        )
        .unwrap(),
    )
    .unwrap();
    json["camera"]["fov_deg"] = serde_json::json!(0);
    std::fs::write(&scene, json.to_string()).unwrap();
    let o = skybake(&["render", scene.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("fov_deg"));

    let o = skybake(&[
        "render",
        "config/scenes/validation-frame.json",
        "-o",
        "frame.tiff",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("output"));

    let o = skybake(&[
        "render",
        "config/scenes/validation-frame.json",
        "--method",
        "magic",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("method"));
    let _ = std::fs::remove_dir_all(&dir);
}
