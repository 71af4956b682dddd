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
//! each take their own D, `Prepared::peak_turned`).

use super::Prepared;
use crate::camera::box_interval;
use crate::peak::{PeakRow, PeakSpread};
use glam::DVec3;

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

impl Prepared<'_> {
    /// The gathering path behind the sample `x` of a ray along `d` (see the module's
    /// documentation): [`TURN_BINS`] look-ups of the density and of D_sun along
    /// b = normalize(s + d), up to the box's face. Empty where b is undefined (d = −s: the
    /// sun straight behind the camera, where the peak's part is 0).
    #[inline(never)]
    pub(super) fn turned_path(&self, x: DVec3, d: DVec3) -> TurnedPath {
        let mut out = TurnedPath {
            n: 0,
            mass: [0.0; TURN_BINS],
            path: [0.0; TURN_BINS],
        };
        let b = self.lighting.sun_dir + d;
        let len = b.length();
        if len < 1e-6 {
            return out;
        }
        let b = b / len;
        let vol = &self.lit.vol;
        let exit = box_interval(x, b, vol.lo, vol.hi).map_or(0.0, |(_, t1)| t1);
        let h = vol.grid.voxel_size_m;
        let (mut lo, mut width, mut cum) = (0.0, h, 0.0);
        for k in 0..TURN_BINS {
            if lo >= exit {
                break;
            }
            let hi = (lo + width).min(exit);
            let w = hi - lo;
            let y = x + b * (lo + 0.5 * w);
            // Trilinear within two voxels of x, the nearest voxel's record beyond (bins of two
            // voxels and more).
            let (rho, d_sun) = if k < 2 {
                (vol.rho(y), self.sun_path_at(y))
            } else {
                self.nearest_record(y)
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

    /// The density and D_sun of the voxel holding `y` (0 outside the grid).
    #[inline]
    fn nearest_record(&self, y: DVec3) -> (f64, f64) {
        let g = &*self.lit.vol.grid;
        let local = (y - g.origin_m) / g.voxel_size_m;
        let mut idx = 0usize;
        let mut stride = 1usize;
        for a in 0..3 {
            let v = local[a];
            if !(v >= 0.0 && v < g.dims[a] as f64) {
                return (0.0, 0.0);
            }
            idx += (v as usize).min(g.dims[a] - 1) * stride;
            stride *= g.dims[a];
        }
        let r = &self.vox[idx * self.stride..idx * self.stride + 2];
        (r[0] as f64, (r[1] as f64).powi(2))
    }

    /// The peak's part r⁺_eff/p of wavelength `l` (the second of [`PeakSpread::ratios`]) at
    /// λ = `lam_s` with its turned part gathered along `tp` instead of the straight line:
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
        tp: &TurnedPath,
        kt: f64,
        kp: f64,
    ) -> f64 {
        let now = p.last_in_peak(row, lam_s);
        let rate = self.lit.peak_rate[l];
        if rate <= 0.0 || kt <= 0.0 {
            return now;
        }
        let d_s = lam_s / (rate * kt);
        // Σ ρw·e^{−kp·path} relative to the straight line's e^{−kp·D} (the exponent bounded:
        // where the straight line is in deep shadow the product with it stays finite).
        let gathered: f64 = (0..tp.n)
            .map(|i| tp.mass[i] * (-kp * (tp.path[i] - d_s)).min(600.0).exp())
            .sum();
        let first = p.last_in_peak(row, 0.0);
        // ωf⁺·kt per unit λ·kt/rate (λ = ωf·kt·D·spread).
        let per_lambda = (1.0 - self.lit.first_extinction_scale[l]) / rate;
        let turned_at = |lam: f64, at: f64| at - (-lam * per_lambda).exp() * first;
        let lam_e = lam_s.max(1e-3);
        let slope = if lam_e > lam_s {
            turned_at(lam_e, p.last_in_peak(row, lam_e))
        } else {
            turned_at(lam_s, now)
        } / (lam_e / (rate * kt));
        (now + gathered * slope - turned_at(lam_s, now)).max(0.0)
    }
}
