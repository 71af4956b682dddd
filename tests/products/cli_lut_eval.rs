//! `skybake lut-eval`: a bundle's files (written by the product's own encoder) read back and
//! evaluated by the reference reader; bad queries exit 2 naming `queries[i].…`. The bundle is a
//! synthetic one with constant textures, so the expected values follow from the textures alone.

use std::process::Command;

use skybake_lut::param::*;
use skybake_lut::{Bundle, Channels, Sample, Texture};
use skybake_product::lut::LutRequest;
use skybake_product::params::RequestParams;

fn constant(width: usize, height: usize, depth: usize, channels: usize, v: f32) -> Texture {
    Texture {
        width,
        height,
        depth,
        channels,
        sample: if channels == 4 {
            Sample::Half
        } else {
            Sample::Float
        },
        data: vec![v; width * height * depth * channels],
    }
}

fn lut_eval(dir: &std::path::Path, queries: &str) -> (i32, String, String) {
    let path = dir.join("queries.json");
    std::fs::write(&path, queries).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_skybake"))
        .arg("lut-eval")
        .arg(dir.join("bundle"))
        .arg(&path)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn lut_eval_reads_a_bundle_back_and_names_bad_queries() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli-lut-eval");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("bundle")).unwrap();
    let bundle = Bundle {
        channels: Channels::Rgb,
        wavelengths_nm: vec![680.0, 550.0, 440.0],
        params: AtmosphereParameters {
            solar_irradiance: vec![1500.0, 1850.0, 1800.0],
            sun_angular_radius: 0.00465,
            bottom_radius: 6_360_000.0,
            top_radius: 6_460_000.0,
            rayleigh_scattering: vec![5.8e-6, 1.35e-5, 3.31e-5],
            mie_scattering: vec![4.0e-6, 4.0e-6, 4.0e-6],
            mie_phase_function_g: 0.8,
            mu_s_min: -0.376,
            ground_albedo: vec![0.1, 0.1, 0.1],
        },
        transmittance: constant(TRANSMITTANCE_WIDTH, TRANSMITTANCE_HEIGHT, 1, 3, 0.5),
        scattering: constant(SCATTERING_WIDTH, SCATTERING_MU, SCATTERING_R, 4, 2.0),
        single_mie: None,
        irradiance: constant(IRRADIANCE_WIDTH, IRRADIANCE_HEIGHT, 1, 3, 8.0),
        timing_ms: [0.0; 4],
    };
    let req = LutRequest::from_params(&RequestParams::default()).unwrap();
    for (name, bytes) in req.files(&bundle).unwrap() {
        std::fs::write(dir.join("bundle").join(name), bytes).unwrap();
    }

    // Constant textures: transmittance 0.5 to the top; the sky irradiance on a horizontal
    // surface is the texture's 8; the sun's is solar irradiance × 0.5 × cos(zenith).
    let r = 6_360_100.0;
    let (code, out, err) = lut_eval(
        &dir,
        &format!(
            r#"{{"queries": [
            {{"function": "sky_radiance", "camera": [0, 0, {r}], "view": [0, 0, 2], "sun": [0.6, 0, 0.8]}},
            {{"function": "sun_and_sky_irradiance", "point": [0, 0, {r}], "normal": [0, 0, 1], "sun": [0.6, 0, 0.8]}}]}}"#
        ),
    );
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let res = &v["results"];
    for c in 0..3 {
        assert_eq!(res[0]["transmittance"][c].as_f64(), Some(0.5), "{out}");
        let l = res[0]["radiance"][c].as_f64().unwrap();
        assert!(l.is_finite() && l > 0.0, "{out}");
        assert!(
            (res[1]["sky_irradiance"][c].as_f64().unwrap() - 8.0).abs() < 1e-9,
            "{out}"
        );
        let sun = [1500.0, 1850.0, 1800.0][c] * 0.5 * 0.8;
        assert!(
            (res[1]["sun_irradiance"][c].as_f64().unwrap() - sun).abs() < 1e-9 * sun,
            "{out}"
        );
    }

    for (queries, field) in [
        (
            r#"{"queries": [{"function": "sky", "camera": [0, 0, 6370000], "view": [0, 0, 1], "sun": [0, 0, 1]}]}"#,
            "queries[0].function",
        ),
        (
            r#"{"queries": [{"function": "sky_radiance", "camera": [0, 0, 6000000], "view": [0, 0, 1], "sun": [0, 0, 1]}]}"#,
            "queries[0].camera",
        ),
        (
            r#"{"queries": [{"function": "sky_radiance", "camera": [0, 0, 6370000], "view": [0, 0, 0], "sun": [0, 0, 1]}]}"#,
            "queries[0].view",
        ),
        (
            r#"{"queries": [{"function": "sky_radiance", "camera": [0, 0], "view": [0, 0, 1], "sun": [0, 0, 1]}]}"#,
            "queries[0].camera",
        ),
        (r#"{"points": []}"#, "queries"),
    ] {
        let (code, _, err) = lut_eval(&dir, queries);
        assert_eq!(code, 2, "{queries}: {err}");
        assert!(err.contains(field), "{queries}: {err} should name {field}");
    }
    std::fs::remove_file(dir.join("bundle").join("scattering.exr")).unwrap();
    let (code, _, err) = lut_eval(&dir, r#"{"queries": []}"#);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("bundle") && err.contains("scattering.exr"),
        "{err}"
    );
}

/// `skybake lut --layout` refuses an unknown layout before computing anything, naming `layout`
/// and the choices.
#[test]
fn lut_refuses_an_unknown_layout_by_name() {
    let dir = std::env::temp_dir().join(format!("skybake-lut-layout-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(["lut", "--layout", "octahedral", "-o"])
        .arg(&dir)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("layout") && stderr.contains("bruneton2017, skyview"),
        "{stderr}"
    );
    assert!(!dir.exists(), "nothing is written");
}
