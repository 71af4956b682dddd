//! Phase functions, normalised to integrate to 1 over the sphere (units sr⁻¹), each with
//! `eval`, `sample` and `pdf` (`sample` draws exactly from `eval`, so `pdf` is `eval`).
//!
//! `cos_theta` is the cosine of the scattering angle between the propagation directions of the
//! incident and scattered light (1 = straight on).

use glam::DVec3;
use std::f64::consts::PI;

/// A phase function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Phase {
    /// Molecular scattering, `3/(16π)(1 + cos²θ)`.
    Rayleigh,
    /// Henyey-Greenstein with asymmetry `g`.
    HenyeyGreenstein { g: f64 },
    /// Cornette-Shanks (Nishita et al. 1996, eq 5), a Mie approximation with asymmetry parameter `g`.
    CornetteShanks { g: f64 },
    /// Isotropic, `1/(4π)`.
    Isotropic,
    /// Nishita et al. 1996, §3.3 eq 4 with two terms: `(1 − f)·CS(g) + f·Rayleigh`, `f` the Rayleigh fraction
    /// (the paper's example: 5 % Rayleigh, the rest Cornette-Shanks for the droplets).
    Mixture { g: f64, rayleigh_fraction: f64 },
}

impl Phase {
    /// Phase function value, sr⁻¹.
    pub fn eval(&self, cos_theta: f64) -> f64 {
        let mu = cos_theta.clamp(-1.0, 1.0);
        match *self {
            Phase::Rayleigh => 3.0 / (16.0 * PI) * (1.0 + mu * mu),
            Phase::HenyeyGreenstein { g } => {
                let d = (1.0 + g * g - 2.0 * g * mu).max(1e-12);
                (1.0 - g * g) / (4.0 * PI * d * d.sqrt())
            }
            Phase::CornetteShanks { g } => {
                // Nishita et al. 1996, eq 5: F(θ) = 3/2 (1−g²)/(2+g²) (1+cos²θ)/(1+g²−2g cosθ)^{3/2}, here
                // divided by 4π so that it integrates to 1 over the sphere.
                let d = (1.0 + g * g - 2.0 * g * mu).max(1e-12);
                3.0 / (8.0 * PI) * (1.0 - g * g) * (1.0 + mu * mu) / ((2.0 + g * g) * d * d.sqrt())
            }
            Phase::Isotropic => 1.0 / (4.0 * PI),
            Phase::Mixture {
                g,
                rayleigh_fraction: f,
            } => (1.0 - f) * Phase::CornetteShanks { g }.eval(mu) + f * Phase::Rayleigh.eval(mu),
        }
    }

    /// Mean cosine of the scattering angle, `∫ p(μ) μ dω` (the first Legendre moment): `g` for
    /// Henyey-Greenstein; for Cornette-Shanks integrated numerically (it is not `g`), 0 for
    /// Rayleigh and isotropic.
    pub fn mean_cosine(&self) -> f64 {
        match *self {
            Phase::HenyeyGreenstein { g } => g,
            Phase::Rayleigh | Phase::Isotropic => 0.0,
            _ => {
                // Midpoint rule in u with μ = 1 − 2u² (dμ = −4u du), which resolves the forward
                // peak at μ = 1.
                let n = 20_000;
                let mut s = 0.0;
                for k in 0..n {
                    let u = (k as f64 + 0.5) / n as f64;
                    let mu = 1.0 - 2.0 * u * u;
                    s += self.eval(mu) * mu * 4.0 * u / n as f64;
                }
                2.0 * PI * s
            }
        }
    }

    /// Probability density of [`Phase::sample`] returning a direction with this cosine, sr⁻¹
    /// (every sampler here is exact, so this equals `eval`).
    pub fn pdf(&self, cos_theta: f64) -> f64 {
        self.eval(cos_theta)
    }

    /// Samples the cosine of the scattering angle from two uniform numbers in [0, 1)
    /// (the second is used only by rejection samplers that need more randomness: pass a
    /// stream via `more`).
    pub fn sample_cos(&self, u: f64, more: &mut dyn FnMut() -> f64) -> f64 {
        match *self {
            Phase::Isotropic => 1.0 - 2.0 * u,
            Phase::Rayleigh => {
                // Invert the CDF (3μ + μ³ + 4)/8 = u: μ = A − 1/A with A = (2z + sqrt(4z² + 1))^{1/3}, z = 4u − 2.
                let z = 4.0 * u - 2.0;
                let a = (z + (z * z + 1.0).sqrt()).cbrt();
                (a - 1.0 / a).clamp(-1.0, 1.0)
            }
            Phase::HenyeyGreenstein { g } => sample_hg(g, u),
            Phase::Mixture {
                g,
                rayleigh_fraction: f,
            } => {
                if more() < f {
                    Phase::Rayleigh.sample_cos(u, more)
                } else {
                    Phase::CornetteShanks { g }.sample_cos(u, more)
                }
            }
            Phase::CornetteShanks { g } => {
                // Rejection from HG: CS/HG = 3(1+μ²)/(2(2+g²)) ≤ 3/(2+g²); accept with (1+μ²)/2.
                let mut mu = sample_hg(g, u);
                for _ in 0..64 {
                    if more() < 0.5 * (1.0 + mu * mu) {
                        return mu;
                    }
                    mu = sample_hg(g, more());
                }
                mu
            }
        }
    }

    /// Samples a scattered direction around the propagation direction `wi` (unit vector).
    /// Returns the direction and its pdf (sr⁻¹).
    pub fn sample(
        &self,
        wi: DVec3,
        u1: f64,
        u2: f64,
        more: &mut dyn FnMut() -> f64,
    ) -> (DVec3, f64) {
        let mu = self.sample_cos(u1, more);
        let phi = 2.0 * PI * u2;
        let s = (1.0 - mu * mu).max(0.0).sqrt();
        let (t, b) = orthonormal_basis(wi);
        let dir = (t * (s * phi.cos()) + b * (s * phi.sin()) + wi * mu).normalize();
        (dir, self.pdf(mu))
    }
}

fn sample_hg(g: f64, u: f64) -> f64 {
    if g.abs() < 1e-4 {
        return 1.0 - 2.0 * u;
    }
    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// Two unit vectors completing `n` to a right-handed orthonormal basis (Duff et al. 2017).
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    const ALL: [Phase; 9] = [
        Phase::Rayleigh,
        Phase::Isotropic,
        Phase::HenyeyGreenstein { g: 0.76 },
        Phase::HenyeyGreenstein { g: -0.3 },
        Phase::CornetteShanks { g: 0.7 },
        Phase::CornetteShanks { g: 0.95 },
        Phase::Mixture {
            g: 0.85,
            rayleigh_fraction: 0.05,
        },
        Phase::Mixture {
            g: 0.6,
            rayleigh_fraction: 0.5,
        },
        Phase::HenyeyGreenstein { g: -0.9 },
    ];

    #[test]
    fn mean_cosine_matches_quadrature() {
        for p in ALL {
            let n = 200_000;
            let h = 2.0 / n as f64;
            let m: f64 = (0..n)
                .map(|i| {
                    let mu = -1.0 + (i as f64 + 0.5) * h;
                    p.eval(mu) * mu * h
                })
                .sum::<f64>()
                * 2.0
                * PI;
            assert!(
                (p.mean_cosine() - m).abs() < 2e-3,
                "{p:?}: {} vs {m}",
                p.mean_cosine()
            );
        }
        // Cornette & Shanks 1992: ⟨μ⟩ = 3g(4 + g²) / (5(2 + g²)), above g for g > 0 (0.885 at 0.85).
        let g: f64 = 0.85;
        let closed = 3.0 * g * (4.0 + g * g) / (5.0 * (2.0 + g * g));
        assert!((Phase::CornetteShanks { g }.mean_cosine() - closed).abs() < 1e-3);
    }

    #[test]
    fn every_phase_integrates_to_one() {
        for p in ALL {
            // ∫ p dω = 2π ∫_{-1}^{1} p(μ) dμ, Simpson with many points (peaks up to g = 0.95).
            let n = 200_000;
            let h = 2.0 / n as f64;
            let mut s = p.eval(-1.0) + p.eval(1.0);
            for i in 1..n {
                s += p.eval(-1.0 + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
            }
            let total = 2.0 * PI * s * h / 3.0;
            assert!((total - 1.0).abs() < 1e-4, "{p:?}: {total}");
        }
    }

    /// χ²-style check: histogram of sampled cosines against the pdf integrated over each bin.
    #[test]
    fn samplers_match_their_pdf() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for p in ALL {
            let bins = 40;
            let n = 200_000;
            let mut hist = vec![0.0f64; bins];
            for _ in 0..n {
                let u = rng.random::<f64>();
                let mut more = || rng.random::<f64>();
                let mu = p.sample_cos(u, &mut more);
                let b = (((mu + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1);
                hist[b] += 1.0;
            }
            let mut chi2 = 0.0;
            for (b, &observed) in hist.iter().enumerate() {
                let (a, c) = (
                    -1.0 + 2.0 * b as f64 / bins as f64,
                    -1.0 + 2.0 * (b + 1) as f64 / bins as f64,
                );
                let m = 200;
                let expected_p: f64 = (0..m)
                    .map(|k| p.pdf(a + (c - a) * (k as f64 + 0.5) / m as f64))
                    .sum::<f64>()
                    * (c - a)
                    / m as f64
                    * 2.0
                    * PI;
                let expected = expected_p * n as f64;
                chi2 += (observed - expected).powi(2) / expected.max(1.0);
            }
            // 39 degrees of freedom: the 99.9 % quantile is about 72.
            assert!(chi2 < 72.0, "{p:?}: chi2 {chi2}");
        }
    }

    #[test]
    fn sampled_directions_are_unit_and_centred_on_wi() {
        let wi = DVec3::new(0.3, -0.4, 0.866).normalize();
        let mut more = || 0.1;
        let (d, pdf) = Phase::HenyeyGreenstein { g: 0.9 }.sample(wi, 0.5, 0.25, &mut more);
        assert!((d.length() - 1.0).abs() < 1e-12);
        assert!(pdf > 0.0);
        assert!(d.dot(wi) > 0.8);
    }
}
