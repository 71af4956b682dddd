//! Transmittance of the sphere model from the meteorological optical range (Ostroushko et al., eqs 1–3).

/// Contrast threshold that defines the meteorological optical range: a black object at distance
/// S_M is seen with contrast 0.02 (Ostroushko et al.: S_M = ln 0.02 / ln t).
pub const MOR_CONTRAST: f64 = 0.02;

/// Extinction coefficient σ = −ln t per metre from the meteorological optical range S_M in metres:
/// the specific transparency is t = 0.02^(1/S_M), so σ = −ln 0.02 / S_M ≈ 3.912 / S_M.
#[inline]
pub fn extinction_from_mor_per_m(mor_m: f64) -> f64 {
    -MOR_CONTRAST.ln() / mor_m
}

/// Edge function f(d, r) = 1 − d/r for d ≤ r, else 0 (Ostroushko et al., eq 2): the share of a sphere's
/// attenuation that applies at distance d from its centre, so transparency grows to the rim.
#[inline]
pub fn edge_weight(d: f64, r: f64) -> f64 {
    if d <= r {
        1.0 - d / r
    } else {
        0.0
    }
}

/// Transmittance of one sphere, T = T_i·f(d, r) + 1 − f(d, r) (Ostroushko et al., eq 3), with
/// T_i = t^ℓ = exp(−σ·ℓ) over the chord length `chord_m` inside it (eq 1) and `d_m` the distance
/// from the sphere centre to the ray.
#[inline]
pub fn sphere_transmittance(extinction_per_m: f64, chord_m: f64, d_m: f64, r_m: f64) -> f64 {
    let f = edge_weight(d_m, r_m);
    (-extinction_per_m * chord_m).exp() * f + 1.0 - f
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_of_one_mor_leaves_two_percent() {
        // Koschmieder 1924: over a path equal to the MOR the transmittance is the 0.02 threshold.
        let s = extinction_from_mor_per_m(150.0);
        assert!(((-s * 150.0).exp() - 0.02).abs() < 1e-15);
        assert!((s - 3.912_023_005_428_146 / 150.0).abs() < 1e-15);
    }

    #[test]
    fn edge_function_and_mixing() {
        assert_eq!(edge_weight(0.0, 2.0), 1.0);
        assert_eq!(edge_weight(1.0, 2.0), 0.5);
        assert_eq!(edge_weight(3.0, 2.0), 0.0);
        // At the centre line the sphere attenuates fully; at half radius half of it applies.
        let s = 0.01;
        assert!((sphere_transmittance(s, 100.0, 0.0, 50.0) - (-1.0f64).exp()).abs() < 1e-15);
        let t = sphere_transmittance(s, 80.0, 25.0, 50.0);
        assert!((t - (0.5 * (-0.8f64).exp() + 0.5)).abs() < 1e-15);
    }
}
