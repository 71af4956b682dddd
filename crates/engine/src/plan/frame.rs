//! Cloud frames: the same rules on the frame's stages. The product core measures the scene (the
//! cloud's box against the camera's view, the pixel footprint, the cloud's optical depth bound, the
//! light's shares) into [`FrameFacts`]; these pure rules decide, and the product core executes the plan
//! (a coarser grid, lighting switches, settings hooks).

use super::*;

/// The fast method's measured error on cloud frames, relative: the worst block NRMSE against
/// Mitsuba 3 and the path tracer at `standard` quality (albedo 0.9, 8.1 %; README "Cloud
/// frames", tests/clouds/render_validation.rs). The presets differ in photon counts and steps, not in
/// the model error that dominates this figure, so it is every preset's budget.
pub const FRAME_MEASURED_ERROR: f64 = 0.081;

/// Factor on the direction-averaged share of sky or ground light before it is compared with
/// the budget: on the validation cloud lit by the sun and a dark ground (no sky) leaving the
/// ground light out moved the frame's mean by 1.24× the averaged share at albedo 0.02 and 1.37×
/// at 0.005 (the camera sees the cloud's lower side, where that light enters; draft, 16 photon
/// seeds, both runs tracing the same sun photons: 2.66–2.80 % and 0.76–0.81 %), so the rule
/// counts twice the share.
pub const LIGHT_SHARE_SAFETY: f64 = 2.0;

/// [`LIGHT_SHARE_SAFETY`] for shares measured on an atmosphere's light
/// ([`FrameFacts::shares_measured`]): on the validation cloud under the earth's atmosphere
/// (sun 35°, ground albedo 0.02, 48×36 px) leaving the light from below out moved the cloud's
/// mean signal (frame less the frame without the cloud) by 27.6 %, 2.28× the averaged share of
/// 12.1 % (`skybake-harness report --planner`): the air under the cloud lights the lower side the camera
/// sees. The rule counts three times the share.
pub const MEASURED_LIGHT_SHARE_SAFETY: f64 = 3.0;

/// Largest factor by which the planner coarsens a cloud's voxels.
pub const MAX_COARSENING: usize = 8;

/// Predicted error of halving a cloud's detail once (block means of 2³ voxels): the cloud-mean
/// change measured by `skybake-harness report --planner` on the validation cloud seen from 30 km.
pub const COARSENING_ERROR: f64 = 0.091;

/// Predicted error, per halving of the resolution, of running the all-order multiple-scattering
/// field (photon transport on a coarse copy of the grid) on coarser cells: the frame's per-pixel
/// RMS change relative to its mean, measured on the validation cloud (25 m voxels, field at most
/// 32 cells per axis, standard quality, 160×120 px) from 4 km: 3.3 %, 6.0 %, 11.7 % for one, two and
/// three halvings (bias +0.3, −0.1, −2.1 %), from 30 km (fov 12°): 2.3 %, 4.2 %, 8.1 %; the worst
/// per halving, 4 %, counts.
pub const MS_GRID_ERROR: f64 = 0.04;

/// Fewest cells along the multiple-scattering field's longest axis the planner leaves.
pub const MIN_MS_GRID_DIM: usize = 4;

/// Predicted error, per level left out, of summing a sphere hierarchy's spheres above the
/// leaves (Ostroushko et al.: each sphere in place of its five children), relative to the cloud's mean
/// signal. Measured on the example sphere cumulus (K = 6, 25 m voxels, 48×36 px, fov 12°) from
/// 30 km and 15 km: the cloud's mean moved by 7.2 % and 8.1 % one level up, 19.8 % and 24.9 %
/// two levels up, 37.5 % and 44.8 % three levels up (the frame's per-pixel RMS change is larger,
/// 55–90 % of the signal one level up: the shape changes); and the K = 9 cumulus of
/// report/planner.md two levels up from 30 km by 39.6 % with the fast method of the view cap and
/// the density-weighted field (23.7 % before it). The worst per level, 20 %, counts.
pub const SPHERE_LEVEL_ERROR: f64 = 0.20;

/// A unit of work of a cloud frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameStage {
    /// The fast method's per-voxel light: the sun's optical path to every voxel (Nishita et al. 1996, §3.2).
    CloudLight,
    /// Sky light on the cloud: sky elements through the cumulative lattice paths (Nishita et al. 1996, eq
    /// 7), the sky's photons in the multiple-scattering field.
    SkyLight,
    /// Ground light on the cloud: the upward light from below (the `ground` product, or the lit
    /// ground plane in vacuum), Nishita et al. 1996, §3.5.
    GroundLight,
    /// Multiple scattering in the cloud (the all-order photon field or the reference pattern).
    MultipleScattering,
    /// The cloud's voxel detail the per-voxel light and the march run at.
    CloudDetail,
    /// The reference method: the path tracer (all orders, all light).
    PathTracer,
}

impl FrameStage {
    /// One line on what the stage does.
    pub fn description(self) -> &'static str {
        match self {
            FrameStage::CloudLight => "cloud light: the sun's optical path per voxel",
            FrameStage::SkyLight => "sky light on the cloud: sky elements through lattice paths",
            FrameStage::GroundLight => "ground light on the cloud: upward light from below",
            FrameStage::MultipleScattering => "multiple scattering in the cloud",
            FrameStage::CloudDetail => "cloud detail: voxels of the per-voxel light and the march",
            FrameStage::PathTracer => "path tracer: all orders, all light",
        }
    }
}

/// Why a frame stage is left out.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum FrameReason {
    /// The cloud's grid holds no density.
    NoCloud,
    /// The cloud's box lies wholly outside the camera's view: no pixel's ray reaches it (its
    /// shadows and shafts of light are still computed).
    CloudOutOfView,
    /// The scene's `lighting` switch turns it off.
    SwitchedOff { switch: &'static str },
    /// There is no such light in the scene (no sky, no ground, albedo 0, a sun below the horizon).
    NoLight,
    /// Cost rule: the cloud is so thin that orders ≥ 2 are under the budget. With ω the largest
    /// single-scattering albedo and τ a bound on the optical path through the cloud (largest
    /// extinction × largest density × the diagonal of the occupied box), once-scattered light
    /// scatters again with probability at most q = ω(1 − e^(−τ)), so orders ≥ 2 add at most
    /// q/(1 − q) of the first order (a geometric series).
    ThinCloud {
        max_optical_depth: f64,
        max_albedo: f64,
        predicted_share: f64,
        budget: Budget,
    },
    /// Cost rule: the light's predicted share of all the light reaching the cloud (averaged
    /// over directions, times [`LIGHT_SHARE_SAFETY`] or [`MEASURED_LIGHT_SHARE_SAFETY`]) is
    /// under the budget.
    UnderBudget {
        predicted_share: f64,
        budget: Budget,
    },
}

impl FrameReason {
    /// One line for people.
    pub fn detail(&self) -> String {
        match self {
            FrameReason::NoCloud => "the cloud's grid holds no density".into(),
            FrameReason::CloudOutOfView => {
                "the cloud's box lies outside the camera's view (its shadows are kept)".into()
            }
            FrameReason::SwitchedOff { switch } => format!("lighting.{switch} is false"),
            FrameReason::NoLight => "no such light reaches the cloud in this scene".into(),
            FrameReason::ThinCloud {
                max_optical_depth,
                max_albedo,
                predicted_share,
                budget,
            } => format!(
                "optically thin cloud (optical path ≤ {max_optical_depth:.3}, albedo ≤ {max_albedo:.3}): orders ≥ 2 add at most {:.2} % of single scattering, under the budget's {:.2} %",
                predicted_share * 100.0,
                budget.allowance * 100.0
            ),
            FrameReason::UnderBudget {
                predicted_share,
                budget,
            } => format!(
                "predicted share {:.2} % of the light reaching the cloud, under the budget's {:.2} %",
                predicted_share * 100.0,
                budget.allowance * 100.0
            ),
        }
    }
}

/// A frame stage run at coarser detail than the scene asks, because the camera cannot resolve it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Coarsening {
    pub stage: FrameStage,
    pub rule: &'static str,
    /// `cloud_detail`: the scene's voxel edge, m; `multiple_scattering`: the field's largest
    /// cell edge at the preset's resolution, m.
    pub from_voxel_m: f64,
    /// The voxel edge the frame runs at (block means of `factor`³ voxels), or the field's
    /// largest cell edge at `1/factor` of the preset's cells per axis, m.
    pub to_voxel_m: f64,
    pub factor: usize,
    /// The smallest pixel footprint on the cloud (at its nearest distance), m.
    pub pixel_footprint_m: f64,
    pub nearest_distance_m: f64,
}

/// What the frame planner needs to know of a sphere-hierarchy cloud (source `spheres`) before
/// it is voxelised: its levels and the deepest one the camera resolves.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SphereFacts {
    /// The level the scene asks for (`level`, default the leaves K).
    pub requested_level: u32,
    /// Whether the scene fixed the level itself (then it is kept).
    pub level_fixed: bool,
    /// The deepest level whose mean sphere diameter is at least the pixel footprint
    /// (`SphereCloud::level_for_resolution`).
    pub resolved_level: u32,
    /// Mean sphere diameter at `resolved_level`, m.
    pub resolved_diameter_m: f64,
    /// The smallest pixel footprint on the spheres' box, m, and the distance it is taken at.
    pub pixel_footprint_m: f64,
    pub nearest_distance_m: f64,
}

/// A sphere-hierarchy cloud summed at a coarser level than the scene asks, because the camera
/// does not resolve the finer spheres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SphereLevel {
    pub rule: &'static str,
    pub from_level: u32,
    pub to_level: u32,
    /// Mean sphere diameter at `to_level`, m (at least the pixel footprint).
    pub mean_diameter_m: f64,
    pub pixel_footprint_m: f64,
    pub nearest_distance_m: f64,
    /// [`SPHERE_LEVEL_ERROR`] × levels left out, spent from the budget.
    pub predicted_error: f64,
}

/// Cost rule on a sphere-hierarchy cloud: the spheres are summed at the deepest level the camera
/// resolves instead of the leaves, when the scene did not fix the level, as many levels up as
/// the budget covers at [`SPHERE_LEVEL_ERROR`] each. Spends from `budget`. The renderer runs it
/// before voxelising ([`plan_frame`] runs it first, so it decides the same).
pub fn sphere_level_rule(s: &SphereFacts, budget: &mut Budget) -> Option<SphereLevel> {
    if s.level_fixed || s.resolved_level >= s.requested_level {
        return None;
    }
    let mut to = s.resolved_level;
    while to < s.requested_level {
        let predicted = SPHERE_LEVEL_ERROR * (s.requested_level - to) as f64;
        if budget.try_spend(predicted) {
            return Some(SphereLevel {
                rule: "pixel_footprint",
                from_level: s.requested_level,
                to_level: to,
                mean_diameter_m: if to == s.resolved_level {
                    s.resolved_diameter_m
                } else {
                    f64::NAN
                },
                pixel_footprint_m: s.pixel_footprint_m,
                nearest_distance_m: s.nearest_distance_m,
                predicted_error: predicted,
            });
        }
        to += 1;
    }
    None
}

/// What the frame planner needs to know of a scene (measured by the renderer).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameFacts {
    /// The reference method (the path tracer): no cost rules, it is the reference.
    pub reference: bool,
    /// The grid holds no density.
    pub cloud_empty: bool,
    /// Some pixel's ray may reach the cloud's occupied box (a conservative test: `false` only
    /// when the box is wholly outside one of the view's bounding planes).
    pub cloud_in_view: bool,
    /// The scene's switches.
    pub sky_light_switch: bool,
    pub ground_light_switch: bool,
    pub multiple_scattering_switch: bool,
    /// The scene has sky light / light from below at all.
    pub has_sky_light: bool,
    pub has_ground_light: bool,
    /// Predicted shares of all the light reaching the cloud, averaged over directions (`None`:
    /// not predicted, the stage runs).
    pub sky_share: Option<f64>,
    pub ground_share: Option<f64>,
    /// The shares were measured on an atmosphere's computed light (then
    /// [`MEASURED_LIGHT_SHARE_SAFETY`] applies) rather than predicted from a vacuum scene's
    /// given light ([`LIGHT_SHARE_SAFETY`]).
    pub shares_measured: bool,
    /// Bound on the optical path through the cloud (any wavelength, any line).
    pub max_optical_depth: f64,
    /// Largest single-scattering albedo of the cloud.
    pub max_albedo: f64,
    pub voxel_size_m: f64,
    /// The grid's voxels per axis.
    pub grid_dims: [usize; 3],
    /// Largest cells per axis of the all-order multiple-scattering field at the scene's quality
    /// (`PhotonSettings::max_coarse_dim`); 0 when the field is not used (the reference method,
    /// the reference pattern).
    pub ms_max_dim: usize,
    /// The smallest pixel footprint at the cloud's nearest distance, m (0 with the camera in it).
    pub pixel_footprint_m: f64,
    pub nearest_distance_m: f64,
    /// The method's measured relative error ([`FRAME_MEASURED_ERROR`]): the budget without a
    /// target.
    pub budget: f64,
    /// The request's `max_rel_error` target, if any: the budget is then the target, and the
    /// cost rules may spend what it leaves over `budget` ([`Budget::for_target`]).
    pub max_rel_error: Option<f64>,
    /// A sphere-hierarchy cloud's levels (`None` for other sources).
    pub sphere: Option<SphereFacts>,
    /// An RGB-only request's wavelengths and their subsets (`None`: the spectral image is
    /// wanted, every requested wavelength runs).
    pub rgb: Option<RgbFacts>,
}

impl FrameFacts {
    /// The frame's budget ([`frame_budget`]).
    pub fn frame_budget(&self) -> Budget {
        frame_budget(self.reference, self.budget, self.max_rel_error)
    }
}

/// A frame's budget: none for the reference method, the target's for a request with
/// `max_rel_error` ([`Budget::for_target`]), else [`BUDGET_SHARE`] of the method's measured
/// error `measured`.
pub fn frame_budget(reference: bool, measured: f64, max_rel_error: Option<f64>) -> Budget {
    match (reference, max_rel_error) {
        (true, _) => Budget::new(0.0),
        (false, Some(target)) => Budget::for_target(target, measured),
        (false, None) => Budget::new(measured),
    }
}

/// The plan of a cloud frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePlan {
    pub stages: Vec<FrameStage>,
    pub left_out: Vec<(FrameStage, FrameReason)>,
    pub coarsened: Vec<Coarsening>,
    /// A sphere-hierarchy cloud summed at a coarser level ([`sphere_level_rule`]).
    pub sphere_level: Option<SphereLevel>,
    /// An RGB-only frame run at fewer wavelengths ([`rgb_wavelengths_rule`]).
    pub wavelengths: Option<WavelengthSubset>,
    pub budget: Budget,
}

impl FramePlan {
    pub fn runs(&self, stage: FrameStage) -> bool {
        self.stages.contains(&stage)
    }

    /// The voxel coarsening factor (1: the scene's voxels).
    pub fn coarsening(&self) -> usize {
        self.coarsened
            .iter()
            .find(|c| c.stage == FrameStage::CloudDetail)
            .map_or(1, |c| c.factor)
    }

    /// The factor by which the multiple-scattering field's cells per axis are divided (1: the
    /// preset's).
    pub fn ms_grid_coarsening(&self) -> usize {
        self.coarsened
            .iter()
            .find(|c| c.stage == FrameStage::MultipleScattering)
            .map_or(1, |c| c.factor)
    }

    /// Whether a stage was left out by a cost rule (budget or resolution), not by the scene.
    fn by_cost_rule(reason: &FrameReason) -> bool {
        matches!(
            reason,
            FrameReason::ThinCloud { .. }
                | FrameReason::UnderBudget { .. }
                | FrameReason::CloudOutOfView
        )
    }

    /// The plan without its cost rules (every stage the scene has runs at the scene's detail),
    /// for measuring what the rules save and cost.
    pub fn without_cost_rules(mut self) -> Self {
        let (cost, kept): (Vec<_>, Vec<_>) = self
            .left_out
            .into_iter()
            .partition(|(_, r)| Self::by_cost_rule(r));
        self.left_out = kept;
        for (stage, _) in cost {
            if !self.stages.contains(&stage) {
                self.stages.push(stage);
            }
        }
        self.coarsened.clear();
        self.sphere_level = None;
        self.wavelengths = None;
        self.budget.spent = 0.0;
        self
    }

    /// The plan without the cost rule that left out or coarsened `stage` (the others kept).
    pub fn without_rule_for(mut self, stage: FrameStage) -> Self {
        if let Some(pos) = self
            .left_out
            .iter()
            .position(|(s, r)| *s == stage && Self::by_cost_rule(r))
        {
            self.left_out.remove(pos);
            self.stages.push(stage);
        }
        self.coarsened.retain(|c| c.stage != stage);
        if stage == FrameStage::CloudDetail {
            self.sphere_level = None;
        }
        self
    }
}

#[derive(Serialize)]
struct FrameStageView {
    stage: FrameStage,
    description: &'static str,
}

#[derive(Serialize)]
struct FrameLeftOutView {
    stage: FrameStage,
    #[serde(flatten)]
    reason: FrameReason,
    detail: String,
}

impl Serialize for FramePlan {
    /// `{"stages": [{"stage", "description"}], "left_out": [{"stage", "reason", …, "detail"}],
    /// "coarsened": [{"stage", "rule", "from_voxel_m", "to_voxel_m", …}], "budget": {…}}`.
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let stages: Vec<FrameStageView> = self
            .stages
            .iter()
            .map(|&stage| FrameStageView {
                stage,
                description: stage.description(),
            })
            .collect();
        let left_out: Vec<FrameLeftOutView> = self
            .left_out
            .iter()
            .map(|&(stage, reason)| FrameLeftOutView {
                stage,
                reason,
                detail: reason.detail(),
            })
            .collect();
        let mut st = s.serialize_struct("FramePlan", 5)?;
        st.serialize_field("stages", &stages)?;
        st.serialize_field("left_out", &left_out)?;
        st.serialize_field("coarsened", &self.coarsened)?;
        if let Some(level) = &self.sphere_level {
            st.serialize_field("sphere_level", level)?;
        }
        if let Some(w) = &self.wavelengths {
            st.serialize_field("wavelengths", &WavelengthsView::of(w))?;
        }
        st.serialize_field("budget", &self.budget)?;
        st.end()
    }
}

/// Plans a cloud frame from its measured facts. Pure.
///
/// Structural rules: no cloud stages without a cloud (an empty grid) or with the cloud outside
/// the view; no sky or ground light on the cloud when the scene switches it off or has none; no
/// multiple scattering when switched off or at albedo 0. Cost rules (the fast method only; the
/// path tracer is the reference): multiple scattering left out for an optically thin cloud
/// ([`FrameReason::ThinCloud`]), ground and sky light left out when their predicted share is
/// under the budget, each spending its prediction from [`Budget::allowance`]; and the voxels
/// coarsened by a power of two (at most [`MAX_COARSENING`]) to the largest size not above the
/// smallest pixel footprint on the cloud (a pixel's single ray cannot resolve finer detail),
/// the multiple-scattering field's cells coarsened likewise (`ms_grid_rule`), a sphere
/// hierarchy summed at the deepest level the camera resolves ([`sphere_level_rule`], decided
/// before voxelising) and an RGB-only request run at fewer wavelengths
/// ([`rgb_wavelengths_rule`], decided first), each where the budget covers its measured cost. A
/// `max_rel_error` target sets the budget ([`FrameFacts::frame_budget`]).
pub fn plan_frame(f: &FrameFacts) -> FramePlan {
    let mut p = FramePlan::start(f.frame_budget());
    if !f.reference {
        if let Some(rgb) = &f.rgb {
            p.decide_wavelengths(rgb);
        }
        if let Some(sphere) = &f.sphere {
            p.decide_sphere_level(sphere);
        }
    }
    plan_frame_rest(f, p)
}

impl FramePlan {
    /// A plan with nothing decided yet, spending from `budget`.
    pub fn start(budget: Budget) -> Self {
        FramePlan {
            stages: Vec::new(),
            left_out: Vec::new(),
            coarsened: Vec::new(),
            sphere_level: None,
            wavelengths: None,
            budget,
        }
    }

    /// The first decision, as a request decides its wavelengths before anything runs: an
    /// RGB-only request's wavelength subset ([`rgb_wavelengths_rule`]).
    pub fn decide_wavelengths(&mut self, rgb: &RgbFacts) {
        self.wavelengths = rgb_wavelengths_rule(rgb, &mut self.budget);
    }

    /// The second, before voxelising: a sphere hierarchy's level ([`sphere_level_rule`]).
    pub fn decide_sphere_level(&mut self, sphere: &SphereFacts) {
        self.sphere_level = sphere_level_rule(sphere, &mut self.budget);
    }
}

/// The frame rules after voxelising, on the measured facts, continuing `p` (whose wavelengths
/// and sphere level are decided, [`FramePlan::decide_wavelengths`] and
/// [`FramePlan::decide_sphere_level`], and whose budget they spent). Each rule runs once per
/// request: the product core decides the first two before it voxelises and this one after.
pub fn plan_frame_rest(f: &FrameFacts, mut p: FramePlan) -> FramePlan {
    let rule = |p: &mut FramePlan, stage: FrameStage, left_out: Option<FrameReason>| match left_out
    {
        None => p.stages.push(stage),
        Some(reason) => p.left_out.push((stage, reason)),
    };
    let no_cloud = if f.cloud_empty {
        Some(FrameReason::NoCloud)
    } else if !f.cloud_in_view && !f.reference {
        Some(FrameReason::CloudOutOfView)
    } else {
        None
    };
    if f.reference {
        rule(&mut p, FrameStage::PathTracer, None);
    } else {
        rule(&mut p, FrameStage::CloudLight, no_cloud);
    }
    let light = |switch_on: bool, name: &'static str, has: bool| {
        no_cloud
            .or((!switch_on).then_some(FrameReason::SwitchedOff { switch: name }))
            .or((!has).then_some(FrameReason::NoLight))
    };
    let safety = if f.shares_measured {
        MEASURED_LIGHT_SHARE_SAFETY
    } else {
        LIGHT_SHARE_SAFETY
    };
    let mut ground = light(f.ground_light_switch, "ground_light", f.has_ground_light);
    if ground.is_none() && !f.reference {
        if let Some(share) = f.ground_share.map(|s| s * safety) {
            if p.budget.try_spend(share) {
                ground = Some(FrameReason::UnderBudget {
                    predicted_share: share,
                    budget: p.budget,
                });
            }
        }
    }
    let mut sky = light(f.sky_light_switch, "sky_light", f.has_sky_light);
    if sky.is_none() && !f.reference {
        if let Some(share) = f.sky_share.map(|s| s * safety) {
            if p.budget.try_spend(share) {
                sky = Some(FrameReason::UnderBudget {
                    predicted_share: share,
                    budget: p.budget,
                });
            }
        }
    }
    rule(&mut p, FrameStage::SkyLight, sky);
    rule(&mut p, FrameStage::GroundLight, ground);
    let mut ms = no_cloud
        .or(
            (!f.multiple_scattering_switch).then_some(FrameReason::SwitchedOff {
                switch: "multiple_scattering",
            }),
        )
        .or((f.max_albedo <= 0.0).then_some(FrameReason::NoLight));
    if ms.is_none() && !f.reference {
        let tau = f.max_optical_depth.max(0.0);
        let q = f.max_albedo.clamp(0.0, 1.0) * -(-tau).exp_m1();
        let share = if q < 1.0 {
            q / (1.0 - q)
        } else {
            f64::INFINITY
        };
        if p.budget.try_spend(share) {
            ms = Some(FrameReason::ThinCloud {
                max_optical_depth: tau,
                max_albedo: f.max_albedo,
                predicted_share: share,
                budget: p.budget,
            });
        }
    }
    if !f.reference {
        rule(&mut p, FrameStage::MultipleScattering, ms);
    }
    if no_cloud.is_none() && !f.reference {
        p.stages.push(FrameStage::CloudDetail);
        // Each halving of the detail is predicted to cost what it cost where it was measured
        // (`report/planner.md`: +9.1 % of the cloud's mean at 50 → 100 m): it runs only when the
        // budget's allowance covers that, which no fast preset's does today.
        let edge = |k: usize| f.voxel_size_m * k as f64;
        coarsen_to_footprint(
            f,
            &mut p,
            FrameStage::CloudDetail,
            COARSENING_ERROR,
            |k| edge(k) <= f.pixel_footprint_m,
            edge,
        );
        if p.runs(FrameStage::MultipleScattering) && f.ms_max_dim > 0 {
            ms_grid_rule(f, &mut p);
        }
    }
    p
}

/// Cost rule on the all-order multiple-scattering field: its cells per axis are divided by a
/// power of two (at most [`MAX_COARSENING`], keeping [`MIN_MS_GRID_DIM`]) while its largest cell
/// stays within the smallest pixel footprint on the cloud, where the budget covers
/// [`MS_GRID_ERROR`] per halving. Runs after the voxel rule, on the grid it leaves.
fn ms_grid_rule(f: &FrameFacts, p: &mut FramePlan) {
    let vf = p.coarsening();
    let dims: [usize; 3] = std::array::from_fn(|a| f.grid_dims[a].div_ceil(vf).max(1));
    // The field's cells are blocks of whole voxels (`render::multiple::Coarse`).
    let cell = |max_dim: usize| {
        let blocks = dims
            .iter()
            .map(|&d| d.div_ceil(max_dim.max(1)))
            .max()
            .unwrap_or(1);
        blocks as f64 * f.voxel_size_m * vf as f64
    };
    let edge = |k: usize| cell(f.ms_max_dim / k);
    coarsen_to_footprint(
        f,
        p,
        FrameStage::MultipleScattering,
        MS_GRID_ERROR,
        |k| f.ms_max_dim / k >= MIN_MS_GRID_DIM && edge(k) <= f.pixel_footprint_m,
        edge,
    );
}

/// Coarsens `stage` by the largest power of two `k` ≤ [`MAX_COARSENING`] that `fits` (its edge
/// within the pixel footprint), halved until the budget covers `per_halving` × log₂ k; records
/// the coarsening with the edges `edge(1)` → `edge(k)`.
fn coarsen_to_footprint(
    f: &FrameFacts,
    p: &mut FramePlan,
    stage: FrameStage,
    per_halving: f64,
    fits: impl Fn(usize) -> bool,
    edge: impl Fn(usize) -> f64,
) {
    let mut k = 1;
    while k * 2 <= MAX_COARSENING && fits(k * 2) {
        k *= 2;
    }
    while k > 1 && !p.budget.try_spend(per_halving * k.ilog2() as f64) {
        k /= 2;
    }
    if k > 1 {
        p.coarsened.push(Coarsening {
            stage,
            rule: "pixel_footprint",
            from_voxel_m: edge(1),
            to_voxel_m: edge(k),
            factor: k,
            pixel_footprint_m: f.pixel_footprint_m,
            nearest_distance_m: f.nearest_distance_m,
        });
    }
}
