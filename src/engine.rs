//! The engine: turns validated specs into products, reusing shared precomputed tables across
//! requests. Pure computation; the only clock read is for timing.

use crate::atmosphere::integrate::{Recorder, Scratch};
use crate::atmosphere::multiple_fast::FastSettings;
use crate::atmosphere::multiple_precise::PreciseSettings;
use crate::atmosphere::quadrature::gauss_legendre;
use crate::atmosphere::shared::{Persistence, SharedTables, TableEvents, TableStore};
use crate::atmosphere::sky::{
    dome_table, horizon_axis_deg, horizon_dip_deg, DomeTable, MsMethod, Observer, RadianceEvaluator,
};
use crate::atmosphere::transmittance::density_integrals;
use crate::atmosphere::{geometry, Medium};
use crate::spec::{CommonSpec, Quality};
use crate::Result;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Engine version: part of every cache key, bumped when results change.
pub const ENGINE_VERSION: &str = concat!("skybake-", env!("CARGO_PKG_VERSION"), "-engine1");

/// Most sets of shared tables kept in memory.
const SHARED_CAPACITY: usize = 8;

/// Relative error of each method against DISORT for the Rayleigh validation cases
/// (tests/atmosphere_validation.rs measures it; keep these in step with that test).
pub fn stated_relative_error(method: MsMethod) -> f64 {
    match method {
        MsMethod::Precise => 0.02,
        MsMethod::Fast => 0.06,
        MsMethod::None => 0.5,
    }
}

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
    pub basis: &'static str,
    /// Whether this request lies inside the validated range (sun elevation ≥ 30°); outside it
    /// `relative_error` is the validated figure, not a bound, and `caveat` says why.
    pub validated: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub caveat: Option<&'static str>,
}

/// Stages that ran and stages left out, with the reason (DESIGN.md "Leaving out").
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
    pub stages: Stages,
    pub timing_ms: f64,
    /// Whether the shared tables were already built (warm) when this ran.
    pub shared_tables_warm: bool,
    /// Colour output caveat when the sampling is too coarse.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colour_note: Option<String>,
}

/// Sun attenuation and irradiance at the observer (DESIGN.md `/v1/sun`).
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

/// Table shape of a sky/ground request.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DomeShape {
    pub elevation_count: usize,
    pub azimuth_count: usize,
}

/// A shared-tables slot, filled by the first request that needs it.
type SharedSlot = Arc<std::sync::OnceLock<Arc<SharedTables>>>;

/// The engine with its cache of shared tables.
#[derive(Default)]
pub struct Engine {
    /// Most recently used last. Each slot is filled once, outside the lock, so concurrent requests
    /// for the same medium wait for one build instead of each building their own.
    shared: Mutex<Vec<(String, SharedSlot)>>,
    counters: Mutex<HashMap<&'static str, u64>>,
    /// Where precise tables are kept between processes (`store::tables`), if anywhere.
    table_store: Option<Arc<dyn TableStore>>,
    table_events: Arc<TableEvents>,
}

impl Engine {
    pub fn new() -> Self {
        Self::default()
    }

    /// An engine that loads precise tables from `store` when it has them and saves those it builds.
    pub fn with_table_store(store: Arc<dyn TableStore>) -> Self {
        Self {
            table_store: Some(store),
            ..Self::default()
        }
    }

    /// How many times each table kind was built (for tests and metrics).
    pub fn build_count(&self, what: &'static str) -> u64 {
        if what == "precise" {
            return TableEvents::get(&self.table_events.precise_built);
        }
        self.counters
            .lock()
            .map(|c| c.get(what).copied().unwrap_or(0))
            .unwrap_or(0)
    }

    /// How many precise tables were loaded from the table store, and how many stored ones were
    /// refused and rebuilt (for tests and metrics).
    pub fn table_loads(&self) -> (u64, u64) {
        (
            TableEvents::get(&self.table_events.precise_loaded),
            TableEvents::get(&self.table_events.precise_rejected),
        )
    }

    fn count(&self, what: &'static str) {
        if let Ok(mut c) = self.counters.lock() {
            *c.entry(what).or_default() += 1;
        }
    }

    /// Shared tables for this spec's medium (LRU of a few).
    pub fn shared(&self, spec: &CommonSpec) -> Result<Arc<SharedTables>> {
        let medium = Medium::new(&spec.atmosphere, &spec.wavelengths_nm, spec.ground_albedo)?;
        let key = serde_json::to_string(&(
            &spec.atmosphere,
            &spec.wavelengths_nm,
            spec.ground_albedo,
            spec.quality,
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
        let tables = slot.get_or_init(|| {
            self.count("density");
            let (fast, precise) = settings_for(spec.quality);
            Arc::new(
                SharedTables::new(medium, fast, precise).with_persistence(Persistence {
                    store: self.table_store.clone(),
                    medium_key: key,
                    engine_version: ENGINE_VERSION,
                    events: self.table_events.clone(),
                }),
            )
        });
        Ok(tables.clone())
    }

    fn evaluator<'a>(
        &self,
        shared: &'a SharedTables,
        spec: &CommonSpec,
    ) -> (RadianceEvaluator<'a>, bool) {
        let warm = match spec.method {
            MsMethod::Precise => shared.has_precise(),
            MsMethod::Fast => shared.has_fast(),
            MsMethod::None => true,
        };
        // Precise builds are counted where they happen (a stored table may be loaded instead).
        if !warm && spec.method == MsMethod::Fast {
            self.count("fast");
        }
        let observer = Observer {
            altitude_m: spec.observer_altitude_m,
            sun_elevation_rad: spec.sun.sun_elevation_deg.to_radians(),
        };
        (
            RadianceEvaluator::new(shared, spec.method, observer, spec.quality.steps()),
            warm,
        )
    }

    fn meta(
        &self,
        shared: &SharedTables,
        spec: &CommonSpec,
        warm: bool,
        start: Instant,
        stages: Stages,
    ) -> ProductMeta {
        let (orders, last) = match spec.method {
            MsMethod::Precise => {
                let c = &shared.precise().convergence;
                (Some(c.orders), Some(c.last_order_fraction))
            }
            _ => (None, None),
        };
        let colour_note = (!spec.wavelengths_nm.adequate_for_colour()).then(|| {
            "wavelength sampling too coarse for accurate colour (needs 400–700 nm with gaps ≤ 40 nm); RGB is indicative".to_string()
        });
        let validated = spec.sun.sun_elevation_deg >= 30.0 && spec.method != MsMethod::None;
        let caveat = match (spec.method, spec.sun.sun_elevation_deg) {
            (MsMethod::Fast, e) if e < 0.0 => Some(
                "twilight: the fast method's isotropic table under-resolves light scattered from the lit upper atmosphere; it reads 2–3x low at −6° and far lower in deep twilight; use method=precise",
            ),
            (MsMethod::None, _) => Some("single scattering only: multiple scattering is left out"),
            (_, e) if e < 30.0 => Some(
                "outside the DISORT-validated range (sun elevation ≥ 30°); energy conservation is verified for all sun positions",
            ),
            _ => None,
        };
        ProductMeta {
            engine_version: ENGINE_VERSION,
            error_estimate: ErrorEstimate {
                method: spec.method,
                relative_error: stated_relative_error(spec.method),
                scattering_orders: orders,
                last_order_fraction: last,
                basis: "max relative deviation from DISORT (Rayleigh, sun zenith 0–60°, view zenith 0–60°, albedo 0 and 0.3), tests/atmosphere_validation.rs",
                validated,
                caveat,
            },
            stages,
            timing_ms: start.elapsed().as_secs_f64() * 1e3,
            shared_tables_warm: warm,
            colour_note,
        }
    }

    /// Stages for a spec (what runs and what is left out, and why); needs only the resolved
    /// medium, so planning costs no table builds.
    pub fn plan(spec: &CommonSpec, m: &Medium) -> Stages {
        let mut st = Stages::default();
        st.ran.push("transmittance: density-integral table".into());
        if spec.sun.sun_elevation_deg < -m.sun_angular_radius_rad.to_degrees() {
            st.ran.push(
                "single scattering: exact ray marching, lit only where the atmosphere still sees the sun (twilight)".into(),
            );
        } else {
            st.ran.push("single scattering: exact ray marching".into());
        }
        match spec.method {
            MsMethod::Precise => st
                .ran
                .push("multiple scattering: successive orders (precise)".into()),
            MsMethod::Fast => st
                .ran
                .push("multiple scattering: Hillaire 2020 table (fast)".into()),
            MsMethod::None => st.skipped.push("multiple scattering: method=none".into()),
        }
        if m.ground_albedo.iter().all(|&a| a == 0.0) {
            st.skipped.push("ground bounce: ground albedo is 0".into());
        } else {
            st.ran
                .push("ground bounce: Lambertian ground lit by sun and sky".into());
        }
        if spec.sun.sun_elevation_deg < -1.0 {
            st.skipped
                .push("direct sun at the observer: the sun is below the horizon".into());
        }
        st
    }

    /// Sun attenuation and irradiances at the observer.
    pub fn sun(&self, spec: &CommonSpec) -> Result<SunProduct> {
        let start = Instant::now();
        let shared = self.shared(spec)?;
        let m = &shared.medium;
        let (eval, warm) = self.evaluator(&shared, spec);
        let transmittance = sun_transmittance(
            m,
            spec.observer_altitude_m,
            spec.sun.sun_elevation_deg.to_radians(),
        );
        let dhi = hemisphere_irradiance(&eval, m.len(), 16, 16);
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
        let stages = Self::plan(spec, &shared.medium);
        let meta = self.meta(&shared, spec, warm, start, stages);
        Ok(SunProduct {
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

    /// Sky-dome table (view elevation −90°…90°) and probes.
    pub fn sky(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
    ) -> Result<DomeProduct> {
        self.dome(spec, shape, probes, -90.0, 90.0)
    }

    /// Upward radiance (view zenith 90°–180°, i.e. elevation −90°…0°) and probes.
    pub fn ground(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
    ) -> Result<DomeProduct> {
        if let Some(&(vz, _)) = probes.iter().find(|(vz, _)| *vz < 90.0) {
            return Err(crate::Error::out_of_range(
                "probe",
                vz,
                "90 to 180 deg view zenith (ground looks down)",
            ));
        }
        self.dome(spec, shape, probes, -90.0, 0.0)
    }

    fn dome(
        &self,
        spec: &CommonSpec,
        shape: DomeShape,
        probes: &[(f64, f64)],
        lo: f64,
        hi: f64,
    ) -> Result<DomeProduct> {
        check_shape(shape)?;
        let start = Instant::now();
        let shared = self.shared(spec)?;
        let (eval, warm) = self.evaluator(&shared, spec);
        let table = dome_table(
            &eval,
            horizon_axis_deg(
                shape.elevation_count,
                lo,
                hi,
                -horizon_dip_deg(shared.medium.bottom_radius_m, spec.observer_altitude_m),
            ),
            shape.azimuth_count,
        );
        let probes = evaluate_probes(&eval, shared.medium.len(), probes);
        let stages = Self::plan(spec, &shared.medium);
        let meta = self.meta(&shared, spec, warm, start, stages);
        Ok(DomeProduct {
            table,
            probes,
            meta,
        })
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
        check_shape(shape)?;
        let cells = shape.elevation_count * shape.azimuth_count * distance_count;
        if cells > crate::spec::MAX_AERIAL_CELLS {
            return Err(crate::Error::too_large(
                "distance_count",
                format!("{cells} cells (elevations × azimuths × distances)"),
                crate::spec::MAX_AERIAL_CELLS,
            ));
        }
        let start = Instant::now();
        let shared = self.shared(spec)?;
        let (eval, warm) = self.evaluator(&shared, spec);
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
        transmittance
            .par_chunks_mut(per_dir)
            .zip(inscatter.par_chunks_mut(per_dir))
            .enumerate()
            .for_each_init(
                || (Scratch::new(n_l), vec![0.0; n_l], vec![0.0; n_l]),
                |(scratch, out, tr), (idx, (t_dst, s_dst))| {
                    let (row, col) = (idx / shape.azimuth_count, idx % shape.azimuth_count);
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
        let stages = Self::plan(spec, &shared.medium);
        let meta = self.meta(&shared, spec, warm, start, stages);
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

fn check_shape(shape: DomeShape) -> Result<()> {
    if shape.elevation_count < 2 || shape.elevation_count > 4096 {
        return Err(crate::Error::out_of_range(
            "elevation_count",
            shape.elevation_count,
            "2 to 4096",
        ));
    }
    if shape.azimuth_count < 1 || shape.azimuth_count > 4096 {
        return Err(crate::Error::out_of_range(
            "azimuth_count",
            shape.azimuth_count,
            "1 to 4096",
        ));
    }
    let cells = shape.elevation_count * shape.azimuth_count;
    if cells > crate::spec::MAX_TABLE_CELLS {
        return Err(crate::Error::too_large(
            "elevation_count",
            format!("{cells} table cells (elevations × azimuths)"),
            crate::spec::MAX_TABLE_CELLS,
        ));
    }
    Ok(())
}

/// Table resolutions for a quality preset.
pub fn settings_for(q: Quality) -> (FastSettings, PreciseSettings) {
    let fast = FastSettings::default();
    let precise = PreciseSettings::default();
    match q {
        Quality::Draft => (
            FastSettings {
                n_r: 16,
                n_mu_s: 32,
                steps: 12,
                ..fast
            },
            PreciseSettings {
                n_r: 12,
                n_mu_s: 20,
                n_mu: 24,
                n_phi: 8,
                steps: 12,
                tolerance: 1e-2,
                ..precise
            },
        ),
        Quality::Standard => (fast, precise),
        Quality::High => (
            FastSettings {
                directions_mu: 16,
                steps: 24,
                ..fast
            },
            PreciseSettings {
                n_r: 28,
                n_mu_s: 36,
                n_mu: 40,
                n_phi: 16,
                steps: 28,
                ..precise
            },
        ),
        Quality::Reference => (
            FastSettings {
                n_r: 64,
                n_mu_s: 96,
                directions_mu: 16,
                directions_phi: 16,
                steps: 32,
            },
            PreciseSettings {
                n_r: 36,
                n_mu_s: 48,
                n_mu: 48,
                n_phi: 20,
                steps: 40,
                tolerance: 1e-4,
                ..precise
            },
        ),
    }
}

/// Spectral transmittance from the top of the atmosphere to an observer at `altitude_m` along
/// the sun direction (elevation `sun_elevation_rad`), times the visible fraction of the sun's
/// disk; exact integration in f64 (not the table), valid from the ground to space.
pub fn sun_transmittance(m: &Medium, altitude_m: f64, sun_elevation_rad: f64) -> Vec<f64> {
    let r = m.bottom_radius_m + altitude_m;
    let mu_s = sun_elevation_rad.sin();
    // Visible fraction of the disk: the sun's centre may be below the geometric horizon.
    let mu_h = geometry::horizon_mu(r, m.bottom_radius_m);
    let width = (m.sun_angular_radius_rad * (1.0 - mu_h * mu_h).max(0.0).sqrt()).max(1e-9);
    let x = ((mu_s - mu_h) / width * 0.5 + 0.5).clamp(0.0, 1.0);
    let vis = x * x * (3.0 - 2.0 * x);
    if vis == 0.0 {
        return vec![0.0; m.len()];
    }
    let mu = mu_s.max(mu_h);
    let d = match geometry::atmosphere_segment(r, mu, m.bottom_radius_m, m.top_radius_m) {
        None => [0.0; 3],
        Some(seg) => {
            // Integrate from the far (upper) end towards the observer: densest part last, so
            // reverse the parametrisation by integrating from the observer outward in two
            // halves around the perigee when it lies on the path.
            let r0 = r.max(m.bottom_radius_m);
            let perigee = -r0 * mu;
            let piece = |a: f64, b: f64| -> [f64; 3] {
                if b <= a {
                    return [0.0; 3];
                }
                let ra = geometry::radius_at(r0, mu, a);
                let mu_a = ((r0 * mu + a) / ra).clamp(-1.0, 1.0);
                density_integrals(m, ra, mu_a, b - a, 4000)
            };
            let (a, b) = (seg.t_start, seg.t_end);
            if perigee > a && perigee < b {
                let p1 = piece(perigee, b);
                // The inbound half mirrors the outbound one from the perigee.
                let rp = geometry::radius_at(r0, mu, perigee);
                let p0 = density_integrals(m, rp, 0.0, perigee - a, 4000);
                [p0[0] + p1[0], p0[1] + p1[1], p0[2] + p1[2]]
            } else {
                piece(a, b)
            }
        }
    };
    (0..m.len())
        .map(|i| (-m.optical_depth(i, &d)).exp() * vis)
        .collect()
}

/// Diffuse irradiance on a horizontal surface at the observer, ∫ L cosθ dω over the upper
/// hemisphere (Gauss-Legendre in cosθ × midpoint in azimuth, symmetric about the sun plane).
pub fn hemisphere_irradiance(
    eval: &RadianceEvaluator,
    n_l: usize,
    n_mu: usize,
    n_phi: usize,
) -> Vec<f64> {
    let (x, w) = gauss_legendre(n_mu);
    let parts: Vec<Vec<f64>> = (0..n_mu * n_phi)
        .into_par_iter()
        .map_init(
            || (Scratch::new(n_l), vec![0.0; n_l], vec![0.0; n_l]),
            |(scratch, out, tr), idx| {
                let (a, b) = (idx / n_phi, idx % n_phi);
                let mu = 0.5 * (x[a] + 1.0);
                let phi = PI * (b as f64 + 0.5) / n_phi as f64;
                eval.eval(mu.acos(), phi, scratch, out, tr);
                let weight = 0.5 * w[a] * mu * 2.0 * PI / n_phi as f64;
                out.iter().map(|v| v * weight).collect()
            },
        )
        .collect();
    let mut e = vec![0.0; n_l];
    for p in parts {
        for (a, b) in e.iter_mut().zip(p) {
            *a += b;
        }
    }
    e
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
    use crate::spec::RequestParams;

    #[test]
    fn concurrent_requests_for_one_medium_build_its_tables_once() {
        let engine = Engine::new();
        let p = RequestParams {
            wavelengths: Some("550".into()),
            ..Default::default()
        };
        let spec = CommonSpec::from_params(&p, -18.0).unwrap();
        let tables: Vec<Arc<SharedTables>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4)
                .map(|_| s.spawn(|| engine.shared(&spec).unwrap()))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(engine.build_count("density"), 1);
        assert!(tables.iter().all(|t| Arc::ptr_eq(t, &tables[0])));
    }
}
