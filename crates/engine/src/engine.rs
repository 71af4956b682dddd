//! The engine: turns validated specs into products, reusing shared precomputed tables across
//! requests. Pure computation; the only clock read is for timing.

use crate::plan::{Plan, Reason, Stage};
use crate::spec::{AerialSpec, CommonSpec, DomeSpec, ProductKind, ProductSpec};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;
use skybake_physics::atmosphere::integrate::{Recorder, Scratch};
use skybake_physics::atmosphere::irradiance::{
    hemisphere_irradiance, SUN_PRODUCT_N_MU, SUN_PRODUCT_N_PHI,
};
use skybake_physics::atmosphere::shared::{
    init_unless, Persistence, SharedTables, TableEvents, TableStore,
};
use skybake_physics::atmosphere::sky::{
    dome_table_unless, horizon_axis_deg, horizon_dip_deg, DomeTable, MsMethod, Observer,
    RadianceEvaluator,
};
use skybake_physics::atmosphere::sun_transmittance::sun_transmittance;
use skybake_physics::atmosphere::Medium;
use skybake_physics::spectrum::colour::XyzWeights;
use skybake_physics::spectrum::photometry::{correlated_colour_temperature, illuminance_lux};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

pub use crate::spec::DomeShape;

/// Engine version: part of every cache key, bumped when results change.
pub const ENGINE_VERSION: &str = concat!("skybake-", env!("CARGO_PKG_VERSION"), "-engine19");

/// A cooperative cancellation check: true once nobody wants the result (every waiting client has gone). The engine
/// asks it at stage boundaries (after the density table, between orders of scattering of the
/// precise table, before the output table) and stops with [`Error::Cancelled`].
pub type CancelCheck<'a> = &'a (dyn Fn() -> bool + Sync);

/// Never cancelled.
const NEVER: CancelCheck<'static> = &|| false;

/// [`Error::Cancelled`] when `cancelled` says so.
fn checkpoint(cancelled: CancelCheck) -> Result<()> {
    if cancelled() {
        Err(Error::Cancelled)
    } else {
        Ok(())
    }
}

/// Most sets of shared tables kept in memory.
const SHARED_CAPACITY: usize = 8;

pub use crate::accuracy::{stated_relative_error, stated_twilight_error};
pub use crate::plan::{effective_method, fast_preset, FAST_TWILIGHT_LIMIT_DEG};
pub use skybake_physics::atmosphere::quality::settings_for;

/// Error estimate attached to every product.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrorEstimate {
    pub method: MsMethod,
    /// Bound on the relative radiance error measured against independent references.
    pub relative_error: f64,
    /// Orders of scattering computed (precise method).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scattering_orders: Option<usize>,
    /// Fraction of the total the last order added (precise method).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_order_fraction: Option<f64>,
    /// Where `relative_error` comes from.
    pub basis: String,
    /// The measured regime (`aerosol/sun band/altitude band`) the figure comes from, when the
    /// request lies in one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub regime: Option<String>,
    /// Whether this request lies inside the validated range (sun elevation ≥ −12°: spherical
    /// Monte Carlo to 10°, DISORT from 30°); outside it `relative_error` is the nearest validated
    /// figure, not a bound, and `caveat` says why.
    pub validated: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub caveat: Option<&'static str>,
}

/// Stages that ran and stages left out, as prose: the cloud frame's list (`render/`) until the
/// frame joins the typed [`Plan`] as a product.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Stages {
    pub ran: Vec<String>,
    pub skipped: Vec<String>,
}

/// Metadata common to all atmosphere products.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProductMeta {
    pub engine_version: &'static str,
    pub error_estimate: ErrorEstimate,
    /// The stages that ran and those left out, and why.
    pub plan: Plan,
    pub timing_ms: f64,
    /// Whether the shared tables were already built (warm) when this ran.
    pub shared_tables_warm: bool,
    /// Colour output caveat when the sampling is too coarse.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colour_note: Option<String>,
}

/// Sun attenuation and irradiance at the observer (the `sun` product, `GET /v1/sun`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SunProduct {
    pub wavelengths_nm: Vec<f64>,
    pub sun_elevation_deg: f64,
    pub observer_altitude_m: f64,
    pub solar_irradiance_w_m2_nm: Vec<f64>,
    pub transmittance: Vec<f64>,
    pub direct_normal_irradiance_w_m2_nm: Vec<f64>,
    pub diffuse_horizontal_irradiance_w_m2_nm: Vec<f64>,
    pub global_horizontal_irradiance_w_m2_nm: Vec<f64>,
    /// Photopic illuminance on a horizontal surface from the whole sky and sun, lux (CIE,
    /// K_m = 683 lm/W; integrated over the requested wavelengths, see `meta.colour_note`).
    pub global_horizontal_illuminance_lux: f64,
    /// The sky's part of it (diffuse), lux.
    pub diffuse_horizontal_illuminance_lux: f64,
    /// Correlated colour temperature of the global horizontal light, K (CIE 015:2018 §9.5;
    /// `null` when it is dark or farther than Duv 0.05 from the Planckian locus).
    pub global_correlated_colour_temperature_k: Option<f64>,
    /// Signed distance of that light from the Planckian locus in CIE 1960 (u, v).
    pub global_duv: Option<f64>,
    pub error_estimate: ErrorEstimate,
    pub timing_ms: f64,
    pub meta: ProductMeta,
}

/// Radiance in one exact direction.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Probe {
    pub view_zenith_deg: f64,
    pub view_azimuth_deg: f64,
    pub radiance_w_m2_sr_nm: Vec<f64>,
}

/// A sky or ground radiance table with probes.
#[derive(Debug, Clone, PartialEq)]
pub struct DomeProduct {
    pub table: DomeTable,
    pub probes: Vec<Probe>,
    pub meta: ProductMeta,
}

/// Aerial perspective: transmittance and in-scattered radiance up to each distance.
#[derive(Debug, Clone, PartialEq)]
pub struct AerialProduct {
    pub wavelengths_nm: Vec<f64>,
    pub elevation_deg: Vec<f64>,
    pub azimuth_deg: Vec<f64>,
    pub distance_m: Vec<f64>,
    /// `[elevation][azimuth][distance][λ]`.
    pub transmittance: Vec<f32>,
    /// `[elevation][azimuth][distance][λ]`, W m⁻² sr⁻¹ nm⁻¹.
    pub inscatter: Vec<f32>,
    pub meta: ProductMeta,
}

/// A shared-tables slot, filled by the first request that needs it.
type SharedSlot = Arc<std::sync::OnceLock<Arc<SharedTables>>>;

/// The shared tables the engine builds, for the build counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Table {
    /// The density-integral (transmittance) table, with the medium.
    Density,
    /// The fast (Hillaire 2020) multiple-scattering table.
    Fast,
    /// The precise (orders of scattering) multiple-scattering table.
    Precise,
}

impl Table {
    pub const ALL: [Table; 3] = [Table::Density, Table::Fast, Table::Precise];

    pub fn name(self) -> &'static str {
        match self {
            Table::Density => "density",
            Table::Fast => "fast",
            Table::Precise => "precise",
        }
    }
}

/// Ray-march terms and product integrals the engine evaluates, for the work counters that show
/// a plan's stages ran (and those left out did not).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Term {
    /// Samples at which single scattering of direct sunlight was evaluated.
    SingleScattering,
    /// Samples at which a multiple-scattering table was evaluated.
    MultipleScattering,
    /// Rays ending on the ground whose ground bounce was evaluated.
    GroundBounce,
    /// Direct-sun transmittances computed (sun product).
    DirectSun,
    /// Hemisphere directions integrated for the diffuse irradiance (sun product).
    DiffuseIrradiance,
}

impl Term {
    pub const ALL: [Term; 5] = [
        Term::SingleScattering,
        Term::MultipleScattering,
        Term::GroundBounce,
        Term::DirectSun,
        Term::DiffuseIrradiance,
    ];
}

/// Any atmosphere product.
#[derive(Debug, Clone, PartialEq)]
pub enum Product {
    Sun(SunProduct),
    Sky(DomeProduct),
    Ground(DomeProduct),
    Aerial(AerialProduct),
}

impl Product {
    pub fn meta(&self) -> &ProductMeta {
        match self {
            Product::Sun(p) => &p.meta,
            Product::Sky(p) | Product::Ground(p) => &p.meta,
            Product::Aerial(p) => &p.meta,
        }
    }
}

/// The engine with its cache of shared tables.
#[derive(Default)]
pub struct Engine {
    /// Most recently used last. Each slot is filled once, outside the lock, so concurrent requests
    /// for the same medium wait for one build instead of each building their own.
    shared: Mutex<Vec<(String, SharedSlot)>>,
    tables: [AtomicU64; 3],
    terms: [AtomicU64; 5],
    /// Where precise tables are kept between processes (`store::tables`), if anywhere.
    table_store: Option<Arc<dyn TableStore>>,
    /// Precise tables built, loaded and refused (counted where they happen, in `SharedTables`).
    table_events: Arc<TableEvents>,
    id: EngineId,
}

/// A number no other engine of the process has (for memos of an engine's products).
#[derive(Debug)]
struct EngineId(u64);

impl Default for EngineId {
    fn default() -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(1);
        Self(NEXT.fetch_add(1, Ordering::Relaxed))
    }
}

impl Engine {
    pub fn new() -> Self {
        Self::default()
    }

    /// This engine's number, unique within the process: what an engine computes depends on
    /// it only through its tables, which a memo keyed by this number need not compare.
    pub fn id(&self) -> u64 {
        self.id.0
    }

    /// An engine that loads precise tables from `store` when it has them and saves those it builds.
    pub fn with_table_store(store: Arc<dyn TableStore>) -> Self {
        Self {
            table_store: Some(store),
            ..Self::default()
        }
    }

    /// How many times each table kind was built (for tests and metrics).
    pub fn table_builds(&self, table: Table) -> u64 {
        match table {
            // A precise table may be loaded from the table store instead of built.
            Table::Precise => TableEvents::get(&self.table_events.precise_built),
            // Counted where it happens (it may be loaded from the table store instead).
            Table::Density => TableEvents::get(&self.table_events.density_built),
            _ => self.tables[table as usize].load(Ordering::Relaxed),
        }
    }

    /// How many precise tables were loaded from the table store, and how many stored ones were
    /// refused (corrupt or not matching) and rebuilt (for tests and metrics).
    pub fn table_loads(&self) -> (u64, u64) {
        (
            TableEvents::get(&self.table_events.precise_loaded),
            TableEvents::get(&self.table_events.precise_rejected),
        )
    }

    /// How many density-integral tables were loaded from the table store, and how many stored
    /// ones were refused (not matching the atmosphere or the resolution) and rebuilt.
    pub fn density_table_loads(&self) -> (u64, u64) {
        (
            TableEvents::get(&self.table_events.density_loaded),
            TableEvents::get(&self.table_events.density_rejected),
        )
    }

    /// How much of each term the engine has evaluated (for tests and metrics).
    pub fn term_count(&self, term: Term) -> u64 {
        self.terms[term as usize].load(Ordering::Relaxed)
    }

    fn count(&self, table: Table) {
        self.tables[table as usize].fetch_add(1, Ordering::Relaxed);
    }

    fn add_terms(&self, term: Term, n: u64) {
        self.terms[term as usize].fetch_add(n, Ordering::Relaxed);
    }

    fn add_ray_work(&self, eval: &RadianceEvaluator) {
        let w = eval.work();
        self.add_terms(Term::SingleScattering, w.single_samples);
        self.add_terms(Term::MultipleScattering, w.source_samples);
        self.add_terms(Term::GroundBounce, w.ground_bounces);
    }

    /// The plan of `product` for `spec` (resolves the medium; builds no tables).
    pub fn plan(spec: &CommonSpec, product: ProductKind) -> Result<Plan> {
        let medium = Medium::new(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo)?;
        Ok(crate::plan::plan(product, spec, &medium))
    }

    /// Plans and computes `product` for `spec`.
    pub fn compute(&self, spec: &CommonSpec, product: &ProductSpec) -> Result<Product> {
        let plan = Self::plan(spec, product.kind())?;
        self.execute(spec, product, &plan)
    }

    /// Executes `plan` for `product`: only the plan's stages run.
    pub fn execute(
        &self,
        spec: &CommonSpec,
        product: &ProductSpec,
        plan: &Plan,
    ) -> Result<Product> {
        self.execute_cancellable(spec, product, plan, NEVER)
    }

    /// [`Self::execute`], stopped with [`Error::Cancelled`] at the next stage boundary once
    /// `cancelled` returns true.
    pub fn execute_cancellable(
        &self,
        spec: &CommonSpec,
        product: &ProductSpec,
        plan: &Plan,
        cancelled: CancelCheck,
    ) -> Result<Product> {
        let c = cancelled;
        Ok(match product {
            ProductSpec::Sun => Product::Sun(self.run_sun(spec, plan, c)?),
            ProductSpec::Sky(d) => Product::Sky(self.run_dome(spec, plan, d, -90.0, 90.0, c)?),
            ProductSpec::Ground(d) => Product::Ground(self.run_dome(spec, plan, d, -90.0, 0.0, c)?),
            ProductSpec::Aerial(a) => Product::Aerial(self.run_aerial(spec, plan, a, c)?),
        })
    }

    /// Shared tables for this spec's medium (LRU of a few), with the precise order series' tolerance
    /// the planner's cost rule gives it (`plan::table_budget`).
    pub fn shared(&self, spec: &CommonSpec) -> Result<Arc<SharedTables>> {
        self.shared_unless(spec, NEVER)
    }

    /// [`Self::shared`], stopped with [`Error::Cancelled`] between two rows of the density table
    /// once `cancelled` returns true (the slot stays empty for the next caller).
    pub fn shared_unless(
        &self,
        spec: &CommonSpec,
        cancelled: CancelCheck,
    ) -> Result<Arc<SharedTables>> {
        let medium = Medium::new(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo)?;
        let plan = crate::plan::plan(ProductKind::Sky, spec, &medium);
        self.shared_with(&plan.spec_for(spec), plan.precise_tolerance, cancelled)
    }

    /// Shared tables for this spec's medium whose precise table stops its order series at
    /// `precise_tolerance` (`None`: the preset's); the tolerance is part of the table's key.
    pub fn shared_with(
        &self,
        spec: &CommonSpec,
        precise_tolerance: Option<f64>,
        cancelled: CancelCheck,
    ) -> Result<Arc<SharedTables>> {
        let medium = Medium::new(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo)?;
        let (fast, mut precise) = settings_for(spec.quality);
        if let Some(t) = precise_tolerance {
            precise.tolerance = t;
        }
        let key = serde_json::to_string(&(
            &spec.atmosphere,
            &spec.wavelengths_nm,
            spec.ground_albedo,
            spec.quality,
            precise.tolerance,
        ))
        .unwrap_or_default();
        let slot = {
            let mut cache = self.shared.lock().unwrap_or_else(|e| e.into_inner());
            let slot = match cache.iter().position(|(k, _)| *k == key) {
                Some(pos) => cache.remove(pos).1,
                None => SharedSlot::default(),
            };
            cache.push((key.clone(), slot.clone()));
            if cache.len() > SHARED_CAPACITY {
                cache.remove(0);
            }
            slot
        };
        let tables = init_unless(&slot, || {
            // The density table depends on the radii and density profiles only.
            let density_key = serde_json::to_string(&(
                medium.bottom_radius_m,
                medium.top_radius_m,
                &medium.profiles,
            ))
            .unwrap_or_default();
            Some(Arc::new(SharedTables::persistent(
                medium,
                fast,
                precise,
                Persistence {
                    // No key, no store: a table is never shared under a key that does not say
                    // what it was built for.
                    store: self
                        .table_store
                        .clone()
                        .filter(|_| !key.is_empty() && !density_key.is_empty()),
                    medium_key: key,
                    density_key,
                    engine_version: ENGINE_VERSION,
                    events: self.table_events.clone(),
                },
            )))
        })
        .ok_or(Error::Cancelled)?;
        // Without a table store the density table is built now (stopped between rows when
        // cancelled); with one it is made on first use, so it can go through the store with a
        // precise table (`SharedTables::persistent`), and stops the same way there.
        if self.table_store.is_none() && tables.density_unless(cancelled).is_none() {
            return Err(Error::Cancelled);
        }
        Ok(tables.clone())
    }

    /// The radiance evaluator of `plan`: the multiple-scattering source only when the plan runs
    /// that stage (building its table on first use, the precise one stopped between orders when
    /// `cancelled`), single scattering and the ground bounce only when the plan runs them.
    fn evaluator<'a>(
        &self,
        shared: &'a SharedTables,
        spec: &CommonSpec,
        plan: &Plan,
        cancelled: CancelCheck,
    ) -> Result<(RadianceEvaluator<'a>, bool)> {
        checkpoint(cancelled)?;
        let method = plan.ms_method();
        let warm = match method {
            MsMethod::Precise => shared.has_precise(),
            MsMethod::Fast => shared.has_fast(),
            MsMethod::None => true,
        };
        // Precise builds are counted where they happen (a stored table may be loaded instead).
        if !warm && method == MsMethod::Fast {
            self.count(Table::Fast);
        }
        if method == MsMethod::Precise && shared.precise_unless(cancelled).is_none() {
            return Err(Error::Cancelled);
        }
        if method == MsMethod::Fast && shared.fast_unless(cancelled).is_none() {
            return Err(Error::Cancelled);
        }
        checkpoint(cancelled)?;
        let observer = Observer {
            altitude_m: spec.observer_altitude_m,
            sun_elevation_rad: spec.sun.sun_elevation_deg.to_radians(),
        };
        let eval = RadianceEvaluator::new(shared, method, observer, spec.quality.steps())
            .with_terms(
                plan.runs(Stage::SingleScattering),
                plan.runs(Stage::GroundBounce),
            );
        Ok((eval, warm))
    }

    fn tables_for(
        &self,
        spec: &CommonSpec,
        plan: &Plan,
        cancelled: CancelCheck,
    ) -> Result<Arc<SharedTables>> {
        if !plan.runs(Stage::DensityTable) {
            return Err(Error::invalid(
                "plan",
                "every atmosphere product needs the density table",
            ));
        }
        self.shared_with(spec, plan.precise_tolerance, cancelled)
    }

    #[allow(clippy::too_many_arguments)]
    fn meta(
        &self,
        kind: ProductKind,
        shared: &SharedTables,
        spec: &CommonSpec,
        warm: bool,
        start: Instant,
        plan: &Plan,
    ) -> ProductMeta {
        let method = plan.ms_method();
        let (orders, last) = match method {
            MsMethod::Precise => {
                let c = &shared.precise().convergence;
                (Some(c.orders), Some(c.last_order_fraction))
            }
            _ => (None, None),
        };
        let colour_note = (!spec.wavelengths_nm.adequate_for_colour()).then(|| {
            "wavelength sampling too coarse for accurate colour (needs 400–700 nm with gaps ≤ 40 nm); RGB is indicative".to_string()
        });
        let e = spec.sun.sun_elevation_deg;
        let night = plan
            .left_out
            .iter()
            .any(|(_, r)| matches!(r, Reason::SunBelowDarkestTwilight { .. }));
        let thick = max_vertical_optical_depth(&shared.medium) > VALIDATED_MAX_OPTICAL_DEPTH;
        let validated = e >= -12.0 && method != MsMethod::None && !thick;
        let caveat = match (method, e) {
            _ if night => Some(
                "night: no sunlit air or ground is in view, so sunlight contributes exactly zero; moonlight, starlight and airglow are not modelled",
            ),
            _ if thick => Some(
                "outside the validated range: the atmosphere's vertical optical depth exceeds 1 at some wavelength (validation covers optically thin to moderate atmospheres); orders of scattering are capped, energy conservation still holds",
            ),
            (MsMethod::None, _) => Some("single scattering only: multiple scattering is left out"),
            (_, e) if e < -12.0 => Some(
                "deep twilight (sun below −12°): validated down to −12° only; energy conservation is verified for all sun positions",
            ),
            (_, e) if e < 30.0 && e > 10.0 => Some(
                "between the validated ranges (spherical Monte Carlo to 10°, DISORT from 30°)",
            ),
            _ => None,
        };
        let independent = if e >= 30.0 {
            "DISORT (Rayleigh, sun zenith 0–60°, view zenith 0–60°, albedo 0 and 0.3), tests/atmosphere/atmosphere_validation.rs"
        } else {
            "the spherical-shell Monte Carlo in this sun-elevation band (Rayleigh, 440–680 nm, albedo 0 and 0.3, observers at 0, 10 and 400 km), tests/atmosphere/atmosphere_twilight.rs"
        };
        // The reference preset's own error against the independent code in this band.
        let reference_error = crate::accuracy::reference_error(e);
        // This product, method and quality in this regime, from the compiled-in report.
        let measured = (!night && method != MsMethod::None)
            .then(|| crate::accuracy::measured_for(kind, method, spec))
            .flatten();
        let stated = if e >= 30.0 {
            stated_relative_error(method)
        } else {
            stated_twilight_error(method, e)
        };
        let (relative_error, basis, regime) = if night {
            // Every scattering term is exactly zero in the model (`plan::darkest_twilight_deg`).
            (
                0.0,
                "night: sunlight contributes exactly zero".to_string(),
                None,
            )
        } else if method == MsMethod::Precise {
            // At least the measured distance from DISORT in this regime (report/external.json).
            crate::accuracy::combined_error(spec, measured, reference_error, stated, independent)
        } else {
            (
                stated,
                format!("max relative deviation from {independent}"),
                None,
            )
        };
        let basis = match plan.substitution {
            Some(crate::plan::Substitution::FastRetired { quality, .. }) => format!(
                "{basis}; the requested fast method is retired: the precise tables at the {} preset ran (plan.method_substitution)",
                crate::accuracy::preset_name(quality)
            ),
            None => basis,
        };
        // Outside the measured altitude and aerosol bands nothing is validated; below the
        // measured sun bands the spherical Monte Carlo's figures stand (to −12°).
        let bands = crate::accuracy::RegimeBands::of(
            &spec.atmosphere,
            spec.sun.sun_elevation_deg,
            spec.observer_altitude_m,
        );
        let validated =
            validated && (night || (bands.altitude.is_some() && bands.aerosol.is_some()));
        ProductMeta {
            engine_version: ENGINE_VERSION,
            error_estimate: ErrorEstimate {
                method,
                relative_error,
                scattering_orders: orders,
                last_order_fraction: last,
                basis,
                regime,
                validated,
                caveat,
            },
            plan: plan.clone(),
            timing_ms: start.elapsed().as_secs_f64() * 1e3,
            shared_tables_warm: warm,
            colour_note,
        }
    }

    /// Sun attenuation and irradiances at the observer (plans, then executes).
    pub fn sun(&self, spec: &CommonSpec) -> Result<SunProduct> {
        self.sun_unless(spec, NEVER)
    }

    /// [`Self::sun`], stopped with [`Error::Cancelled`] once `cancelled` returns true.
    pub fn sun_unless(&self, spec: &CommonSpec, cancelled: CancelCheck) -> Result<SunProduct> {
        let plan = Self::plan(spec, ProductKind::Sun)?;
        self.run_sun(spec, &plan, cancelled)
    }

    /// Sky-dome table (view elevation −90°…90°) and probes (plans, then executes).
    pub fn sky(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
    ) -> Result<DomeProduct> {
        self.sky_unless(spec, shape, probes, NEVER)
    }

    /// [`Self::sky`], stopped with [`Error::Cancelled`] once `cancelled` returns true.
    pub fn sky_unless(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
        cancelled: CancelCheck,
    ) -> Result<DomeProduct> {
        let dome = DomeSpec::sky(shape, probes.to_vec())?;
        let plan = Self::plan(spec, ProductKind::Sky)?;
        self.run_dome(spec, &plan, &dome, -90.0, 90.0, cancelled)
    }

    /// Upward radiance (view zenith 90°–180°, i.e. elevation −90°…0°) and probes.
    pub fn ground(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
    ) -> Result<DomeProduct> {
        self.ground_unless(spec, shape, probes, NEVER)
    }

    /// [`Self::ground`], stopped with [`Error::Cancelled`] once `cancelled` returns true.
    pub fn ground_unless(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
        cancelled: CancelCheck,
    ) -> Result<DomeProduct> {
        let dome = DomeSpec::ground(shape, probes.to_vec())?;
        let plan = Self::plan(spec, ProductKind::Ground)?;
        self.run_dome(spec, &plan, &dome, -90.0, 0.0, cancelled)
    }

    /// Aerial perspective table: `elevation_count` × `azimuth_count` directions × `distance_count`
    /// distances from 0 to `max_distance_m` (quadratic spacing, dense near the viewer).
    pub fn aerial(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        distance_count: usize,
        max_distance_m: f64,
    ) -> Result<AerialProduct> {
        self.aerial_unless(spec, shape, distance_count, max_distance_m, NEVER)
    }

    /// [`Self::aerial`], stopped with [`Error::Cancelled`] once `cancelled` returns true.
    pub fn aerial_unless(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        distance_count: usize,
        max_distance_m: f64,
        cancelled: CancelCheck,
    ) -> Result<AerialProduct> {
        let aerial = AerialSpec::new(shape, distance_count, max_distance_m)?;
        let plan = Self::plan(spec, ProductKind::Aerial)?;
        self.run_aerial(spec, &plan, &aerial, cancelled)
    }

    fn run_sun(
        &self,
        spec: &CommonSpec,
        plan: &Plan,
        cancelled: CancelCheck,
    ) -> Result<SunProduct> {
        let spec = &plan.spec_for(spec);
        let start = Instant::now();
        let shared = self.tables_for(spec, plan, cancelled)?;
        let m = &shared.medium;
        let (eval, warm) = self.evaluator(&shared, spec, plan, cancelled)?;
        let transmittance = if plan.runs(Stage::DirectSun) {
            self.add_terms(Term::DirectSun, 1);
            sun_transmittance(
                m,
                spec.observer_altitude_m,
                spec.sun.sun_elevation_deg.to_radians(),
            )
        } else {
            vec![0.0; m.len()]
        };
        let dhi = if plan.runs(Stage::DiffuseIrradiance) {
            self.add_terms(
                Term::DiffuseIrradiance,
                (SUN_PRODUCT_N_MU * SUN_PRODUCT_N_PHI) as u64,
            );
            hemisphere_irradiance(&eval, m.len(), SUN_PRODUCT_N_MU, SUN_PRODUCT_N_PHI)
        } else {
            vec![0.0; m.len()]
        };
        self.add_ray_work(&eval);
        let mu_s = spec.sun.sun_elevation_deg.to_radians().sin();
        let dni: Vec<f64> = transmittance
            .iter()
            .zip(&m.solar_irradiance)
            .map(|(t, e)| t * e)
            .collect();
        let ghi: Vec<f64> = dni
            .iter()
            .zip(&dhi)
            .map(|(d, h)| d * mu_s.max(0.0) + h)
            .collect();
        let meta = self.meta(ProductKind::Sun, &shared, spec, warm, start, plan);
        let nm = &m.wavelengths_nm;
        let cct = correlated_colour_temperature(XyzWeights::new(nm).xyz(&ghi));
        Ok(SunProduct {
            global_horizontal_illuminance_lux: illuminance_lux(nm, &ghi),
            diffuse_horizontal_illuminance_lux: illuminance_lux(nm, &dhi),
            global_correlated_colour_temperature_k: cct.map(|c| c.kelvin),
            global_duv: cct.map(|c| c.duv),
            wavelengths_nm: m.wavelengths_nm.clone(),
            sun_elevation_deg: spec.sun.sun_elevation_deg,
            observer_altitude_m: spec.observer_altitude_m,
            solar_irradiance_w_m2_nm: m.solar_irradiance.clone(),
            transmittance,
            direct_normal_irradiance_w_m2_nm: dni,
            diffuse_horizontal_irradiance_w_m2_nm: dhi,
            global_horizontal_irradiance_w_m2_nm: ghi,
            error_estimate: meta.error_estimate.clone(),
            timing_ms: meta.timing_ms,
            meta,
        })
    }

    fn run_dome(
        &self,
        spec: &CommonSpec,
        plan: &Plan,
        dome: &DomeSpec,
        lo: f64,
        hi: f64,
        cancelled: CancelCheck,
    ) -> Result<DomeProduct> {
        let spec = &plan.spec_for(spec);
        let shape = dome.shape();
        let start = Instant::now();
        let shared = self.tables_for(spec, plan, cancelled)?;
        let (eval, warm) = self.evaluator(&shared, spec, plan, cancelled)?;
        let table = dome_table_unless(
            &eval,
            horizon_axis_deg(
                shape.elevation_count,
                lo,
                hi,
                -horizon_dip_deg(shared.medium.bottom_radius_m, spec.observer_altitude_m),
            ),
            shape.azimuth_count,
            cancelled,
        )
        .ok_or(Error::Cancelled)?;
        let probes = evaluate_probes(&eval, shared.medium.len(), dome.probes());
        self.add_ray_work(&eval);
        let kind = if hi > 0.0 {
            ProductKind::Sky
        } else {
            ProductKind::Ground
        };
        let meta = self.meta(kind, &shared, spec, warm, start, plan);
        Ok(DomeProduct {
            table,
            probes,
            meta,
        })
    }

    fn run_aerial(
        &self,
        spec: &CommonSpec,
        plan: &Plan,
        aerial: &AerialSpec,
        cancelled: CancelCheck,
    ) -> Result<AerialProduct> {
        let spec = &plan.spec_for(spec);
        let (shape, distance_count, max_distance_m) = (
            aerial.shape(),
            aerial.distance_count(),
            aerial.max_distance_m(),
        );
        let start = Instant::now();
        let shared = self.tables_for(spec, plan, cancelled)?;
        let (eval, warm) = self.evaluator(&shared, spec, plan, cancelled)?;
        let m = &shared.medium;
        let n_l = m.len();
        let elevation_deg = horizon_axis_deg(
            shape.elevation_count,
            -90.0,
            90.0,
            -horizon_dip_deg(m.bottom_radius_m, spec.observer_altitude_m),
        );
        let azimuth_deg: Vec<f64> = (0..shape.azimuth_count)
            .map(|k| {
                if shape.azimuth_count == 1 {
                    0.0
                } else {
                    180.0 * k as f64 / (shape.azimuth_count - 1) as f64
                }
            })
            .collect();
        let distance_m: Vec<f64> = (0..distance_count)
            .map(|k| {
                let u = if distance_count == 1 {
                    1.0
                } else {
                    k as f64 / (distance_count - 1) as f64
                };
                max_distance_m * u * u
            })
            .collect();
        let per_dir = distance_count * n_l;
        let mut transmittance = vec![0f32; shape.elevation_count * shape.azimuth_count * per_dir];
        let mut inscatter = vec![0f32; transmittance.len()];
        let steps = spec.quality.steps() * 2;
        let stopped = AtomicBool::new(false);
        transmittance
            .par_chunks_mut(per_dir)
            .zip(inscatter.par_chunks_mut(per_dir))
            .enumerate()
            .for_each_init(
                || (Scratch::new(n_l), vec![0.0; n_l], vec![0.0; n_l]),
                |(scratch, out, tr), (idx, (t_dst, s_dst))| {
                    let (row, col) = (idx / shape.azimuth_count, idx % shape.azimuth_count);
                    // One check per row of elevation; once stopped, the rest is skipped.
                    if stopped.load(Ordering::Relaxed) {
                        return;
                    }
                    if col == 0 && cancelled() {
                        stopped.store(true, Ordering::Relaxed);
                        return;
                    }
                    let theta = (90.0 - elevation_deg[row]).to_radians();
                    let (mu, nu) = eval.direction(theta, azimuth_deg[col].to_radians());
                    let mut rec = Recorder {
                        distances_m: &distance_m,
                        transmittance: t_dst,
                        inscatter: s_dst,
                    };
                    eval.trace(mu, nu, steps, scratch, out, tr, Some(&mut rec));
                    for (k, v) in s_dst.iter_mut().enumerate() {
                        *v *= m.solar_irradiance[k % n_l] as f32;
                    }
                },
            );
        if stopped.load(Ordering::Relaxed) {
            return Err(Error::Cancelled);
        }
        self.add_ray_work(&eval);
        let meta = self.meta(ProductKind::Aerial, &shared, spec, warm, start, plan);
        Ok(AerialProduct {
            wavelengths_nm: m.wavelengths_nm.clone(),
            elevation_deg,
            azimuth_deg,
            distance_m,
            transmittance,
            inscatter,
            meta,
        })
    }
}

/// Largest vertical optical depth (all constituents) of the validated range: the DISORT
/// comparisons (tests/atmosphere/atmosphere_validation.rs) are Rayleigh atmospheres, τ ≈ 0.56 at 360 nm;
/// beyond τ = 1 the orders-of-scattering series converges slowly and is capped (the product then carries an "outside the validated range" caveat).
pub const VALIDATED_MAX_OPTICAL_DEPTH: f64 = 1.0;

/// The largest vertical optical depth of `m` over its wavelengths.
pub fn max_vertical_optical_depth(m: &Medium) -> f64 {
    (0..m.len())
        .map(|i| m.vertical_optical_depth(i).iter().sum::<f64>())
        .fold(0.0, f64::max)
}

fn evaluate_probes(eval: &RadianceEvaluator, n_l: usize, probes: &[(f64, f64)]) -> Vec<Probe> {
    probes
        .par_iter()
        .map_init(
            || (Scratch::new(n_l), vec![0.0; n_l], vec![0.0; n_l]),
            |(scratch, out, tr), &(vz, va)| {
                eval.eval(vz.to_radians(), va.to_radians(), scratch, out, tr);
                Probe {
                    view_zenith_deg: vz,
                    view_azimuth_deg: va,
                    radiance_w_m2_sr_nm: out.clone(),
                }
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::{Quality, SunPosition};
    use skybake_physics::atmosphere::presets::preset;
    use skybake_physics::atmosphere::sky::MsMethod;
    use skybake_physics::spectrum::Wavelengths;

    #[test]
    fn concurrent_requests_for_one_medium_build_its_tables_once() {
        let engine = Engine::new();
        let spec = CommonSpec {
            atmosphere: preset("earth").unwrap(),
            wavelengths_nm: Wavelengths::parse("550").unwrap(),
            sun: SunPosition {
                sun_elevation_deg: 30.0,
                from_location: None,
            },
            observer_altitude_m: 0.0,
            ground_albedo: None,
            method: MsMethod::Precise,
            quality: Quality::Standard,
        };
        let tables: Vec<Arc<SharedTables>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4)
                .map(|_| s.spawn(|| engine.shared(&spec).unwrap()))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(engine.table_builds(Table::Density), 1);
        assert!(tables.iter().all(|t| Arc::ptr_eq(t, &tables[0])));
    }
}
