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

/// `skybake lut-eval` on a `skyview` bundle (the manifest's `format`): a synthetic bundle whose
/// textures are constant, so every value follows from the geometry alone — the stored values
/// are per metre of ray, so the sky radiance is texel × scale × the ray's length × the phase
/// function (Rayleigh's and the aerosol's Cornette–Shanks, written out here), the aerial
/// perspective along a ray to the top is the same per metre times the segment's length (its
/// transmittance is the ratio of two equal lookups, 1), and the sky irradiance is the table's
/// value × the depth of atmosphere above.
#[test]
fn lut_eval_reads_a_skyview_bundle() {
    use skybake_lut::skyview::{self, N_ALT, N_AZ, N_SUN, N_VIEW};
    use skybake_lut::SkyViewBundle;
    use skybake_physics::phase::Phase;
    use skybake_product::lut::Layout;

    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli-lut-eval-skyview");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("bundle")).unwrap();
    let (bottom, top) = (6_360_000.0f64, 6_460_000.0f64);
    let g = 0.7f64;
    let solar = [1500.0, 1850.0, 1800.0];
    // Per-slice scales of the Rayleigh-like part (R, G, B) and the Mie part.
    let (s_r, s_m) = ([1.0f32, 2.0, 4.0], [3.0f32, 3.0, 1.5]);
    let texel = 0.25f32;
    let mut scale = constant(N_SUN, N_ALT, 1, 6, 0.0);
    for px in scale.data.chunks_mut(6) {
        px[..3].copy_from_slice(&s_r);
        px[3..].copy_from_slice(&s_m);
    }
    let view_texture = || Texture {
        sample: Sample::Half,
        ..constant(N_AZ, N_VIEW, N_ALT * N_SUN, 3, texel)
    };
    let bundle = SkyViewBundle {
        channels: Channels::Rgb,
        wavelengths_nm: vec![680.0, 550.0, 440.0],
        params: AtmosphereParameters {
            solar_irradiance: solar.to_vec(),
            sun_angular_radius: 0.00465,
            bottom_radius: bottom,
            top_radius: top,
            rayleigh_scattering: vec![5.8e-6, 1.35e-5, 3.31e-5],
            mie_scattering: vec![4.0e-6, 4.0e-6, 4.0e-6],
            mie_phase_function_g: g,
            mu_s_min: -0.376,
            ground_albedo: vec![0.1, 0.1, 0.1],
        },
        aerosol_phase: Phase::CornetteShanks { g },
        transmittance: constant(TRANSMITTANCE_WIDTH, TRANSMITTANCE_HEIGHT, 1, 3, 0.5),
        rayleigh: view_texture(),
        mie: view_texture(),
        scale,
        irradiance: constant(N_SUN, N_ALT, 1, 3, 8.0),
        timing_ms: [0.0; 4],
    };
    let req = LutRequest::from_params(&RequestParams::default())
        .unwrap()
        .with_layout(Layout::SkyView);
    for (name, bytes) in req.skyview_files(&bundle).unwrap() {
        std::fs::write(dir.join("bundle").join(name), bytes).unwrap();
    }

    let pi = std::f64::consts::PI;
    let rayleigh_phase = |nu: f64| 3.0 / (16.0 * pi) * (1.0 + nu * nu);
    let cornette_shanks = |nu: f64| {
        3.0 / (8.0 * pi) * (1.0 - g * g) / (2.0 + g * g) * (1.0 + nu * nu)
            / (1.0 + g * g - 2.0 * g * nu).powf(1.5)
    };
    // Per metre of ray, channel c, for view–sun cosine nu.
    let per_metre = |c: usize, nu: f64| {
        (texel * s_r[c]) as f64 * rayleigh_phase(nu) + (texel * s_m[c]) as f64 * cornette_shanks(nu)
    };
    let r = bottom + 1000.0;
    let sun = [0.6, 0.0, 0.8];
    // Up at 30° from the zenith: to the top; down at 120°: to the ground (below the horizon).
    let up = [0.5, 0.0, 0.75f64.sqrt()];
    let down = [120f64.to_radians().sin(), 0.0, 120f64.to_radians().cos()];
    let to_top = |mu: f64| -r * mu + (r * r * (mu * mu - 1.0) + top * top).sqrt();
    let to_ground = |mu: f64| -r * mu - (r * r * (mu * mu - 1.0) + bottom * bottom).sqrt();
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // A point 20 km up the first ray, and the ground point the second ray meets.
    let along = |v: [f64; 3], d: f64| [v[0] * d, v[1] * d, r + v[2] * d];
    let ground_point = along(down, to_ground(down[2]));
    let queries = serde_json::json!({"queries": [
        {"function": "sky_radiance", "camera": [0, 0, r], "view": up, "sun": sun},
        {"function": "sky_radiance", "camera": [0, 0, r], "view": down, "sun": sun},
        {"function": "sky_radiance_to_point", "camera": [0, 0, r], "point": along(up, 20_000.0), "sun": sun},
        {"function": "sky_radiance_to_point", "camera": [0, 0, r], "point": ground_point, "sun": sun},
        {"function": "sun_and_sky_irradiance", "point": [0, 0, r], "normal": [0, 0, 1], "sun": sun},
        {"function": "sun_and_sky_irradiance", "point": [0, 0, r], "normal": [1, 0, 0], "sun": sun},
    ]});
    let (code, out, err) = lut_eval(&dir, &queries.to_string());
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["format"], skyview::LAYOUT, "{out}");
    let res = &v["results"];
    let value = |i: usize, key: &str, c: usize| res[i][key][c].as_f64().unwrap();
    let close = |got: f64, want: f64, rel: f64, what: &str| {
        assert!(
            (got - want).abs() <= rel * want.abs(),
            "{what}: {got} against {want}\n{out}"
        )
    };
    for (c, solar) in solar.iter().enumerate() {
        let (nu_up, nu_down) = (dot(up, sun), dot(down, sun));
        close(
            value(0, "radiance", c),
            per_metre(c, nu_up) * to_top(up[2]),
            1e-9,
            "sky up",
        );
        assert_eq!(value(0, "transmittance", c), 0.5, "{out}");
        close(
            value(1, "radiance", c),
            per_metre(c, nu_down) * to_ground(down[2]),
            1e-9,
            "sky down",
        );
        assert_eq!(value(1, "transmittance", c), 0.0, "{out}");
        close(
            value(2, "radiance", c),
            per_metre(c, nu_up) * 20_000.0,
            1e-7,
            "aerial up",
        );
        close(
            value(2, "transmittance", c),
            1.0,
            1e-12,
            "aerial up transmittance",
        );
        // The ground point's ray has no length (to a millimetre of rounding).
        close(
            value(3, "radiance", c),
            per_metre(c, nu_down) * to_ground(down[2]),
            1e-5,
            "aerial to the ground",
        );
        close(
            value(4, "sky_irradiance", c),
            8.0 * (top - r),
            1e-6,
            "sky irradiance",
        );
        close(
            value(4, "sun_irradiance", c),
            solar * 0.5 * 0.8,
            1e-9,
            "sun irradiance",
        );
        // A vertical surface facing the sun: half the sky (his tilt factor), the sun at 0.6.
        close(
            value(5, "sky_irradiance", c),
            8.0 * (top - r) * 0.5,
            1e-6,
            "sky irradiance, tilted",
        );
        close(
            value(5, "sun_irradiance", c),
            solar * 0.5 * 0.6,
            1e-9,
            "sun irradiance, tilted",
        );
    }

    // A manifest of another layout, or a missing texture, is refused by name.
    let manifest_path = dir.join("bundle").join("manifest.json");
    let text = std::fs::read_to_string(&manifest_path).unwrap();
    let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
    m["format"] = "octahedral".into();
    std::fs::write(&manifest_path, m.to_string()).unwrap();
    let (code, _, err) = lut_eval(&dir, r#"{"queries": []}"#);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("manifest") && err.contains("bruneton2017, skyview"),
        "{err}"
    );
    m["format"] = skyview::LAYOUT.into();
    m["parameterisation"]["sizes"]["N_AZ"] = 24.into();
    std::fs::write(&manifest_path, m.to_string()).unwrap();
    let (code, _, err) = lut_eval(&dir, r#"{"queries": []}"#);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("manifest") && err.contains("N_AZ"), "{err}");
    std::fs::write(&manifest_path, text).unwrap();
    std::fs::remove_file(dir.join("bundle").join(skyview::MIE_FILE)).unwrap();
    let (code, _, err) = lut_eval(&dir, r#"{"queries": []}"#);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("bundle") && err.contains(skyview::MIE_FILE),
        "{err}"
    );
}
