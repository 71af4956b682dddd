//! The random-bit look-up table of Dobashi et al. 2000, appendix A (eqs A.4–A.6) and the per-slice random
//! streams that index it.
//!
//! Row `(level, sequence)` of the table is a 64-bit word whose bits are set independently with
//! probability `level / levels` (`p[i][j]` in the paper, `i = 0..=n_p`, `j = 1..=n_i`). A rule with
//! probability `p` at a cell takes bit `x mod 64` of row `(int(p·n_p), int(rnd·n_i))`, where one
//! `rnd` is drawn per 64-cell word and rule. This turns 64 Bernoulli draws into one table load.
//!
//! The rows of one sequence are nested: each sequence holds 64 uniform integers `u_b` in
//! `0..n_p` and bit `b` of row `(i, j)` is `u_b < i`, which is 1 with probability exactly `i/n_p`.
//! A word whose 64 cells have different levels then needs only 64 small-integer comparisons
//! against one sequence instead of 64 loads from different rows.

use crate::{Error, Result};
use rand::{Rng, RngCore, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Largest accepted number of probability levels `n_p`.
pub const MAX_PROBABILITY_LEVELS: usize = 65_534;
/// Largest accepted table size, in 64-bit words (32 MiB).
pub const MAX_TABLE_WORDS: usize = 1 << 22;

/// Look-up table of random bit sequences, `p[level][sequence]` (Dobashi et al. 2000, app. A).
#[derive(Debug, Clone, PartialEq)]
pub struct RandomBitTable {
    levels: usize,
    sequences: usize,
    /// `sequences × 64` uniform integers in `0..levels`.
    uniforms: Vec<u16>,
    words: Vec<u64>,
}

impl RandomBitTable {
    /// Builds the table for `levels` probability steps (`n_p`) and `sequences` rows per level
    /// (`n_i`). Bit `b` of row `(i, j)` is `u[j][b] < i` with `u` uniform in `0..levels`, so it is 1
    /// with probability exactly `i / levels`; level 0 rows are all zeros, level `levels` all ones.
    pub fn new(levels: usize, sequences: usize, seed: u64) -> Result<Self> {
        if !(1..=MAX_PROBABILITY_LEVELS).contains(&levels) {
            return Err(Error::out_of_range(
                "probability_levels",
                levels,
                format!("1..={MAX_PROBABILITY_LEVELS}"),
            ));
        }
        if sequences == 0 {
            return Err(Error::out_of_range("random_sequences", sequences, ">= 1"));
        }
        let count = (levels + 1)
            .checked_mul(sequences)
            .filter(|&c| c <= MAX_TABLE_WORDS)
            .ok_or_else(|| {
                Error::too_large(
                    "random_sequences",
                    format!("(probability_levels + 1) x random_sequences = {levels}+1 x {sequences} words"),
                    format!("{MAX_TABLE_WORDS} words"),
                )
            })?;
        let mut rng = Pcg64Mcg::seed_from_u64(mix(seed, TABLE_TAG, 0));
        let uniforms: Vec<u16> = (0..sequences * 64)
            .map(|_| rng.random_range(0..levels) as u16)
            .collect();
        let mut words = Vec::with_capacity(count);
        for level in 0..=levels {
            for j in 0..sequences {
                let u = &uniforms[j * 64..(j + 1) * 64];
                words.push(below(u, |_| level as u16));
            }
        }
        Ok(Self {
            levels,
            sequences,
            uniforms,
            words,
        })
    }

    /// Number of probability levels `n_p`.
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Number of sequences per level `n_i`.
    pub fn sequences(&self) -> usize {
        self.sequences
    }

    /// Quantised level of a probability: `int(p · n_p)` (eqs A.4–A.6), clamped to `0..=n_p`.
    #[inline]
    pub fn level_of(&self, probability: f64) -> u16 {
        quantise(probability, self.levels)
    }

    /// The sequence row chosen by one uniform 32-bit draw: `int(rnd · n_i)` with `rnd = draw / 2³²`.
    #[inline]
    pub fn sequence_of(&self, draw: u32) -> usize {
        ((draw as u64 * self.sequences as u64) >> 32) as usize
    }

    /// Row `(level, sequence)` of the table.
    #[inline]
    pub fn word(&self, level: u16, sequence: usize) -> u64 {
        self.words[level as usize * self.sequences + sequence]
    }

    /// Bits `b` where cell `b` of a word draws below its own level: bit `b` of row
    /// `(levels[b], sequence)` for every `b`, as one comparison pass over the sequence.
    #[inline]
    pub fn bits_below(&self, sequence: usize, levels: &[u16; 64]) -> u64 {
        let u: &[u16; 64] = self.uniforms[sequence * 64..(sequence + 1) * 64]
            .try_into()
            .expect("64 uniforms per sequence");
        below_64(u, levels)
    }

    /// Bit `bit` (0..64) of row `(level, sequence)`.
    #[inline]
    pub fn bit(&self, level: u16, sequence: usize, bit: usize) -> bool {
        (self.word(level, sequence) >> bit) & 1 == 1
    }
}

/// Mask of the bits `b` with `u[b] < level(b)`.
#[inline]
fn below(u: &[u16], level: impl Fn(usize) -> u16) -> u64 {
    let mut bits = 0u64;
    for (b, &ub) in u.iter().enumerate().take(64) {
        bits |= ((ub < level(b)) as u64) << b;
    }
    bits
}

/// Mask of the bits `b` with `u[b] < level[b]`, 16 lanes at a time with SSE2 (x86_64 baseline).
#[cfg(target_arch = "x86_64")]
#[inline]
fn below_64(u: &[u16; 64], level: &[u16; 64]) -> u64 {
    // SAFETY: SSE2 is part of the x86_64 baseline, so the feature is always present.
    unsafe { below_64_sse2(u, level) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
fn below_64_sse2(u: &[u16; 64], level: &[u16; 64]) -> u64 {
    use std::arch::x86_64::{
        __m128i, _mm_cmplt_epi16, _mm_loadu_si128, _mm_movemask_epi8, _mm_packs_epi16,
        _mm_set1_epi16, _mm_xor_si128,
    };
    // Flipping the sign bit turns the signed 16-bit compare into an unsigned one.
    let flip = _mm_set1_epi16(i16::MIN);
    let mut bits = 0u64;
    for q in 0..4 {
        let at = q * 16;
        // SAFETY: `at + 16 <= 64`, so each unaligned 16-byte load reads 8 lanes inside the arrays.
        let (u0, u1, l0, l1) = unsafe {
            (
                _mm_loadu_si128(u.as_ptr().add(at) as *const __m128i),
                _mm_loadu_si128(u.as_ptr().add(at + 8) as *const __m128i),
                _mm_loadu_si128(level.as_ptr().add(at) as *const __m128i),
                _mm_loadu_si128(level.as_ptr().add(at + 8) as *const __m128i),
            )
        };
        let lt0 = _mm_cmplt_epi16(_mm_xor_si128(u0, flip), _mm_xor_si128(l0, flip));
        let lt1 = _mm_cmplt_epi16(_mm_xor_si128(u1, flip), _mm_xor_si128(l1, flip));
        let mask = _mm_movemask_epi8(_mm_packs_epi16(lt0, lt1)) as u32 as u64;
        bits |= mask << at;
    }
    bits
}

/// Mask of the bits `b` with `u[b] < level[b]`.
#[cfg(not(target_arch = "x86_64"))]
#[inline]
fn below_64(u: &[u16; 64], level: &[u16; 64]) -> u64 {
    below(u, |b| level[b])
}

/// `int(p · n_p)` clamped to `0..=n_p` (NaN maps to 0).
#[inline]
pub fn quantise(probability: f64, levels: usize) -> u16 {
    let l = (probability * levels as f64).floor();
    if l >= levels as f64 {
        levels as u16
    } else if l >= 0.0 {
        l as u16
    } else {
        0
    }
}

/// The random stream of slice `k` at step `step`: each step draws, for every row `j` (ascending)
/// and every word along x (ascending), three `u32` values in the order extinction, vapour,
/// activation (eqs 5, 6, 7). One stream per slice keeps the run independent of thread count.
pub fn slice_rng(seed: u64, step: u64, k: usize) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(mix(seed, step.wrapping_add(STEP_TAG), k as u64))
}

/// The stream used for the initial state and for randomly placed ellipsoids (`purpose` 0 and 1).
pub fn setup_rng(seed: u64, purpose: u64) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(mix(seed, INIT_TAG, purpose))
}

/// Draws the next `u32` (a thin wrapper so callers need not import `RngCore`).
#[inline]
pub fn draw(rng: &mut Pcg64Mcg) -> u32 {
    rng.next_u32()
}

const TABLE_TAG: u64 = 0x7461_626c_6500_0001;
const INIT_TAG: u64 = 0x696e_6974_0000_0002;
const STEP_TAG: u64 = 0x7374_6570_0000_0003;

/// SplitMix64-style mixing of three words into one seed.
fn mix(a: u64, b: u64, c: u64) -> u64 {
    let mut z = a ^ b.rotate_left(21) ^ c.rotate_left(42) ^ 0x9e37_79b9_7f4a_7c15;
    for _ in 0..2 {
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
    }
    z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extreme_levels_are_all_zero_and_all_one() {
        let t = RandomBitTable::new(10, 4, 1).unwrap();
        for j in 0..4 {
            assert_eq!(t.word(0, j), 0);
            assert_eq!(t.word(10, j), u64::MAX);
        }
    }

    #[test]
    fn bit_frequency_matches_level_probability() {
        // 64 * 256 bits per level: the binomial standard deviation of the mean is < 0.4 %.
        let t = RandomBitTable::new(8, 256, 7).unwrap();
        for level in 1..8u16 {
            let ones: u32 = (0..256).map(|j| t.word(level, j).count_ones()).sum();
            let p = ones as f64 / (256.0 * 64.0);
            assert!((p - level as f64 / 8.0).abs() < 0.02, "level {level}: {p}");
        }
    }

    #[test]
    fn mixed_word_bits_are_the_rows_of_each_cells_level() {
        let t = RandomBitTable::new(100, 8, 3).unwrap();
        let mut levels: [u16; 64] = std::array::from_fn(|b| (b as u16 * 7) % 101);
        levels[5] = 0;
        levels[63] = 100;
        for j in 0..8 {
            let bits = t.bits_below(j, &levels);
            for (b, &l) in levels.iter().enumerate() {
                assert_eq!((bits >> b) & 1 == 1, t.bit(l, j, b));
            }
        }
        // Levels above 32767 exercise the unsigned comparison.
        let t = RandomBitTable::new(60_000, 4, 5).unwrap();
        let levels: [u16; 64] = std::array::from_fn(|b| (b as u16) * 937);
        for j in 0..4 {
            let bits = t.bits_below(j, &levels);
            for (b, &l) in levels.iter().enumerate() {
                assert_eq!((bits >> b) & 1 == 1, t.bit(l, j, b), "level {l}");
            }
        }
    }

    #[test]
    fn quantise_follows_integer_part() {
        assert_eq!(quantise(0.001, 1000), 1);
        assert_eq!(quantise(0.0999, 10), 0);
        assert_eq!(quantise(1.5, 10), 10);
        assert_eq!(quantise(-0.2, 10), 0);
        assert_eq!(quantise(f64::NAN, 10), 0);
        let t = RandomBitTable::new(4, 8, 0).unwrap();
        assert_eq!(t.sequence_of(0), 0);
        assert_eq!(t.sequence_of(u32::MAX), 7);
    }

    #[test]
    fn oversized_table_is_refused() {
        let e = RandomBitTable::new(60_000, 1000, 0).unwrap_err();
        assert_eq!(e.field(), "random_sequences");
        assert_eq!(
            RandomBitTable::new(0, 4, 0).unwrap_err().field(),
            "probability_levels"
        );
    }
}
