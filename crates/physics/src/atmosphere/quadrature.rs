//! Quadrature rules and small interpolation helpers shared by the scattering stages.

/// Gauss-Legendre nodes and weights on [−1, 1] (Newton iteration on P_n; exact to 1e-15).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 { 1.0 } else { p1 };
            let pn1 = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (z * pn - pn1) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-15 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

/// Position of `x` on a uniform grid of `n` nodes over [0, 1]: (lower index, fraction), clamped.
#[inline]
pub fn grid_pos(x: f64, n: usize) -> (usize, f64) {
    let f = x.clamp(0.0, 1.0) * (n - 1) as f64;
    let i = (f.floor() as usize).min(n.saturating_sub(2));
    (i, f - i as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        for n in [2, 5, 8, 16, 33] {
            let (x, w) = gauss_legendre(n);
            assert!((w.iter().sum::<f64>() - 2.0).abs() < 1e-12);
            // ∫ x^(2n−2) dx = 2/(2n−1).
            let p = 2 * n - 2;
            let got: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(p as i32)).sum();
            assert!((got - 2.0 / (p as f64 + 1.0)).abs() < 1e-10, "n {n}");
        }
    }
}
