//! Sampling the sphere model into a [`DensityGrid`] for the volume renderer.

use super::model::{SphereCloud, CHILDREN};
use super::optics::edge_weight;
use crate::cloud::grid::checked_voxel_count;
use crate::cloud::DensityGrid;
use crate::{Error, Result};
use glam::DVec3;

impl SphereCloud {
    /// Density at a point: Σ over the spheres of level `level` containing it of f(d, r) (Ostroushko et al.,
    /// eq 2 with d the distance from the sphere centre), so that the local extinction is
    /// `extinction_per_m() × density`. This is the volumetric reading of eq 3's edge function:
    /// extinction falls linearly from the centre to the rim of each sphere. Only spheres whose
    /// ancestors contain the point are visited.
    pub fn density_at(&self, p_m: DVec3, level: u32) -> f64 {
        let level = level.min(self.max_level());
        let q = p_m - self.centre_m();
        let mut sum = 0.0;
        let mut stack = vec![(0u32, 0usize)];
        while let Some((k, i)) = stack.pop() {
            let s = &self.level(k)[i];
            let r = s.radius as f64;
            let d = q.distance(s.centre_m());
            if k == level {
                sum += edge_weight(d, r);
            } else if d <= r * (1.0 + 1e-5) + 1e-6 {
                stack.extend((0..CHILDREN).map(|j| (k + 1, i * CHILDREN + j)));
            }
        }
        sum
    }

    /// Voxelises the cloud: cubic voxels of `voxel_size_m` over the bounding box of the spheres of
    /// `level` (default K), density [`Self::density_at`] at every voxel centre (the grid's
    /// cell-centred convention). Multiply by [`Self::extinction_per_m`] for extinction.
    pub fn voxelize(&self, voxel_size_m: f64, level: Option<u32>) -> Result<DensityGrid> {
        self.voxelize_unless(voxel_size_m, level, &|| false)
    }

    /// [`Self::voxelize`], stopped with [`crate::Error::Cancelled`] once `cancelled` returns true
    /// (asked before every z-slice).
    pub fn voxelize_unless(
        &self,
        voxel_size_m: f64,
        level: Option<u32>,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<DensityGrid> {
        let (dims, origin, level) = self.grid_box(voxel_size_m, level)?;
        DensityGrid::from_fn_unless(
            dims,
            voxel_size_m,
            origin,
            |p| self.density_at(p, level) as f32,
            cancelled,
        )
    }

    /// The grid [`Self::voxelize`] builds, without building it: dims `[nx, ny, nz]`, minimum
    /// corner and the level used. Refuses a voxel size out of range, a level above K and a grid
    /// over the cloud module's voxel limit.
    pub fn grid_box(
        &self,
        voxel_size_m: f64,
        level: Option<u32>,
    ) -> Result<([usize; 3], DVec3, u32)> {
        if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
            return Err(Error::out_of_range(
                "voxel_size_m",
                voxel_size_m,
                "a finite value > 0",
            ));
        }
        let level = level.unwrap_or(self.max_level());
        if level > self.max_level() {
            return Err(Error::out_of_range(
                "level",
                level,
                format!("0..={}", self.max_level()),
            ));
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for s in self.level(level) {
            let c = s.centre_m();
            lo = lo.min(c - s.radius as f64);
            hi = hi.max(c + s.radius as f64);
        }
        let extent = (hi - lo) / voxel_size_m;
        if !extent.is_finite() || extent.max_element() >= 1e7 {
            return Err(Error::too_large(
                "voxel_size_m",
                format!("{voxel_size_m} m voxels over a {:?} m box", hi - lo),
                format!("{} voxels", crate::cloud::grid::MAX_VOXELS),
            ));
        }
        let dims = [
            (extent.x.ceil() as usize).max(1),
            (extent.y.ceil() as usize).max(1),
            (extent.z.ceil() as usize).max(1),
        ];
        checked_voxel_count(dims).map_err(|e| match e {
            Error::TooLarge { reason, limit, .. } => Error::TooLarge {
                field: "voxel_size_m".into(),
                reason,
                limit,
            },
            other => other,
        })?;
        Ok((dims, self.centre_m() + lo, level))
    }
}
