//! Twilight and the spherical planet: sky radiance against an independent backward
//! Monte Carlo on the spherical shell (tools/spherical_mc.py, numpy; its plane-parallel limit
//! agrees with DISORT to 0.8 % max, −0.1 % mean, see tools/README.md). The reference files are
//! tests/data/spherical_mc_*.json; each case carries its Monte Carlo standard error.
//!
//! Tolerances of the precise method: 2 % for sun ≥ 0°, 4 % down to −6°, 10 % down to
//! −12°, each widened by twice the case's Monte Carlo standard error (the reference's own noise).

//! Twilight and the spherical planet: sky radiance against an independent backward
//! Monte Carlo on the spherical shell (tools/spherical_mc.py, numpy; its plane-parallel limit
//! agrees with DISORT to 0.8 % max, −0.1 % mean, see tools/README.md). The reference files are
//! tests/data/spherical_mc_*.json; each case carries its Monte Carlo standard error.
//!
//! Tolerances of the precise method: 2 % for sun ≥ 0°, 4 % down to −6°, 10 % down to
//! −12°, each widened by twice the case's Monte Carlo standard error (the reference's own noise).
//!
//! Every case goes through the `sky` product a user would request (probes at the Monte Carlo's
//! view directions), at standard quality, the quality the README figures are stated for; one
//! engine is shared by the tests of this file, so each table is built once. The same comparison
//! at quality `high` is `#[ignore]`d (minutes on 2 cores).

use serde_json::Value;
use skybake_engine::engine::{stated_twilight_error, Engine, FAST_TWILIGHT_LIMIT_DEG};
use skybake_engine::spec::{DomeShape, Quality};
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_physics::atmosphere::{presets::preset, Medium};
use skybake_physics::spectrum::Wavelengths;
use skybake_product::params::RequestParams;
use std::sync::OnceLock;

/// The engine shared by the tests of this file (its table cache keeps the shared tables).
fn engine() -> &'static Engine {
    static ENGINE: OnceLock<Engine> = OnceLock::new();
    ENGINE.get_or_init(Engine::new)
}

const ALL: [&str; 3] = [
    "spherical_mc_ground.json",
    "spherical_mc_spectral.json",
    "spherical_mc_altitude.json",
];

fn load(name: &str) -> Vec<Value> {
    let path = format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    v["cases"].as_array().unwrap().clone()
}

fn f(v: &Value, k: &str) -> f64 {
    v[k].as_f64().unwrap()
}

/// Tolerance of the precise method in a sun-elevation band.
fn precise_tolerance(sun_deg: f64) -> f64 {
    if sun_deg >= 0.0 {
        0.02
    } else if sun_deg >= -6.0 {
        0.04
    } else {
        0.10
    }
}

/// One compared case.
struct Row {
    sun_deg: f64,
    deviation: f64,
    /// The error the product states (`error_estimate.relative_error`).
    stated: f64,
    mc_rel_error: f64,
    label: String,
}

/// Our radiance for every Monte Carlo case, per unit solar irradiance, from `sky` requests with
/// `method` at `quality` on the `rayleigh-only` atmosphere the Monte Carlo uses (R = 6360 km):
/// one request per (albedo, observer altitude, sun elevation) with every wavelength of that
/// albedo's cases and the cases' view directions as probes.
fn compare(method: &str, quality: &str) -> Vec<Row> {
    let cases: Vec<Value> = ALL.iter().flat_map(|n| load(n)).collect();
    let key = |c: &Value| {
        (
            f(c, "ground_albedo"),
            f(c, "observer_altitude_m"),
            f(c, "sun_elevation_deg"),
        )
    };
    let mut groups: Vec<(f64, f64, f64)> = cases.iter().map(key).collect();
    groups.sort_by(|a, b| a.partial_cmp(b).unwrap());
    groups.dedup();
    let mut rows = Vec::new();
    for g @ (albedo, altitude, sun) in groups {
        let mut nm: Vec<f64> = cases
            .iter()
            .filter(|c| f(c, "ground_albedo") == albedo)
            .map(|c| f(c, "wavelength_nm"))
            .collect();
        nm.sort_by(f64::total_cmp);
        nm.dedup();
        let mine: Vec<&Value> = cases.iter().filter(|c| key(c) == g).collect();
        let probes: Vec<(f64, f64)> = mine
            .iter()
            .map(|c| (f(c, "view_zenith_deg"), f(c, "view_azimuth_deg")))
            .collect();
        let wavelengths = nm
            .iter()
            .map(|l| l.to_string())
            .collect::<Vec<_>>()
            .join(",");
        let spec = skybake_product::params::common_spec(
            &RequestParams {
                sun_elevation_deg: Some(sun.to_string()),
                observer_altitude_m: Some(altitude.to_string()),
                atmosphere: Some("rayleigh-only".into()),
                ground_albedo: Some(albedo.to_string()),
                wavelengths: Some(wavelengths),
                method: Some(method.into()),
                quality: Some(quality.into()),
                ..Default::default()
            },
            -90.0,
        )
        .unwrap();
        let shape = DomeShape {
            elevation_count: 2,
            azimuth_count: 1,
        };
        let sky = engine().sky(&spec, shape, &probes).unwrap();
        let w = Wavelengths::new(nm.clone()).unwrap();
        let m = Medium::new(&preset("rayleigh-only").unwrap(), &w, Some(albedo)).unwrap();
        for (c, probe) in mine.iter().zip(&sky.probes) {
            let li = nm.iter().position(|&l| l == f(c, "wavelength_nm")).unwrap();
            let ours = probe.radiance_w_m2_sr_nm[li] / m.solar_irradiance[li];
            let mc = f(c, "radiance_per_sr");
            if f(c, "std_error_per_sr") > 0.2 * mc {
                // The night side seen from 400 km: too dark for the Monte Carlo to resolve.
                eprintln!("skipped (MC noise > 20 %): {c}");
                continue;
            }
            rows.push(Row {
                sun_deg: sun,
                deviation: ours / mc - 1.0,
                stated: sky.meta.error_estimate.relative_error,
                mc_rel_error: f(c, "std_error_per_sr") / mc,
                label: format!(
                    "{} nm a {albedo} h {altitude} m sun {sun}° vz {} va {}",
                    nm[li], probe.view_zenith_deg, probe.view_azimuth_deg
                ),
            });
        }
    }
    rows
}

fn report(what: &str, rows: &[Row]) {
    for r in rows {
        eprintln!(
            "{what} {}: {:+.2} % (MC ±{:.2} %)",
            r.label,
            100.0 * r.deviation,
            100.0 * r.mc_rel_error
        );
    }
}

/// Largest |deviation| in each band (sun ≥ 0, [−6, 0), [−12, −6)).
fn band_maxima(rows: &[Row]) -> [f64; 3] {
    let mut m = [0.0f64; 3];
    for r in rows {
        let b = if r.sun_deg >= 0.0 {
            0
        } else if r.sun_deg >= -6.0 {
            1
        } else {
            2
        };
        m[b] = m[b].max(r.deviation.abs());
    }
    m
}

/// Checks the precise method's rows against the tolerances of `precise_tolerance`.
fn check_precise(quality: &str) {
    let rows = compare("precise", quality);
    report("precise", &rows);
    let bands = band_maxima(&rows);
    eprintln!(
        "precise ({quality}) max |deviation|: sun ≥ 0° {:.2} %, 0…−6° {:.2} %, −6…−12° {:.2} %",
        100.0 * bands[0],
        100.0 * bands[1],
        100.0 * bands[2]
    );
    let bad: Vec<String> = rows
        .iter()
        .filter(|r| r.deviation.abs() > precise_tolerance(r.sun_deg) + 2.0 * r.mc_rel_error)
        .map(|r| format!("{}: {:+.2} %", r.label, 100.0 * r.deviation))
        .collect();
    assert!(bad.is_empty(), "outside tolerance: {bad:#?}");
    // What the product states covers what was measured.
    for r in &rows {
        let stated = stated_twilight_error(MsMethod::Precise, r.sun_deg);
        assert!(
            r.deviation.abs() <= stated + 2.0 * r.mc_rel_error,
            "{}: {:+.2} % > stated {:.1} %",
            r.label,
            100.0 * r.deviation,
            100.0 * stated
        );
    }
}

#[test]
fn precise_sky_matches_spherical_monte_carlo_from_day_to_nautical_twilight() {
    // The twilight regression test: before the fix, the precise sky at −6° read 33 % too
    // bright at view zenith 85° away from the sun and 36 % at 89° (+85 % at −4°, +106 % at −9°).
    check_precise("standard");
}

#[test]
#[ignore = "quality high: minutes on 2 cores; run with --ignored for the README figures"]
fn precise_sky_matches_spherical_monte_carlo_at_quality_high() {
    check_precise("high");
}

#[test]
fn a_fast_request_in_twilight_is_within_what_its_error_estimate_states() {
    // What a `method=fast` request gets: the fast method is retired, so the precise tables at
    // the draft preset (the plan says so), within the error the product states.
    let rows = compare("fast", "standard");
    report("fast", &rows);
    let bands = band_maxima(&rows);
    eprintln!(
        "fast requests max |deviation|: sun ≥ 0° {:.1} %, 0…−6° {:.1} %, −6…−12° {:.1} %",
        100.0 * bands[0],
        100.0 * bands[1],
        100.0 * bands[2]
    );
    for r in &rows {
        let stated = r.stated;
        assert!(
            r.deviation.abs() <= stated + 2.0 * r.mc_rel_error,
            "{}: {:+.1} % > stated {:.1} %",
            r.label,
            100.0 * r.deviation,
            100.0 * stated
        );
    }
}

#[test]
fn fast_tables_alone_are_too_dark_below_the_substitution_limit() {
    // One reason the fast method is retired: its tables (evaluated without the planner, as
    // the paper's method) against the ground-level Monte Carlo cases (550 nm, black ground)
    // below −4°.
    use skybake_physics::atmosphere::integrate::Scratch;
    use skybake_physics::atmosphere::shared::SharedTables;
    use skybake_physics::atmosphere::sky::{Observer, RadianceEvaluator};
    let (fast, precise) = skybake_engine::engine::settings_for(Quality::Standard);
    let w = Wavelengths::new(vec![550.0]).unwrap();
    let m = Medium::new(&preset("rayleigh-only").unwrap(), &w, Some(0.0)).unwrap();
    let shared = SharedTables::new(m, fast, precise);
    let (mut s, mut out, mut tr) = (Scratch::new(1), vec![0.0], vec![0.0]);
    let mut worst = [0.0f64; 2];
    for c in load("spherical_mc_ground.json") {
        let sun = f(&c, "sun_elevation_deg");
        if sun >= FAST_TWILIGHT_LIMIT_DEG {
            continue;
        }
        let obs = Observer {
            altitude_m: 0.0,
            sun_elevation_rad: sun.to_radians(),
        };
        let ev = RadianceEvaluator::new(&shared, MsMethod::Fast, obs, Quality::Standard.steps());
        let (vz, va) = (f(&c, "view_zenith_deg"), f(&c, "view_azimuth_deg"));
        ev.eval(vz.to_radians(), va.to_radians(), &mut s, &mut out, &mut tr);
        let deviation = out[0] / shared.medium.solar_irradiance[0] / f(&c, "radiance_per_sr") - 1.0;
        let band = usize::from(sun < -6.0);
        worst[band] = worst[band].max(deviation.abs());
    }
    eprintln!(
        "fast tables alone, max |deviation|: −4…−6° {:.0} %, −6…−12° {:.0} %",
        100.0 * worst[0],
        100.0 * worst[1]
    );
    assert!(worst[0] > 0.10 && worst[1] > 0.10, "{worst:?}");
}

/// `sun` product at `sun_deg` on the `earth` preset (aerosol 0.1, ozone 300 DU), precise method.
fn earth_sun(sun_deg: f64) -> skybake_engine::engine::SunProduct {
    let p = RequestParams {
        sun_elevation_deg: Some(sun_deg.to_string()),
        atmosphere: Some("earth".into()),
        wavelengths: Some("400,440,480,520,560,600,640,680,700".into()),
        method: Some("precise".into()),
        quality: Some("standard".into()),
        ..Default::default()
    };
    engine()
        .sun(&skybake_product::params::common_spec(&p, -90.0).unwrap())
        .unwrap()
}

#[test]
fn twilight_illuminance_is_near_published_clear_sky_measurements() {
    // AMS Glossary of Meteorology (2024), "Civil twilight" and "Nautical twilight": during a clear
    // evening horizontal illuminance falls from ~585–410 lx at sunset (sun's unrefracted centre at
    // 0°) to ~3.5–2 lx at −6° and ~0.008 lx at −12°. Those are measurements under real skies
    // (varying aerosol and ozone), ours the `earth` model atmosphere (aerosol optical depth 0.1).
    // Measured here (9 wavelengths): 983 lx, 6.5 lx and 0.018 lx, 1.7–2.4× the published figures at
    // all three elevations (and 6.8e-5 lx at −18° against the glossary's ~6e-4 lx, 0.11×). The
    // comparison is a plausibility check, not a validation: the glossary gives climatological
    // ranges for no stated atmosphere. What we measured of the causes (16 wavelengths, `skybake
    // sun`): aerosol optical depth 0.3 instead of 0.1 lowers 0° and −6° by 13–14 % (850 lx,
    // 5.55 lx); the apparent sunset (refracted upper limb on the horizon, centre at −0.833°) gives
    // 638 lx. The check is within a factor 2.5 of the published range.
    let published = [(0.0, 410.0, 585.0), (-6.0, 2.0, 3.5), (-12.0, 0.008, 0.008)];
    for (sun, lo, hi) in published {
        let p = earth_sun(sun);
        let lux = p.global_horizontal_illuminance_lux;
        eprintln!(
            "sun {sun}°: {lux:.4} lx (published {lo}–{hi} lx), diffuse {:.4} lx, CCT {:?} K, Duv {:?}",
            p.diffuse_horizontal_illuminance_lux,
            p.global_correlated_colour_temperature_k,
            p.global_duv
        );
        assert!(lux >= lo / 2.5 && lux <= 2.5 * hi, "sun {sun}: {lux} lx");
        if sun < -1.0 {
            // Below the horizon the light is all diffuse.
            assert_eq!(lux, p.diffuse_horizontal_illuminance_lux);
            assert!(p.direct_normal_irradiance_w_m2_nm.iter().all(|&v| v == 0.0));
        }
    }
    // Down to the darkest modelled twilight (about −32° for a ground observer): no refusal,
    // finite, falling with the sun.
    let mut last = f64::INFINITY;
    for sun in [-8.0, -10.0, -14.0, -18.0, -24.0] {
        let lux = earth_sun(sun).global_horizontal_illuminance_lux;
        eprintln!("sun {sun}°: {lux:.3e} lx");
        assert!(
            lux.is_finite() && lux > 0.0 && lux < last,
            "sun {sun}: {lux}"
        );
        last = lux;
    }
}
