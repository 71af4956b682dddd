//! Radiance in any direction for an observer, and tables of it over the view sphere: the sky
//! dome (`sky`), the lower hemisphere of ground-reflected upward skylight (`ground`, Nishita et al. 1996,
//! §3.5), both from the same integrator so they join seamlessly at the horizon.

use super::integrate::{
    integrate_ray_counted, NoSource, RayWork, Recorder, Scratch, Source, Terms,
};
use super::shared::SharedTables;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

/// How orders of scattering ≥ 2 are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MsMethod {
    /// Successive orders on the spherical planet until the next adds < 0.1 %.
    Precise,
    /// Hillaire 2020 isotropic multiple-scattering table.
    Fast,
    /// Single scattering only (for references and diagnostics).
    None,
}

impl MsMethod {
    pub fn parse(s: &str) -> crate::Result<Self> {
        match s {
            "precise" => Ok(Self::Precise),
            "fast" => Ok(Self::Fast),
            "none" | "single" => Ok(Self::None),
            _ => Err(crate::Error::invalid(
                "method",
                format!("'{s}' is not one of precise, fast, none"),
            )),
        }
    }
}

/// Where the observer is and where the sun is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observer {
    /// Altitude above the ground, m.
    pub altitude_m: f64,
    /// Sun elevation above the observer's horizontal plane, radians.
    pub sun_elevation_rad: f64,
}

/// Evaluates radiance for one observer (W m⁻² sr⁻¹ nm⁻¹ per wavelength).
pub struct RadianceEvaluator<'a> {
    shared: &'a SharedTables,
    source: &'a dyn Source,
    has_source: bool,
    r: f64,
    mu_s: f64,
    steps: usize,
    single: bool,
    ground_bounce: bool,
    /// Work done so far: single-scattering samples, source samples, ground bounces.
    work: [AtomicU64; 3],
}

impl<'a> RadianceEvaluator<'a> {
    /// Prepares evaluation (builds the multiple-scattering table on first use).
    pub fn new(
        shared: &'a SharedTables,
        method: MsMethod,
        observer: Observer,
        steps: usize,
    ) -> Self {
        let source: &dyn Source = match method {
            MsMethod::Precise => shared.precise(),
            MsMethod::Fast => shared.fast(),
            MsMethod::None => &NoSource,
        };
        Self {
            shared,
            source,
            has_source: method != MsMethod::None,
            r: shared.medium.bottom_radius_m + observer.altitude_m,
            mu_s: observer.sun_elevation_rad.sin(),
            steps,
            single: true,
            ground_bounce: true,
            work: Default::default(),
        }
    }

    /// Which terms to integrate (the plan's stages): single scattering of direct sunlight, and
    /// the Lambertian ground bounce at the end of rays that hit the ground. Both on by default.
    pub fn with_terms(mut self, single: bool, ground_bounce: bool) -> Self {
        self.single = single;
        self.ground_bounce = ground_bounce;
        self
    }

    /// Work done by every ray traced so far (summed over threads).
    pub fn work(&self) -> RayWork {
        RayWork {
            single_samples: self.work[0].load(Ordering::Relaxed),
            source_samples: self.work[1].load(Ordering::Relaxed),
            ground_bounces: self.work[2].load(Ordering::Relaxed),
        }
    }

    /// Zenith cosine μ and view-sun cosine ν of the view direction with zenith `theta` and
    /// azimuth `phi` (relative to the sun), radians.
    pub fn direction(&self, theta: f64, phi: f64) -> (f64, f64) {
        let mu = theta.cos();
        let sin_s = (1.0 - self.mu_s * self.mu_s).max(0.0).sqrt();
        (
            mu,
            (mu * self.mu_s + theta.sin() * sin_s * phi.cos()).clamp(-1.0, 1.0),
        )
    }

    /// Integrates the view ray (μ, ν) from the observer with `steps` samples per segment:
    /// radiance per unit solar irradiance to `out`, transmittance to `tr`, and partial results
    /// at the recorder's distances if one is given.
    #[allow(clippy::too_many_arguments)]
    pub fn trace(
        &self,
        mu: f64,
        nu: f64,
        steps: usize,
        scratch: &mut Scratch,
        out: &mut [f64],
        tr: &mut [f64],
        rec: Option<&mut Recorder>,
    ) {
        let terms = Terms {
            single: self.single,
            ground_direct: self.ground_bounce,
        };
        let m = &self.shared.medium;
        let work = integrate_ray_counted(
            m,
            self.shared.density(),
            self.source,
            terms,
            self.ground_bounce,
            self.r,
            mu,
            self.mu_s,
            nu,
            steps,
            scratch,
            out,
            tr,
            rec,
        );
        // One relaxed add per counter per ray: negligible next to the ray's samples.
        if work.single_samples > 0 {
            self.work[0].fetch_add(work.single_samples, Ordering::Relaxed);
        }
        if self.has_source && work.source_samples > 0 {
            self.work[1].fetch_add(work.source_samples, Ordering::Relaxed);
        }
        if work.ground_bounces > 0 {
            self.work[2].fetch_add(work.ground_bounces, Ordering::Relaxed);
        }
    }

    /// Radiance arriving from view zenith `theta` and azimuth `phi` (relative to the sun),
    /// radians, written to `out` in W m⁻² sr⁻¹ nm⁻¹; also the path transmittance to `tr`.
    pub fn eval(
        &self,
        theta: f64,
        phi: f64,
        scratch: &mut Scratch,
        out: &mut [f64],
        tr: &mut [f64],
    ) {
        let (mu, nu) = self.direction(theta, phi);
        self.trace(mu, nu, self.steps, scratch, out, tr, None);
        for (o, e) in out.iter_mut().zip(&self.shared.medium.solar_irradiance) {
            *o *= e;
        }
    }
}

/// View elevations (degrees) from `lo_deg` to `hi_deg`, `n` nodes, concentrated quadratically
/// at `centre_deg` (the observer's geometric horizon: 0° on the ground, below 0° aloft), which is
/// a node whenever it lies inside the range and `n` allows.
pub fn horizon_axis_deg(n: usize, lo_deg: f64, hi_deg: f64, centre_deg: f64) -> Vec<f64> {
    let centre = centre_deg.clamp(lo_deg, hi_deg);
    let x_lo = if lo_deg < centre { -1.0 } else { 0.0 };
    let x_hi = if hi_deg > centre { 1.0 } else { 0.0 };
    (0..n)
        .map(|k| {
            let x = if n == 1 {
                0.0
            } else {
                x_lo + (x_hi - x_lo) * k as f64 / (n - 1) as f64
            };
            let scale = if x < 0.0 {
                centre - lo_deg
            } else {
                hi_deg - centre
            };
            centre + x.signum() * x * x * scale
        })
        .collect()
}

/// Depression of the geometric horizon below the horizontal for an observer at `altitude_m`
/// above a sphere of radius `radius_m`, degrees (0 on the ground).
pub fn horizon_dip_deg(radius_m: f64, altitude_m: f64) -> f64 {
    (radius_m / (radius_m + altitude_m.max(0.0)))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// A table of radiance over view elevation × azimuth (relative to the sun, 0–180°).
#[derive(Debug, Clone, PartialEq)]
pub struct DomeTable {
    pub wavelengths_nm: Vec<f64>,
    /// Row coordinates: view elevation above the horizontal, degrees (view zenith = 90 − this).
    pub elevation_deg: Vec<f64>,
    /// Column coordinates: view azimuth relative to the sun, degrees (0 = towards the sun).
    pub azimuth_deg: Vec<f64>,
    /// Radiance, W m⁻² sr⁻¹ nm⁻¹, `[row][col][λ]`.
    pub radiance: Vec<f32>,
}

/// Computes a dome table (parallel over directions).
pub fn dome_table(
    eval: &RadianceEvaluator,
    elevation_deg: Vec<f64>,
    n_azimuth: usize,
) -> DomeTable {
    dome_table_unless(eval, elevation_deg, n_azimuth, &|| false)
        .unwrap_or_else(|| unreachable!("never cancelled"))
}

/// [`dome_table`], stopped (`None`) when `cancelled` returns true: it is asked once per row of
/// elevation, as the row's first entry starts, so an abandoned request stops within a row.
pub fn dome_table_unless(
    eval: &RadianceEvaluator,
    elevation_deg: Vec<f64>,
    n_azimuth: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Option<DomeTable> {
    let stopped = std::sync::atomic::AtomicBool::new(false);
    let n_l = eval.shared.medium.len();
    let azimuth_deg: Vec<f64> = (0..n_azimuth)
        .map(|k| {
            if n_azimuth == 1 {
                0.0
            } else {
                180.0 * k as f64 / (n_azimuth - 1) as f64
            }
        })
        .collect();
    let mut radiance = vec![0.0f32; elevation_deg.len() * n_azimuth * n_l];
    radiance.par_chunks_mut(n_l).enumerate().for_each_init(
        || (Scratch::new(n_l), vec![0.0; n_l], vec![0.0; n_l]),
        |(scratch, out, tr), (idx, dst)| {
            let (row, col) = (idx / n_azimuth, idx % n_azimuth);
            if stopped.load(std::sync::atomic::Ordering::Relaxed) {
                return;
            }
            if col == 0 && cancelled() {
                stopped.store(true, std::sync::atomic::Ordering::Relaxed);
                return;
            }
            let theta = (90.0 - elevation_deg[row]).to_radians();
            eval.eval(theta, azimuth_deg[col].to_radians(), scratch, out, tr);
            for (d, v) in dst.iter_mut().zip(out.iter()) {
                *d = *v as f32;
            }
        },
    );
    if stopped.into_inner() {
        return None;
    }
    Some(DomeTable {
        wavelengths_nm: eval.shared.medium.wavelengths_nm.clone(),
        elevation_deg,
        azimuth_deg,
        radiance,
    })
}
