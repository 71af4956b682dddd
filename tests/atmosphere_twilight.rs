//! Twilight and the spherical planet (issue 14): sky radiance against an independent backward
//! Monte Carlo on the spherical shell (tools/spherical_mc.py, numpy; its plane-parallel limit
//! agrees with DISORT to 0.8 % max, −0.1 % mean, see tools/README.md). The reference files are
//! tests/data/spherical_mc_*.json; each case carries its Monte Carlo standard error.
//!
//! Tolerances of the precise method (issue 14): 2 % for sun ≥ 0°, 4 % down to −6°, 10 % down to
//! −12°, each widened by twice the case's Monte Carlo standard error (the reference's own noise).

use serde_json::Value;
use skybake::atmosphere::integrate::Scratch;
use skybake::atmosphere::sky::{MsMethod, Observer, RadianceEvaluator};
use skybake::atmosphere::{presets::preset, shared::SharedTables, Medium};
use skybake::engine::{settings_for, stated_twilight_error, FAST_TWILIGHT_LIMIT_DEG};
use skybake::spec::Quality;
use skybake::spectrum::Wavelengths;

fn load(name: &str) -> Vec<Value> {
    let path = format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    v["cases"].as_array().unwrap().clone()
}

fn f(v: &Value, k: &str) -> f64 {
    v[k].as_f64().unwrap()
}

/// Tolerance of the precise method in a sun-elevation band (issue 14).
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
    mc_rel_error: f64,
    label: String,
}

/// Our radiance for every Monte Carlo case in `files`, per unit solar irradiance, with `method`
/// at `quality`, on the `rayleigh-only` atmosphere the Monte Carlo uses (R = 6360 km).
fn compare(files: &[&str], method: MsMethod, quality: Quality) -> Vec<Row> {
    let mut cases: Vec<Value> = files.iter().flat_map(|n| load(n)).collect();
    cases.sort_by(|a, b| f(a, "ground_albedo").total_cmp(&f(b, "ground_albedo")));
    let mut rows = Vec::new();
    // One set of shared tables per albedo, with every wavelength the cases use.
    let mut albedos: Vec<f64> = cases.iter().map(|c| f(c, "ground_albedo")).collect();
    albedos.dedup();
    for albedo in albedos {
        let mine: Vec<&Value> = cases
            .iter()
            .filter(|c| f(c, "ground_albedo") == albedo)
            .collect();
        let mut nm: Vec<f64> = mine.iter().map(|c| f(c, "wavelength_nm")).collect();
        nm.sort_by(f64::total_cmp);
        nm.dedup();
        let w = Wavelengths::new(nm.clone()).unwrap();
        let m = Medium::new(&preset("rayleigh-only").unwrap(), &w, Some(albedo)).unwrap();
        let (fast, precise) = settings_for(quality);
        let shared = SharedTables::new(m, fast, precise);
        let n = nm.len();
        let (mut s, mut out, mut tr) = (Scratch::new(n), vec![0.0; n], vec![0.0; n]);
        for c in mine {
            let li = nm.iter().position(|&l| l == f(c, "wavelength_nm")).unwrap();
            let obs = Observer {
                altitude_m: f(c, "observer_altitude_m"),
                sun_elevation_rad: f(c, "sun_elevation_deg").to_radians(),
            };
            let ev = RadianceEvaluator::new(&shared, method, obs, quality.steps());
            let (vz, va) = (f(c, "view_zenith_deg"), f(c, "view_azimuth_deg"));
            ev.eval(vz.to_radians(), va.to_radians(), &mut s, &mut out, &mut tr);
            let ours = out[li] / shared.medium.solar_irradiance[li];
            let mc = f(c, "radiance_per_sr");
            if f(c, "std_error_per_sr") > 0.2 * mc {
                // The night side seen from 400 km: too dark for the Monte Carlo to resolve.
                eprintln!("skipped (MC noise > 20 %): {c}");
                continue;
            }
            rows.push(Row {
                sun_deg: f(c, "sun_elevation_deg"),
                deviation: ours / mc - 1.0,
                mc_rel_error: f(c, "std_error_per_sr") / mc,
                label: format!(
                    "{} nm a {albedo} h {} m sun {}° vz {vz} va {va}",
                    nm[li],
                    obs.altitude_m,
                    f(c, "sun_elevation_deg")
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

#[test]
fn precise_sky_matches_spherical_monte_carlo_from_day_to_nautical_twilight() {
    // The regression test of issue 14: before the fix, the precise sky at −6° read 33 % too
    // bright at view zenith 85° away from the sun and 36 % at 89° (+85 % at −4°, +106 % at −9°).
    let rows = compare(
        &[
            "spherical_mc_ground.json",
            "spherical_mc_spectral.json",
            "spherical_mc_altitude.json",
        ],
        MsMethod::Precise,
        Quality::High,
    );
    report("precise", &rows);
    let bands = band_maxima(&rows);
    eprintln!(
        "precise max |deviation|: sun ≥ 0° {:.2} %, 0…−6° {:.2} %, −6…−12° {:.2} %",
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
}

#[test]
fn fast_sky_error_in_twilight_is_within_what_its_error_estimate_states() {
    let rows = compare(
        &[
            "spherical_mc_ground.json",
            "spherical_mc_spectral.json",
            "spherical_mc_altitude.json",
        ],
        MsMethod::Fast,
        Quality::Standard,
    );
    report("fast", &rows);
    let bands = band_maxima(&rows);
    eprintln!(
        "fast max |deviation|: sun ≥ 0° {:.1} %, 0…−6° {:.1} %, −6…−12° {:.1} %",
        100.0 * bands[0],
        100.0 * bands[1],
        100.0 * bands[2]
    );
    // Where the planner keeps the fast method, its error is within what the product states;
    // below the limit the planner switches to the precise tables because it is not.
    let mut worst_below = 0.0f64;
    for r in &rows {
        if r.sun_deg < FAST_TWILIGHT_LIMIT_DEG {
            worst_below = worst_below.max(r.deviation.abs());
            continue;
        }
        let stated = stated_twilight_error(MsMethod::Fast, r.sun_deg);
        assert!(
            r.deviation.abs() <= stated + 2.0 * r.mc_rel_error,
            "{}: {:+.1} % > stated {:.0} %",
            r.label,
            100.0 * r.deviation,
            100.0 * stated
        );
    }
    assert!(worst_below > 0.10, "{worst_below}");
}

/// `sun` product at `sun_deg` on the `earth` preset (aerosol 0.1, ozone 300 DU), precise method.
fn earth_sun(engine: &skybake::engine::Engine, sun_deg: f64) -> skybake::engine::SunProduct {
    let p = skybake::product::params::RequestParams {
        sun_elevation_deg: Some(sun_deg.to_string()),
        atmosphere: Some("earth".into()),
        wavelengths: Some("400,440,480,520,560,600,640,680,700".into()),
        method: Some("precise".into()),
        quality: Some("standard".into()),
        ..Default::default()
    };
    engine
        .sun(&skybake::spec::CommonSpec::from_params(&p, -18.0).unwrap())
        .unwrap()
}

#[test]
fn twilight_illuminance_is_near_published_clear_sky_measurements() {
    // AMS Glossary of Meteorology (2024), "Civil twilight" and "Nautical twilight": during a clear
    // evening horizontal illuminance falls from ~585–410 lx at sunset (sun's unrefracted centre at
    // 0°) to ~3.5–2 lx at −6° and ~0.008 lx at −12°. Those are measurements under real skies
    // (varying aerosol and ozone), ours the `earth` model atmosphere (aerosol optical depth 0.1).
    // Measured here: 969 lx, 6.5 lx and 0.017 lx, 1.7–2.4× the published figures at all three
    // elevations; the check is within a factor 2.5 of the published range.
    let engine = skybake::engine::Engine::new();
    let published = [(0.0, 410.0, 585.0), (-6.0, 2.0, 3.5), (-12.0, 0.008, 0.008)];
    for (sun, lo, hi) in published {
        let p = earth_sun(&engine, sun);
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
    // The whole range the sky accepts, down to −18°: no refusal, finite, falling with the sun.
    let mut last = f64::INFINITY;
    for sun in [-8.0, -10.0, -14.0, -18.0] {
        let lux = earth_sun(&engine, sun).global_horizontal_illuminance_lux;
        assert!(
            lux.is_finite() && lux >= 0.0 && lux < last,
            "sun {sun}: {lux}"
        );
        last = lux;
    }
}
