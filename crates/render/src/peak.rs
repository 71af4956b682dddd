//! The forward peak that the δ-M truncation takes out of the phase function, spread over the
//! scaled direct beam (the fast method's single scattering of sunlight).
//!
//! The δ-M scaled problem (see `multiple`) counts a scattering within the truncated peak as no
//! scattering: the scaled direct beam e^{−τ*}, τ* = (1 − ωf)τ, is the true direct beam e^{−τ}
//! plus the light scattered only within the peak, k times with Poisson weight (ωfτ)^k/k!. TMS
//! (Nakajima & Tanaka 1988, eq 13) scatters all of it towards the viewer with the true phase
//! function p(Θ) as if it were still collimated. The peak of g = 0.85 with f = g^3.5 is not
//! narrow (most of it within 25° of the forward direction), so after a few peak scatterings the
//! beam is spread, and p(Θ), convex and steep at 10–60°, underestimates the light scattered
//! towards a viewer looking towards the sun (back-lit clouds, the silver lining).
//!
//! Here the beam's angular spread is the Goudsmit & Saunderson (1940, eq 9) distribution of a
//! beam that has travelled through a medium scattering with the peak h alone: its Legendre
//! moments decay as e^{−ωf⁺τ(1 − h_l)}, so the effective single-scattering phase function is
//! p_eff(Θ, τ) = Σ_l (2l + 1)/(4π) p_l e^{−ωf⁺τ(1 − h_l)} P_l(cos Θ) (the path-length
//! differences of the spread beam neglected). h is the positive part of p − (1 − f)·HG(g*), the
//! true phase function less the part the scaled problem keeps, normalised by its integral f⁺.
//! The table holds p_eff/p over Θ and λ = ωfτ (τ the true optical depth towards the sun), both
//! series summed to the same order, so the ratio is exactly 1 at τ = 0; a second table holds
//! the part of it scattered last within the peak, r⁺_eff/p with moments r⁺_l e^{−ωf⁺τ(1 − h_l)}
//! (r⁺ = f⁺h), which the march sees through the true extinction instead of the scaled one
//! (`march::Prepared::march`). The renderer looks them up at `PEAK_SPREAD` times that λ (1,
//! the full rate).
//!
//! The smooth remainder p − r⁺ = min(p, (1 − f)·HG(g*)) has a kink where r⁺ ends (50.7° for
//! g = 0.85), and spreading it whole moves the kink's dip to the angles beyond it: on a DISORT
//! slab the single scattering 60° from the sun (scattering angle 60°) read 34–42 % below the
//! classed path tracer's light of one smooth scattering. Only the scaled phase function's part
//! (1 − f)·HG(g*), the one the δ-M scaled transport carries (Wiscombe 1977), is spread; the true
//! phase function's deficit below it beyond the kink, q = max((1 − f)·HG(g*) − p, 0), is held
//! (p − r⁺ = (1 − f)·HG(g*) − q), which reads within 1 % there at τ 1 and leaves the other
//! views within 1 point (docs/frames.md, "By class").

use crate::multiple::Truncation;
use rayon::prelude::*;
use skybake_physics::phase::Phase;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex};

/// Scattering angles of the table: 0 to 180° in 0.5° steps.
pub const N_THETA: usize = 361;
/// Largest λ = ωfτ tabulated (beyond it the ratio is held: e^{−τ*} ≤ e^{−λ(1−ωf)/(ωf)} is
/// negligible there for cloud phase functions).
pub const LAMBDA_MAX: f64 = 24.0;
pub const N_LAMBDA: usize = 97;
/// Legendre orders summed (Henyey-Greenstein g = 0.9: g^384 ≈ 3·10⁻¹⁸).
const L_MAX: usize = 384;
/// Quadrature points for the moments, μ = 1 − 2u² with u uniform (resolves the peak at μ = 1).
const N_QUAD: usize = 8192;

/// p_eff/p tables, one per distinct (phase function, albedo, truncation), and the truncated
/// peak's share of them (see [`PeakSpread::ratios`]).
pub struct PeakSpread {
    table_of: Vec<usize>,
    tables: Vec<Arc<Tables>>,
}

/// One phase function's and truncation's p_eff/p table, its peak part and the peak's integral
/// f⁺ (see [`table`]).
type Tables = (Vec<f32>, Vec<f32>, f64);

/// The tables computed so far in this process, by the bits of what [`table`] reads (the phase
/// function, f, g* and ω): a frame rendered again (another camera, a warm service) finds its
/// table here instead of summing the Legendre series again (30 ms of CPU per frame). The most
/// recent [`MEMO_ENTRIES`] are kept (280 kB each).
static MEMO: Mutex<Vec<(MemoKey, Arc<Tables>)>> = Mutex::new(Vec::new());
const MEMO_ENTRIES: usize = 8;
type MemoKey = (Phase, [u64; 3]);

/// [`table`] of `phase` and `t`, from [`MEMO`] when it was computed before (the same values).
fn memo_table(phase: &Phase, t: &Truncation) -> Arc<Tables> {
    let key: MemoKey = (
        *phase,
        [
            t.fraction.to_bits(),
            t.g_scaled.to_bits(),
            t.albedo.to_bits(),
        ],
    );
    let cached = MEMO
        .lock()
        .ok()
        .and_then(|m| m.iter().find(|(k, _)| *k == key).map(|(_, v)| v.clone()));
    if let Some(v) = cached {
        return v;
    }
    let v = Arc::new(table(phase, t));
    if let Ok(mut m) = MEMO.lock() {
        if !m.iter().any(|(k, _)| *k == key) {
            if m.len() >= MEMO_ENTRIES {
                m.remove(0);
            }
            m.push((key, v.clone()));
        }
    }
    v
}

/// A ray's row of the table for one wavelength: the angle's two rows and the weight of the second.
#[derive(Debug, Clone, Copy)]
pub struct PeakRow {
    table: usize,
    i0: usize,
    w1: f64,
}

impl PeakSpread {
    /// Tables for every wavelength whose truncation is on; `None` when none is truncated (then the
    /// scaled beam is the true direct beam and single scattering is exact).
    pub fn new(phases: &[Phase], truncation: &[Truncation]) -> Option<Self> {
        if truncation.iter().all(|t| t.fraction <= 0.0) {
            return None;
        }
        let mut keys: Vec<(Phase, u64, u64)> = Vec::new();
        let mut tables = Vec::new();
        let mut table_of = Vec::with_capacity(phases.len());
        for (p, t) in phases.iter().zip(truncation) {
            let key = (*p, t.fraction.to_bits(), t.albedo.to_bits());
            let i = match keys.iter().position(|k| *k == key) {
                Some(i) => i,
                None => {
                    keys.push(key);
                    tables.push(memo_table(p, t));
                    tables.len() - 1
                }
            };
            table_of.push(i);
        }
        Some(Self { table_of, tables })
    }

    /// Wavelength `l`'s table of p_eff/p, `[θ][λ]`: [`N_THETA`] scattering angles 0 to 180° in
    /// 0.5° steps by [`N_LAMBDA`] values of λ = ωfτ from 0 to [`LAMBDA_MAX`] (what
    /// [`Self::ratio`] interpolates bilinearly, λ held beyond the last).
    pub fn table(&self, l: usize) -> &[f32] {
        &self.tables[self.table_of[l]].0
    }

    /// Wavelength `l`'s table of the part of p_eff/p scattered last within the truncated
    /// peak, r⁺_eff/p (laid out as [`Self::table`]).
    pub fn peak_table(&self, l: usize) -> &[f32] {
        &self.tables[self.table_of[l]].1
    }

    /// The integral f⁺ of wavelength `l`'s truncated peak r⁺ = max(p − (1 − f)·HG(g*), 0) over
    /// the sphere (f⁺ ≥ f: (1 − f)·HG(g*) exceeds p beyond the peak, where r⁺ is 0; 0.582
    /// against f = 0.566 for Henyey-Greenstein g = 0.85), the probability that a scattering is
    /// one within the peak; 0 where the table is 1 (no truncation).
    pub fn peak_fraction(&self, l: usize) -> f64 {
        self.tables[self.table_of[l]].2
    }

    /// The row for wavelength `l` and the cosine of the scattering angle (sun direction · ray).
    pub fn row(&self, l: usize, cos_theta: f64) -> PeakRow {
        let x = cos_theta.clamp(-1.0, 1.0).acos().to_degrees() * 2.0;
        let i0 = (super::volume::floor(x) as usize).min(N_THETA - 2);
        PeakRow {
            table: self.table_of[l],
            i0,
            w1: (x - i0 as f64).clamp(0.0, 1.0),
        }
    }

    /// p_eff/p for the row at λ = ωfτ.
    #[inline]
    pub fn ratio(&self, row: PeakRow, lambda: f64) -> f64 {
        let (at, v) = cell(row, lambda);
        lookup_at(&self.tables[row.table].0, at, v, row.w1)
    }

    /// p_eff/p for the row at λ = ωfτ split into the part scattered last by the smooth
    /// remainder p − r⁺ and the part scattered last within the truncated peak r⁺ (their sum is
    /// [`Self::ratio`]): (smooth, peak).
    #[inline(always)]
    pub fn ratios(&self, row: PeakRow, lambda: f64) -> (f64, f64) {
        // Both tables at the same cell (its place and weights found once).
        let (at, v) = cell(row, lambda);
        let tables = &self.tables[row.table];
        let full = lookup_at(&tables.0, at, v, row.w1);
        let peak = lookup_at(&tables.1, at, v, row.w1);
        (full - peak, peak)
    }

    /// The part of p_eff/p scattered last within the truncated peak alone (the second of
    /// [`Self::ratios`]), for the row at λ = ωfτ.
    #[inline(always)]
    pub fn last_in_peak(&self, row: PeakRow, lambda: f64) -> f64 {
        let (at, v) = cell(row, lambda);
        lookup_at(&self.tables[row.table].1, at, v, row.w1)
    }
}

/// The offset of the table cell of the row's first angle at λ = `lambda` and the weight of
/// its second λ (λ held beyond the last).
#[inline(always)]
fn cell(row: PeakRow, lambda: f64) -> (usize, f64) {
    let y = (lambda.max(0.0) / LAMBDA_MAX * (N_LAMBDA - 1) as f64).min((N_LAMBDA - 1) as f64);
    let j0 = (super::volume::floor(y) as usize).min(N_LAMBDA - 2);
    (row.i0 * N_LAMBDA + j0, y - j0 as f64)
}

/// Bilinear look-up of a `[θ][λ]` table at a [`cell`] and the angle weight `w1`.
#[inline(always)]
fn lookup_at(t: &[f32], at: usize, v: f64, w1: f64) -> f64 {
    let c = &t[at..at + N_LAMBDA + 2];
    let a = c[0] as f64 * (1.0 - v) + c[1] as f64 * v;
    let b = c[N_LAMBDA] as f64 * (1.0 - v) + c[N_LAMBDA + 1] as f64 * v;
    a * (1.0 - w1) + b * w1
}

/// The share of the rate [`path_kept_rate`] at which the smooth part's light is lost: fitted on
/// the back-lit Mitsuba cases' first orders against the classed path tracer (`sun_back20`,
/// `sun_back35`; docs/frames.md, "δ-M truncation and TMS", item 10). A smooth scattering takes
/// the beam's photons from every direction, the oblique ones with their longer track through
/// each depth too (their fluence), so less of its light is lost than of the peak's last
/// scattering, which sees only the photons the beam turned into one direction.
pub const SMOOTH_PATH_SHARE: f64 = 0.4;

/// The rate κ per unit λ = ωfτ at which the spread beam's longer paths take its light,
/// the beam keeping 1/cosh(κλ) of it: in the small-angle picture a photon's direction diffuses
/// by (1 − h₁) per peak scattering (the mean cosine of the beam decays as e^{−cτ}, c =
/// ωf⁺(1 − h₁)), its path exceeds the depth it has crossed by ∫θ²/2, and a path is lost at
/// σ_t⁺/σ_t = 1 − ωf⁺ per unit length; for a two-dimensional Brownian walk of the angle θ,
/// E[e^{−a∫θ²/2 dz}] = 1/cosh(z√(ac)) (Cameron & Martin 1944; the path lengths of Fermi's
/// small-angle theory, Eyges 1948), so κ = √((1 − ωf⁺)·c)/(ωf): 0.148 for Henyey-Greenstein
/// g = 0.85 and ω = 0.999. The Goudsmit & Saunderson moments alone take every photon along the
/// straight line, with no longer path (docs/frames.md, item 10).
fn path_kept_rate(albedo: f64, f: f64, f_plus: f64, h1: f64) -> f64 {
    let diffusion = albedo * f_plus * (1.0 - h1).max(0.0);
    let removal = (1.0 - albedo * f_plus).max(0.0);
    (removal * diffusion).sqrt() / (albedo * f)
}

/// Legendre polynomials P_0..P_{L_MAX} at `mu` into `out` (Bonnet's recurrence).
fn legendre(mu: f64, out: &mut [f64]) {
    out[0] = 1.0;
    if out.len() > 1 {
        out[1] = mu;
    }
    for l in 2..out.len() {
        out[l] = ((2 * l - 1) as f64 * mu * out[l - 1] - (l - 1) as f64 * out[l - 2]) / l as f64;
    }
}

/// The p_eff/p table `[θ][λ]` of one phase function and truncation, and the same for the peak
/// part alone, r⁺_eff/p (moments r⁺_l e^{−ωf⁺τ(1 − h_l)}), and f⁺. p_eff is r⁺_eff plus the
/// smooth remainder with only its scaled part (1 − f)·HG(g*) spread (moments (1 − f)g*^l
/// e^{−ωf⁺τ(1 − h_l)}), less the deficit q held (see the module's documentation).
fn table(phase: &Phase, t: &Truncation) -> Tables {
    let f = t.fraction;
    let smooth = Phase::HenyeyGreenstein { g: t.g_scaled };
    // Moments 2π∫ x P_l dμ of p and of the positive remainder r⁺ = max(p − (1 − f)p*, 0).
    let mut p_l = vec![0.0; L_MAX + 1];
    let mut h_l = vec![0.0; L_MAX + 1];
    let mut pl = vec![0.0; L_MAX + 1];
    for k in 0..N_QUAD {
        let u = (k as f64 + 0.5) / N_QUAD as f64;
        let mu = 1.0 - 2.0 * u * u;
        let dmu = 4.0 * u / N_QUAD as f64;
        let p = phase.eval(mu);
        let r = (p - (1.0 - f) * smooth.eval(mu)).max(0.0);
        legendre(mu, &mut pl);
        for l in 0..=L_MAX {
            p_l[l] += 2.0 * PI * p * pl[l] * dmu;
            h_l[l] += 2.0 * PI * r * pl[l] * dmu;
        }
    }
    let f_plus = h_l[0];
    let albedo = t.albedo;
    let mut out = vec![1f32; N_THETA * N_LAMBDA];
    let mut out_peak = vec![0f32; N_THETA * N_LAMBDA];
    if f_plus <= 0.0 || f <= 0.0 || albedo <= 0.0 {
        return (out, out_peak, 0.0);
    }
    // λ = ωfτ; the peak's scattering rate is ωf⁺ per unit optical depth.
    let strength = f_plus / f;
    let path_rate = path_kept_rate(albedo, f, f_plus, h_l[1] / f_plus);
    let decay: Vec<Vec<f64>> = (0..N_LAMBDA)
        .map(|j| {
            let lambda = LAMBDA_MAX * j as f64 / (N_LAMBDA - 1) as f64;
            (0..=L_MAX)
                .map(|l| (-lambda * strength * (1.0 - h_l[l] / f_plus)).exp())
                .collect()
        })
        .collect();
    // The angles' rows in parallel (each row's sums as in a serial loop).
    out.par_chunks_mut(N_LAMBDA)
        .zip(out_peak.par_chunks_mut(N_LAMBDA))
        .enumerate()
        .for_each(|(i, (row, row_peak))| {
            let mut pl = vec![0.0; L_MAX + 1];
            let mu = (i as f64 * 0.5).to_radians().cos();
            legendre(mu, &mut pl);
            let terms: Vec<f64> = (0..=L_MAX)
                .map(|l| (2 * l + 1) as f64 / (4.0 * PI) * p_l[l] * pl[l])
                .collect();
            let peak_terms: Vec<f64> = (0..=L_MAX)
                .map(|l| (2 * l + 1) as f64 / (4.0 * PI) * h_l[l] * pl[l])
                .collect();
            let s0: f64 = terms.iter().sum();
            // The smooth remainder min(p, (1 − f)·HG(g*)) = (1 − f)·HG(g*) − q: the scaled
            // phase function's part (moments (1 − f)·g*^l) spread, the true phase function's
            // deficit q = max((1 − f)·HG(g*) − p, 0) beyond the kink where r⁺ ends held
            // (its series r⁺_l − p_l + (1 − f)·g*^l, so that the sum at λ = 0 is p's series).
            let spread_terms: Vec<f64> = (0..=L_MAX)
                .map(|l| {
                    peak_terms[l]
                        + (2 * l + 1) as f64 / (4.0 * PI)
                            * (1.0 - f)
                            * t.g_scaled.powi(l as i32)
                            * pl[l]
                })
                .collect();
            let held: f64 = (0..=L_MAX).map(|l| spread_terms[l] - terms[l]).sum();
            for (j, (o, o_peak)) in row.iter_mut().zip(row_peak.iter_mut()).enumerate() {
                let s: f64 = spread_terms
                    .iter()
                    .zip(&decay[j])
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
                    - held;
                let sp: f64 = peak_terms.iter().zip(&decay[j]).map(|(a, b)| a * b).sum();
                let (full, peak) = if s0 > 1e-12 {
                    let full = (s / s0).max(0.0);
                    (full, (sp / s0).clamp(0.0, full))
                } else {
                    (1.0, 0.0)
                };
                // What the spread beam's longer paths leave of each part (see [`path_kept_rate`]).
                let lambda = LAMBDA_MAX * j as f64 / (N_LAMBDA - 1) as f64;
                let kept = 1.0 / (path_rate * lambda).cosh();
                let kept_smooth = 1.0 / (SMOOTH_PATH_SHARE * path_rate * lambda).cosh();
                let full = (full - peak) * kept_smooth + peak * kept;
                let peak = peak * kept;
                *o = full as f32;
                *o_peak = peak as f32;
            }
        });
    (out, out_peak, f_plus)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table found in the memo is the one computed afresh, bit for bit, and a different
    /// truncation gets its own.
    #[test]
    fn memoised_tables_are_the_computed_ones() {
        let phase = Phase::HenyeyGreenstein { g: 0.8 };
        let t = Truncation::new(0.8, 0.99, 3.5);
        let first = PeakSpread::new(&[phase], &[t]).unwrap();
        let again = PeakSpread::new(&[phase, phase], &[t, t]).unwrap();
        let (full, peak, _) = table(&phase, &t);
        for s in [&first, &again] {
            assert!(s
                .table(0)
                .iter()
                .zip(&full)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
            assert!(s
                .peak_table(0)
                .iter()
                .zip(&peak)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
        }
        let other = Truncation::new(0.8, 0.99, 2.0);
        let s = PeakSpread::new(&[phase], &[other]).unwrap();
        let (full_other, _, _) = table(&phase, &other);
        assert!(s.table(0).iter().zip(&full_other).all(|(a, b)| a == b));
        assert!(full_other.iter().zip(&full).any(|(a, b)| a != b));
    }

    /// The table is 1 without peak scatterings, and the spread beam keeps what its longer paths
    /// leave: the ratio weighted by p over the sphere integrates to between 1/cosh(κλ) (the
    /// peak's part) and 1/cosh(0.4κλ) (the smooth part's) at every λ (the l = 0 moment does
    /// not decay).
    #[test]
    fn ratio_is_one_at_zero_depth_and_keeps_what_the_longer_paths_leave() {
        let phase = Phase::HenyeyGreenstein { g: 0.85 };
        let t = Truncation::new(0.85, 0.999, 3.5);
        let s = PeakSpread::new(&[phase], &[t]).unwrap();
        for deg in [0.0f64, 10.0, 35.0, 90.0, 150.0] {
            let r = s.ratio(s.row(0, deg.to_radians().cos()), 0.0);
            assert!((r - 1.0).abs() < 1e-5, "{deg}: {r}");
        }
        // κ = √((1 − ωf⁺)·ωf⁺(1 − h₁))/(ωf) from f⁺ = 0.58163 and the peak's mean cosine
        // h₁ = 0.97130, both by an independent trapezoidal quadrature (2·10⁶ points in μ,
        // outside this crate): 0.1478.
        let kappa = 0.1478;
        assert!((path_kept_rate(0.999, t.fraction, 0.58163, 0.97130) - kappa).abs() < 5e-4);
        for lambda in [0.5, 2.0, 8.0] {
            // ∫ p·ratio dω by the midpoint rule in θ (the table's angular resolution).
            let n = 36_000;
            let mut e = 0.0;
            for k in 0..n {
                let th = (k as f64 + 0.5) / n as f64 * PI;
                let mu = th.cos();
                e += 2.0 * PI * th.sin() * PI / n as f64
                    * phase.eval(mu)
                    * s.ratio(s.row(0, mu), lambda);
            }
            let (low, high) = (
                1.0 / (kappa * lambda).cosh(),
                1.0 / (SMOOTH_PATH_SHARE * kappa * lambda).cosh(),
            );
            assert!(
                e > low - 0.01 && e < high + 0.01 && (lambda < 2.0 || e < 0.99),
                "λ {lambda}: {e} ({low}…{high})"
            );
        }
        // Spreading moves light from the peak to 20–60°.
        let at = |deg: f64, lambda: f64| s.ratio(s.row(0, deg.to_radians().cos()), lambda);
        assert!(at(0.0, 4.0) < 0.5 && at(35.0, 4.0) > 1.5);
        assert!(PeakSpread::new(&[phase], &[Truncation::new(0.85, 0.999, 0.0)]).is_none());
        // f⁺, the integral of r⁺ = max(p − (1 − f)·HG(g*), 0): 0.58163 by an independent
        // midpoint quadrature (2·10⁵ points in μ = 1 − 2u², outside this crate), above f = 0.56620.
        let f_plus = s.peak_fraction(0);
        assert!(
            (f_plus - 0.58163).abs() < 5e-4 && f_plus > t.fraction,
            "{f_plus}"
        );
        // The peak's part: at λ = 0 the truncated peak's positive part r⁺ = max(p − (1 − f)·HG(g*),
        // 0) over p, evaluated directly here (the table sums Legendre series); never above the
        // whole, and the two parts add up to it at every λ.
        let smooth = Phase::HenyeyGreenstein { g: t.g_scaled };
        for deg in [2.0f64, 10.0, 20.0, 40.0] {
            let mu = deg.to_radians().cos();
            let r_plus = (phase.eval(mu) - (1.0 - t.fraction) * smooth.eval(mu)).max(0.0);
            let (rest, peak) = s.ratios(s.row(0, mu), 0.0);
            assert!(
                (peak - r_plus / phase.eval(mu)).abs() < 0.01,
                "{deg}: {peak}"
            );
            for lambda in [0.0, 2.0, 8.0] {
                let (rest, peak) = s.ratios(s.row(0, mu), lambda);
                assert!(
                    peak >= 0.0 && rest >= -1e-6,
                    "{deg} {lambda}: {rest} {peak}"
                );
                let whole = s.ratio(s.row(0, mu), lambda);
                assert!((rest + peak - whole).abs() < 1e-9);
            }
            assert!(rest >= 0.0);
        }
    }
}
