//! Diffuse (sky) irradiance on a horizontal surface at the observer: E = ∫ L(θ, φ) cos θ dω over
//! the upper hemisphere (the sky light of Nishita et al. 1996, §3.5, integrated against the cosine), by
//! Gauss-Legendre quadrature in cos θ × midpoint rule in azimuth, using the symmetry of the sky
//! about the sun's vertical plane (azimuth 0…π, doubled).

use super::integrate::Scratch;
use super::quadrature::gauss_legendre;
use super::sky::RadianceEvaluator;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Quadrature nodes in cos θ used by the `sun` product.
pub const SUN_PRODUCT_N_MU: usize = 16;
/// Quadrature nodes in azimuth (0…π) used by the `sun` product.
pub const SUN_PRODUCT_N_PHI: usize = 16;

/// Diffuse irradiance per wavelength, W m⁻² nm⁻¹ (radiance from `eval` is absolute), with `n_mu`
/// Gauss-Legendre nodes in cos θ ∈ (0, 1) and `n_phi` midpoints in azimuth ∈ (0, π).
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
