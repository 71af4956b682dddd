//! The cloud as a participating medium: density lookups with shared trilinear weights, the box,
//! a block grid of maximum densities for skipping empty space, and optical paths along rays.

use super::camera::box_interval;
use glam::DVec3;
use rayon::prelude::*;
use skybake_physics::cloud::DensityGrid;
use std::sync::Arc;

/// Edge of the empty-space blocks, voxels.
pub const BLOCK: usize = 8;

/// Largest distance [`CloudVolume::empty_cells`] holds, cells (a march step skips at most
/// this many voxels along its largest axis at once; the 8³ blocks end its runs anyway).
pub const EMPTY_CAP: u8 = 8;

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
    /// Per trilinear cell (the voxels' layout, indexed by the stencil's lower corner, see
    /// [`trilinear_stencil`]): the Chebyshev distance in cells to the nearest cell whose
    /// stencil holds a non-zero density, capped at [`EMPTY_CAP`] (0: the cell holds density;
    /// see [`empty_distances`]).
    empty: Vec<u8>,
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
            empty: empty_distances(&grid),
            grid,
        }
    }

    /// The trilinear stencil at `p` (the grid's convention, [`trilinear_stencil`]); `None`
    /// outside.
    #[inline(always)]
    pub fn stencil(&self, p: DVec3) -> Option<(usize, [usize; 3], [f64; 3])> {
        let g = &*self.grid;
        trilinear_stencil((p - g.origin_m) / g.voxel_size_m, g.dims)
    }

    /// Per trilinear cell, indexed by its stencil's first value ([`Self::stencil`]): the
    /// Chebyshev distance in cells to the nearest cell with density or less, at most
    /// [`EMPTY_CAP`]; 0 where the cell's stencil holds density. Where it is k > 0, every point whose clamped
    /// voxel coordinates (`local − ½` clamped to the centres' range) lie within k − 1 of this
    /// point's on every axis has an all-zero stencil (or lies outside the box).
    #[inline(always)]
    pub fn empty_cells(&self) -> &[u8] {
        &self.empty
    }

    /// Trilinear weights of the 8 voxels around `p` (the grid's convention); `None` outside.
    #[inline(always)]
    pub fn weights(&self, p: DVec3) -> Option<[(usize, f64); 8]> {
        Some(Self::stencil_weights(self.stencil(p)?))
    }

    /// The 8 voxels and weights of a stencil of [`Self::stencil`] (what [`Self::weights`]
    /// returns).
    #[inline(always)]
    pub fn stencil_weights((base, di, f): (usize, [usize; 3], [f64; 3])) -> [(usize, f64); 8] {
        let (gx, gy, gz) = ([1.0 - f[0], f[0]], [1.0 - f[1], f[1]], [1.0 - f[2], f[2]]);
        let mut out = [(0usize, 0f64); 8];
        for (corner, o) in out.iter_mut().enumerate() {
            let (bx, by, bz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let w = gx[bx] * gy[by] * gz[bz];
            *o = (base + bx * di[0] + by * di[1] + bz * di[2], w);
        }
        out
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

/// [`CloudVolume::empty_cells`] of `grid`: 0 at the cells whose stencil (the voxel and its
/// neighbours one up along each axis, clamped at the last) holds a non-zero density, elsewhere
/// the Chebyshev distance to them capped at [`EMPTY_CAP`], d(x) = min over the cells y with
/// density of maxₐ |xₐ − yₐ|, a minimum of maxima that separates by axes (Rosenfeld & Pfaltz
/// 1968, §4): one axis at a time, d ← min over |k| ≤ cap of max(|k|, d k cells away). Each
/// pass runs over whole layers (vectorised), so along x a row's window runs on into the next
/// row: within [`EMPTY_CAP`] cells of the grid's x faces a distance can come out smaller than
/// the true one (never larger; exact elsewhere), which only skips less.
fn empty_distances(grid: &DensityGrid) -> Vec<u8> {
    let [nx, ny, nz] = grid.dims;
    let layer = nx * ny;
    let len = layer * nz;
    let cap = EMPTY_CAP;
    if len == 0 {
        return Vec::new();
    }
    // `out[i] = min(out[i], max(k, src[i]))` over two slices.
    fn min_max(out: &mut [u8], src: &[u8], k: u8) {
        for (o, &v) in out.iter_mut().zip(src) {
            *o = (*o).min(v.max(k));
        }
    }
    // 0 at the voxels with density, `cap` elsewhere; then the cells whose stencil holds one:
    // the minimum with the neighbour one up along x (within the row), y, then z (the last keeps
    // its own).
    let mut a = vec![0u8; len];
    a.par_chunks_mut(layer)
        .zip(grid.data.par_chunks(layer))
        .for_each(|(out, rho)| {
            for (o, &v) in out.iter_mut().zip(rho) {
                *o = if v != 0.0 { 0 } else { cap };
            }
            for row in out.chunks_mut(nx) {
                for x in 0..nx - 1 {
                    row[x] = row[x].min(row[x + 1]);
                }
            }
        });
    let mut b = vec![0u8; len];
    b.par_chunks_mut(layer)
        .zip(a.par_chunks(layer))
        .for_each(|(out, src)| {
            out.copy_from_slice(src);
            min_max(&mut out[..layer - nx], &src[nx..], 0);
        });
    a.par_chunks_mut(layer).enumerate().for_each(|(z, out)| {
        let up = (z + 1).min(nz - 1);
        out.copy_from_slice(&b[z * layer..(z + 1) * layer]);
        min_max(out, &b[up * layer..(up + 1) * layer], 0);
    });
    // Along x (whole layers: see above), then y (within each layer).
    b.par_chunks_mut(layer)
        .zip(a.par_chunks(layer))
        .for_each(|(out, src)| {
            out.copy_from_slice(src);
            for k in 1..=(cap as usize).min(nx - 1) {
                min_max(&mut out[..layer - k], &src[k..], k as u8);
                min_max(&mut out[k..], &src[..layer - k], k as u8);
            }
        });
    a.par_chunks_mut(layer)
        .zip(b.par_chunks(layer))
        .for_each(|(out, src)| {
            out.copy_from_slice(src);
            for k in 1..=(cap as usize).min(ny - 1) {
                let s = k * nx;
                min_max(&mut out[..layer - s], &src[s..], k as u8);
                min_max(&mut out[s..], &src[..layer - s], k as u8);
            }
        });
    // Along z: each layer from the layers within `cap`.
    b.par_chunks_mut(layer).enumerate().for_each(|(z, out)| {
        out.copy_from_slice(&a[z * layer..(z + 1) * layer]);
        for k in 1..=(cap as usize) {
            for zz in [z.checked_sub(k), (z + k < nz).then_some(z + k)]
                .into_iter()
                .flatten()
            {
                min_max(out, &a[zz * layer..(zz + 1) * layer], k as u8);
            }
        }
    });
    b
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A small grid with a few scattered voxels of density (some on the faces), the rest 0.
    fn sparse_grid(seed: u64) -> DensityGrid {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let dims = [41, 17, 19];
        let mut grid =
            DensityGrid::from_fn(dims, 7.0, DVec3::new(-60.0, 20.0, 900.0), |_| 0.0).expect("grid");
        for _ in 0..6 {
            let (x, y, z) = (
                rng.random_range(0..dims[0]),
                rng.random_range(0..dims[1]),
                rng.random_range(0..dims[2]),
            );
            grid.data[(z * dims[1] + y) * dims[0] + x] = rng.random_range(0.1f32..1.0);
        }
        // One on the last layer of every axis (the clamped stencils there), one in the middle.
        grid.data[(5 * dims[1] + dims[1] - 1) * dims[0] + dims[0] - 1] = 0.5;
        grid.data[(9 * dims[1] + 8) * dims[0] + 20] = 0.5;
        grid
    }

    /// [`CloudVolume::empty_cells`] against a brute-force Chebyshev distance (every cell's 8
    /// corners read directly from the grid, every pair of cells compared): exact away from the
    /// grid's x faces, never above it near them.
    #[test]
    fn empty_cells_are_the_capped_chebyshev_distance_or_below() {
        for seed in [1, 2, 3] {
            let grid = sparse_grid(seed);
            let [nx, ny, nz] = grid.dims;
            let mut dense = Vec::new();
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let any = (0..8).any(|c| {
                            grid.at(
                                (x + (c & 1)).min(nx - 1),
                                (y + ((c >> 1) & 1)).min(ny - 1),
                                (z + (c >> 2)).min(nz - 1),
                            ) != 0.0
                        });
                        if any {
                            dense.push([x, y, z]);
                        }
                    }
                }
            }
            assert!(!dense.is_empty());
            let vol = CloudVolume::new(Arc::new(grid.clone()));
            let empty = vol.empty_cells();
            let mut counts = [0usize; EMPTY_CAP as usize + 1];
            let (mut near_faces, mut short) = (0, 0);
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let d = dense
                            .iter()
                            .map(|c| c[0].abs_diff(x).max(c[1].abs_diff(y)).max(c[2].abs_diff(z)))
                            .min()
                            .unwrap()
                            .min(EMPTY_CAP as usize);
                        let got = empty[(z * ny + y) * nx + x] as usize;
                        // Never above the distance; exact away from the x faces.
                        assert!(got <= d, "seed {seed} cell {x} {y} {z}: {got} > {d}");
                        if x >= EMPTY_CAP as usize && x + (EMPTY_CAP as usize) < nx {
                            assert_eq!(got, d, "seed {seed} cell {x} {y} {z}");
                            counts[d] += 1;
                        } else {
                            near_faces += 1;
                            short += usize::from(got < d);
                        }
                    }
                }
            }
            // Every distance occurs (the test sees more than empty and full cells), and near
            // the x faces few distances come out short.
            assert!(counts.iter().all(|&c| c > 0), "{counts:?}");
            assert!(short * 4 < near_faces, "{short} of {near_faces}");
        }
    }

    /// What the march relies on: from a point whose cell reads k > 0, every point within
    /// k − 1 voxels on every axis samples no density (or lies outside the box).
    #[test]
    fn points_within_the_empty_distance_sample_no_density() {
        let grid = sparse_grid(7);
        let vol = CloudVolume::new(Arc::new(grid.clone()));
        let size = DVec3::new(41.0, 17.0, 19.0) * 7.0;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let (mut far, mut near_density) = (0, 0);
        for _ in 0..20_000 {
            let u = DVec3::new(rng.random(), rng.random(), rng.random());
            let p = vol.lo + u * size;
            let Some(stencil) = vol.stencil(p) else {
                continue;
            };
            let k = vol.empty_cells()[stencil.0];
            if k == 0 {
                continue;
            }
            assert_eq!(sample(&grid, p), 0.0);
            let r = (k as f64 - 1.0 - 1e-3) * 7.0;
            for _ in 0..8 {
                let v = DVec3::new(
                    rng.random_range(-1.0..=1.0),
                    rng.random_range(-1.0..=1.0),
                    rng.random_range(-1.0..=1.0),
                );
                // Often on the cube's faces, where the bound is tight.
                let v = if rng.random_bool(0.5) {
                    v / v.abs().max_element()
                } else {
                    v
                };
                let q = p + v * r;
                assert_eq!(sample(&grid, q), 0.0, "{p} {q} k {k}");
                // Just beyond one voxel more, density is sometimes found (the bound is tight).
                if k < EMPTY_CAP && sample(&grid, p + v * (r + 7.0 * 1.01)) != 0.0 {
                    near_density += 1;
                }
            }
            far += usize::from(k > 2);
        }
        assert!(far > 1000 && near_density > 10, "{far} {near_density}");
    }
}
