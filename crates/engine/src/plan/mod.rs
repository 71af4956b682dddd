//! The planner (README.md "What the planner leaves out"): a product spec and its
//! resolved medium become the [`Stage`]s that will run and those left out, each with a typed
//! [`Reason`]. Pure and cheap (no tables are built), so `POST /v1/plan` and `skybake plan` answer
//! without computing. The engine **executes** the plan: a stage not in it does not run (no table
//! is built, no ray-march term is evaluated), a stage in it does; `tests/atmosphere/plan.rs` checks each rule
//! against the engine's work counters.
//!
//! Rules live here and nowhere else, the choice of multiple-scattering method among them (`fast`
//! is retired and runs the precise tables at [`fast_preset`]: its measured error exceeds 5 % against
//! DISORT with aerosol and in twilight) and night (below
//! [`darkest_twilight_deg`] nothing the observer sees is lit, and every scattering stage is left
//! out). Cost rules (work whose predicted contribution is under the error budget) are new arms of [`plan`], with a new [`Reason`] each.

use crate::spec::{CommonSpec, ProductKind, Quality};
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
    /// Multiple scattering: the precise (orders of scattering) table, evaluated along every
    /// output ray (the fast table of Hillaire 2020 only in the harness's comparison rows).
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

pub use crate::accuracy::{fast_preset, FAST_TWILIGHT_LIMIT_DEG};

/// The multiple-scattering method a spec is computed with: the requested one, except `fast`,
/// which is retired (its measured error exceeds 5 % against DISORT with aerosol and in twilight,
/// `docs/validation.md`): a `fast` request runs on the precise tables at [`fast_preset`]
/// ([`Substitution::FastRetired`]).
pub fn effective_method(spec: &CommonSpec) -> MsMethod {
    match spec.method {
        MsMethod::Fast => MsMethod::Precise,
        m => m,
    }
}

/// The quality preset a spec is computed at: [`fast_preset`] for a `fast` request, otherwise the
/// requested one.
pub fn effective_quality(spec: &CommonSpec) -> Quality {
    match spec.method {
        MsMethod::Fast => fast_preset(&spec.atmosphere),
        _ => spec.quality,
    }
}

/// The spec as it is computed: [`effective_method`] and [`effective_quality`].
pub fn effective_spec(spec: &CommonSpec) -> CommonSpec {
    CommonSpec {
        method: effective_method(spec),
        quality: effective_quality(spec),
        ..spec.clone()
    }
}

/// Why the multiple-scattering stage runs another method than the one requested.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Substitution {
    /// `fast` requested: the fast method (Hillaire 2020) is retired and the precise tables run at
    /// the coarse preset `quality` ([`fast_preset`]).
    FastRetired {
        requested: MsMethod,
        quality: Quality,
    },
}

impl Substitution {
    /// One line for people.
    pub fn detail(&self) -> String {
        match self {
            Substitution::FastRetired { quality, .. } => format!(
                "multiple scattering: successive orders (precise) at the {} preset in place of the requested fast method, which is retired: its measured error exceeds 5 % against DISORT with aerosol ({}) and in twilight against the spherical Monte Carlo (up to 54 % low at −6°); the precise tables at {} measure {}",
                crate::accuracy::preset_name(*quality),
                crate::accuracy::FAST_MEASURED_ERROR,
                crate::accuracy::preset_name(*quality),
                crate::accuracy::fast_preset_evidence(*quality)
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
    /// The quality preset the stages run at (the effective one, see [`effective_quality`]).
    pub quality: Quality,
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

    /// The spec the plan's stages run with: `spec` with the plan's method and quality.
    pub fn spec_for(&self, spec: &CommonSpec) -> CommonSpec {
        CommonSpec {
            method: self.method,
            quality: self.quality,
            ..spec.clone()
        }
    }

    /// The plan with the paper's fast method (Hillaire 2020, isotropic orders ≥ 2) at `quality`
    /// in place of the precise tables: for the measurement harness's comparison rows only (no
    /// product request is planned with it; `method=fast` runs the precise tables).
    pub fn with_paper_fast_method(mut self, quality: Quality) -> Self {
        self.method = MsMethod::Fast;
        self.quality = quality;
        self.substitution = None;
        self.stages.retain(|s| *s != Stage::HigherOrders);
        self.left_out.retain(|(s, _)| *s != Stage::HigherOrders);
        self
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
        let mut st = s.serialize_struct("Plan", 6)?;
        st.serialize_field("method", &self.method)?;
        st.serialize_field("quality", &self.quality)?;
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
    let requested = spec;
    let spec = &effective_spec(requested);
    let method = spec.method;
    let elevation = spec.sun.sun_elevation_deg;
    let darkest = darkest_twilight_deg(m, spec.observer_altitude_m, method);
    let night = (elevation < darkest).then_some(Reason::SunBelowDarkestTwilight {
        sun_elevation_deg: elevation,
        darkest_twilight_deg: darkest,
    });
    let substitution =
        (method != requested.method && night.is_none()).then_some(Substitution::FastRetired {
            requested: requested.method,
            quality: spec.quality,
        });
    let mut p = Plan {
        stages: vec![Stage::DensityTable],
        left_out: Vec::new(),
        method,
        quality: spec.quality,
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

mod budget;
use budget::precise_orders_rule;
mod frame;
mod wavelengths;

pub use budget::*;
pub use frame::*;
pub use wavelengths::*;
