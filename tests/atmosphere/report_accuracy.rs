//! Quality by target and error estimates from the measured report, through
//! the product path a request takes (`ProductRequest::from_params` → `Engine::compute`).

use skybake_engine::accuracy::{self, RegimeBands, REFERENCE_ERROR};
use skybake_engine::engine::{Engine, ErrorEstimate};
use skybake_physics::atmosphere::presets::preset;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};

fn params(sun: f64, altitude: f64) -> RequestParams {
    RequestParams {
        wavelengths: Some("550".into()),
        sun_elevation_deg: Some(sun.to_string()),
        observer_altitude_m: Some(altitude.to_string()),
        elevation_count: Some("9".into()),
        azimuth_count: Some("4".into()),
        ..Default::default()
    }
}

fn estimate(engine: &Engine, p: &RequestParams) -> (ErrorEstimate, Quality) {
    let req = ProductRequest::from_params(ProductKind::Sky, p).unwrap();
    let product = engine.compute(&req.spec, &req.product).unwrap();
    (product.meta().error_estimate.clone(), req.spec.quality)
}

#[test]
fn the_error_estimate_is_the_measured_figure_of_the_regime() {
    let engine = Engine::new();
    let mut p = params(45.0, 0.0);
    p.quality = Some("draft".into());
    let (e, _) = estimate(&engine, &p);
    let report = accuracy::committed().unwrap();
    let bands = RegimeBands::of(&preset("earth").unwrap(), 45.0, 0.0);
    let m = accuracy::measured(
        report,
        ProductKind::Sky,
        MsMethod::Precise,
        Quality::Draft,
        &bands,
    )
    .unwrap();
    assert_eq!(e.regime.as_deref(), Some("clear/high/ground"));
    assert!((e.relative_error - (m.relative_error + REFERENCE_ERROR)).abs() < 1e-12);
    assert!(e.validated);
    assert!(e.basis.contains("skybake report"), "{}", e.basis);

    // Above the measured altitude bands: no figure, not validated.
    let mut p = params(45.0, 400_000.0);
    p.quality = Some("draft".into());
    let (e, _) = estimate(&engine, &p);
    assert_eq!(e.regime, None);
    assert!(!e.validated);
}

#[test]
fn max_rel_error_picks_a_quality_that_meets_it() {
    let engine = Engine::new();
    let mut p = params(45.0, 0.0);
    p.max_rel_error = Some("0.2".into());
    let (e, quality) = estimate(&engine, &p);
    assert!(e.relative_error <= 0.2, "{e:?}");
    // The cheapest such preset: every cheaper one misses the target.
    let report = accuracy::committed().unwrap();
    let bands = RegimeBands::of(&preset("earth").unwrap(), 45.0, 0.0);
    let cost = |q| {
        accuracy::measured(report, ProductKind::Sky, MsMethod::Precise, q, &bands)
            .unwrap()
            .cold_cpu_ms
    };
    for q in accuracy::PRESETS {
        let m = accuracy::measured(report, ProductKind::Sky, MsMethod::Precise, q, &bands).unwrap();
        if cost(q) < cost(quality) {
            assert!(
                m.relative_error + REFERENCE_ERROR > 0.2,
                "{q:?} is cheaper and meets it"
            );
        }
    }

    let mut both = params(45.0, 0.0);
    both.max_rel_error = Some("0.2".into());
    both.quality = Some("high".into());
    let err = ProductRequest::from_params(ProductKind::Sky, &both)
        .unwrap_err()
        .to_string();
    assert!(err.contains("max_rel_error"), "{err}");

    let mut tight = params(45.0, 0.0);
    tight.max_rel_error = Some("0.0001".into());
    let err = ProductRequest::from_params(ProductKind::Sky, &tight)
        .unwrap_err()
        .to_string();
    assert!(err.contains("best measured error"), "{err}");
}
