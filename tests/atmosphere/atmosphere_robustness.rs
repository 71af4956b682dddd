//! Numerical robustness: extreme sun angles, observers from the ground to orbit,
//! horizontal and grazing views, the ends of the wavelength range and a very thick aerosol layer.
//! Every output finite and non-negative, and continuous where the physics is.

use skybake_engine::engine::{DomeShape, Engine};
use skybake_engine::spec::CommonSpec;
use skybake_product::params::RequestParams;

fn spec(pairs: &[(&str, &str)]) -> CommonSpec {
    let mut p = RequestParams {
        wavelengths: Some("360,550,830".into()),
        method: Some("fast".into()),
        quality: Some("draft".into()),
        ..Default::default()
    };
    for (k, v) in pairs {
        let v = Some(v.to_string());
        match *k {
            "sun_elevation_deg" => p.sun_elevation_deg = v,
            "observer_altitude_m" => p.observer_altitude_m = v,
            "atmosphere" => p.atmosphere = v,
            "method" => p.method = v,
            "quality" => p.quality = v,
            "wavelengths" => p.wavelengths = v,
            "ground_albedo" => p.ground_albedo = v,
            _ => panic!("unknown key {k}"),
        }
    }
    skybake_product::params::common_spec(&p, -18.0).unwrap()
}

fn assert_valid(values: impl IntoIterator<Item = f64>, what: &str) {
    for v in values {
        assert!(v.is_finite() && v >= 0.0, "{what}: {v}");
    }
}

const SUN: [&str; 5] = ["-18", "-0.5", "0", "0.05", "90"];
const ALTITUDES: [&str; 4] = ["0", "99999", "100000", "400000"];

#[test]
fn every_output_is_finite_and_non_negative_at_extremes() {
    let engine = Engine::new();
    let shape = DomeShape {
        elevation_count: 33,
        azimuth_count: 9,
    };
    // Exactly horizontal, just above and below, straight up and down.
    let probes = [
        (90.0, 0.0),
        (89.99, 0.0),
        (90.01, 180.0),
        (0.0, 0.0),
        (180.0, 0.0),
        (90.0, 90.0),
    ];
    for sun in SUN {
        for alt in ALTITUDES {
            let s = spec(&[("sun_elevation_deg", sun), ("observer_altitude_m", alt)]);
            let sky = engine.sky(&s, shape, &probes).unwrap();
            assert_valid(
                sky.table.radiance.iter().map(|&v| v as f64),
                &format!("sky sun {sun} alt {alt}"),
            );
            for p in &sky.probes {
                assert_valid(
                    p.radiance_w_m2_sr_nm.iter().copied(),
                    &format!("probe {p:?}"),
                );
            }
            let ground = engine.ground(&s, shape, &[]).unwrap();
            assert_valid(ground.table.radiance.iter().map(|&v| v as f64), "ground");
            let sun_p = engine.sun(&CommonSpec { ..s.clone() }).unwrap();
            assert_valid(sun_p.transmittance.iter().copied(), "transmittance");
            assert!(sun_p.transmittance.iter().all(|&t| t <= 1.0));
            assert_valid(
                sun_p.global_horizontal_irradiance_w_m2_nm.iter().copied(),
                "ghi",
            );
            assert_valid(
                sun_p.diffuse_horizontal_irradiance_w_m2_nm.iter().copied(),
                "dhi",
            );
        }
    }
}

#[test]
fn thick_aerosol_stays_finite_with_both_methods() {
    let atmosphere = include_str!("../../config/atmospheres/earth-hazy.json")
        .replace("\"value\": 1.0", "\"value\": 10.0");
    let engine = Engine::new();
    for method in ["fast", "precise"] {
        for sun in ["-18", "0", "45"] {
            let s = spec(&[
                ("atmosphere", &atmosphere),
                ("method", method),
                ("sun_elevation_deg", sun),
            ]);
            let sky = engine
                .sky(
                    &s,
                    DomeShape {
                        elevation_count: 17,
                        azimuth_count: 5,
                    },
                    &[(90.0, 0.0)],
                )
                .unwrap();
            assert_valid(sky.table.radiance.iter().map(|&v| v as f64), "aod 10");
        }
    }
}

/// Radiance towards the horizon near the sun, as the sun crosses the horizon: no jump.
#[test]
fn sunset_is_continuous() {
    let engine = Engine::new();
    let shape = DomeShape {
        elevation_count: 3,
        azimuth_count: 1,
    };
    let mut last: Option<Vec<f64>> = None;
    for k in -20..=20 {
        let elev = k as f64 * 0.02; // −0.4° … 0.4° in 0.02° steps
        let s = spec(&[
            ("sun_elevation_deg", &elev.to_string()),
            ("wavelengths", "550"),
        ]);
        let sky = engine.sky(&s, shape, &[(80.0, 0.0), (0.0, 0.0)]).unwrap();
        let now: Vec<f64> = sky
            .probes
            .iter()
            .map(|p| p.radiance_w_m2_sr_nm[0])
            .collect();
        if let Some(prev) = &last {
            for (a, b) in prev.iter().zip(&now) {
                // 0.02° of sun motion changes sky radiance by far less than 5 %.
                assert!(
                    (a - b).abs() <= 0.05 * a.max(*b) + 1e-9,
                    "jump at {elev}°: {a} -> {b}"
                );
            }
        }
        last = Some(now);
    }
}

/// Climbing through the top of the atmosphere into space: no pop.
#[test]
fn climbing_into_space_is_continuous() {
    let engine = Engine::new();
    let shape = DomeShape {
        elevation_count: 3,
        azimuth_count: 1,
    };
    let probes = [(120.0, 0.0), (100.0, 90.0), (170.0, 180.0)];
    let at = |alt: &str| -> Vec<f64> {
        let s = spec(&[
            ("observer_altitude_m", alt),
            ("sun_elevation_deg", "20"),
            ("wavelengths", "550"),
        ]);
        engine
            .sky(&s, shape, &probes)
            .unwrap()
            .probes
            .iter()
            .map(|p| p.radiance_w_m2_sr_nm[0])
            .collect()
    };
    let (below, top, above) = (at("99999"), at("100000"), at("100001"));
    for i in 0..probes.len() {
        for (a, b) in [(below[i], top[i]), (top[i], above[i])] {
            assert!(
                (a - b).abs() <= 1e-3 * a.max(b),
                "probe {:?}: {a} vs {b}",
                probes[i]
            );
        }
    }
}

/// No banding: along the elevation axis near the horizon (sky side) radiance varies smoothly.
#[test]
fn horizon_rows_are_smooth() {
    let engine = Engine::new();
    let s = spec(&[
        ("sun_elevation_deg", "5"),
        ("wavelengths", "550"),
        ("quality", "standard"),
    ]);
    let shape = DomeShape {
        elevation_count: 129,
        azimuth_count: 3,
    };
    let sky = engine.sky(&s, shape, &[]).unwrap();
    let t = &sky.table;
    for col in 0..3 {
        let column: Vec<(f64, f64)> = (0..t.elevation_deg.len())
            .filter(|&r| t.elevation_deg[r] > 0.0 && t.elevation_deg[r] < 20.0)
            .map(|r| (t.elevation_deg[r], t.radiance[r * 3 + col] as f64))
            .collect();
        assert!(column.len() > 10);
        // Above the horizon, sky radiance decreases monotonically with elevation near it
        // (the bright horizon band), without oscillation.
        let sign_changes = column
            .windows(3)
            .filter(|w| ((w[1].1 - w[0].1) * (w[2].1 - w[1].1)) < 0.0)
            .count();
        assert!(sign_changes <= 1, "column {col}: {column:?}");
    }
}

/// Twilight fades monotonically to nothing: no glow is left once the sun is 18° down.
#[test]
fn twilight_fades_without_leftover_glow() {
    let engine = Engine::new();
    let shape = DomeShape {
        elevation_count: 3,
        azimuth_count: 1,
    };
    let zenith = |sun: f64| -> f64 {
        let s = spec(&[
            ("sun_elevation_deg", &sun.to_string()),
            ("method", "precise"),
            ("wavelengths", "550"),
        ]);
        engine.sky(&s, shape, &[(0.0, 0.0)]).unwrap().probes[0].radiance_w_m2_sr_nm[0]
    };
    let day = zenith(30.0);
    let mut last = day;
    for sun in [0.0, -3.0, -6.0, -9.0, -12.0, -15.0, -18.0] {
        let l = zenith(sun);
        assert!(l > 0.0 && l < last, "sun {sun}: {l} after {last}");
        last = l;
    }
    assert!(last < 1e-5 * day, "{last} vs day {day}");
}
