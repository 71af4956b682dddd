//! The cost estimate of a product request: cells × wavelengths × expected
//! orders of scattering, from the plan and the resolved medium, so the service can refuse a
//! request that would hold a compute slot for minutes (an inline atmosphere with aerosol optical
//! depth 100 took 90 s of CPU for one `sun` product) before any table is built.
//!
//! Cells are those of the multiple-scattering table the plan's method builds (precise: r × μ_s ×
//! μ × φ; fast: r × μ_s × directions; none: no table) plus the output cells (pixels, probes, or the
//! sun product's hemisphere directions). The expected number of orders of the precise method is
//! that of a geometric series whose ratio is the chance that scattered light scatters again,
//! `q = ω τ / (1 + τ)` (ω the column single-scattering albedo, τ the vertical optical depth; the
//! escape probability of diffuse light from a slab, 1/(1 + τ), is the two-stream estimate of
//! Bohren & Clothiaux 2006 §5.2), summed until the next order adds less than the table's
//! tolerance: `n = ln(tol) / ln(q)`, at least 1 and at most the table's `max_orders`. The worst
//! wavelength decides. The estimate assumes cold tables (a warm table costs nothing to reuse),
//! so it is an upper bound on the first request for a medium.

use crate::ProductRequest;
use crate::Result;
use serde::Serialize;
use skybake_engine::spec::ProductSpec;
use skybake_physics::atmosphere::irradiance::{SUN_PRODUCT_N_MU, SUN_PRODUCT_N_PHI};
use skybake_physics::atmosphere::medium::{MIE, RAYLEIGH};
use skybake_physics::atmosphere::multiple_precise::{
    table_radius_and_azimuth_nodes, table_zenith_nodes,
};
use skybake_physics::atmosphere::quality::settings_for;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_physics::atmosphere::Medium;

/// The cost estimate of one request, in cell-wavelength-order units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Cost {
    /// Cells of the multiple-scattering table the plan builds (0 for `method=none`).
    pub table_cells: u64,
    /// Output cells: pixels and probes, or the sun product's hemisphere directions.
    pub output_cells: u64,
    pub wavelengths: u64,
    /// Expected orders of scattering of the precise table (1 for the other methods).
    pub expected_orders: u64,
    /// `(table_cells × expected_orders + output_cells) × wavelengths`.
    pub units: u64,
}

/// Expected orders of scattering of the precise method for `m` (see the module documentation).
pub fn expected_orders(m: &Medium, tolerance: f64, max_orders: usize) -> u64 {
    let mut worst = 1.0f64;
    for i in 0..m.len() {
        let tau_parts = m.vertical_optical_depth(i);
        let tau: f64 = tau_parts.iter().sum();
        if !(tau.is_finite() && tau > 0.0) {
            continue;
        }
        let column = |k: usize| {
            let ext = m.extinction_per_m[k][i];
            if ext > 0.0 {
                tau_parts[k] / ext
            } else {
                0.0
            }
        };
        let scattering = m.rayleigh_scattering_per_m[i] * column(RAYLEIGH)
            + m.mie_scattering_per_m[i] * column(MIE);
        let omega = (scattering / tau).clamp(0.0, 1.0);
        let q = omega * tau / (1.0 + tau);
        if q <= 0.0 {
            continue;
        }
        let n = if q >= 1.0 {
            max_orders as f64
        } else {
            tolerance.ln() / q.ln()
        };
        worst = worst.max(n.ceil());
    }
    (worst as u64).clamp(1, max_orders.max(1) as u64)
}

/// The cost estimate of `req` (plans it and resolves its medium; builds no table).
pub fn estimate(req: &ProductRequest) -> Result<Cost> {
    let spec = &req.spec;
    let m = Medium::new(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo)?;
    estimate_in(req, &m)
}

/// The medium key of `req`: requests with equal keys resolve to the same [`Medium`].
pub fn medium_key(req: &ProductRequest) -> String {
    let spec = &req.spec;
    serde_json::to_string(&(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo))
        .unwrap_or_default()
}

/// [`estimate`] with the request's medium already resolved (`m` must be the medium of
/// [`medium_key`]`(req)`).
pub fn estimate_in(req: &ProductRequest, m: &Medium) -> Result<Cost> {
    let spec = &req.spec;
    let plan = skybake_engine::plan::plan(req.kind(), spec, m);
    // The preset that runs (a retired `fast` request runs the precise tables at its preset).
    let (fast, precise) = settings_for(plan.quality);
    let (table_cells, expected_orders) = match plan.ms_method() {
        MsMethod::Precise => (
            {
                // The table's own grid: more radius nodes in thick haze, more azimuth nodes for a
                // strongly forward aerosol, more radius and zenith nodes for a dense one.
                let (n_r, n_phi) = table_radius_and_azimuth_nodes(&precise, m);
                let (n_mu_s, n_mu) = table_zenith_nodes(&precise, m);
                (n_r * n_mu_s * n_mu * n_phi) as u64
            },
            expected_orders(
                m,
                plan.precise_tolerance.unwrap_or(precise.tolerance),
                precise.max_orders,
            ),
        ),
        MsMethod::Fast => (
            (fast.n_r * fast.n_mu_s * fast.directions_mu * fast.directions_phi) as u64,
            1,
        ),
        MsMethod::None => (0, 1),
    };
    let output_cells = match &req.product {
        ProductSpec::Sun => (SUN_PRODUCT_N_MU * SUN_PRODUCT_N_PHI) as u64,
        p => (p.pixel_count() + p.probes().len()) as u64,
    };
    let wavelengths = m.len() as u64;
    let units = table_cells
        .saturating_mul(expected_orders)
        .saturating_add(output_cells)
        .saturating_mul(wavelengths);
    Ok(Cost {
        table_cells,
        output_cells,
        wavelengths,
        expected_orders,
        units,
    })
}

/// The estimated cost of a job's product items: every distinct multiple-scattering table once
/// (the engine shares a table between the requests of one medium and quality) plus every item's
/// output cells, × wavelengths, in the units of [`Cost::units`]. Add requests with [`Self::add`].
#[derive(Debug, Default)]
pub struct JobCost {
    media: std::collections::HashMap<String, Medium>,
    tables: std::collections::HashSet<String>,
    /// The total so far.
    pub units: u64,
}

impl JobCost {
    /// Adds `req`'s output cells, and its table unless an earlier request builds the same one.
    pub fn add(&mut self, req: &ProductRequest) -> Result<()> {
        let key = medium_key(req);
        let m = match self.media.entry(key.clone()) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let spec = &req.spec;
                e.insert(Medium::new(
                    &spec.atmosphere,
                    &spec.wavelengths_nm,
                    spec.ground_albedo,
                )?)
            }
        };
        let c = estimate_in(req, m)?;
        let quality = skybake_engine::plan::effective_quality(&req.spec);
        let table = format!("{key}|{quality:?}|{}", c.table_cells);
        let table_units = if self.tables.insert(table) {
            c.table_cells.saturating_mul(c.expected_orders)
        } else {
            0
        };
        self.units = self.units.saturating_add(
            table_units
                .saturating_add(c.output_cells)
                .saturating_mul(c.wavelengths),
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::RequestParams;
    use skybake_engine::spec::ProductKind;

    fn request(kind: ProductKind, pairs: &[(&str, &str)]) -> ProductRequest {
        let p = RequestParams::from_pairs(pairs.iter().map(|&(k, v)| (k, v))).unwrap();
        ProductRequest::from_params(kind, &p).unwrap()
    }

    #[test]
    fn thin_atmosphere_needs_few_orders_thick_one_many() {
        // Rayleigh at 400 nm: τ ≈ 0.36, q ≈ 0.26, ln(1e-3)/ln(0.26) ≈ 5.1 → 6 (the precise table
        // converges in 5 with its tail extrapolation).
        let thin = estimate(&request(ProductKind::Sky, &[])).unwrap();
        assert!((3..=10).contains(&thin.expected_orders), "{thin:?}");
        // The case that motivated the estimate: the earth preset with aerosol optical depth 100 (90 s of CPU).
        let hazy = include_str!("../../../config/atmospheres/earth-hazy.json");
        let earth = include_str!("../../../config/atmospheres/earth.json");
        let thick_json = earth.replace("\"value\": 0.1,", "\"value\": 100.0,");
        assert_ne!(thick_json, earth);
        let thick = estimate(&request(ProductKind::Sun, &[("atmosphere", &thick_json)])).unwrap();
        assert!(thick.expected_orders >= 40, "{thick:?}");
        assert!(thick.units > 5 * thin.units, "{thick:?} vs {thin:?}");
        let moderate = estimate(&request(ProductKind::Sky, &[("atmosphere", hazy)])).unwrap();
        assert!(moderate.expected_orders < thick.expected_orders);
        let none = estimate(&request(ProductKind::Sky, &[("method", "none")])).unwrap();
        assert_eq!(none.table_cells, 0);
        assert!(none.units < thin.units);
    }
}
