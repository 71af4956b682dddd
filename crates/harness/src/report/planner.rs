//! `skybake-harness report --planner`: what each of the planner's cost rules saves
//! and costs. For one case per rule, the request runs with its plan and with the same plan
//! without the cost rules (`Plan::without_cost_rules`, `FramePlan::without_cost_rules`); both are
//! timed and compared with the reference: the precise method at the `reference` preset for the
//! sky product, the path tracer for frames. Writes `planner.md`.
//!
//! Error measures: sky, `rel_max` and `rel_rms` of the report (`report::errors`); frames, the
//! normalised RMS over pixels and wavelengths √(mean (x − r)²) / mean r and the bias of the mean
//! (mean x − mean r) / mean r, against a path-traced frame whose own noise is in the table.

use crate::{Error, Result};
use serde_json::{json, Value};
use skybake_engine::engine::{Engine, Product};
use skybake_engine::plan::{FramePlan, FrameReason};
use skybake_physics::cloud::DensityGrid;
use skybake_product::frame::{
    execute_plan, frame_facts_with, plan_frame, sphere_facts, PlanInputs,
};
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};
use skybake_render::{lighting_for, render_tile, FrameScene, Lighting, Method, Prepared};
use std::time::Instant;

/// One rule's measurement.
#[derive(Debug, Clone)]
pub struct RuleSaving {
    pub rule: String,
    pub case: String,
    /// What the plan left out or coarsened, as the plan says it.
    pub plan: String,
    pub ms_with: f64,
    pub ms_without: f64,
    /// CPU time (user + system, all threads) of the same runs, the smallest of the runs, ms
    /// (`NaN` where not measurable): fairer than wall time on a shared machine.
    pub cpu_with: f64,
    pub cpu_without: f64,
    /// What the rule changes: (normalised RMS or largest relative deviation, bias) of the
    /// result with the rule against the result without it.
    pub change: (f64, f64),
    /// Error against the reference with and without the rule.
    pub error_with: f64,
    pub error_without: f64,
    /// What the error against the reference is.
    pub measures: &'static str,
    pub note: String,
}

/// Path-tracer samples per pixel of the frames' references.
const REFERENCE_SPP: usize = 64;
/// Timed runs per configuration (the fastest counts: the machine is shared).
const RUNS: usize = 2;

/// The result of `f` and the smallest wall and CPU times of [`RUNS`] runs, ms.
fn fastest<T>(mut f: impl FnMut() -> Result<T>) -> Result<(T, f64, f64)> {
    let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
    let mut out = None;
    for _ in 0..RUNS {
        let cpu = super::process_cpu_ms();
        let t = Instant::now();
        let v = f()?;
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        best_cpu = match (cpu, super::process_cpu_ms()) {
            (Some(a), Some(b)) => best_cpu.min(b - a),
            _ => f64::NAN,
        };
        out = Some(v);
    }
    out.map(|v| (v, best, best_cpu))
        .ok_or_else(|| Error::internal("planner report", "no run"))
}

/// The sky rule: precise orders under the error budget (clear air, standard, 3 wavelengths).
fn sky_orders() -> Result<RuleSaving> {
    let pairs = [
        ("method", "precise"),
        ("quality", "standard"),
        ("wavelengths", "440"),
        ("sun_elevation_deg", "30"),
        ("elevation_count", "33"),
        ("azimuth_count", "16"),
    ];
    let request = |quality: &str| -> Result<ProductRequest> {
        let mut p = RequestParams::from_pairs(pairs.iter().copied())
            .map_err(|e| Error::invalid("planner report", format!("{e:?}")))?;
        p.quality = Some(quality.into());
        ProductRequest::from_params(ProductKind::Sky, &p)
    };
    let req = request("standard")?;
    let plan = req.plan()?;
    let full = plan.clone().without_cost_rules();
    // Cold: a new engine (tables built) each run.
    let (with, ms_with, cpu_with) =
        fastest(|| Engine::new().execute(&req.spec, &req.product, &plan))?;
    let (without, ms_without, cpu_without) =
        fastest(|| Engine::new().execute(&req.spec, &req.product, &full))?;
    let reference_req = request("reference")?;
    let reference = Engine::new().compute(&reference_req.spec, &reference_req.product)?;
    let table = |p: &Product| -> Vec<f64> {
        match p {
            Product::Sky(d) => d.table.radiance.iter().map(|&v| v as f64).collect(),
            _ => Vec::new(),
        }
    };
    let r = table(&reference);
    let err = |p: &Product| super::errors(&table(p), &r).1;
    let (change_rms, change_max) = super::errors(&table(&with), &table(&without));
    let orders = |p: &Product| p.meta().error_estimate.scattering_orders.unwrap_or(0);
    let left = plan
        .left_out
        .iter()
        .find(|(s, _)| *s == skybake_engine::plan::Stage::HigherOrders)
        .map(|(_, r)| r.detail())
        .unwrap_or_else(|| "(rule did not fire)".into());
    Ok(RuleSaving {
        rule: "sky: precise orders under the error budget".into(),
        case: "sky 33×16, earth, 440 nm, sun 30°, standard, cold tables".into(),
        plan: left,
        ms_with,
        ms_without,
        cpu_with,
        cpu_without,
        change: (change_max, change_rms),
        error_with: err(&with),
        error_without: err(&without),
        measures: "rel_max against the precise method at the reference preset",
        note: format!(
            "orders {} with, {} without",
            orders(&with),
            orders(&without)
        ),
    })
}

/// The validation cloud (vacuum, collimated sun 1, constant sky 0.1) at 50 m voxels, 48×36 px,
/// standard quality, edited.
fn frame_scene(edit: impl FnOnce(&mut Value)) -> Result<FrameScene> {
    let mut v: Value = serde_json::from_str(include_str!(
        "../../../../config/scenes/validation-frame.json"
    ))
    .map_err(|e| Error::internal("planner report", e))?;
    v["cloud"]["voxel_size_m"] = json!(50.0);
    v["camera"]["width"] = json!(48);
    v["camera"]["height"] = json!(36);
    v["quality"] = json!("standard");
    edit(&mut v);
    FrameScene::parse(&serde_json::to_vec(&v).map_err(|e| Error::internal("planner report", e))?)
}

fn render(
    scene: &FrameScene,
    grid: &DensityGrid,
    plan: &FramePlan,
    method: Method,
) -> Result<Vec<f32>> {
    render_lit(scene, grid, plan, method, None)
}

/// [`render`], with an atmosphere lit as `FrameRequest` does: the scene's whole light computed
/// first (the planner measures the shares on it), less what the plan leaves out.
fn render_measured(
    scene: &FrameScene,
    grid: &DensityGrid,
    plan: &FramePlan,
    method: Method,
) -> Result<Vec<f32>> {
    if scene.atmosphere.is_none() || plan.coarsening() > 1 {
        return render(scene, grid, plan, method);
    }
    let measured = lighting_for(scene, grid, &Engine::new())?;
    render_lit(scene, grid, plan, method, Some(measured))
}

fn render_lit(
    scene: &FrameScene,
    grid: &DensityGrid,
    plan: &FramePlan,
    method: Method,
    measured: Option<Lighting>,
) -> Result<Vec<f32>> {
    let run = execute_plan(plan, scene, grid, method)?;
    let grid = run.grid.as_ref().unwrap_or(grid);
    let lighting = match measured {
        Some(l) => {
            let sw = run.scene.lighting;
            l.masked(sw.sky_light, sw.ground_light).unwrap_or(l)
        }
        None => lighting_for(&run.scene, grid, &Engine::new())?,
    };
    let mut settings = run.settings;
    settings.spp = REFERENCE_SPP;
    let p = Prepared::new(&run.scene, grid, &lighting, settings, &|| false)?;
    Ok(render_tile(&p, None, &|_| {}, &|| false)?.radiance)
}

/// The frame of `scene` without its cloud (an empty grid of `grid`'s shape), fast method: the
/// background the cloud's signal is measured against.
fn background_of(scene: &FrameScene, grid: &DensityGrid) -> Result<Vec<f32>> {
    let empty = DensityGrid::zeros(grid.dims, grid.voxel_size_m, grid.origin_m)?;
    render(
        scene,
        &empty,
        &plan_frame(scene, &empty, Method::Fast),
        Method::Fast,
    )
}

/// Normalised RMS and bias of `x` against `r`, relative to the cloud's signal: the mean of
/// |r − b| with `b` the frame without the cloud (module docs), so a faint cloud over a bright
/// background is not hidden by the background. (0, 0) for identical frames.
fn frame_errors(x: &[f32], r: &[f32], b: &[f32]) -> (f64, f64) {
    if x == r {
        return (0.0, 0.0);
    }
    let n = r.len().max(1) as f64;
    let signal = r
        .iter()
        .zip(b)
        .map(|(r, b)| (*r as f64 - *b as f64).abs())
        .sum::<f64>()
        / n;
    let diff = x
        .iter()
        .zip(r)
        .map(|(a, b)| *a as f64 - *b as f64)
        .sum::<f64>()
        / n;
    let mse = x
        .iter()
        .zip(r)
        .map(|(a, b)| (*a as f64 - *b as f64).powi(2))
        .sum::<f64>()
        / n;
    (mse.sqrt() / signal, diff / signal)
}

/// The fast plan of `scene` on `grid` with the request's `target`, the light measured on the
/// scene's computed lighting when it has an atmosphere (as `FrameRequest` plans).
fn fast_plan(scene: &FrameScene, grid: &DensityGrid, target: Option<f64>) -> Result<FramePlan> {
    let lighting = match scene.atmosphere {
        Some(_) => Some(lighting_for(scene, grid, &Engine::new())?),
        None => None,
    };
    Ok(skybake_engine::plan::plan_frame(&frame_facts_with(
        scene,
        grid,
        Method::Fast,
        &PlanInputs {
            max_rel_error: target,
            lighting: lighting.as_ref(),
            sphere: None,
            rgb: None,
        },
    )))
}

fn frame_rule(
    rule: &str,
    case: &str,
    scene: FrameScene,
    reference: bool,
    target: Option<f64>,
) -> Result<RuleSaving> {
    let grid = scene
        .cloud
        .voxelize(&|_| Err(Error::invalid("path", "no files")))?;
    let plan = fast_plan(&scene, &grid, target)?;
    let full = plan.clone().without_cost_rules();
    let (with, ms_with, cpu_with) =
        fastest(|| render_measured(&scene, &grid, &plan, Method::Fast))?;
    let (without, ms_without, cpu_without) =
        fastest(|| render_measured(&scene, &grid, &full, Method::Fast))?;
    let background = background_of(&scene, &grid)?;
    let change = frame_errors(&with, &without, &background);
    let (error_with, error_without, note) = if reference {
        let pt_plan = plan_frame(&scene, &grid, Method::Reference);
        let r = render(&scene, &grid, &pt_plan, Method::Reference)?;
        (
            frame_errors(&with, &r, &background).1,
            frame_errors(&without, &r, &background).1,
            format!("path tracer {REFERENCE_SPP} spp"),
        )
    } else {
        (
            f64::NAN,
            f64::NAN,
            format!(
                "identical frames: {}; no path tracer needed",
                with == without
            ),
        )
    };
    let mut what: Vec<String> = plan
        .left_out
        .iter()
        .filter(|(_, r)| {
            matches!(
                r,
                FrameReason::ThinCloud { .. }
                    | FrameReason::UnderBudget { .. }
                    | FrameReason::CloudOutOfView
            )
        })
        .map(|(s, r)| format!("{s:?}: {}", r.detail()))
        .collect();
    what.extend(plan.coarsened.iter().map(|c| {
        let what = match c.stage {
            skybake_engine::plan::FrameStage::MultipleScattering => "field cells",
            _ => "voxels",
        };
        format!(
            "{:?}: {what} {} m → {} m (pixel footprint {:.0} m at {:.0} m)",
            c.stage, c.from_voxel_m, c.to_voxel_m, c.pixel_footprint_m, c.nearest_distance_m
        )
    }));
    Ok(RuleSaving {
        rule: rule.into(),
        case: case.into(),
        plan: if what.is_empty() {
            "(rule did not fire)".into()
        } else {
            what.join("; ")
        },
        ms_with,
        ms_without,
        cpu_with,
        cpu_without,
        change,
        error_with,
        error_without,
        measures: "bias of the cloud's mean signal against the path tracer",
        note,
    })
}

/// The sphere-level rule: the example sphere cumulus with K = `levels` (Ostroushko et al.) seen from
/// 30 km, with the request's `target`: built, voxelised and rendered at the plan's level and at
/// the leaves; the error against the path tracer on the leaves.
fn sphere_rule(levels: u32, target: f64) -> Result<RuleSaving> {
    let spheres: Value =
        serde_json::from_str(include_str!("../../../../config/scenes/sphere-cloud.json"))
            .map_err(|e| Error::internal("planner report", e))?;
    let scene = frame_scene(|v| {
        v["cloud"] = spheres["cloud"].clone();
        v["cloud"]["source"]["params"]["levels"] = json!(levels);
        v["cloud"]["voxel_size_m"] = json!(25.0);
        // The model's own extinction, −ln 0.02 / S_M with S_M = 60 m.
        v["optics"]["extinction_per_density_m"] = json!(3.912 / 60.0);
        v["camera"]["position_m"] = json!([0, -30000, 1200]);
        v["camera"]["look_at_m"] = json!([0, 0, 1500]);
        v["camera"]["fov_deg"] = json!(12);
    })?;
    let facts = sphere_facts(&scene)?
        .ok_or_else(|| Error::internal("planner report", "not a sphere cloud"))?;
    let mut budget = skybake_engine::plan::frame_budget(
        false,
        skybake_engine::plan::FRAME_MEASURED_ERROR,
        Some(target),
    );
    let level = skybake_engine::plan::sphere_level_rule(&facts, &mut budget);
    let voxelize = |to: Option<u32>| -> Result<DensityGrid> {
        let mut cloud = scene.cloud.clone();
        if let (Some(to), skybake_physics::cloud::scene::CloudSource::Spheres(s)) =
            (to, &mut cloud.source)
        {
            s.params.levels = to;
        }
        cloud.voxelize(&|_| Err(Error::invalid("path", "no files")))
    };
    let to = level.map(|l| l.to_level);
    let timed = |to: Option<u32>| -> Result<Vec<f32>> {
        let grid = voxelize(to)?;
        let plan = plan_frame(&scene, &grid, Method::Fast).without_cost_rules();
        render(&scene, &grid, &plan, Method::Fast)
    };
    let (with, ms_with, cpu_with) = fastest(|| timed(to))?;
    let (without, ms_without, cpu_without) = fastest(|| timed(None))?;
    let leaves = voxelize(None)?;
    let background = background_of(&scene, &leaves)?;
    let r = render(
        &scene,
        &leaves,
        &plan_frame(&scene, &leaves, Method::Reference),
        Method::Reference,
    )?;
    Ok(RuleSaving {
        rule: format!("frame: sphere hierarchy at the pixel footprint (max_rel_error {target})"),
        case: format!(
            "example sphere cumulus, K = {levels}, 25 m voxels, from 30 km, fov 12°, 48×36; building, voxelising and rendering"
        ),
        plan: match level {
            Some(l) => format!(
                "CloudDetail: spheres summed at level {} instead of {} (level {} of mean diameter {:.0} m resolves the pixel footprint {:.0} m at {:.0} m; predicted {:.0} % of a {:.0} % allowance)",
                l.to_level,
                l.from_level,
                facts.resolved_level,
                facts.resolved_diameter_m,
                l.pixel_footprint_m,
                l.nearest_distance_m,
                l.predicted_error * 100.0,
                budget.allowance * 100.0
            ),
            None => "(rule did not fire)".into(),
        },
        ms_with,
        ms_without,
        cpu_with,
        cpu_without,
        change: frame_errors(&with, &without, &background),
        error_with: frame_errors(&with, &r, &background).1,
        error_without: frame_errors(&without, &r, &background).1,
        measures: "bias of the cloud's mean signal against the path tracer",
        note: format!("path tracer {REFERENCE_SPP} spp on the leaves"),
    })
}

/// The RGB planes of a frame artifact, flattened (R, then G, then B).
fn rgb_of(image: &skybake_physics::image::SpectralImage) -> Result<Vec<f32>> {
    let rgb = image
        .rgb()
        .ok_or_else(|| Error::internal("planner report", "a frame without RGB planes"))?;
    Ok(rgb.iter().flatten().copied().collect())
}

/// Per pixel, the largest change of a channel relative to the pixel's mean |channel| in the
/// frame without the rule (the measure the wavelength rule predicts): (RMS over pixels,
/// largest).
fn rgb_pixel_changes(with: &[f32], without: &[f32]) -> (f64, f64) {
    let n = without.len() / 3;
    let (mut sum2, mut worst) = (0.0f64, 0.0f64);
    for p in 0..n {
        let at = |v: &[f32], c: usize| v[c * n + p] as f64;
        let scale = (0..3).map(|c| at(without, c).abs()).sum::<f64>() / 3.0;
        let d = (0..3)
            .map(|c| (at(with, c) - at(without, c)).abs())
            .fold(0.0, f64::max);
        let e = if scale > 0.0 { d / scale } else { 0.0 };
        sum2 += e * e;
        worst = worst.max(e);
    }
    ((sum2 / n.max(1) as f64).sqrt(), worst)
}

/// (mean x − mean r) / mean r.
fn mean_bias(x: &[f32], r: &[f32]) -> f64 {
    let sum = |v: &[f32]| v.iter().map(|&a| a as f64).sum::<f64>();
    sum(x) / sum(r).max(1e-300) - 1.0
}

fn signed_pct(v: f64) -> String {
    format!("{:+.2} %", v * 100.0)
}

/// The wavelength rule: the example cumulus frame (earth atmosphere and sky, ground albedo 0.3,
/// sun 35°) asked at the default 16 wavelengths 380–755 nm as a PNG (RGB-only) and as the
/// spectral EXR, both through `FrameRequest` (voxels, light with cold tables, pixels).
fn rgb_rule(width: usize, height: usize) -> Result<RuleSaving> {
    use skybake_product::frame::FrameRequest;
    let mut v: Value =
        serde_json::from_str(include_str!("../../../../config/scenes/cumulus-frame.json"))
            .map_err(|e| Error::internal("planner report", e))?;
    v["wavelengths_nm"] = json!((0..16).map(|i| 380 + 25 * i).collect::<Vec<_>>());
    v["camera"]["width"] = json!(width);
    v["camera"]["height"] = json!(height);
    let no_files = |_: &str| -> Result<Vec<u8>> { Err(Error::invalid("path", "no files")) };
    let request = |v: &Value, method: Method, rgb_only: bool| -> Result<FrameRequest> {
        Ok(FrameRequest::from_value(v, method)?.with_rgb_only(rgb_only))
    };
    let compute = |r: &FrameRequest| r.compute(&Engine::new(), &no_files, &|_| {}, &|| false);
    let rgb_req = request(&v, Method::Fast, true)?;
    let full_req = request(&v, Method::Fast, false)?;
    let plan = rgb_req.plan(&Engine::new(), &no_files)?;
    let (with, ms_with, cpu_with) = fastest(|| compute(&rgb_req))?;
    let (without, ms_without, cpu_without) = fastest(|| compute(&full_req))?;
    let (with, without) = (rgb_of(&with)?, rgb_of(&without)?);
    let (rms, worst) = rgb_pixel_changes(&with, &without);
    let bias = mean_bias(&with, &without);
    let mut empty = v.clone();
    empty["optics"]["extinction_per_density_m"] = json!(0.0);
    let background = rgb_of(&compute(&request(&empty, Method::Fast, false)?)?)?;
    let reference = rgb_of(&compute(&request(&v, Method::Reference, false)?)?)?;
    let spp =
        skybake_render::RenderSettings::for_quality(full_req.scene.quality, Method::Reference).spp;
    Ok(RuleSaving {
        rule: "frame: RGB-only output at fewer wavelengths".into(),
        case: format!(
            "example cumulus frame, earth atmosphere, sun 35°, ground albedo 0.3, 16 wavelengths 380–755 nm, {width}×{height}, PNG (RGB-only) against EXR; voxels, light (cold tables) and pixels"
        ),
        plan: match &plan.wavelengths {
            Some(w) => format!(
                "{}; measured per-pixel change of the RGB: RMS {:.2} %, largest {:.2} % (predicted {:.2} %)",
                w.detail(),
                rms * 100.0,
                worst * 100.0,
                w.predicted_error * 100.0
            ),
            None => "(rule did not fire)".into(),
        },
        ms_with,
        ms_without,
        cpu_with,
        cpu_without,
        change: (rms, bias),
        error_with: frame_errors(&with, &reference, &background).1,
        error_without: frame_errors(&without, &reference, &background).1,
        measures: "bias of the cloud's mean RGB signal against the path tracer",
        note: format!(
            "path tracer {spp} spp at the 16 wavelengths; change: per-pixel largest channel change relative to the pixel's mean channel (RMS over pixels) / bias of the image's mean; against the path tracer relative to its mean pixel (the frames' stated measure, sky included): bias {} with, {} without",
            signed_pct(mean_bias(&with, &reference)),
            signed_pct(mean_bias(&without, &reference))
        ),
    })
}

/// Linear sRGB of every direction of a sky artifact.
fn dome_rgb(image: &skybake_physics::image::SpectralImage) -> Result<Vec<[f64; 3]>> {
    let table = skybake_product::artifact::dome_table_of(image)?;
    let w = skybake_physics::spectrum::colour::XyzWeights::new(&table.wavelengths_nm);
    Ok(table
        .radiance
        .chunks(table.wavelengths_nm.len().max(1))
        .map(|s| w.linear_srgb(&s.iter().map(|&v| v as f64).collect::<Vec<_>>()))
        .collect())
}

/// Per direction, the largest channel change of `x` against `r` relative to the direction's
/// mean |channel| in `r`: (largest, RMS) over the directions that are lit.
fn rgb_direction_changes(x: &[[f64; 3]], r: &[[f64; 3]]) -> (f64, f64) {
    let (mut worst, mut sum2, mut n) = (0.0f64, 0.0f64, 0usize);
    for (a, b) in x.iter().zip(r) {
        let scale = (b[0].abs() + b[1].abs() + b[2].abs()) / 3.0;
        if scale > 0.0 {
            let e = (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0, f64::max) / scale;
            worst = worst.max(e);
            sum2 += e * e;
            n += 1;
        }
    }
    (worst, (sum2 / n.max(1) as f64).sqrt())
}

/// The wavelength rule on a sky PNG: the default 16 wavelengths, fast, standard, sun 30°, the
/// default 33×16 table, as a PNG (RGB-only) and as the spectral artifact (cold engines), against
/// the precise method at the `reference` preset at every wavelength.
fn sky_rgb_rule() -> Result<RuleSaving> {
    let request = |format: &str, method: &str, quality: &str| -> Result<ProductRequest> {
        let pairs = [
            ("format", format),
            ("method", method),
            ("quality", quality),
            ("sun_elevation_deg", "30"),
        ];
        let p = RequestParams::from_pairs(pairs.iter().copied())
            .map_err(|e| Error::invalid("planner report", format!("{e:?}")))?;
        ProductRequest::from_params(ProductKind::Sky, &p)
    };
    let png = request("png", "fast", "standard")?;
    let spectral = png.clone().without_rgb_only()?;
    let (with, ms_with, cpu_with) = fastest(|| png.compute(&Engine::new()))?;
    let (without, ms_without, cpu_without) = fastest(|| spectral.compute(&Engine::new()))?;
    let reference = request("json", "precise", "reference")?.compute(&Engine::new())?;
    let (with, without, reference) = (dome_rgb(&with)?, dome_rgb(&without)?, dome_rgb(&reference)?);
    let (worst, rms) = rgb_direction_changes(&with, &without);
    Ok(RuleSaving {
        rule: "sky: RGB-only PNG at fewer wavelengths".into(),
        case: "sky 33×16, earth, fast, standard, sun 30°, 16 wavelengths 380–755 nm, PNG (RGB-only) against the spectral artifact; cold tables".into(),
        plan: match &png.rgb_only {
            Some(w) => w.detail(),
            None => "(rule did not fire)".into(),
        },
        ms_with,
        ms_without,
        cpu_with,
        cpu_without,
        change: (worst, rms),
        error_with: rgb_direction_changes(&with, &reference).0,
        error_without: rgb_direction_changes(&without, &reference).0,
        measures: "largest RGB deviation of a direction (relative to its mean channel) from the precise method at the reference preset",
        note: "change: largest / RMS over directions of the largest channel change relative to the direction's mean channel".into(),
    })
}

/// Measures every rule (see the module docs). `progress(done, total)` after each.
pub fn run(progress: &dyn Fn(usize, usize)) -> Result<Vec<RuleSaving>> {
    let total = 11;
    let mut out = Vec::new();
    out.push(sky_orders()?);
    progress(1, total);
    out.push(sky_rgb_rule()?);
    progress(2, total);
    out.push(frame_rule(
        "frame: cloud outside the view",
        "validation cloud, camera turned away, 48×36",
        frame_scene(|v| v["camera"]["look_at_m"] = json!([0, -9000, 1200]))?,
        false,
        None,
    )?);
    progress(3, total);
    out.push(frame_rule(
        "frame: thin cloud, no multiple scattering",
        "validation cloud at extinction 5e-6 /m (optical path ≤ 0.013), 48×36",
        frame_scene(|v| v["optics"]["extinction_per_density_m"] = json!(5e-6))?,
        true,
        None,
    )?);
    progress(4, total);
    out.push(frame_rule(
        "frame: ground light under budget (no sky: lattice paths left out)",
        "validation cloud, no sky, ground albedo 0.005, 48×36",
        frame_scene(|v| {
            v["sky"] = Value::Null;
            v["ground"] = json!({"albedo": 0.005, "height_m": 0});
        })?,
        true,
        None,
    )?);
    progress(5, total);
    out.push(frame_rule(
        "frame: coarser voxels at the pixel footprint",
        "validation cloud from 30 km, fov 12°, 48×36",
        frame_scene(|v| {
            v["camera"]["position_m"] = json!([0, -30000, 1200]);
            v["camera"]["fov_deg"] = json!(12);
        })?,
        true,
        None,
    )?);
    progress(6, total);
    out.push(frame_rule(
        "frame: coarser voxels at the pixel footprint (max_rel_error 0.3)",
        "validation cloud from 30 km, fov 12°, 48×36",
        frame_scene(|v| {
            v["camera"]["position_m"] = json!([0, -30000, 1200]);
            v["camera"]["fov_deg"] = json!(12);
        })?,
        true,
        Some(0.3),
    )?);
    progress(7, total);
    out.push(frame_rule(
        "frame: coarser multiple-scattering field at the pixel footprint (max_rel_error 0.13)",
        "validation cloud at 25 m voxels from 30 km, fov 12°, 48×36",
        frame_scene(|v| {
            v["cloud"]["voxel_size_m"] = json!(25.0);
            v["camera"]["position_m"] = json!([0, -30000, 1200]);
            v["camera"]["fov_deg"] = json!(12);
        })?,
        true,
        Some(0.13),
    )?);
    progress(8, total);
    out.push(frame_rule(
        "frame: ground light under budget with an atmosphere, measured share (max_rel_error 0.5)",
        "validation cloud, earth atmosphere and sky, sun 35°, ground albedo 0.02, 440/550/680 nm, 48×36; lighting included (cold tables)",
        frame_scene(|v| {
            v["atmosphere"] = json!("earth");
            v["sky"] = json!("atmosphere");
            v["sun"] = json!({"elevation_deg": 35, "azimuth_deg": 140});
            v["ground"] = json!({"albedo": 0.02, "height_m": 0});
            v["wavelengths_nm"] = json!([440, 550, 680]);
        })?,
        true,
        Some(0.5),
    )?);
    progress(9, total);
    out.push(sphere_rule(9, 0.5)?);
    progress(10, total);
    out.push(rgb_rule(160, 120)?);
    progress(11, total);
    Ok(out)
}

/// The markdown of `planner.md`.
pub fn markdown(rows: &[RuleSaving], threads: usize, load: Option<&str>) -> String {
    let mut s = String::from(
        "# What the planner's cost rules save\n\n\
         Written by `skybake-harness report --planner` (`crates/harness/src/report/planner.rs`): one case per rule, run with its \
         plan and with the same plan without the cost rules, each the fastest of 2 runs in wall \
         time and in CPU time (user + system of all threads, 10 ms ticks; fairer on a shared \
         machine) (sky: cold tables, a new engine per run; frames: lighting, preparation and \
         pixels; with an atmosphere the whole light is computed first, as the planner measures \
         its shares on it; sphere hierarchies: building and voxelising too; the RGB-only frame: \
         the whole request through `FrameRequest`, cold tables), and \
         compared with the reference (sky: the precise method at the `reference` preset; frames: \
         the path tracer). Frames: RMS and mean of the difference from the path tracer over all \
         pixels and wavelengths, relative to the cloud's mean signal |path tracer − frame without \
         the cloud|; the RMS includes the path tracer's own noise, equal for both columns.\n\n",
    );
    s.push_str(&format!(
        "Machine: {threads} threads{}.\n\n",
        load.map(|l| format!(", load average {l}"))
            .unwrap_or_default()
    ));
    s.push_str(
        "| rule | case | time with | time without | saving | CPU with | CPU without | CPU saving | change by the rule | error with | error without | error measure |\n",
    );
    s.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    let pct = |v: f64| {
        if v.is_finite() {
            format!("{:+.2} %", v * 100.0)
        } else {
            "—".into()
        }
    };
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {:.0} ms | {:.0} ms | {:.0} % | {:.0} ms | {:.0} ms | {:.0} % | {:.2} % / {} | {} | {} | {} |\n",
            r.rule,
            r.case,
            r.ms_with,
            r.ms_without,
            100.0 * (1.0 - r.ms_with / r.ms_without.max(1e-9)),
            r.cpu_with,
            r.cpu_without,
            100.0 * (1.0 - r.cpu_with / r.cpu_without.max(1e-9)),
            r.change.0 * 100.0,
            pct(r.change.1),
            pct(r.error_with),
            pct(r.error_without),
            r.measures
        ));
    }
    s.push_str(
        "\n`change by the rule`: the result with the rule against the result without it (sky: \
         largest relative deviation / RMS; frames: RMS / bias, relative to the cloud's mean \
         signal). The frames' path tracer has 64 samples per pixel: its noise on these small \
         clouds' signal is too large for a per-pixel error, so the bias of the mean is given.\n",
    );
    s.push_str("\nWhat each plan said and notes:\n\n");
    for r in rows {
        s.push_str(&format!("- **{}**: {} ({})\n", r.rule, r.plan, r.note));
    }
    s
}
