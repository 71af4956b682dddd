//! The CLI contract for the atmosphere products: JSON on stdout, files with -o, clear errors
//! naming the argument with exit code 2.

use std::process::Command;

/// The cache directory of this test binary's CLI calls, under the target directory (precise
/// tables persist between calls and runs, keyed by engine version like every cache entry).
fn table_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(concat!(module_path!(), "-tables"))
}

fn skybake(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(args)
        // Stored tables go to this test's own directory, not ./skybake-cache.
        .env("SKYBAKE_CACHE_DIR", table_dir())
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn invalid_arguments_exit_2_and_name_the_argument() {
    let cases: &[(&[&str], &str)] = &[
        (
            &["sky", "--sun-elevation-deg", "-95"],
            "--sun-elevation-deg",
        ),
        (
            &["sun", "--sun-elevation-deg", "-90.5"],
            "--sun-elevation-deg",
        ),
        (&["sky", "--wavelengths", "300,550"], "--wavelengths"),
        (
            &["sky", "--observer-altitude-m", "-5"],
            "--observer-altitude-m",
        ),
        (&["sky", "--atmosphere", "venus"], "--atmosphere"),
        (&["sky", "--ground-albedo", "2"], "--ground-albedo"),
        (&["sky", "--probe", "30"], "--probe"),
        (&["sky", "--elevation-count", "100000"], "--elevation-count"),
        (
            &[
                "sun",
                "--latitude",
                "95",
                "--longitude",
                "0",
                "--time",
                "2026-01-01T00:00:00Z",
            ],
            "--latitude",
        ),
        (
            &[
                "sun",
                "--latitude",
                "45",
                "--longitude",
                "0",
                "--time",
                "noon",
            ],
            "--time",
        ),
        (
            &[
                "sky",
                "-o",
                "table.txt",
                "--method",
                "fast",
                "--quality",
                "draft",
                "--wavelengths",
                "550",
            ],
            "output",
        ),
    ];
    for (args, field) in cases {
        let (code, _, err) = skybake(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(field), "{args:?}: '{err}' should name {field}");
    }
}

#[test]
fn a_missing_atmosphere_file_is_named_as_a_file_not_a_preset() {
    let (code, _, err) = skybake(&["sky", "--atmosphere", "nope.json"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--atmosphere"), "{err}");
    assert!(err.contains("cannot read nope.json"), "{err}");
    assert!(!err.contains("unknown preset"), "{err}");
    // An inline atmosphere's field is named under the flag, not as the query parameter.
    let earth = include_str!("../../config/atmospheres/earth.json");
    let bad = earth.replace("\"ground_albedo\": 0.1", "\"ground_albedo\": 7");
    assert_ne!(bad, earth);
    let (code, _, err) = skybake(&["sun", "--atmosphere", &bad]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--atmosphere ground_albedo"), "{err}");
}

#[test]
fn sky_probes_print_json_in_the_contract_shape() {
    let (code, out, err) = skybake(&[
        "sky",
        "--method",
        "fast",
        "--quality",
        "draft",
        "--wavelengths",
        "440,550,680",
        "--sun-elevation-deg",
        "25",
        "--probe",
        "30:0,60:180",
        "--format",
        "json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let probes = v["probes"].as_array().unwrap();
    assert_eq!(probes.len(), 2);
    assert_eq!(probes[1]["view_zenith_deg"], 60.0);
    assert_eq!(probes[1]["view_azimuth_deg"], 180.0);
    assert_eq!(
        probes[0]["radiance_w_m2_sr_nm"].as_array().unwrap().len(),
        3
    );
    assert!(v["error_estimate"]["relative_error"].as_f64().unwrap() > 0.0);
}

#[test]
fn atmosphere_print_round_trips_through_a_file() {
    let (code, out, _) = skybake(&["atmosphere", "--print", "mars"]);
    assert_eq!(code, 0);
    let dir = std::env::temp_dir().join(format!("skybake-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("mars.json");
    std::fs::write(&path, &out).unwrap();
    let (code, out, err) = skybake(&[
        "sun",
        "--atmosphere",
        path.to_str().unwrap(),
        "--method",
        "fast",
        "--quality",
        "draft",
        "--wavelengths",
        "550",
        "--sun-elevation-deg",
        "40",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    // Mars is 1.524 AU from the sun: 1/1.524² of Earth's solar irradiance.
    let e = v["solar_irradiance_w_m2_nm"][0].as_f64().unwrap();
    assert!((e - 1.8646 / (1.524f64 * 1.524)).abs() < 0.01, "{e}");
    let png = dir.join("sky.png");
    let (code, _, err) = skybake(&[
        "sky",
        "--atmosphere",
        "mars",
        "--method",
        "fast",
        "--quality",
        "draft",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    std::fs::remove_dir_all(&dir).ok();
}

/// `skybake plan` of a `--method fast` request shows the retired method's substitution: the
/// precise tables at the coarse preset of its atmosphere (draft in clear air, standard in haze),
/// with the reason and the measured evidence.
#[test]
fn plan_of_a_fast_request_shows_the_substitution() {
    for (atmosphere, preset) in [("earth", "draft"), ("earth-hazy", "standard")] {
        let (code, out, err) = skybake(&[
            "plan",
            "sky",
            "--method",
            "fast",
            "--quality",
            "high",
            "--atmosphere",
            atmosphere,
        ]);
        assert_eq!(code, 0, "{err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        let plan = &v["plan"];
        assert_eq!(plan["method"], "precise", "{v}");
        assert_eq!(plan["quality"], preset, "{v}");
        let sub = &plan["method_substitution"];
        assert_eq!(sub["reason"], "fast_retired", "{v}");
        assert_eq!(sub["requested"], "fast", "{v}");
        let detail = sub["detail"].as_str().unwrap();
        assert!(
            detail.contains("retired") && detail.contains("DISORT") && detail.contains(preset),
            "{detail}"
        );
    }
}
