//! One artifact, whoever asks: the CLI's `-o sky.exr`, the service's `format=exr` (through the
//! router, `app(state).oneshot`) and a bake's EXR of the same request are the same file apart from
//! the values of the timing attributes, byte for byte; and a malformed cached artifact is a server fault that is recomputed,
//! never a request error.

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use service_support::{bake_single_exr, settings, Scratch};
use skybake_physics::image::layout::ATTR_FILE_CHECKSUM;
use skybake_product::params::RequestParams;
use skybake_product::{render, Format, ProductKind, ProductRequest, TIMING_ATTRIBUTES};
use skybake_service::{app, AppState};
use tower::ServiceExt;

const QUERY: &str = "method=fast&quality=draft&wavelengths=440,550&sun_elevation_deg=20&elevation_count=5&azimuth_count=3";

/// The file with the values of its timing attributes and of the whole-file checksum (which covers
/// them) overwritten by `#`: a byte-range replacement, since those values have a fixed width.
/// Everything else (header, attribute order, offset table, every compressed chunk in file order)
/// is left as written.
fn without_timing(bytes: &[u8]) -> Vec<u8> {
    let mut masked = bytes.to_vec();
    for name in TIMING_ATTRIBUTES.iter().chain([&ATTR_FILE_CHECKSUM]) {
        // An OpenEXR attribute: name, NUL, type name, NUL, i32 size, value.
        let prefix = [name.as_bytes(), b"\0string\0"].concat();
        let at = bytes
            .windows(prefix.len())
            .position(|w| w == prefix.as_slice())
            .unwrap_or_else(|| panic!("{name} missing"));
        let size_at = at + prefix.len();
        let size = i32::from_le_bytes(bytes[size_at..size_at + 4].try_into().unwrap()) as usize;
        masked[size_at + 4..size_at + 4 + size].fill(b'#');
    }
    masked
}

fn first_difference(a: &[u8], b: &[u8]) -> Option<usize> {
    (0..a.len().max(b.len())).find(|&i| a.get(i) != b.get(i))
}

async fn get(state: &AppState, uri: &str) -> (u16, Vec<u8>) {
    let req = Request::builder().uri(uri).body(Body::empty()).unwrap();
    let resp = app(state.clone()).oneshot(req).await.unwrap();
    let status = resp.status().as_u16();
    let bytes = axum::body::to_bytes(resp.into_body(), 1 << 26)
        .await
        .unwrap();
    (status, bytes.to_vec())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cli_http_and_bake_write_the_same_artifact() {
    let dir = Scratch::new("artifact");
    // CLI.
    let cli_path = dir.path().join("cli.exr");
    let mut args = vec!["sky".to_string()];
    for pair in QUERY.split('&') {
        let (k, v) = pair.split_once('=').unwrap();
        args.push(format!("--{}", k.replace('_', "-")));
        args.push(v.to_string());
    }
    args.extend(["-o".into(), cli_path.to_str().unwrap().to_string()]);
    service_support::skybake_ok(&args);
    let cli = std::fs::read(&cli_path).unwrap();
    // HTTP.
    let state = AppState::new(settings(&dir.path().join("cache"))).unwrap();
    let (status, http) = get(&state, &format!("/v1/sky?{QUERY}&format=exr")).await;
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&http));
    // Bake.
    let job = serde_json::json!({"products": [{"product": "sky", "method": "fast", "quality": "draft",
        "wavelengths": "440,550", "sun_elevation_deg": 20, "elevation_count": 5, "azimuth_count": 3}]});
    let baked = dir.path().join("baked");
    let bake = bake_single_exr(&job, &baked);

    // Byte for byte, apart from the timing values.
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
    // And the CLI's JSON is the service's JSON body.
    let json = std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(&args[..args.len() - 2])
        .output()
        .unwrap();
    let cli_json: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    let (_, body) = get(&state, &format!("/v1/sky?{QUERY}")).await;
    let http_json: serde_json::Value = serde_json::from_slice(&body).unwrap();
    for field in [
        "radiance_w_m2_sr_nm",
        "elevation_deg",
        "spec",
        "error_estimate",
    ] {
        assert_eq!(cli_json[field], http_json[field], "{field}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_malformed_cached_artifact_is_a_server_fault_and_is_recomputed() {
    let dir = Scratch::new("malformed");
    let state = AppState::new(settings(dir.path())).unwrap();
    let p = RequestParams::from_pairs(skybake_service::extract::query_pairs(Some(QUERY)).unwrap())
        .unwrap();
    let req = ProductRequest::from_params(ProductKind::Sky, &p).unwrap();
    // A verified EXR (it passes the store's checksum) without the response envelope.
    let bad = skybake_physics::image::SpectralImage::emissive(
        3,
        5,
        &[440.0, 550.0],
        vec![vec![0.0; 15]; 2],
    )
    .unwrap();
    let err = render(ProductKind::Sky, Format::Json, &bad).unwrap_err();
    assert!(
        !err.is_input(),
        "a malformed artifact is not the request's fault: {err}"
    );
    assert_eq!(
        skybake_service::problem::ApiError::from(err)
            .status()
            .as_u16(),
        500
    );
    state.cache().put_image(&req.cache_key(), &bad).unwrap();
    let (status, body) = get(&state, &format!("/v1/sky?{QUERY}")).await;
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    let v: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(v["radiance_w_m2_sr_nm"].as_array().unwrap().len(), 5);
    assert_eq!(state.metrics().computations("sky"), 1);
    // The good artifact replaced the bad one.
    let stored = state.cache().get_image(&req.cache_key()).unwrap().unwrap();
    assert!(stored
        .attribute(skybake_product::ATTR_RESPONSE_JSON)
        .is_some());
}
