//! Haze as users describe it (`visibility_km`, `aerosol_type`, `boundary_layer_top_m`) through the
//! product path: fog of visibility 1 km converges, stays finite and non-negative (haze beyond the
//! largest optical depth allowed is refused by name), and an observer above the boundary layer
//! climbs out of it. Energy conservation of the layered profile down to visibility 1 km is
//! checked in atmosphere_validation.rs, its sky against DISORT in atmosphere_fog.rs.

use serde_json::Value;
use skybake_engine::engine::Engine;
use skybake_product::params::RequestParams;
use skybake_product::{render, Format, ProductKind, ProductRequest};

fn body(engine: &Engine, kind: ProductKind, pairs: &[(&str, &str)]) -> Value {
    let p = RequestParams::from_pairs(pairs.iter().copied()).unwrap();
    let req = ProductRequest::from_params(kind, &p).unwrap();
    let image = req.compute(engine).unwrap();
    serde_json::from_slice(&render(req.kind(), Format::Json, &image).unwrap()).unwrap()
}

fn floats(v: &Value) -> Vec<f64> {
    let mut out = Vec::new();
    match v {
        Value::Array(a) => a.iter().for_each(|x| out.extend(floats(x))),
        Value::Number(n) => out.push(n.as_f64().unwrap()),
        _ => {}
    }
    out
}

#[test]
fn fog_of_visibility_1_km_converges_and_stays_finite() {
    // Visibility 1 km in a 1.5 km boundary layer: optical depth 5.85 at 550 nm, fog-like haze
    // (the largest `visibility_km` may give is 6: haze::MAX_BOUNDARY_LAYER_OPTICAL_DEPTH_550).
    let engine = Engine::new();
    for kind in ["continental", "urban"] {
        let v = body(
            &engine,
            ProductKind::Sky,
            &[
                ("visibility_km", "1"),
                ("aerosol_type", kind),
                ("boundary_layer_top_m", "1500"),
                ("wavelengths", "440,550,680"),
                ("sun_elevation_deg", "30"),
                ("probe", "0:0,30:0,60:90,80:180,89:0"),
            ],
        );
        let e = &v["error_estimate"];
        let orders = e["scattering_orders"].as_u64().unwrap();
        let last = e["last_order_fraction"].as_f64().unwrap();
        eprintln!("visibility 1 km, {kind}: {orders} orders, last order {last:.2e}");
        // The series ends (last order or its extrapolated geometric tail under the tolerance)
        // before the cap of 60 orders.
        assert!(orders < 60, "{orders} {last}");
        // Optical depth 5.85 at 550 nm: outside the validated range, and the product says so.
        assert_eq!(e["validated"], Value::Bool(false), "{e}");
        let radiance: Vec<f64> = v["probes"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|p| floats(&p["radiance_w_m2_sr_nm"]))
            .collect();
        assert_eq!(radiance.len(), 15);
        assert!(radiance.iter().all(|x| x.is_finite() && *x >= 0.0));
        // The sky is lit: the zenith at 550 nm is not black under thick haze.
        assert!(v["probes"][0]["radiance_w_m2_sr_nm"][1].as_f64().unwrap() > 1e-3);
    }
    // Visibility 1 km in a 3 km layer (optical depth 11.7) is refused by name.
    let p = RequestParams::from_pairs([("visibility_km", "1"), ("boundary_layer_top_m", "3000")])
        .unwrap();
    let err = ProductRequest::from_params(ProductKind::Sky, &p).unwrap_err();
    assert_eq!(err.field(), "visibility_km", "{err}");
}

#[test]
fn an_observer_above_the_boundary_layer_climbs_out_of_the_haze() {
    // Visibility 2 km in a 1 km boundary layer: optical depth ≈ 1.95 in the layer, 0.025 above.
    let engine = Engine::new();
    let transmittance = |altitude: &str| {
        let v = body(
            &engine,
            ProductKind::Sun,
            &[
                ("visibility_km", "2"),
                ("boundary_layer_top_m", "1000"),
                ("wavelengths", "550"),
                ("sun_elevation_deg", "90"),
                ("observer_altitude_m", altitude),
                ("method", "none"),
            ],
        );
        floats(&v["transmittance"])[0]
    };
    let (ground, above) = (transmittance("0"), transmittance("1200"));
    eprintln!("sun transmittance at 550 nm: ground {ground:.4}, 1200 m {above:.4}");
    // Koschmieder: β = 3.912 / 2 km of total extinction at the ground, Rayleigh's 1.16e-5 m⁻¹
    // of it; the aerosol's (β − β_R) × 1 km is the layer's optical depth, plus 0.014 of Rayleigh
    // and free troposphere below 1200 m.
    let below = ground.ln().abs() - above.ln().abs();
    let want = 3.912 / 2.0 - 1.16e-2 + 0.014;
    assert!((below - want).abs() < 0.01, "{below} {want}");
    assert!(above > 0.85, "{above}");
}
