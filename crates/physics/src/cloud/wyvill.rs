//! Wyvill's metaball field function and its normalisation (Dobashi et al. 2000, appendix B, eqs B.1–B.2).
//!
//! `h(r) = -4/9 a⁶ + 17/9 a⁴ - 22/9 a² + 1` for `r <= R` (0 beyond), with `a = r/R`. It falls
//! smoothly from 1 at the centre to 0 with zero slope at the effective radius `R`.
//!
//! # The printed normalisation (B.2) is not a volume integral
//!
//! Dobashi et al. 2000 normalises `f = h/c` "by its total density" with `c = 4π∫₀ᴿ h(r) dr = 748/405 πR`.
//! Neither half of that holds: `4π∫₀ᴿ h dr` is `1888/945 πR` (not `748/405 πR`), and a factor
//! linear in `R` cannot make a 3-D density integrate to a constant. The total density of one
//! metaball is the volume integral
//!
//! `c = ∫∫∫ h(|x|) dV = 4π∫₀ᴿ h(r) r² dr = 736/2835 πR³ ≈ 0.8156 R³`,
//!
//! which is what [`normalisation_m3`] returns, so `∫∫∫ f dV = 1` (checked by 3-D quadrature in
//! the tests). Eq 12 of Dobashi et al. 2000 (`ρ = Σ q f`) then conserves the total of the cell densities `q`.

use std::f64::consts::PI;

/// `∫∫∫ h dV / R³ = 736π/2835` (see the module docs; replaces the printed B.2).
pub const VOLUME_FACTOR: f64 = 736.0 * PI / 2835.0;

/// The normalisation as printed in Dobashi et al. 2000, eq B.2, `c/R = 748π/405` (kept only to document the
/// discrepancy; do not use it to normalise a 3-D density).
pub const PRINTED_B2_FACTOR: f64 = 748.0 * PI / 405.0;

/// Field value from the squared normalised distance `a² = (r/R)²` (Dobashi et al. 2000, eq B.1); 0 for
/// `a² >= 1`. Taking `a²` avoids a square root in inner loops.
#[inline]
pub fn h_of_a2(a2: f64) -> f64 {
    if a2 >= 1.0 {
        return 0.0;
    }
    // Horner form of -4/9 s³ + 17/9 s² - 22/9 s + 1 with s = a².
    ((-4.0 / 9.0 * a2 + 17.0 / 9.0) * a2 - 22.0 / 9.0) * a2 + 1.0
}

/// Wyvill's field `h(r)` at distance `r_m` from the centre of a ball of effective radius
/// `radius_m` (Dobashi et al. 2000, eq B.1). Dimensionless, 1 at the centre, 0 for `r >= R`.
/// Precondition: `radius_m > 0`.
#[inline]
pub fn h(r_m: f64, radius_m: f64) -> f64 {
    let a = r_m / radius_m;
    h_of_a2(a * a)
}

/// Total density of one unit metaball, `c = ∫∫∫ h dV = 736/2835 πR³` in m³ (the corrected Dobashi et al. 2000,
/// eq B.2; see the module docs).
#[inline]
pub fn normalisation_m3(radius_m: f64) -> f64 {
    VOLUME_FACTOR * radius_m * radius_m * radius_m
}

/// The normalised basis function `f = h/c` (Dobashi et al. 2000, appendix B), in m⁻³: it integrates to 1
/// over space, so `Σ q f` conserves `Σ q` (Dobashi et al. 2000, eq 12).
#[inline]
pub fn normalised(r_m: f64, radius_m: f64) -> f64 {
    h(r_m, radius_m) / normalisation_m3(radius_m)
}

/// Derivative `dh/dr` in m⁻¹ (0 outside the ball); used for surface normals.
#[inline]
pub fn dh_dr(r_m: f64, radius_m: f64) -> f64 {
    let a = r_m / radius_m;
    if a >= 1.0 {
        return 0.0;
    }
    let a2 = a * a;
    // d/da of the polynomial: -24/9 a⁵ + 68/9 a³ - 44/9 a.
    let dh_da = a * ((-24.0 / 9.0 * a2 + 68.0 / 9.0) * a2 - 44.0 / 9.0);
    dh_da / radius_m
}

/// Column integral `∫ h dz` through a ball of radius `radius_m` along a straight line passing at
/// distance `d_m` from its centre, in metres (closed form: `h` is a polynomial in `d² + z²`).
/// The projection of the field that an optically thin, vertically viewed image sees
/// (Nishita & Dobashi 2001, §3.1).
pub fn column_integral_m(d_m: f64, radius_m: f64) -> f64 {
    let u = d_m / radius_m;
    let u2 = u * u;
    if u2 >= 1.0 {
        return 0.0;
    }
    let half = (1.0 - u2).sqrt();
    // h = Σ_n c_n s^n, s = u² + t²; ∫_{-L}^{L} (u² + t²)^n dt = 2 Σ_k C(n,k) u^{2(n-k)} L^{2k+1}/(2k+1).
    const C: [f64; 4] = [1.0, -22.0 / 9.0, 17.0 / 9.0, -4.0 / 9.0];
    const BINOM: [[f64; 4]; 4] = [
        [1.0, 0.0, 0.0, 0.0],
        [1.0, 1.0, 0.0, 0.0],
        [1.0, 2.0, 1.0, 0.0],
        [1.0, 3.0, 3.0, 1.0],
    ];
    let mut total = 0.0;
    for (n, cn) in C.iter().enumerate() {
        let mut term = 0.0;
        for (k, binom) in BINOM[n].iter().enumerate().take(n + 1) {
            let l_pow = half.powi(2 * k as i32 + 1);
            term += binom * u2.powi((n - k) as i32) * l_pow / (2 * k + 1) as f64;
        }
        total += cn * 2.0 * term;
    }
    total.max(0.0) * radius_m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_is_one_at_centre_and_zero_with_zero_slope_at_radius() {
        assert_eq!(h(0.0, 3.0), 1.0);
        assert!(h(3.0, 3.0).abs() < 1e-15);
        assert_eq!(h(3.5, 3.0), 0.0);
        assert!(dh_dr(3.0 - 1e-12, 3.0).abs() < 1e-9);
        // Monotone decreasing inside the ball.
        let mut prev = 1.0;
        for i in 1..=100 {
            let v = h(i as f64 * 0.03, 3.0);
            assert!(v <= prev);
            prev = v;
        }
    }

    #[test]
    fn derivative_matches_central_difference() {
        for &r in &[0.1, 0.7, 1.3, 1.9] {
            let eps = 1e-6;
            let fd = (h(r + eps, 2.0) - h(r - eps, 2.0)) / (2.0 * eps);
            assert!((fd - dh_dr(r, 2.0)).abs() < 1e-7, "r = {r}");
        }
    }

    /// The normalised basis integrates to 1 over space: Cartesian midpoint quadrature on a
    /// 160³ lattice (independent of the radial closed form), tolerance 1e-3.
    #[test]
    fn normalised_field_integrates_to_one_by_cartesian_quadrature() {
        let radius_m = 2.5;
        let n = 160usize;
        let step = 2.0 * radius_m / n as f64;
        let mut sum = 0.0;
        for k in 0..n {
            let z = -radius_m + (k as f64 + 0.5) * step;
            for j in 0..n {
                let y = -radius_m + (j as f64 + 0.5) * step;
                for i in 0..n {
                    let x = -radius_m + (i as f64 + 0.5) * step;
                    sum += normalised((x * x + y * y + z * z).sqrt(), radius_m);
                }
            }
        }
        let integral = sum * step * step * step;
        assert!((integral - 1.0).abs() < 1e-3, "∫f dV = {integral}");
    }

    /// The printed B.2 constant is neither the volume integral nor 4π∫h dr (Simpson's rule).
    #[test]
    fn printed_b2_is_not_the_volume_integral() {
        let radius_m = 1.0;
        let n = 2000;
        let simpson = |g: &dyn Fn(f64) -> f64| {
            let step = radius_m / n as f64;
            let mut s = g(0.0) + g(radius_m);
            for i in 1..n {
                s += g(i as f64 * step) * if i % 2 == 1 { 4.0 } else { 2.0 };
            }
            s * step / 3.0
        };
        let radial = 4.0 * PI * simpson(&|r| h(r, radius_m));
        let volume = 4.0 * PI * simpson(&|r| h(r, radius_m) * r * r);
        assert!((radial - 1888.0 / 945.0 * PI).abs() < 1e-9);
        assert!((volume - normalisation_m3(radius_m)).abs() < 1e-9);
        assert!((radial - PRINTED_B2_FACTOR).abs() > 0.4);
        assert!((volume - PRINTED_B2_FACTOR).abs() > 4.0);
    }

    #[test]
    fn column_integral_matches_numerical_line_integral() {
        let radius_m = 4.0;
        for &d in &[0.0, 0.5, 1.7, 3.2, 3.99] {
            let n = 20_000;
            let half = radius_m;
            let step = 2.0 * half / n as f64;
            let numeric: f64 = (0..n)
                .map(|i| {
                    let z = -half + (i as f64 + 0.5) * step;
                    h((d * d + z * z).sqrt(), radius_m)
                })
                .sum::<f64>()
                * step;
            let exact = column_integral_m(d, radius_m);
            assert!(
                (numeric - exact).abs() < 1e-6,
                "d = {d}: {numeric} vs {exact}"
            );
        }
        assert_eq!(column_integral_m(4.0, radius_m), 0.0);
        assert!((column_integral_m(0.0, 1.0) - 2.0 * 472.0 / 945.0).abs() < 1e-12);
    }
}
