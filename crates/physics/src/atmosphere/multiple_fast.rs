//! Fast multiple scattering: the isotropic multiple-scattering table of Hillaire 2020
//! ("A Scalable and Production Ready Sky and Atmosphere Rendering Technique", §5.5, eqs. 5–10).
//!
//! At each (r, μ_s), L₂ = (1/4π)∮ L′(ω) dω with L′ the single-scattered (and ground-reflected)
//! radiance arriving from ω, and f_ms = (1/4π)∮ ∫ T σ_s dt dω the fraction of an isotropic source
//! that comes back; all orders ≥ 2 then sum to Ψ_ms = L₂ / (1 − f_ms), a geometric series.
//! The in-scattering source of orders ≥ 2 is J_ms(y) = σ_s(y) Ψ_ms(r_y, μ_s,y) (isotropic).

use super::geometry::safe_sqrt;
use super::integrate::{integrate_ray, ray_samples, NoSource, RaySample, Scratch, Source, Terms};
use super::medium::{Medium, CONSTITUENTS, MIE, RAYLEIGH};
use super::quadrature::{gauss_legendre, grid_pos};
use super::transmittance::DensityIntegralTable;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Resolution and quadrature of the fast method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FastSettings {
    pub n_r: usize,
    pub n_mu_s: usize,
    pub directions_mu: usize,
    pub directions_phi: usize,
    pub steps: usize,
}

impl Default for FastSettings {
    fn default() -> Self {
        Self {
            n_r: 32,
            n_mu_s: 48,
            directions_mu: 8,
            directions_phi: 8,
            steps: 16,
        }
    }
}

/// The Ψ_ms table and the sky irradiance on the ground it implies.
pub struct FastMultipleScattering {
    n_r: usize,
    n_mu_s: usize,
    n_l: usize,
    bottom: f64,
    top: f64,
    scattering: [Vec<f64>; 2],
    profiles: [super::medium::Profile; CONSTITUENTS],
    /// Ψ_ms, `[i_r][i_mu_s][λ]`.
    psi: Vec<f64>,
    /// Sky irradiance on the ground per unit solar irradiance, `[i_mu_s][λ]`.
    ground_sky: Vec<f64>,
}

fn x_r_of(r: f64, bottom: f64, top: f64) -> f64 {
    let h = safe_sqrt(top * top - bottom * bottom);
    safe_sqrt(r * r - bottom * bottom) / h
}

fn r_of(x_r: f64, bottom: f64, top: f64) -> f64 {
    let h = safe_sqrt(top * top - bottom * bottom);
    let rho = x_r * h;
    safe_sqrt(rho * rho + bottom * bottom)
}

impl FastMultipleScattering {
    /// Builds the table for `medium` (parallel over table entries).
    pub fn new(medium: &Medium, table: &DensityIntegralTable, s: FastSettings) -> Self {
        Self::new_unless(medium, table, s, &|| false)
            .unwrap_or_else(|| unreachable!("never cancelled"))
    }

    /// [`Self::new`], stopped (`None`) when `cancelled` returns true: it is asked once per row of
    /// radius of each ψ pass and before each pass, so an abandoned request stops within a row.
    pub fn new_unless(
        medium: &Medium,
        table: &DensityIntegralTable,
        s: FastSettings,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<Self> {
        let stopped = std::sync::atomic::AtomicBool::new(false);
        let stop = || {
            stopped.load(std::sync::atomic::Ordering::Relaxed) || {
                let now = cancelled();
                stopped.fetch_or(now, std::sync::atomic::Ordering::Relaxed);
                now
            }
        };
        let n_l = medium.len();
        let (bottom, top) = (medium.bottom_radius_m, medium.top_radius_m);
        let (gx, gw) = gauss_legendre(s.directions_mu);
        let compute_psi = |ground: &dyn Source| -> Vec<f64> {
            (0..s.n_r * s.n_mu_s)
                .into_par_iter()
                .flat_map_iter(|idx| {
                    // Once stopped, the remaining entries are skipped (the result is dropped).
                    if stopped.load(std::sync::atomic::Ordering::Relaxed)
                        || (idx % s.n_mu_s == 0 && stop())
                    {
                        return Vec::new();
                    }
                    let r = r_of((idx / s.n_mu_s) as f64 / (s.n_r - 1) as f64, bottom, top);
                    let mu_s = -1.0 + 2.0 * (idx % s.n_mu_s) as f64 / (s.n_mu_s - 1) as f64;
                    let mut scratch = Scratch::new(n_l);
                    let mut l1 = vec![0.0; n_l];
                    let mut tr = vec![0.0; n_l];
                    let mut l2 = vec![0.0; n_l];
                    let mut fms = vec![0.0; n_l];
                    let sin_s = safe_sqrt(1.0 - mu_s * mu_s);
                    for (a, &mu) in gx.iter().enumerate() {
                        let sin_v = safe_sqrt(1.0 - mu * mu);
                        for b in 0..s.directions_phi {
                            let phi = 2.0 * PI * (b as f64 + 0.5) / s.directions_phi as f64;
                            // Solid-angle weight of this direction, times the isotropic phase 1/(4π).
                            let w = gw[a] * 2.0 * PI / s.directions_phi as f64 / (4.0 * PI);
                            // Light arriving from direction ω travels along −ω: integrate the ray
                            // looking towards ω (mu, nu as seen by the viewer).
                            let nu = mu * mu_s + sin_v * sin_s * phi.cos();
                            let terms = Terms {
                                single: true,
                                ground_direct: true,
                            };
                            integrate_ray(
                                medium,
                                table,
                                ground,
                                terms,
                                r,
                                mu,
                                mu_s,
                                nu,
                                s.steps,
                                &mut scratch,
                                &mut l1,
                                &mut tr,
                                None,
                            );
                            let (_, samples) = ray_samples(medium, r, mu, mu_s, nu, s.steps);
                            let mut d_view = [0.0; CONSTITUENTS];
                            for smp in &samples {
                                let rho = medium.densities(smp.r);
                                let mut d_mid = d_view;
                                for k in 0..CONSTITUENTS {
                                    d_mid[k] += 0.5 * rho[k] * smp.weight;
                                    d_view[k] += rho[k] * smp.weight;
                                }
                                for i in 0..n_l {
                                    let sigma_s = medium.rayleigh_scattering_per_m[i]
                                        * rho[RAYLEIGH]
                                        + medium.mie_scattering_per_m[i] * rho[MIE];
                                    fms[i] += w
                                        * (-medium.optical_depth(i, &d_mid)).exp()
                                        * sigma_s
                                        * smp.weight;
                                }
                            }
                            for i in 0..n_l {
                                l2[i] += w * l1[i];
                            }
                        }
                    }
                    (0..n_l)
                        .map(|i| l2[i] / (1.0 - fms[i].min(0.999)))
                        .collect::<Vec<f64>>()
                })
                .collect()
        };
        let mut fast = Self {
            n_r: s.n_r,
            n_mu_s: s.n_mu_s,
            n_l,
            bottom,
            top,
            scattering: [
                medium.rayleigh_scattering_per_m.clone(),
                medium.mie_scattering_per_m.clone(),
            ],
            profiles: medium.profiles,
            psi: compute_psi(&NoSource),
            ground_sky: vec![0.0; s.n_mu_s * n_l],
        };
        if stop() {
            return None;
        }
        fast.ground_sky =
            ground_sky_irradiance(medium, table, &fast, s.n_mu_s, 16, 16, s.steps * 2);
        // Hillaire's transfer factor leaves out light that the ground sends back up. A second
        // pass adds the ground's reflection of the first pass's skylight to L′, then recomputes
        // the skylight: one more bounce between ground and sky, where most of that light is.
        if medium.ground_albedo.iter().any(|&a| a > 0.0) {
            let ground = GroundSky {
                table: &fast.ground_sky,
                n_mu_s: s.n_mu_s,
                n_l,
            };
            if stop() {
                return None;
            }
            let psi = compute_psi(&ground);
            if stop() {
                return None;
            }
            fast.psi = psi;
            fast.ground_sky =
                ground_sky_irradiance(medium, table, &fast, s.n_mu_s, 16, 16, s.steps * 2);
        }
        Some(fast)
    }
}

/// Sky irradiance on the ground only (no scattering source): the ground term of L′.
struct GroundSky<'a> {
    table: &'a [f64],
    n_mu_s: usize,
    n_l: usize,
}

impl Source for GroundSky<'_> {
    fn add_scattering(&self, _: &RaySample, _: &mut [f64]) {}
    fn add_ground_sky_irradiance(&self, mu_s: f64, out: &mut [f64]) {
        interp_mu_s_table(self.table, self.n_mu_s, self.n_l, mu_s, out);
    }
}

impl Source for FastMultipleScattering {
    fn add_scattering(&self, s: &RaySample, out: &mut [f64]) {
        let h = s.r - self.bottom;
        let (rr, rm) = (
            self.profiles[RAYLEIGH].density(h),
            self.profiles[MIE].density(h),
        );
        let (ir, fr) = grid_pos(x_r_of(s.r, self.bottom, self.top), self.n_r);
        let (im, fm) = grid_pos(0.5 * (s.mu_s + 1.0), self.n_mu_s);
        let n = self.n_l;
        let idx = |a: usize, b: usize| (a * self.n_mu_s + b) * n;
        let (i00, i01, i10, i11) = (
            idx(ir, im),
            idx(ir, im + 1),
            idx(ir + 1, im),
            idx(ir + 1, im + 1),
        );
        for i in 0..n {
            let v0 = self.psi[i00 + i] * (1.0 - fm) + self.psi[i01 + i] * fm;
            let v1 = self.psi[i10 + i] * (1.0 - fm) + self.psi[i11 + i] * fm;
            let sigma_s = self.scattering[0][i] * rr + self.scattering[1][i] * rm;
            out[i] += sigma_s * (v0 * (1.0 - fr) + v1 * fr);
        }
    }

    fn add_ground_sky_irradiance(&self, mu_s: f64, out: &mut [f64]) {
        interp_mu_s_table(&self.ground_sky, self.n_mu_s, self.n_l, mu_s, out);
    }
}

/// Linear interpolation in a `[i_mu_s][λ]` table on the uniform μ_s ∈ [−1, 1] grid, added to `out`.
pub fn interp_mu_s_table(table: &[f64], n_mu_s: usize, n_l: usize, mu_s: f64, out: &mut [f64]) {
    let (im, fm) = grid_pos(0.5 * (mu_s + 1.0), n_mu_s);
    for i in 0..n_l {
        out[i] += table[im * n_l + i] * (1.0 - fm) + table[(im + 1) * n_l + i] * fm;
    }
}

/// Sky irradiance on the ground, E(μ_s) = ∫ L cosθ dω over the upper hemisphere, per unit solar
/// irradiance, on the uniform μ_s ∈ [−1, 1] grid; L from single scattering plus `source`.
pub fn ground_sky_irradiance(
    medium: &Medium,
    table: &DensityIntegralTable,
    source: &dyn Source,
    n_mu_s: usize,
    dirs_mu: usize,
    dirs_phi: usize,
    steps: usize,
) -> Vec<f64> {
    let n_l = medium.len();
    let r = medium.bottom_radius_m;
    let (gx, gw) = gauss_legendre(dirs_mu);
    (0..n_mu_s)
        .into_par_iter()
        .flat_map_iter(|j| {
            let mu_s = -1.0 + 2.0 * j as f64 / (n_mu_s - 1) as f64;
            let sin_s = safe_sqrt(1.0 - mu_s * mu_s);
            let mut scratch = Scratch::new(n_l);
            let (mut l, mut tr) = (vec![0.0; n_l], vec![0.0; n_l]);
            let mut e = vec![0.0; n_l];
            for (a, &x) in gx.iter().enumerate() {
                let mu = 0.5 * (x + 1.0); // upper hemisphere, μ ∈ (0, 1)
                let sin_v = safe_sqrt(1.0 - mu * mu);
                for b in 0..dirs_phi {
                    let phi = PI * (b as f64 + 0.5) / dirs_phi as f64;
                    let nu = mu * mu_s + sin_v * sin_s * phi.cos();
                    let terms = Terms {
                        single: true,
                        ground_direct: false,
                    };
                    integrate_ray(
                        medium,
                        table,
                        source,
                        terms,
                        r,
                        mu,
                        mu_s,
                        nu,
                        steps,
                        &mut scratch,
                        &mut l,
                        &mut tr,
                        None,
                    );
                    // dω = dμ dφ; both halves of the azimuth circle by symmetry.
                    let w = 0.5 * gw[a] * mu * 2.0 * PI / dirs_phi as f64;
                    for i in 0..n_l {
                        e[i] += w * l[i];
                    }
                }
            }
            e.into_iter()
        })
        .collect()
}
