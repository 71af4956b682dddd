//! Photometry of sampled spectra: illuminance (CIE photopic, lux) and correlated colour
//! temperature.
//!
//! Illuminance: E_v = K_m ∫ E(λ) V(λ) dλ with K_m = 683 lm/W and V(λ) = ȳ(λ) of CIE 1931 (CIE 015:2018
//! §3 and §9.5), integrated by the same rule as [`super::colour`] (samples interpolated linearly onto
//! 1 nm, 360–830 nm).
//!
//! Correlated colour temperature (CIE 015:2018 §9.5): the temperature of the Planckian radiator
//! whose chromaticity is nearest in the CIE 1960 UCS (u, v) diagram. The Planckian locus is computed
//! here from Planck's law and the CIE 1931 CMFs (no tabulated isotemperature lines): a scan in
//! reciprocal temperature then golden-section refinement of the squared (u, v) distance. Duv is
//! that distance, positive above the locus (towards green). CIE 015 calls the CCT meaningful only
//! for |Duv| ≤ 0.05; beyond it none is given.

use super::colour::XyzWeights;
use super::data::cie1931_cmfs;

/// Maximum luminous efficacy of photopic vision, lm/W (CIE 015:2018).
pub const LUMINOUS_EFFICACY_LM_PER_W: f64 = 683.0;
/// Second radiation constant c₂ = hc/k, m·K (CODATA 2018).
const C2_M_K: f64 = 1.438_776_877e-2;
/// Largest |Duv| for which a CCT is reported (CIE 015:2018 §9.5).
pub const MAX_DUV: f64 = 0.05;
/// Temperatures searched, K.
const T_MIN_K: f64 = 1000.0;
const T_MAX_K: f64 = 100_000.0;

/// Photopic illuminance, lux, of a spectral irradiance in W m⁻² nm⁻¹ sampled at `wavelengths_nm`.
pub fn illuminance_lux(wavelengths_nm: &[f64], irradiance_w_m2_nm: &[f64]) -> f64 {
    LUMINOUS_EFFICACY_LM_PER_W * XyzWeights::new(wavelengths_nm).xyz(irradiance_w_m2_nm)[1]
}

/// A correlated colour temperature and the signed distance from the Planckian locus.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Cct {
    /// Correlated colour temperature, K.
    pub kelvin: f64,
    /// Signed distance from the Planckian locus in CIE 1960 (u, v), positive above it.
    pub duv: f64,
}

/// CIE 1960 (u, v) of XYZ.
fn uv_1960(xyz: [f64; 3]) -> Option<(f64, f64)> {
    let d = xyz[0] + 15.0 * xyz[1] + 3.0 * xyz[2];
    (d > 0.0 && d.is_finite()).then(|| (4.0 * xyz[0] / d, 6.0 * xyz[1] / d))
}

/// CIE 1960 (u, v) of a Planckian radiator at `t_k`, from Planck's law on the 1 nm CMFs.
pub fn planckian_uv(t_k: f64) -> (f64, f64) {
    let cmfs = cie1931_cmfs();
    let mut xyz = [0.0; 3];
    for k in 0..=470 {
        let lambda_nm = 360.0 + k as f64;
        let lambda_m = lambda_nm * 1e-9;
        // Relative spectral radiance: λ⁻⁵ / (exp(c₂/λT) − 1); constants cancel in (u, v).
        let b = 1.0 / (lambda_m.powi(5) * (C2_M_K / (lambda_m * t_k)).exp_m1()) * 1e-30;
        for (c, cmf) in cmfs.iter().enumerate() {
            xyz[c] += b * cmf.eval(lambda_nm);
        }
    }
    uv_1960(xyz).unwrap_or((0.0, 0.0))
}

/// Correlated colour temperature of XYZ, or `None` when the colour is black or farther than
/// [`MAX_DUV`] from the Planckian locus in the 1000–100 000 K range.
pub fn correlated_colour_temperature(xyz: [f64; 3]) -> Option<Cct> {
    let (u, v) = uv_1960(xyz)?;
    let dist2 = |mired: f64| {
        let (pu, pv) = planckian_uv(1e6 / mired);
        (u - pu).powi(2) + (v - pv).powi(2)
    };
    // Scan in reciprocal temperature (the locus is nearly uniform in mired), then refine.
    let (lo, hi) = (1e6 / T_MAX_K, 1e6 / T_MIN_K);
    let n = 100;
    let step = (hi - lo) / n as f64;
    let (mut best, mut best_d) = (lo, f64::INFINITY);
    for i in 0..=n {
        let m = lo + step * i as f64;
        let d = dist2(m);
        if d < best_d {
            (best, best_d) = (m, d);
        }
    }
    let (mut a, mut b) = ((best - step).max(lo), (best + step).min(hi));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (dist2(c), dist2(d));
    while b - a > 1e-6 {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = dist2(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = dist2(d);
        }
    }
    let mired = 0.5 * (a + b);
    let kelvin = 1e6 / mired;
    let (pu, pv) = planckian_uv(kelvin);
    // Above the locus = on the side away from the locus' centre of curvature (towards green, +v).
    let sign = if v >= pv { 1.0 } else { -1.0 };
    let duv = sign * ((u - pu).powi(2) + (v - pv).powi(2)).sqrt();
    (duv.abs() <= MAX_DUV && kelvin > T_MIN_K * 1.0001 && kelvin < T_MAX_K * 0.9999)
        .then_some(Cct { kelvin, duv })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_planckian_radiator_has_its_own_temperature_and_zero_duv() {
        for t in [1500.0, 2856.0, 5000.0, 6504.0, 10_000.0, 25_000.0] {
            let nm: Vec<f64> = (0..=470).map(|k| 360.0 + k as f64).collect();
            let e: Vec<f64> = nm
                .iter()
                .map(|&l| {
                    let m = l * 1e-9;
                    1.0 / (m.powi(5) * (C2_M_K / (m * t)).exp_m1()) * 1e-30
                })
                .collect();
            let xyz = XyzWeights::new(&nm).xyz(&e);
            let c = correlated_colour_temperature(xyz).unwrap();
            assert!((c.kelvin / t - 1.0).abs() < 1e-5, "{t}: {c:?}");
            assert!(c.duv.abs() < 1e-7, "{t}: {c:?}");
        }
    }

    #[test]
    fn black_and_far_off_locus_colours_have_no_cct() {
        assert!(correlated_colour_temperature([0.0, 0.0, 0.0]).is_none());
        // Pure green-ish (x 0.2, y 0.7) is far above the locus.
        assert!(correlated_colour_temperature([0.2, 0.7, 0.1]).is_none());
    }

    #[test]
    fn illuminance_of_a_flat_spectrum_is_683_times_the_integral_of_v() {
        // ∫ ȳ dλ over 360–830 nm at 1 nm is 106.857 (CIE 1931 2° table).
        let lux = illuminance_lux(&[360.0, 830.0], &[1.0, 1.0]);
        assert!((lux / (683.0 * 106.857) - 1.0).abs() < 1e-3, "{lux}");
    }
}
