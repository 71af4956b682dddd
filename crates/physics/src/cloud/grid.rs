//! Cell-centred voxel density grids.
//!
//! Values sit at voxel centres; `origin_m` is the minimum corner of the box, so voxel (i, j, k) is
//! centred at `origin + (i+½, j+½, k+½)·voxel_size`. Sampling is trilinear between centres, clamped
//! to the outermost centre out to the box face, and zero outside the box (OpenVDB cell-centred
//! voxels, Mitsuba's `gridvolume`). Storage order is `[z][y][x]` (x fastest), as in `.npy`.

use crate::{Error, Result};
use glam::DVec3;

/// Largest grid accepted, in voxels (512³ f32 = 512 MiB).
pub const MAX_VOXELS: usize = 512 * 512 * 512;

/// A density grid in metres; density is dimensionless (scaled by the medium's extinction).
#[derive(Debug, Clone, PartialEq)]
pub struct DensityGrid {
    /// Number of voxels along x, y, z.
    pub dims: [usize; 3],
    /// Edge length of a cubic voxel, metres.
    pub voxel_size_m: f64,
    /// Minimum corner of the box, metres.
    pub origin_m: DVec3,
    /// Densities, index `(z * ny + y) * nx + x`.
    pub data: Vec<f32>,
}

impl DensityGrid {
    /// A zero-filled grid, validating dimensions and memory before allocating.
    pub fn zeros(dims: [usize; 3], voxel_size_m: f64, origin_m: DVec3) -> Result<Self> {
        let count = checked_voxel_count(dims)?;
        if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
            return Err(Error::out_of_range(
                "voxel_size_m",
                voxel_size_m,
                "a finite value > 0",
            ));
        }
        if !origin_m.is_finite() {
            return Err(Error::invalid("origin_m", "must be finite"));
        }
        Ok(Self {
            dims,
            voxel_size_m,
            origin_m,
            data: vec![0.0; count],
        })
    }

    /// A grid from existing data (length must match `dims`).
    pub fn from_data(
        dims: [usize; 3],
        voxel_size_m: f64,
        origin_m: DVec3,
        data: Vec<f32>,
    ) -> Result<Self> {
        let mut grid = Self::zeros([1, 1, 1], voxel_size_m, origin_m)?;
        let count = checked_voxel_count(dims)?;
        if data.len() != count {
            return Err(Error::invalid(
                "data",
                format!("has {} values, dims {:?} need {}", data.len(), dims, count),
            ));
        }
        if let Some(bad) = data.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(Error::invalid(
                "data",
                format!("densities must be finite and >= 0, found {bad}"),
            ));
        }
        grid.dims = dims;
        grid.data = data;
        Ok(grid)
    }

    /// A grid holding `density(p)` at every voxel centre `p` (metres), evaluated in parallel over
    /// z-slices; dimensions and memory are validated before allocating.
    pub fn from_fn(
        dims: [usize; 3],
        voxel_size_m: f64,
        origin_m: DVec3,
        density: impl Fn(DVec3) -> f32 + Sync,
    ) -> Result<Self> {
        Self::from_fn_unless(dims, voxel_size_m, origin_m, density, &|| false)
    }

    /// [`Self::from_fn`], stopped with [`Error::Cancelled`] once `cancelled` returns true (asked
    /// before every z-slice).
    pub fn from_fn_unless(
        dims: [usize; 3],
        voxel_size_m: f64,
        origin_m: DVec3,
        density: impl Fn(DVec3) -> f32 + Sync,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<Self> {
        use rayon::prelude::*;
        use std::sync::atomic::{AtomicBool, Ordering};
        let mut grid = Self::zeros(dims, voxel_size_m, origin_m)?;
        let [nx, ny, _] = dims;
        let stopped = AtomicBool::new(false);
        grid.data
            .par_chunks_mut(nx * ny)
            .enumerate()
            .for_each(|(z, slice)| {
                if stopped.load(Ordering::Relaxed) || cancelled() {
                    stopped.store(true, Ordering::Relaxed);
                    return;
                }
                for (i, v) in slice.iter_mut().enumerate() {
                    let (x, y) = (i % nx, i / nx);
                    let p =
                        origin_m + (DVec3::new(x as f64, y as f64, z as f64) + 0.5) * voxel_size_m;
                    *v = density(p);
                }
            });
        if stopped.load(Ordering::Relaxed) {
            return Err(Error::Cancelled);
        }
        Ok(grid)
    }

    /// Linear index of voxel (x, y, z).
    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    /// Density stored at voxel (x, y, z).
    #[inline]
    pub fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        self.data[self.index(x, y, z)]
    }

    /// Centre of voxel (x, y, z), metres.
    pub fn voxel_centre(&self, x: usize, y: usize, z: usize) -> DVec3 {
        self.origin_m + (DVec3::new(x as f64, y as f64, z as f64) + 0.5) * self.voxel_size_m
    }

    /// Maximum corner of the box, metres.
    pub fn max_corner_m(&self) -> DVec3 {
        self.origin_m
            + DVec3::new(
                self.dims[0] as f64,
                self.dims[1] as f64,
                self.dims[2] as f64,
            ) * self.voxel_size_m
    }

    /// The grid at `factor` times the voxel edge: each coarse voxel holds the mean density of
    /// the `factor`³ fine voxels it covers (fine voxels past the grid's edge count as 0, the
    /// density outside the box), so every coarse voxel keeps the mass of its block. Same origin;
    /// the box grows by less than one coarse voxel where `factor` does not divide the dims.
    pub fn block_mean(&self, factor: usize) -> Result<Self> {
        let f = factor.max(1);
        let dims = [
            self.dims[0].div_ceil(f),
            self.dims[1].div_ceil(f),
            self.dims[2].div_ceil(f),
        ];
        let mut sum = vec![0f64; checked_voxel_count(dims)?];
        for z in 0..self.dims[2] {
            for y in 0..self.dims[1] {
                let row = self.index(0, y, z);
                let base = ((z / f) * dims[1] + y / f) * dims[0];
                for (x, v) in self.data[row..row + self.dims[0]].iter().enumerate() {
                    sum[base + x / f] += *v as f64;
                }
            }
        }
        let volume = (f * f * f) as f64;
        Self::from_data(
            dims,
            self.voxel_size_m * f as f64,
            self.origin_m,
            sum.iter().map(|s| (s / volume) as f32).collect(),
        )
    }

    /// Largest density in the grid (0 for an empty grid).
    pub fn max_density(&self) -> f32 {
        self.data.iter().copied().fold(0.0, f32::max)
    }

    /// Trilinear density at a world position (see the module docs for the convention).
    pub fn sample(&self, p: DVec3) -> f32 {
        let local = (p - self.origin_m) / self.voxel_size_m;
        let n = [self.dims[0], self.dims[1], self.dims[2]];
        let l = [local.x, local.y, local.z];
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut f = [0.0f64; 3];
        for a in 0..3 {
            if !(l[a] >= 0.0 && l[a] <= n[a] as f64) {
                return 0.0;
            }
            // Position in centre coordinates, clamped to the outermost centres.
            let c = (l[a] - 0.5).clamp(0.0, (n[a] - 1) as f64);
            let lo = (c.floor() as usize).min(n[a] - 1);
            i0[a] = lo;
            i1[a] = (lo + 1).min(n[a] - 1);
            f[a] = c - lo as f64;
        }
        let v = |x: usize, y: usize, z: usize| self.at(x, y, z) as f64;
        let c00 = v(i0[0], i0[1], i0[2]) * (1.0 - f[0]) + v(i1[0], i0[1], i0[2]) * f[0];
        let c10 = v(i0[0], i1[1], i0[2]) * (1.0 - f[0]) + v(i1[0], i1[1], i0[2]) * f[0];
        let c01 = v(i0[0], i0[1], i1[2]) * (1.0 - f[0]) + v(i1[0], i0[1], i1[2]) * f[0];
        let c11 = v(i0[0], i1[1], i1[2]) * (1.0 - f[0]) + v(i1[0], i1[1], i1[2]) * f[0];
        let c0 = c00 * (1.0 - f[1]) + c10 * f[1];
        let c1 = c01 * (1.0 - f[1]) + c11 * f[1];
        (c0 * (1.0 - f[2]) + c1 * f[2]) as f32
    }
}

/// Voxel count for `dims`, refusing empty or oversized grids before any allocation.
pub fn checked_voxel_count(dims: [usize; 3]) -> Result<usize> {
    checked_count(dims, MAX_VOXELS, "voxels")
}

/// `nx·ny·nz` for `dims`, refusing a zero dimension (out of range on `dims`) or a product above
/// `limit` (too large on `dims`, counted in `unit`) before anything is allocated.
pub fn checked_count(dims: [usize; 3], limit: usize, unit: &str) -> Result<usize> {
    if dims.contains(&0) {
        return Err(Error::out_of_range(
            "dims",
            format!("{dims:?}"),
            "each >= 1",
        ));
    }
    dims.iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .filter(|&c| c <= limit)
        .ok_or_else(|| {
            Error::too_large(
                "dims",
                format!("{dims:?} is too many {unit}"),
                format!("{limit} {unit}"),
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_follows_cell_centred_convention() {
        let mut g = DensityGrid::zeros([2, 1, 1], 1.0, DVec3::ZERO).unwrap();
        g.data = vec![1.0, 3.0];
        // At the centres: the stored values.
        assert_eq!(g.sample(DVec3::new(0.5, 0.5, 0.5)), 1.0);
        assert_eq!(g.sample(DVec3::new(1.5, 0.5, 0.5)), 3.0);
        // Halfway between centres: the mean.
        assert_eq!(g.sample(DVec3::new(1.0, 0.5, 0.5)), 2.0);
        // Between the outermost centre and the face: clamped.
        assert_eq!(g.sample(DVec3::new(0.1, 0.5, 0.5)), 1.0);
        assert_eq!(g.sample(DVec3::new(1.9, 0.2, 0.9)), 3.0);
        // Outside the box: zero.
        assert_eq!(g.sample(DVec3::new(2.1, 0.5, 0.5)), 0.0);
        assert_eq!(g.sample(DVec3::new(0.5, -0.1, 0.5)), 0.0);
    }

    #[test]
    fn oversized_grid_is_refused_before_allocation() {
        let err = DensityGrid::zeros([100_000, 100_000, 100_000], 1.0, DVec3::ZERO).unwrap_err();
        assert_eq!(err.field(), "dims");
        assert!(DensityGrid::zeros([0, 4, 4], 1.0, DVec3::ZERO).is_err());
    }
}
