//! The planner's wavelength rule: an RGB-only frame request (a PNG) runs at
//! the fewest of its wavelengths whose predicted change of the RGB image fits the error budget;
//! the image it gives changes by less than predicted, the wavelengths it keeps are computed as
//! in the spectral frame, and it has its own cache key (CLI, service, plan).

use serde_json::{json, Value};
use skybake_engine::plan::{
    rgb_wavelengths_rule, Budget, RgbFacts, WavelengthCandidate, FRAME_MEASURED_ERROR,
    RGB_PROXY_SAFETY,
};
use skybake_physics::image::SpectralImage;
use skybake_product::frame::FrameRequest;
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};
use skybake_render::Method;
use skybake_service::AppState;

use crate::service_support;
use service_support::{call, settings, skybake_ok, Scratch};

/// The 16 wavelengths of the default set, 380–755 nm.
fn sixteen() -> Vec<f64> {
    (0..16).map(|i| 380.0 + 25.0 * i as f64).collect()
}

/// The validation cloud under the earth's atmosphere and sky (sun 35°, ground albedo 0.3) at
/// 50 m voxels, `width`×`height` px, standard quality, 16 wavelengths.
fn scene(width: usize, height: usize) -> Value {
    let mut v: Value =
        serde_json::from_str(include_str!("../../config/scenes/validation-frame.json")).unwrap();
    v["cloud"]["voxel_size_m"] = json!(50.0);
    v["camera"]["width"] = json!(width);
    v["camera"]["height"] = json!(height);
    v["quality"] = json!("standard");
    v["atmosphere"] = json!("earth");
    v["sky"] = json!("atmosphere");
    v["sun"] = json!({"elevation_deg": 35, "azimuth_deg": 140});
    v["ground"] = json!({"albedo": 0.3, "height_m": 0});
    v["wavelengths_nm"] = json!(sixteen());
    v
}

fn no_files(_: &str) -> skybake_physics::Result<Vec<u8>> {
    Err(skybake_physics::Error::invalid("path", "no files"))
}

fn planes(img: &SpectralImage) -> Vec<Vec<f32>> {
    img.layer("S0").unwrap().planes().to_vec()
}

#[test]
fn the_rule_takes_the_fewest_wavelengths_whose_prediction_fits_and_spends_it() {
    let facts = RgbFacts {
        requested_nm: vec![400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0],
        candidates: vec![
            WavelengthCandidate {
                internal_nm: vec![400.0, 550.0, 700.0],
                proxy_error: 0.05,
            },
            WavelengthCandidate {
                internal_nm: vec![400.0, 500.0, 600.0, 700.0],
                proxy_error: 0.008,
            },
            WavelengthCandidate {
                internal_nm: vec![400.0, 450.0, 500.0, 600.0, 650.0, 700.0],
                proxy_error: 0.001,
            },
        ],
    };
    // Default budget: a quarter of 8.1 % = 2.025 %; the three-wavelength subset's 2 × 5 % does
    // not fit, the four-wavelength one's 2 × 0.8 % does.
    let mut budget = Budget::new(FRAME_MEASURED_ERROR);
    let s = rgb_wavelengths_rule(&facts, &mut budget).unwrap();
    assert_eq!(s.internal_nm, vec![400.0, 500.0, 600.0, 700.0]);
    assert_eq!(s.left_out_nm, vec![450.0, 550.0, 650.0]);
    assert_eq!(s.rule, "rgb_only");
    assert!((s.predicted_error - RGB_PROXY_SAFETY * 0.008).abs() < 1e-15);
    assert!((budget.spent - s.predicted_error).abs() < 1e-15);
    // A loose target pays for three wavelengths; the reference method's empty budget for none.
    let mut loose = Budget::for_target(0.3, FRAME_MEASURED_ERROR);
    assert_eq!(
        rgb_wavelengths_rule(&facts, &mut loose)
            .unwrap()
            .internal_nm
            .len(),
        3
    );
    assert!(rgb_wavelengths_rule(&facts, &mut Budget::new(0.0)).is_none());
}

#[test]
fn an_rgb_only_frame_runs_at_fewer_wavelengths_and_its_rgb_changes_less_than_predicted() {
    let v = scene(48, 36);
    let engine = service_support::shared_engine();
    let spectral = FrameRequest::from_value(&v, Method::Fast).unwrap();
    let rgb = spectral.clone().with_rgb_only(true);
    // Its own cache key; the spectral request's key is as it was.
    assert_ne!(rgb.cache_key(), spectral.cache_key());
    assert_eq!(
        rgb.clone().with_rgb_only(false).cache_key(),
        spectral.cache_key()
    );
    let plan = rgb.plan(engine, &no_files).unwrap();
    let subset = plan.wavelengths.clone().expect("the rule fires");
    eprintln!(
        "internal {:?}, predicted {:.4}, budget {:?}",
        subset.internal_nm, subset.predicted_error, plan.budget
    );
    assert!(subset.internal_nm.len() < 16 && subset.internal_nm.len() >= 3);
    assert!(subset.predicted_error <= plan.budget.allowance);
    assert!(spectral
        .plan(engine, &no_files)
        .unwrap()
        .wavelengths
        .is_none());
    let json = serde_json::to_value(&plan).unwrap();
    assert_eq!(json["wavelengths"]["rule"], "rgb_only");
    assert!(json["wavelengths"]["detail"]
        .as_str()
        .unwrap()
        .contains("RGB-only"));

    let full = spectral
        .compute(
            service_support::shared_engine(),
            &no_files,
            &|_| {},
            &|| false,
        )
        .unwrap();
    let fewer = rgb
        .compute(
            service_support::shared_engine(),
            &no_files,
            &|_| {},
            &|| false,
        )
        .unwrap();
    assert_eq!(fewer.wavelengths_nm(), subset.internal_nm.as_slice());
    assert_eq!(full.wavelengths_nm(), sixteen().as_slice());
    // The kept wavelengths are computed as in the spectral frame.
    let (pf, pr) = (planes(&full), planes(&fewer));
    for (j, nm) in subset.internal_nm.iter().enumerate() {
        let i = sixteen().iter().position(|w| w == nm).unwrap();
        let scale = pf[i].iter().map(|v| v.abs() as f64).sum::<f64>() / pf[i].len() as f64;
        let worst = pf[i]
            .iter()
            .zip(&pr[j])
            .map(|(a, b)| (a - b).abs() as f64)
            .fold(0.0, f64::max);
        assert!(worst <= 1e-4 * scale, "{nm} nm: {worst} of {scale}");
    }
    // The RGB changes by less than predicted: per pixel, the largest channel change relative
    // to the pixel's mean channel, RMS over the frame.
    let (a, b) = (full.rgb().unwrap(), fewer.rgb().unwrap());
    let n = a[0].len();
    let (mut sum2, mut worst) = (0.0f64, 0.0f64);
    for p in 0..n {
        let scale = (0..3).map(|c| a[c][p].abs() as f64).sum::<f64>() / 3.0;
        let d = (0..3)
            .map(|c| (a[c][p] - b[c][p]).abs() as f64)
            .fold(0.0, f64::max);
        let e = d / scale;
        sum2 += e * e;
        worst = worst.max(e);
    }
    let rms = (sum2 / n as f64).sqrt();
    eprintln!("RGB change: RMS {rms:.4}, largest {worst:.4}");
    assert!(rms <= subset.predicted_error, "{rms}");
    assert!(worst <= 2.0 * subset.predicted_error, "{worst}");
}

#[test]
fn few_wavelengths_the_reference_method_and_spectral_requests_keep_every_wavelength() {
    let mut three = scene(16, 12);
    three["wavelengths_nm"] = json!([440, 550, 680]);
    let engine = service_support::shared_engine();
    let req = FrameRequest::from_value(&three, Method::Fast)
        .unwrap()
        .with_rgb_only(true);
    assert!(req.plan(engine, &no_files).unwrap().wavelengths.is_none());
    assert_eq!(
        req.internal_wavelengths().unwrap().as_nm(),
        &[440.0, 550.0, 680.0]
    );
    let reference = FrameRequest::from_value(&scene(16, 12), Method::Reference)
        .unwrap()
        .with_rgb_only(true);
    assert_eq!(reference.internal_wavelengths().unwrap().len(), 16);
    assert!(reference
        .plan(engine, &no_files)
        .unwrap()
        .wavelengths
        .is_none());
    // A looser target buys fewer wavelengths.
    let rgb = FrameRequest::from_value(&scene(16, 12), Method::Fast)
        .unwrap()
        .with_rgb_only(true);
    let default = rgb.internal_wavelengths().unwrap().len();
    let loose = rgb
        .clone()
        .with_max_rel_error(Some("0.5"))
        .unwrap()
        .internal_wavelengths()
        .unwrap()
        .len();
    assert!(loose < default, "{loose} vs {default}");
}

#[test]
fn the_cli_runs_a_png_as_an_rgb_only_request() {
    let v = scene(16, 12);
    let dir = Scratch::new("rgb-only-cli");
    let path = dir.path().join("scene.json");
    std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
    let rgb = FrameRequest::from_value(&v, Method::Fast)
        .unwrap()
        .with_rgb_only(true);
    let internal = rgb.internal_wavelengths().unwrap();
    // `plan frame --rgb-only` shows the subset; `--rgb-only` is refused for other products.
    let scene_arg = path.to_str().unwrap();
    let out = skybake_ok(["plan", "frame", "--rgb-only", "--scene", scene_arg]);
    let plan: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(plan["cache_key"], json!(rgb.cache_key()));
    assert_eq!(
        plan["plan"]["wavelengths"]["internal_nm"],
        json!(internal.as_nm())
    );
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(["plan", "sky", "--rgb-only"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("rgb"));
    // `render -o FRAME.png` runs the RGB-only request: its summary lists the subset.
    let png = dir.path().join("frame.png");
    let png_arg = png.to_str().unwrap();
    let out = skybake_ok(["render", scene_arg, "-o", png_arg, "--format", "json"]);
    let summary: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["wavelengths_nm"], json!(internal.as_nm()));
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_service_runs_a_png_as_an_rgb_only_request_unless_the_spectral_frame_is_cached() {
    let v = scene(16, 12);
    let dir = Scratch::new("rgb-only-service");
    let state = AppState::new(settings(dir.path())).unwrap();
    let spectral = FrameRequest::from_value(&v, Method::Fast).unwrap();
    let rgb = spectral.clone().with_rgb_only(true);
    let body = serde_json::to_vec(&v).unwrap();
    // A PNG first: the RGB-only request.
    let resp = call(&state, "POST", "/v1/render?format=png", body.clone()).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    assert_eq!(
        resp.header("x-skybake-cache-key"),
        Some(rgb.cache_key().as_str())
    );
    assert!(resp.body.starts_with(b"\x89PNG"));
    // The EXR: every wavelength, the spectral key; a PNG after it takes that frame.
    let resp = call(&state, "POST", "/v1/render?format=exr", body.clone()).await;
    assert_eq!(
        resp.header("x-skybake-cache-key"),
        Some(spectral.cache_key().as_str())
    );
    let resp = call(&state, "POST", "/v1/render?format=png", body.clone()).await;
    assert_eq!(resp.status, 200);
    assert_eq!(
        resp.header("x-skybake-cache-key"),
        Some(spectral.cache_key().as_str())
    );
    // The plan with "output": "rgb"; another output is refused naming the member.
    let plan_body = |output: Value| {
        serde_json::to_vec(&json!({"product": "frame", "scene": v, "output": output})).unwrap()
    };
    let resp = call(&state, "POST", "/v1/plan", plan_body(json!("rgb"))).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let plan = resp.json();
    assert_eq!(plan["cache_key"], json!(rgb.cache_key()));
    assert_eq!(plan["plan"]["wavelengths"]["rule"], "rgb_only");
    let resp = call(&state, "POST", "/v1/plan", plan_body(json!("grey"))).await;
    assert_eq!(resp.status, 422);
    assert_eq!(resp.json()["parameter"], "output", "{}", resp.text());
}

/// A sky or ground request by the parameter table's pairs (sun 30°, fast, standard, the default
/// 16 wavelengths, each overridden by `extra`), in `format`.
fn dome_request(kind: ProductKind, format: &str, extra: &[(&str, &str)]) -> ProductRequest {
    let mut pairs = vec![
        ("format", format),
        ("method", "fast"),
        ("quality", "standard"),
        ("sun_elevation_deg", "30"),
    ];
    for &(k, v) in extra {
        match pairs.iter_mut().find(|(name, _)| *name == k) {
            Some(pair) => pair.1 = v,
            None => pairs.push((k, v)),
        }
    }
    ProductRequest::from_params(kind, &RequestParams::from_pairs(pairs).unwrap()).unwrap()
}

/// Linear sRGB of every direction of a sky or ground artifact.
fn dome_rgb(req: &ProductRequest) -> Vec<[f64; 3]> {
    let image = req.compute(service_support::shared_engine()).unwrap();
    let table = skybake_product::artifact::dome_table_of(&image).unwrap();
    let w = skybake_physics::spectrum::colour::XyzWeights::new(&table.wavelengths_nm);
    table
        .radiance
        .chunks(table.wavelengths_nm.len())
        .map(|s| w.linear_srgb(&s.iter().map(|&v| v as f64).collect::<Vec<_>>()))
        .collect()
}

#[test]
fn a_sky_or_ground_png_runs_at_fewer_wavelengths_and_changes_less_than_predicted() {
    let small = [("elevation_count", "17"), ("azimuth_count", "12")];
    for (kind, extra) in [
        (ProductKind::Sky, small.to_vec()),
        (
            ProductKind::Sky,
            [&small[..], &[("sun_elevation_deg", "5")]].concat(),
        ),
        (ProductKind::Ground, small.to_vec()),
    ] {
        let (png, spectral) = (
            dome_request(kind, "png", &extra),
            dome_request(kind, "json", &extra),
        );
        let subset = png.rgb_only.clone().expect("the rule fires");
        assert!(spectral.rgb_only.is_none());
        assert_eq!(subset.requested_nm, sixteen());
        assert!(subset.internal_nm.len() < 16 && subset.internal_nm.len() >= 3);
        assert_eq!(
            png.spec.wavelengths_nm.as_nm(),
            subset.internal_nm.as_slice()
        );
        assert!(subset.predicted_error <= subset.allowance);
        // Its own key; undone, it is the spectral request.
        assert_ne!(png.cache_key(), spectral.cache_key());
        assert_eq!(
            png.clone().without_rgb_only().unwrap().cache_key(),
            spectral.cache_key()
        );
        let plan = serde_json::to_value(png.plan().unwrap()).unwrap();
        assert_eq!(plan["wavelengths"]["rule"], "rgb_only", "{plan}");
        // The RGB of every direction changes by less than predicted (largest channel change
        // relative to the direction's mean channel).
        let (a, b) = (dome_rgb(&png), dome_rgb(&spectral));
        let worst = a
            .iter()
            .zip(&b)
            .filter(|(_, f)| f.iter().any(|&v| v != 0.0))
            .map(|(x, f)| {
                let scale = (f[0].abs() + f[1].abs() + f[2].abs()) / 3.0;
                (0..3).map(|c| (x[c] - f[c]).abs()).fold(0.0, f64::max) / scale
            })
            .fold(0.0, f64::max);
        eprintln!(
            "{kind:?} {extra:?}: {} of 16 wavelengths, largest RGB change {worst:.4}, predicted {:.4}",
            subset.internal_nm.len(),
            subset.predicted_error
        );
        assert!(worst <= subset.predicted_error, "{worst}");
    }
    // Three wavelengths keep theirs.
    let three = dome_request(ProductKind::Sky, "png", &[("wavelengths", "440,550,680")]);
    assert!(three.rgb_only.is_none());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sky_png_has_its_own_key_unless_the_spectral_sky_is_cached_and_jobs_keep_theirs() {
    let dir = Scratch::new("rgb-only-sky");
    let state = AppState::new(settings(dir.path())).unwrap();
    state.start_job_workers();
    let q = "method=fast&quality=draft&elevation_count=9&azimuth_count=8&sun_elevation_deg=30";
    let png = dome_request(
        ProductKind::Sky,
        "png",
        &[
            ("quality", "draft"),
            ("elevation_count", "9"),
            ("azimuth_count", "8"),
        ],
    );
    let spectral = png.clone().without_rgb_only().unwrap();
    assert!(png.rgb_only.is_some());
    let state = &state;
    let get = |uri: String| async move { call(state, "GET", &uri, Vec::new()).await };
    let key = |r: &service_support::Response| r.header("x-skybake-cache-key").map(str::to_string);
    let r = get(format!("/v1/sky?{q}&format=png")).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(key(&r), Some(png.cache_key()));
    let r = get(format!("/v1/sky?{q}&format=exr")).await;
    assert_eq!(key(&r), Some(spectral.cache_key()));
    let r = get(format!("/v1/sky?{q}&format=png")).await;
    assert_eq!(key(&r), Some(spectral.cache_key()));
    // The plan of a PNG names the rule.
    let body = json!({"product": "sky", "format": "png", "method": "fast", "quality": "draft",
                      "elevation_count": 9, "azimuth_count": 8, "sun_elevation_deg": 30});
    let r = call(state, "POST", "/v1/plan", body.to_string()).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["plan"]["wavelengths"]["rule"], "rgb_only");
    // A job's item downloaded as a PNG is the job's spectral artifact.
    let job = json!({"products": [{"product": "sky", "method": "fast", "quality": "draft",
        "elevation_count": 9, "azimuth_count": 8, "sun_elevation_deg": 40}]});
    let r = call(state, "POST", "/v1/jobs", job.to_string()).await;
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let mut status = Value::Null;
    for _ in 0..600 {
        status = get(format!("/v1/jobs/{id}")).await.json();
        if status["state"] == "completed" {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert_eq!(status["state"], "completed", "{status}");
    let item_key = status["artifacts"]["items"][0]["cache_key"]
        .as_str()
        .unwrap()
        .to_string();
    let r = get(format!("/v1/jobs/{id}/artifacts/0?format=png")).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(key(&r), Some(item_key));
    assert!(r.body.starts_with(b"\x89PNG"));
}
