//! Night and polar cases: every product accepts any sun elevation. Below the
//! darkest modelled twilight (`plan::darkest_twilight_deg`) the plan leaves every scattering stage
//! out with a reason, builds no multiple-scattering table and the products are zero; leaving the
//! stages out loses nothing (the full computation there is exactly zero too), and just above the
//! limit the twilight tail is still there.

use skybake_engine::engine::{Engine, Product, Table, Term};
use skybake_engine::plan::{darkest_twilight_deg, Plan, Reason, Stage};
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};

fn request(kind: ProductKind, pairs: &[(&str, String)]) -> ProductRequest {
    let base = [
        ("method", "precise"),
        ("quality", "draft"),
        ("wavelengths", "450,550,650"),
        ("atmosphere", "earth"),
    ];
    let mut p = RequestParams::from_pairs(base.iter().copied()).unwrap();
    for (k, v) in pairs {
        *p.slot(k).unwrap() = Some(v.clone());
    }
    if kind != ProductKind::Sun {
        p.elevation_count = Some("9".into());
        p.azimuth_count = Some("3".into());
    }
    ProductRequest::from_params(kind, &p).unwrap()
}

/// The plan with every stage of `product` in it (nothing left out).
fn full_plan(req: &ProductRequest) -> Plan {
    let mut plan = req.plan().unwrap();
    let left: Vec<Stage> = plan.left_out.drain(..).map(|(s, _)| s).collect();
    plan.stages.extend(left);
    plan
}

/// Largest radiance or irradiance value of a product (the limb, the dome, the probes, DHI).
fn brightest(p: &Product) -> f64 {
    let max = |v: &[f64]| v.iter().fold(0.0f64, |a, &b| a.max(b));
    match p {
        Product::Sun(s) => max(&s.global_horizontal_irradiance_w_m2_nm),
        Product::Sky(d) | Product::Ground(d) => {
            let probes = d
                .probes
                .iter()
                .map(|q| max(&q.radiance_w_m2_sr_nm))
                .fold(0.0, f64::max);
            let table = d
                .table
                .radiance
                .iter()
                .fold(0.0f64, |a, &b| a.max(b as f64));
            probes.max(table)
        }
        Product::Aerial(a) => a.inscatter.iter().fold(0.0f64, |x, &y| x.max(y as f64)),
    }
}

#[test]
fn midnight_is_answered_by_every_product_with_zero_and_the_plan_says_why() {
    for kind in [
        ProductKind::Sun,
        ProductKind::Sky,
        ProductKind::Ground,
        ProductKind::Aerial,
    ] {
        for method in ["precise", "fast", "none"] {
            let req = request(
                kind,
                &[
                    ("sun_elevation_deg", "-90".into()),
                    ("method", method.into()),
                ],
            );
            let plan = req.plan().unwrap();
            for stage in [Stage::SingleScattering, Stage::GroundBounce] {
                assert!(!plan.runs(stage), "{kind:?} {method}: {stage:?}");
                assert!(
                    plan.left_out
                        .iter()
                        .any(|(s, r)| *s == stage
                            && matches!(r, Reason::SunBelowDarkestTwilight { .. })),
                    "{kind:?} {method}: {:?}",
                    plan.left_out
                );
            }
            assert!(!plan.runs(Stage::MultipleScattering));
            assert!(plan.substitution.is_none(), "{kind:?} {method}");
            let engine = Engine::new();
            let product = engine.execute(&req.spec, &req.product, &plan).unwrap();
            assert_eq!(brightest(&product), 0.0, "{kind:?} {method}");
            assert_eq!(engine.table_builds(Table::Precise), 0);
            assert_eq!(engine.table_builds(Table::Fast), 0);
            assert_eq!(engine.term_count(Term::SingleScattering), 0);
            if let Product::Sun(s) = &product {
                assert_eq!(s.global_horizontal_illuminance_lux, 0.0);
                assert_eq!(s.global_correlated_colour_temperature_k, None);
                assert!(s.direct_normal_irradiance_w_m2_nm.iter().all(|&v| v == 0.0));
                assert!(s.error_estimate.caveat.unwrap_or("").starts_with("night"));
                // The JSON names the reason.
                let json = serde_json::to_string(&plan).unwrap();
                assert!(json.contains("sun_below_darkest_twilight"), "{json}");
            }
        }
    }
}

#[test]
fn darkest_twilight_follows_the_observer_altitude_and_the_method() {
    let earth = request(ProductKind::Sky, &[]);
    let m = skybake_physics::atmosphere::Medium::new(
        &earth.spec.atmosphere,
        &earth.spec.wavelengths_nm,
        None,
    )
    .unwrap();
    let ground = darkest_twilight_deg(&m, 0.0, MsMethod::Precise);
    let orbit = darkest_twilight_deg(&m, 400_000.0, MsMethod::Precise);
    let single = darkest_twilight_deg(&m, 0.0, MsMethod::None);
    eprintln!(
        "darkest twilight: ground {ground:.2}°, 400 km {orbit:.2}°, single only {single:.2}°"
    );
    // From the ground no air beyond about 20° below the horizon can be lit directly (twice the
    // top's horizon dip, 10.1° for a 100 km atmosphere on 6360 km); from orbit much more is seen.
    assert!((-21.0..-19.5).contains(&single), "{single}");
    assert!(ground < single && orbit < ground - 15.0, "{ground} {orbit}");
}

#[test]
fn leaving_the_stages_out_at_night_loses_nothing_and_the_twilight_tail_reaches_the_limit() {
    // Probes towards the sun near the horizon see the last lit air.
    let probes = "90:0,89:0,87:0,80:0,60:0,0:0,89:90,89:180".to_string();
    for altitude in [0.0, 400_000.0] {
        let base = request(ProductKind::Sky, &[]);
        let m = skybake_physics::atmosphere::Medium::new(
            &base.spec.atmosphere,
            &base.spec.wavelengths_nm,
            None,
        )
        .unwrap();
        let limit = darkest_twilight_deg(&m, altitude, MsMethod::Precise);
        let engine = Engine::new();
        for kind in [ProductKind::Sky, ProductKind::Sun] {
            let at = |sun: f64| {
                let mut pairs = vec![
                    ("sun_elevation_deg", sun.to_string()),
                    ("observer_altitude_m", altitude.to_string()),
                ];
                if kind == ProductKind::Sky {
                    pairs.push(("probe", probes.clone()));
                }
                request(kind, &pairs)
            };
            // Just below the limit the planner leaves everything out; forcing every stage back
            // in computes exactly the same zeros.
            let night = at(limit - 0.25);
            assert!(!night.plan().unwrap().runs(Stage::SingleScattering));
            let full = engine
                .execute(&night.spec, &night.product, &full_plan(&night))
                .unwrap();
            assert_eq!(brightest(&full), 0.0, "{kind:?} at {altitude} m");
            if kind == ProductKind::Sun && altitude > 100_000.0 {
                // Above the atmosphere the upper hemisphere holds no air: DHI is always zero.
                continue;
            }
            // A little above it the plan runs and the twilight tail is not yet zero.
            let dusk = at(limit + 3.0);
            let plan = dusk.plan().unwrap();
            assert!(plan.runs(Stage::MultipleScattering));
            let p = engine.execute(&dusk.spec, &dusk.product, &plan).unwrap();
            let b = brightest(&p);
            eprintln!("{kind:?} at {altitude} m, sun {:.2}°: {b:.3e}", limit + 3.0);
            assert!(b > 0.0 && b.is_finite(), "{kind:?} at {altitude} m: {b}");
        }
    }
}
