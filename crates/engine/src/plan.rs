//! The planner (README.md "What the planner leaves out"): a product spec and its
//! resolved medium become the [`Stage`]s that will run and those left out, each with a typed
//! [`Reason`]. Pure and cheap (no tables are built), so `POST /v1/plan` and `skybake plan` answer
//! without computing. The engine **executes** the plan: a stage not in it does not run (no table
//! is built, no ray-march term is evaluated), a stage in it does; `tests/plan.rs` checks each rule
//! against the engine's work counters.
//!
//! Rules live here and nowhere else, the choice of multiple-scattering method among them (`fast`
//! below [`FAST_TWILIGHT_LIMIT_DEG`] runs the precise tables: the fast method's twilight error exceeds 10 % there) and night (below
//! [`darkest_twilight_deg`] nothing the observer sees is lit, and every scattering stage is left
//! out). Cost rules (work whose predicted contribution is under the error budget) are new arms of [`plan`], with a new [`Reason`] each.

use crate::spec::{CommonSpec, ProductKind};
use serde::ser::SerializeStruct;
use serde::{Serialize, Serializer};
use skybake_physics::atmosphere::multiple_precise::source_sun_zenith_limit_rad;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_physics::atmosphere::sun_transmittance::sun_disk_visible_fraction;
use skybake_physics::atmosphere::Medium;
use std::f64::consts::FRAC_PI_2;

/// A unit of work the engine can run for a product.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// The density-integral (transmittance) table T(r, μ) of the medium.
    DensityTable,
    /// Exact single scattering of direct sunlight by ray marching along every output ray.
    SingleScattering,
    /// Multiple scattering: the precise (orders of scattering) or fast (Hillaire 2020) table,
    /// as the spec's `method` says, evaluated along every output ray.
    MultipleScattering,
    /// Lambertian ground reflection of sun and sky at the end of rays that hit the ground.
    GroundBounce,
    /// `sun` product: transmittance and direct normal irradiance of the sun's disk at the observer.
    DirectSun,
    /// `sun` product: diffuse horizontal irradiance, the sky radiance integrated over the upper
    /// hemisphere.
    DiffuseIrradiance,
    /// The precise table's orders of scattering beyond those the error budget needs (the order
    /// series stops at the preset's tolerance unless the budget rule loosens it).
    HigherOrders,
}

impl Stage {
    /// One line on what the stage does.
    pub fn description(self) -> &'static str {
        match self {
            Stage::DensityTable => "transmittance: density-integral table T(r, mu)",
            Stage::SingleScattering => "single scattering: exact ray marching of direct sunlight",
            Stage::MultipleScattering => "multiple scattering along every output ray",
            Stage::GroundBounce => "ground bounce: Lambertian ground lit by sun and sky",
            Stage::DirectSun => "direct sun: transmittance and direct normal irradiance",
            Stage::DiffuseIrradiance => {
                "diffuse irradiance: sky radiance over the upper hemisphere"
            }
            Stage::HigherOrders => {
                "higher orders of scattering of the precise table, to the preset's tolerance"
            }
        }
    }
}

pub use crate::accuracy::FAST_TWILIGHT_LIMIT_DEG;

/// The multiple-scattering method a spec is computed with: `fast` below
/// [`FAST_TWILIGHT_LIMIT_DEG`] runs on the precise tables, where the fast method's measured error
/// exceeds 10 %; otherwise the requested one.
pub fn effective_method(spec: &CommonSpec) -> MsMethod {
    match spec.method {
        MsMethod::Fast if spec.sun.sun_elevation_deg < FAST_TWILIGHT_LIMIT_DEG => MsMethod::Precise,
        m => m,
    }
}

/// Why the multiple-scattering stage runs another method than the one requested.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Substitution {
    /// `fast` requested with the sun below [`FAST_TWILIGHT_LIMIT_DEG`]: the precise tables run.
    FastInTwilight {
        requested: MsMethod,
        sun_elevation_deg: f64,
        limit_deg: f64,
    },
}

impl Substitution {
    /// One line for people.
    pub fn detail(&self) -> String {
        match self {
            Substitution::FastInTwilight {
                sun_elevation_deg,
                limit_deg,
                ..
            } => format!(
                "multiple scattering: successive orders (precise) in place of the requested fast method: the sun at {sun_elevation_deg}° is below {limit_deg}°, where the fast method's measured error exceeds 10 % (up to 54 % low at −6°)"
            ),
        }
    }
}

/// Why a stage is left out.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Reason {
    /// `method=none`: single scattering only.
    MethodNone,
    /// The ground albedo is 0 at every requested wavelength: the ground reflects nothing.
    ZeroGroundAlbedo,
    /// The whole sun disk is below the observer's geometric horizon (which dips below the
    /// horizontal aloft), by the same test as the transmittance.
    SunBelowHorizon {
        sun_elevation_deg: f64,
        horizon_elevation_deg: f64,
    },
    /// Night: the sun is below [`darkest_twilight_deg`], so no air and no ground the observer can
    /// see is lit, directly or through the modelled multiple scattering; the stage's result is
    /// exactly zero.
    SunBelowDarkestTwilight {
        sun_elevation_deg: f64,
        darkest_twilight_deg: f64,
    },
    /// Cost rule: the precise order series stops once an order adds less than
    /// `tolerance` of the total (or its extrapolated tail's error is below it), `tolerance` being
    /// the budget's allowance instead of the preset's tighter `preset_tolerance`.
    OrdersUnderBudget {
        tolerance: f64,
        preset_tolerance: f64,
        budget: Budget,
    },
}

impl Reason {
    /// One line for people.
    pub fn detail(&self) -> String {
        match self {
            Reason::MethodNone => "method=none asks for single scattering only".into(),
            Reason::ZeroGroundAlbedo => "the ground albedo is 0 at every wavelength".into(),
            Reason::SunBelowHorizon {
                sun_elevation_deg,
                horizon_elevation_deg,
            } => format!(
                "the sun's disk (centre at {sun_elevation_deg}°) is wholly below the observer's horizon at {horizon_elevation_deg:.3}°"
            ),
            Reason::SunBelowDarkestTwilight {
                sun_elevation_deg,
                darkest_twilight_deg,
            } => format!(
                "night: with the sun at {sun_elevation_deg}°, below {darkest_twilight_deg:.2}°, no air or ground this observer sees is lit by the sun or by the modelled multiple scattering (moonlight, starlight and airglow are not modelled)"
            ),
            Reason::OrdersUnderBudget {
                tolerance,
                preset_tolerance,
                budget,
            } => format!(
                "orders adding less than {tolerance:.2e} of the total (the preset stops at {preset_tolerance:.0e}) are under the error budget: {:.2} % of {:.2} % (the smallest measured error of the products sharing the table at this preset) may be spent on left-out work",
                budget.allowance * 100.0,
                budget.relative_error * 100.0
            ),
        }
    }
}

/// The stages that run, in order, and those left out with their reasons.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    pub stages: Vec<Stage>,
    pub left_out: Vec<(Stage, Reason)>,
    /// The multiple-scattering method the [`Stage::MultipleScattering`] stage uses (the
    /// effective one, see [`effective_method`]).
    pub method: MsMethod,
    /// Set when `method` is not the requested one, with the reason.
    pub substitution: Option<Substitution>,
    /// The precise table's order-series tolerance when the error budget loosens it (cost rule
    /// [`Reason::OrdersUnderBudget`]); `None`: the preset's.
    pub precise_tolerance: Option<f64>,
    /// An RGB-only request (a sky or ground PNG) run at fewer wavelengths
    /// ([`rgb_wavelengths_rule`], set by `product::ProductRequest`).
    pub wavelengths: Option<WavelengthSubset>,
}

impl Plan {
    /// Whether `stage` runs.
    pub fn runs(&self, stage: Stage) -> bool {
        self.stages.contains(&stage)
    }

    /// The multiple-scattering method that runs (`None` when the stage is left out).
    pub fn ms_method(&self) -> MsMethod {
        if self.runs(Stage::MultipleScattering) {
            self.method
        } else {
            MsMethod::None
        }
    }

    /// The plan without `stage` (a stage forced out, for tests and diagnostics).
    pub fn without(mut self, stage: Stage) -> Self {
        self.stages.retain(|s| *s != stage);
        self
    }

    /// The plan without its cost rules: every stage a cost rule left out runs as the
    /// preset says, for measuring what the rules save and cost.
    pub fn without_cost_rules(mut self) -> Self {
        let (cost, kept): (Vec<_>, Vec<_>) = self
            .left_out
            .into_iter()
            .partition(|(_, r)| matches!(r, Reason::OrdersUnderBudget { .. }));
        self.left_out = kept;
        for (stage, _) in cost {
            if !self.stages.contains(&stage) {
                self.stages.push(stage);
            }
        }
        self.precise_tolerance = None;
        self
    }
}

#[derive(Serialize)]
struct StageView {
    stage: Stage,
    description: &'static str,
}

#[derive(Serialize)]
struct SubstitutionView {
    #[serde(flatten)]
    substitution: Substitution,
    detail: String,
}

#[derive(Serialize)]
struct LeftOutView {
    stage: Stage,
    #[serde(flatten)]
    reason: Reason,
    detail: String,
}

impl Serialize for Plan {
    /// `{"method", "stages": [{"stage", "description"}], "left_out": [{"stage", "reason", …,
    /// "detail"}]}`, with `"method_substitution": {"reason", "requested", …, "detail"}` when the
    /// method that runs is not the requested one.
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let stages: Vec<StageView> = self
            .stages
            .iter()
            .map(|&stage| StageView {
                stage,
                description: stage.description(),
            })
            .collect();
        let left_out: Vec<LeftOutView> = self
            .left_out
            .iter()
            .map(|&(stage, reason)| LeftOutView {
                stage,
                reason,
                detail: reason.detail(),
            })
            .collect();
        let mut st = s.serialize_struct("Plan", 4)?;
        st.serialize_field("method", &self.method)?;
        if let Some(substitution) = self.substitution {
            st.serialize_field(
                "method_substitution",
                &SubstitutionView {
                    substitution,
                    detail: substitution.detail(),
                },
            )?;
        }
        st.serialize_field("stages", &stages)?;
        st.serialize_field("left_out", &left_out)?;
        if let Some(w) = &self.wavelengths {
            st.serialize_field("wavelengths", &WavelengthsView::of(w))?;
        }
        st.end()
    }
}

/// A [`WavelengthSubset`] with its line for people.
#[derive(Serialize)]
struct WavelengthsView<'a> {
    #[serde(flatten)]
    subset: &'a WavelengthSubset,
    detail: String,
}

impl<'a> WavelengthsView<'a> {
    fn of(subset: &'a WavelengthSubset) -> Self {
        Self {
            subset,
            detail: subset.detail(),
        }
    }
}

/// The sun elevation, degrees, below which nothing an observer at `observer_altitude_m` can see
/// is lit, directly or through the modelled multiple scattering (`method`): the darkest modelled
/// twilight (below it the products are zero).
///
/// The air the observer sees reaches at most the geocentric angle α = acos(R/r_o) + acos(R/R_top)
/// from it (along the ray that grazes the ground). A point α towards the sun sees it at local
/// zenith angle θ_s − α. Air there is lit by the sun when its local zenith angle is below the
/// top's horizon, 90° + acos(R/R_top), plus the sun's angular radius (single scattering and the
/// ground); the precise tables hold a source up to [`source_sun_zenith_limit_rad`] (12° further).
/// Below the returned elevation every scattering term is exactly zero.
pub fn darkest_twilight_deg(m: &Medium, observer_altitude_m: f64, method: MsMethod) -> f64 {
    let (bottom, top) = (m.bottom_radius_m, m.top_radius_m);
    let observer = bottom + observer_altitude_m.max(0.0);
    let reach =
        (bottom / observer).clamp(-1.0, 1.0).acos() + (bottom / top).clamp(-1.0, 1.0).acos();
    let lit = FRAC_PI_2 + (bottom / top).clamp(-1.0, 1.0).acos() + m.sun_angular_radius_rad;
    let source = match method {
        MsMethod::None => lit,
        MsMethod::Fast | MsMethod::Precise => lit.max(source_sun_zenith_limit_rad(bottom, top)),
    };
    90.0 - (source + reach).to_degrees()
}

/// Plans `product` for `spec` on the resolved medium `m` (which carries the effective ground
/// albedo). Pure: no tables, no I/O.
pub fn plan(product: ProductKind, spec: &CommonSpec, m: &Medium) -> Plan {
    let method = effective_method(spec);
    let elevation = spec.sun.sun_elevation_deg;
    let darkest = darkest_twilight_deg(m, spec.observer_altitude_m, method);
    let night = (elevation < darkest).then_some(Reason::SunBelowDarkestTwilight {
        sun_elevation_deg: elevation,
        darkest_twilight_deg: darkest,
    });
    let substitution =
        (method != spec.method && night.is_none()).then_some(Substitution::FastInTwilight {
            requested: spec.method,
            sun_elevation_deg: elevation,
            limit_deg: FAST_TWILIGHT_LIMIT_DEG,
        });
    let mut p = Plan {
        stages: vec![Stage::DensityTable],
        left_out: Vec::new(),
        method,
        substitution,
        precise_tolerance: None,
        wavelengths: None,
    };
    let mut rule = |stage: Stage, left_out: Option<Reason>| match left_out {
        None => p.stages.push(stage),
        Some(reason) => p.left_out.push((stage, reason)),
    };
    rule(Stage::SingleScattering, night);
    rule(
        Stage::MultipleScattering,
        (spec.method == MsMethod::None)
            .then_some(Reason::MethodNone)
            .or(night),
    );
    rule(
        Stage::GroundBounce,
        m.ground_albedo
            .iter()
            .all(|&a| a == 0.0)
            .then_some(Reason::ZeroGroundAlbedo)
            .or(night),
    );
    if product == ProductKind::Sun {
        let visible =
            sun_disk_visible_fraction(m, spec.observer_altitude_m, elevation.to_radians());
        let horizon_elevation_deg = -skybake_physics::atmosphere::sky::horizon_dip_deg(
            m.bottom_radius_m,
            spec.observer_altitude_m,
        );
        rule(
            Stage::DirectSun,
            (visible == 0.0).then_some(Reason::SunBelowHorizon {
                sun_elevation_deg: elevation,
                horizon_elevation_deg,
            }),
        );
        rule(Stage::DiffuseIrradiance, night);
    }
    // The tolerance is set whatever the method, so every product of one medium and quality
    // shares one set of tables (the tolerance is part of their key).
    let orders = precise_orders_rule(spec);
    p.precise_tolerance = orders.map(|(tolerance, _)| tolerance);
    if p.ms_method() == MsMethod::Precise {
        match orders {
            Some((_, reason)) => p.left_out.push((Stage::HigherOrders, reason)),
            None => p.stages.push(Stage::HigherOrders),
        }
    }
    p
}

// ---------------------------------------------------------------------------------------------
// Cost rules: work whose predicted contribution falls under the error budget.

/// Share of a request's error budget the cost rules may spend on what they leave out or coarsen;
/// the rest stays with the method's own (measured) error, so the result keeps within the budget.
pub const BUDGET_SHARE: f64 = 0.25;

/// A request's error budget and what the cost rules spent of it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Budget {
    /// The relative error the request may have: its preset's measured error (a `max_rel_error`
    /// target picks the preset, whose measured error is at most the target).
    pub relative_error: f64,
    /// What the cost rules may spend: [`BUDGET_SHARE`] × `relative_error`, or with a user's
    /// target ([`Budget::for_target`]) what the target leaves over the method's measured error.
    pub allowance: f64,
    /// The predicted error of what they left out or coarsened.
    pub spent: f64,
}

impl Budget {
    pub fn new(relative_error: f64) -> Self {
        let e = if relative_error.is_finite() {
            relative_error.max(0.0)
        } else {
            0.0
        };
        Self {
            relative_error: e,
            allowance: BUDGET_SHARE * e,
            spent: 0.0,
        }
    }

    /// The budget of a request with a `max_rel_error` target: the result may be off by `target`,
    /// of which the method's own measured error `measured` is spent already, so the cost rules
    /// may spend the rest (`target − measured`, 0 when the target is tighter than the method).
    pub fn for_target(target: f64, measured: f64) -> Self {
        let clean = |v: f64| if v.is_finite() { v.max(0.0) } else { 0.0 };
        let (target, measured) = (clean(target), clean(measured));
        Self {
            relative_error: target,
            allowance: (target - measured).max(0.0),
            spent: 0.0,
        }
    }

    /// Spends `predicted` if it fits in what is left of the allowance.
    pub fn try_spend(&mut self, predicted: f64) -> bool {
        let fits =
            predicted.is_finite() && predicted >= 0.0 && self.spent + predicted <= self.allowance;
        if fits {
            self.spent += predicted;
        }
        fits
    }
}

/// The error budget of the precise table of `spec`'s medium at its quality: the smallest
/// measured error of the precise method at this preset over every product sharing the table
/// (sun, sky, ground, aerial) and every regime of the request's aerosol band (the table serves
/// every sun position and observer), plus the reference's own error against DISORT
/// (`accuracy::REFERENCE_ERROR`). `None` outside the measured aerosol bands, without report data,
/// and for the `reference` preset (the converged reference is never loosened).
pub fn table_budget(spec: &CommonSpec) -> Option<Budget> {
    use crate::accuracy;
    if spec.quality == skybake_physics::atmosphere::quality::Quality::Reference {
        return None;
    }
    let report = accuracy::committed()?;
    let aerosol = accuracy::aerosol_optical_depth_550(&spec.atmosphere)
        .and_then(accuracy::band_of_aerosol)?;
    let smallest = report
        .curves
        .iter()
        .filter(|c| c.method == MsMethod::Precise)
        .filter(|c| {
            report
                .regimes
                .iter()
                .any(|r| r.name == c.regime && r.aerosol_band == aerosol)
        })
        .filter_map(|c| c.points.iter().find(|p| p.quality == spec.quality))
        .map(|p| p.rel_max)
        .filter(|e| e.is_finite())
        .fold(None, |m: Option<f64>, e| Some(m.map_or(e, |m| m.min(e))))?;
    Some(Budget::new(smallest + accuracy::REFERENCE_ERROR))
}

/// Cost rule: the precise order series stops at the budget's allowance where that is looser than
/// the preset's tolerance. The series' own stopping test bounds what the left-out orders add
/// (the last order's share of the total, or the error of the extrapolated geometric tail), so
/// the predicted error spent is the tolerance itself.
fn precise_orders_rule(spec: &CommonSpec) -> Option<(f64, Reason)> {
    let preset_tolerance = skybake_physics::atmosphere::quality::settings_for(spec.quality)
        .1
        .tolerance;
    let mut budget = table_budget(spec)?;
    let tolerance = budget.allowance;
    (tolerance > preset_tolerance && budget.try_spend(tolerance)).then_some((
        tolerance,
        Reason::OrdersUnderBudget {
            tolerance,
            preset_tolerance,
            budget,
        },
    ))
}

// ---------------------------------------------------------------------------------------------
// Cloud frames: the same rules on the frame's stages. The renderer measures
// the scene (`render::product::frame_facts`: the cloud's box against the camera's view, the pixel
// footprint, the cloud's optical depth bound, the light's shares) and these pure rules decide;
// `render::product` executes the plan (a coarser grid, lighting switches, settings hooks).

/// The fast method's measured error on cloud frames, relative: the worst block NRMSE against
/// Mitsuba 3 and the path tracer at `standard` quality (albedo 0.9, 8.1 %; README "Cloud
/// frames", tests/render_validation.rs). The presets differ in photon counts and steps, not in
/// the model error that dominates this figure, so it is every preset's budget.
pub const FRAME_MEASURED_ERROR: f64 = 0.081;

/// Factor on the direction-averaged share of sky or ground light before it is compared with
/// the budget: on the validation cloud lit by the sun and a dark ground (albedo 0.02, no sky)
/// leaving the ground light out moved the frame's mean by 1.27× the averaged share (the camera
/// sees the cloud's lower side, where that light enters), so the rule counts twice the share.
pub const LIGHT_SHARE_SAFETY: f64 = 2.0;

/// [`LIGHT_SHARE_SAFETY`] for shares measured on an atmosphere's light
/// ([`FrameFacts::shares_measured`]): on the validation cloud under the earth's atmosphere
/// (sun 35°, ground albedo 0.02, 48×36 px) leaving the light from below out moved the cloud's
/// mean signal (frame less the frame without the cloud) by 27.6 %, 2.28× the averaged share of
/// 12.1 % (`skybake report --planner`): the air under the cloud lights the lower side the camera
/// sees. The rule counts three times the share.
pub const MEASURED_LIGHT_SHARE_SAFETY: f64 = 3.0;

/// Largest factor by which the planner coarsens a cloud's voxels.
pub const MAX_COARSENING: usize = 8;

/// Predicted error of halving a cloud's detail once (block means of 2³ voxels): the cloud-mean
/// change measured by `skybake report --planner` on the validation cloud seen from 30 km.
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

/// Factor on the proxies' predicted change of an RGB-only request run at fewer wavelengths
/// ([`RgbFacts`]): the proxies are the scene's light spectra, the pixels and directions mix them
/// (light scattered once and many times, along paths of every length), so the rule counts twice
/// the worst proxy's change. Measured (largest per-pixel or per-direction change of the RGB
/// relative to its mean channel, against the prediction): the fast sky at sun 30° 1.7 % of
/// 4.2 %, at sun 5° 4.8 % of 6.1 %, the ground 1.5 % of 4.2 %, the example cumulus frame under
/// the earth's atmosphere 0.5 % of 1.3 % (`tests/plan_rgb_only.rs`, `report/planner.md`); with
/// the proxies of the sunlit air alone, without the long view paths, the sky's largest change
/// exceeded the doubled prediction (5.1 % of 4.2 %).
pub const RGB_PROXY_SAFETY: f64 = 2.0;

pub use skybake_physics::spectrum::subsets::MIN_RGB_WAVELENGTHS;

/// A subset of the requested wavelengths and the change of the RGB image its proxies predict.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WavelengthCandidate {
    /// The wavelengths kept, nm, ascending (the first and last requested ones among them).
    pub internal_nm: Vec<f64>,
    /// The largest change of the proxies' linear sRGB, relative to their mean channel, when
    /// their spectra are known at `internal_nm` only (linear between them, as the frame's RGB
    /// planes are made) instead of at every requested wavelength.
    pub proxy_error: f64,
}

/// What the planner needs to know of an RGB-only frame request (one whose only output is the
/// RGB image, e.g. a PNG): its wavelengths and the subsets it could run at, fewest first.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RgbFacts {
    pub requested_nm: Vec<f64>,
    /// Subsets by backward elimination (each drops the interior wavelength whose loss changes
    /// the proxies least), fewest wavelengths first.
    pub candidates: Vec<WavelengthCandidate>,
}

/// An RGB-only request (a frame or a sky or ground PNG) run at fewer wavelengths than requested.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WavelengthSubset {
    pub rule: &'static str,
    pub requested_nm: Vec<f64>,
    /// The wavelengths the frame runs at (its spectral planes; the RGB planes interpolate
    /// linearly between them).
    pub internal_nm: Vec<f64>,
    pub left_out_nm: Vec<f64>,
    /// [`RGB_PROXY_SAFETY`] × the candidate's proxy error, spent from the budget.
    pub predicted_error: f64,
    /// The budget's allowance when the rule ran.
    pub allowance: f64,
}

impl WavelengthSubset {
    /// One line for people.
    pub fn detail(&self) -> String {
        format!(
            "RGB-only output: runs at {} of the {} requested wavelengths ({} nm); the RGB image is predicted to change by {:.2} % of its mean channel, within the budget's {:.2} %",
            self.internal_nm.len(),
            self.requested_nm.len(),
            self.internal_nm
                .iter()
                .map(|w| format!("{w}"))
                .collect::<Vec<_>>()
                .join(", "),
            self.predicted_error * 100.0,
            self.allowance * 100.0
        )
    }
}

/// Cost rule on an RGB-only frame: it runs at the fewest of the requested wavelengths whose
/// predicted RGB change ([`RGB_PROXY_SAFETY`] × the proxies') fits in what is left of the
/// budget. Spends from `budget`; runs first ([`plan_frame`] and the renderer decide the same).
pub fn rgb_wavelengths_rule(f: &RgbFacts, budget: &mut Budget) -> Option<WavelengthSubset> {
    let c = f
        .candidates
        .iter()
        .filter(|c| {
            c.internal_nm.len() >= MIN_RGB_WAVELENGTHS && c.internal_nm.len() < f.requested_nm.len()
        })
        .find(|c| budget.try_spend(RGB_PROXY_SAFETY * c.proxy_error))?;
    Some(WavelengthSubset {
        rule: "rgb_only",
        requested_nm: f.requested_nm.clone(),
        internal_nm: c.internal_nm.clone(),
        left_out_nm: f
            .requested_nm
            .iter()
            .copied()
            .filter(|w| !c.internal_nm.contains(w))
            .collect(),
        predicted_error: RGB_PROXY_SAFETY * c.proxy_error,
        allowance: budget.allowance,
    })
}

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
    let mut p = FramePlan {
        stages: Vec::new(),
        left_out: Vec::new(),
        coarsened: Vec::new(),
        sphere_level: None,
        wavelengths: None,
        budget: f.frame_budget(),
    };
    // First, as the request decides its wavelengths before anything runs, then the sphere
    // level, as the renderer runs it before voxelising (same budget, same decisions).
    if let (false, Some(rgb)) = (f.reference, &f.rgb) {
        p.wavelengths = rgb_wavelengths_rule(rgb, &mut p.budget);
    }
    if let (false, Some(sphere)) = (f.reference, &f.sphere) {
        p.sphere_level = sphere_level_rule(sphere, &mut p.budget);
    }
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
