//! Precise multiple scattering by successive orders on the spherical planet (the method of
//! Bruneton & Neyret 2008 / Bruneton 2017, reorganised for CPUs), with ground bounce.
//!
//! Fields live on a regular grid over (r, θ_s, θ, φ): radius, sun zenith, view zenith and view
//! azimuth relative to the sun (φ ∈ [0, π] by symmetry). For order n:
//!
//! - L_n(x, ω) = ∫ T(x, y) J_n(y, ω) ds + T(x, g)(a/π) E_{n−1}(g) along the ray (L_1 is exact single
//!   scattering plus the ground's reflection of direct sun, E_0 = direct irradiance);
//! - E_n = ∫ L_n(ground, ω) cosθ dω, the sky irradiance on the ground;
//! - J_{n+1}(x, ω) = Σ_c σ_c(x) ∫ p_c(ω·ω′) L_n(x, ω′) dω′ — at fixed (r, θ_s) this is a matrix
//!   product with a phase matrix whose entries are the phase function integrated over each
//!   direction cell (rows normalised to exactly 1, so the angular quadrature conserves energy).
//!
//! Orders are added until the last one contributes less than `tolerance` (0.1 %) of the total
//! radiance. Products integrate J_ms = Σ_{n≥2} J_n along their own rays at full resolution,
//! beside exact single scattering, so the table only has to resolve the smooth multiple part.
//! Tables are interpolated in ln J, Catmull–Rom in sun zenith, so that the steep fall of J across
//! the terminator is followed in twilight (issue 14; see [`lookup_j`]).

use super::geometry::{horizon_mu, safe_sqrt};
use super::integrate::{integrate_ray, NoSource, RaySample, Scratch, Source, Terms};
use super::medium::{Medium, MIE, RAYLEIGH};
use super::quadrature::grid_pos;
use super::transmittance::DensityIntegralTable;
use crate::phase::Phase;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Resolution and convergence settings of the precise method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreciseSettings {
    pub n_r: usize,
    pub n_mu_s: usize,
    pub n_mu: usize,
    pub n_phi: usize,
    /// Samples per ray segment when integrating J along table rays.
    pub steps: usize,
    /// Stop when the last order adds less than this fraction of the total.
    pub tolerance: f64,
    /// Never compute more orders than this.
    pub max_orders: usize,
    /// Cells whose centre lies within this angle of the local horizon are averaged over sub-rays.
    pub horizon_band_rad: f64,
    /// Sub-rays per cell (per side of the horizon) in that band.
    pub horizon_subrays: usize,
}

impl Default for PreciseSettings {
    fn default() -> Self {
        Self {
            n_r: 20,
            n_mu_s: 28,
            n_mu: 32,
            n_phi: 12,
            steps: 20,
            tolerance: 1e-3,
            max_orders: 60,
            horizon_band_rad: 10f64.to_radians(),
            horizon_subrays: 3,
        }
    }
}

/// Convergence record of one precise computation.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Convergence {
    /// Number of scattering orders computed (including the first).
    pub orders: usize,
    /// Fraction of the total that the last order added.
    pub last_order_fraction: f64,
    /// Fraction each order added, in order.
    pub order_fractions: Vec<f64>,
}

/// The converged multiple-scattering source J_ms = Σ_{n≥2} J_n and ground sky irradiance.
pub struct PreciseMultipleScattering {
    grid: Grid,
    n_l: usize,
    /// `[cell][λ]`, ln of the scattering source of orders ≥ 2, m⁻¹ sr⁻¹ per unit solar
    /// irradiance (−∞ where it is zero).
    ln_j_ms: Vec<f64>,
    /// `[i_mu_s][λ]`, ln of the sky irradiance on the ground per unit solar irradiance.
    ln_ground_sky: Vec<f64>,
    pub convergence: Convergence,
}

#[derive(Debug, Clone, Copy)]
struct Grid {
    s: PreciseSettings,
    bottom: f64,
    top: f64,
    theta_s_max: f64,
}

impl Grid {
    fn dirs(&self) -> usize {
        self.s.n_mu * self.s.n_phi
    }
    fn cells(&self) -> usize {
        self.s.n_r * self.s.n_mu_s * self.dirs()
    }
    fn r(&self, i: usize) -> f64 {
        let h = safe_sqrt(self.top * self.top - self.bottom * self.bottom);
        let rho = h * i as f64 / (self.s.n_r - 1) as f64;
        safe_sqrt(rho * rho + self.bottom * self.bottom)
    }
    fn x_r(&self, r: f64) -> f64 {
        let h = safe_sqrt(self.top * self.top - self.bottom * self.bottom);
        safe_sqrt(r * r - self.bottom * self.bottom) / h
    }
    fn theta_s(&self, j: usize) -> f64 {
        self.theta_s_max * j as f64 / (self.s.n_mu_s - 1) as f64
    }
    /// View zenith of direction node `k` (cell centres, uniform in angle).
    fn theta(&self, k: usize) -> f64 {
        PI * (k as f64 + 0.5) / self.s.n_mu as f64
    }
    fn phi(&self, l: usize) -> f64 {
        PI * (l as f64 + 0.5) / self.s.n_phi as f64
    }
    /// Interpolation position on a cell-centred grid of `n` nodes over [0, π].
    fn centred_pos(angle: f64, n: usize) -> (usize, f64) {
        let f = (angle / PI * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i = (f.floor() as usize).min(n.saturating_sub(2));
        (i, f - i as f64)
    }
}

/// Phase matrices for the Rayleigh and Mie components, `[o][i]`: ∫_{cell i and its mirror}
/// p(ω_o·ω) dω, rows normalised to sum to 1.
fn phase_matrices(grid: &Grid, mie: Phase) -> [Vec<f64>; 2] {
    let d = grid.dirs();
    let (n_mu, n_phi) = (grid.s.n_mu, grid.s.n_phi);
    let dir = |theta: f64, phi: f64| {
        let s = theta.sin();
        [s * phi.cos(), s * phi.sin(), theta.cos()]
    };
    let sub = 6;
    [Phase::Rayleigh, mie].map(|phase| {
        let mut m: Vec<f64> = (0..d * d)
            .into_par_iter()
            .map(|oi| {
                let (o, i) = (oi / d, oi % d);
                let wo = dir(grid.theta(o / n_phi), grid.phi(o % n_phi));
                let (k, l) = (i / n_phi, i % n_phi);
                let (t0, t1) = (
                    PI * k as f64 / n_mu as f64,
                    PI * (k + 1) as f64 / n_mu as f64,
                );
                let (p0, p1) = (
                    PI * l as f64 / n_phi as f64,
                    PI * (l + 1) as f64 / n_phi as f64,
                );
                let mut sum = 0.0;
                for a in 0..sub {
                    let th = t0 + (t1 - t0) * (a as f64 + 0.5) / sub as f64;
                    let w = th.sin() * (t1 - t0) / sub as f64 * (p1 - p0) / sub as f64;
                    for b in 0..sub {
                        let ph = p0 + (p1 - p0) * (b as f64 + 0.5) / sub as f64;
                        for sign in [1.0, -1.0] {
                            let wi = dir(th, sign * ph);
                            let c = wo[0] * wi[0] + wo[1] * wi[1] + wo[2] * wi[2];
                            sum += phase.eval(c) * w;
                        }
                    }
                }
                sum
            })
            .collect();
        for row in m.chunks_mut(d) {
            let s: f64 = row.iter().sum();
            if s > 0.0 {
                row.iter_mut().for_each(|v| *v /= s);
            }
        }
        m
    })
}

/// Solid angle × cosθ of each upward direction cell (both mirror halves), for E = ∫ L cosθ dω.
fn upward_cosine_weights(grid: &Grid) -> Vec<f64> {
    let (n_mu, n_phi) = (grid.s.n_mu, grid.s.n_phi);
    let dphi = PI / n_phi as f64;
    let mut w = vec![0.0; grid.dirs()];
    for k in 0..n_mu {
        let (t0, t1) = (
            PI * k as f64 / n_mu as f64,
            (PI * (k + 1) as f64 / n_mu as f64).min(PI / 2.0),
        );
        if t1 <= t0 {
            continue;
        }
        // ∫ cosθ sinθ dθ = (sin²t1 − sin²t0)/2, times 2Δφ for the cell and its mirror.
        let v = (t1.sin().powi(2) - t0.sin().powi(2)) * dphi;
        for l in 0..n_phi {
            w[k * n_phi + l] = v;
        }
    }
    w
}

/// A source made of one order's J table and the previous order's ground irradiance, both as ln.
struct OrderSource<'a> {
    grid: &'a Grid,
    n_l: usize,
    ln_j: &'a [f64],
    ln_ground: &'a [f64],
}

/// Catmull–Rom weights and node indices for position `(i, f)` on a grid of `n` nodes (end
/// nodes repeated at the edges).
fn catmull_rom(i: usize, f: f64, n: usize) -> ([usize; 4], [f64; 4]) {
    let (f2, f3) = (f * f, f * f * f);
    (
        [
            i.saturating_sub(1),
            i,
            (i + 1).min(n - 1),
            (i + 2).min(n - 1),
        ],
        [
            0.5 * (-f3 + 2.0 * f2 - f),
            0.5 * (3.0 * f3 - 5.0 * f2 + 2.0),
            0.5 * (-3.0 * f3 + 4.0 * f2 + f),
            0.5 * (f3 - f2),
        ],
    )
}

/// Natural logarithm of every table entry (−∞ for zeros): the tables are interpolated in
/// ln J (see [`lookup_j`]).
fn ln_table(j: &[f64]) -> Vec<f64> {
    j.par_iter()
        .map(|&v| if v > 0.0 { v.ln() } else { f64::NEG_INFINITY })
        .collect()
}

/// Interpolates a J table stored as ln J at a ray sample, adding J to `out[λ]`.
///
/// Across the terminator J falls by about an order of magnitude per table step in sun zenith
/// (the lower atmosphere then sees only light scattered from the lit air above and towards the
/// sun), so linear interpolation of J overestimates it between nodes: by 30–100 % in the sky
/// away from the sun at −2° to −9° (issue 14). ln J is smooth through the terminator and close to
/// linear beyond it, so the table is interpolated in ln J: Catmull–Rom in sun zenith (exact for
/// an exponential decay, third order where ln J bends at the terminator), multilinear in radius
/// and direction (where ln J is close to linear too: J ∝ air density in r). Where a corner is
/// zero (deep twilight, ln J = −∞) the interpolation falls back to multilinear in J.
fn lookup_j(grid: &Grid, n_l: usize, ln_j: &[f64], s: &RaySample, out: &mut [f64]) {
    let theta_s = s.mu_s.clamp(-1.0, 1.0).acos();
    if theta_s > grid.theta_s_max {
        return;
    }
    let (ir, fr) = grid_pos(grid.x_r(s.r), grid.s.n_r);
    let (is, fs) = grid_pos(theta_s / grid.theta_s_max, grid.s.n_mu_s);
    let theta = s.mu.clamp(-1.0, 1.0).acos();
    let (im, fm) = Grid::centred_pos(theta, grid.s.n_mu);
    let denom = safe_sqrt(1.0 - s.mu * s.mu) * safe_sqrt(1.0 - s.mu_s * s.mu_s);
    let cos_phi = if denom > 1e-9 {
        ((s.nu - s.mu * s.mu_s) / denom).clamp(-1.0, 1.0)
    } else {
        1.0
    };
    let (ip, fp) = Grid::centred_pos(cos_phi.acos(), grid.s.n_phi);
    let (n_mu_s, n_mu, n_phi) = (grid.s.n_mu_s, grid.s.n_mu, grid.s.n_phi);
    let (nodes_s, w_s) = catmull_rom(is, fs, n_mu_s);
    let mut acc = [0.0f64; crate::spectrum::wavelengths::MAX_WAVELENGTHS];
    let acc = &mut acc[..n_l];
    let mut corners = [(0usize, 0.0f64); 8];
    let mut k = 0;
    for (a, wa) in [(ir, 1.0 - fr), (ir + 1, fr)] {
        for (c, wc) in [(im, 1.0 - fm), (im + 1, fm)] {
            for (e, we) in [(ip, 1.0 - fp), (ip + 1, fp)] {
                corners[k] = ((a * n_mu_s * n_mu + c) * n_phi + e, wa * wc * we);
                k += 1;
            }
        }
    }
    // Stride of one sun-zenith node in the flat index.
    let stride_s = n_mu * n_phi;
    for &(base, w) in &corners {
        if w == 0.0 {
            continue;
        }
        for (&b, &ws) in nodes_s.iter().zip(&w_s) {
            if ws == 0.0 {
                continue;
            }
            let row = &ln_j[(base + b * stride_s) * n_l..][..n_l];
            for (a, v) in acc.iter_mut().zip(row) {
                *a += w * ws * v;
            }
        }
    }
    for i in 0..n_l {
        if acc[i].is_finite() {
            out[i] += acc[i].exp();
        } else {
            // A zero corner: multilinear in J.
            for &(base, w) in &corners {
                if w == 0.0 {
                    continue;
                }
                for (b, wb) in [(is, 1.0 - fs), (is + 1, fs)] {
                    out[i] += w * wb * ln_j[(base + b * stride_s) * n_l + i].exp();
                }
            }
        }
    }
}

/// Sky irradiance on the ground from a table stored as ln E over sun zenith (Catmull–Rom in
/// ln E, as [`lookup_j`]; linear in E where a node is zero).
fn lookup_ground(grid: &Grid, n_l: usize, ln_table: &[f64], mu_s: f64, out: &mut [f64]) {
    let theta_s = mu_s.clamp(-1.0, 1.0).acos();
    if theta_s > grid.theta_s_max {
        return;
    }
    let (is, fs) = grid_pos(theta_s / grid.theta_s_max, grid.s.n_mu_s);
    let (nodes, w) = catmull_rom(is, fs, grid.s.n_mu_s);
    for i in 0..n_l {
        let v: f64 = (0..4).map(|q| w[q] * ln_table[nodes[q] * n_l + i]).sum();
        out[i] += if v.is_finite() {
            v.exp()
        } else {
            ln_table[is * n_l + i].exp() * (1.0 - fs) + ln_table[(is + 1) * n_l + i].exp() * fs
        };
    }
}

impl Source for OrderSource<'_> {
    fn add_scattering(&self, s: &RaySample, out: &mut [f64]) {
        lookup_j(self.grid, self.n_l, self.ln_j, s, out);
    }
    fn add_ground_sky_irradiance(&self, mu_s: f64, out: &mut [f64]) {
        lookup_ground(self.grid, self.n_l, self.ln_ground, mu_s, out);
    }
}

impl PreciseMultipleScattering {
    /// Computes orders of scattering until convergence.
    pub fn new(medium: &Medium, table: &DensityIntegralTable, s: PreciseSettings) -> Self {
        let (bottom, top) = (medium.bottom_radius_m, medium.top_radius_m);
        // Beyond 12° below the top's horizon no point of the atmosphere sees any light worth
        // tabulating.
        let theta_s_max = (horizon_mu(top, bottom).acos() + 12f64.to_radians()).min(PI);
        let grid = Grid {
            s,
            bottom,
            top,
            theta_s_max,
        };
        let n_l = medium.len();
        let dirs = grid.dirs();
        let slab = dirs * n_l;
        let phase = phase_matrices(&grid, medium.mie_phase);
        let up_w = upward_cosine_weights(&grid);

        // Radiance of one order on every cell, given a source and which direct terms to include.
        let compute_l = |source: &dyn Source, terms: Terms| -> Vec<f64> {
            let mut l = vec![0.0; grid.cells() * n_l];
            l.par_chunks_mut(n_l).enumerate().for_each_init(
                || (Scratch::new(n_l), vec![0.0; n_l]),
                |(scratch, tr), (cell, out)| {
                    let e = cell % dirs;
                    let rs = cell / dirs;
                    let (ir, is) = (rs / s.n_mu_s, rs % s.n_mu_s);
                    let r = grid.r(ir);
                    let k = e / s.n_phi;
                    let (ts, th, ph) = (grid.theta_s(is), grid.theta(k), grid.phi(e % s.n_phi));
                    let mu_s = ts.cos();
                    let ray =
                        |theta: f64, scratch: &mut Scratch, out: &mut [f64], tr: &mut [f64]| {
                            let mu = theta.cos();
                            let nu = mu * mu_s + theta.sin() * ts.sin() * ph.cos();
                            integrate_ray(
                                medium, table, source, terms, r, mu, mu_s, nu, s.steps, scratch,
                                out, tr, None,
                            );
                        };
                    // A cell the horizon cuts holds ground on one side and sky on the other: its
                    // value is the solid-angle average of sub-rays on both sides, not the centre's.
                    let (t0, t1) = (
                        PI * k as f64 / s.n_mu as f64,
                        PI * (k + 1) as f64 / s.n_mu as f64,
                    );
                    let theta_h = horizon_mu(r, bottom).acos();
                    // Near the local horizon, L changes fast (long grazing paths on both sides,
                    // ground on one): the cell value is the solid-angle average of sub-rays,
                    // split at the horizon, instead of the value at the cell centre.
                    let straddles = theta_h > t0 + 1e-9 && theta_h < t1 - 1e-9;
                    let near = (th - theta_h).abs() < s.horizon_band_rad;
                    if straddles || near {
                        let pieces: &[(f64, f64)] = if straddles {
                            &[(t0, theta_h), (theta_h, t1)]
                        } else {
                            &[(t0, t1)]
                        };
                        let sub = s.horizon_subrays;
                        let mut acc = vec![0.0; n_l];
                        let mut wsum = 0.0;
                        for &(a, b) in pieces {
                            for q in 0..sub {
                                let theta = a + (b - a) * (q as f64 + 0.5) / sub as f64;
                                let w = theta.sin() * (b - a);
                                ray(theta, scratch, out, tr);
                                for i in 0..n_l {
                                    acc[i] += w * out[i];
                                }
                                wsum += w;
                            }
                        }
                        for i in 0..n_l {
                            out[i] = acc[i] / wsum;
                        }
                    } else {
                        ray(th, scratch, out, tr);
                    }
                },
            );
            l
        };
        // Sky irradiance on the ground from one order's radiance at r = bottom.
        let ground_of = |l: &[f64]| -> Vec<f64> {
            let mut e = vec![0.0; s.n_mu_s * n_l];
            for is in 0..s.n_mu_s {
                let base = is * slab;
                for (d, w) in up_w.iter().enumerate() {
                    if *w == 0.0 {
                        continue;
                    }
                    for i in 0..n_l {
                        e[is * n_l + i] += w * l[base + d * n_l + i];
                    }
                }
            }
            e
        };
        // J of the next order from one order's radiance: per (r, θ_s) slab, a matrix product.
        let compute_j = |l: &[f64]| -> Vec<f64> {
            let mut j = vec![0.0; grid.cells() * n_l];
            j.par_chunks_mut(slab).enumerate().for_each_init(
                || vec![0.0; 2 * n_l],
                |acc, (rs, out)| {
                    let ir = rs / s.n_mu_s;
                    let rho = medium.densities(grid.r(ir));
                    let lin = &l[rs * slab..(rs + 1) * slab];
                    for o in 0..dirs {
                        acc.fill(0.0);
                        let (pr, pm) = (
                            &phase[0][o * dirs..(o + 1) * dirs],
                            &phase[1][o * dirs..(o + 1) * dirs],
                        );
                        for d in 0..dirs {
                            let (wr, wm) = (pr[d], pm[d]);
                            let src = &lin[d * n_l..(d + 1) * n_l];
                            for i in 0..n_l {
                                acc[i] += wr * src[i];
                                acc[n_l + i] += wm * src[i];
                            }
                        }
                        for i in 0..n_l {
                            out[o * n_l + i] =
                                medium.rayleigh_scattering_per_m[i] * rho[RAYLEIGH] * acc[i]
                                    + medium.mie_scattering_per_m[i] * rho[MIE] * acc[n_l + i];
                        }
                    }
                },
            );
            j
        };

        let mut l_n = compute_l(
            &NoSource,
            Terms {
                single: true,
                ground_direct: true,
            },
        );
        let mut total: f64 = l_n.iter().sum();
        let mut e_n = ground_of(&l_n);
        let mut ground_sky = e_n.clone();
        let mut j_ms = vec![0.0; grid.cells() * n_l];
        let mut fractions = vec![1.0];
        let mut orders = 1;
        while orders < s.max_orders {
            let t_j = std::time::Instant::now();
            let j_n = compute_j(&l_n);
            let j_ms_elapsed = t_j.elapsed().as_secs_f64() * 1e3;
            let t_l = std::time::Instant::now();
            let (ln_jn, ln_en) = (ln_table(&j_n), ln_table(&e_n));
            let source = OrderSource {
                grid: &grid,
                n_l,
                ln_j: &ln_jn,
                ln_ground: &ln_en,
            };
            l_n = compute_l(
                &source,
                Terms {
                    single: false,
                    ground_direct: false,
                },
            );
            e_n = ground_of(&l_n);
            j_ms.par_iter_mut().zip(&j_n).for_each(|(a, b)| *a += b);
            ground_sky.iter_mut().zip(&e_n).for_each(|(a, b)| *a += b);
            let added: f64 = l_n.iter().sum();
            total += added;
            orders += 1;
            let fraction = if total > 0.0 { added / total } else { 0.0 };
            tracing::debug!(
                order = orders,
                fraction,
                scattering_density_ms = j_ms_elapsed,
                radiance_ms = t_l.elapsed().as_secs_f64() * 1e3,
                "precise multiple scattering order"
            );
            fractions.push(fraction);
            if fraction < s.tolerance {
                break;
            }
        }
        Self {
            grid,
            n_l,
            ln_j_ms: ln_table(&j_ms),
            ln_ground_sky: ln_table(&ground_sky),
            convergence: Convergence {
                orders,
                last_order_fraction: *fractions.last().unwrap_or(&0.0),
                order_fractions: fractions,
            },
        }
    }
}

impl Source for PreciseMultipleScattering {
    fn add_scattering(&self, s: &RaySample, out: &mut [f64]) {
        lookup_j(&self.grid, self.n_l, &self.ln_j_ms, s, out);
    }
    fn add_ground_sky_irradiance(&self, mu_s: f64, out: &mut [f64]) {
        lookup_ground(&self.grid, self.n_l, &self.ln_ground_sky, mu_s, out);
    }
}
