//! The cloud as a participating medium: density lookups with shared trilinear weights, the box,
//! a block grid of maximum densities for skipping empty space, and optical paths along rays.

use super::camera::box_interval;
use glam::DVec3;
use rayon::prelude::*;
use skybake_physics::cloud::DensityGrid;
use std::sync::Arc;

/// Edge of the empty-space blocks, voxels.
pub const BLOCK: usize = 8;

/// ⌊x⌋, equal to `f64::floor` for every input, without the libm call that targets without
/// SSE4.1 make of `floor` (a conversion to an integer and back, corrected for negative x).
#[inline(always)]
pub fn floor(x: f64) -> f64 {
    if x.abs() < 4.0e15 {
        let t = x as i64 as f64;
        if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        x.floor()
    }
}

/// The grid's density at `p`, the same value as [`DensityGrid::sample`] (same weights, same
/// order of operations) without its `floor` calls.
#[inline]
pub fn sample(g: &DensityGrid, p: DVec3) -> f32 {
    let local = (p - g.origin_m) / g.voxel_size_m;
    let Some((b, [dx, dy, dz], f)) = trilinear_stencil(local, g.dims) else {
        return 0.0;
    };
    let d = &g.data;
    let v = |i: usize| d[i] as f64;
    let c00 = v(b) * (1.0 - f[0]) + v(b + dx) * f[0];
    let c10 = v(b + dy) * (1.0 - f[0]) + v(b + dy + dx) * f[0];
    let c01 = v(b + dz) * (1.0 - f[0]) + v(b + dz + dx) * f[0];
    let c11 = v(b + dz + dy) * (1.0 - f[0]) + v(b + dz + dy + dx) * f[0];
    let c0 = c00 * (1.0 - f[1]) + c10 * f[1];
    let c1 = c01 * (1.0 - f[1]) + c11 * f[1];
    (c0 * (1.0 - f[2]) + c1 * f[2]) as f32
}

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
    /// Corners of the box round every block whose support holds density (slightly enlarged),
    /// m; `None` for an empty grid. Outside it every density look-up returns 0.
    pub occupied: Option<(DVec3, DVec3)>,
}

impl CloudVolume {
    pub fn new(grid: Arc<DensityGrid>) -> Self {
        let [nx, ny, nz] = grid.dims;
        let bd = [nx.div_ceil(BLOCK), ny.div_ceil(BLOCK), nz.div_ceil(BLOCK)];
        let mut block_max = vec![0f32; bd[0] * bd[1] * bd[2]];
        // Each layer of blocks from the voxel layers that reach it (in parallel: a maximum,
        // the same in any order).
        block_max
            .par_chunks_mut(bd[0] * bd[1])
            .enumerate()
            .for_each(|(bz, layer)| {
                for z in (bz * BLOCK).saturating_sub(1)..((bz + 1) * BLOCK + 1).min(nz) {
                    for y in 0..ny {
                        for x in 0..nx {
                            let v = grid.at(x, y, z);
                            if v <= 0.0 {
                                continue;
                            }
                            // A voxel's value reaches one voxel into its neighbours' blocks.
                            for by in (y.saturating_sub(1) / BLOCK)..=((y + 1).min(ny - 1) / BLOCK)
                            {
                                for bx in
                                    (x.saturating_sub(1) / BLOCK)..=((x + 1).min(nx - 1) / BLOCK)
                                {
                                    let b = by * bd[0] + bx;
                                    layer[b] = layer[b].max(v);
                                }
                            }
                        }
                    }
                }
            });
        let (mut bmin, mut bmax) = ([usize::MAX; 3], [0usize; 3]);
        for bz in 0..bd[2] {
            for by in 0..bd[1] {
                for bx in 0..bd[0] {
                    if block_max[(bz * bd[1] + by) * bd[0] + bx] > 0.0 {
                        for (a, v) in [bx, by, bz].into_iter().enumerate() {
                            bmin[a] = bmin[a].min(v);
                            bmax[a] = bmax[a].max(v + 1);
                        }
                    }
                }
            }
        }
        let lo = grid.origin_m;
        let hi = grid.max_corner_m();
        let hb = grid.voxel_size_m * BLOCK as f64;
        // Enlarged by a thousandth of a voxel so that rounding at a block face never puts a
        // point of an occupied block outside.
        let margin = 1e-3 * grid.voxel_size_m;
        let occupied = (bmin[0] != usize::MAX).then(|| {
            let a = DVec3::new(bmin[0] as f64, bmin[1] as f64, bmin[2] as f64) * hb + lo;
            let b = DVec3::new(bmax[0] as f64, bmax[1] as f64, bmax[2] as f64) * hb + lo;
            (a - DVec3::splat(margin), b.min(hi) + DVec3::splat(margin))
        });
        Self {
            lo,
            hi,
            rho_max: grid.max_density() as f64,
            block_dims: bd,
            block_max,
            occupied,
            grid,
        }
    }

    /// Trilinear weights of the 8 voxels around `p` (the grid's convention); `None` outside.
    #[inline(always)]
    pub fn weights(&self, p: DVec3) -> Option<[(usize, f64); 8]> {
        let g = &*self.grid;
        let local = (p - g.origin_m) / g.voxel_size_m;
        let (base, di, f) = trilinear_stencil(local, g.dims)?;
        let (gx, gy, gz) = ([1.0 - f[0], f[0]], [1.0 - f[1], f[1]], [1.0 - f[2], f[2]]);
        let mut out = [(0usize, 0f64); 8];
        for (corner, o) in out.iter_mut().enumerate() {
            let (bx, by, bz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let w = gx[bx] * gy[by] * gz[bz];
            *o = (base + bx * di[0] + by * di[1] + bz * di[2], w);
        }
        Some(out)
    }

    /// Density at `p` (0 outside the box).
    #[inline]
    pub fn rho(&self, p: DVec3) -> f64 {
        sample(&self.grid, p) as f64
    }

    /// Entry and exit distances of the ray with the box.
    pub fn interval(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        box_interval(o, d, self.lo, self.hi)
    }

    /// Whether `p` lies in an empty block of the block grid, where every density look-up
    /// ([`sample`], [`Self::weights`]) returns 0 (false outside the block grid: not known).
    #[inline]
    pub fn in_empty_block(&self, p: DVec3) -> bool {
        let h = self.grid.voxel_size_m * BLOCK as f64;
        let local = (p - self.lo) / h;
        let mut b = [0usize; 3];
        for a in 0..3 {
            let v = floor(local[a]);
            if !(v >= 0.0 && v < self.block_dims[a] as f64) {
                return false;
            }
            b[a] = v as usize;
        }
        self.block_max[(b[2] * self.block_dims[1] + b[1]) * self.block_dims[0] + b[0]] <= 0.0
    }

    /// If the block containing `p` is empty, the distance along `d` to leave it; else `None`.
    #[inline]
    pub fn empty_skip(&self, p: DVec3, d: DVec3) -> Option<f64> {
        let h = self.grid.voxel_size_m * BLOCK as f64;
        let local = (p - self.lo) / h;
        let mut b = [0usize; 3];
        for a in 0..3 {
            let v = floor(local[a]);
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

    /// [`Self::empty_skip`] and more: `(true, skip)` where it returns `Some(skip)`; otherwise
    /// `(false, t)` with `t` a distance along `d` from `p` before which every point of the ray
    /// (computed as `o + d·t'` like `p`) stays in the same occupied block, so `empty_skip`
    /// would return `None` there too: short of the block's faces by a millionth of a voxel plus
    /// a bound on the rounding of the points (0 outside the block grid).
    #[inline(always)]
    pub fn block_exit(&self, p: DVec3, d: DVec3) -> (bool, f64) {
        let h = self.grid.voxel_size_m * BLOCK as f64;
        let local = (p - self.lo) / h;
        let mut b = [0usize; 3];
        for a in 0..3 {
            let v = floor(local[a]);
            if v < 0.0 || v >= self.block_dims[a] as f64 {
                return (false, 0.0);
            }
            b[a] = v as usize;
        }
        let idx = (b[2] * self.block_dims[1] + b[1]) * self.block_dims[0] + b[0];
        let blo = self.lo + DVec3::new(b[0] as f64, b[1] as f64, b[2] as f64) * h;
        let bhi = blo + DVec3::splat(h);
        if self.block_max[idx] <= 0.0 {
            let mut t = f64::INFINITY;
            for a in 0..3 {
                if d[a] > 0.0 {
                    t = t.min((bhi[a] - p[a]) / d[a]);
                } else if d[a] < 0.0 {
                    t = t.min((blo[a] - p[a]) / d[a]);
                }
            }
            return (true, t.max(0.0));
        }
        let mut t = f64::INFINITY;
        let guard = 1e-6 * self.grid.voxel_size_m;
        for a in 0..3 {
            let face = if d[a] > 0.0 {
                bhi[a]
            } else if d[a] < 0.0 {
                blo[a]
            } else {
                continue;
            };
            let slack = 1e-9 * (p[a].abs() + self.lo[a].abs() + h) / d[a].abs();
            t = t.min((face - p[a]) / d[a] - guard - slack);
        }
        (false, t.max(0.0))
    }

    /// Density integral ∫ρ ds (m) from `o` along unit `d` to the box exit, midpoint rule with
    /// steps of `step_m`, skipping empty blocks; f64.
    pub fn density_integral(&self, o: DVec3, d: DVec3, step_m: f64) -> f64 {
        let Some((t0, t1)) = self.interval(o, d) else {
            return 0.0;
        };
        // Every density outside the occupied blocks' box is 0: a ray that misses it sums
        // nothing, and the steps after it leaves add 0 (the same sum).
        let Some((occ_lo, occ_hi)) = self.occupied else {
            return 0.0;
        };
        let Some((_, t_occ_end)) = box_interval(o, d, occ_lo, occ_hi) else {
            return 0.0;
        };
        let mut t = t0;
        let mut sum = 0.0;
        // No empty-space test while the ray stays in an occupied block (see
        // [`Self::block_exit`]): the steps are those of the test at every step.
        let mut occupied_until = f64::NEG_INFINITY;
        while t < t1 {
            if t > t_occ_end {
                break;
            }
            if t >= occupied_until {
                match self.block_exit(o + d * t, d) {
                    (true, skip) => {
                        t += skip + 1e-6 * step_m;
                        continue;
                    }
                    (false, exit) => occupied_until = t + exit,
                }
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

/// The trilinear stencil of the grid's convention at `local` (voxel units from the grid's
/// origin, voxel centres at half-integers) in a grid of `n` voxels (x fastest): the lower
/// corner's index, the index steps to the upper corner along x, y, z (0 at the last voxel: the
/// edge value continues beyond the outermost centres) and the fractions; `None` outside the
/// box.
#[inline(always)]
pub(crate) fn trilinear_stencil(
    local: DVec3,
    n: [usize; 3],
) -> Option<(usize, [usize; 3], [f64; 3])> {
    let strides = [1, n[0], n[0] * n[1]];
    let mut i0 = [0usize; 3];
    let mut di = [0usize; 3];
    let mut f = [0f64; 3];
    for a in 0..3 {
        let l = local[a];
        if !(l >= 0.0 && l <= n[a] as f64) {
            return None;
        }
        let c = (l - 0.5).clamp(0.0, (n[a] - 1) as f64);
        // c ≥ 0: truncation is the floor.
        let lo = (c as usize).min(n[a] - 1);
        i0[a] = lo;
        di[a] = ((lo + 1).min(n[a] - 1) - lo) * strides[a];
        f[a] = c - lo as f64;
    }
    Some((i0[2] * strides[2] + i0[1] * strides[1] + i0[0], di, f))
}
