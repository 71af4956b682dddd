//! The field's coefficients laid out for the reconstruction towards a camera.
//!
//! [`MsField::inscatter`] reconstructs J* = Σ_l p*_l Σ_m L_lm Y_lm(ω_o) at every voxel a camera
//! sees, over the 8 coarse cells round it, per wavelength: 8 × λ chains of (L + 1)² terms
//! (p*_l·L_lm)·Y_lm, the coefficients read from [`MsField::data`] (`[cell][λ][(L + 1)²]`),
//! one wavelength's coefficient after another's. [`ConvolvedCells`] holds the same `f32`
//! coefficients with the wavelengths side by side (`[cell][(L + 1)²][4]`, three or four
//! wavelengths), so that [`MsField::inscatter_convolved`] runs the four wavelengths' chains as
//! one vector of four `f64` per cell (each lane the same operations in the same order as the
//! scalar chain: the same values), compiled a second time for AVX2 (`simd_dispatch!`, no fused
//! multiply-adds). Kept in the lit volume: built by its first camera, read by the next.

use super::{MsField, MAX_ORDER};
use glam::DVec3;
use rayon::prelude::*;

/// Wavelengths side by side in [`ConvolvedCells`].
const LANES: usize = 4;

/// [`MsField::data`] as `[cell][(L + 1)²][4]` (the fourth lane 0 for three wavelengths), see
/// the module text; empty for other wavelength counts.
pub struct ConvolvedCells {
    values: Vec<f32>,
}

impl ConvolvedCells {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * self.values.len()
    }
}

impl MsField {
    /// The field's coefficients with the wavelengths side by side (cells in parallel).
    pub fn convolved_cells(&self) -> ConvolvedCells {
        let (n, n_l) = (self.moments, self.n_l);
        if !matches!(n_l, 3 | 4) {
            return ConvolvedCells { values: Vec::new() };
        }
        let mut values = vec![0.0f32; self.data.len() / n_l * LANES];
        values
            .par_chunks_mut(n * LANES)
            .zip(self.data.par_chunks(n_l * n))
            .for_each(|(out, cell)| {
                for l in 0..n_l {
                    for m in 0..n {
                        out[m * LANES + l] = cell[l * n + m];
                    }
                }
            });
        ConvolvedCells { values }
    }

    /// Bytes [`Self::convolved_cells`] takes.
    pub fn convolved_bytes(&self) -> usize {
        if matches!(self.n_l, 3 | 4) {
            4 * self.data.len() / self.n_l * LANES
        } else {
            0
        }
    }

    /// [`Self::inscatter`] with the coefficients read from `cells` (this field's
    /// [`Self::convolved_cells`]): the same values.
    pub fn inscatter_convolved(&self, cells: &ConvolvedCells, p: DVec3, d: DVec3, out: &mut [f64]) {
        self.inscatter_convolved_weighted(cells, p, &self.cell_weights(p), d, out);
    }

    /// [`Self::inscatter_convolved`] with the cells' weights round `p` given (`weights`, this
    /// field's [`Self::cell_weights`] at `p`, which a caller that reads other tallies at `p`
    /// computes once): the same values.
    pub fn inscatter_convolved_weighted(
        &self,
        cells: &ConvolvedCells,
        p: DVec3,
        weights: &[(usize, f64); 8],
        d: DVec3,
        out: &mut [f64],
    ) {
        let n_l = self.n_l;
        if !matches!(n_l, 3 | 4) || cells.values.len() != self.data.len() / n_l * LANES {
            return self.inscatter(p, d, out);
        }
        out.iter_mut().for_each(|o| *o = 0.0);
        let mut ylm = [0.0; (MAX_ORDER + 1) * (MAX_ORDER + 1)];
        super::real_sh(-d, self.angular_order, &mut ylm);
        // p*_l per order, the wavelengths side by side (the padding lane's 0).
        let mut pm = [[0.0f64; LANES]; MAX_ORDER + 1];
        for (order, row) in pm.iter_mut().enumerate().take(self.angular_order + 1) {
            for l in 0..n_l {
                row[l] = self.phase_moments[l][order];
            }
        }
        let sums = cell_sums(&cells.values, weights, &ylm, &pm, self.angular_order);
        for ((_, w), sum) in weights.iter().zip(&sums) {
            if *w == 0.0 {
                continue;
            }
            for l in 0..n_l {
                out[l] += w * sum[l];
            }
        }
        for o in out.iter_mut() {
            *o = o.max(0.0);
        }
    }
}

skybake_physics::simd_dispatch! {
    /// Per cell of `weights` (all 8, as [`MsField::inscatter`]), the 4 lanes' sums
    /// Σ_l Σ_m (p*_l·L_lm)·Y_lm in the order of the coefficients, up to the angular order
    /// `order_max`; `pm[order]` holds the lanes' p*_l.
    fn cell_sums(
        values: &[f32],
        weights: &[(usize, f64); 8],
        ylm: &[f64],
        pm: &[[f64; LANES]; MAX_ORDER + 1],
        order_max: usize,
    ) -> [[f64; LANES]; 8] {
        let n = (order_max + 1) * (order_max + 1);
        let rows: [&[f32]; 8] = std::array::from_fn(|k| {
            let c = weights[k].0;
            &values[c * n * LANES..(c + 1) * n * LANES]
        });
        let mut sums = [[0.0f64; LANES]; 8];
        for (order, p) in pm.iter().enumerate().take(order_max + 1) {
            for m in order * order..(order + 1) * (order + 1) {
                let y = ylm[m];
                for (sum, row) in sums.iter_mut().zip(&rows) {
                    let c = &row[m * LANES..(m + 1) * LANES];
                    for l in 0..LANES {
                        sum[l] += p[l] * c[l] as f64 * y;
                    }
                }
            }
        }
        sums
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The reconstruction from the side-by-side coefficients gives the values of
    /// [`MsField::inscatter`] bit for bit: at points between cells with and without cloud
    /// (weights 0 left out), at the grid's edges, towards any direction, for 3 and 4
    /// wavelengths of different phase moments.
    #[test]
    fn the_side_by_side_reconstruction_is_the_field_s() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for n_l in [3, 4] {
            let order = 3;
            let n = (order + 1) * (order + 1);
            let cells = 27;
            let field = MsField {
                dims: [3, 3, 3],
                cell_m: DVec3::new(10.0, 12.0, 9.0),
                origin_m: DVec3::new(-5.0, 2.0, 100.0),
                n_l,
                data: (0..cells * n_l * n)
                    .map(|_| rng.random_range(-1.0f32..3.0))
                    .collect(),
                phase_moments: (0..n_l)
                    .map(|l| {
                        (0..=order)
                            .map(|o| 0.8f64.powi(o as i32) / (1.0 + l as f64))
                            .collect()
                    })
                    .collect(),
                extinction_scale: vec![1.0; n_l],
                albedo_scaled: vec![1.0; n_l],
                rho: (0..cells)
                    .map(|c| if c % 3 == 1 { 0.0 } else { 1.0 + c as f32 })
                    .collect(),
                skin: None,
                angular_order: order,
                once: None,
                moments: n,
            };
            let kept = field.convolved_cells();
            assert_eq!(kept.bytes(), field.convolved_bytes());
            let (mut a, mut b) = (vec![0.0; n_l], vec![0.0; n_l]);
            let (mut positive, mut clamped) = (0, 0);
            for _ in 0..2000 {
                let p = field.origin_m
                    + DVec3::new(
                        rng.random_range(-3.0..33.0),
                        rng.random_range(-3.0..39.0),
                        rng.random_range(-3.0..30.0),
                    );
                let d = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize_or(DVec3::Z);
                field.inscatter(p, d, &mut a);
                field.inscatter_convolved(&kept, p, d, &mut b);
                for l in 0..n_l {
                    assert_eq!(a[l].to_bits(), b[l].to_bits(), "{p} {d} λ{l}: {a:?} {b:?}");
                    if a[l] > 0.0 {
                        positive += 1;
                    } else {
                        clamped += 1;
                    }
                }
            }
            // Both signs of the sums were seen (the clamp at 0 is exercised too).
            assert!(positive > 100 && clamped > 10, "{positive} {clamped}");
        }
    }
}
