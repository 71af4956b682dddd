//! The sun's once-scattered light, transported in the true medium and seen through the classed
//! smooth kernel p − r⁺ to a high angular order.
//!
//! The δ-M scaled transport (module `multiple`) counts a scattering within the truncated peak as
//! no scattering (Wiscombe 1977): the sun's beam reaches its first smooth scattering collimated,
//! and the once-scattered light L₁ flies on undeflected. The true peak is not a δ (most of it
//! within 25°, reaching 50.7° for g = 0.85): the beam is spread before its first smooth
//! scattering and L₁ after it, as Goudsmit & Saunderson (1940) describe for the direct beam
//! (`peak`). Seen through the scaled phase function's P3 series, L₁'s lobe round the sun's
//! direction reads 1.64× the smooth kernel at 66°; through the kernel's own moments, L₁ without
//! the spread reads 9.5 % low against a path tracer that classes every scattering as within the
//! peak (probability r⁺/p) or smooth.
//!
//! Here the sun's photons fly through the true medium (σ_t, ω, the true phase function p), every
//! collision classed as the path tracer does: within the peak r⁺ = max(p − (1 − f)·HG(g*), 0)
//! (the direction drawn from p and kept), or smooth. Their tracks after exactly one smooth
//! scattering are scored in real spherical harmonics to order [`ONCE_ORDER`] (the track-length
//! estimator, as the field's) per unit sun irradiance, and the photons end at their second
//! smooth scattering. A viewer looking along d sees J₁ = Σ_l k_l Σ_m L₁,lm Y_lm(−d) with k_l
//! the Legendre moments of (p − r⁺)/(1 − f), weighted by the field's σ_s* = ω(1 − f)σ_t: the
//! source ω σ_t ∫ (p − r⁺) L₁ dω of the classed path tracer's second smooth scattering.
//!
//! The field keeps its own once-scattered light L*₁ (the sun photons' tracks between their
//! first and second scattering in the scaled medium), also tallied apart: in the cloud's
//! interior J₁ replaces the field's Σ p*_l L*₁,lm Y_lm; at a voxel seen through the cloud's
//! face the field is kept whole, since its build-up below the face (module `face`, the formal
//! solution of Chandrasekhar 1960 §1.8) models the once-scattered light's depth profile there.
//! The change is evaluated per coarse cell towards the camera and interpolated to the voxels.

use super::{fly, real_sh, Coarse, MsField, Photon, Truncation};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use skybake_physics::phase::{orthonormal_basis, Phase};
use std::f64::consts::PI;

/// Angular order of the once-scattered light: the kernel's moments k_l (g = 0.85: 0.96, 0.66,
/// 0.44, 0.28, 0.18, 0.12, 0.08, 0.05, 0.03 for l = 0 … 8) have converged there.
pub const ONCE_ORDER: usize = 8;
/// Harmonics per wavelength group, (L + 1)².
pub const ONCE_MOMENTS: usize = (ONCE_ORDER + 1) * (ONCE_ORDER + 1);
/// Photons per sun photon of the field: the once-scattered light's tally at order 8 is noisier
/// than the field's at order 3 (with as many photons `sun_albedo09` read 5.0 % block NRMSE
/// against Mitsuba 3 at the default seed, with 4× 4.3 %).
pub const PHOTONS_PER_SUN_PHOTON: usize = 2;
/// A photon's collisions before its second smooth scattering are bounded by this (a chain of
/// peak scatterings in a conservative medium is geometric with ratio f⁺ ≈ 0.6).
const MAX_EVENTS: usize = 4096;

/// The sun's once-scattered light per coarse cell, and what replaces the field's with it.
pub struct OnceField {
    /// `[cell][group][ONCE_MOMENTS]`: L₁,lm per unit sun irradiance (until [`Self::finish`]).
    data: Vec<f32>,
    /// Groups (wavelengths of identical optics).
    groups: usize,
    /// Per wavelength: its group.
    group_of: Vec<usize>,
    /// Per wavelength: the sun's irradiance (W m⁻² nm⁻¹).
    irradiance: Vec<f64>,
    /// Per wavelength: k_0 … k_L of (p − r⁺)/(1 − f) ([`classed_moments`]).
    kernel: Vec<Vec<f64>>,
    /// `[cell][λ][ONCE_MOMENTS]`: E_sun·k_l·L₁,lm − p*_l·L*₁,lm, the once-scattered light's
    /// source in place of the δ-M field's (L*₁ the field's tracks between the sun photons'
    /// first and second scattering, l ≤ the field's order), W m⁻² nm⁻¹.
    delta: Vec<f32>,
    n_l: usize,
}

impl OnceField {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.data.len() + self.delta.len())
    }
}

/// Legendre moments k_l = ∫ k(μ) P_l(μ) dΩ of the classed smooth kernel k = (p − r⁺)/(1 − f) =
/// min(p, (1 − f)·HG(g*))/(1 − f), l = 0 … `order` (midpoint rule in u with μ = 1 − 2u²).
pub fn classed_moments(phase: &Phase, t: &Truncation, order: usize) -> Vec<f64> {
    let f = t.fraction;
    let hg = Phase::HenyeyGreenstein { g: t.g_scaled };
    let nq = 16_384;
    let mut k = vec![0.0; order + 1];
    let mut pl = vec![0.0; order + 1];
    for i in 0..nq {
        let u = (i as f64 + 0.5) / nq as f64;
        let mu = 1.0 - 2.0 * u * u;
        let dmu = 4.0 * u / nq as f64;
        let v = phase.eval(mu).min((1.0 - f) * hg.eval(mu)) / (1.0 - f);
        legendre(mu, &mut pl);
        for (kl, p) in k.iter_mut().zip(&pl) {
            *kl += 2.0 * PI * v * p * dmu;
        }
    }
    k
}

/// P_0(μ) … P_n(μ) by Bonnet's recurrence.
fn legendre(mu: f64, out: &mut [f64]) {
    for l in 0..out.len() {
        out[l] = match l {
            0 => 1.0,
            1 => mu,
            _ => ((2 * l - 1) as f64 * mu * out[l - 1] - (l - 1) as f64 * out[l - 2]) / l as f64,
        };
    }
}

/// Real orthonormal spherical harmonics of unit `d` to order `order` in [`real_sh`]'s order and
/// convention: l ≤ 4 from [`real_sh`], higher l from the associated Legendre recurrences
/// (P_m^m = (−1)^m (2m − 1)!! (1 − z²)^{m/2}, P_{m+1}^m = z(2m + 1)P_m^m,
/// (l − m)P_l^m = (2l − 1)zP_{l−1}^m − (l + m − 1)P_{l−2}^m; Press et al. 2007, §6.7) with the
/// azimuthal factors (1 − z²)^{m/2}(cos mφ, sin mφ) as Re/Im of (x + iy)^m.
pub fn real_sh_high(d: DVec3, order: usize, out: &mut [f64]) {
    static NORM: std::sync::OnceLock<[f64; ONCE_MOMENTS]> = std::sync::OnceLock::new();
    let order = order.min(ONCE_ORDER);
    real_sh(d, order.min(4), out);
    if order <= 4 {
        return;
    }
    let (x, y, z) = (d.x, d.y, d.z);
    let norm = NORM.get_or_init(|| {
        // √((2l + 1)/(4π)·(l − m)!/(l + m)!) at index l² + l + m, m ≥ 0.
        let mut t = [0.0; ONCE_MOMENTS];
        for l in 0..=ONCE_ORDER {
            for m in 0..=l {
                let ratio: f64 = (l - m + 1..=l + m).map(|i| 1.0 / i as f64).product();
                t[l * l + l + m] = ((2 * l + 1) as f64 / (4.0 * PI) * ratio).sqrt();
            }
        }
        t
    });
    let (mut cm, mut sm) = (1.0f64, 0.0f64);
    let mut dfact = 1.0;
    for m in 0..=order {
        if m > 0 {
            (cm, sm) = (cm * x - sm * y, cm * y + sm * x);
            dfact *= (2 * m - 1) as f64;
        }
        // P_l^m / (1 − z²)^{m/2}.
        let pmm = if m % 2 == 1 { -dfact } else { dfact };
        let (mut a, mut b) = (0.0f64, pmm);
        for l in m..=order {
            let p = if l == m {
                pmm
            } else {
                let p = if l == m + 1 {
                    z * (2 * m + 1) as f64 * pmm
                } else {
                    ((2 * l - 1) as f64 * z * b - (l + m - 1) as f64 * a) / (l - m) as f64
                };
                a = b;
                b = p;
                p
            };
            if l >= 5 {
                let k = norm[l * l + l + m];
                if m == 0 {
                    out[l * l + l] = k * p;
                } else {
                    let k = k * std::f64::consts::SQRT_2 * p;
                    out[l * l + l + m] = k * cm;
                    out[l * l + l - m] = k * sm;
                }
            }
        }
    }
}

/// What [`trace`] needs of one wavelength group.
pub(super) struct Group<'a> {
    pub phase: &'a Phase,
    pub truncation: &'a Truncation,
    /// True extinction per density, m⁻¹.
    pub k: f64,
    /// Direction of the sun's light's travel.
    pub travel: DVec3,
    /// Photons.
    pub photons: usize,
    pub seed: u64,
}

/// Traces one group's sun photons through the true medium and returns L₁,lm per unit sun
/// irradiance, `[cell][ONCE_MOMENTS]` (module text). `lanes` accumulators, each a fixed,
/// interleaved set of chunks, summed in order: the same field on every machine.
pub(super) fn trace(coarse: &Coarse, g: &Group, lanes: usize) -> Vec<f64> {
    let lo = coarse.origin_m;
    let hi = coarse.hi();
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length() * 1.001;
    // Per photon, of unit irradiance over the disc.
    let w = [PI * radius * radius / g.photons as f64];
    let cell_volume = coarse.cell_m.x * coarse.cell_m.y * coarse.cell_m.z;
    let skin = coarse.skin.as_ref().map_or(0, super::skin::Skin::len);
    let cells = coarse.rho.len();
    let len = (cells + skin) * ONCE_MOMENTS;
    let f = g.truncation.fraction;
    let hg = Phase::HenyeyGreenstein {
        g: g.truncation.g_scaled,
    };
    let rplus = |mu: f64| (g.phase.eval(mu) - (1.0 - f) * hg.eval(mu)).max(0.0);
    let (tb, bb) = orthonormal_basis(g.travel);
    let chunk = 4096usize;
    let chunks = g.photons.div_ceil(chunk);
    let lanes = lanes.clamp(1, chunks.max(1));
    let parts: Vec<Vec<f64>> = (0..lanes)
        .into_par_iter()
        .map(|lane| {
            let mut acc = super::super::pages::take_zeroed(len);
            let mut ylm = [0.0; ONCE_MOMENTS];
            let mut w = w;
            for ci in (lane..chunks).step_by(lanes) {
                let mut rng = Pcg64::seed_from_u64(
                    g.seed ^ 0x0_4CE5_CA77 ^ (ci as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                for _ in ci * chunk..((ci + 1) * chunk).min(g.photons) {
                    w[0] = PI * radius * radius / g.photons as f64;
                    let r = radius * rng.random::<f64>().sqrt();
                    let phi = 2.0 * PI * rng.random::<f64>();
                    let mut ph = Photon {
                        pos: centre + (tb * phi.cos() + bb * phi.sin()) * r
                            - g.travel * (2.0 * radius),
                        dir: g.travel,
                        scattered: false,
                    };
                    for _ in 0..MAX_EVENTS {
                        let tau = -(1.0 - rng.random::<f64>()).ln();
                        if !fly(
                            coarse,
                            lo,
                            hi,
                            &mut ph,
                            tau,
                            g.k,
                            cell_volume,
                            &w,
                            &mut acc,
                            1,
                            &ylm,
                        ) {
                            break;
                        }
                        w[0] *= g.truncation.albedo;
                        if w[0] <= 0.0 {
                            break;
                        }
                        let nd = {
                            let mut more = || rng.random::<f64>();
                            let (u1, u2) = (more(), more());
                            g.phase.sample(ph.dir, u1, u2, &mut more).0
                        };
                        let mu = nd.dot(ph.dir);
                        let peak = rng.random::<f64>() * g.phase.eval(mu) < rplus(mu);
                        if !peak && ph.scattered {
                            break;
                        }
                        ph.dir = nd;
                        if !peak {
                            ph.scattered = true;
                        }
                        if ph.scattered {
                            real_sh_high(ph.dir, ONCE_ORDER, &mut ylm);
                        }
                    }
                }
            }
            acc
        })
        .collect();
    let mut out = vec![0.0; cells * ONCE_MOMENTS];
    for p in parts {
        for (o, v) in out.iter_mut().zip(&p) {
            *o += v;
        }
        super::super::pages::give_back(p);
    }
    out
}

impl OnceField {
    /// An empty field for `n_l` wavelengths in `groups` groups.
    pub(super) fn new(
        cells: usize,
        groups: usize,
        group_of: Vec<usize>,
        irradiance: Vec<f64>,
        kernel: Vec<Vec<f64>>,
    ) -> Self {
        Self {
            data: vec![0.0; cells * groups * ONCE_MOMENTS],
            groups,
            group_of,
            irradiance,
            kernel,
            delta: Vec::new(),
            n_l: 0,
        }
    }

    /// Stores group `gi`'s [`trace`].
    pub(super) fn set_group(&mut self, gi: usize, acc: &[f64]) {
        for (c, cell) in acc.chunks_exact(ONCE_MOMENTS).enumerate() {
            let b = (c * self.groups + gi) * ONCE_MOMENTS;
            for (d, v) in self.data[b..b + ONCE_MOMENTS].iter_mut().zip(cell) {
                *d = *v as f32;
            }
        }
    }

    /// The source's coefficients per cell ([`Self::delta`]) from the tallies and the δ-M
    /// once-scattered light `dm` (`[cell][λ][moments]`, radiance moments of the field's order
    /// with the scaled phase moments `pm`); the tallies are dropped.
    pub(super) fn finish(&mut self, dm: &[f32], moments: usize, pm: &[Vec<f64>]) {
        let n_l = self.group_of.len();
        let cells = self.data.len() / (self.groups * ONCE_MOMENTS);
        let mut delta = vec![0f32; cells * n_l * ONCE_MOMENTS];
        for (c, out) in delta.chunks_exact_mut(n_l * ONCE_MOMENTS).enumerate() {
            for l in 0..n_l {
                let b = (c * self.groups + self.group_of[l]) * ONCE_MOMENTS;
                let v = &self.data[b..b + ONCE_MOMENTS];
                let o = &mut out[l * ONCE_MOMENTS..(l + 1) * ONCE_MOMENTS];
                for (order, k) in self.kernel[l].iter().enumerate() {
                    for m in order * order..(order + 1) * (order + 1) {
                        let mut x = self.irradiance[l] * k * v[m] as f64;
                        if m < moments {
                            x -= pm[l][order] * dm[(c * n_l + l) * moments + m] as f64;
                        }
                        o[m] = x as f32;
                    }
                }
            }
        }
        self.delta = delta;
        self.n_l = n_l;
        self.data = Vec::new();
    }
}

impl MsField {
    /// The once-scattered light's source coefficients at `p` per wavelength, `[λ][ONCE_MOMENTS]`
    /// into `out` (zeros without it), interpolated as the field ([`Self::cell_weights`]): added
    /// to the field's J* towards `d` as Σ_lm out_lm Y_lm(−d) where the field is not seen
    /// through a face ([`Self::once_towards`]).
    pub fn once_coefficients(&self, p: DVec3, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let Some(o) = &self.once else {
            return;
        };
        let n = o.n_l * ONCE_MOMENTS;
        for (c, w) in self.cell_weights(p) {
            if w == 0.0 {
                continue;
            }
            for (x, v) in out.iter_mut().zip(&o.delta[c * n..(c + 1) * n]) {
                *x += w * *v as f64;
            }
        }
    }

    /// Whether the field holds the sun's once-scattered light apart.
    pub fn has_once(&self) -> bool {
        self.once.is_some()
    }

    /// Per coarse cell that holds cloud, the once-scattered light's change of the source
    /// towards a camera, Σ_lm (E_sun·k_l·L₁,lm − p*_l·L*₁,lm)·Y_lm(−d) with d = `view` of the
    /// cell's centre, `[cell][λ]` (empty without it): evaluated per cell, not per voxel, and
    /// interpolated by [`Self::once_add`].
    pub fn once_towards(&self, view: &(dyn Fn(DVec3) -> DVec3 + Sync)) -> Vec<f32> {
        let Some(o) = &self.once else {
            return Vec::new();
        };
        let n_l = o.n_l;
        let [nx, ny, _] = self.dims;
        let mut out = vec![0f32; self.rho.len() * n_l];
        out.par_chunks_mut(n_l)
            .zip(o.delta.par_chunks(n_l * ONCE_MOMENTS))
            .enumerate()
            .for_each(|(c, (out, v))| {
                if self.rho[c] <= 0.0 {
                    return;
                }
                let ijk = DVec3::new((c % nx) as f64, ((c / nx) % ny) as f64, (c / (nx * ny)) as f64);
                let centre = self.origin_m + (ijk + DVec3::splat(0.5)) * self.cell_m;
                let mut ylm = [0.0; ONCE_MOMENTS];
                real_sh_high(-view(centre), ONCE_ORDER, &mut ylm);
                for (l, o) in out.iter_mut().enumerate() {
                    let v = &v[l * ONCE_MOMENTS..(l + 1) * ONCE_MOMENTS];
                    *o = v.iter().zip(&ylm).map(|(a, b)| *a as f64 * b).sum::<f64>() as f32;
                }
            });
        out
    }

    /// Adds [`Self::once_towards`]'s `cells` interpolated at `p` to the field's source `out`
    /// (kept ≥ 0); nothing where `cells` is empty.
    pub fn once_add(&self, cells: &[f32], p: DVec3, out: &mut [f64]) {
        if cells.is_empty() {
            return;
        }
        let n_l = out.len();
        for (c, w) in self.cell_weights(p) {
            if w == 0.0 {
                continue;
            }
            for (o, v) in out.iter_mut().zip(&cells[c * n_l..(c + 1) * n_l]) {
                *o += w * *v as f64;
            }
        }
        for o in out.iter_mut() {
            *o = o.max(0.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The harmonics to order 8 satisfy the addition theorem Σ_m Y_lm(a)Y_lm(b) =
    /// (2l + 1)/(4π) P_l(a·b).
    #[test]
    fn high_order_harmonics_satisfy_the_addition_theorem() {
        let mut ya = [0.0; ONCE_MOMENTS];
        let mut yb = [0.0; ONCE_MOMENTS];
        let mut pl = [0.0; ONCE_ORDER + 1];
        for i in 0..40 {
            let a = super::super::uniform_sphere(
                (i as f64 * 0.618_034).fract(),
                (i as f64 + 0.5) / 40.0,
            );
            let b = super::super::uniform_sphere(
                (i as f64 * 0.414_214).fract(),
                (i as f64 + 0.7) / 40.0,
            );
            real_sh_high(a, ONCE_ORDER, &mut ya);
            real_sh_high(b, ONCE_ORDER, &mut yb);
            legendre(a.dot(b), &mut pl);
            for l in 0..=ONCE_ORDER {
                let sum: f64 = (l * l..(l + 1) * (l + 1)).map(|m| ya[m] * yb[m]).sum();
                let expected = (2 * l + 1) as f64 / (4.0 * PI) * pl[l];
                assert!((sum - expected).abs() < 1e-11, "l {l}: {sum} vs {expected}");
            }
        }
    }

    /// Without a peak beyond the scaled phase function (p = (1 − f)·HG(g*) + f·δ has r⁺ = 0
    /// away from μ = 1), the kernel's moments are Henyey-Greenstein's g*^l.
    #[test]
    fn classed_moments_of_a_hg_remainder_are_its_moments() {
        // p = HG(g) has a peak; take the truncation of g* = 0.5 with f = 0 instead: r⁺ = max(p −
        // HG(0.5), 0) = 0 for p = HG(0.5).
        let t = Truncation::new(0.5, 1.0, 0.0);
        let k = classed_moments(&Phase::HenyeyGreenstein { g: 0.5 }, &t, 6);
        for (l, kl) in k.iter().enumerate() {
            assert!((kl - 0.5f64.powi(l as i32)).abs() < 2e-4, "l {l}: {kl}");
        }
    }
}
