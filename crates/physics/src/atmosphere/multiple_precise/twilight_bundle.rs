//! The texture bundles' twilight lookup ([`super::PackedPoint`]): the operations of
//! [`super::twilight_fixed`] with a cheaper exponential, [`exp_cubic_f32`] (relative error
//! ≤ 8·10⁻⁵, against [`super::exp_fast_f32`]'s 2·10⁻⁷), whose polynomial is the larger part of
//! a twilight corner's arithmetic. The RGB bundles store half floats (a relative step of
//! 4.9·10⁻⁴), so the difference stays below their own rounding (a spectral form of up to four
//! wavelengths, stored in floats, carries it: ≤ 2·10⁻⁵ of its texels, the exponential's error
//! times the multiple scattering's share); the products and the precise table's build keep
//! [`super::twilight_fixed`].

/// `exp(x)` in f32 to a relative error of 7.9·10⁻⁵ for x ∈ [−87, 88] (clamped there; measured
/// against f64 `exp` over [−87, 5] by the test below), branch-free: x log₂e = k + f with k an
/// integer and |f| ≤ ½ (the product rounded once: an error ≤ 7.5·10⁻⁶ in f at |x| = 87,
/// 5·10⁻⁶ of the result), 2^f by the cubic nearest to it in relative error on [−½, ½] (7.5·10⁻⁵; Lawson's
/// iteration of weighted least squares, Rice 1964, "The Approximation of Functions", vol. 1,
/// §6-5), scaled by 2^k through the exponent bits (Cody & Waite 1980, "Software Manual for the
/// Elementary Functions", ch. 6): 13 operations beside the clamp, against 24 for
/// [`super::exp_fast_f32`]'s two-part reduction and degree-6 polynomial.
#[inline(always)]
pub(super) fn exp_cubic_f32(x: f32) -> f32 {
    // 1.5·2^23: adding it rounds to an integer that lands in the low mantissa bits.
    const SHIFT: f32 = 12_582_912.0;
    const C0: f32 = 0.999_928;
    const C1: f32 = 0.693_259_54;
    const C2: f32 = 0.242_611_86;
    const C3: f32 = 0.055_179_648;
    let t = x.clamp(-87.0, 88.0) * std::f32::consts::LOG2_E;
    let kf = t + SHIFT;
    let f = t - (kf - SHIFT);
    let p = ((C3 * f + C2) * f + C1) * f + C0;
    // k + 127 ∈ [2, 254] after the clamp: shifted into the exponent field it makes 2^k.
    let scale = f32::from_bits(kf.to_bits().wrapping_add(127) << 23);
    p * scale
}

/// [`super::twilight_fixed`] with [`exp_cubic_f32`]: `N` lanes interpolated over sun zenith on
/// the four Catmull–Rom node rows `v` (logarithms `ln_v`, [`super::ln_or_zero_f32`]), weights
/// `wq`, in ln where the four nodes are positive, linearly between the middle two (fraction
/// `fs`) elsewhere.
#[inline(always)]
pub(super) fn twilight_fixed_cubic<const N: usize>(
    v: [&[f32; N]; 4],
    ln_v: [&[f32; N]; 4],
    wq: [f32; 4],
    fs: f32,
) -> [f32; N] {
    super::twilight_fixed_with(v, ln_v, wq, fs, exp_cubic_f32)
}

/// Adds to `a` the [`twilight_fixed_cubic`] of the first azimuth node of the four sun-zenith
/// nodes' runs of two adjacent azimuth nodes (values `v`, logarithms `ln`,
/// [`super::packed_runs`]) times `w[0]`, then that of the second times `w[1]`: the operations of
/// one node at a time, in the same order.
#[inline(always)]
pub(super) fn add_pair(
    v: [&[f32; 2 * super::PACKED_LANES]; 4],
    ln: [&[f32; 2 * super::PACKED_LANES]; 4],
    w: [f32; 2],
    wq: [f32; 4],
    fs: f32,
    a: &mut [f32; super::PACKED_LANES],
) {
    const L: usize = super::PACKED_LANES;
    for (e, &w) in w.iter().enumerate() {
        let row = |q: &[f32; 2 * L]| -> [f32; L] {
            let mut x = [0.0f32; L];
            x.copy_from_slice(&q[e * L..][..L]);
            x
        };
        let v = [row(v[0]), row(v[1]), row(v[2]), row(v[3])];
        let ln = [row(ln[0]), row(ln[1]), row(ln[2]), row(ln[3])];
        let x = twilight_fixed_cubic(
            [&v[0], &v[1], &v[2], &v[3]],
            [&ln[0], &ln[1], &ln[2], &ln[3]],
            wq,
            fs,
        );
        for (o, v) in a.iter_mut().zip(&x) {
            *o += w * *v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_cubic_f32_within_its_stated_error() {
        let mut worst: f64 = 0.0;
        for i in 0..2_000_000 {
            let x = (-87.0 + 92.0 * i as f64 / 2_000_000.0) as f32;
            let exact = (x as f64).exp();
            worst = worst.max((exp_cubic_f32(x) as f64 / exact - 1.0).abs());
        }
        // Measured 7.9e-5 (the cubic's 7.5e-5, the rest the rounded reduction).
        assert!(worst < 8.2e-5, "{worst}");
        assert!((exp_cubic_f32(0.0) - 1.0).abs() < 8e-5);
        assert!(exp_cubic_f32(-1e6) < 2e-38 && exp_cubic_f32(-1e6) >= 0.0);
        assert!(exp_cubic_f32(1e6).is_finite());
    }
}
