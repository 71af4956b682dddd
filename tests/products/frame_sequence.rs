//! Frame sequences: a camera path (`view_orbit_deg`, `view_distance_m`) and a sun sweep as job
//! entries; frames computed with a shared `FrameReuse` (grid and lit cloud) are bit for bit the
//! frames computed alone, and share what they should.

use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_job::spec::JobSpec;
use skybake_product::frame::{FrameRequest, FrameReuse, NoTiles, EXAMPLE_SCENES};
use skybake_product::params::Defaults;
use skybake_product::{AnyRequest, ComputeEnv};
use std::sync::Arc;

/// The validation cloud (sun, constant sky, and here a ground: sky, ground light, multiple
/// scattering, shadows), `w` × `h` pixels, draft quality, 100 m voxels.
fn tiny_scene(w: usize, h: usize) -> Value {
    let text = EXAMPLE_SCENES
        .iter()
        .find(|(n, _)| *n == "validation-frame")
        .unwrap()
        .1;
    let mut scene: Value = serde_json::from_str(text).unwrap();
    scene["camera"]["width"] = json!(w);
    scene["camera"]["height"] = json!(h);
    scene["quality"] = json!("draft");
    scene["cloud"]["voxel_size_m"] = json!(100.0);
    scene["ground"] = json!({"albedo": 0.3, "height_m": 0});
    scene
}

fn frames(body: Value) -> Vec<Arc<FrameRequest>> {
    let spec = JobSpec::parse(body.as_object().unwrap(), 1000).unwrap();
    (0..spec.len())
        .map(|i| match spec.request(i, &Defaults::default()).unwrap() {
            AnyRequest::Frame(f) => f,
            AnyRequest::Atmosphere(_) => panic!("item {i} is not a frame"),
        })
        .collect()
}

fn compute(
    engine: &Engine,
    req: &Arc<FrameRequest>,
    reuse: Option<&FrameReuse>,
) -> skybake_physics::image::SpectralImage {
    let env = ComputeEnv {
        loader: &skybake_product::frame::example_file,
        tiles: &NoTiles,
        progress: &|_| {},
        cancel: &|| false,
        reuse,
    };
    AnyRequest::Frame(req.clone())
        .compute(engine, &env)
        .unwrap()
}

/// The frame's stages (the artifact's meta without its timings).
fn stages(img: &skybake_physics::image::SpectralImage) -> Value {
    let meta: Value = serde_json::from_str(img.attribute("skybakeFrameMeta").unwrap()).unwrap();
    meta["stages"].clone()
}

/// Every frame of `body` computed in order with one `FrameReuse` equals the frame computed
/// alone (every layer and the RGB image bitwise, the same stages); returns the reuse counters.
fn sequence_equals_frames_alone(body: Value) -> skybake_product::frame::ReuseCounts {
    let engine = Engine::new();
    let reuse = FrameReuse::default();
    for (k, req) in frames(body).iter().enumerate() {
        let shared = compute(&engine, req, Some(&reuse));
        let alone = compute(&engine, req, None);
        assert_eq!(shared.layers(), alone.layers(), "frame {k}");
        assert_eq!(shared.rgb(), alone.rgb(), "frame {k}");
        assert_eq!(stages(&shared), stages(&alone), "frame {k}");
        assert!(shared.layers()[0].planes()[0].iter().any(|&v| v > 0.0));
    }
    reuse.counts()
}

#[test]
fn camera_path_reuses_the_lit_cloud_and_changes_no_pixel() {
    let counts = sequence_equals_frames_alone(json!({"frames": [{
        "scene": tiny_scene(24, 16),
        "sweep": {"view_orbit_deg": [0, 35, 190], "view_distance_m": [3000, 5000]}}]}));
    // Six cameras, one cloud and one sun: voxelised and lit once.
    assert_eq!((counts.grids_computed, counts.grids_reused), (1, 5));
    assert_eq!((counts.lit_computed, counts.lit_reused), (1, 5));
    // The engine's products at two camera heights (one per distance; the aerial product's
    // reach is the ground's bound at each).
    assert_eq!((counts.lighting_computed, counts.lighting_reused), (2, 4));
}

#[test]
fn sun_sweep_reuses_the_grid_and_changes_no_pixel() {
    let counts = sequence_equals_frames_alone(json!({"frames": [{
        "scene": tiny_scene(20, 12),
        "sweep": {"sun_azimuth_deg": [60, 200], "view_orbit_deg": [0, 90]}}]}));
    // The camera varies fastest: each sun's lit cloud serves its two cameras.
    assert_eq!((counts.grids_computed, counts.grids_reused), (1, 3));
    assert_eq!((counts.lit_computed, counts.lit_reused), (2, 2));
    // One camera height: the engine's products once per sun.
    assert_eq!((counts.lighting_computed, counts.lighting_reused), (2, 2));
}

#[test]
fn view_axes_move_the_camera_and_name_their_mistakes() {
    let f = frames(json!({"frames": [{"scene": tiny_scene(8, 8),
        "sweep": {"view_orbit_deg": [0, 90], "view_distance_m": [2000]}}]}));
    let pos = |i: usize| -> Vec<f64> {
        f[i].scene_json()["camera"]["position_m"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    // The scene's camera: (0, -4000, 1200) looking at (0, 0, 1550); at 2000 m on that line.
    let rel = [0.0, -4000.0, -350.0];
    let d = (4000.0f64 * 4000.0 + 350.0 * 350.0).sqrt();
    let at = [0.0, rel[1] * 2000.0 / d, 1550.0 + rel[2] * 2000.0 / d];
    for (a, b) in pos(0).iter().zip(at) {
        assert!((a - b).abs() < 1e-9, "{:?}", pos(0));
    }
    // Turned by 90° towards increasing azimuth (from +y towards +x): from −y to −x.
    let turned = [at[1], 0.0, at[2]];
    for (a, b) in pos(1).iter().zip(turned) {
        assert!((a - b).abs() < 1e-9, "{:?}", pos(1));
    }
    // The untouched camera keeps the scene's key (whole numbers stay integers).
    let same = frames(json!({"frames": [{"scene": tiny_scene(8, 8),
        "sweep": {"view_orbit_deg": [0]}}]}));
    let plain = FrameRequest::from_value(&tiny_scene(8, 8), skybake_render::Method::Fast).unwrap();
    assert_eq!(same[0].cache_key(), plain.cache_key());
    let field = |sweep: Value| -> String {
        let body = json!({"frames": [{"scene": tiny_scene(8, 8), "sweep": sweep}]});
        let spec = JobSpec::parse(body.as_object().unwrap(), 1000);
        let e = match spec {
            Err(e) => e,
            Ok(s) => s.validate(&Defaults::default()).unwrap_err(),
        };
        assert!(e.is_input(), "{e}");
        e.parameter().unwrap_or_default()
    };
    assert_eq!(
        field(json!({"view_distance_m": [0]})),
        "frames[0][0].view_distance_m"
    );
    assert_eq!(
        field(json!({"view_orbit_deg": [1e6]})),
        "frames[0][0].view_orbit_deg"
    );
}
