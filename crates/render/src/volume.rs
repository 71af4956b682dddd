//! The cloud as a participating medium: density lookups with shared trilinear weights, the box,
//! a block grid of maximum densities for skipping empty space, and optical paths along rays.

use super::camera::box_interval;
use glam::DVec3;
use skybake_physics::cloud::DensityGrid;
use std::sync::Arc;

/// Edge of the empty-space blocks, voxels.
pub const BLOCK: usize = 8;

/// A density grid prepared for ray marching and tracking (it shares the grid, so a lit volume
/// kept for a sequence of frames keeps it).
pub struct CloudVolume {
    pub grid: Arc<DensityGrid>,
    pub lo: DVec3,
    pub hi: DVec3,
    pub rho_max: f64,
    block_dims: [usize; 3],
    /// Largest density each block's trilinear support can return.
    block_max: Vec<f32>,
}

impl CloudVolume {
    pub fn new(grid: Arc<DensityGrid>) -> Self {
        let [nx, ny, nz] = grid.dims;
        let bd = [nx.div_ceil(BLOCK), ny.div_ceil(BLOCK), nz.div_ceil(BLOCK)];
        let mut block_max = vec![0f32; bd[0] * bd[1] * bd[2]];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let v = grid.at(x, y, z);
                    if v <= 0.0 {
                        continue;
                    }
                    // A voxel's value reaches one voxel into its neighbours' blocks.
                    for bz in (z.saturating_sub(1) / BLOCK)..=((z + 1).min(nz - 1) / BLOCK) {
                        for by in (y.saturating_sub(1) / BLOCK)..=((y + 1).min(ny - 1) / BLOCK) {
                            for bx in (x.saturating_sub(1) / BLOCK)..=((x + 1).min(nx - 1) / BLOCK)
                            {
                                let b = (bz * bd[1] + by) * bd[0] + bx;
                                block_max[b] = block_max[b].max(v);
                            }
                        }
                    }
                }
            }
        }
        Self {
            lo: grid.origin_m,
            hi: grid.max_corner_m(),
            rho_max: grid.max_density() as f64,
            block_dims: bd,
            block_max,
            grid,
        }
    }

    /// Trilinear weights of the 8 voxels around `p` (the grid's convention); `None` outside.
    #[inline]
    pub fn weights(&self, p: DVec3) -> Option<[(usize, f64); 8]> {
        let g = &*self.grid;
        let local = (p - g.origin_m) / g.voxel_size_m;
        let n = g.dims;
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut f = [0f64; 3];
        for a in 0..3 {
            let l = local[a];
            if !(l >= 0.0 && l <= n[a] as f64) {
                return None;
            }
            let c = (l - 0.5).clamp(0.0, (n[a] - 1) as f64);
            let lo = (c.floor() as usize).min(n[a] - 1);
            i0[a] = lo;
            i1[a] = (lo + 1).min(n[a] - 1);
            f[a] = c - lo as f64;
        }
        let mut out = [(0usize, 0f64); 8];
        for (corner, o) in out.iter_mut().enumerate() {
            let x = if corner & 1 == 0 { i0[0] } else { i1[0] };
            let y = if corner & 2 == 0 { i0[1] } else { i1[1] };
            let z = if corner & 4 == 0 { i0[2] } else { i1[2] };
            let w = (if corner & 1 == 0 { 1.0 - f[0] } else { f[0] })
                * (if corner & 2 == 0 { 1.0 - f[1] } else { f[1] })
                * (if corner & 4 == 0 { 1.0 - f[2] } else { f[2] });
            *o = (g.index(x, y, z), w);
        }
        Some(out)
    }

    /// Density at `p` (0 outside the box).
    #[inline]
    pub fn rho(&self, p: DVec3) -> f64 {
        self.grid.sample(p) as f64
    }

    /// Entry and exit distances of the ray with the box.
    pub fn interval(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        box_interval(o, d, self.lo, self.hi)
    }

    /// If the block containing `p` is empty, the distance along `d` to leave it; else `None`.
    #[inline]
    pub fn empty_skip(&self, p: DVec3, d: DVec3) -> Option<f64> {
        let h = self.grid.voxel_size_m * BLOCK as f64;
        let local = (p - self.lo) / h;
        let mut b = [0usize; 3];
        for a in 0..3 {
            let v = local[a].floor();
            if v < 0.0 || v >= self.block_dims[a] as f64 {
                return None;
            }
            b[a] = v as usize;
        }
        let idx = (b[2] * self.block_dims[1] + b[1]) * self.block_dims[0] + b[0];
        if self.block_max[idx] > 0.0 {
            return None;
        }
        let blo = self.lo + DVec3::new(b[0] as f64, b[1] as f64, b[2] as f64) * h;
        let bhi = blo + DVec3::splat(h);
        let mut t = f64::INFINITY;
        for a in 0..3 {
            if d[a] > 0.0 {
                t = t.min((bhi[a] - p[a]) / d[a]);
            } else if d[a] < 0.0 {
                t = t.min((blo[a] - p[a]) / d[a]);
            }
        }
        Some(t.max(0.0))
    }

    /// Density integral ∫ρ ds (m) from `o` along unit `d` to the box exit, midpoint rule with
    /// steps of `step_m`, skipping empty blocks; f64.
    pub fn density_integral(&self, o: DVec3, d: DVec3, step_m: f64) -> f64 {
        let Some((t0, t1)) = self.interval(o, d) else {
            return 0.0;
        };
        let mut t = t0;
        let mut sum = 0.0;
        while t < t1 {
            let p = o + d * t;
            if let Some(skip) = self.empty_skip(p, d) {
                t += skip + 1e-6 * step_m;
                continue;
            }
            let dt = step_m.min(t1 - t);
            sum += self.rho(o + d * (t + 0.5 * dt)) * dt;
            t += dt;
        }
        sum
    }

    /// Distance to the first point along the ray where the density's block is not empty (an
    /// approximation of the cloud's front, for aerial perspective), or `None`.
    pub fn first_occupied(&self, o: DVec3, d: DVec3, step_m: f64) -> Option<f64> {
        let (t0, t1) = self.interval(o, d)?;
        let mut t = t0;
        while t < t1 {
            let p = o + d * t;
            match self.empty_skip(p, d) {
                Some(skip) => t += skip + 1e-6 * step_m,
                None => {
                    if self.rho(p) > 0.0 {
                        return Some(t);
                    }
                    t += step_m;
                }
            }
        }
        None
    }
}
