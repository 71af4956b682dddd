//! From binary cloud to continuous density (Dobashi et al. 2000, §5.1): space-time smoothing of cld (eq 11),
//! then a sum of metaballs with Wyvill's field function (eq 12, appendix B eq B.1).

use crate::cloud::wyvill;
use crate::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Largest smoothing half-width accepted, in cells or steps.
pub const MAX_SMOOTHING: usize = 16;
/// Largest metaball radius accepted, in cells.
pub const MAX_METABALL_RADIUS_CELLS: f64 = 8.0;

/// Half-widths i0, j0, k0 (cells) and t0 (steps) of the smoothing window of eq 11.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Smoothing {
    /// Half-width along x, cells.
    pub i0: usize,
    /// Half-width along y, cells.
    pub j0: usize,
    /// Half-width along z, cells.
    pub k0: usize,
    /// Half-width in time, steps.
    pub t0: usize,
}

impl Default for Smoothing {
    fn default() -> Self {
        Self {
            i0: 1,
            j0: 1,
            k0: 1,
            t0: 1,
        }
    }
}

impl Smoothing {
    /// Checks every half-width is at most [`MAX_SMOOTHING`].
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("smoothing.i0", self.i0),
            ("smoothing.j0", self.j0),
            ("smoothing.k0", self.k0),
            ("smoothing.t0", self.t0),
        ] {
            if v > MAX_SMOOTHING {
                return Err(Error::out_of_range(name, v, format!("0..={MAX_SMOOTHING}")));
            }
        }
        Ok(())
    }
}

/// Smoothed cloud fraction q (Dobashi et al. 2000, eq 11) at one step, with w ≡ 1, so q is the mean of cld
/// over the (2i0+1)(2j0+1)(2k0+1) cells and (2t0+1) steps around the cell; cells outside the
/// space count as 0 (the paper's boundary condition). `frames[t]` are the packed cld words of the
/// 2t0+1 steps (the caller clamps steps before 0 to step 0). Result index `(k·ny + j)·nx + x`.
pub fn smoothed_fraction(
    frames: &[&[u64]],
    dims: [usize; 3],
    words_per_row: usize,
    s: &Smoothing,
) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    let mut acc = vec![0f32; nx * ny * nz];
    for f in frames {
        acc.par_chunks_mut(nx).enumerate().for_each(|(row, out)| {
            let words = &f[row * words_per_row..(row + 1) * words_per_row];
            for (x, o) in out.iter_mut().enumerate() {
                *o += ((words[x / 64] >> (x % 64)) & 1) as f32;
            }
        });
    }
    box_sum_x(&mut acc, nx, s.i0);
    box_sum_strided(&mut acc, [nx, ny, nz], 1, s.j0);
    box_sum_strided(&mut acc, [nx, ny, nz], 2, s.k0);
    let norm = ((2 * s.t0 + 1) * (2 * s.i0 + 1) * (2 * s.j0 + 1) * (2 * s.k0 + 1)) as f32;
    acc.par_iter_mut().for_each(|v| *v /= norm);
    acc
}

/// Sliding box sum of half-width `h` along x, zero outside.
fn box_sum_x(data: &mut [f32], nx: usize, h: usize) {
    if h == 0 {
        return;
    }
    data.par_chunks_mut(nx).for_each(|row| {
        let src = row.to_vec();
        for (x, o) in row.iter_mut().enumerate() {
            let lo = x.saturating_sub(h);
            let hi = (x + h + 1).min(nx);
            *o = src[lo..hi].iter().sum();
        }
    });
}

/// Box sum of half-width `h` along y (`axis` 1) or z (`axis` 2), zero outside.
fn box_sum_strided(data: &mut [f32], dims: [usize; 3], axis: usize, h: usize) {
    if h == 0 {
        return;
    }
    let [nx, ny, nz] = dims;
    let src = data.to_vec();
    let (n, stride) = if axis == 1 { (ny, nx) } else { (nz, nx * ny) };
    data.par_chunks_mut(nx).enumerate().for_each(|(row, out)| {
        let (j, k) = (row % ny, row / ny);
        let i = if axis == 1 { j } else { k };
        let lo = i.saturating_sub(h);
        let hi = (i + h + 1).min(n);
        for (x, o) in out.iter_mut().enumerate() {
            let base = row * nx + x - i * stride;
            *o = (lo..hi).map(|t| src[base + t * stride]).sum();
        }
    });
}

/// Metaball kernel of eq 12 on the cell lattice: integer offsets within `radius_cells` with weights
/// h(|d|)/c, where c is the sum of h over the lattice offsets, so that q ≡ 1 gives density 1 away
/// from the boundary. (Eq B.2 normalises by the continuous integral; its printed value 748π R/405
/// matches neither ∫h dr nor ∫h dV = 736π R³/2835. The lattice sum is the discrete version of
/// "normalise by its total density".)
#[derive(Debug, Clone, PartialEq)]
pub struct MetaballKernel {
    radius_cells: f64,
    normaliser: f64,
    offsets: Vec<([isize; 3], f32)>,
}

impl MetaballKernel {
    /// Kernel for an effective radius in cells (0 < R ≤ [`MAX_METABALL_RADIUS_CELLS`]).
    pub fn new(radius_cells: f64) -> Result<Self> {
        if !(radius_cells > 0.0 && radius_cells <= MAX_METABALL_RADIUS_CELLS) {
            return Err(Error::out_of_range(
                "metaball_radius_cells",
                radius_cells,
                format!("0 < R <= {MAX_METABALL_RADIUS_CELLS}"),
            ));
        }
        let n = radius_cells.floor() as isize;
        let mut raw = Vec::new();
        for dk in -n..=n {
            for dj in -n..=n {
                for di in -n..=n {
                    let r = ((di * di + dj * dj + dk * dk) as f64).sqrt();
                    let h = wyvill::h(r, radius_cells);
                    if h > 0.0 {
                        raw.push(([di, dj, dk], h));
                    }
                }
            }
        }
        let normaliser: f64 = raw.iter().map(|(_, h)| h).sum();
        let offsets = raw
            .into_iter()
            .map(|(d, h)| (d, (h / normaliser) as f32))
            .collect();
        Ok(Self {
            radius_cells,
            normaliser,
            offsets,
        })
    }

    /// Density ρ at every cell centre (eq 12), index `(k·ny + j)·nx + x`.
    pub fn density(&self, q: &[f32], dims: [usize; 3]) -> Vec<f32> {
        let [nx, ny, nz] = dims;
        let mut out = vec![0f32; nx * ny * nz];
        out.par_chunks_mut(nx).enumerate().for_each(|(row, o)| {
            let (j, k) = ((row % ny) as isize, (row / ny) as isize);
            for &([di, dj, dk], w) in &self.offsets {
                let (jj, kk) = (j + dj, k + dk);
                if jj < 0 || jj >= ny as isize || kk < 0 || kk >= nz as isize {
                    continue;
                }
                let src = &q[(kk as usize * ny + jj as usize) * nx..][..nx];
                let lo = (-di).max(0) as usize;
                let hi = (nx as isize - di.max(0)) as usize;
                for x in lo..hi.max(lo) {
                    o[x] += w * src[(x as isize + di) as usize];
                }
            }
        });
        out
    }

    /// Density ρ at an arbitrary point in cell units (cell (i, j, k) centred at (i+½, j+½, k+½)):
    /// eq 12 summed over the cells whose centres lie within R, with the same normalisation.
    pub fn density_at(&self, q: &[f32], dims: [usize; 3], p_cells: DVec3) -> f64 {
        let [nx, ny, nz] = dims;
        let r = self.radius_cells;
        let lo = (p_cells - 0.5 - r).floor().max(DVec3::ZERO);
        let hi = (p_cells - 0.5 + r).ceil();
        let mut sum = 0.0;
        for k in lo.z as usize..=(hi.z.max(0.0) as usize).min(nz - 1) {
            for j in lo.y as usize..=(hi.y.max(0.0) as usize).min(ny - 1) {
                for i in lo.x as usize..=(hi.x.max(0.0) as usize).min(nx - 1) {
                    let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                    let h = wyvill::h(c.distance(p_cells), r);
                    sum += h * q[(k * ny + j) * nx + i] as f64;
                }
            }
        }
        sum / self.normaliser
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernel weights are eq B.1 at the lattice offsets, normalised to sum to 1.
    #[test]
    fn kernel_weights_are_wyvill_field_at_lattice_offsets() {
        let kernel = MetaballKernel::new(2.0).unwrap();
        let sum: f64 = kernel.offsets.iter().map(|(_, w)| *w as f64).sum();
        assert!((sum - 1.0).abs() < 1e-6);
        // Half radius: a² = 1/4 → −4/9/64 + 17/9/16 − 22/9/4 + 1, relative to the centre's 1.
        let expect = -4.0 / 9.0 / 64.0 + 17.0 / 9.0 / 16.0 - 22.0 / 9.0 / 4.0 + 1.0;
        let weight = |d: [isize; 3]| kernel.offsets.iter().find(|(o, _)| *o == d).unwrap().1;
        let ratio = weight([1, 0, 0]) as f64 / weight([0, 0, 0]) as f64;
        assert!((ratio - expect).abs() < 1e-6);
        // Offsets at or beyond R carry no weight: (2, 0, 0) lies on the rim.
        assert!(kernel.offsets.iter().all(|(o, _)| *o != [2, 0, 0]));
    }

    #[test]
    fn full_cloud_gives_unit_fraction_and_density_inside() {
        let dims = [70, 6, 6];
        let words = [u64::MAX, (1u64 << 6) - 1].repeat(36);
        let s = Smoothing::default();
        let frames = [words.as_slice(); 3];
        let q = smoothed_fraction(&frames, dims, 2, &s);
        let idx = |x: usize, y: usize, z: usize| (z * 6 + y) * 70 + x;
        assert!((q[idx(30, 3, 3)] - 1.0).abs() < 1e-6);
        // A corner sees 2·2·2 of the 27 cells.
        assert!((q[idx(0, 0, 0)] - 8.0 / 27.0).abs() < 1e-6);
        let kernel = MetaballKernel::new(2.0).unwrap();
        let rho = kernel.density(&q, dims);
        assert!((rho[idx(30, 3, 3)] - 1.0).abs() < 1e-5);
        let at = kernel.density_at(&q, dims, DVec3::new(30.5, 3.5, 3.5));
        assert!((at - rho[idx(30, 3, 3)] as f64).abs() < 1e-5);
    }

    #[test]
    fn smoothing_matches_direct_window_mean() {
        let dims = [9, 5, 4];
        let mut bits = vec![0u64; 5 * 4];
        let on = |x: usize, y: usize, z: usize| (x * 7 + y * 3 + z * 5) % 4 == 0;
        for z in 0..4 {
            for y in 0..5 {
                for x in 0..9 {
                    if on(x, y, z) {
                        bits[z * 5 + y] |= 1 << x;
                    }
                }
            }
        }
        let s = Smoothing {
            i0: 2,
            j0: 1,
            k0: 1,
            t0: 0,
        };
        let q = smoothed_fraction(&[bits.as_slice()], dims, 1, &s);
        for z in 0..4i32 {
            for y in 0..5i32 {
                for x in 0..9i32 {
                    let mut n = 0;
                    for dz in -1..=1 {
                        for dy in -1..=1 {
                            for dx in -2..=2 {
                                let (a, b, c) = (x + dx, y + dy, z + dz);
                                if (0..9).contains(&a)
                                    && (0..5).contains(&b)
                                    && (0..4).contains(&c)
                                    && on(a as usize, b as usize, c as usize)
                                {
                                    n += 1;
                                }
                            }
                        }
                    }
                    let got = q[((z * 5 + y) * 9 + x) as usize];
                    assert!((got - n as f32 / 45.0).abs() < 1e-6);
                }
            }
        }
    }
}
