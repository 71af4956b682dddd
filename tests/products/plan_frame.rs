//! The frame planner's rules: each rule changes the typed plan AND the work
//! the renderer does (voxels lit, lattice paths, the multiple-scattering field, grid size), and
//! what a cost rule leaves out changes the image by less than its predicted share.

use serde_json::{json, Value};
use skybake_engine::plan::{
    Coarsening, FramePlan, FrameReason, FrameStage, COARSENING_ERROR, FRAME_MEASURED_ERROR,
    MEASURED_LIGHT_SHARE_SAFETY, MS_GRID_ERROR, SPHERE_LEVEL_ERROR,
};
use skybake_physics::cloud::DensityGrid;
use skybake_product::artifact::frame_summary;
use skybake_product::frame::FrameRequest;
use skybake_product::frame::{execute_plan, measured_shares, plan_frame, sphere_facts, NoTiles};
use skybake_render::{lighting_for, render_tile, FrameScene, Method, Prepared, RenderSettings};
use skybake_service::AppState;

use crate::service_support;
use service_support::{call, settings, skybake_ok, Scratch};

/// The validation cloud (vacuum, collimated sun 1, constant sky 0.1) at 50 m voxels, 32×24 px.
fn scene(edit: impl FnOnce(&mut Value)) -> Value {
    let mut v: Value =
        serde_json::from_str(include_str!("../../config/scenes/validation-frame.json")).unwrap();
    v["cloud"]["voxel_size_m"] = json!(50.0);
    v["camera"]["width"] = json!(32);
    v["camera"]["height"] = json!(24);
    v["quality"] = json!("draft");
    edit(&mut v);
    v
}

fn parse(v: &Value) -> FrameScene {
    FrameScene::parse(&serde_json::to_vec(v).unwrap()).unwrap()
}

fn voxelize(s: &FrameScene) -> DensityGrid {
    s.cloud
        .voxelize(&|_| Err(skybake_physics::Error::invalid("path", "no files")))
        .unwrap()
}

/// What one run did: the image, voxels lit, lattice paths, whether the multiple-scattering field
/// was built, the grid's voxel count.
struct Run {
    radiance: Vec<f32>,
    voxels_lit: usize,
    lattice_paths: usize,
    ms_field: bool,
    /// The multiple-scattering field's cells per axis.
    ms_dims: Option<[usize; 3]>,
    grid_voxels: usize,
}

fn run(scene: &FrameScene, grid: &DensityGrid, plan: &FramePlan) -> Run {
    run_edited(scene, grid, plan, |_| {})
}

/// [`run`] with the executed plan's render settings changed by `edit`.
fn run_edited(
    scene: &FrameScene,
    grid: &DensityGrid,
    plan: &FramePlan,
    edit: impl FnOnce(&mut RenderSettings),
) -> Run {
    let planned = execute_plan(plan, scene, grid, Method::Fast).unwrap();
    let grid = planned.grid.as_ref().unwrap_or(grid);
    let lighting = lighting_for(&planned.scene, grid, service_support::shared_engine()).unwrap();
    let mut settings = planned.settings;
    edit(&mut settings);
    let p = Prepared::new(&planned.scene, grid, &lighting, settings, &|| false).unwrap();
    let frame = render_tile(&p, None, &|_| {}, &|| false).unwrap();
    Run {
        radiance: frame.radiance,
        voxels_lit: p.vox.len() / p.stride,
        lattice_paths: p.lattice_paths,
        ms_field: p.lit.ms.is_some(),
        ms_dims: p.lit.ms.as_ref().map(|m| m.dims),
        grid_voxels: grid.data.len(),
    }
}

/// Relative difference of the mean radiance of `reference` from that of `a`: the bias a left-out
/// light's share predicts (positive where `a` lacks light). The mean keeps the field's photon
/// noise: the two runs must trace the same photons for it to measure the light alone.
fn mean_difference(a: &[f32], reference: &[f32]) -> f64 {
    let sum = |x: &[f32]| x.iter().map(|&v| v as f64).sum::<f64>();
    (sum(reference) - sum(a)) / sum(reference)
}

/// Mean absolute difference over the image relative to the mean radiance of `reference`.
fn relative_difference(a: &[f32], reference: &[f32]) -> f64 {
    let mean = reference.iter().map(|&v| v as f64).sum::<f64>() / reference.len() as f64;
    let diff = a
        .iter()
        .zip(reference)
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .sum::<f64>()
        / a.len() as f64;
    diff / mean
}

fn reason(plan: &FramePlan, stage: FrameStage) -> Option<FrameReason> {
    plan.left_out
        .iter()
        .find(|(s, _)| *s == stage)
        .map(|(_, r)| *r)
}

#[test]
fn a_cloud_outside_the_view_gets_no_per_voxel_light_and_the_image_is_unchanged() {
    // Looking away from the cloud (towards −y), still over the ground-less vacuum.
    let s = parse(&scene(|v| {
        v["camera"]["look_at_m"] = json!([0, -9000, 1200])
    }));
    let grid = voxelize(&s);
    let plan = plan_frame(&s, &grid, Method::Fast);
    assert_eq!(
        reason(&plan, FrameStage::CloudLight),
        Some(FrameReason::CloudOutOfView)
    );
    assert!(!plan.runs(FrameStage::MultipleScattering));
    let with = run(&s, &grid, &plan);
    let without = run(&s, &grid, &plan.clone().without_cost_rules());
    assert_eq!(with.voxels_lit, 0);
    assert!(!with.ms_field && with.lattice_paths == 0);
    assert_eq!(without.voxels_lit, grid.data.len());
    assert!(without.ms_field && without.lattice_paths == 14);
    // No pixel's ray reaches the cloud: the rule is exact.
    assert_eq!(with.radiance, without.radiance);

    // Facing it, the cloud is in view.
    let facing = parse(&scene(|_| {}));
    let plan = plan_frame(&facing, &voxelize(&facing), Method::Fast);
    assert!(plan.runs(FrameStage::CloudLight));
}

#[test]
fn an_empty_grid_runs_no_cloud_stage() {
    let s = parse(&scene(|_| {}));
    let full = voxelize(&s);
    let grid = DensityGrid::zeros(full.dims, full.voxel_size_m, full.origin_m).unwrap();
    let plan = plan_frame(&s, &grid, Method::Fast);
    for stage in [
        FrameStage::CloudLight,
        FrameStage::SkyLight,
        FrameStage::GroundLight,
        FrameStage::MultipleScattering,
    ] {
        assert_eq!(
            reason(&plan, stage),
            Some(FrameReason::NoCloud),
            "{stage:?}"
        );
    }
    let r = run(&s, &grid, &plan);
    assert_eq!((r.voxels_lit, r.lattice_paths, r.ms_field), (0, 0, false));
    // The reference method plans its path tracer and no budget rule.
    let reference = plan_frame(&s, &grid, Method::Reference);
    assert!(reference.runs(FrameStage::PathTracer));
    assert_eq!(reference.budget.allowance, 0.0);
}

#[test]
fn an_optically_thin_cloud_runs_no_multiple_scattering() {
    // Extinction 5e-6 per unit density: optical path through the cloud ≤ 0.013.
    let thin = parse(&scene(|v| {
        v["optics"]["extinction_per_density_m"] = json!(5e-6);
    }));
    let grid = voxelize(&thin);
    let plan = plan_frame(&thin, &grid, Method::Fast);
    let Some(FrameReason::ThinCloud {
        predicted_share, ..
    }) = reason(&plan, FrameStage::MultipleScattering)
    else {
        panic!("{plan:?}")
    };
    assert!(predicted_share <= plan.budget.allowance);
    let with = run(&thin, &grid, &plan);
    let without = run(&thin, &grid, &plan.clone().without_cost_rules());
    assert!(!with.ms_field && without.ms_field);
    // The image changes by less than the predicted share of orders ≥ 2 (plus photon noise of the
    // field that is no longer there).
    let d = relative_difference(&with.radiance, &without.radiance);
    assert!(d <= predicted_share + 0.005, "{d} vs {predicted_share}");

    // The validation cloud (optical path up to ≈ 100) keeps it.
    let thick = parse(&scene(|_| {}));
    let plan = plan_frame(&thick, &voxelize(&thick), Method::Fast);
    assert!(plan.runs(FrameStage::MultipleScattering));
}

#[test]
fn dim_ground_and_no_sky_leave_the_lattice_paths_out() {
    // No sky; a dark ground (albedo 0.005) under the sun: ground light ≈ 0.55 % of the light at
    // the cloud, twice that under the budget (a quarter of the frame's measured 8.1 %).
    let s = parse(&scene(|v| {
        v["sky"] = Value::Null;
        v["ground"] = json!({"albedo": 0.005, "height_m": 0});
    }));
    let grid = voxelize(&s);
    let plan = plan_frame(&s, &grid, Method::Fast);
    assert_eq!(
        reason(&plan, FrameStage::SkyLight),
        Some(FrameReason::NoLight)
    );
    let Some(FrameReason::UnderBudget {
        predicted_share, ..
    }) = reason(&plan, FrameStage::GroundLight)
    else {
        panic!("{plan:?}")
    };
    assert!(predicted_share > 0.005 && predicted_share <= plan.budget.allowance);
    // The image's mean moves by less than the predicted (doubled) share. Left out, the ground's
    // photons go to the sun (the field's budget rule): the run with its light traces as many sun
    // photons, the same streams, so the two differ by the ground's light alone. Against the
    // frame with the default budgets, the sun field's photon noise moved the mean by ±0.9 %
    // (standard deviation over 16 photon seeds at draft; up to 2.6 %), the ground's light
    // 0.76–0.81 %.
    let with = run(&s, &grid, &plan);
    let without = run_edited(&s, &grid, &plan.clone().without_cost_rules(), |r| {
        r.photons.sun_photons += r.photons.env_photons
    });
    assert_eq!((with.lattice_paths, without.lattice_paths), (0, 14));
    let bias = mean_difference(&with.radiance, &without.radiance);
    let d = relative_difference(&with.radiance, &without.radiance);
    eprintln!("ground light left out: mean {bias:.4}, mean |difference| {d:.4}, predicted {predicted_share:.4}");
    assert!(
        bias > 0.0 && bias <= predicted_share,
        "{bias} vs {predicted_share}"
    );
    // A ground of albedo 0.02 (predicted 2 × 2.2 %) keeps its light, as does a bright one.
    let grey = parse(&scene(|v| {
        v["sky"] = Value::Null;
        v["ground"] = json!({"albedo": 0.02, "height_m": 0});
    }));
    assert!(plan_frame(&grey, &voxelize(&grey), Method::Fast).runs(FrameStage::GroundLight));
    let bright = parse(&scene(|v| {
        v["sky"] = Value::Null;
        v["ground"] = json!({"albedo": 0.5, "height_m": 0});
    }));
    let plan = plan_frame(&bright, &voxelize(&bright), Method::Fast);
    assert!(plan.runs(FrameStage::GroundLight));
    // Switched off by the scene: named as such.
    let off = parse(&scene(|v| v["lighting"]["sky_light"] = json!(false)));
    let plan = plan_frame(&off, &voxelize(&off), Method::Fast);
    assert_eq!(
        reason(&plan, FrameStage::SkyLight),
        Some(FrameReason::SwitchedOff {
            switch: "sky_light"
        })
    );
}

#[test]
fn a_distant_cloud_runs_on_coarser_voxels() {
    // 30 km away at 32 px over 50°: a pixel covers ≈ 650 m of the cloud, 13 voxels of 50 m.
    let far = parse(&scene(|v| {
        v["camera"]["position_m"] = json!([0, -30000, 1200]);
        v["camera"]["fov_deg"] = json!(8);
    }));
    let grid = voxelize(&far);
    let plan = plan_frame(&far, &grid, Method::Fast);
    // fov 8°: pitch 0.0044 rad, at ≈ 29 km ≈ 127 m: a factor 2 would fit the footprint, but its
    // measured error (COARSENING_ERROR, 9.1 %) is over the fast method's allowance: not coarsened.
    assert_eq!(plan.coarsening(), 1, "{plan:?}");
    assert!(COARSENING_ERROR > plan.budget.allowance, "{plan:?}");
    // Where a budget allows it, the coarsened plan runs on block means of 2³ voxels.
    let mut plan = plan;
    plan.coarsened.push(Coarsening {
        stage: FrameStage::CloudDetail,
        rule: "pixel_footprint",
        from_voxel_m: grid.voxel_size_m,
        to_voxel_m: 2.0 * grid.voxel_size_m,
        factor: 2,
        pixel_footprint_m: 127.0,
        nearest_distance_m: 29_000.0,
    });
    let with = run(&far, &grid, &plan);
    let without = run(&far, &grid, &plan.clone().without_cost_rules());
    assert!(
        with.grid_voxels * 6 < without.grid_voxels,
        "{} vs {}",
        with.grid_voxels,
        without.grid_voxels
    );
    assert_eq!(with.voxels_lit, with.grid_voxels);
    let d = relative_difference(&with.radiance, &without.radiance);
    assert!(d < 0.05, "{d}");
    // The validation camera (4 km, 160 px) resolves the 25 m voxels: nothing coarsened.
    let near: Value =
        serde_json::from_str(include_str!("../../config/scenes/validation-frame.json")).unwrap();
    let near = parse(&near);
    assert_eq!(
        plan_frame(&near, &voxelize(&near), Method::Fast).coarsening(),
        1
    );
}

#[test]
fn a_distant_cloud_runs_its_multiple_scattering_field_on_coarser_cells_under_a_target() {
    // 30 km away at 16 px over 8°: a pixel covers ≈ 253 m of the cloud. At 50 m voxels the
    // draft field (at most 24 cells per axis) has cells of 2 voxels, 100 m; at 12 cells per
    // axis 4 voxels, 200 m, within the footprint; at 6, 350 m, not.
    let v = scene(|v| {
        v["camera"]["position_m"] = json!([0, -30000, 1200]);
        v["camera"]["fov_deg"] = json!(8);
        v["camera"]["width"] = json!(16);
        v["camera"]["height"] = json!(12);
    });
    let engine = service_support::shared_engine();
    let req = FrameRequest::from_value(&v, Method::Fast).unwrap();
    // The fast method's own allowance (2 %) does not cover one halving (4 %): kept.
    let plan = req.plan(engine, &no_files).unwrap();
    assert_eq!(plan.ms_grid_coarsening(), 1, "{plan:?}");
    // A target of 0.17 leaves 8.9 %: one halving of the field (4 %), not one of the voxels
    // (9.1 %).
    let plan = req
        .clone()
        .with_max_rel_error(Some("0.17"))
        .unwrap()
        .plan(engine, &no_files)
        .unwrap();
    assert_eq!(plan.coarsening(), 1, "{plan:?}");
    assert_eq!(plan.ms_grid_coarsening(), 2, "{plan:?}");
    let c = plan
        .coarsened
        .iter()
        .find(|c| c.stage == FrameStage::MultipleScattering)
        .unwrap();
    assert_eq!((c.from_voxel_m, c.to_voxel_m), (100.0, 200.0), "{c:?}");
    assert!(c.to_voxel_m <= c.pixel_footprint_m);
    assert!((plan.budget.spent - MS_GRID_ERROR).abs() < 1e-12);
    let json = serde_json::to_value(&plan).unwrap();
    assert_eq!(json["coarsened"][0]["stage"], "multiple_scattering");
    // Executed: the field has at most 12 cells per axis (a quarter of the cells or fewer), and
    // the frame changes by less than predicted.
    let s = parse(&v);
    let grid = voxelize(&s);
    let with = run(&s, &grid, &plan);
    let without = run(&s, &grid, &plan.clone().without_cost_rules());
    let (a, b) = (with.ms_dims.unwrap(), without.ms_dims.unwrap());
    let cells = |d: [usize; 3]| d[0] * d[1] * d[2];
    assert!(
        a.iter().all(|&n| n <= 12) && 3 * cells(a) <= cells(b),
        "{a:?} vs {b:?}"
    );
    let d = relative_difference(&with.radiance, &without.radiance);
    eprintln!("field {b:?} -> {a:?} cells: mean absolute change {d:.4}");
    assert!(d < MS_GRID_ERROR, "{d}");
}

#[test]
fn the_frame_summary_names_each_left_out_stage_and_its_rule() {
    let v = scene(|v| v["camera"]["look_at_m"] = json!([0, -9000, 1200]));
    let req = FrameRequest::from_value(&v, Method::Fast).unwrap();
    let image = req
        .compute_tiled(
            service_support::shared_engine(),
            &|_| Err(skybake_physics::Error::invalid("path", "none")),
            &NoTiles,
            &|_| {},
            &|| false,
        )
        .unwrap();
    let summary = frame_summary(&image);
    let left: Vec<(&str, &str)> = summary["plan"]["left_out"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| (l["stage"].as_str().unwrap(), l["reason"].as_str().unwrap()))
        .collect();
    assert!(
        left.contains(&("cloud_light", "cloud_out_of_view")),
        "{left:?}"
    );
    assert!(
        left.contains(&("multiple_scattering", "cloud_out_of_view")),
        "{left:?}"
    );
    assert!(summary["plan"]["budget"]["allowance"].as_f64().unwrap() > 0.0);
}

fn no_files(_: &str) -> skybake_physics::Result<Vec<u8>> {
    Err(skybake_physics::Error::invalid("path", "no files"))
}

#[test]
fn max_rel_error_sets_the_frame_budget_and_a_target_under_the_measured_error_is_refused() {
    let far = scene(|v| {
        v["camera"]["position_m"] = json!([0, -30000, 1200]);
        v["camera"]["fov_deg"] = json!(8);
    });
    let req = FrameRequest::from_value(&far, Method::Fast).unwrap();
    // Below the fast method's measured error: refused, naming the best achievable error.
    let err = req
        .clone()
        .with_max_rel_error(Some("0.05"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("max_rel_error") && err.contains("0.0810"),
        "{err}"
    );
    for bad in ["abc", "0", "2"] {
        let err = req.clone().with_max_rel_error(Some(bad)).unwrap_err();
        assert!(err.to_string().contains("max_rel_error"), "{bad}: {err}");
    }
    let err = FrameRequest::from_value(&far, Method::Reference)
        .unwrap()
        .with_max_rel_error(Some("0.3"))
        .unwrap_err();
    assert!(err.to_string().contains("max_rel_error"), "{err}");
    // A target is part of the request (its cache key); no target leaves the key as it was.
    let targeted = req.clone().with_max_rel_error(Some("0.3")).unwrap();
    assert_ne!(targeted.cache_key(), req.cache_key());
    assert_eq!(
        req.clone().with_max_rel_error(None).unwrap().cache_key(),
        req.cache_key()
    );
    // The budget is the target; the cost rules may spend what it leaves over the method's
    // measured error, which here covers one halving of the distant cloud's voxels.
    let engine = service_support::shared_engine();
    let plan = targeted.plan(engine, &no_files).unwrap();
    assert!((plan.budget.relative_error - 0.3).abs() < 1e-12, "{plan:?}");
    assert!(
        (plan.budget.allowance - (0.3 - FRAME_MEASURED_ERROR)).abs() < 1e-12,
        "{plan:?}"
    );
    assert_eq!(plan.coarsening(), 2, "{plan:?}");
    assert!(plan.budget.spent >= COARSENING_ERROR);
    assert_eq!(req.plan(engine, &no_files).unwrap().coarsening(), 1);
}

/// The validation cloud under the earth's atmosphere and sky, sun 35°, a dark ground (albedo
/// 0.02, the open sea), three wavelengths.
fn atmosphere_scene() -> Value {
    scene(|v| {
        v["atmosphere"] = json!("earth");
        v["sky"] = json!("atmosphere");
        v["sun"] = json!({"elevation_deg": 35, "azimuth_deg": 140});
        v["ground"] = json!({"albedo": 0.02, "height_m": 0});
        v["wavelengths_nm"] = json!([440, 550, 680]);
    })
}

#[test]
fn with_an_atmosphere_the_light_shares_are_measured_and_ground_light_left_out_under_a_loose_target()
{
    let v = atmosphere_scene();
    let engine = service_support::shared_engine();
    let req = FrameRequest::from_value(&v, Method::Fast).unwrap();
    // The shares measured on the scene's light: the sky's about a quarter, the light from below
    // (the dark sea and the air under the cloud) about an eighth.
    let s = parse(&v);
    let grid = voxelize(&s);
    let lighting = lighting_for(&s, &grid, engine).unwrap();
    let (sky, ground) = measured_shares(&lighting);
    eprintln!("measured shares: sky {sky:.4}, ground {ground:.4}");
    assert!((0.15..0.4).contains(&sky) && (0.05..0.2).contains(&ground));
    // At the default budget (a quarter of 8.1 %) both run.
    let plan = req.plan(engine, &no_files).unwrap();
    assert!(plan.runs(FrameStage::SkyLight) && plan.runs(FrameStage::GroundLight));
    // Under a target of 0.5 the ground share, counted three times, fits the allowance (0.398);
    // the sky's does not.
    let loose = req.clone().with_max_rel_error(Some("0.5")).unwrap();
    let plan = loose.plan(engine, &no_files).unwrap();
    let Some(FrameReason::UnderBudget {
        predicted_share, ..
    }) = reason(&plan, FrameStage::GroundLight)
    else {
        panic!("{plan:?}")
    };
    assert!(
        (predicted_share - MEASURED_LIGHT_SHARE_SAFETY * ground).abs() < 1e-9,
        "{plan:?}"
    );
    assert!(plan.runs(FrameStage::SkyLight));
    // Executed: the `ground` product is not used for the cloud, and the frame's mean moves by
    // less than the predicted share.
    let image = loose
        .compute_tiled(engine, &no_files, &NoTiles, &|_| {}, &|| false)
        .unwrap();
    let summary = frame_summary(&image);
    let notes = summary["lighting_notes"].to_string();
    assert!(!notes.contains("ground product"), "{notes}");
    assert!(notes.contains("sky product"), "{notes}");
    let full = req
        .compute_tiled(engine, &no_files, &NoTiles, &|_| {}, &|| false)
        .unwrap();
    assert!(frame_summary(&full)["lighting_notes"]
        .to_string()
        .contains("ground product"));
    let radiance = |img: &skybake_physics::image::SpectralImage| -> Vec<f32> {
        img.layer("S0")
            .unwrap()
            .planes()
            .iter()
            .flatten()
            .copied()
            .collect()
    };
    let bias = mean_difference(&radiance(&image), &radiance(&full));
    eprintln!(
        "ground light left out under an atmosphere: mean {bias:.4}, predicted {predicted_share:.4}"
    );
    assert!(bias > 0.0 && bias <= predicted_share, "{bias}");
}

/// The example sphere cumulus (K = 6, 25 m voxels) from `distance_m`, fov 12°.
fn sphere_scene(distance_m: f64, level: Option<u32>) -> Value {
    let spheres: Value =
        serde_json::from_str(include_str!("../../config/scenes/sphere-cloud.json")).unwrap();
    scene(|v| {
        v["cloud"] = spheres["cloud"].clone();
        v["cloud"]["voxel_size_m"] = json!(25.0);
        v["cloud"]["source"]["level"] = json!(level);
        v["optics"]["extinction_per_density_m"] = json!(3.912 / 60.0);
        v["camera"]["position_m"] = json!([0, -distance_m, 1200]);
        v["camera"]["look_at_m"] = json!([0, 0, 1500]);
        v["camera"]["fov_deg"] = json!(12);
    })
}

#[test]
fn a_distant_sphere_hierarchy_is_summed_at_the_level_the_camera_resolves_under_a_loose_target() {
    let v = sphere_scene(30_000.0, None);
    let s = parse(&v);
    let facts = sphere_facts(&s).unwrap().unwrap();
    // 32 px over 12° at ≈ 29 km: a pixel covers ≈ 190 m; the leaves (level 6) are ≈ 35 m across.
    assert_eq!(facts.requested_level, 6);
    assert!(facts.resolved_level < 6, "{facts:?}");
    assert!(
        facts.resolved_diameter_m >= facts.pixel_footprint_m,
        "{facts:?}"
    );
    let engine = service_support::shared_engine();
    let req = FrameRequest::from_value(&v, Method::Fast).unwrap();
    // The default budget does not cover one level (SPHERE_LEVEL_ERROR).
    assert!(SPHERE_LEVEL_ERROR > req.plan(engine, &no_files).unwrap().budget.allowance);
    assert_eq!(req.plan(engine, &no_files).unwrap().sphere_level, None);
    // A target of 0.5 leaves 0.398: two levels (0.30), not three.
    let loose = req.clone().with_max_rel_error(Some("0.5")).unwrap();
    let plan = loose.plan(engine, &no_files).unwrap();
    let level = plan.sphere_level.expect("sphere level coarsened");
    let levels_up = ((0.5 - FRAME_MEASURED_ERROR) / SPHERE_LEVEL_ERROR).floor() as u32;
    assert_eq!(
        level.to_level,
        facts.resolved_level.max(6 - levels_up),
        "{level:?}"
    );
    assert_eq!(
        serde_json::to_value(&plan).unwrap()["sphere_level"]["to_level"],
        json!(level.to_level)
    );
    // The hierarchy is built only to that level: its leaves are the full hierarchy's level.
    let at = |levels: u32, level: Option<u32>| {
        let mut c = s.cloud.clone();
        if let skybake_physics::cloud::scene::CloudSource::Spheres(src) = &mut c.source {
            src.params.levels = levels;
            src.level = level;
        }
        c.voxelize(&no_files).unwrap()
    };
    let truncated = at(level.to_level, None);
    let full = at(6, Some(level.to_level));
    assert_eq!(truncated.dims, full.dims);
    assert_eq!(truncated.data, full.data);
    // A level the scene fixes is kept.
    let fixed = FrameRequest::from_value(&sphere_scene(30_000.0, Some(6)), Method::Fast)
        .unwrap()
        .with_max_rel_error(Some("0.5"))
        .unwrap();
    assert_eq!(fixed.plan(engine, &no_files).unwrap().sphere_level, None);
    // Near, the camera resolves the leaves: nothing to coarsen.
    let near = parse(&sphere_scene(3_000.0, None));
    let f = sphere_facts(&near).unwrap().unwrap();
    assert_eq!(f.resolved_level, 6, "{f:?}");
}

#[test]
fn the_cli_and_the_service_take_max_rel_error_for_frames() {
    // CLI: a target under the measured error is refused naming the parameter and the figure.
    let dir = std::env::temp_dir().join(format!("skybake-plan-frame-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.json");
    std::fs::write(&path, serde_json::to_vec(&scene(|_| {})).unwrap()).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(["render", path.to_str().unwrap(), "--max-rel-error", "0.05"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("--max-rel-error") && stderr.contains("0.0810"),
        "{stderr}"
    );
    let scene_arg = path.to_str().unwrap();
    let out = skybake_ok([
        "plan",
        "frame",
        "--scene",
        scene_arg,
        "--max-rel-error",
        "0.3",
    ]);
    let plan: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(plan["plan"]["budget"]["relative_error"], json!(0.3));
    let _ = std::fs::remove_dir_all(&dir);

    // Service: a 400 naming the best achievable error; a met target sets the budget.
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let cache = Scratch::new("plan-frame-service");
        let state = AppState::new(settings(cache.path())).unwrap();
        let body = serde_json::to_vec(&scene(|_| {})).unwrap();
        let post = |uri: &'static str| call(&state, "POST", uri, body.clone());
        let resp = post("/v1/render?max_rel_error=0.05").await;
        assert_eq!(resp.status, 400);
        let text = resp.text();
        assert!(
            text.contains("max_rel_error") && text.contains("0.0810"),
            "{text}"
        );
        let resp = post("/v1/render?max_rel_error=0.3&format=json").await;
        assert_eq!(resp.status, 200);
        assert_eq!(resp.json()["plan"]["budget"]["relative_error"], json!(0.3));
    });
}

#[test]
fn measured_shares_agree_with_the_given_light_of_a_vacuum_scene() {
    // Vacuum: sun 1 (collimated), constant sky 0.1, ground albedo 0.3 lit by both. The shares
    // measured on the lighting (4096 directions) must be the closed forms the planner predicts
    // for vacuum scenes: sun E/(4π), sky L_s/2, ground a/π·(E μ_s + π L_s)/2.
    let v = scene(|v| v["ground"] = json!({"albedo": 0.3, "height_m": 0}));
    let s = parse(&v);
    let grid = voxelize(&s);
    let lighting = lighting_for(&s, &grid, service_support::shared_engine()).unwrap();
    let (sky, ground) = measured_shares(&lighting);
    let pi = std::f64::consts::PI;
    let mu_s = 35f64.to_radians().sin();
    let (e, l_s) = (1.0, 0.1);
    let l_g = 0.3 / pi * (e * mu_s + pi * l_s);
    let total = e / (4.0 * pi) + l_s / 2.0 + l_g / 2.0;
    let (sky_exact, ground_exact) = (l_s / 2.0 / total, l_g / 2.0 / total);
    assert!((sky - sky_exact).abs() < 1e-3, "{sky} vs {sky_exact}");
    assert!(
        (ground - ground_exact).abs() < 1e-3,
        "{ground} vs {ground_exact}"
    );
    let facts = skybake_product::frame::frame_facts(&s, &grid, Method::Fast);
    assert!(!facts.shares_measured);
    assert!((facts.sky_share.unwrap() - sky_exact).abs() < 1e-9);
}
