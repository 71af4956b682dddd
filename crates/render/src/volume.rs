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
    /// Per block, whether its trilinear support (its voxels and one more round them) holds a
    /// density above 0.
    block_occupied: Vec<bool>,
    /// Corners of the box round every block whose support holds density (slightly enlarged),
    /// m; `None` for an empty grid. Outside it every density look-up returns 0.
    pub occupied: Option<(DVec3, DVec3)>,
    /// Per trilinear cell (the voxels' layout, indexed by the stencil's lower corner, see
    /// [`trilinear_stencil`]): the Chebyshev distance in cells to the nearest cell whose
    /// stencil holds a non-zero density, capped at [`EMPTY_CAP`] (0: the cell holds density;
    /// see [`occupancy`]).
    empty: Vec<u8>,
    /// A bit per voxel, set where its density is not 0 (x along the bits of 64-bit words,
    /// `dense_row` words a row; [`Self::voxel_dense`]).
    dense: Vec<u64>,
    dense_row: usize,
}

impl CloudVolume {
    pub fn new(grid: Arc<DensityGrid>) -> Self {
        let [nx, ny, nz] = grid.dims;
        let bd = [nx.div_ceil(BLOCK), ny.div_ceil(BLOCK), nz.div_ceil(BLOCK)];
        let (block_occupied, empty, dense) = occupancy(&grid, bd);
        let (mut bmin, mut bmax) = ([usize::MAX; 3], [0usize; 3]);
        for bz in 0..bd[2] {
            for by in 0..bd[1] {
                for bx in 0..bd[0] {
                    if block_occupied[(bz * bd[1] + by) * bd[0] + bx] {
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
            block_occupied,
            occupied,
            empty,
            dense,
            dense_row: nx.div_ceil(64),
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

    /// Whether voxel `(x, y, z)` (inside the grid) holds a non-zero density: one bit of a
    /// plane of 1/32 of the densities' size, which stays in cache where they do not.
    #[inline(always)]
    pub fn voxel_dense(&self, x: usize, y: usize, z: usize) -> bool {
        let word = (z * self.grid.dims[1] + y) * self.dense_row + x / 64;
        (self.dense[word] >> (x % 64)) & 1 != 0
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
        !self.block_occupied[(b[2] * self.block_dims[1] + b[1]) * self.block_dims[0] + b[0]]
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
        if self.block_occupied[idx] {
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
        if !self.block_occupied[idx] {
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

/// Per byte value, its 8 bits spread to one byte each (bit i → byte i, 0 or 1).
const SPREAD: [u64; 256] = {
    let mut t = [0u64; 256];
    let mut v = 0;
    while v < 256 {
        let mut i = 0;
        while i < 8 {
            t[v] |= (((v >> i) & 1) as u64) << (8 * i);
            i += 1;
        }
        v += 1;
    }
    t
};

/// Sets of voxels (or cells) as bit planes: a bit per voxel, x along the bits of 64-bit
/// words, each row padded to whole words (the padding 0), rows then layers as the voxels.
struct Planes {
    dims: [usize; 3],
    /// Words per row and per layer.
    w: usize,
    lw: usize,
    /// The bits of a row's last word that are voxels.
    last_mask: u64,
}

impl Planes {
    fn new(dims: [usize; 3]) -> Self {
        let w = dims[0].div_ceil(64);
        let last_mask = if dims[0] % 64 == 0 {
            u64::MAX
        } else {
            (1u64 << (dims[0] % 64)) - 1
        };
        Self {
            dims,
            w,
            lw: w * dims[1],
            last_mask,
        }
    }

    fn zeros(&self) -> Vec<u64> {
        vec![0u64; self.lw * self.dims[2]]
    }

    /// Word `i` of row `r` with each voxel taking the bit of its neighbour one up along x.
    #[inline(always)]
    fn next(r: &[u64], i: usize) -> u64 {
        (r[i] >> 1) | if i + 1 < r.len() { r[i + 1] << 63 } else { 0 }
    }

    /// Word `i` of row `r` with each voxel taking the bit of its neighbour one down along x.
    #[inline(always)]
    fn prev(r: &[u64], i: usize) -> u64 {
        (r[i] << 1) | if i > 0 { r[i - 1] >> 63 } else { 0 }
    }

    /// The voxels of `grid` with a non-zero density and those with a density above 0.
    fn of_grid(&self, grid: &DensityGrid) -> (Vec<u64>, Vec<u64>) {
        let [nx, ny, _] = self.dims;
        let (mut nonzero, mut positive) = (self.zeros(), self.zeros());
        nonzero
            .par_chunks_mut(self.lw)
            .zip(positive.par_chunks_mut(self.lw))
            .zip(grid.data.par_chunks(nx * ny))
            .for_each(|((nz_bits, pos_bits), rho)| {
                for (y, r) in rho.chunks(nx).enumerate() {
                    for (i, chunk) in r.chunks(64).enumerate() {
                        let (mut m, mut p) = (0u64, 0u64);
                        for (j, &v) in chunk.iter().enumerate() {
                            m |= u64::from(v != 0.0) << j;
                            p |= u64::from(v > 0.0) << j;
                        }
                        nz_bits[y * self.w + i] = m;
                        pos_bits[y * self.w + i] = p;
                    }
                }
            });
        (nonzero, positive)
    }

    /// `src` dilated by the 3×3×3 cube (every voxel within one of a voxel of `src` on every
    /// axis) into `out`, through `tmp` (the dilation along x and y).
    fn dilate(&self, src: &[u64], tmp: &mut [u64], out: &mut [u64]) {
        let (w, lw, ny, nz) = (self.w, self.lw, self.dims[1], self.dims[2]);
        tmp.par_chunks_mut(lw)
            .zip(src.par_chunks(lw))
            .for_each_init(
                || vec![0u64; lw],
                |xs, (layer, s)| {
                    for (o, r) in xs.chunks_mut(w).zip(s.chunks(w)) {
                        for i in 0..w {
                            o[i] = r[i] | Self::next(r, i) | Self::prev(r, i);
                        }
                        o[w - 1] &= self.last_mask;
                    }
                    for y in 0..ny {
                        for i in 0..w {
                            let mut v = xs[y * w + i];
                            if y > 0 {
                                v |= xs[(y - 1) * w + i];
                            }
                            if y + 1 < ny {
                                v |= xs[(y + 1) * w + i];
                            }
                            layer[y * w + i] = v;
                        }
                    }
                },
            );
        let tmp = &*tmp;
        out.par_chunks_mut(lw).enumerate().for_each(|(z, layer)| {
            let (below, above) = (z.saturating_sub(1), (z + 1).min(nz - 1));
            for (i, o) in layer.iter_mut().enumerate() {
                *o = tmp[below * lw + i] | tmp[z * lw + i] | tmp[above * lw + i];
            }
        });
    }
}

/// The block grid's occupancy ([`CloudVolume::in_empty_block`]: a block whose support, its
/// voxels and one more round them, holds a density above 0) and the empty cells' distances
/// ([`CloudVolume::empty_cells`]), both from bit planes of the voxels with density, and the
/// plane of the voxels with a non-zero density ([`CloudVolume::voxel_dense`]).
///
/// The distances: 0 at the cells whose stencil (the voxel and its neighbours one up along
/// each axis, clamped at the last) holds a non-zero density, elsewhere the Chebyshev distance
/// to them capped at [`EMPTY_CAP`], d(x) = min over the cells y with density of
/// maxₐ |xₐ − yₐ|. The cells within k of them are their set dilated k times by the 3×3×3
/// cube (separable by axes, Rosenfeld & Pfaltz 1968, §4), so d counts the dilations
/// 0 … cap − 1 that miss the cell. Exact everywhere.
fn occupancy(grid: &DensityGrid, bd: [usize; 3]) -> (Vec<bool>, Vec<u8>, Vec<u64>) {
    let [nx, ny, nz] = grid.dims;
    let len = nx * ny * nz;
    if len == 0 {
        return (vec![false; bd[0] * bd[1] * bd[2]], Vec::new(), Vec::new());
    }
    let pl = Planes::new(grid.dims);
    let (w, lw) = (pl.w, pl.lw);
    let (dense, positive) = pl.of_grid(grid);
    let mut a = dense.clone();
    let mut tmp = pl.zeros();
    // Blocks: the voxels with density dilated by one, then any bit within the block's own
    // voxels (64 = 8 blocks of 8 bits a word).
    let mut reach = pl.zeros();
    pl.dilate(&positive, &mut tmp, &mut reach);
    drop(positive);
    let mut block_occupied = vec![false; bd[0] * bd[1] * bd[2]];
    block_occupied
        .par_chunks_mut(bd[0] * bd[1])
        .enumerate()
        .for_each(|(bz, layer)| {
            for z in bz * BLOCK..((bz + 1) * BLOCK).min(nz) {
                for y in 0..ny {
                    let row = &reach[z * lw + y * w..z * lw + (y + 1) * w];
                    for bx in 0..bd[0] {
                        let byte = (row[bx * BLOCK / 64] >> (bx * BLOCK % 64)) & 0xff;
                        layer[(y / BLOCK) * bd[0] + bx] |= byte != 0;
                    }
                }
            }
        });
    // The cells whose stencil holds a non-zero density: the voxels with one, with the
    // neighbour one up along x (the row's last keeps its own: the padding is 0), y, then z
    // (the last keeps its own).
    a.par_chunks_mut(lw).for_each(|layer| {
        for y in 0..ny {
            for i in 0..w {
                let r = &layer[y * w..(y + 1) * w];
                let v = r[i] | Planes::next(r, i);
                layer[y * w + i] = v;
            }
        }
        for y in 0..ny - 1 {
            for i in 0..w {
                layer[y * w + i] |= layer[(y + 1) * w + i];
            }
        }
    });
    let cap = EMPTY_CAP as usize;
    let mut planes = vec![pl.zeros(); cap];
    {
        let a = &a;
        planes[0]
            .par_chunks_mut(lw)
            .enumerate()
            .for_each(|(z, out)| {
                let above = (z + 1).min(nz - 1);
                for (i, o) in out.iter_mut().enumerate() {
                    *o = a[z * lw + i] | a[above * lw + i];
                }
            });
    }
    for k in 1..cap {
        let (done, rest) = planes.split_at_mut(k);
        pl.dilate(&done[k - 1], &mut tmp, &mut rest[0]);
    }
    // Per cell the planes that miss it, 8 cells at a time (a byte each).
    let mut empty = vec![0u8; len];
    let planes = &planes;
    empty
        .par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, layer)| {
            for (y, row) in layer.chunks_mut(nx).enumerate() {
                let base = z * lw + y * w;
                for i in 0..w {
                    // Words no plane reaches (all the cap), or the first covers (all 0).
                    let cells = i * 64..(i * 64 + 64).min(nx);
                    if planes[cap - 1][base + i] == 0 {
                        row[cells].fill(EMPTY_CAP);
                        continue;
                    }
                    if planes[0][base + i] == u64::MAX {
                        row[cells].fill(0);
                        continue;
                    }
                    let missed: [u64; EMPTY_CAP as usize] =
                        std::array::from_fn(|k| !planes[k][base + i]);
                    for g in 0..8 {
                        let x0 = i * 64 + 8 * g;
                        if x0 >= nx {
                            break;
                        }
                        let mut d = 0u64;
                        for m in missed {
                            d += SPREAD[((m >> (8 * g)) & 0xff) as usize];
                        }
                        let n = (nx - x0).min(8);
                        row[x0..x0 + n].copy_from_slice(&d.to_le_bytes()[..n]);
                    }
                }
            }
        });
    (block_occupied, empty, dense)
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

    /// A small grid of `dims` with a few scattered voxels of density (some on the faces), the
    /// rest 0.
    fn sparse_grid(seed: u64, dims: [usize; 3]) -> DensityGrid {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
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
        // One on the last layer of every axis (the clamped stencils there), one in the middle,
        // one on each side of x = 64 (a word's edge in the distances' bit planes).
        grid.data[(5 * dims[1] + dims[1] - 1) * dims[0] + dims[0] - 1] = 0.5;
        grid.data[(9 * dims[1] + 8) * dims[0] + 20] = 0.5;
        if dims[0] > 66 {
            grid.data[(3 * dims[1] + 2) * dims[0] + 63] = 0.5;
            grid.data[(12 * dims[1] + 4) * dims[0] + 65] = 0.5;
        }
        grid
    }

    /// [`CloudVolume::empty_cells`] against a brute-force Chebyshev distance (every cell's 8
    /// corners read directly from the grid, every pair of cells compared), on grids narrower
    /// than a 64-bit word and wider than two.
    #[test]
    fn empty_cells_are_the_capped_chebyshev_distance() {
        for (seed, dims) in [
            (1, [41, 17, 19]),
            (2, [41, 17, 19]),
            (3, [41, 17, 19]),
            (4, [150, 11, 16]),
        ] {
            let grid = sparse_grid(seed, dims);
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
            assert_eq!(empty.len(), nx * ny * nz);
            let mut counts = [0usize; EMPTY_CAP as usize + 1];
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
                        assert_eq!(got, d, "seed {seed} cell {x} {y} {z}");
                        counts[d] += 1;
                    }
                }
            }
            // Every distance occurs (the test sees more than empty and full cells).
            assert!(counts.iter().all(|&c| c > 0), "{counts:?}");
        }
    }

    /// What the march relies on: from a point whose cell reads k > 0, every point within
    /// k − 1 voxels on every axis samples no density (or lies outside the box).
    #[test]
    fn points_within_the_empty_distance_sample_no_density() {
        let grid = sparse_grid(7, [41, 17, 19]);
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
