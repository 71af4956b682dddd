//! The sun's once-scattered light, transported in the true medium.
//!
//! The δ-M scaled transport (module `multiple`) counts a scattering within the truncated peak as
//! no scattering (Wiscombe 1977): the sun's beam reaches its first smooth scattering collimated,
//! and the once-scattered light L*₁ flies on undeflected. The true peak is not a δ (most of it
//! within 25°, reaching 50.7° for g = 0.85): it spreads the beam before its first smooth
//! scattering and the once-scattered light after it, as Goudsmit & Saunderson (1940) describe for
//! the direct beam (`peak`).
//!
//! Here the sun's photons fly through the true medium (σ_t, ω, the true phase function p), every
//! collision classed as within the peak r⁺ = max(p − (1 − f)·HG(g*), 0) with probability r⁺/p
//! (the direction drawn from p and kept) or smooth. Their tracks after exactly one smooth
//! scattering are scored in real spherical harmonics to the field's order (the track-length
//! estimator, as the field's) per unit sun irradiance, and the photons end at their second
//! smooth scattering. The field tallies its own L*₁ (its sun photons' tracks between their first
//! and second scattering) apart too; in the cloud's interior the source
//! Σ_l Σ_m (k_l·E_sun·L₁,lm − p*_l·L*₁,lm) Y_lm(−d) is added to the field's: the field's own
//! once-scattered light seen through its δ-M phase series p*_l taken out, the true medium's seen
//! through k_l. The view scattering of light scattered once smoothly is itself smooth, with the
//! kernel p − r⁺ = min(p, (1 − f)·HG(g*)); its Legendre moments κ_l (per 1 − f; g 0.85: 0.964,
//! 0.657, 0.435, 0.283) exceed the δ-M moments (1, 0.654, 0.360, 0.110) at l = 2, 3. Truncated at
//! order 3, a once-scattered lobe seen through p*_l reads 7–33 % high 66° from the sun and
//! through κ_l 4–24 % low 98° from it (lobes of mean cosine 0.55–0.8 against the whole series);
//! k_l = (p*_l + κ_l)/2 halves both (against Mitsuba 3, docs/frames.md). At a voxel seen through
//! the cloud's face the field is kept whole: its build-up below the face (module `face`, the
//! formal solution of Chandrasekhar 1960 §1.8) models the once-scattered light's depth profile
//! there. The change is evaluated per coarse
//! cell towards the camera and interpolated to the voxels.

use super::{real_sh, Coarse, DdaStart, MsField, Photon, Truncation};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use skybake_physics::phase::{orthonormal_basis, Phase};
use std::f64::consts::PI;

/// Angular order of the once-scattered light: the field's (a tally to order 8 seen through the
/// Legendre moments of p − r⁺ took the back-lit case 22° from the sun to +2.3 % bias against
/// Mitsuba 3, docs/frames.md).
pub const ONCE_ORDER: usize = 3;
/// Harmonics per wavelength group, (L + 1)².
pub const ONCE_MOMENTS: usize = (ONCE_ORDER + 1) * (ONCE_ORDER + 1);
/// The field's sun photons per photon traced here (half as many took the side-lit thin Mitsuba
/// cloud's block NRMSE from 3.4 to 4.7 %, docs/frames.md).
pub const SUN_PHOTONS_PER_PHOTON: usize = 1;
/// A photon's first collision is forced onto its line (the forced collision, e.g. Lux &
/// Koblinger 1991, "Monte Carlo particle transport methods") where the line's true optical
/// depth is below this: every photon that crosses thin cloud scatters there, at the weight of
/// the chance that it would (photons passing a thin cloud unscattered scored nothing). On the
/// thin side-lit Mitsuba 3 cloud each block's spread between 16 photon seeds 2.59 → 1.92 %
/// (docs/frames.md). Above it the line is not followed further and the first flight is drawn as
/// any other (the photon passes with probability below e^{−2}): either way unbiased. 2 instead
/// of 4: the same spread in every case measured (8 seeds), 1–2 % less CPU on the sunlit frames.
const FORCE_DEPTH: f64 = 2.0;
/// A photon's collisions before its second smooth scattering are bounded by this (a chain of
/// peak scatterings in a conservative medium is geometric with ratio f⁺ ≈ 0.6).
const MAX_EVENTS: usize = 4096;

/// The sun's once-scattered light per coarse cell, and what replaces the field's with it.
pub struct OnceField {
    /// `[cell][group][ONCE_MOMENTS]`: L₁,lm per unit sun irradiance (until [`Self::finish`]).
    data: Vec<f32>,
    /// Groups (wavelengths of identical optics).
    groups: usize,
    /// Per wavelength: its group.
    group_of: Vec<usize>,
    /// Per wavelength: the sun's irradiance (W m⁻² nm⁻¹).
    irradiance: Vec<f64>,
    /// `[cell][λ][ONCE_MOMENTS]`: k_l·E_sun·L₁,lm − p*_l·L*₁,lm, the once-scattered light's
    /// source in place of the δ-M field's (L*₁ the field's tracks between the sun photons'
    /// first and second scattering; k_l module text), W m⁻² nm⁻¹.
    delta: Vec<f32>,
    n_l: usize,
    /// Per group: the Legendre moments κ_l of p − r⁺ per 1 − f ([`kernel_moments`]).
    kernel: Vec<[f64; ONCE_ORDER + 1]>,
}

impl OnceField {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.data.len() + self.delta.len())
    }
}

/// What [`trace`] needs of one wavelength group.
pub(super) struct Group<'a> {
    pub phase: &'a Phase,
    pub truncation: &'a Truncation,
    /// True extinction per density, m⁻¹.
    pub k: f64,
    /// Direction of the sun's light's travel.
    pub travel: DVec3,
    /// Photons.
    pub photons: usize,
    pub seed: u64,
}

/// Traces one group's sun photons through the true medium and returns L₁,lm per unit sun
/// irradiance, `[cell][ONCE_MOMENTS]` (module text). `lanes` accumulators, each a fixed,
/// interleaved set of chunks, summed in order: the same field on every machine.
pub(super) fn trace(coarse: &Coarse, g: &Group, lanes: usize) -> Vec<f64> {
    let lo = coarse.origin_m;
    let hi = coarse.hi();
    let grid_radius = 0.5 * (hi - lo).length() * 1.001;
    let cells = coarse.rho.len();
    // Accumulators for the cells that hold cloud only (the only ones scored).
    let len = coarse.cloud_cells * ONCE_MOMENTS;
    // The photons are launched over the disc of the sphere round the cells that hold cloud
    // (the centre of their box, the radius to the farthest corner of one): a photon beside it
    // meets no cloud and scores nothing. As many per unit area as over the grid's disc (the
    // same noise), so fewer where the grid's corners are empty.
    let [nx, ny, _] = coarse.dims;
    let corners = |c: usize| -> [DVec3; 2] {
        let ijk = DVec3::new(
            (c % nx) as f64,
            ((c / nx) % ny) as f64,
            (c / (nx * ny)) as f64,
        );
        let a = lo + ijk * coarse.cell_m;
        [a, a + coarse.cell_m]
    };
    let (mut bmin, mut bmax) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for c in (0..cells).filter(|&c| coarse.rho[c] > 0.0) {
        let [a, b] = corners(c);
        bmin = bmin.min(a);
        bmax = bmax.max(b);
    }
    if bmin.x > bmax.x {
        return vec![0.0; cells * ONCE_MOMENTS];
    }
    let centre = 0.5 * (bmin + bmax);
    let mut radius = 0.0f64;
    for c in (0..cells).filter(|&c| coarse.rho[c] > 0.0) {
        let [a, b] = corners(c);
        radius = radius.max((a - centre).abs().max((b - centre).abs()).length());
    }
    let radius = (radius * 1.001).min(grid_radius);
    let photons = ((g.photons as f64 * (radius / grid_radius).powi(2)).ceil() as usize).max(1);
    // Per photon, of unit irradiance over the disc.
    let w = [PI * radius * radius / photons as f64];
    let cell_volume = coarse.cell_m.x * coarse.cell_m.y * coarse.cell_m.z;
    let f = g.truncation.fraction;
    let hg = Phase::HenyeyGreenstein {
        g: g.truncation.g_scaled,
    };
    let (tb, bb) = orthonormal_basis(g.travel);
    let chunk = 4096usize;
    let chunks = photons.div_ceil(chunk);
    let lanes = lanes.clamp(1, chunks.max(1));
    let parts: Vec<Vec<f32>> = (0..lanes)
        .into_par_iter()
        .map(|lane| {
            let mut acc = crate::pages::take_f32(len);
            acc.fill(0.0);
            let mut ylm = [0.0; ONCE_MOMENTS];
            let mut w = w;
            for ci in (lane..chunks).step_by(lanes) {
                let mut rng = Pcg64::seed_from_u64(
                    g.seed ^ 0x0_4CE5_CA77 ^ (ci as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                for _ in ci * chunk..((ci + 1) * chunk).min(photons) {
                    w[0] = PI * radius * radius / photons as f64;
                    let r = radius * rng.random::<f64>().sqrt();
                    let phi = 2.0 * PI * rng.random::<f64>();
                    let mut ph = Photon {
                        pos: centre + (tb * phi.cos() + bb * phi.sin()) * r
                            // Outside the grid's box (the centre is within it).
                            - g.travel * (4.0 * grid_radius),
                        dir: g.travel,
                        scattered: false,
                    };
                    for event in 0..MAX_EVENTS {
                        let mut tau = -(1.0 - rng.random::<f64>()).ln();
                        if event == 0 {
                            // The first collision forced onto the line where it crosses
                            // less than FORCE_DEPTH: the depth drawn from the exponential
                            // truncated at the line's optical depth τ_l, the weight times
                            // 1 − e^{−τ_l}.
                            match line_depth(coarse, lo, hi, &ph, g.k, FORCE_DEPTH) {
                                Some(line) if line <= 0.0 => break,
                                Some(line) => {
                                    let p = -(-line).exp_m1();
                                    let u = -(-tau).exp_m1();
                                    tau = (-(-(u * p)).ln_1p()).min(line * (1.0 - 1e-9));
                                    w[0] *= p;
                                }
                                None => {}
                            }
                        }
                        if !fly(
                            coarse,
                            lo,
                            hi,
                            &mut ph,
                            tau,
                            g.k,
                            w[0] / cell_volume,
                            &mut acc,
                            &ylm,
                        ) {
                            break;
                        }
                        w[0] *= g.truncation.albedo;
                        if w[0] <= 0.0 {
                            break;
                        }
                        let nd = {
                            let mut more = || rng.random::<f64>();
                            let (u1, u2) = (more(), more());
                            g.phase.sample(ph.dir, u1, u2, &mut more).0
                        };
                        let mu = nd.dot(ph.dir);
                        // Within the peak with probability r⁺(μ)/p(μ).
                        let p = g.phase.eval(mu);
                        let peak = rng.random::<f64>() * p < (p - (1.0 - f) * hg.eval(mu)).max(0.0);
                        if !peak && ph.scattered {
                            break;
                        }
                        ph.dir = nd;
                        if !peak {
                            ph.scattered = true;
                        }
                        if ph.scattered {
                            real_sh(ph.dir, ONCE_ORDER, &mut ylm);
                        }
                    }
                }
            }
            acc
        })
        .collect();
    let mut out = vec![0.0; cells * ONCE_MOMENTS];
    for p in parts {
        for (o, c) in out.chunks_exact_mut(ONCE_MOMENTS).zip(&coarse.compact) {
            if *c == u32::MAX {
                continue;
            }
            let k = *c as usize * ONCE_MOMENTS;
            for (o, v) in o.iter_mut().zip(&p[k..k + ONCE_MOMENTS]) {
                *o += *v as f64;
            }
        }
        crate::pages::give_back_f32(p);
    }
    out
}

/// Optical depth of the line from `ph` along its direction through the cells that hold cloud
/// (extinction `k` per density), or `None` once it reaches `cap`.
fn line_depth(g: &Coarse, lo: DVec3, hi: DVec3, ph: &Photon, k: f64, cap: f64) -> Option<f64> {
    if !g.span.meets(ph.pos, ph.dir) {
        return Some(0.0);
    }
    let mut depth = 0.0;
    for (c, t, t_exit) in CellWalk::new(g, lo, hi, ph.pos, ph.dir)
        .into_iter()
        .flatten()
    {
        depth += k * g.rho[c] as f64 * (t_exit - t).max(0.0);
        if depth >= cap {
            return None;
        }
    }
    Some(depth)
}

/// The cells of the coarse grid a line crosses, in order (the DDA of Amanatides & Woo 1987):
/// each cell's index and the line's parameters where it enters and leaves the cell, until the
/// line leaves the grid or the cells that hold cloud (`Span`).
struct CellWalk<'a> {
    g: &'a Coarse,
    t: f64,
    t1: f64,
    cell: [i64; 3],
    step: [i64; 3],
    t_next: [f64; 3],
    t_delta: [f64; 3],
    done: bool,
}

impl<'a> CellWalk<'a> {
    /// The walk from `pos` along `d` (unit), or `None` where the line misses the grid's box.
    fn new(g: &'a Coarse, lo: DVec3, hi: DVec3, pos: DVec3, d: DVec3) -> Option<Self> {
        let (t0, t1) = crate::camera::box_interval(pos, d, lo, hi)?;
        let DdaStart {
            cell,
            step,
            t_next,
            t_delta,
        } = g.dda_start(lo, pos, d, t0);
        Some(Self {
            g,
            t: t0,
            t1,
            cell,
            step,
            t_next,
            t_delta,
            done: false,
        })
    }
}

impl Iterator for CellWalk<'_> {
    /// The cell's index, the line's parameter where it enters and where it leaves the cell.
    type Item = (usize, f64, f64);

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let (g, cell) = (self.g, &mut self.cell);
        let t_next = &self.t_next;
        let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
            0
        } else if t_next[1] <= t_next[2] {
            1
        } else {
            2
        };
        let t_exit = t_next[a].min(self.t1);
        let c = ((cell[2] as usize * g.dims[1]) + cell[1] as usize) * g.dims[0] + cell[0] as usize;
        let entry = self.t;
        self.t = t_exit;
        if t_exit >= self.t1 {
            self.done = true;
        } else {
            cell[a] += self.step[a];
            if cell[a] < 0 || cell[a] >= g.dims[a] as i64 || g.span.passed(a, cell[a], self.step[a])
            {
                self.done = true;
            } else {
                self.t_next[a] += self.t_delta[a];
            }
        }
        Some((c, entry, t_exit))
    }
}

/// Flies `ph` `tau` true optical depths through the coarse cells (extinction `k` per density)
/// and returns whether it collided within the grid (its place moved there) or left it. While
/// it has scattered (smoothly) it scores the track-length estimator `ws`·length·Y_lm (`ws` its
/// weight per cell volume) in the cells that hold cloud (the only ones read; `acc` in their
/// [`Coarse::compact`] order), in `f32`: the DDA of the field's photons (module `multiple`),
/// without its skins or look-ahead (a once photon's flights in the true medium cross a cell or
/// two).
#[allow(clippy::too_many_arguments)]
fn fly(
    g: &Coarse,
    lo: DVec3,
    hi: DVec3,
    ph: &mut Photon,
    tau_in: f64,
    k: f64,
    ws: f64,
    acc: &mut [f32],
    ylm: &[f64; ONCE_MOMENTS],
) -> bool {
    let mut tau = tau_in;
    // As the field's flights: a photon from outside whose line misses the cells that hold
    // cloud meets nothing, and a flight ends where it leaves them (`Span`).
    if !ph.scattered && !g.span.meets(ph.pos, ph.dir) {
        return false;
    }
    let Some(walk) = CellWalk::new(g, lo, hi, ph.pos, ph.dir) else {
        return false;
    };
    let d = ph.dir;
    for (c, t, t_exit) in walk {
        let rho = g.rho[c];
        let sigma = k * rho as f64;
        let len = (t_exit - t).max(0.0);
        let (used, hit) = if sigma * len >= tau && sigma > 0.0 {
            (tau / sigma, true)
        } else {
            (len, false)
        };
        if ph.scattered && used > 0.0 && rho > 0.0 {
            let s = ws * used;
            let b = g.compact[c] as usize * ONCE_MOMENTS;
            for (a, y) in acc[b..b + ONCE_MOMENTS].iter_mut().zip(ylm) {
                *a += (s * y) as f32;
            }
        }
        if hit {
            ph.pos += d * (t + used);
            return true;
        }
        tau -= sigma * len;
    }
    false
}

/// Legendre moments k_l = 2π ∫ (p − r⁺)(μ) P_l(μ) dμ / (1 − f), l ≤ [`ONCE_ORDER`], of the
/// kernel a smooth scattering stands for (p − r⁺ = min(p, (1 − f)·HG(g*))), by the midpoint rule.
fn kernel_moments(phase: &Phase, t: &Truncation) -> [f64; ONCE_ORDER + 1] {
    let hg = Phase::HenyeyGreenstein { g: t.g_scaled };
    let f = t.fraction;
    let n = 8192;
    let mut k = [0.0; ONCE_ORDER + 1];
    for i in 0..n {
        let mu = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
        let v = phase.eval(mu).min((1.0 - f) * hg.eval(mu)) * 2.0 * PI * 2.0 / n as f64;
        let (mut p0, mut p1) = (1.0, mu);
        k[0] += v;
        k[1] += v * mu;
        for (l, kl) in k.iter_mut().enumerate().skip(2) {
            let p2 = ((2 * l - 1) as f64 * mu * p1 - (l - 1) as f64 * p0) / l as f64;
            *kl += v * p2;
            p0 = p1;
            p1 = p2;
        }
    }
    k.map(|x| x / (1.0 - f))
}

impl OnceField {
    /// An empty field for `n_l` wavelengths in `groups` groups.
    pub(super) fn new(
        cells: usize,
        groups: usize,
        group_of: Vec<usize>,
        irradiance: Vec<f64>,
    ) -> Self {
        Self {
            data: vec![0.0; cells * groups * ONCE_MOMENTS],
            groups,
            group_of,
            irradiance,
            delta: Vec::new(),
            n_l: 0,
            kernel: vec![[0.0; ONCE_ORDER + 1]; groups],
        }
    }

    /// Stores group `gi`'s [`trace`] and its kernel's moments.
    pub(super) fn set_group(&mut self, gi: usize, g: &Group, acc: &[f64]) {
        self.kernel[gi] = kernel_moments(g.phase, g.truncation);
        for (c, cell) in acc.chunks_exact(ONCE_MOMENTS).enumerate() {
            let b = (c * self.groups + gi) * ONCE_MOMENTS;
            for (d, v) in self.data[b..b + ONCE_MOMENTS].iter_mut().zip(cell) {
                *d = *v as f32;
            }
        }
    }

    /// The source's coefficients per cell ([`Self::delta`]) from the tallies and the δ-M
    /// once-scattered light `dm` (`[cell][λ][moments]`, radiance moments of the field's order
    /// with the scaled phase moments `pm`), 0 in the cells without cloud (`rho`, which no
    /// voxel reads); the tallies are dropped.
    pub(super) fn finish(&mut self, dm: &[f32], moments: usize, pm: &[Vec<f64>], rho: &[f32]) {
        let n_l = self.group_of.len();
        let cells = self.data.len() / (self.groups * ONCE_MOMENTS);
        let mut delta = vec![0f32; cells * n_l * ONCE_MOMENTS];
        // Cells in parallel.
        delta
            .par_chunks_exact_mut(n_l * ONCE_MOMENTS)
            .enumerate()
            .for_each(|(c, out)| {
                if rho[c] <= 0.0 {
                    return;
                }
                for l in 0..n_l {
                    let b = (c * self.groups + self.group_of[l]) * ONCE_MOMENTS;
                    let v = &self.data[b..b + ONCE_MOMENTS];
                    let o = &mut out[l * ONCE_MOMENTS..(l + 1) * ONCE_MOMENTS];
                    let kern = &self.kernel[self.group_of[l]];
                    for (order, p) in pm[l].iter().enumerate().take(ONCE_ORDER + 1) {
                        // L₁'s view kernel: halfway between the δ-M moments and the true kernel's
                        // (module text).
                        let k = 0.5 * (p + kern[order]);
                        for m in order * order..(order + 1) * (order + 1) {
                            let d = dm[(c * n_l + l) * moments + m] as f64;
                            o[m] = (k * self.irradiance[l] * v[m] as f64 - p * d) as f32;
                        }
                    }
                }
            });
        self.delta = delta;
        self.n_l = n_l;
        self.data = Vec::new();
    }
}

impl MsField {
    /// The once-scattered light's source coefficients at `p` per wavelength, `[λ][ONCE_MOMENTS]`
    /// into `out` (zeros without it), interpolated as the field ([`Self::cell_weights`]): added
    /// to the field's J* towards `d` as Σ_lm out_lm Y_lm(−d) where the field is not seen
    /// through a face ([`Self::once_towards`]).
    pub fn once_coefficients(&self, p: DVec3, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let Some(o) = &self.once else {
            return;
        };
        let n = o.n_l * ONCE_MOMENTS;
        for (c, w) in self.cell_weights(p) {
            if w == 0.0 {
                continue;
            }
            for (x, v) in out.iter_mut().zip(&o.delta[c * n..(c + 1) * n]) {
                *x += w * *v as f64;
            }
        }
    }

    /// Whether the field holds the sun's once-scattered light apart.
    pub fn has_once(&self) -> bool {
        self.once.is_some()
    }

    /// Per coarse cell that holds cloud, the once-scattered light's change of the source
    /// towards a camera, Σ_lm (k_l·E_sun·L₁,lm − p*_l·L*₁,lm)·Y_lm(−d) with d = `view` of the
    /// cell's centre, `[cell][λ]` (empty without it): evaluated per cell, not per voxel, and
    /// interpolated by [`Self::once_add`].
    pub fn once_towards(&self, view: &(dyn Fn(DVec3) -> DVec3 + Sync)) -> Vec<f32> {
        let Some(o) = &self.once else {
            return Vec::new();
        };
        let n_l = o.n_l;
        let [nx, ny, _] = self.dims;
        let mut out = vec![0f32; self.rho.len() * n_l];
        out.par_chunks_mut(n_l)
            .zip(o.delta.par_chunks(n_l * ONCE_MOMENTS))
            .enumerate()
            .for_each(|(c, (out, v))| {
                if self.rho[c] <= 0.0 {
                    return;
                }
                let ijk = DVec3::new(
                    (c % nx) as f64,
                    ((c / nx) % ny) as f64,
                    (c / (nx * ny)) as f64,
                );
                let centre = self.origin_m + (ijk + DVec3::splat(0.5)) * self.cell_m;
                let mut ylm = [0.0; ONCE_MOMENTS];
                real_sh(-view(centre), ONCE_ORDER, &mut ylm);
                for (l, o) in out.iter_mut().enumerate() {
                    let v = &v[l * ONCE_MOMENTS..(l + 1) * ONCE_MOMENTS];
                    *o = v.iter().zip(&ylm).map(|(a, b)| *a as f64 * b).sum::<f64>() as f32;
                }
            });
        out
    }

    /// Adds [`Self::once_towards`]'s `cells` interpolated at `p` to the field's source `out`
    /// (kept ≥ 0); nothing where `cells` is empty.
    pub fn once_add(&self, cells: &[f32], p: DVec3, out: &mut [f64]) {
        if cells.is_empty() {
            return;
        }
        self.once_add_weighted(cells, &self.cell_weights(p), out);
    }

    /// [`Self::once_add`] with the cells' weights round the point given (`weights`, this
    /// field's [`Self::cell_weights`] there): the same values.
    pub fn once_add_weighted(&self, cells: &[f32], weights: &[(usize, f64); 8], out: &mut [f64]) {
        if cells.is_empty() {
            return;
        }
        let n_l = out.len();
        for &(c, w) in weights {
            if w == 0.0 {
                continue;
            }
            for (o, v) in out.iter_mut().zip(&cells[c * n_l..(c + 1) * n_l]) {
                *o += w * *v as f64;
            }
        }
        for o in out.iter_mut() {
            *o = o.max(0.0);
        }
    }
}
