//! What the animator controls (Dobashi et al. 2000, §4.3, §4.5, §6): the height-dependent wind, ellipsoids that
//! set the vapour / activation / extinction probabilities, and obstacles (terrain) that cannot hold
//! cloud.

use super::random::quantise;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Largest accepted wind speed, cells per step.
pub const MAX_WIND_CELLS_PER_STEP: f64 = 4096.0;
/// Largest accepted number of ellipsoids.
pub const MAX_ELLIPSOIDS: usize = 10_000;
/// Largest accepted number of hills.
pub const MAX_HILLS: usize = 256;
/// Largest accepted total size of the ellipsoid stamps, in cells (6 bytes each).
pub const MAX_STAMP_CELLS: usize = 1 << 25;

/// One knot of the piecewise-linear wind profile v(z) (Dobashi et al. 2000, §4.3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindKnot {
    /// Height of the knot, in cells above the bottom of the simulation space.
    pub height_cells: f64,
    /// Wind speed along +x, cells per step (rounded to an integer per cell layer).
    pub velocity_cells_per_step: f64,
}

/// Integer wind velocity per cell layer, from a piecewise-linear profile (Dobashi et al. 2000, eqs 8–10).
#[derive(Debug, Clone, PartialEq)]
pub struct WindProfile {
    velocity: Vec<i32>,
}

impl WindProfile {
    /// Evaluates the profile at each layer's centre height `k + ½`, clamping beyond the end knots,
    /// and rounds to the nearest integer. No knots means calm.
    pub fn new(knots: &[WindKnot], nz: usize) -> Result<Self> {
        for w in knots.windows(2) {
            if w[1].height_cells.partial_cmp(&w[0].height_cells)
                != Some(std::cmp::Ordering::Greater)
            {
                return Err(Error::invalid(
                    "wind",
                    "knot heights must be strictly increasing",
                ));
            }
        }
        for k in knots {
            if !k.height_cells.is_finite() {
                return Err(Error::invalid("wind.height_cells", "must be finite"));
            }
            let v = k.velocity_cells_per_step;
            if !(v.is_finite() && v.abs() <= MAX_WIND_CELLS_PER_STEP) {
                return Err(Error::out_of_range(
                    "wind.velocity_cells_per_step",
                    k.velocity_cells_per_step,
                    format!("-{MAX_WIND_CELLS_PER_STEP}..={MAX_WIND_CELLS_PER_STEP}"),
                ));
            }
        }
        let velocity = (0..nz)
            .map(|k| piecewise_linear(knots, k as f64 + 0.5).round() as i32)
            .collect();
        Ok(Self { velocity })
    }

    /// Integer velocity v(z_k) of layer `k`, cells per step along +x.
    #[inline]
    pub fn velocity_cells(&self, k: usize) -> i32 {
        self.velocity[k]
    }
}

fn piecewise_linear(knots: &[WindKnot], z: f64) -> f64 {
    match knots {
        [] => 0.0,
        [only] => only.velocity_cells_per_step,
        _ => {
            let first = knots[0];
            let last = knots[knots.len() - 1];
            if z <= first.height_cells {
                return first.velocity_cells_per_step;
            }
            if z >= last.height_cells {
                return last.velocity_cells_per_step;
            }
            let i = knots.partition_point(|k| k.height_cells <= z);
            let (a, b) = (knots[i - 1], knots[i]);
            let t = (z - a.height_cells) / (b.height_cells - a.height_cells);
            a.velocity_cells_per_step + t * (b.velocity_cells_per_step - a.velocity_cells_per_step)
        }
    }
}

/// Probabilities of the three stochastic rules (Dobashi et al. 2000, eqs 5–7), each in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RuleProbabilities {
    /// Vapour supply probability p_hum (eq 6).
    pub hum: f64,
    /// Activation supply probability p_act (eq 7).
    pub act: f64,
    /// Cloud extinction probability p_ext (eq 5).
    pub ext: f64,
}

impl RuleProbabilities {
    fn validate(&self, field: &str) -> Result<()> {
        for (name, p) in [("hum", self.hum), ("act", self.act), ("ext", self.ext)] {
            if !(0.0..=1.0).contains(&p) {
                return Err(Error::out_of_range(&format!("{field}.{name}"), p, "0..=1"));
            }
        }
        Ok(())
    }
}

/// An air parcel controlling the probabilities (Dobashi et al. 2000, §4.5). Inside it, with ρ the normalised
/// ellipsoidal radius, p_hum = hum·(1−ρ²), p_act = act·(1−ρ²) and
/// p_ext = ext_centre + (ext_edge − ext_centre)·ρ²: vapour and activation highest at the centre,
/// extinction lowest there (the paper gives no profile; 1−ρ² is the simplest smooth one).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ellipsoid {
    /// Centre, in cells (cell (i, j, k) is centred at (i+½, j+½, k+½)).
    pub centre_cells: [f64; 3],
    /// Semi-axes along x, y, z, in cells (each > 0).
    pub semi_axes_cells: [f64; 3],
    /// Probabilities at the centre.
    pub centre: RuleProbabilities,
    /// Extinction probability at the edge.
    pub ext_edge: f64,
}

impl Ellipsoid {
    fn validate(&self, field: &str) -> Result<()> {
        if !self.centre_cells.iter().all(|c| c.is_finite()) {
            return Err(Error::invalid(
                &format!("{field}.centre_cells"),
                "must be finite",
            ));
        }
        if !self
            .semi_axes_cells
            .iter()
            .all(|a| a.is_finite() && *a > 0.0 && *a <= 1e6)
        {
            return Err(Error::out_of_range(
                &format!("{field}.semi_axes_cells"),
                format!("{:?}", self.semi_axes_cells),
                "each finite, > 0 and <= 1e6",
            ));
        }
        self.centre.validate(&format!("{field}.centre"))?;
        if !(0.0..=1.0).contains(&self.ext_edge) {
            return Err(Error::out_of_range(
                &format!("{field}.ext_edge"),
                self.ext_edge,
                "0..=1",
            ));
        }
        Ok(())
    }
}

/// Ellipsoids placed with uniform random numbers (Dobashi et al. 2000, §6, Fig. 8).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomEllipsoids {
    /// How many.
    pub count: usize,
    /// Smallest semi-axes, cells.
    pub semi_axes_min_cells: [f64; 3],
    /// Largest semi-axes, cells.
    pub semi_axes_max_cells: [f64; 3],
    /// Range of centre heights, cells (x and y are uniform over the whole space).
    pub centre_height_range_cells: [f64; 2],
    /// Probabilities at each centre.
    pub centre: RuleProbabilities,
    /// Extinction probability at the edges.
    pub ext_edge: f64,
}

/// Terrain that cannot hold cloud: cell (i, j, k) is solid when its centre height k+½ lies below the
/// terrain height at the column centre (Dobashi et al. 2000, §6, Fig. 9).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Obstacle {
    /// Heights in cells for every column, row-major `[y][x]` (`nx · ny` values).
    Heightmap { heights_cells: Vec<f64> },
    /// Gaussian hills: height(x, y) = max over hills of h·exp(−d²/(2σ²)).
    Hills { hills: Vec<Hill> },
}

/// One Gaussian hill of an [`Obstacle::Hills`] terrain.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hill {
    /// Summit position (x, y), cells.
    pub centre_cells: [f64; 2],
    /// Summit height, cells.
    pub height_cells: f64,
    /// Gaussian width σ, cells (> 0).
    pub sigma_cells: f64,
}

impl Obstacle {
    /// Terrain height (cells) of every column, row-major `[y][x]`.
    pub fn column_heights(&self, nx: usize, ny: usize) -> Result<Vec<f64>> {
        match self {
            Obstacle::Heightmap { heights_cells } => {
                if heights_cells.len() != nx * ny {
                    return Err(Error::invalid(
                        "obstacle.heights_cells",
                        format!("has {} values, nx·ny = {}", heights_cells.len(), nx * ny),
                    ));
                }
                if heights_cells.iter().any(|h| !h.is_finite()) {
                    return Err(Error::invalid("obstacle.heights_cells", "must be finite"));
                }
                Ok(heights_cells.clone())
            }
            Obstacle::Hills { hills } => {
                if hills.len() > MAX_HILLS {
                    return Err(Error::too_large(
                        "obstacle.hills",
                        format!("{} hills", hills.len()),
                        MAX_HILLS,
                    ));
                }
                for h in hills {
                    let ok = h.centre_cells.iter().all(|c| c.is_finite())
                        && h.height_cells.is_finite()
                        && h.sigma_cells.is_finite()
                        && h.sigma_cells > 0.0;
                    if !ok {
                        return Err(Error::invalid(
                            "obstacle.hills",
                            "centre and height must be finite and sigma_cells > 0",
                        ));
                    }
                }
                let mut out = vec![0.0; nx * ny];
                for y in 0..ny {
                    for x in 0..nx {
                        let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                        out[y * nx + x] = hills
                            .iter()
                            .map(|h| {
                                let d2 = (px - h.centre_cells[0]).powi(2)
                                    + (py - h.centre_cells[1]).powi(2);
                                h.height_cells * (-d2 / (2.0 * h.sigma_cells.powi(2))).exp()
                            })
                            .fold(0.0, f64::max);
                    }
                }
                Ok(out)
            }
        }
    }
}

/// Scratch for the levels of one row: per rule, one level per cell (64 per word), and which
/// words ellipsoids touch.
#[derive(Debug, Clone, PartialEq)]
pub struct RowLevels {
    /// `[hum, act, ext]` levels, index x (length 64 · words).
    pub levels: [Vec<u16>; 3],
    /// Per word: whether any ellipsoid touches it (its levels are then in `levels`).
    pub touched: Vec<bool>,
    places: Vec<(usize, usize, usize, usize)>,
}

impl RowLevels {
    /// Scratch for rows of `nx` cells.
    pub fn new(nx: usize) -> Self {
        let m = nx.div_ceil(64);
        Self {
            levels: std::array::from_fn(|_| vec![0; m * 64]),
            touched: vec![false; m],
            places: Vec::new(),
        }
    }
}

/// The probability fields: per cell, the quantised levels `int(p·n_p)` of p_hum, p_act and p_ext
/// (Dobashi et al. 2000, eqs A.4–A.6), from the background and the ellipsoids, which drift with the wind.
///
/// Ellipsoids move only along x and by whole cells, so each one's levels are computed once, as a
/// stamp of row segments, and pasted at its current integer offset. Quantisation is monotone, so
/// combining quantised stamps (max for hum and act, min for ext) equals quantising the combined
/// probabilities.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbabilityControl {
    dims: [usize; 3],
    background: [u16; 3],
    ellipsoids: Vec<Ellipsoid>,
    /// Whole cells each ellipsoid has drifted since its stamp was made.
    offsets: Vec<i64>,
    /// floor(initial centre x) of each ellipsoid, the stamps' reference.
    bases: Vec<i64>,
    /// Stamp segments: (ellipsoid, first x relative to floor(initial centre x), levels per rule).
    segments: Vec<(usize, i64, [Vec<u16>; 3])>,
    /// Per row `k·ny + j`: indices into `segments`.
    row_segments: Vec<Vec<usize>>,
}

/// Index of the three rules in level triples: `[HUM, ACT, EXT]`.
pub const HUM: usize = 0;
/// Activation rule index in level triples.
pub const ACT: usize = 1;
/// Extinction rule index in level triples.
pub const EXT: usize = 2;

impl ProbabilityControl {
    /// Validates and stores the background probabilities (outside every ellipsoid) and ellipsoids,
    /// quantised to `levels` steps.
    pub fn new(
        dims: [usize; 3],
        levels: usize,
        background: RuleProbabilities,
        ellipsoids: Vec<Ellipsoid>,
    ) -> Result<Self> {
        background.validate("background")?;
        if ellipsoids.len() > MAX_ELLIPSOIDS {
            return Err(Error::too_large(
                "ellipsoids",
                format!("{} ellipsoids", ellipsoids.len()),
                MAX_ELLIPSOIDS,
            ));
        }
        for (i, e) in ellipsoids.iter().enumerate() {
            e.validate(&format!("ellipsoids[{i}]"))?;
        }
        let [_, ny, nz] = dims;
        let q = |p: f64| quantise(p, levels);
        // Bound the stamps before building them: rows inside the space times the x extent.
        let mut stamp_cells = 0usize;
        for e in &ellipsoids {
            let [_, cy, cz] = e.centre_cells;
            let [ax, ay, az] = e.semi_axes_cells;
            let rows_j = ((cy + ay).ceil().clamp(0.0, ny as f64)
                - (cy - ay).floor().clamp(0.0, ny as f64)) as usize;
            let rows_k = ((cz + az).ceil().clamp(0.0, nz as f64)
                - (cz - az).floor().clamp(0.0, nz as f64)) as usize;
            let per_row = 2 * ax.ceil() as usize + 3;
            stamp_cells = stamp_cells.saturating_add(rows_j * rows_k * per_row);
        }
        if stamp_cells > MAX_STAMP_CELLS {
            return Err(Error::too_large(
                "ellipsoids",
                format!("the ellipsoids cover {stamp_cells} cells in total"),
                format!("{MAX_STAMP_CELLS} cells"),
            ));
        }
        let mut segments = Vec::new();
        let mut row_segments = vec![Vec::new(); ny * nz];
        for (ei, e) in ellipsoids.iter().enumerate() {
            let [cx, cy, cz] = e.centre_cells;
            let [ax, ay, az] = e.semi_axes_cells;
            let base = cx.floor();
            let frac = cx - base;
            let k_lo = (cz - az).floor().max(0.0) as usize;
            let k_hi = ((cz + az).ceil().max(0.0) as usize).min(nz);
            let j_lo = (cy - ay).floor().max(0.0) as usize;
            let j_hi = ((cy + ay).ceil().max(0.0) as usize).min(ny);
            // The stamp may cover at most the row width plus the ellipsoid on either side.
            let half = ax.ceil() as i64 + 1;
            let (rel_lo, rel_hi) = (-half, half);
            for k in k_lo..k_hi {
                for j in j_lo..j_hi {
                    let dy = (j as f64 + 0.5 - cy) / ay;
                    let dz = (k as f64 + 0.5 - cz) / az;
                    let qyz = dy * dy + dz * dz;
                    if qyz >= 1.0 {
                        continue;
                    }
                    let mut first = None;
                    let mut cells: [Vec<u16>; 3] = Default::default();
                    for rel in rel_lo..=rel_hi {
                        let dx = (rel as f64 + 0.5 - frac) / ax;
                        let rho2 = qyz + dx * dx;
                        if rho2 >= 1.0 {
                            if first.is_some() {
                                break;
                            }
                            continue;
                        }
                        first.get_or_insert(rel);
                        let w = 1.0 - rho2;
                        let pe = e.centre.ext + (e.ext_edge - e.centre.ext) * rho2;
                        cells[HUM].push(q(e.centre.hum * w));
                        cells[ACT].push(q(e.centre.act * w));
                        cells[EXT].push(q(pe));
                    }
                    if let Some(first) = first {
                        row_segments[k * ny + j].push(segments.len());
                        segments.push((ei, first, cells));
                    }
                }
            }
        }
        Ok(Self {
            dims,
            background: [q(background.hum), q(background.act), q(background.ext)],
            offsets: vec![0; ellipsoids.len()],
            bases: ellipsoids
                .iter()
                .map(|e| e.centre_cells[0].floor() as i64)
                .collect(),
            ellipsoids,
            segments,
            row_segments,
        })
    }

    /// The ellipsoids at their current positions.
    pub fn ellipsoids(&self) -> &[Ellipsoid] {
        &self.ellipsoids
    }

    /// Whether row (j, k) is touched by any ellipsoid (otherwise it is uniform background).
    pub fn row_has_ellipsoids(&self, j: usize, k: usize) -> bool {
        !self.row_segments[k * self.dims[1] + j].is_empty()
    }

    /// Moves each ellipsoid by the integer wind velocity at its centre layer (§4.5: "ellipsoids
    /// also move in the direction of the wind"). One that has left the space downwind re-enters
    /// upwind (a whole-cell jump of nx + 2·ceil(a)), so a long animation keeps its parcels.
    /// Returns whether any ellipsoid moved.
    pub fn advect(&mut self, wind: &WindProfile) -> bool {
        let nx = self.dims[0] as i64;
        let nz = self.dims[2];
        let mut moved = false;
        for (e, off) in self.ellipsoids.iter_mut().zip(&mut self.offsets) {
            let k = (e.centre_cells[2].floor().max(0.0) as usize).min(nz - 1);
            let mut v = wind.velocity_cells(k) as i64;
            let a = e.semi_axes_cells[0];
            let x = e.centre_cells[0] + v as f64;
            let span = nx + 2 * a.ceil() as i64;
            if v > 0 && x - a >= nx as f64 {
                v -= span;
            } else if v < 0 && x + a <= 0.0 {
                v += span;
            }
            if v != 0 {
                moved = true;
                *off += v;
                e.centre_cells[0] += v as f64;
            }
        }
        moved
    }

    /// The quantised background levels `[hum, act, ext]`.
    pub fn background_levels(&self) -> [u16; 3] {
        self.background
    }

    /// Levels of row (j, k) in the 64-cell words that ellipsoids touch, written per rule into
    /// `row.levels` (index x) with `row.touched[w]` set for those words; the other words are
    /// background and their levels are left stale.
    pub fn fill_row_words(&self, j: usize, k: usize, row: &mut RowLevels) {
        let nx = self.dims[0];
        let segs = &self.row_segments[k * self.dims[1] + j];
        row.touched.fill(false);
        row.places.clear();
        for &s in segs {
            let (e, first, cells) = &self.segments[s];
            let x0 = self.bases[*e] + self.offsets[*e] + first;
            let lo = x0.clamp(0, nx as i64) as usize;
            let hi = (x0 + cells[HUM].len() as i64).clamp(0, nx as i64) as usize;
            if lo < hi {
                row.places.push((s, lo, hi, (lo as i64 - x0) as usize));
            }
        }
        let [bh, ba, be] = self.background;
        let [hum, act, ext] = &mut row.levels;
        for &(_, lo, hi, _) in &row.places {
            for w in lo / 64..hi.div_ceil(64) {
                if !row.touched[w] {
                    row.touched[w] = true;
                    let cells = w * 64..w * 64 + 64;
                    hum[cells.clone()].fill(bh);
                    act[cells.clone()].fill(ba);
                    // Ext starts "unset" so it becomes the min over the containing ellipsoids.
                    ext[cells].fill(u16::MAX);
                }
            }
        }
        for &(s, lo, hi, off) in &row.places {
            let st = &self.segments[s].2;
            let n = hi - lo;
            for (o, l) in hum[lo..hi].iter_mut().zip(&st[HUM][off..off + n]) {
                *o = (*o).max(*l);
            }
            for (o, l) in act[lo..hi].iter_mut().zip(&st[ACT][off..off + n]) {
                *o = (*o).max(*l);
            }
            for (o, l) in ext[lo..hi].iter_mut().zip(&st[EXT][off..off + n]) {
                *o = (*o).min(*l);
            }
        }
        for (w, _) in row.touched.iter().enumerate().filter(|(_, t)| **t) {
            for e in &mut ext[w * 64..w * 64 + 64] {
                // Unconditional store of a select, so the loop vectorises.
                *e = if *e == u16::MAX { be } else { *e };
            }
        }
    }

    /// Levels `[hum, act, ext]` of every cell in row (j, k), written to `out[x]` (`nx` entries).
    pub fn fill_row(&self, j: usize, k: usize, out: &mut [[u16; 3]]) {
        let nx = self.dims[0];
        let mut row = RowLevels::new(nx);
        self.fill_row_words(j, k, &mut row);
        for (x, o) in out[..nx].iter_mut().enumerate() {
            *o = if row.touched[x / 64] {
                [row.levels[HUM][x], row.levels[ACT][x], row.levels[EXT][x]]
            } else {
                self.background
            };
        }
    }

    /// Levels `[hum, act, ext]` of cell (x, y, z) (the same values [`Self::fill_row`] writes).
    pub fn levels_at(&self, x: usize, y: usize, z: usize) -> [u16; 3] {
        let mut row = vec![[0u16; 3]; self.dims[0]];
        self.fill_row(y, z, &mut row);
        row[x]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn knot(h: f64, v: f64) -> WindKnot {
        WindKnot {
            height_cells: h,
            velocity_cells_per_step: v,
        }
    }

    #[test]
    fn wind_is_piecewise_linear_and_rounded() {
        let w = WindProfile::new(&[knot(0.0, 0.0), knot(10.0, 4.0)], 12).unwrap();
        // Layer 4 centre z = 4.5 → 1.8 → 2; clamped above the last knot.
        assert_eq!(w.velocity_cells(4), 2);
        assert_eq!(w.velocity_cells(0), 0);
        assert_eq!(w.velocity_cells(11), 4);
        assert!(WindProfile::new(&[knot(1.0, 0.0), knot(1.0, 1.0)], 3).is_err());
        let e = WindProfile::new(&[knot(0.0, 1e9)], 3).unwrap_err();
        assert_eq!(e.field(), "wind.velocity_cells_per_step");
    }

    #[test]
    fn ellipsoid_sets_centre_and_background_levels() {
        let bg = RuleProbabilities {
            hum: 0.0,
            act: 0.0,
            ext: 0.5,
        };
        let e = Ellipsoid {
            centre_cells: [8.5, 8.5, 4.5],
            semi_axes_cells: [4.0, 3.0, 2.0],
            centre: RuleProbabilities {
                hum: 0.1,
                act: 0.001,
                ext: 0.1,
            },
            ext_edge: 0.3,
        };
        let c = ProbabilityControl::new([20, 16, 8], 1000, bg, vec![e]).unwrap();
        assert_eq!(c.levels_at(8, 8, 4), [100, 1, 100]);
        assert_eq!(c.levels_at(0, 0, 0), [0, 0, 500]);
        // Two cells from the centre along x: ρ² = 1/4 → hum 0.075, ext 0.15.
        assert_eq!(c.levels_at(10, 8, 4), [75, 0, 150]);
    }

    #[test]
    fn hills_mark_columns_below_their_height() {
        let o = Obstacle::Hills {
            hills: vec![Hill {
                centre_cells: [2.5, 2.5],
                height_cells: 3.0,
                sigma_cells: 1.0,
            }],
        };
        let h = o.column_heights(5, 5).unwrap();
        assert_eq!(h[2 * 5 + 2], 3.0);
        assert!(h[0] < 0.1);
        let bad = Obstacle::Heightmap {
            heights_cells: vec![0.0; 3],
        };
        assert_eq!(
            bad.column_heights(2, 2).unwrap_err().field(),
            "obstacle.heights_cells"
        );
    }
}
