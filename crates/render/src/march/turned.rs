//! The light scattered last within the truncated peak, gathered along the direction the peak
//! turned it, through the cloud's own density (the peak's part of the sun's single
//! scattering, `Prepared::march`).
//!
//! The peak's table (`peak`) spreads the sun's beam as if every peak scattering before the
//! last happened on the straight line from the sun to the sample: the beam that arrives has
//! crossed the sun's optical depth τ_s and its spread is the Goudsmit & Saunderson (1940)
//! distribution at ωf⁺τ_s. A photon the peak turns away from the sun's direction, though,
//! travels on along the turned direction, and where that direction is shallower than the
//! sun's (towards the horizontal under a low sun) it stays near the lit surface for longer
//! than the straight line allows: a view towards the sun at a grazing angle collects it. The
//! turned light arriving at a sample x is, at first order in the peak's scatterings,
//! ∫ σ(y) e^{−τ⁺_sun(y) − τ⁺(y, x)} dℓ over the points y = x + ℓb behind x along the mean
//! turned direction −b (a small-angle random walk that ends in a direction turned by Θ from
//! its start travels on average halfway between them: b = normalize(s + d) for the direction
//! s towards the sun and the view ray's d), where the straight line gives σ⁺·D·e^{−τ⁺_s}
//! (τ⁺ through σ_t⁺ = σ_t(1 − ωf⁺), as the spread beam is attenuated). The ratio of the two,
//! evaluated through the cloud's density and the sun's density integral D_sun at each y,
//! scales the turned part of the peak's table (all of it but the unturned e^{−ωf⁺τ_s}·r⁺/p).
//! A thin edge or a face the sun lights from behind has little density along b, so the
//! photons that leave are not gathered; in a laterally infinite slab the gain is largest
//! near the top, towards the horizontal. Only views within 90° of the sun (cos Θ > 0) gather:
//! beyond, r⁺ (which ends at 50.7° for g = 0.85) reaches them only through several peak
//! turns, and the straight line is kept. One path serves a whole thick step (its sub-steps
//! each take their own D, `Prepared::peak_turned`). Where the camera's true transmittance
//! before a step is below [`TURNED_SEEN`] the straight line is kept too: the step adds at most
//! that fraction of what it would at the cloud's face (measured: pixels within 0.2 %).

use super::Prepared;
use crate::peak::{PeakRow, PeakSpread};
use crate::volume::trilinear_stencil;
use glam::DVec3;

/// The camera's true transmittance below which a step keeps the straight line's peak part
/// (its turned light is not gathered): the step's share of the pixel is below this fraction
/// of what the same source would give at the cloud's face.
pub(super) const TURNED_SEEN: f64 = 5e-2;

/// Bins along −b of widths 1, 1, 2, 4, … voxels (64 voxels in all), each sampled at its
/// middle (trilinear in the first two, the nearest voxel beyond).
const TURN_BINS: usize = 7;

/// The gathering path of one sample: per bin, the density times its width (m) and the
/// density integral D_sun at its middle plus the density integral from x to it along b (m).
#[derive(Debug, Clone, Copy)]
pub(super) struct TurnedPath {
    n: usize,
    mass: [f64; TURN_BINS],
    path: [f64; TURN_BINS],
}

/// What the gathering paths of one view ray share: the mean turned direction b and what the
/// box's exit along it needs (per axis the face b leaves through and 1/b).
#[derive(Debug, Clone, Copy)]
pub(super) struct TurnedRay {
    b: DVec3,
    face: DVec3,
    inv: DVec3,
}

impl Prepared<'_> {
    /// The mean turned direction b = normalize(s + d) of a view ray along `d` (see the
    /// module's documentation; s where b is undefined, d = −s, where cos Θ = −1 and nothing is
    /// gathered).
    pub(super) fn turned_ray(&self, d: DVec3) -> TurnedRay {
        let b = self.lighting.sun_dir + d;
        let len = b.length();
        let b = if len < 1e-6 {
            self.lighting.sun_dir
        } else {
            b / len
        };
        let vol = &self.lit.vol;
        let mut face = DVec3::ZERO;
        let mut inv = DVec3::ZERO;
        for a in 0..3 {
            // An axis b does not move along never limits the path (`box_interval`).
            if b[a].abs() >= 1e-300 {
                inv[a] = 1.0 / b[a];
                face[a] = if b[a] > 0.0 { vol.hi[a] } else { vol.lo[a] };
            }
        }
        TurnedRay { b, face, inv }
    }

    /// The gathering path behind the sample `x` of a view ray (see the module's
    /// documentation): [`TURN_BINS`] look-ups of the density and of D_sun along the ray's b,
    /// up to the box's face.
    #[inline(never)]
    pub(super) fn turned_path(&self, x: DVec3, ray: &TurnedRay) -> TurnedPath {
        let mut out = TurnedPath {
            n: 0,
            mass: [0.0; TURN_BINS],
            path: [0.0; TURN_BINS],
        };
        let g = &*self.lit.vol.grid;
        let h = g.voxel_size_m;
        let inv_h = 1.0 / h;
        // The distance to the box's face along b (x is inside the box).
        let mut exit = f64::INFINITY;
        for a in 0..3 {
            if ray.inv[a] != 0.0 {
                exit = exit.min((ray.face[a] - x[a]) * ray.inv[a]);
            }
        }
        // Positions in voxel units from the grid's origin, b in voxels per voxel.
        let xl = (x - g.origin_m) * inv_h;
        let (mut lo, mut width, mut cum) = (0.0, h, 0.0);
        for k in 0..TURN_BINS {
            if lo >= exit {
                break;
            }
            let hi = (lo + width).min(exit);
            let w = hi - lo;
            let yl = xl + ray.b * ((lo + 0.5 * w) * inv_h);
            // Trilinear within two voxels of x, the nearest voxel's record beyond (bins of two
            // voxels and more).
            let (rho, d_sun) = if k < 2 {
                self.near_record(yl)
            } else {
                self.nearest_record(yl)
            };
            out.mass[k] = rho * w;
            out.path[k] = d_sun + cum + 0.5 * rho * w;
            cum += rho * w;
            out.n = k + 1;
            lo = hi;
            if k > 0 {
                width *= 2.0;
            }
        }
        out
    }

    /// The density and D_sun at `local` (voxel units from the grid's origin) trilinear, with
    /// the weights and order of operations of [`CloudVolume::rho`] and `Prepared::sun_path_at`,
    /// from one pass over the 8 corners' voxel records `[ρ, √D, …]`; both 0 where no corner
    /// holds density.
    ///
    /// [`CloudVolume::rho`]: crate::volume::CloudVolume::rho
    #[inline]
    fn near_record(&self, local: DVec3) -> (f64, f64) {
        let g = &*self.lit.vol.grid;
        let n = g.dims;
        let Some((base, di, f)) = trilinear_stencil(local, n) else {
            return (0.0, 0.0);
        };
        // No density at any corner: nothing gathered, D_sun never used (`nearest_record`).
        if self.lit.vol.empty_cells()[base] > 0 {
            return (0.0, 0.0);
        }
        let s = self.stride;
        let rec = |i: usize| {
            let r = &self.vox[i * s..i * s + 2];
            (r[0] as f64, r[1] as f64)
        };
        // Corners in the order of `CloudVolume::weights` (x fastest).
        let c = [
            rec(base),
            rec(base + di[0]),
            rec(base + di[1]),
            rec(base + di[1] + di[0]),
            rec(base + di[2]),
            rec(base + di[2] + di[0]),
            rec(base + di[2] + di[1]),
            rec(base + di[2] + di[1] + di[0]),
        ];
        // The density as `volume::sample` combines it (x, then y, then z; rounded to f32).
        let (gx0, gx1) = (1.0 - f[0], f[0]);
        let c00 = c[0].0 * gx0 + c[1].0 * gx1;
        let c10 = c[2].0 * gx0 + c[3].0 * gx1;
        let c01 = c[4].0 * gx0 + c[5].0 * gx1;
        let c11 = c[6].0 * gx0 + c[7].0 * gx1;
        let c0 = c00 * (1.0 - f[1]) + c10 * f[1];
        let c1 = c01 * (1.0 - f[1]) + c11 * f[1];
        let rho = ((c0 * (1.0 - f[2]) + c1 * f[2]) as f32) as f64;
        // √D as `Prepared::root_interpolated` sums it (the corners' weight products in order).
        let (gx, gy, gz) = ([gx0, gx1], [1.0 - f[1], f[1]], [1.0 - f[2], f[2]]);
        let mut r = 0.0;
        for (corner, v) in c.iter().enumerate() {
            let (bx, by, bz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            r += gx[bx] * gy[by] * gz[bz] * v.1;
        }
        // Beyond the outermost centres D is continued as `Prepared::sun_root_at` does it.
        let inner = (0..3).all(|a| n[a] < 2 || (local[a] >= 0.5 && local[a] <= n[a] as f64 - 0.5));
        if inner {
            (rho, r * r)
        } else {
            let y = g.origin_m + local * g.voxel_size_m;
            (rho, self.root_beyond_edge_centres(y, r).powi(2))
        }
    }

    /// The density and D_sun of the voxel holding `local` (voxel units from the grid's
    /// origin; both 0 outside the grid and where the density is 0).
    #[inline]
    fn nearest_record(&self, local: DVec3) -> (f64, f64) {
        let vol = &self.lit.vol;
        let g = &*vol.grid;
        let mut ijk = [0usize; 3];
        for a in 0..3 {
            let v = local[a];
            if !(v >= 0.0 && v < g.dims[a] as f64) {
                return (0.0, 0.0);
            }
            ijk[a] = (v as usize).min(g.dims[a] - 1);
        }
        // A voxel without density gathers nothing (its D_sun is never used): its record, far
        // from the step's and seldom in cache, is not read.
        if !vol.voxel_dense(ijk[0], ijk[1], ijk[2]) {
            return (0.0, 0.0);
        }
        let idx = (ijk[2] * g.dims[1] + ijk[1]) * g.dims[0] + ijk[0];
        let r = &self.vox[idx * self.stride..idx * self.stride + 2];
        (r[0] as f64, (r[1] as f64).powi(2))
    }

    /// The peak's part r⁺_eff/p of wavelength `l` (the second of [`PeakSpread::ratios`]) at
    /// λ = `lam_s` (`now`: the table's r⁺_eff/p there, [`PeakSpread::last_in_peak`]) with its
    /// turned part gathered along `tp` instead of the straight line:
    /// r⁺_eff(λ) + (G − 1)·T(λ), T = r⁺_eff(λ) − e^{−ωf⁺τ_s}·r⁺_eff(0) the turned part and G
    /// the gathered first order over the straight line's. `kt`, `kp` are the true extinction
    /// and σ_t⁺ per density. At a lit surface (D → 0) T/D is the table's slope at λ = 10⁻³.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    pub(super) fn peak_turned(
        &self,
        p: &PeakSpread,
        row: PeakRow,
        l: usize,
        lam_s: f64,
        now: f64,
        tp: &TurnedPath,
        kt: f64,
        kp: f64,
    ) -> f64 {
        let rate = self.lit.peak_rate[l];
        if rate <= 0.0 || kt <= 0.0 {
            return now;
        }
        let d_s = lam_s / (rate * kt);
        // Σ ρw·e^{−kp·path} relative to the straight line's e^{−kp·D} (the exponent bounded:
        // where the straight line is in deep shadow the product with it stays finite).
        // Bins without density add 0 whatever their path: their exponential is not taken.
        let gathered: f64 = (0..tp.n)
            .filter(|&i| tp.mass[i] != 0.0)
            .map(|i| tp.mass[i] * (-kp * (tp.path[i] - d_s)).min(600.0).exp())
            .sum();
        let first = p.last_in_peak(row, 0.0);
        // ωf⁺·kt per unit λ·kt/rate (λ = ωf·kt·D·spread).
        let per_lambda = (1.0 - self.lit.first_extinction_scale[l]) / rate;
        let turned_at = |lam: f64, at: f64| at - (-lam * per_lambda).exp() * first;
        let lam_e = lam_s.max(1e-3);
        let turned_now = turned_at(lam_s, now);
        let slope = if lam_e > lam_s {
            turned_at(lam_e, p.last_in_peak(row, lam_e))
        } else {
            turned_now
        } / (lam_e / (rate * kt));
        (now + gathered * slope - turned_now).max(0.0)
    }
}
