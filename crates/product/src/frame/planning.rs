//! Planning a frame once per request: the facts the planner decides on (the cloud against the
//! camera, its optical depth, the light's shares, the sphere levels, the RGB-only wavelengths), the
//! plan, and its execution (lighting switches, a coarser grid, settings hooks).

use super::*;

/// The planner's view of a scene and its voxelised cloud (the facts the planner's frame rules decide on): whether there is a
/// cloud and whether any pixel's ray can reach it, the smallest pixel footprint on it, a bound on
/// its optical path, and the predicted shares of sky and ground light.
///
/// - Occupied box: the voxels holding density, one voxel wider on every side (trilinear
///   interpolation reaches the next centre), within the grid's box.
/// - In view (conservative: `false` only when no ray can reach the box): pinhole, the box wholly
///   behind the camera or beyond one of the four side planes of the view frustum; orthographic,
///   beyond one of the four side planes or behind the image plane; fisheye, the box's bounding
///   sphere farther from the axis than the image circle's half angle.
/// - Pixel footprint at the box's nearest point (distance d): pinhole d·Δ·cos²θ_c, Δ the pixel
///   pitch at unit distance and θ_c the angle of the image corner (where the angular pitch is
///   smallest); orthographic the pixel pitch; fisheye d times the radians per pixel.
/// - Optical path bound: the largest extinction × the largest density × the box's diagonal.
/// - Shares (vacuum scenes, where the light is given): the light reaching a cloud point averaged
///   over directions, sun E/(4π), a constant sky L_s over the upper hemisphere L_s/2, the lit
///   Lambertian ground below L_g/2 with L_g = a/π·(E μ_s + π L_s); a share is its part of the sum,
///   largest over wavelengths. With an atmosphere the shares are not predicted (the stages run).
pub fn frame_facts(scene: &FrameScene, grid: &DensityGrid, method: Method) -> FrameFacts {
    frame_facts_with(scene, grid, method, &PlanInputs::default())
}

/// What the frame planner takes besides the scene and its grid.
#[derive(Debug, Clone, Copy, Default)]
pub struct PlanInputs<'a> {
    /// The request's `max_rel_error` target.
    pub max_rel_error: Option<f64>,
    /// The light at the cloud as computed for the scene: with an atmosphere the shares of sky
    /// and ground light are measured on it ([`measured_shares`]); without, they are not
    /// predicted (the stages run).
    pub lighting: Option<&'a skybake_render::Lighting>,
    /// A sphere-hierarchy cloud's levels ([`sphere_facts`]).
    pub sphere: Option<SphereFacts>,
    /// An RGB-only request's wavelengths and their subsets ([`skybake_render::rgb_only::rgb_facts`]).
    pub rgb: Option<&'a RgbFacts>,
}

/// Shares of sky light and of ground light (light from below) in all the light reaching the
/// cloud, averaged over directions, largest over wavelengths, measured on the scene's computed
/// light: the sun E/(4π), the sky's and the ground's radiance tables averaged over 4096
/// directions evenly spread over the sphere (a Fibonacci lattice), each hemisphere's mean
/// weighted by its half of the sphere.
pub fn measured_shares(lighting: &skybake_render::Lighting) -> (f64, f64) {
    use glam::DVec3;
    const N: usize = 4096;
    let n_l = lighting.wavelengths_nm.len();
    let (mut up, mut down) = (vec![0.0f64; n_l], vec![0.0f64; n_l]);
    let mut l = vec![0.0f64; n_l];
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..N {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / N as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = golden * i as f64;
        let dir = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        lighting.env(dir, &mut l);
        let acc = if z >= 0.0 { &mut up } else { &mut down };
        for (a, v) in acc.iter_mut().zip(&l) {
            *a += v.max(0.0) / N as f64;
        }
    }
    let (mut sky, mut ground) = (0.0f64, 0.0f64);
    for i in 0..n_l {
        let sun = lighting
            .sun_irradiance
            .get(i)
            .copied()
            .unwrap_or(0.0)
            .max(0.0)
            / (4.0 * std::f64::consts::PI);
        let total = sun + up[i] + down[i];
        if total > 0.0 {
            sky = sky.max(up[i] / total);
            ground = ground.max(down[i] / total);
        }
    }
    (sky, ground)
}

/// Whether the camera sees a box, its smallest pixel footprint on it and its nearest distance
/// (see [`frame_facts`]).
fn view_of_box(
    cam: &skybake_render::scene::CameraSpec,
    lo: glam::DVec3,
    hi: glam::DVec3,
) -> (bool, f64, f64) {
    use glam::DVec3;
    use skybake_render::scene::Projection;
    let corners: Vec<DVec3> = (0..8)
        .map(|c| {
            DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            ) - cam.position_m
        })
        .collect();
    let local: Vec<(f64, f64, f64)> = corners
        .iter()
        .map(|v| (v.dot(cam.right), v.dot(cam.up), v.dot(cam.forward)))
        .collect();
    let all = |f: &dyn Fn(&(f64, f64, f64)) -> bool| local.iter().all(f);
    let nearest = (cam.position_m.clamp(lo, hi) - cam.position_m).length();
    let (in_view, footprint) = match cam.projection {
        Projection::Pinhole { half_w, half_h } => {
            let out = all(&|c| c.2 <= 0.0)
                || all(&|c| c.0 > half_w * c.2)
                || all(&|c| c.0 < -half_w * c.2)
                || all(&|c| c.1 > half_h * c.2)
                || all(&|c| c.1 < -half_h * c.2);
            let pitch = (2.0 * half_w / cam.width as f64).min(2.0 * half_h / cam.height as f64);
            let cos2 = 1.0 / (1.0 + half_w * half_w + half_h * half_h);
            (!out, nearest * pitch * cos2)
        }
        Projection::Orthographic { half_w, half_h } => {
            let out = all(&|c| c.2 <= 0.0)
                || all(&|c| c.0 > half_w)
                || all(&|c| c.0 < -half_w)
                || all(&|c| c.1 > half_h)
                || all(&|c| c.1 < -half_h);
            let pitch = (2.0 * half_w / cam.width as f64).min(2.0 * half_h / cam.height as f64);
            (!out, pitch)
        }
        Projection::Fisheye { rad_per_px } => {
            let centre = 0.5 * (lo + hi) - cam.position_m;
            let radius = 0.5 * (hi - lo).length();
            let dist = centre.length();
            let half_diagonal =
                0.5 * ((cam.width * cam.width + cam.height * cam.height) as f64).sqrt();
            let theta_max = (rad_per_px * half_diagonal).min(std::f64::consts::PI);
            let in_view = dist <= radius || {
                let axis = (centre.dot(cam.forward) / dist).clamp(-1.0, 1.0).acos();
                axis - (radius / dist).clamp(-1.0, 1.0).asin() <= theta_max
            };
            (in_view, nearest * rad_per_px)
        }
    };
    (in_view, footprint, nearest)
}

/// The sphere-hierarchy facts of a scene whose cloud source is `spheres` (`None` otherwise):
/// the pixel footprint on the base sphere's box (every level's spheres lie inside it) and the
/// deepest level whose mean sphere diameter is at least that footprint
/// (`SphereCloud::level_for_resolution`). The levels are built one at a time and only as deep
/// as needed (a parent's children come from its own random stream, so the first L levels of a
/// hierarchy of K ≥ L ≥ 1 levels are those of a hierarchy of L levels); no voxels.
pub fn sphere_facts(scene: &FrameScene) -> Result<Option<SphereFacts>> {
    use glam::DVec3;
    use skybake_physics::cloud::scene::CloudSource;
    use skybake_physics::cloud::spheres::SphereCloud;
    let CloudSource::Spheres(source) = &scene.cloud.source else {
        return Ok(None);
    };
    let k_max = source.params.levels;
    let requested_level = source.level.unwrap_or(k_max).min(k_max);
    let build = |levels: u32| {
        let mut params = source.params.clone();
        params.levels = levels;
        SphereCloud::new(&params).map_err(|e| e.prefixed("cloud.source.params."))
    };
    let mean_diameter = |model: &SphereCloud, k: u32| {
        let spheres = model.level(k);
        2.0 * spheres.iter().map(|s| s.radius as f64).sum::<f64>() / spheres.len().max(1) as f64
    };
    let base = build(k_max.min(1))?;
    let r0 = base.level(0)[0].radius as f64;
    let (lo, hi) = (
        base.centre_m() - DVec3::splat(r0),
        base.centre_m() + DVec3::splat(r0),
    );
    let (_, footprint, nearest) = view_of_box(&scene.camera, lo, hi);
    let (mut resolved_level, mut resolved_diameter_m) = (0, mean_diameter(&base, 0));
    for k in 1..=requested_level {
        let model = build(k)?;
        let d = mean_diameter(&model, k);
        if d < footprint {
            break;
        }
        (resolved_level, resolved_diameter_m) = (k, d);
    }
    Ok(Some(SphereFacts {
        requested_level,
        level_fixed: source.level.is_some(),
        resolved_level,
        resolved_diameter_m,
        pixel_footprint_m: footprint,
        nearest_distance_m: nearest,
    }))
}

/// [`frame_facts`] with the request's target, its measured light and its sphere levels.
pub fn frame_facts_with(
    scene: &FrameScene,
    grid: &DensityGrid,
    method: Method,
    inputs: &PlanInputs,
) -> FrameFacts {
    use glam::DVec3;
    use skybake_render::scene::SkySpec;
    let [nx, ny, nz] = grid.dims;
    let (mut lo_i, mut hi_i) = ([usize::MAX; 3], [0usize; 3]);
    for z in 0..nz {
        for y in 0..ny {
            let row = grid.index(0, y, z);
            for (x, v) in grid.data[row..row + nx].iter().enumerate() {
                if *v > 0.0 {
                    for (a, i) in [x, y, z].into_iter().enumerate() {
                        lo_i[a] = lo_i[a].min(i);
                        hi_i[a] = hi_i[a].max(i);
                    }
                }
            }
        }
    }
    let empty = lo_i[0] == usize::MAX;
    let h = grid.voxel_size_m;
    let (lo, hi) = if empty {
        (grid.origin_m, grid.max_corner_m())
    } else {
        let at = |i: [usize; 3], pad: f64| {
            grid.origin_m + DVec3::new(i[0] as f64, i[1] as f64, i[2] as f64) * h + pad * h
        };
        (
            at(lo_i, -1.0).max(grid.origin_m),
            at(hi_i, 2.0).min(grid.max_corner_m()),
        )
    };
    let (in_view, footprint, nearest) = view_of_box(&scene.camera, lo, hi);
    let optics = &scene.optics;
    let k_max = optics
        .extinction_per_density_m
        .iter()
        .copied()
        .fold(0.0, f64::max);
    let max_albedo = optics.albedo.iter().copied().fold(0.0, f64::max);
    let n_l = scene.wavelengths.len();
    let sky_l = match &scene.sky {
        SkySpec::Constant(v) => v.clone(),
        _ => vec![0.0; n_l],
    };
    let has_sky_light = match &scene.sky {
        SkySpec::Atmosphere => scene.atmosphere.is_some(),
        SkySpec::Constant(v) => v.iter().any(|&x| x > 0.0),
        SkySpec::None => false,
    };
    let has_ground_light = if scene.atmosphere.is_some() {
        // The `ground` product (ground and the air below) lights the cloud from below.
        !matches!(scene.sky, SkySpec::None)
    } else {
        scene
            .ground
            .as_ref()
            .is_some_and(|g| g.albedo.iter().any(|&a| a > 0.0))
    };
    let (mut sky_share, mut ground_share) = (None, None);
    let mut shares_measured = false;
    if scene.atmosphere.is_none() {
        let sun = scene
            .sun
            .collimated_irradiance
            .clone()
            .unwrap_or_else(|| vec![1.0; n_l]);
        let mu_s = scene.sun.direction().z.max(0.0);
        let sw = scene.lighting;
        let (mut s_max, mut g_max) = (0.0f64, 0.0f64);
        for l in 0..n_l {
            let sky = if sw.sky_light { sky_l[l] } else { 0.0 };
            let l_g = match (&scene.ground, sw.ground_light) {
                (Some(g), true) => {
                    g.albedo[l] / std::f64::consts::PI
                        * (sun[l] * mu_s + std::f64::consts::PI * sky_l[l])
                }
                _ => 0.0,
            };
            let total = sun[l] / (4.0 * std::f64::consts::PI) + 0.5 * sky + 0.5 * l_g;
            if total > 0.0 {
                s_max = s_max.max(0.5 * sky / total);
                g_max = g_max.max(0.5 * l_g / total);
            }
        }
        sky_share = Some(s_max);
        ground_share = Some(g_max);
    } else if let Some(lighting) = inputs.lighting {
        let (sky, ground) = measured_shares(lighting);
        sky_share = Some(sky);
        ground_share = Some(ground);
        shares_measured = true;
    }
    FrameFacts {
        reference: method == Method::Reference,
        cloud_empty: empty,
        cloud_in_view: in_view,
        sky_light_switch: scene.lighting.sky_light,
        ground_light_switch: scene.lighting.ground_light,
        multiple_scattering_switch: scene.lighting.multiple_scattering,
        has_sky_light,
        has_ground_light,
        sky_share,
        ground_share,
        shares_measured,
        max_optical_depth: k_max * grid.max_density() as f64 * (hi - lo).length(),
        max_albedo,
        voxel_size_m: h,
        grid_dims: grid.dims,
        ms_max_dim: match (method, scene.multiple_scattering_method) {
            (Method::Fast, skybake_render::CloudMsMethod::AllOrders) => {
                RenderSettings::for_quality(scene.quality, method)
                    .photons
                    .max_coarse_dim
            }
            _ => 0,
        },
        pixel_footprint_m: footprint,
        nearest_distance_m: nearest,
        budget: skybake_engine::plan::FRAME_MEASURED_ERROR,
        max_rel_error: inputs.max_rel_error,
        sphere: inputs.sphere,
        rgb: inputs.rgb.cloned(),
    }
}

/// The frame plan of a scene and its voxelised cloud (`plan::plan_frame` on [`frame_facts`]).
pub fn plan_frame(scene: &FrameScene, grid: &DensityGrid, method: Method) -> FramePlan {
    skybake_engine::plan::plan_frame(&frame_facts(scene, grid, method))
}

/// The plan as far as it is decided before anything runs: an RGB-only request's facts and the
/// wavelength rule's decision, with the budget it leaves ([`FrameRequest::rgb_decision`]).
pub(super) struct RgbDecision {
    pub(super) facts: Option<RgbFacts>,
    pub(super) plan: FramePlan,
}

impl RgbDecision {
    /// The wavelengths the frame runs at: the subset, or the scene's own.
    pub(super) fn wavelengths(&self, scene: &FrameScene) -> Result<Wavelengths> {
        match &self.plan.wavelengths {
            Some(s) => Wavelengths::new(s.internal_nm.clone()),
            None => Ok(scene.wavelengths.clone()),
        }
    }
}

/// A frame planned and ready to render ([`FrameRequest::planned`]).
pub(super) struct PlannedFrame {
    pub(super) plan: FramePlan,
    pub(super) scene: FrameScene,
    pub(super) grid: std::sync::Arc<DensityGrid>,
    pub(super) settings: RenderSettings,
    pub(super) lighting: skybake_render::Lighting,
    /// voxelize, plan, lighting, ms.
    pub(super) timing_ms: Vec<(String, f64)>,
}

/// What a frame runs with under its plan.
pub struct PlannedRun {
    /// The scene with the lighting switches the plan turns off (its JSON and cache key are the
    /// request's: the plan is a function of the request).
    pub scene: FrameScene,
    /// The coarsened grid, when the plan coarsens the cloud's detail.
    pub grid: Option<DensityGrid>,
    pub settings: RenderSettings,
}

/// Executes `plan`: multiple scattering of a thin cloud off, sky or ground light left out on the
/// cloud (settings hooks, the background unchanged; with an atmosphere the `sky` product at the
/// cloud or the `ground` product not computed), no per-voxel light for a cloud out of view,
/// no lighting products for the cloud when no cloud stage runs, the grid's block means at
/// the coarsened voxel size, and the multiple-scattering field at the coarsened cells per axis.
pub fn execute_plan(
    plan: &FramePlan,
    scene: &FrameScene,
    grid: &DensityGrid,
    method: Method,
) -> Result<PlannedRun> {
    use skybake_render::scene::SkySpec;
    let mut scene = scene.clone();
    let mut settings = RenderSettings::for_quality(scene.quality, method);
    let reason = |stage: FrameStage| {
        plan.left_out
            .iter()
            .find(|(s, _)| *s == stage)
            .map(|(_, r)| *r)
    };
    if let Some(FrameReason::ThinCloud { .. }) = reason(FrameStage::MultipleScattering) {
        scene.lighting.multiple_scattering = false;
    }
    let under_budget = |stage| matches!(reason(stage), Some(FrameReason::UnderBudget { .. }));
    settings.sky_light = !under_budget(FrameStage::SkyLight);
    settings.ground_light = !under_budget(FrameStage::GroundLight);
    // With an atmosphere the camera's background is its own `sky` product, so the products
    // that light only the cloud (`sky` at the cloud, `ground`) are not computed either.
    if matches!(scene.sky, SkySpec::Atmosphere) && scene.atmosphere.is_some() {
        scene.lighting.sky_light &= settings.sky_light;
        scene.lighting.ground_light &= settings.ground_light;
    }
    if let Some(r @ (FrameReason::CloudOutOfView | FrameReason::NoCloud)) =
        reason(FrameStage::CloudLight)
    {
        settings.cloud_in_view = r != FrameReason::CloudOutOfView;
        // Nothing lights a cloud nobody sees: the `sky` product at the cloud and the `ground`
        // product are not computed (the camera's background comes from its own `sky` product).
        if matches!(scene.sky, SkySpec::Atmosphere) && scene.atmosphere.is_some() {
            scene.lighting.sky_light = false;
            scene.lighting.ground_light = false;
        }
    }
    let k = plan.ms_grid_coarsening();
    if k > 1 {
        settings.photons.max_coarse_dim =
            (settings.photons.max_coarse_dim / k).max(skybake_engine::plan::MIN_MS_GRID_DIM);
        // The planner's cells, as its cost rule measured them (not made smaller again).
        settings.photons.transport_cells = false;
    }
    let factor = plan.coarsening();
    let grid = if factor > 1 {
        Some(grid.block_mean(factor)?)
    } else {
        None
    };
    Ok(PlannedRun {
        scene,
        grid,
        settings,
    })
}

/// Voxelises a frame's cloud within the renderer's limit, checked before the grid is allocated;
/// a grid too large names the scene field that sets its size.
fn voxelize_cloud(
    cloud: &skybake_physics::cloud::scene::CloudSection,
    loader: &dyn Fn(&str) -> Result<Vec<u8>>,
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<DensityGrid> {
    cloud
        .voxelize_unless(loader, skybake_render::MAX_RENDER_VOXELS, cancel)
        .map_err(|e| match e {
            Error::TooLarge {
                field,
                reason,
                limit,
            } if field == "dims" => Error::TooLarge {
                field: "cloud.voxel_size_m".into(),
                reason: format!("the grid at this voxel size: {reason}"),
                limit: format!("{limit} (use a larger voxel_size_m)"),
            },
            other => other,
        })
}

impl FrameRequest {
    /// The RGB-only facts and the wavelength rule's decision on a fresh budget (the rule runs
    /// first, so the planner repeats the same decision); no facts and no subset for a request
    /// that wants the spectral image or for the reference method.
    pub(super) fn rgb_decision(&self) -> Result<RgbDecision> {
        let reference = self.method == Method::Reference;
        let mut plan = FramePlan::start(skybake_engine::plan::frame_budget(
            reference,
            skybake_engine::plan::FRAME_MEASURED_ERROR,
            self.max_rel_error,
        ));
        if !self.rgb_only || reference {
            return Ok(RgbDecision { facts: None, plan });
        }
        let facts = skybake_render::rgb_only::rgb_facts(&self.scene)?;
        plan.decide_wavelengths(&facts);
        Ok(RgbDecision {
            facts: Some(facts),
            plan,
        })
    }

    /// The wavelengths the frame runs at and its artifact holds: the requested ones, or an
    /// RGB-only request's subset of them.
    pub fn internal_wavelengths(&self) -> Result<Wavelengths> {
        self.rgb_decision()?.wavelengths(&self.scene)
    }

    /// The frame's plan (voxelises the cloud to measure it; lights and renders nothing): what
    /// `skybake plan frame` and `POST /v1/plan` with `"product": "frame"` answer.
    ///
    /// With an atmosphere the light at the cloud is computed (the `sky` and `ground` products
    /// at the cloud, tables kept in `engine`) to measure the shares of sky and ground light.
    pub fn plan(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
    ) -> Result<FramePlan> {
        self.plan_unless(engine, loader, &|| false)
    }

    /// [`Self::plan`], stopped with [`Error::Cancelled`] once `cancel` returns true (asked
    /// before every automaton step, every z-slice voxelised and every row of the light's tables).
    pub fn plan_unless(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<FramePlan> {
        Ok(self
            .planned(engine, loader, self.rgb_decision()?, None, cancel)?
            .plan)
    }

    /// Voxelises (a sphere hierarchy at the level the plan chooses), measures, plans and
    /// executes the plan, and computes the light the frame runs with; `rgb` is the request's
    /// [`Self::rgb_decision`]. With `reuse`, a grid voxelised for an earlier frame of the same
    /// cloud (section, sphere level and file bytes) is taken as it is.
    pub(super) fn planned(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        rgb: RgbDecision,
        reuse: Option<&super::FrameReuse>,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<PlannedFrame> {
        let start = Instant::now();
        let reference = self.method == Method::Reference;
        // The wavelength rule ran first (an RGB-only request may run at a subset of its
        // wavelengths); the sphere-level rule runs before voxelising, the rest after.
        let RgbDecision {
            facts: rgb,
            plan: mut early,
        } = rgb;
        let sphere = if reference {
            None
        } else {
            sphere_facts(&self.scene)?
        };
        if let Some(s) = &sphere {
            early.decide_sphere_level(s);
        }
        let scene = match &early.wavelengths {
            Some(s) => self.scene.at_wavelengths(&s.internal_nm)?,
            None => self.scene.clone(),
        };
        let mut cloud = self.scene.cloud.clone();
        if let (Some(level), skybake_physics::cloud::scene::CloudSource::Spheres(source)) =
            (&early.sphere_level, &mut cloud.source)
        {
            // The hierarchy is built only to the level summed (see `sphere_facts`); level 0 of
            // a hierarchy of K ≥ 1 levels is another sphere than that of K = 0.
            if level.to_level >= 1 {
                source.params.levels = level.to_level;
                source.level = None;
            } else {
                source.level = Some(0);
            }
        }
        let grid = match reuse {
            Some(reuse) => {
                let key = super::reuse::grid_key(
                    self.scene_json
                        .get("cloud")
                        .unwrap_or(&serde_json::Value::Null),
                    &format!("{:?}", early.sphere_level),
                    &cloud.source.files(),
                    loader,
                )?;
                reuse.grid(&key, || voxelize_cloud(&cloud, loader, cancel))?
            }
            None => std::sync::Arc::new(voxelize_cloud(&cloud, loader, cancel)?),
        };
        let voxelize_ms = start.elapsed().as_secs_f64() * 1e3;
        skybake_render::check_grid(&grid)?;
        let start = Instant::now();
        let mut inputs = PlanInputs {
            max_rel_error: self.max_rel_error,
            lighting: None,
            sphere,
            rgb: rgb.as_ref(),
        };
        let facts = frame_facts_with(&scene, &grid, self.method, &inputs);
        // With an atmosphere the shares of sky and ground light are measured on the light the
        // scene computes anyway (kept for the frame when the plan does not change it).
        let measure = scene.atmosphere.is_some()
            && !reference
            && !facts.cloud_empty
            && facts.cloud_in_view
            && ((facts.sky_light_switch && facts.has_sky_light)
                || (facts.ground_light_switch && facts.has_ground_light));
        let mut lighting_ms = 0.0;
        let measured = if measure {
            let t = Instant::now();
            let l = match reuse {
                Some(reuse) => reuse.lighting(&scene, &grid, engine, cancel)?,
                None => lighting_for_unless(&scene, &grid, engine, cancel)?,
            };
            lighting_ms += t.elapsed().as_secs_f64() * 1e3;
            Some(l)
        } else {
            None
        };
        inputs.lighting = measured.as_ref();
        let plan = skybake_engine::plan::plan_frame_rest(
            &frame_facts_with(&scene, &grid, self.method, &inputs),
            early,
        );
        let run = execute_plan(&plan, &scene, &grid, self.method)?;
        let grid = match run.grid {
            Some(g) => std::sync::Arc::new(g),
            None => grid,
        };
        let plan_ms = start.elapsed().as_secs_f64() * 1e3 - lighting_ms;
        let lighting = match measured {
            // The light measured is the frame's, less what the plan left out.
            Some(l) if plan.coarsening() == 1 => {
                let (sky, ground) = (
                    run.scene.lighting.sky_light,
                    run.scene.lighting.ground_light,
                );
                match l.masked(sky, ground) {
                    Some(mut masked) => {
                        masked.notes.retain(|n| {
                            (sky || !n.starts_with("sky product at"))
                                && (ground || !n.starts_with("ground product at"))
                        });
                        masked
                    }
                    None => l,
                }
            }
            _ => {
                let t = Instant::now();
                let l = match reuse {
                    Some(reuse) => reuse.lighting(&run.scene, &grid, engine, cancel)?,
                    None => lighting_for_unless(&run.scene, &grid, engine, cancel)?,
                };
                lighting_ms += t.elapsed().as_secs_f64() * 1e3;
                l
            }
        };
        Ok(PlannedFrame {
            plan,
            scene: run.scene,
            grid,
            settings: run.settings,
            lighting,
            timing_ms: vec![
                ("voxelize".to_string(), voxelize_ms),
                ("plan".to_string(), plan_ms),
                ("lighting".to_string(), lighting_ms),
            ],
        })
    }
}
