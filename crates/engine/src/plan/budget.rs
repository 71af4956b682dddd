//! Cost rules: work whose predicted contribution falls under the error budget (a share of the
//! request's measured error, or of what a `max_rel_error` target leaves over it).

use super::*;

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
///
/// `high` keeps its preset's tolerance: the extrapolated tail takes the angular shape of the last
/// order computed, still peaked towards the sun in hazy air, and that error is several times the
/// tolerance that stops the series (against DISORT with aerosol at optical depth 0.4, sun at 75°,
/// the anti-sun low sky: 1.21 % with the series stopped at the budget, 0.91 % at the preset's
/// 10⁻⁴; docs/validation.md).
pub(super) fn precise_orders_rule(spec: &CommonSpec) -> Option<(f64, Reason)> {
    if spec.quality == skybake_physics::atmosphere::quality::Quality::High {
        return None;
    }
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
