//! The field in the skin of optically thick cells: the first optical depth below each face
//! that borders thinner cloud or the grid's edge, tallied on its own.
//!
//! A view ray that ends in a cell of many optical depths sees the source of its first one
//! (the formal solution I = ∫ S(τ) e^{−τ} dτ, Chandrasekhar 1960 §1.8), but the cell's
//! track-length tally is the mean over all of them. Below a lit surface the diffuse radiance
//! is not that mean: in the diffusion picture it rises from the surface value (the Milne
//! problem's extrapolation length ≈ 0.71 transport mean free paths, L ∝ z + z₀) towards its
//! interior profile over a few transport lengths (Chandrasekhar 1960 §§ 47–48, Eddington's
//! approximation); where the cell holds only a few, its angular distribution near the face
//! (light leaving upwards) differs from the mean's too. The same photons' tracks scored over
//! the skin alone (the track length within [`SKIN_TAU`] of a surface face, divided by the
//! skin's volume) estimate that layer's angular moments without a model of the profile, and
//! their sum with the interior's is the cell's tally (the same energy). The march's thick
//! steps use them for the first [`SKIN_TAU`] of scaled optical depth along a view ray.

use super::{Coarse, MsField, MAX_ORDER};
use glam::DVec3;

/// Depth of the skin below a surface face, scaled optical depths σ*·ρ·z (at the wavelength of
/// the lowest scaled extinction; proportionally deeper at the others).
pub const SKIN_TAU: f64 = 1.0;

/// A face borders thinner cloud where the neighbouring cell's mean density is below this
/// fraction of the cell's (or the grid ends there).
const SURFACE_CONTRAST: f64 = 0.5;

/// Which coarse cells have a skin, and where: built once per photon pass.
pub(super) struct Skin {
    /// Per coarse cell: its index among the skin cells, or `u32::MAX`.
    index: Vec<u32>,
    /// Per skin cell: the box that is not skin (the cell shrunk by the skin's depth on its
    /// surface faces), m.
    inner: Vec<[DVec3; 2]>,
    /// Per skin cell: 1 / the skin's volume, 1/m³.
    inv_volume: Vec<f64>,
}

impl Skin {
    /// The skins of the cells whose voxels are optically thick (σ*·ρ·voxel ≥ `thick_voxel_tau`
    /// with the cell's mean density: only there does the march take thick steps), on every
    /// face that borders thinner cloud and along whose axis the cell holds at least two skin
    /// depths; `None` where no cell has one (the photon pass is then unchanged).
    pub(super) fn new(g: &Coarse, k_min: f64, voxel_m: f64, thick_voxel_tau: f64) -> Option<Self> {
        if !(k_min > 0.0 && k_min.is_finite()) {
            return None;
        }
        let [nx, ny, nz] = g.dims;
        let idx = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
        let mut index = vec![u32::MAX; g.rho.len()];
        let mut inner = Vec::new();
        let mut inv_volume = Vec::new();
        let cell_volume = g.cell_m.x * g.cell_m.y * g.cell_m.z;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let c = idx(x, y, z);
                    let rho = g.rho[c] as f64;
                    let sigma = k_min * rho;
                    if sigma * voxel_m < thick_voxel_tau {
                        continue;
                    }
                    let depth = SKIN_TAU / sigma;
                    let pos = [x, y, z];
                    let lo = g.origin_m + DVec3::new(x as f64, y as f64, z as f64) * g.cell_m;
                    let hi = lo + g.cell_m;
                    let (mut ilo, mut ihi) = (lo, hi);
                    let mut any = false;
                    for a in 0..3 {
                        if g.cell_m[a] < 2.0 * depth {
                            continue;
                        }
                        let thinner = |step: i64| {
                            let q = pos[a] as i64 + step;
                            if q < 0 || q >= g.dims[a] as i64 {
                                return true;
                            }
                            let mut n = pos;
                            n[a] = q as usize;
                            (g.rho[idx(n[0], n[1], n[2])] as f64) < SURFACE_CONTRAST * rho
                        };
                        if thinner(-1) {
                            ilo[a] += depth;
                            any = true;
                        }
                        if thinner(1) {
                            ihi[a] -= depth;
                            any = true;
                        }
                    }
                    if !any {
                        continue;
                    }
                    let inner_volume = (ihi - ilo)
                        .max(DVec3::ZERO)
                        .to_array()
                        .iter()
                        .product::<f64>();
                    index[c] = inner.len() as u32;
                    inner.push([ilo, ihi]);
                    inv_volume.push(1.0 / (cell_volume - inner_volume));
                }
            }
        }
        (!inner.is_empty()).then_some(Self {
            index,
            inner,
            inv_volume,
        })
    }

    /// Number of skin cells.
    pub(super) fn len(&self) -> usize {
        self.inner.len()
    }

    /// Scores a scattered photon's track in cell `c` (from `a` along `d`, length `len`, weights
    /// `w`, the harmonics `ylm` of its direction) over the part of it in the cell's skin, into
    /// the skin's accumulators after the first `cells` cells' ones in `acc` (those of the cells
    /// that hold cloud).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(super) fn score(
        &self,
        c: usize,
        cells: usize,
        a: DVec3,
        d: DVec3,
        len: f64,
        w: &[f64],
        acc: &mut [impl super::Tally],
        ylm: &[f64],
    ) {
        let s = self.index[c];
        if s == u32::MAX {
            return;
        }
        let s = s as usize;
        let [lo, hi] = self.inner[s];
        // The track's length inside the inner box (slab clipping).
        let (mut t0, mut t1) = (0.0f64, len);
        for k in 0..3 {
            if d[k] == 0.0 {
                if a[k] < lo[k] || a[k] > hi[k] {
                    t1 = -1.0;
                }
                continue;
            }
            let (u, v) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
            t0 = t0.max(u.min(v));
            t1 = t1.min(u.max(v));
        }
        let in_skin = len - (t1 - t0).max(0.0);
        if in_skin <= 0.0 {
            return;
        }
        let n = ylm.len();
        let ng = w.len();
        let f = in_skin * self.inv_volume[s];
        for (gi, wi) in w.iter().enumerate() {
            let b = ((cells + s) * ng + gi) * n;
            let ws = wi * f;
            for (x, y) in acc[b..b + n].iter_mut().zip(ylm) {
                x.add(ws * y);
            }
        }
    }
}

/// The skin tallies of a field: [`Skin`]'s cells and their harmonic coefficients.
pub struct SkinField {
    /// Per coarse cell: its index among the skin cells, or `u32::MAX`.
    pub(super) index: Vec<u32>,
    /// `[skin cell][λ][(L + 1)²]`, as [`MsField::data`].
    pub(super) data: Vec<f32>,
    /// Per wavelength: the skin's depth in scaled optical depths.
    pub(super) depth_tau: Vec<f64>,
}

impl SkinField {
    pub(super) fn new(skin: Skin, data: Vec<f32>, depth_tau: Vec<f64>) -> Self {
        Self {
            index: skin.index,
            data,
            depth_tau,
        }
    }

    pub(super) fn bytes(&self) -> usize {
        4 * (self.index.len() + self.data.len()) + 8 * self.depth_tau.len()
    }
}

impl MsField {
    /// Whether the field has skin tallies (some cell's voxels are optically thick).
    pub fn has_skin(&self) -> bool {
        self.skin.is_some()
    }

    /// The skin's depth at wavelength `l`, scaled optical depths (0 without skin tallies).
    pub fn skin_depth_tau(&self, l: usize) -> f64 {
        self.skin.as_ref().map_or(0.0, |s| s.depth_tau[l])
    }

    /// The coarse cells round `p` with their weights, or `None` where none of them has a skin.
    fn skin_cells(&self, p: DVec3) -> Option<(&SkinField, [(usize, f64); 8])> {
        let skin = self.skin.as_ref()?;
        let weights = self.cell_weights(p);
        if weights
            .iter()
            .all(|&(c, w)| w == 0.0 || skin.index[c] == u32::MAX)
        {
            return None;
        }
        Some((skin, weights))
    }

    /// Cell `c`'s coefficients at wavelength `l`: its skin tally where it has one, its whole
    /// tally otherwise.
    fn skin_or_cell<'a>(&'a self, skin: &'a SkinField, c: usize, l: usize) -> &'a [f32] {
        let n = self.moments;
        let (data, i) = match skin.index[c] {
            u32::MAX => (&self.data, c),
            s => (&skin.data, s as usize),
        };
        &data[(i * self.n_l + l) * n..(i * self.n_l + l + 1) * n]
    }

    /// [`MsField::inscatter`] with each cell's skin tally in place of its whole tally where
    /// it has one: the orders ≥ 2 a view ray sees in the first [`SKIN_TAU`] below a thick
    /// cell's surface. Returns false (and `out` untouched) where no cell round `p` has a skin.
    pub fn inscatter_skin(&self, p: DVec3, d: DVec3, out: &mut [f64]) -> bool {
        let Some((skin, weights)) = self.skin_cells(p) else {
            return false;
        };
        let mut ylm = [0.0; (MAX_ORDER + 1) * (MAX_ORDER + 1)];
        super::real_sh(-d, self.angular_order, &mut ylm);
        out.iter_mut().for_each(|o| *o = 0.0);
        for (c, w) in weights {
            if w == 0.0 {
                continue;
            }
            for (l, o) in out.iter_mut().enumerate() {
                let v = self.skin_or_cell(skin, c, l);
                let pl = &self.phase_moments[l];
                let mut sum = 0.0;
                for (order, p_l) in pl.iter().enumerate() {
                    for m in order * order..(order + 1) * (order + 1) {
                        sum += p_l * v[m] as f64 * ylm[m];
                    }
                }
                *o += w * sum;
            }
        }
        for o in out.iter_mut() {
            *o = o.max(0.0);
        }
        true
    }

    /// [`MsField::convolved_coefficients`] with each cell's skin tally in place of its whole
    /// tally where it has one: the moments whose reconstruction is [`Self::inscatter_skin`]
    /// (for exports of the field, `[λ·(L + 1)² + lm]`). Returns false (and `out` untouched)
    /// where no cell round `p` has a skin.
    pub fn convolved_skin_coefficients(&self, p: DVec3, out: &mut [f64]) -> bool {
        let Some((skin, weights)) = self.skin_cells(p) else {
            return false;
        };
        let n = self.moments;
        out.iter_mut().for_each(|o| *o = 0.0);
        for (c, w) in weights {
            if w == 0.0 {
                continue;
            }
            for l in 0..self.n_l {
                let v = self.skin_or_cell(skin, c, l);
                for (order, p_l) in self.phase_moments[l].iter().enumerate() {
                    for m in order * order..(order + 1) * (order + 1) {
                        out[l * n + m] += w * p_l * v[m] as f64;
                    }
                }
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 5×5×5 coarse grid of 10 m cells: density 1 in the 3×3×3 block at its centre, 0 round
    /// it, except the block's top layer, whose density is `top`.
    fn block(top: f32) -> Coarse {
        let n = 5;
        let mut rho = vec![0f32; n * n * n];
        for z in 1..4 {
            for y in 1..4 {
                for x in 1..4 {
                    rho[(z * n + y) * n + x] = if z == 3 { top } else { 1.0 };
                }
            }
        }
        Coarse::from_cells([n, n, n], DVec3::splat(10.0), DVec3::ZERO, rho)
    }

    fn cell(x: usize, y: usize, z: usize) -> usize {
        (z * 5 + y) * 5 + x
    }

    #[test]
    fn skins_are_on_the_faces_that_border_thinner_cloud() {
        // σ* = 0.5/m: 5 optical depths per cell, a skin of 2 m.
        let g = block(1.0);
        let skin = Skin::new(&g, 0.5, 10.0, 1.0).unwrap();
        // The block's centre borders no thinner cell; its 26 others do.
        assert_eq!(skin.index[cell(2, 2, 2)], u32::MAX);
        assert_eq!(skin.len(), 26);
        // The top face's centre cell: skin only above, 2 m deep.
        let s = skin.index[cell(2, 2, 3)] as usize;
        let [lo, hi] = skin.inner[s];
        assert_eq!((lo.z, hi.z), (30.0, 38.0));
        assert_eq!((lo.x, hi.x, lo.y, hi.y), (20.0, 30.0, 20.0, 30.0));
        assert!((1.0 / skin.inv_volume[s] - 200.0).abs() < 1e-9);
        // Voxels of less than the thick steps' optical depth: no skins at all.
        assert!(Skin::new(&g, 0.05, 10.0, 1.0).is_none());
        // Cells too thin for two skins along an axis get none on that axis: 1.5 optical
        // depths per cell (voxels of 1.5) and a skin of 1 leave every face without one.
        assert!(Skin::new(&g, 0.15, 10.0, 1.0).is_none());
        // A top layer of a third of the density: the layer below borders thinner cloud
        // above it, and the layer itself (σ*·10 m = 1.67) is too thin for skins.
        let g = block(1.0 / 3.0);
        let skin = Skin::new(&g, 0.5, 10.0, 1.0).unwrap();
        let s = skin.index[cell(2, 2, 2)] as usize;
        assert_eq!((skin.inner[s][0].z, skin.inner[s][1].z), (20.0, 28.0));
        assert_eq!(skin.index[cell(2, 2, 3)], u32::MAX);
    }

    /// The skin's score of a track is its length within the skin divided by the skin's volume:
    /// against the length measured by sampling points along random tracks and testing each
    /// against the faces' distances directly.
    #[test]
    fn a_track_scores_its_length_within_the_skin() {
        let g = block(1.0);
        let skin = Skin::new(&g, 0.5, 10.0, 1.0).unwrap();
        let cells = g.rho.len();
        // The corner cell (1, 1, 3): thinner cloud at x < 10, y < 10 and z > 40 (skin depth 2).
        let c = cell(1, 1, 3);
        let s = skin.index[c] as usize;
        let in_skin = |p: DVec3| p.x < 12.0 || p.y < 12.0 || p.z > 38.0;
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..200 {
            let a = DVec3::new(
                10.0 + 10.0 * next(),
                10.0 + 10.0 * next(),
                30.0 + 10.0 * next(),
            );
            let d = DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
            // Up to the cell's boundary.
            let mut len = f64::INFINITY;
            for k in 0..3 {
                let (lo, hi) = ([10.0, 10.0, 30.0][k], [20.0, 20.0, 40.0][k]);
                if d[k] > 0.0 {
                    len = len.min((hi - a[k]) / d[k]);
                } else if d[k] < 0.0 {
                    len = len.min((lo - a[k]) / d[k]);
                }
            }
            let mut acc = vec![0.0; (cells + skin.len()) * 2];
            skin.score(c, cells, a, d, len, &[2.0], &mut acc, &[1.0, 0.5]);
            let n = 200_000;
            let sampled = (0..n)
                .filter(|&i| in_skin(a + d * (len * (i as f64 + 0.5) / n as f64)))
                .count() as f64
                * len
                / n as f64;
            let scored = acc[(cells + s) * 2] / (2.0 * skin.inv_volume[s]);
            assert!(
                (scored - sampled).abs() < 1e-3 * len.max(1.0),
                "{scored} vs {sampled}"
            );
            assert!((acc[(cells + s) * 2 + 1] - 0.5 * acc[(cells + s) * 2]).abs() < 1e-12);
            // Nothing is scored outside the skin's accumulators.
            assert!(acc[..cells * 2].iter().all(|&x| x == 0.0));
        }
        // A cell without a skin scores nothing.
        let mut acc = vec![0.0; (cells + skin.len()) * 2];
        let centre = DVec3::splat(25.0);
        skin.score(
            cell(2, 2, 2),
            cells,
            centre,
            DVec3::Z,
            5.0,
            &[1.0],
            &mut acc,
            &[1.0, 1.0],
        );
        assert!(acc.iter().all(|&x| x == 0.0));
    }
}
