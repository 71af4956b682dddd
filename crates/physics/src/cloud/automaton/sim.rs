//! The bit-packed cellular automaton (Dobashi et al. 2000, §4.1–4.4 and appendix A): hum / act / cld stored one
//! bit per cell, 64 cells of a row along x per `u64` word, so every rule updates 64 cells at once.

use super::control::{ProbabilityControl, RowLevels, WindProfile, ACT, EXT, HUM};
use super::random::{draw, setup_rng, slice_rng, RandomBitTable};
use super::AutomatonParams;
use crate::Result;
use rand::Rng;
use rayon::prelude::*;

/// Largest simulation space accepted, in cells (the per-cell probability levels take 6 bytes each).
pub const MAX_CELLS: usize = 1 << 25;

/// Bit-packed state: bit `x % 64` of word `(k·ny + j)·words_per_row + x / 64` is cell (x, j, k).
/// Bits beyond `nx` in the last word of a row are always zero.
#[derive(Debug, Clone, PartialEq)]
pub struct CaState {
    /// Vapour / humidity, `hum`.
    pub hum: Vec<u64>,
    /// Phase-transition (activation) factor, `act`.
    pub act: Vec<u64>,
    /// Cloud, `cld`.
    pub cld: Vec<u64>,
}

/// A running simulation: state, controls, the random-bit table and the step counter.
#[derive(Debug, Clone)]
pub struct Automaton {
    dims: [usize; 3],
    words_per_row: usize,
    seed: u64,
    supply_interval: u64,
    table: RandomBitTable,
    control: ProbabilityControl,
    wind: WindProfile,
    /// Per word: cells that may hold anything (inside the space and not solid).
    valid: Vec<u64>,
    state: CaState,
    next: CaState,
    steps_done: u64,
}

impl Automaton {
    /// Validates `params` (sizes before any allocation) and sets the initial state: hum and act
    /// random with the initial probabilities, cld zero (Dobashi et al. 2000, §4.1), all zero inside obstacles.
    /// The initial draws come from `setup_rng(seed, 0)`: per cell in (k, j, x) order, one `f64` for
    /// hum then one for act.
    pub fn new(params: &AutomatonParams) -> Result<Self> {
        let [nx, ny, nz] = params.dims;
        checked_cells(params.dims)?;
        let words_per_row = nx.div_ceil(64);
        let table = RandomBitTable::new(
            params.probability_levels,
            params.random_sequences,
            params.seed,
        )?;
        let wind = WindProfile::new(&params.wind, nz)?;
        let ellipsoids = params.all_ellipsoids()?;
        let control = ProbabilityControl::new(
            params.dims,
            params.probability_levels,
            params.background,
            ellipsoids,
        )?;
        let heights = match &params.obstacle {
            Some(o) => Some(o.column_heights(nx, ny)?),
            None => None,
        };
        let words = words_per_row * ny * nz;
        let mut valid = vec![0u64; words];
        for k in 0..nz {
            for j in 0..ny {
                for x in 0..nx {
                    let solid = heights
                        .as_ref()
                        .is_some_and(|h| (k as f64 + 0.5) < h[j * nx + x]);
                    if !solid {
                        valid[(k * ny + j) * words_per_row + x / 64] |= 1 << (x % 64);
                    }
                }
            }
        }
        let mut state = CaState {
            hum: vec![0; words],
            act: vec![0; words],
            cld: vec![0; words],
        };
        let mut rng = setup_rng(params.seed, 0);
        for k in 0..nz {
            for j in 0..ny {
                for x in 0..nx {
                    let w = (k * ny + j) * words_per_row + x / 64;
                    let bit = 1u64 << (x % 64);
                    if rng.random::<f64>() < params.initial_hum_probability {
                        state.hum[w] |= bit;
                    }
                    if rng.random::<f64>() < params.initial_act_probability {
                        state.act[w] |= bit;
                    }
                }
            }
        }
        for (i, v) in valid.iter().enumerate() {
            state.hum[i] &= v;
            state.act[i] &= v;
        }
        Ok(Self {
            dims: params.dims,
            words_per_row,
            seed: params.seed,
            supply_interval: params.supply_interval_steps,
            table,
            control,
            wind,
            valid,
            next: state.clone(),
            state,
            steps_done: 0,
        })
    }

    /// Cells along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Words per row along x (`ceil(nx / 64)`).
    pub fn words_per_row(&self) -> usize {
        self.words_per_row
    }

    /// Steps taken so far; the next [`Self::step`] is step number `steps_done()`.
    pub fn steps_done(&self) -> u64 {
        self.steps_done
    }

    /// The current state.
    pub fn state(&self) -> &CaState {
        &self.state
    }

    /// The random-bit table.
    pub fn table(&self) -> &RandomBitTable {
        &self.table
    }

    /// The probability control (ellipsoids at their current positions).
    pub fn control(&self) -> &ProbabilityControl {
        &self.control
    }

    /// The integer wind velocity per layer.
    pub fn wind(&self) -> &WindProfile {
        &self.wind
    }

    /// The simulation seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Whether vapour and activation are supplied (eqs 6–7) at step `step`: every
    /// `supply_interval_steps` steps, starting with step 0.
    pub fn supplies_at(&self, step: u64) -> bool {
        step % self.supply_interval == 0
    }

    /// Whether cell (x, y, z) can hold vapour, activation or cloud (inside the space, not terrain).
    pub fn is_open(&self, x: usize, y: usize, z: usize) -> bool {
        let [_, ny, _] = self.dims;
        (self.valid[(z * ny + y) * self.words_per_row + x / 64] >> (x % 64)) & 1 == 1
    }

    /// The word index and bit of cell (x, y, z).
    #[inline]
    pub fn word_bit(&self, x: usize, y: usize, z: usize) -> (usize, u32) {
        let [_, ny, _] = self.dims;
        ((z * ny + y) * self.words_per_row + x / 64, (x % 64) as u32)
    }

    /// Cloud bit of cell (x, y, z).
    pub fn cloud(&self, x: usize, y: usize, z: usize) -> bool {
        let (w, b) = self.word_bit(x, y, z);
        (self.state.cld[w] >> b) & 1 == 1
    }

    /// Fraction of open cells holding cloud.
    pub fn cloud_cover(&self) -> f64 {
        let c: u64 = self.state.cld.iter().map(|w| w.count_ones() as u64).sum();
        let open: u64 = self.valid.iter().map(|w| w.count_ones() as u64).sum();
        if open == 0 {
            0.0
        } else {
            c as f64 / open as f64
        }
    }

    /// One time step t_i → t_{i+1}. For each word, in this order:
    /// 1. growth, eqs 1–4 (A.1–A.3), from the state at t_i;
    /// 2. extinction, eq 5: `cld ∧ ¬p[ext level][seq]` (the table row holds the bits where
    ///    rnd < p_ext, so its complement is IS(rnd > p_ext));
    /// 3. on supply steps, vapour and activation supply, eqs 6–7: `hum ∨ p[..]`, `act ∨ p[..]`;
    /// 4. wind, eqs 8–10: the row shifts by v(z_k) cells along x, zeros entering;
    /// 5. cells in obstacles are cleared.
    ///
    /// The sequence rows come from [`slice_rng`]`(seed, step, k)` (three draws per word, see
    /// there). The probability levels of each row are rebuilt from the ellipsoid stamps into a
    /// small per-thread buffer just before the row is updated; afterwards the ellipsoids drift.
    pub fn step(&mut self) {
        let [_, ny, _] = self.dims;
        let m = self.words_per_row;
        let slice = m * ny;
        let step = self.steps_done;
        let supply = self.supplies_at(step);
        let mut next = std::mem::replace(
            &mut self.next,
            CaState {
                hum: Vec::new(),
                act: Vec::new(),
                cld: Vec::new(),
            },
        );
        let this = &*self;
        next.hum
            .par_chunks_mut(slice)
            .zip(next.act.par_chunks_mut(slice))
            .zip(next.cld.par_chunks_mut(slice))
            .enumerate()
            .for_each(|(k, ((h, a), c))| this.step_slice(k, step, supply, h, a, c));
        std::mem::swap(&mut self.state, &mut next);
        self.next = next;
        self.steps_done += 1;
        self.control.advect(&self.wind);
    }

    fn step_slice(
        &self,
        k: usize,
        step: u64,
        supply: bool,
        out_h: &mut [u64],
        out_a: &mut [u64],
        out_c: &mut [u64],
    ) {
        let [nx, ny, nz] = self.dims;
        let m = self.words_per_row;
        let s = &self.state;
        let pad = last_word_mask(nx);
        let mut rng = slice_rng(self.seed, step, k);
        let mut th = vec![0u64; m];
        let mut ta = vec![0u64; m];
        let mut tc = vec![0u64; m];
        let mut row_levels = RowLevels::new(nx);
        let row_base = |j: isize, kk: isize| -> Option<usize> {
            (j >= 0 && (j as usize) < ny && kk >= 0 && (kk as usize) < nz)
                .then(|| (kk as usize * ny + j as usize) * m)
        };
        let v = self.wind.velocity_cells(k);
        for j in 0..ny {
            let base = (k * ny + j) * m;
            self.control.fill_row_words(j, k, &mut row_levels);
            let (ji, ki) = (j as isize, k as isize);
            let neighbours = [
                row_base(ji + 1, ki),
                row_base(ji - 1, ki),
                row_base(ji + 2, ki),
                row_base(ji - 2, ki),
                row_base(ji, ki + 1),
                row_base(ji, ki - 1),
                row_base(ji, ki - 2),
            ];
            for w in 0..m {
                let a0 = s.act[base + w];
                let h0 = s.hum[base + w];
                let c0 = s.cld[base + w];
                let prev = if w > 0 { s.act[base + w - 1] } else { 0 };
                let next = if w + 1 < m { s.act[base + w + 1] } else { 0 };
                // Eq 4: act at i±1, i±2 (A.3's shifted copies), j±1, j±2, k±1, k−2.
                let mut f = (a0 << 1 | prev >> 63)
                    | (a0 << 2 | prev >> 62)
                    | (a0 >> 1 | next << 63)
                    | (a0 >> 2 | next << 62);
                for nb in neighbours.iter().flatten() {
                    f |= s.act[nb + w];
                }
                let h1 = h0 & !a0; // eq 1
                let c1 = c0 | a0; // eq 2
                let a1 = !a0 & h0 & f; // eq 3
                let seq_ext = self.table.sequence_of(draw(&mut rng));
                let seq_hum = self.table.sequence_of(draw(&mut rng));
                let seq_act = self.table.sequence_of(draw(&mut rng));
                let seqs = [seq_hum, seq_act, seq_ext];
                let bits = self.rule_bits(w, seqs, supply, &row_levels);
                th[w] = h1 | bits[HUM]; // eq 6 (bits zero unless a supply step)
                ta[w] = a1 | bits[ACT]; // eq 7
                tc[w] = c1 & !bits[EXT]; // eq 5
            }
            th[m - 1] &= pad;
            ta[m - 1] &= pad;
            tc[m - 1] &= pad;
            let out = (j * m)..(j * m + m);
            shift_row(&th, &mut out_h[out.clone()], v);
            shift_row(&ta, &mut out_a[out.clone()], v);
            shift_row(&tc, &mut out_c[out.clone()], v);
            for w in 0..m {
                let ok = self.valid[base + w];
                out_h[j * m + w] &= ok;
                out_a[j * m + w] &= ok;
                out_c[j * m + w] &= ok;
            }
        }
    }

    /// Bits where `rnd < p` for the three rules `[hum, act, ext]` in word `w` (eqs A.4–A.6): bit
    /// `x % 64` of table row `(level(x), seq)` for each cell x. Words no ellipsoid touches share
    /// the background levels and need one table load per rule; the others compare the cells'
    /// levels (from `row`) against the sequence's uniforms.
    #[inline]
    fn rule_bits(&self, w: usize, seq: [usize; 3], supply: bool, row: &RowLevels) -> [u64; 3] {
        let mut out = [0u64; 3];
        let rules: &[usize] = if supply { &[HUM, ACT, EXT] } else { &[EXT] };
        if row.touched[w] {
            for &rule in rules {
                let cells: &[u16; 64] = row.levels[rule][w * 64..w * 64 + 64]
                    .try_into()
                    .expect("64 levels per word");
                out[rule] = self.table.bits_below(seq[rule], cells);
            }
        } else {
            let bg = self.control.background_levels();
            for &rule in rules {
                if bg[rule] != 0 {
                    out[rule] = self.table.word(bg[rule], seq[rule]);
                }
            }
        }
        out
    }
}

/// Cell count of `dims`, refusing empty or oversized spaces before allocating.
pub fn checked_cells(dims: [usize; 3]) -> Result<usize> {
    crate::cloud::grid::checked_count(dims, MAX_CELLS, "cells")
}

/// Mask of the valid bits in the last word of a row of `nx` cells.
#[inline]
fn last_word_mask(nx: usize) -> u64 {
    match nx % 64 {
        0 => u64::MAX,
        r => (1u64 << r) - 1,
    }
}

/// dst(x) = src(x − v), zero where x − v falls outside the row (eqs 8–10, either direction).
fn shift_row(src: &[u64], dst: &mut [u64], v: i32) {
    let m = src.len();
    let u = v.unsigned_abs() as usize;
    let (q, r) = (u / 64, (u % 64) as u32);
    for (w, d) in dst.iter_mut().enumerate() {
        *d = if v >= 0 {
            let main = if w >= q { src[w - q] << r } else { 0 };
            let carry = if r > 0 && w > q {
                src[w - q - 1] >> (64 - r)
            } else {
                0
            };
            main | carry
        } else {
            let main = if w + q < m { src[w + q] >> r } else { 0 };
            let carry = if r > 0 && w + q + 1 < m {
                src[w + q + 1] << (64 - r)
            } else {
                0
            };
            main | carry
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shift_row_moves_bits_across_words_both_ways() {
        let src = [1u64 << 63, 1, 0];
        let mut dst = [0u64; 3];
        shift_row(&src, &mut dst, 2);
        assert_eq!(dst, [0, 1 << 1 | 1 << 2, 0]);
        shift_row(&src, &mut dst, -64);
        assert_eq!(dst, [1, 0, 0]);
        shift_row(&src, &mut dst, 200);
        assert_eq!(dst, [0, 0, 0]);
        shift_row(&src, &mut dst, -1);
        assert_eq!(dst, [1 << 62 | 1 << 63, 0, 0]);
    }

    #[test]
    fn masks() {
        assert_eq!(last_word_mask(64), u64::MAX);
        assert_eq!(last_word_mask(65), 1);
    }
}
