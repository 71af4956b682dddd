//! Metaball density fields (Nishita & Dobashi 2001, eq 3; Nishita et al. 1996, §4): `ρ(P) = Σ_j q_j h(|P - C_j|, R_j)` with
//! Wyvill's field `h` (Dobashi et al. 2000, eq B.1), so `q_j` is the density at the centre of ball `j`.
//!
//! Evaluation uses a uniform grid of bins, each listing the balls whose bounding box overlaps
//! it (compressed-row storage), so a lookup touches only nearby balls. Voxelisation into a
//! [`DensityGrid`] runs over z-slices in parallel with rayon.

use super::grid::{checked_count, checked_voxel_count, DensityGrid, MAX_VOXELS};
use super::wyvill;
use crate::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Most metaballs accepted in one field.
pub const MAX_BALLS: usize = 1_000_000;
/// Largest accepted |coordinate| of a ball centre, metres.
pub const MAX_COORDINATE_M: f64 = 1.0e8;
/// Largest accepted effective radius, metres.
pub const MAX_RADIUS_M: f64 = 1.0e7;
/// Largest accepted centre density.
pub const MAX_DENSITY: f64 = 1.0e6;
/// Most bins in the acceleration grid.
const MAX_BINS: u64 = 1 << 21;
/// Most (bin, ball) references in the acceleration grid.
const MAX_BIN_REFS: u64 = 1 << 25;

/// One metaball: centre, effective radius and density at the centre (Nishita & Dobashi 2001, eq 3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Metaball {
    /// Centre `C_j`, metres (x, y, z; z up).
    pub centre_m: DVec3,
    /// Effective radius `R_j`, metres (> 0); the field is zero beyond it.
    pub radius_m: f64,
    /// Density `q_j` at the centre (dimensionless, >= 0; scaled by the medium's extinction).
    pub density: f64,
}

/// Checks every ball (finite, in range) and the count, naming the offending entry.
pub fn validate_balls(balls: &[Metaball]) -> Result<()> {
    if balls.is_empty() {
        return Err(Error::invalid(
            "balls",
            "must contain at least one metaball",
        ));
    }
    if balls.len() > MAX_BALLS {
        return Err(Error::too_large(
            "balls",
            format!("{} metaballs", balls.len()),
            MAX_BALLS,
        ));
    }
    for (i, b) in balls.iter().enumerate() {
        if !(b.centre_m.is_finite() && b.centre_m.abs().max_element() <= MAX_COORDINATE_M) {
            return Err(Error::out_of_range(
                &format!("balls[{i}].centre_m"),
                b.centre_m,
                format!("finite coordinates within ±{MAX_COORDINATE_M} m"),
            ));
        }
        if !(b.radius_m.is_finite() && b.radius_m > 0.0 && b.radius_m <= MAX_RADIUS_M) {
            return Err(Error::out_of_range(
                &format!("balls[{i}].radius_m"),
                b.radius_m,
                format!("0 < radius_m <= {MAX_RADIUS_M}"),
            ));
        }
        if !(b.density.is_finite() && b.density >= 0.0 && b.density <= MAX_DENSITY) {
            return Err(Error::out_of_range(
                &format!("balls[{i}].density"),
                b.density,
                format!("0 <= density <= {MAX_DENSITY}"),
            ));
        }
    }
    Ok(())
}

/// Density at `p` by summing over every ball (Nishita & Dobashi 2001, eq 3); the reference for the binned
/// evaluator and the baseline in benchmarks.
pub fn density_brute_force(balls: &[Metaball], p: DVec3) -> f64 {
    balls
        .iter()
        .map(|b| b.density * wyvill::h(p.distance(b.centre_m), b.radius_m))
        .sum()
}

/// Ball data packed for the inner loop.
#[derive(Debug, Clone, Copy)]
struct Packed {
    centre: DVec3,
    inv_r2: f64,
    density: f64,
    radius: f64,
}

/// A validated set of metaballs with a bin grid for fast evaluation.
#[derive(Debug, Clone)]
pub struct MetaballField {
    balls: Vec<Metaball>,
    packed: Vec<Packed>,
    min_m: DVec3,
    max_m: DVec3,
    bin_origin_m: DVec3,
    bin_size_m: f64,
    bin_dims: [usize; 3],
    /// `bin_start[b]..bin_start[b + 1]` indexes `bin_balls` for bin `b`.
    bin_start: Vec<u32>,
    bin_balls: Vec<u32>,
}

impl MetaballField {
    /// Validates the balls and builds the bin grid (bin edge about twice the mean radius,
    /// enlarged until the grid and its references stay within fixed memory bounds).
    pub fn new(balls: Vec<Metaball>) -> Result<Self> {
        validate_balls(&balls)?;
        let mut min_m = DVec3::splat(f64::INFINITY);
        let mut max_m = DVec3::splat(f64::NEG_INFINITY);
        for b in &balls {
            min_m = min_m.min(b.centre_m - b.radius_m);
            max_m = max_m.max(b.centre_m + b.radius_m);
        }
        let extent = max_m - min_m;
        let mean_radius = balls.iter().map(|b| b.radius_m).sum::<f64>() / balls.len() as f64;
        let mut bin_size_m = 2.0 * mean_radius;
        let (bin_dims, refs) = loop {
            let dims_f = (extent / bin_size_m).ceil().max(DVec3::ONE);
            let bins = dims_f.x * dims_f.y * dims_f.z;
            if bins <= MAX_BINS as f64 {
                let dims = [dims_f.x as usize, dims_f.y as usize, dims_f.z as usize];
                let refs = count_refs(&balls, min_m, bin_size_m, dims);
                if refs <= MAX_BIN_REFS {
                    break (dims, refs);
                }
            }
            bin_size_m *= 1.5;
        };
        let bin_count = bin_dims[0] * bin_dims[1] * bin_dims[2];
        let mut counts = vec![0u32; bin_count + 1];
        for_each_bin(&balls, min_m, bin_size_m, bin_dims, |_, bin| {
            counts[bin] += 1
        });
        let mut bin_start = Vec::with_capacity(bin_count + 1);
        let mut acc = 0u32;
        for c in &counts[..bin_count] {
            bin_start.push(acc);
            acc += c;
        }
        bin_start.push(acc);
        debug_assert_eq!(acc as u64, refs);
        let mut fill = bin_start.clone();
        let mut bin_balls = vec![0u32; acc as usize];
        for_each_bin(&balls, min_m, bin_size_m, bin_dims, |i, bin| {
            bin_balls[fill[bin] as usize] = i as u32;
            fill[bin] += 1;
        });
        let packed = balls
            .iter()
            .map(|b| Packed {
                centre: b.centre_m,
                inv_r2: 1.0 / (b.radius_m * b.radius_m),
                density: b.density,
                radius: b.radius_m,
            })
            .collect();
        Ok(Self {
            balls,
            packed,
            min_m,
            max_m,
            bin_origin_m: min_m,
            bin_size_m,
            bin_dims,
            bin_start,
            bin_balls,
        })
    }

    /// The balls, in input order.
    pub fn balls(&self) -> &[Metaball] {
        &self.balls
    }

    /// Bounding box of the support of the field (union of the balls' boxes), metres.
    pub fn bounds_m(&self) -> (DVec3, DVec3) {
        (self.min_m, self.max_m)
    }

    fn bin_of(&self, p: DVec3) -> Option<usize> {
        let l = (p - self.bin_origin_m) / self.bin_size_m;
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let v = l[a];
            if !(v >= 0.0 && v <= self.bin_dims[a] as f64) {
                return None;
            }
            idx[a] = (v as usize).min(self.bin_dims[a] - 1);
        }
        Some((idx[2] * self.bin_dims[1] + idx[1]) * self.bin_dims[0] + idx[0])
    }

    fn balls_near(&self, p: DVec3) -> impl Iterator<Item = &Packed> + '_ {
        let range = match self.bin_of(p) {
            Some(b) => self.bin_start[b] as usize..self.bin_start[b + 1] as usize,
            None => 0..0,
        };
        self.bin_balls[range]
            .iter()
            .map(move |&i| &self.packed[i as usize])
    }

    /// Density at `p` (Nishita & Dobashi 2001, eq 3), from the balls in `p`'s bin.
    pub fn density(&self, p: DVec3) -> f64 {
        let mut sum = 0.0;
        for b in self.balls_near(p) {
            let a2 = (p - b.centre).length_squared() * b.inv_r2;
            if a2 < 1.0 {
                sum += b.density * wyvill::h_of_a2(a2);
            }
        }
        sum
    }

    /// Gradient of the density at `p`, per metre (points towards denser cloud).
    pub fn gradient(&self, p: DVec3) -> DVec3 {
        let mut g = DVec3::ZERO;
        for b in self.balls_near(p) {
            let d = p - b.centre;
            let r = d.length();
            if r > 0.0 && r < b.radius {
                g += d * (b.density * wyvill::dh_dr(r, b.radius) / r);
            }
        }
        g
    }

    /// Voxelises the field over its support plus `margin_m` on every side, at voxel edge
    /// `voxel_size_m`, centring the box on the support. Validates the voxel count first.
    pub fn voxelize(&self, voxel_size_m: f64, margin_m: f64) -> Result<DensityGrid> {
        self.voxelize_within(voxel_size_m, margin_m, MAX_VOXELS)
    }

    /// [`Self::voxelize`], refusing a grid of more than `max_voxels` voxels (too large on `dims`)
    /// before it is allocated.
    pub fn voxelize_within(
        &self,
        voxel_size_m: f64,
        margin_m: f64,
        max_voxels: usize,
    ) -> Result<DensityGrid> {
        self.voxelize_within_unless(voxel_size_m, margin_m, max_voxels, &|| false)
    }

    /// [`Self::voxelize_within`], stopped with [`Error::Cancelled`] once `cancelled` returns true
    /// (asked before every z-slice).
    pub fn voxelize_within_unless(
        &self,
        voxel_size_m: f64,
        margin_m: f64,
        max_voxels: usize,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<DensityGrid> {
        if !(margin_m.is_finite() && margin_m >= 0.0) {
            return Err(Error::out_of_range(
                "margin_m",
                margin_m,
                "a finite value >= 0",
            ));
        }
        let (lo, hi) = (self.min_m - margin_m, self.max_m + margin_m);
        let (dims, origin_m) = box_dims(lo, hi, voxel_size_m)?;
        checked_count(dims, max_voxels, "voxels")?;
        DensityGrid::from_fn_unless(
            dims,
            voxel_size_m,
            origin_m,
            |p| self.density(p) as f32,
            cancelled,
        )
    }

    /// Voxelises the field into a given box (cell-centred samples), in parallel over z-slices.
    pub fn voxelize_box(
        &self,
        dims: [usize; 3],
        voxel_size_m: f64,
        origin_m: DVec3,
    ) -> Result<DensityGrid> {
        DensityGrid::from_fn(dims, voxel_size_m, origin_m, |p| self.density(p) as f32)
    }
}

/// Dimensions and origin of a grid of edge `voxel_size_m` covering `[lo, hi]`, centred on it;
/// refuses oversized grids before anything is allocated.
pub fn box_dims(lo: DVec3, hi: DVec3, voxel_size_m: f64) -> Result<([usize; 3], DVec3)> {
    if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
        return Err(Error::out_of_range(
            "voxel_size_m",
            voxel_size_m,
            "a finite value > 0",
        ));
    }
    let extent = hi - lo;
    let dims_f = (extent / voxel_size_m).ceil().max(DVec3::ONE);
    if !(dims_f.is_finite() && dims_f.x * dims_f.y * dims_f.z <= MAX_VOXELS as f64) {
        return Err(Error::too_large(
            "voxel_size_m",
            format!(
                "{voxel_size_m} m over a {:.0} × {:.0} × {:.0} m box needs {:.3e} voxels",
                extent.x,
                extent.y,
                extent.z,
                dims_f.x * dims_f.y * dims_f.z
            ),
            format!("{MAX_VOXELS} voxels"),
        ));
    }
    let dims = [dims_f.x as usize, dims_f.y as usize, dims_f.z as usize];
    checked_voxel_count(dims)?;
    let origin_m = lo - (dims_f * voxel_size_m - extent) * 0.5;
    Ok((dims, origin_m))
}

/// Bin index range `[lo, hi]` along each axis covered by a ball's bounding box.
fn bin_range(b: &Metaball, origin: DVec3, size: f64, dims: [usize; 3]) -> [[usize; 2]; 3] {
    let lo = ((b.centre_m - b.radius_m - origin) / size).floor();
    let hi = ((b.centre_m + b.radius_m - origin) / size).floor();
    let mut r = [[0usize; 2]; 3];
    for a in 0..3 {
        let max = (dims[a] - 1) as f64;
        r[a] = [
            lo[a].clamp(0.0, max) as usize,
            hi[a].clamp(0.0, max) as usize,
        ];
    }
    r
}

fn count_refs(balls: &[Metaball], origin: DVec3, size: f64, dims: [usize; 3]) -> u64 {
    balls
        .iter()
        .map(|b| {
            let r = bin_range(b, origin, size, dims);
            r.iter().map(|[l, h]| (h - l + 1) as u64).product::<u64>()
        })
        .fold(0u64, |a, c| a.saturating_add(c))
}

fn for_each_bin(
    balls: &[Metaball],
    origin: DVec3,
    size: f64,
    dims: [usize; 3],
    mut f: impl FnMut(usize, usize),
) {
    for (i, b) in balls.iter().enumerate() {
        let r = bin_range(b, origin, size, dims);
        for z in r[2][0]..=r[2][1] {
            for y in r[1][0]..=r[1][1] {
                for x in r[0][0]..=r[0][1] {
                    f(i, (z * dims[1] + y) * dims[0] + x);
                }
            }
        }
    }
}
