//! The photon pass's scattering with the truncated peak resolved.
//!
//! The δ-M scaled transport (Wiscombe 1977) scatters at σ_t* = σ_t(1 − ωf) with HG(g*), and
//! (1 − f)·HG(g*) = (p − r⁺) + q: the true smooth part p − r⁺ (r⁺ = max(p − (1 − f)·HG(g*), 0),
//! of integral f⁺) and q = max((1 − f)·HG(g*) − p, 0), the peak's small turns (integral f⁺ − f)
//! moved to angles beyond the kink (50.7° for g 0.85), where (1 − f)·HG(g*) exceeds p by 7–25 %:
//! the scaled transport reads the backward light high (docs/frames.md, "The backward views'
//! field, by order").
//!
//! Here the same scaled collisions (σ_t*, ω*, hence the same skins, faces and march) scatter with
//! the true phase function less the δ part: the smooth part (p − r⁺)/(1 − f⁺) with probability
//! (1 − f⁺)/(1 − f), else a turn drawn from the peak r⁺/f⁺; and between them the peak's δ part
//! turns the photon too, at the rate σ_t ωf (per scaled optical depth ωf/(1 − ωf)), each turn
//! drawn from r⁺/f⁺, at its place on the track. Every event of the true medium is then flown
//! (the peak classed by r⁺/p as in `once`), and the scaled collisions alone count as
//! scatterings (weights, roulette, the once-scattered class).

use super::Truncation;
use glam::DVec3;
use rand::Rng;
use skybake_physics::phase::Phase;
use std::f64::consts::PI;

/// Draws before a rejection loop gives up and keeps its last draw (the acceptance is at least
/// 1 − f⁺ ≥ 0.3 for clouds; 64 misses are below 10⁻¹⁰).
const MAX_DRAWS: usize = 64;
/// Quadrature points of f⁺ (μ = 1 − 2u², as `peak`).
const N_QUAD: usize = 8192;

/// The true phase function split as the scaled transport's collisions and the peak's turns.
#[derive(Debug, Clone, Copy)]
pub(super) struct PeakTurns {
    phase: Phase,
    kept: Phase,
    one_minus_f: f64,
    /// (f⁺ − f)/f⁺: a collision drawn within the peak is kept as a collision.
    keep_peak: f64,
    /// ωf: the share of the true medium's events that are the peak's δ part.
    delta: f64,
}

impl PeakTurns {
    /// None without a truncated peak (f = 0 or ω = 0).
    pub(super) fn new(phase: &Phase, t: &Truncation) -> Option<Self> {
        let f = t.fraction;
        if f <= 0.0 || f >= 1.0 || t.albedo <= 0.0 {
            return None;
        }
        let kept = Phase::HenyeyGreenstein { g: t.g_scaled };
        let (mut total, mut peak) = (0.0, 0.0);
        for k in 0..N_QUAD {
            let u = (k as f64 + 0.5) / N_QUAD as f64;
            let mu = 1.0 - 2.0 * u * u;
            let dmu = 4.0 * u / N_QUAD as f64;
            let p = phase.eval(mu);
            total += 2.0 * PI * p * dmu;
            peak += 2.0 * PI * (p - (1.0 - f) * kept.eval(mu)).max(0.0) * dmu;
        }
        let f_plus = peak / total;
        if f_plus <= f || !f_plus.is_finite() {
            return None;
        }
        Some(Self {
            phase: *phase,
            kept,
            one_minus_f: 1.0 - f,
            keep_peak: (f_plus - f) / f_plus,
            delta: t.albedo * f,
        })
    }

    /// ωf: the probability that an event of the true medium is a turn within the peak's δ part
    /// (the free paths between events are (1 − ωf) scaled optical depths on average).
    pub(super) fn delta_share(&self) -> f64 {
        self.delta
    }

    /// A direction drawn from p around `dir` and whether it lies within the peak (r⁺/p).
    fn draw<R: Rng>(&self, dir: DVec3, rng: &mut R) -> (DVec3, bool) {
        let mut more = || rng.random::<f64>();
        let (u1, u2) = (more(), more());
        let nd = self.phase.sample(dir, u1, u2, &mut more).0;
        let mu = nd.dot(dir);
        let p = self.phase.eval(mu);
        let r = (p - self.one_minus_f * self.kept.eval(mu)).max(0.0);
        (nd, rng.random::<f64>() * p < r)
    }

    /// The direction after a scaled collision, (p − r⁺ + (f⁺ − f)·r⁺/f⁺)/(1 − f), and whether
    /// it was a turn within the peak (not a smooth scattering).
    pub(super) fn scatter<R: Rng>(&self, dir: DVec3, rng: &mut R) -> (DVec3, bool) {
        let mut nd = (dir, false);
        for _ in 0..MAX_DRAWS {
            let (d, in_peak) = self.draw(dir, rng);
            nd = (d, in_peak);
            if !in_peak || rng.random::<f64>() < self.keep_peak {
                break;
            }
        }
        nd
    }

    /// The direction after a turn within the peak: r⁺/f⁺.
    pub(super) fn turn<R: Rng>(&self, dir: DVec3, rng: &mut R) -> DVec3 {
        let mut nd = dir;
        for _ in 0..MAX_DRAWS {
            let (d, in_peak) = self.draw(dir, rng);
            if in_peak {
                return d;
            }
            nd = d;
        }
        nd
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64;

    /// Scaled collisions and the δ part's turns together are the true phase function's
    /// scatterings: their mean cosines (per event, weighted ωf and 1 − ωf at ω = 1) give back
    /// g of HG 0.85, and the collisions alone the δ-M g* only on the first moment's budget
    /// (the collisions' mean cosine is g − f·ḡ_r over 1 − f, ḡ_r the peak's mean cosine).
    #[test]
    fn collisions_and_turns_are_the_true_phase_function() {
        let g = 0.85;
        let t = Truncation::new(g, 1.0, 3.5);
        let pt = PeakTurns::new(&Phase::HenyeyGreenstein { g }, &t).unwrap();
        let mut rng = Pcg64::seed_from_u64(7);
        let z = DVec3::Z;
        let n = 400_000;
        let (mut c, mut r) = (0.0, 0.0);
        for _ in 0..n {
            c += pt.scatter(z, &mut rng).0.z;
            r += pt.turn(z, &mut rng).z;
        }
        let (c, r) = (c / n as f64, r / n as f64);
        let f = t.fraction;
        let mean = f * r + (1.0 - f) * c;
        // Standard error of a mean cosine over n draws ≤ 1/√n = 0.0016.
        assert!((mean - g).abs() < 0.005, "mean cosine {mean}");
        assert!(r > 0.85 && r < 1.0, "peak's mean cosine {r}");
    }
}
