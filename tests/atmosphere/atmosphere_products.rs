//! The products' contracts: field names, consistency between products, aerial perspective
//! against Beer-Lambert, and spectral EXR round trips.

use skybake_engine::engine::{DomeShape, Engine};
use skybake_engine::spec::CommonSpec;
use skybake_product::params::RequestParams;

fn spec(method: &str, wavelengths: &str, atmosphere: &str, sun: &str, alt: &str) -> CommonSpec {
    let p = RequestParams {
        method: Some(method.into()),
        wavelengths: Some(wavelengths.into()),
        atmosphere: Some(atmosphere.into()),
        sun_elevation_deg: Some(sun.into()),
        observer_altitude_m: Some(alt.into()),
        ..Default::default()
    };
    skybake_product::params::common_spec(&p, -18.0).unwrap()
}

#[test]
fn sun_json_has_the_contract_fields_and_consistent_irradiances() {
    let engine = Engine::new();
    let s = spec("fast", "440,550,680", "earth", "35", "0");
    let sun = engine.sun(&s).unwrap();
    let json = serde_json::to_value(&sun).unwrap();
    for field in [
        "wavelengths_nm",
        "solar_irradiance_w_m2_nm",
        "transmittance",
        "direct_normal_irradiance_w_m2_nm",
        "diffuse_horizontal_irradiance_w_m2_nm",
        "global_horizontal_irradiance_w_m2_nm",
        "error_estimate",
        "timing_ms",
    ] {
        assert!(json.get(field).is_some(), "missing {field}");
    }
    let mu = 35f64.to_radians().sin();
    for i in 0..3 {
        let ghi = sun.direct_normal_irradiance_w_m2_nm[i] * mu
            + sun.diffuse_horizontal_irradiance_w_m2_nm[i];
        assert!((ghi - sun.global_horizontal_irradiance_w_m2_nm[i]).abs() < 1e-12);
        assert!(
            (sun.direct_normal_irradiance_w_m2_nm[i]
                - sun.transmittance[i] * sun.solar_irradiance_w_m2_nm[i])
                .abs()
                < 1e-12
        );
    }
    // Blue sky: more diffuse light at 440 nm than at 680 nm relative to the direct beam.
    let ratio = |i: usize| {
        sun.diffuse_horizontal_irradiance_w_m2_nm[i] / sun.direct_normal_irradiance_w_m2_nm[i]
    };
    assert!(ratio(0) > 2.0 * ratio(2));
    // Above the atmosphere the sun is unattenuated and there is no diffuse light from above.
    let space = engine
        .sun(&spec("fast", "440,550,680", "earth", "35", "400000"))
        .unwrap();
    assert!(space.transmittance.iter().all(|&t| t == 1.0));
    assert!(space
        .diffuse_horizontal_irradiance_w_m2_nm
        .iter()
        .all(|&d| d < 1e-6));
}

#[test]
fn aerial_perspective_follows_beer_lambert_and_ends_at_the_sky() {
    let engine = Engine::new();
    let s = spec("precise", "550", "rayleigh-only", "20", "0");
    let shape = DomeShape {
        elevation_count: 33,
        azimuth_count: 3,
    };
    let a = engine.aerial(&s, shape, 16, 20_000.0).unwrap();
    let row = a.elevation_deg.iter().position(|&e| e == 0.0).unwrap();
    let beta = 1.3558e-5;
    for (k, &d) in a.distance_m.iter().enumerate() {
        let idx = (row * 3) * a.distance_m.len() + k; // one wavelength
        let t = a.transmittance[idx] as f64;
        // Horizontal ray at the ground: the density is uniform to 0.1 % over 20 km.
        assert!((t - (-beta * d).exp()).abs() < 2e-3, "d {d}: {t}");
        if k > 0 {
            assert!(a.transmittance[idx] <= a.transmittance[idx - 1]);
            assert!(a.inscatter[idx] >= a.inscatter[idx - 1]);
        }
    }
    // At a distance beyond the atmosphere, in-scattered radiance is the sky's radiance.
    let far = engine
        .aerial(
            &s,
            DomeShape {
                elevation_count: 3,
                azimuth_count: 1,
            },
            2,
            5.0e6,
        )
        .unwrap();
    let sky = engine
        .sky(
            &s,
            DomeShape {
                elevation_count: 3,
                azimuth_count: 1,
            },
            &[(0.0, 0.0)],
        )
        .unwrap();
    // Row 2 (zenith), the only azimuth, the second (far) distance.
    let zenith_far = far.inscatter[2 * 2 + 1] as f64;
    let zenith_sky = sky.probes[0].radiance_w_m2_sr_nm[0];
    assert!(
        (zenith_far / zenith_sky - 1.0).abs() < 1e-3,
        "{zenith_far} vs {zenith_sky}"
    );
}

#[test]
fn ground_product_looks_down_and_joins_the_sky_table() {
    // Looks down: the table spans view elevation −90° up to the observer's geometric horizon,
    // −acos(R / (R + h)), and no further; a probe looking up is refused.
    let engine = Engine::new();
    let s = spec("fast", "450,550,650", "earth", "30", "3000");
    let shape = DomeShape {
        elevation_count: 33,
        azimuth_count: 5,
    };
    let g = engine.ground(&s, shape, &[]).unwrap();
    let dip = (6_360_000.0f64 / 6_363_000.0).acos().to_degrees();
    assert_eq!(g.table.elevation_deg[0], -90.0);
    let top = *g.table.elevation_deg.last().unwrap();
    assert!(
        (top + dip).abs() < 1e-9 || top <= 0.0,
        "top row {top}°, dip {dip}°"
    );
    assert!(g.table.elevation_deg.iter().all(|&e| e <= 0.0));
    assert!(engine.ground(&s, shape, &[(45.0, 0.0)]).is_err());

    // Joins the sky: across the observer's horizon the radiance is continuous, the ground table's
    // rows approaching the sky table's first rows above the horizon (both ends look through
    // ~200 km of air at the horizon, so the airlight dominates either side).
    let sky = engine
        .sky(
            &s,
            DomeShape {
                elevation_count: 257,
                azimuth_count: 5,
            },
            &[],
        )
        .unwrap();
    let n_l = 3;
    let row_of = |t: &skybake_physics::atmosphere::sky::DomeTable, e: f64| {
        t.elevation_deg
            .iter()
            .position(|&x| (x - e).abs() < 1e-9)
            .unwrap()
    };
    let h_sky = row_of(&sky.table, -dip);
    let above = sky.table.elevation_deg[h_sky + 1];
    assert!(
        above - -dip < 0.05,
        "first row above the horizon at {above}°"
    );
    let h_ground = row_of(&g.table, -dip);
    for col in 0..5 {
        for i in 0..n_l {
            let below = g.table.radiance[(h_ground * 5 + col) * n_l + i] as f64;
            let over = sky.table.radiance[((h_sky + 1) * 5 + col) * n_l + i] as f64;
            assert!(
                (below / over - 1.0).abs() < 0.05,
                "azimuth column {col}, λ {i}: {below} below vs {over} above the horizon"
            );
        }
    }
}

#[test]
fn ground_nadir_radiance_at_the_surface_is_albedo_over_pi_times_global_irradiance() {
    // An observer on a Lambertian ground looking straight down sees L = (a/π)·E_global, with
    // E_global the global horizontal irradiance of the `sun` product (direct + the sky radiance
    // integrated over the hemisphere) — two independent code paths: the ground product takes the
    // sky's irradiance on the ground from the multiple-scattering tables.
    let engine = Engine::new();
    for sun in ["60", "20"] {
        let mut s = spec("precise", "450,550,650", "earth", sun, "0");
        s.ground_albedo = Some(0.3);
        let ghi = engine.sun(&s).unwrap().global_horizontal_irradiance_w_m2_nm;
        let g = engine
            .ground(
                &s,
                DomeShape {
                    elevation_count: 3,
                    azimuth_count: 1,
                },
                &[(180.0, 0.0)],
            )
            .unwrap();
        for (i, &e) in ghi.iter().enumerate() {
            let expected = 0.3 / std::f64::consts::PI * e;
            let got = g.probes[0].radiance_w_m2_sr_nm[i];
            eprintln!("sun {sun}°, λ {i}: nadir {got:.5} vs (a/π)·GHI {expected:.5}");
            assert!(
                (got / expected - 1.0).abs() < 0.002,
                "sun {sun}°, λ {i}: {got} vs {expected}"
            );
        }
    }
}

#[test]
fn sky_exr_round_trips_through_the_store() {
    use skybake_product::{ProductKind, ProductRequest};
    let p = RequestParams {
        method: Some("fast".into()),
        wavelengths: Some("400,500,600,700".into()),
        sun_elevation_deg: Some("10".into()),
        elevation_count: Some("9".into()),
        azimuth_count: Some("7".into()),
        ..Default::default()
    };
    let req = ProductRequest::from_params(ProductKind::Sky, &p).unwrap();
    let image = req.compute(&Engine::new()).unwrap();
    let bytes = skybake_store::encode_exr(&image).unwrap();
    let img = skybake_store::decode_exr(&bytes).unwrap();
    assert_eq!((img.width(), img.height()), (7, 9));
    assert_eq!(img.wavelengths_nm(), &[400.0, 500.0, 600.0, 700.0]);
    // The same table computed directly by the engine.
    let table = Engine::new()
        .sky(
            &req.spec,
            DomeShape {
                elevation_count: 9,
                azimuth_count: 7,
            },
            &[],
        )
        .unwrap()
        .table;
    let layer = img.layer("S0").unwrap();
    // Top image row = highest elevation = last table row.
    for col in 0..7 {
        for i in 0..4 {
            assert_eq!(
                layer.plane(i).unwrap()[col],
                table.radiance[(8 * 7 + col) * 4 + i]
            );
        }
    }
    assert!(img
        .attribute("skybakeSpec")
        .unwrap()
        .contains("\"product\":\"sky\""));
    assert!(img.rgb().is_some());
}
