//! Small numeric kernels for the precomputation hot loops: an `exp` and an `acos` that compile to
//! straight-line arithmetic (so loops over wavelengths vectorise), and a dispatcher that runs a
//! whole loop nest compiled for AVX2 + FMA when the CPU has them.

use std::f64::consts::{LN_2, LOG2_E, PI};

/// `exp(x)` to 1e-14 relative for x in [−708, 709] (clamped outside: exp(−708) ≈ 3e−308 stands
/// for 0). Cody-Waite reduction x = k ln 2 + r, |r| ≤ ln2/2, degree-11 Taylor polynomial for
/// e^r (truncation r¹²/12! < 1e−14), 2^k assembled in the exponent bits. No branches and no
/// calls, so a loop over wavelengths vectorises.
#[inline(always)]
pub fn exp_fast(x: f64) -> f64 {
    // 1.5·2^52: adding it rounds to an integer that lands in the low mantissa bits.
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    // fdlibm's split of ln 2 (the high part has trailing zero bits, so k·LN2_HI is exact).
    #[allow(clippy::excessive_precision)]
    const LN2_HI: f64 = 0.693_147_180_369_123_816_49;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    let x = x.clamp(-708.0, 709.0);
    let kf = x * LOG2_E + SHIFT;
    let k = kf - SHIFT;
    let r = (x - k * LN2_HI) - k * LN2_LO;
    debug_assert!(r.abs() <= 0.5 * LN_2 + 1e-9);
    let mut p = 1.0 / 39_916_800.0;
    p = p * r + 1.0 / 3_628_800.0;
    p = p * r + 1.0 / 362_880.0;
    p = p * r + 1.0 / 40_320.0;
    p = p * r + 1.0 / 5_040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r + 1.0;
    p = p * r + 1.0;
    // The low mantissa bits of kf hold k (two's complement); shifted into the exponent field
    // with the bias they make 2^k (k + 1023 ∈ [2, 2046] after the clamp).
    let scale = f64::from_bits(kf.to_bits().wrapping_add(1023) << 52);
    p * scale
}

/// `ln(x)` to 1e-15 absolute (ln of a normal positive f64), branch-free so a loop over
/// wavelengths vectorises (AVX2 has no 64-bit arithmetic shift or int→float conversion, so only
/// logical shifts, adds and masks are used). Reduction x = 2^k z with z ∈ [√½, √2) (the offset
/// trick of musl's `log`), then ln z = 2 atanh s = 2(s + s³/3 + … + s¹⁹/19), s = (z − 1)/(z + 1),
/// |s| ≤ 0.172 (truncation s²¹/21 < 1e-17). Not for 0, subnormals, infinities or NaN: callers
/// mask those (the result is then finite but meaningless).
#[inline(always)]
pub fn ln_fast(x: f64) -> f64 {
    // Bits of √½; `ix − OFF` has the exponent of x relative to the reduced range in its top bits.
    const OFF: u64 = 0x3fe6_a09e_667f_3bcd;
    const BIAS: u64 = 1024 << 52;
    // 2^52 as f64: OR-ing a small integer into its mantissa and subtracting gives it exactly.
    const TWO52: f64 = 4_503_599_627_370_496.0;
    #[allow(clippy::excessive_precision)]
    const LN2_HI: f64 = 0.693_147_180_369_123_816_49;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    let ix = x.to_bits();
    // k + 1024 in the top 12 bits (x positive and normal: no wrap-around).
    let tmp = ix.wrapping_sub(OFF).wrapping_add(BIAS);
    let kb = tmp >> 52;
    let z = f64::from_bits(ix.wrapping_sub((tmp & (0xfff << 52)).wrapping_sub(BIAS)));
    let k = (f64::from_bits(0x4330_0000_0000_0000 | kb) - TWO52) - 1024.0;
    let s = (z - 1.0) / (z + 1.0);
    let s2 = s * s;
    let mut p = 1.0 / 19.0;
    p = p * s2 + 1.0 / 17.0;
    p = p * s2 + 1.0 / 15.0;
    p = p * s2 + 1.0 / 13.0;
    p = p * s2 + 1.0 / 11.0;
    p = p * s2 + 1.0 / 9.0;
    p = p * s2 + 1.0 / 7.0;
    p = p * s2 + 1.0 / 5.0;
    p = p * s2 + 1.0 / 3.0;
    p = p * s2 + 1.0;
    k * LN2_HI + (2.0 * s * p + k * LN2_LO)
}

/// `exp(x)` in f32 to 2e-7 relative (a few ulp) for x in [−87, 88] (clamped outside: exp(−87) ≈
/// 1.6e−38, the smallest normal f32 order, stands for 0). Cody-Waite reduction x = k ln 2 + r,
/// |r| ≤ ln2/2, with Cephes' degree-7 minimax polynomial for e^r; 2^k assembled in the exponent
/// bits. Branch-free, so a loop over wavelengths vectorises 8 wide under AVX2 (twice the lanes
/// of [`exp_fast`], and half its terms). For quantities stored in f32 anyway; optical depths are
/// summed in f64 before they are rounded to f32 here (|τ| × 6e-8 relative more).
#[inline(always)]
pub fn exp_fast_f32(x: f32) -> f32 {
    // 1.5·2^23: adding it rounds to an integer that lands in the low mantissa bits.
    const SHIFT: f32 = 12_582_912.0;
    // Cephes' split of ln 2 (the high part has trailing zero bits, so k·LN2_HI is exact).
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.0, 88.0);
    let kf = x * std::f32::consts::LOG2_E + SHIFT;
    let k = kf - SHIFT;
    let r = (x - k * LN2_HI) - k * LN2_LO;
    let mut p = 1.987_569_1e-4;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    // k + 127 ∈ [1, 254] after the clamp: shifted into the exponent field it makes 2^k.
    let scale = f32::from_bits(kf.to_bits().wrapping_add(127) << 23);
    e * scale
}

/// `ln(x)` in f32 to 2e-7 absolute plus half an ulp of the result, for positive normal `x`
/// (≥ `f32::MIN_POSITIVE`), branch-free (AVX2 has 32-bit arithmetic shifts and int→float
/// conversion, so this is musl's `logf` reduction): x = 2^k z with z ∈ [√½, √2), then
/// ln z = 2 atanh s = 2(s + s³/3 + … + s¹¹/11), s = (z − 1)/(z + 1), |s| ≤ 0.172 (truncation
/// s¹³/13 < 1e-10). Not for 0, subnormals, infinities or NaN: callers mask those.
#[inline(always)]
pub fn ln_fast_f32(x: f32) -> f32 {
    // Bits of √½; `ix − OFF` has the exponent of x relative to the reduced range in its top bits.
    const OFF: u32 = 0x3f35_04f3;
    // musl's split of ln 2 (0x3f317180: k·LN2_HI is exact for |k| < 2^8).
    const LN2_HI: f32 = 0.693_138_1;
    const LN2_LO: f32 = 9.058_001e-6;
    let ix = x.to_bits();
    let tmp = ix.wrapping_sub(OFF);
    let k = ((tmp as i32) >> 23) as f32;
    let z = f32::from_bits(ix.wrapping_sub(tmp & 0xff80_0000));
    let s = (z - 1.0) / (z + 1.0);
    let s2 = s * s;
    let mut p = 1.0 / 11.0;
    p = p * s2 + 1.0 / 9.0;
    p = p * s2 + 1.0 / 7.0;
    p = p * s2 + 1.0 / 5.0;
    p = p * s2 + 1.0 / 3.0;
    p = p * s2 + 1.0;
    k * LN2_HI + (2.0 * s * p + k * LN2_LO)
}

/// `acos(x)` to 2e−8 rad (Abramowitz & Stegun 4.4.46), `x` clamped to [−1, 1]; enough for
/// grid positions, which is all it is used for.
#[inline(always)]
pub fn acos_fast(x: f64) -> f64 {
    let a = x.abs().min(1.0);
    let mut p = -0.001_262_491_1;
    p = p * a + 0.006_670_090_1;
    p = p * a - 0.017_088_125_6;
    p = p * a + 0.030_891_881_0;
    p = p * a - 0.050_174_304_6;
    p = p * a + 0.088_978_987_4;
    p = p * a - 0.214_598_801_6;
    p = p * a + 1.570_796_305_0;
    let v = (1.0 - a).max(0.0).sqrt() * p;
    if x < 0.0 {
        PI - v
    } else {
        v
    }
}

/// Whether the AVX2 + FMA variants can run here.
#[inline]
pub fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the AVX-512 variants of [`simd_dispatch_avx512`] can run here (AVX-512 F, DQ, VL and
/// BW, with AVX2 and FMA).
#[inline]
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512dq")
            && std::is_x86_feature_detected!("avx512vl")
            && std::is_x86_feature_detected!("avx512bw")
            && has_avx2_fma()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`simd_dispatch`] with a third copy of the body compiled for AVX-512 ([`has_avx512`]), run
/// where the CPU has it: loops over many independent values (suns) then run 8 × f64 / 16 × f32
/// wide. The same IEEE operations in every copy (Rust forms no fused multiply-adds), so the
/// same values.
#[macro_export]
#[doc(hidden)]
macro_rules! simd_dispatch_avx512 {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$m])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            #[allow(clippy::too_many_arguments)]
            fn inner($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512dq,avx512vl,avx512bw,avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                fn avx512($($arg: $ty),*) $(-> $ret)? { inner($($arg),*) }
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                fn avx2($($arg: $ty),*) $(-> $ret)? { inner($($arg),*) }
                if $crate::atmosphere::kernels::has_avx512() {
                    // SAFETY: the CPU supports AVX-512 F/DQ/VL/BW, AVX2 and FMA (checked just above).
                    return unsafe { avx512($($arg),*) };
                }
                if $crate::atmosphere::kernels::has_avx2_fma() {
                    // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                    return unsafe { avx2($($arg),*) };
                }
            }
            inner($($arg),*)
        }
    };
}

/// Defines a function whose body is compiled twice, generically and for AVX2 + FMA, and runs
/// the AVX2 copy when the CPU has those features: every loop the body (and what it inlines)
/// runs over wavelengths is then vectorised 4 × f64 / 8 × f32 wide. Arguments are plain
/// `name: Type` pairs.
#[macro_export]
#[doc(hidden)]
macro_rules! simd_dispatch {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$m])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            #[allow(clippy::too_many_arguments)]
            fn inner($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                fn avx2($($arg: $ty),*) $(-> $ret)? { inner($($arg),*) }
                if $crate::atmosphere::kernels::has_avx2_fma() {
                    // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                    return unsafe { avx2($($arg),*) };
                }
            }
            inner($($arg),*)
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_fast_matches_libm() {
        let mut worst: f64 = 0.0;
        for i in 0..200_000 {
            let x = -700.0 + 709.0 * i as f64 / 200_000.0;
            let (a, b) = (exp_fast(x), x.exp());
            worst = worst.max((a / b - 1.0).abs());
        }
        assert!(worst < 1e-13, "{worst}");
        assert_eq!(exp_fast(0.0), 1.0);
        assert!(exp_fast(-1e6) < 1e-300 && exp_fast(-1e6) >= 0.0);
    }

    #[test]
    fn ln_fast_matches_libm() {
        let mut worst: f64 = 0.0;
        // 1e-300 … 1e300 in uneven steps, and around 1 where ln is small.
        for i in 0..200_000 {
            let x =
                10f64.powf(-300.0 + 600.0 * i as f64 / 200_000.0) * (1.0 + 0.37 * (i % 7) as f64);
            worst = worst.max((ln_fast(x) - x.ln()).abs() / x.ln().abs().max(1.0));
        }
        for i in 0..20_000 {
            let x = 0.5 + i as f64 / 10_000.0;
            worst = worst.max((ln_fast(x) - x.ln()).abs());
        }
        assert!(worst < 1e-15, "{worst}");
        assert_eq!(ln_fast(1.0), 0.0);
        assert!((ln_fast(f64::MIN_POSITIVE) - f64::MIN_POSITIVE.ln()).abs() < 1e-12);
    }

    #[test]
    fn exp_fast_f32_matches_libm() {
        let mut worst: f64 = 0.0;
        for i in 0..400_000 {
            let x = -87.0 + 175.0 * i as f64 / 400_000.0;
            let (a, b) = (exp_fast_f32(x as f32) as f64, (x as f32 as f64).exp());
            worst = worst.max((a / b - 1.0).abs());
        }
        assert!(worst < 2e-7, "{worst}");
        assert_eq!(exp_fast_f32(0.0), 1.0);
        assert!(exp_fast_f32(-1e6) < 2e-38 && exp_fast_f32(-1e6) >= 0.0);
        assert!(exp_fast_f32(1e6).is_finite());
    }

    #[test]
    fn ln_fast_f32_matches_libm() {
        let mut worst: f64 = 0.0;
        // The whole normal range in uneven steps, and around 1 where ln is small.
        for i in 0..200_000 {
            let x = (10f64.powf(-37.9 + 75.8 * i as f64 / 200_000.0)
                * (1.0 + 0.37 * (i % 7) as f64)) as f32;
            let exact = (x as f64).ln();
            let err = (ln_fast_f32(x) as f64 - exact).abs();
            // Half an ulp of the result (its rounding to f32) plus 2e-7.
            worst = worst.max(err / (2e-7 + 0.5 * f32::EPSILON as f64 * exact.abs()));
        }
        for i in 0..20_000 {
            let x = (0.5 + i as f64 / 10_000.0) as f32;
            let err = (ln_fast_f32(x) as f64 - (x as f64).ln()).abs();
            worst = worst.max(err / 2e-7);
        }
        assert!(worst <= 1.0, "{worst}");
        assert_eq!(ln_fast_f32(1.0), 0.0);
        assert!((ln_fast_f32(f32::MIN_POSITIVE) - f32::MIN_POSITIVE.ln()).abs() < 1e-5);
    }

    #[test]
    fn acos_fast_matches_libm() {
        let mut worst: f64 = 0.0;
        for i in 0..=200_000 {
            let x = -1.0 + 2.0 * i as f64 / 200_000.0;
            worst = worst.max((acos_fast(x) - x.acos()).abs());
        }
        assert!(worst < 3e-8, "{worst}");
        assert!((acos_fast(1.5) - 0.0).abs() < 1e-12 && (acos_fast(-1.5) - PI).abs() < 3e-8);
    }

    crate::simd_dispatch! {
        fn sum_exp(v: &[f64]) -> f64 {
            v.iter().map(|&x| exp_fast(x)).sum()
        }
    }

    #[test]
    fn simd_dispatch_gives_the_generic_result() {
        let v: Vec<f64> = (0..37).map(|i| -0.1 * i as f64).collect();
        let e: f64 = v.iter().map(|x| x.exp()).sum();
        assert!((sum_exp(&v) / e - 1.0).abs() < 1e-13);
    }
}
