//! The field's phase-convolved coefficients p*_l·L_lm kept per coarse cell.
//!
//! [`MsField::inscatter`] reconstructs J* = Σ_l p*_l Σ_m L_lm Y_lm(ω_o) at every voxel a camera
//! sees, over the 8 coarse cells round it: each term converts the cell's `f32` coefficient and
//! multiplies it by p*_l before Y_lm. The products p*_l·L_lm do not depend on the view, so a lit
//! volume seen by several cameras (or by one, over its many voxels per cell) can keep them:
//! [`ConvolvedCells`] holds them in `f64`, each the very product the reconstruction forms
//! (p*_l × L_lm rounded once), so [`MsField::inscatter_convolved`] adds the same terms in the
//! same order and returns the same values, with one multiplication and one conversion fewer per
//! term.

use super::MsField;
use glam::DVec3;
use rayon::prelude::*;

/// A coarse cell's coefficient as [`MsField::inscatter_n`] reads it: the product p*_l·L_lm.
pub(super) trait CellTerm: Copy + Sync {
    /// p*_l·L_lm, from L_lm (`p_l` = p*_l) or kept as the product.
    fn convolved(self, p_l: f64) -> f64;
}

impl CellTerm for f32 {
    #[inline(always)]
    fn convolved(self, p_l: f64) -> f64 {
        p_l * self as f64
    }
}

impl CellTerm for f64 {
    #[inline(always)]
    fn convolved(self, _p_l: f64) -> f64 {
        self
    }
}

/// p*_l·L_lm per coarse cell, wavelength and coefficient, `[cell][λ][(L + 1)²]` as
/// [`MsField::data`] (see the module text).
pub struct ConvolvedCells {
    values: Vec<f64>,
}

impl ConvolvedCells {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        8 * self.values.len()
    }
}

impl MsField {
    /// The products p*_l·L_lm of every coarse cell (cells in parallel).
    pub fn convolved_cells(&self) -> ConvolvedCells {
        let n = self.moments;
        let mut values = vec![0.0; self.data.len()];
        values
            .par_chunks_mut(self.n_l * n)
            .zip(self.data.par_chunks(self.n_l * n))
            .for_each(|(out, cell)| {
                for l in 0..self.n_l {
                    for order in 0..=self.angular_order {
                        let p_l = self.phase_moments[l][order];
                        for m in order * order..(order + 1) * (order + 1) {
                            out[l * n + m] = cell[l * n + m].convolved(p_l);
                        }
                    }
                }
            });
        ConvolvedCells { values }
    }

    /// [`Self::inscatter`] from the products kept in `cells` (from [`Self::convolved_cells`]
    /// of this field): the same values.
    pub fn inscatter_convolved(&self, cells: &ConvolvedCells, p: DVec3, d: DVec3, out: &mut [f64]) {
        let kept = (cells.values.len() == self.data.len()).then_some(&cells.values[..]);
        debug_assert!(kept.is_some(), "products of another field");
        self.inscatter_from(kept, p, d, out)
    }
}
