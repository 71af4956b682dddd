//! The typed plan is executed: every planner rule changes both the plan and the work the engine
//! does (table builds, ray-march terms counted by the engine), and a stage taken out of a plan
//! does not run.

use skybake_engine::engine::{Engine, Product, Table, Term};
use skybake_engine::plan::{Reason, Stage};
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};

fn request(kind: ProductKind, pairs: &[(&str, &str)]) -> ProductRequest {
    let base = [
        ("method", "precise"),
        ("quality", "draft"),
        ("wavelengths", "550"),
    ];
    let mut p = RequestParams::from_pairs(base.iter().copied()).unwrap();
    for (k, v) in pairs {
        *p.slot(k).unwrap() = Some(v.to_string());
    }
    if kind != ProductKind::Sun {
        p.elevation_count = Some("9".into());
        p.azimuth_count = Some("3".into());
    }
    ProductRequest::from_params(kind, &p).unwrap()
}

/// Runs the request's own plan on a fresh engine; returns the engine (for its counters) and the
/// product.
fn engine_run(req: &ProductRequest, plan: &skybake_engine::plan::Plan) -> Product {
    Engine::new()
        .execute(&req.spec, &req.product, plan)
        .unwrap()
}

fn run(req: &ProductRequest) -> (Engine, Product) {
    let engine = Engine::new();
    let plan = req.plan().unwrap();
    let product = engine.execute(&req.spec, &req.product, &plan).unwrap();
    (engine, product)
}

/// Table builds of `engine`, density, fast, precise.
fn builds(engine: &Engine) -> [u64; 3] {
    [Table::Density, Table::Fast, Table::Precise].map(|t| engine.table_builds(t))
}

/// Planning an atmosphere request builds no table. By construction: `ProductRequest::plan`
/// and `Engine::plan` take no engine (these coercions stop compiling if either starts to need
/// one). On the engine the request path executes with (`ProductRequest::compute(&engine)`
/// plans, then executes there) the tables built are exactly those of the plans executed, each
/// once: planning precise requests before and between executions adds none, and a `method=none`
/// request executed after a precise one was planned builds neither multiple-scattering table.
#[test]
fn planning_builds_no_table_on_the_engine_that_executes_the_request() {
    let _plan_takes_no_engine: fn(&ProductRequest) -> _ = ProductRequest::plan;
    let _engine_plan_takes_no_engine: fn(&skybake_engine::spec::CommonSpec, ProductKind) -> _ =
        Engine::plan;

    let precise = request(ProductKind::Sky, &[("method", "precise")]);
    let precise_sun = request(ProductKind::Sun, &[("method", "precise")]);
    let fast = request(ProductKind::Sky, &[("method", "fast")]);
    let none = request(ProductKind::Sky, &[("method", "none")]);
    let engine = Engine::new();
    let plan_all = || {
        for req in [&precise, &precise_sun, &fast, &none] {
            req.plan().unwrap();
        }
    };

    plan_all();
    assert_eq!(builds(&engine), [0, 0, 0], "planned only");
    assert!(precise.plan().unwrap().runs(Stage::MultipleScattering));
    none.compute(&engine).unwrap();
    assert_eq!(builds(&engine), [1, 0, 0], "method=none executed");

    precise.compute(&engine).unwrap();
    let after_precise = builds(&engine);
    assert_eq!(after_precise[1..], [0, 1], "precise executed");

    plan_all();
    precise.compute(&engine).unwrap();
    precise_sun.compute(&engine).unwrap();
    none.compute(&engine).unwrap();
    assert_eq!(builds(&engine), after_precise, "all warm");
    // The retired fast method runs the precise tables at draft: the same tables, warm.
    fast.compute(&engine).unwrap();
    assert_eq!(
        builds(&engine),
        after_precise,
        "fast executed on the precise draft tables"
    );
}

/// The frame's plan takes an engine (with an atmosphere it computes the light at the cloud,
/// by design): in vacuum it builds no table on it; with an atmosphere, at draft quality, only
/// the tables of the light it documents (the precise tables at draft, for draft and standard), each once,
/// and planning the frame again builds nothing more.
#[test]
fn planning_a_frame_builds_only_the_tables_of_its_light() {
    use serde_json::json;
    use skybake_product::frame::FrameRequest;
    use skybake_render::Method;
    let no_files = |name: &str| -> skybake_physics::Result<Vec<u8>> {
        Err(skybake_physics::Error::invalid(
            "path",
            format!("no file {name}"),
        ))
    };
    let frame = |json: &str| {
        let mut v: serde_json::Value = serde_json::from_str(json).unwrap();
        v["cloud"]["voxel_size_m"] = json!(100.0);
        v["camera"]["width"] = json!(16);
        v["camera"]["height"] = json!(12);
        v["quality"] = json!("draft");
        FrameRequest::from_value(&v, Method::Fast).unwrap()
    };

    let vacuum = frame(include_str!("../../config/scenes/validation-frame.json"));
    let engine = Engine::new();
    vacuum.plan(&engine, &no_files).unwrap();
    assert_eq!(builds(&engine), [0, 0, 0], "vacuum");

    let lit = frame(include_str!("../../config/scenes/cumulus-frame.json"));
    let engine = Engine::new();
    lit.plan(&engine, &no_files).unwrap();
    let first = builds(&engine);
    assert_eq!(
        first,
        [1, 0, 1],
        "atmosphere, draft: density and precise tables"
    );
    lit.plan(&engine, &no_files).unwrap();
    assert_eq!(builds(&engine), first, "planned again");
}

#[test]
fn method_none_leaves_out_multiple_scattering_and_its_table() {
    let none = request(ProductKind::Sky, &[("method", "none")]);
    let plan = none.plan().unwrap();
    assert!(!plan.runs(Stage::MultipleScattering));
    assert!(plan
        .left_out
        .contains(&(Stage::MultipleScattering, Reason::MethodNone)));
    let (engine, _) = run(&none);
    assert_eq!(engine.table_builds(Table::Fast), 0);
    assert_eq!(engine.table_builds(Table::Precise), 0);
    assert_eq!(engine.term_count(Term::MultipleScattering), 0);

    let precise = request(ProductKind::Sky, &[]);
    assert!(precise.plan().unwrap().runs(Stage::MultipleScattering));
    let (engine, _) = run(&precise);
    assert_eq!(engine.table_builds(Table::Fast), 0);
    assert_eq!(engine.table_builds(Table::Precise), 1);
    assert!(engine.term_count(Term::MultipleScattering) > 0);
}

#[test]
fn zero_albedo_leaves_out_the_ground_bounce() {
    let black = request(ProductKind::Sky, &[("ground_albedo", "0")]);
    let plan = black.plan().unwrap();
    assert!(plan
        .left_out
        .contains(&(Stage::GroundBounce, Reason::ZeroGroundAlbedo)));
    let (engine, _) = run(&black);
    assert_eq!(engine.term_count(Term::GroundBounce), 0);

    let grey = request(ProductKind::Sky, &[("ground_albedo", "0.3")]);
    assert!(grey.plan().unwrap().runs(Stage::GroundBounce));
    let (engine, _) = run(&grey);
    // The table's rows below the horizon (4 of 9, × 3 azimuths) end on the ground.
    assert!(engine.term_count(Term::GroundBounce) >= 12);
}

#[test]
fn direct_sun_follows_the_observers_horizon() {
    // At −10° the sun is below the horizon on the ground but not from 400 km, where the horizon
    // dips 20°: the plan and the transmittance use the same geometric test.
    for (altitude, visible) in [("0", false), ("400000", true)] {
        let req = request(
            ProductKind::Sun,
            &[
                ("sun_elevation_deg", "-10"),
                ("observer_altitude_m", altitude),
            ],
        );
        let plan = req.plan().unwrap();
        assert_eq!(plan.runs(Stage::DirectSun), visible, "{altitude} m");
        assert_eq!(
            plan.left_out
                .iter()
                .any(|(s, r)| *s == Stage::DirectSun
                    && matches!(r, Reason::SunBelowHorizon { .. })),
            !visible,
            "{altitude} m"
        );
        let (engine, product) = run(&req);
        assert_eq!(engine.term_count(Term::DirectSun), u64::from(visible));
        let Product::Sun(sun) = product else {
            panic!("not a sun product")
        };
        assert_eq!(sun.transmittance[0] > 0.0, visible, "{altitude} m");
        assert_eq!(sun.meta.plan, plan);
    }
}

#[test]
fn a_stage_taken_out_of_the_plan_does_not_run() {
    let req = request(ProductKind::Sky, &[("ground_albedo", "0.3")]);
    let full = req.plan().unwrap();
    let engine = Engine::new();
    let with = engine.execute(&req.spec, &req.product, &full).unwrap();
    let single = engine.term_count(Term::SingleScattering);
    assert!(single > 0);
    for stage in [
        Stage::SingleScattering,
        Stage::GroundBounce,
        Stage::MultipleScattering,
    ] {
        let engine = Engine::new();
        let plan = full.clone().without(stage);
        let without = engine.execute(&req.spec, &req.product, &plan).unwrap();
        let term = match stage {
            Stage::SingleScattering => Term::SingleScattering,
            Stage::GroundBounce => Term::GroundBounce,
            _ => Term::MultipleScattering,
        };
        assert_eq!(engine.term_count(term), 0, "{stage:?}");
        if stage == Stage::MultipleScattering {
            assert_eq!(engine.table_builds(Table::Precise), 0);
        }
        let (Product::Sky(a), Product::Sky(b)) = (&with, &without) else {
            panic!("not sky products")
        };
        let (sum_a, sum_b): (f64, f64) = (
            a.table.radiance.iter().map(|&v| v as f64).sum(),
            b.table.radiance.iter().map(|&v| v as f64).sum(),
        );
        assert!(sum_b < sum_a, "{stage:?}: {sum_b} !< {sum_a}");
        assert_eq!(b.meta.plan, plan);
    }
    // Without the density table nothing can run: refused, not computed.
    let engine = Engine::new();
    assert!(engine
        .execute(&req.spec, &req.product, &full.without(Stage::DensityTable))
        .is_err());
    assert_eq!(engine.table_builds(Table::Density), 0);
}

#[test]
fn precise_orders_under_the_error_budget_are_left_out() {
    // Clear air at 440 nm, standard: the preset's tolerance 1e-3 and the budget's (a quarter of
    // the smallest measured error of the products sharing the table, the sun's 0.28 % + the
    // reference's 0.5 %) both take 4 orders since ray cells are weighted by their mean
    // transmittance (before: 5 and 4). Measured the same for earth at 380–680 nm, sun 10–60°,
    // `earth-hazy` (9, 8, 7 orders at 440, 550, 680 nm), `draft` and `high`: the geometric tail's
    // error estimate falls past both tolerances in one order. The rule must never add orders,
    // and what it may leave out must stay within the allowances.
    let pairs = [
        ("method", "precise"),
        ("quality", "standard"),
        ("wavelengths", "440"),
        ("sun_elevation_deg", "30"),
    ];
    let req = request(ProductKind::Sky, &pairs);
    let plan = req.plan().unwrap();
    let Some(&(
        _,
        Reason::OrdersUnderBudget {
            tolerance,
            preset_tolerance,
            budget,
        },
    )) = plan
        .left_out
        .iter()
        .find(|(s, _)| *s == Stage::HigherOrders)
    else {
        panic!("{plan:?}")
    };
    assert!(tolerance > preset_tolerance && tolerance <= budget.allowance);
    assert_eq!(plan.precise_tolerance, Some(tolerance));
    let (_, with) = run(&req);
    let engine = Engine::new();
    let full = plan.clone().without_cost_rules();
    assert!(full.runs(Stage::HigherOrders) && full.precise_tolerance.is_none());
    let without = engine.execute(&req.spec, &req.product, &full).unwrap();
    let orders = |p: &Product| p.meta().error_estimate.scattering_orders.unwrap();
    let (Product::Sky(a), Product::Sky(b)) = (&with, &without) else {
        panic!("not sky products")
    };
    let worst = a
        .table
        .radiance
        .iter()
        .zip(&b.table.radiance)
        .map(|(x, y)| ((x - y).abs() / y.abs().max(1e-30)) as f64)
        .fold(0.0, f64::max);
    eprintln!(
        "orders {} vs {}, worst relative difference {worst:.2e}, tolerance {tolerance:.2e}",
        orders(&with),
        orders(&without)
    );
    assert!(orders(&with) <= orders(&without));
    // What the left-out orders change in the sky table stays within the sky's allowance (a
    // quarter of its measured error in this regime), …
    let (sky_measured, _) =
        skybake_engine::accuracy::measured_for(ProductKind::Sky, MsMethod::Precise, &req.spec)
            .unwrap();
    let sky_allowance = skybake_engine::plan::BUDGET_SHARE
        * (sky_measured.relative_error + skybake_engine::accuracy::REFERENCE_ERROR);
    assert!(worst <= sky_allowance, "{worst} > {sky_allowance}");
    // … and in the sun product (the smallest measured error, which sets the table's budget)
    // within the table's allowance.
    let sun = request(ProductKind::Sun, &pairs);
    let sun_with = engine_run(&sun, &sun.plan().unwrap());
    let sun_without = engine_run(&sun, &sun.plan().unwrap().without_cost_rules());
    let (Product::Sun(a), Product::Sun(b)) = (&sun_with, &sun_without) else {
        panic!("not sun products")
    };
    let sun_worst = a
        .diffuse_horizontal_irradiance_w_m2_nm
        .iter()
        .zip(&b.diffuse_horizontal_irradiance_w_m2_nm)
        .map(|(x, y)| (x - y).abs() / y.abs())
        .fold(0.0, f64::max);
    eprintln!("sun diffuse: {sun_worst:.2e}");
    assert!(sun_worst <= budget.allowance, "{sun_worst}");

    // The converged reference is never loosened.
    let reference = request(
        ProductKind::Sky,
        &[("method", "precise"), ("quality", "reference")],
    );
    let plan = reference.plan().unwrap();
    assert!(plan.runs(Stage::HigherOrders) && plan.precise_tolerance.is_none());
}

fn precise_spec_atmosphere() -> skybake_physics::atmosphere::params::AtmosphereParams {
    request(ProductKind::Sky, &[]).spec.atmosphere
}

/// The fast method is retired: a `method=fast` request (any quality) plans the precise tables at
/// the coarse preset with the substitution and its reason, states the precise method in its
/// error estimate, and computes exactly the precise-draft product (the same numbers, from the
/// same shared tables).
#[test]
fn a_fast_request_runs_the_precise_tables_at_the_coarse_preset() {
    use skybake_engine::plan::{fast_preset, Substitution};
    use skybake_engine::spec::Quality;
    // The `earth` atmosphere is clear air (aerosol optical depth 0.1): draft.
    assert_eq!(fast_preset(&precise_spec_atmosphere()), Quality::Draft);
    let precise = request(ProductKind::Sky, &[("ground_albedo", "0.3")]);
    let engine = Engine::new();
    let Product::Sky(reference) = engine
        .execute(&precise.spec, &precise.product, &precise.plan().unwrap())
        .unwrap()
    else {
        panic!("not a sky product")
    };
    for quality in ["draft", "standard", "high"] {
        let fast = request(
            ProductKind::Sky,
            &[
                ("method", "fast"),
                ("quality", quality),
                ("ground_albedo", "0.3"),
            ],
        );
        let plan = fast.plan().unwrap();
        assert_eq!(plan.method, MsMethod::Precise, "{quality}");
        assert_eq!(plan.quality, Quality::Draft, "{quality}");
        assert_eq!(
            plan.substitution,
            Some(Substitution::FastRetired {
                requested: MsMethod::Fast,
                quality: Quality::Draft
            })
        );
        let v = serde_json::to_value(&plan).unwrap();
        let detail = v["method_substitution"]["detail"].as_str().unwrap();
        assert!(
            detail.contains("retired") && detail.contains("DISORT") && detail.contains("draft"),
            "{detail}"
        );
        assert_eq!(v["method_substitution"]["reason"], "fast_retired");
        let Product::Sky(sky) = engine.execute(&fast.spec, &fast.product, &plan).unwrap() else {
            panic!("not a sky product")
        };
        assert_eq!(sky.table.radiance, reference.table.radiance, "{quality}");
        assert_eq!(sky.meta.error_estimate.method, MsMethod::Precise);
        assert!(
            sky.meta
                .error_estimate
                .basis
                .contains("fast method is retired"),
            "{}",
            sky.meta.error_estimate.basis
        );
        assert_eq!(
            sky.meta.error_estimate.relative_error,
            reference.meta.error_estimate.relative_error
        );
        // The same predicted cost as the precise-draft request.
        assert_eq!(
            skybake_product::cost::estimate(&fast).unwrap().units,
            skybake_product::cost::estimate(&precise).unwrap().units
        );
    }
    assert_eq!(engine.table_builds(Table::Fast), 0);
    assert_eq!(engine.table_builds(Table::Precise), 1);
}

/// A `max_rel_error` target on a `fast` request is met by the coarse preset or refused, naming
/// the parameter: the retired method never runs at an error above what the request asks.
#[test]
fn a_fast_request_with_a_target_is_met_at_the_coarse_preset_or_refused() {
    use skybake_engine::spec::Quality;
    let target = |t: &str| {
        let p = RequestParams::from_pairs([
            ("method", "fast"),
            ("wavelengths", "550"),
            ("max_rel_error", t),
        ])
        .unwrap();
        ProductRequest::from_params(ProductKind::Sun, &p)
    };
    let loose = target("0.5").unwrap();
    assert_eq!(loose.plan().unwrap().quality, Quality::Draft);
    let err = target("0.01").unwrap_err().to_string();
    assert!(
        err.contains("max_rel_error") && err.contains("retired") && err.contains("precise"),
        "{err}"
    );
}
