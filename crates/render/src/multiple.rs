//! All-order multiple scattering: a photon-transport estimate of the fluence
//! Φ and the net flux vector F of light that has scattered at least once in the cloud, on a
//! coarse copy of the grid (block means, piecewise constant), all orders, with sun, sky and
//! ground light as sources.
//!
//! Method (ours; measured against the path tracer in tests/render_*.rs):
//! - Photons enter from the sun (collimated, over the disc of the box's bounding sphere) and from
//!   every direction of the environment (sky above, ground light below), with exact free paths
//!   in the coarse medium (regular tracking cell by cell).
//! - The forward peak of the phase function is truncated (δ-M with two moments, the
//!   δ-Eddington/δ-HG scaling of Joseph, Wiscombe & Weinman 1976 and Wiscombe 1977): a fraction
//!   f = g₁² of every scattering is treated as no scattering at all, so the whole transport runs
//!   in a scaled medium σ_t* = σ_t(1 − ω f), ω* = ω(1 − f)/(1 − ω f) with a Henyey-Greenstein
//!   phase function of g* = (g₁ − f)/(1 − f) = g₁/(1 + g₁), the same transport optical
//!   thickness σ_t*(1 − ω* g*) = σ_t(1 − ω g₁), hence as cheap as similarity scaling in optically
//!   thick clouds (τ 10–100).
//! - Every track of a scattered photon scores its length times the real spherical harmonics
//!   Y_lm of its direction (l ≤ L, the track-length estimator of the radiance's harmonic
//!   coefficients, unbiased for the scaled medium; L = 3 at every quality, up to 4 possible).
//! - Absorption (ω* < 1) lowers the photon's weight at every collision (implicit capture) instead
//!   of ending the photon with probability 1 − ω*; a Russian roulette only once that weight is low
//!   ([`WEIGHT_FLOOR`]) and on very long paths.
//! - The in-scattered radiance of orders ≥ 2 towards a viewer looking along d is the
//!   reconstruction J* = Σ_l p*_l Σ_m L_lm Y_lm(−d) (the phase convolution exact in the harmonic
//!   basis up to L), clamped at 0; the final march attenuates it with the
//!   scaled extinction and weighs it with σ_s* = ω* σ_t*, while the single scattering keeps the
//!   true extinction and phase function: the TMS correction of Nakajima & Tanaka (1988, eq 13),
//!   as in DISORT. Measured: the untruncated P1 (or isotropic) reconstruction cannot represent the
//!   strongly forward-peaked orders 2–5 of g = 0.85 and overestimates side-scattered light by
//!   30 % (thick) to 180 % (thin cloud) against Mitsuba 3; with the truncation see README.

use super::lighting::{Hemisphere, Lighting};
use super::scene::Optics;
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use skybake_physics::cloud::DensityGrid;
use skybake_physics::phase::{orthonormal_basis, Phase};
use std::f64::consts::PI;

mod convolved;
mod face;
mod once;
mod skin;
pub use convolved::ConvolvedCells;
pub use face::{
    outward_profiles as face_outward_profiles, outward_ratio as face_outward_ratio,
    profiles as face_build_up, FaceQuadrature, SunAtVoxel, MU_NODES as FACE_MU_NODES,
    N_PHI as FACE_N_PHI, OUTWARD_MAX_DEPTH as FACE_OUTWARD_MAX_DEPTH,
};
pub use once::{OnceField, ONCE_MOMENTS, ONCE_ORDER};
pub use skin::{SkinField, SKIN_TAU};

/// Settings of the photon pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotonSettings {
    /// Photons from the sun; a frame without sky and ground light traces `env_photons` more of
    /// them (the environment's share of the budget).
    pub sun_photons: usize,
    /// Photons from the environment (sky and ground light); a frame whose sun gives no light
    /// traces `sun_photons` more of them (the sun's share of the budget).
    pub env_photons: usize,
    /// Largest coarse-grid dimension (blocks of whole voxels).
    pub max_coarse_dim: usize,
    /// Whether each axis's block of voxels is made smaller where it is wider than
    /// [`CELL_TRANSPORT_FRACTION`] of the transport mean free path (see [`Coarse::new`]); the
    /// frame planner turns it off where it coarsens the field on purpose.
    pub transport_cells: bool,
    /// Seed of the random streams.
    pub seed: u64,
    /// Angular order L of the field's spherical harmonics (0 isotropic, 1 fluence and flux, … 4).
    pub angular_order: usize,
    /// δ-M truncation of the forward peak, f = g₁^p with this p (2: δ-Eddington), with the TMS
    /// correction; 0: none, the true phase function throughout.
    pub truncation_power: f64,
    /// Spread of the truncated peak over the scaled sun beam, 0 to 1 (see `peak`).
    pub peak_spread: f64,
}

/// Φ and F on the coarse grid, per wavelength.
pub struct MsField {
    pub dims: [usize; 3],
    /// Coarse cell edges along x, y, z, m.
    pub cell_m: DVec3,
    pub origin_m: DVec3,
    pub n_l: usize,
    /// `[cell][λ][(L + 1)²]`: the radiance's real spherical-harmonic coefficients
    /// L_lm = ∫ L(ω) Y_lm(ω) dω up to the angular order L (W m⁻² nm⁻¹; L_00 = Φ/√(4π)).
    pub data: Vec<f32>,
    /// Legendre moments p*_l of the scaled phase function per wavelength, l = 0 … L (see
    /// [`scaled_moments`]).
    pub phase_moments: Vec<Vec<f64>>,
    /// σ_t*/σ_t = 1 − ω f per wavelength (1 without truncation).
    pub extinction_scale: Vec<f64>,
    /// ω* per wavelength.
    pub albedo_scaled: Vec<f64>,
    /// Mean density of each coarse cell (which cells [`MsField::inscatter`] interpolates
    /// between: those that hold cloud).
    rho: Vec<f32>,
    /// The tallies of optically thick cells' skins (see [`SkinField`]), where any cell has one.
    skin: Option<SkinField>,
    angular_order: usize,
    /// Coefficients per cell and wavelength, (L + 1)².
    moments: usize,
    /// The sun's once-scattered light in the true medium, which the field's tallies leave out
    /// (see [`once`]); `None` without δ-M truncation or sunlight.
    once: Option<OnceField>,
}

/// Largest scaled optical depth σ_t*·Δ (at the densest voxel round a step) over which one
/// march step is integrated as one piece; a thicker step is resolved in sub-steps of at most
/// this optical depth (`march::Prepared::thick_step`), and cells of voxels this thick get skin
/// tallies ([`skin`]). No step of the bench frame or of the Mitsuba 3 validation frames reaches
/// it (standard quality); draft's steps of 1.5 voxels through the cumulus in voxels of 50 m do
/// in places.
pub const THICK_STEP: f64 = 1.0;

/// Photon-pass accumulators: at most this many, fewer when one would be large, never fewer
/// than two (so two cores stay busy). Fixed, not the thread count, so the field is the same on
/// every machine.
const MAX_LANES: usize = 8;
/// Memory the accumulators of one wavelength group may take together, bytes (two lanes are
/// kept whatever their size: the scene limits bound it).
const LANE_BUDGET_BYTES: usize = 256 << 20;

/// Number of accumulator lanes for accumulators of `len` f64 values each.
fn accumulator_lanes(len: usize) -> usize {
    (LANE_BUDGET_BYTES / (len * 8).max(1)).clamp(2, MAX_LANES)
}

/// A coarse, piecewise-constant copy of the density grid: blocks of whole voxels, each axis
/// coarsened only as far as it needs to be (a thin slab keeps its vertical resolution).
struct Coarse {
    dims: [usize; 3],
    /// Cell edges along x, y, z, m.
    cell_m: DVec3,
    origin_m: DVec3,
    rho: Vec<f32>,
    /// The cells whose skins the photons' tracks are also scored in (see `skin`).
    skin: Option<skin::Skin>,
    /// The range of the cells that hold cloud.
    span: Span,
    /// Per cell: its index among the cells that hold cloud (their accumulators'), or
    /// `u32::MAX` for an empty cell (never scored).
    compact: Vec<u32>,
    /// Number of cells that hold cloud.
    cloud_cells: usize,
    /// Whether [`Coarse::new`] made an axis's cells smaller than `max_coarse_dim` gives (the
    /// transport mean free path's rule): the photon pass then traces [`REFINED_PHOTONS`]× the
    /// budget.
    refined: bool,
}

/// The cells that hold cloud: their index range per axis and the box round them. Outside it
/// the coarse density is 0, so a photon there does not collide, and its tracks would score
/// only empty cells, which no reconstruction reads: [`MsField::cell_weights`] gives an empty
/// cell no weight where a cell round the point holds cloud, as at every voxel within a voxel of
/// the cloud (the lit volume's mask). The photons' flights end where they leave it, and
/// score the cells that hold cloud only: the cells that hold cloud get the same scores in the
/// same order (the same field there).
#[derive(Debug, Clone, Copy)]
struct Span {
    /// Lowest and highest cell index per axis (lo > hi when no cell holds cloud).
    lo: [i64; 3],
    hi: [i64; 3],
    /// The box round those cells, m, widened by a hundredth of a cell.
    box_lo: DVec3,
    box_hi: DVec3,
}

impl Span {
    fn new(dims: [usize; 3], rho: &[f32], cell_m: DVec3, origin_m: DVec3) -> Self {
        let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
        for (c, &r) in rho.iter().enumerate() {
            if r <= 0.0 {
                continue;
            }
            let ijk = [
                c % dims[0],
                (c / dims[0]) % dims[1],
                c / (dims[0] * dims[1]),
            ];
            for a in 0..3 {
                lo[a] = lo[a].min(ijk[a] as i64);
                hi[a] = hi[a].max(ijk[a] as i64);
            }
        }
        let corner = |i: [i64; 3]| DVec3::new(i[0] as f64, i[1] as f64, i[2] as f64) * cell_m;
        let margin = 0.01 * cell_m;
        Self {
            lo,
            hi,
            box_lo: origin_m + corner(lo) - margin,
            box_hi: origin_m + corner(hi.map(|h| h.saturating_add(1))) + margin,
        }
    }

    /// Whether the line through `p` along `d` meets the box round the cells that hold cloud.
    fn meets(&self, p: DVec3, d: DVec3) -> bool {
        self.lo[0] <= self.hi[0]
            && super::camera::box_interval(p, d, self.box_lo, self.box_hi).is_some()
    }

    /// Whether a track that has stepped (`step` ±1) to cell index `i` along axis `a` has left
    /// the cells that hold cloud for good.
    #[inline(always)]
    fn passed(&self, a: usize, i: i64, step: i64) -> bool {
        (step > 0 && i > self.hi[a]) || (step < 0 && i < self.lo[a])
    }
}

/// Where the DDA of Amanatides & Woo (1987) starts a line through the coarse cells: the cell
/// it enters at parameter `t0`, the step per axis, the parameters of the next cell boundary per
/// axis and their spacing.
struct DdaStart {
    cell: [i64; 3],
    step: [i64; 3],
    t_next: [f64; 3],
    t_delta: [f64; 3],
}

impl Coarse {
    /// The DDA's start for the line `pos + t·d` (`d` unit) entering the box from `lo` at `t0`.
    #[inline(always)]
    fn dda_start(&self, lo: DVec3, pos: DVec3, d: DVec3, t0: f64) -> DdaStart {
        let p0 = pos + d * (t0 + 1e-9 * self.cell_m.min_element());
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        let mut t_next = [f64::INFINITY; 3];
        let mut t_delta = [f64::INFINITY; 3];
        for a in 0..3 {
            let h = self.cell_m[a];
            let local = (p0[a] - lo[a]) / h;
            cell[a] = (super::volume::floor(local) as i64).clamp(0, self.dims[a] as i64 - 1);
            if d[a] > 0.0 {
                step[a] = 1;
                t_next[a] = t0 + ((cell[a] + 1) as f64 * h + lo[a] - p0[a]) / d[a];
                t_delta[a] = h / d[a];
            } else if d[a] < 0.0 {
                step[a] = -1;
                t_next[a] = t0 + (cell[a] as f64 * h + lo[a] - p0[a]) / d[a];
                t_delta[a] = -h / d[a];
            }
        }
        DdaStart {
            cell,
            step,
            t_next,
            t_delta,
        }
    }

    /// The coarse grid of at most `max_dim` cells per axis (blocks of whole voxels). Where an
    /// axis's block is wider than [`CELL_TRANSPORT_FRACTION`] of `transport_m` (the transport
    /// mean free path at the cloud's mean density, [`transport_mean_free_path`]; `None`: kept)
    /// and a block of at least half its voxels would not be, the block becomes the widest such;
    /// where not even one voxel is within it (the voxels themselves too thick: the skins hold
    /// the lit surface there), the block is kept.
    fn new(grid: &DensityGrid, max_dim: usize, transport_m: Option<f64>) -> Self {
        let cap: [usize; 3] = std::array::from_fn(|a| grid.dims[a].div_ceil(max_dim.max(1)).max(1));
        let f: [usize; 3] = std::array::from_fn(|a| {
            let Some(tr) = transport_m else {
                return cap[a];
            };
            let fits = |f: usize, frac: f64| f as f64 * grid.voxel_size_m <= frac * tr;
            // Within 0.1 ℓ_tr where a block can be; else within ¼ ℓ_tr (the g 0.5 cloud's
            // 30 m voxels are 0.19 ℓ_tr); else kept.
            [CELL_TRANSPORT_FRACTION, CELL_TRANSPORT_FRACTION_COARSE]
                .into_iter()
                .find_map(|frac| (cap[a].div_ceil(2)..=cap[a]).rev().find(|&f| fits(f, frac)))
                .unwrap_or(cap[a])
        });
        let refined = f != cap;
        let dims: [usize; 3] = std::array::from_fn(|a| grid.dims[a].div_ceil(f[a]));
        let [nx, ny, nz] = grid.dims;
        // Each layer of cells sums its voxels in parallel (every cell's voxels added in the
        // grid's order, z, y, x, as one pass would).
        let layer = dims[0] * dims[1];
        let mut sum = vec![0f64; layer * dims[2]];
        let mut cnt = vec![0u32; sum.len()];
        sum.par_chunks_mut(layer)
            .zip(cnt.par_chunks_mut(layer))
            .enumerate()
            .for_each(|(cz, (sum, cnt))| {
                for z in cz * f[2]..((cz + 1) * f[2]).min(nz) {
                    for y in 0..ny {
                        let row = &grid.data[(z * ny + y) * nx..][..nx];
                        let cells = (y / f[1]) * dims[0];
                        for (cx, run) in row.chunks(f[0]).enumerate() {
                            let (s, c) = (&mut sum[cells + cx], &mut cnt[cells + cx]);
                            for &v in run {
                                *s += v as f64;
                            }
                            *c += run.len() as u32;
                        }
                    }
                }
            });
        // Cells past the grid's edge (when f does not divide it) keep the mean of the voxels
        // they cover: the coarse box is slightly larger than the grid's.
        let rho: Vec<f32> = sum
            .iter()
            .zip(&cnt)
            .map(|(s, &c)| if c > 0 { (s / c as f64) as f32 } else { 0.0 })
            .collect();
        let cell_m = DVec3::new(f[0] as f64, f[1] as f64, f[2] as f64) * grid.voxel_size_m;
        Self {
            refined,
            ..Self::from_cells(dims, cell_m, grid.origin_m, rho)
        }
    }

    /// The coarse grid of `dims` cells of edges `cell_m` from `origin_m` with densities `rho`
    /// (x fastest), without skins.
    fn from_cells(dims: [usize; 3], cell_m: DVec3, origin_m: DVec3, rho: Vec<f32>) -> Self {
        let mut cloud_cells = 0;
        let compact = rho
            .iter()
            .map(|&r| {
                if r > 0.0 {
                    cloud_cells += 1;
                    cloud_cells as u32 - 1
                } else {
                    u32::MAX
                }
            })
            .collect();
        Self {
            dims,
            cell_m,
            origin_m,
            span: Span::new(dims, &rho, cell_m, origin_m),
            rho,
            skin: None,
            compact,
            cloud_cells,
            refined: false,
        }
    }

    fn hi(&self) -> DVec3 {
        self.origin_m
            + DVec3::new(
                self.dims[0] as f64,
                self.dims[1] as f64,
                self.dims[2] as f64,
            ) * self.cell_m
    }
}

/// One photon's state.
struct Photon {
    pos: DVec3,
    dir: DVec3,
    scattered: bool,
}

impl MsField {
    /// Bytes held by the field's tables.
    pub fn bytes(&self) -> usize {
        4 * (self.data.len() + self.rho.len())
            + self.skin.as_ref().map_or(0, SkinField::bytes)
            + self.once.as_ref().map_or(0, OnceField::bytes)
    }

    /// Runs the photon pass for every group of wavelengths with identical optics; `cancel` is
    /// polled before every chunk of 4096 photons ([`crate::Error::Cancelled`]).
    pub fn compute(
        grid: &DensityGrid,
        optics: &Optics,
        lighting: &Lighting,
        s: &PhotonSettings,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> crate::Result<Self> {
        let cancelled = std::sync::atomic::AtomicBool::new(false);
        let mut coarse = Coarse::new(
            grid,
            s.max_coarse_dim,
            s.transport_cells
                .then(|| transport_mean_free_path(grid, optics)),
        );
        // Finer cells hold fewer of the photons' tracks each: the refined field traces more
        // photons (see [`REFINED_PHOTONS`]).
        let refined_settings;
        let s = if coarse.refined {
            refined_settings = PhotonSettings {
                sun_photons: s.sun_photons.saturating_mul(REFINED_PHOTONS),
                env_photons: s.env_photons.saturating_mul(REFINED_PHOTONS),
                ..*s
            };
            &refined_settings
        } else {
            s
        };
        let n_l = optics.albedo.len();
        let cells = coarse.rho.len();
        let order = s.angular_order.min(MAX_ORDER);
        let moments = (order + 1) * (order + 1);
        let mut data = vec![0f32; cells * n_l * moments];
        let truncation: Vec<Truncation> = optics
            .phase
            .iter()
            .zip(&optics.albedo)
            .map(|(p, &a)| Truncation::new(p.mean_cosine(), a, s.truncation_power))
            .collect();
        let (skin_cells, skin_depth) = skin_setup(&mut coarse, grid, optics, &truncation);
        // The δ-M once-scattered sunlight's part of `data` (cells only).
        let mut once_dm = vec![0f32; cells * n_l * moments];
        let mut skin_data = vec![0f32; skin_cells * n_l * moments];
        let lo = coarse.origin_m;
        let hi = coarse.hi();
        let centre = 0.5 * (lo + hi);
        let radius = 0.5 * (hi - lo).length() * 1.001;
        let disc_area = PI * radius * radius;
        let cell_volume = coarse.cell_m.x * coarse.cell_m.y * coarse.cell_m.z;
        let groups = optics.groups();
        let mut group_of = vec![0; n_l];
        for (gi, group) in groups.iter().enumerate() {
            for &l in group {
                group_of[l] = gi;
            }
        }
        // The sun's once-scattered light apart, in the true medium, for the groups with a
        // truncated peak (see [`once`]).
        let once_of = |l: usize| {
            s.truncation_power > 0.0
                && truncation[l].fraction > 0.0
                && lighting.sun_dir.is_finite()
                && lighting.sun_irradiance[l] > 0.0
                && s.sun_photons > 0
        };
        let mut once = (0..n_l).any(once_of).then(|| {
            OnceField::new(
                cells,
                groups.len(),
                group_of,
                lighting.sun_irradiance.clone(),
            )
        });
        for (gi, group) in groups.into_iter().enumerate() {
            let l0 = group[0];
            let k = optics.extinction_per_density_m[l0];
            let tr = truncation[l0];
            let phase = if s.truncation_power > 0.0 {
                Phase::HenyeyGreenstein { g: tr.g_scaled }
            } else {
                optics.phase[l0]
            };
            let scale = tr.extinction_scale;
            let albedo_scaled = tr.albedo_scaled;
            // Diffusion jumps in optically thick cells of a conservative medium (see
            // [`DiffusionJump`]); none where no cell is thick enough (the same photons as
            // without them).
            let jump = DiffusionJump::new(&coarse, k * scale, phase.mean_cosine(), albedo_scaled);
            let sun_w: Vec<f64> = group
                .iter()
                .map(|&l| lighting.sun_irradiance[l] * disc_area)
                .collect();
            let sun_on =
                lighting.sun_dir.is_finite() && sun_w.iter().any(|&w| w > 0.0) && s.sun_photons > 0;
            let (n_sun, n_env) = photon_budget(s, sun_on, environment_gives_light(lighting));
            // The share of environment photons entering from the upper hemisphere (sky): a
            // hemisphere without light at any of the group's wavelengths gets no photons instead
            // of half of them scoring nothing; otherwise each gets half. Not in proportion to the
            // hemispheres' power: that ratio depends on which wavelengths are computed, and a
            // wavelength's field must not (an RGB-only frame computes its kept wavelengths
            // exactly as the spectral frame does).
            let (p_up, p_down) = hemisphere_power(lighting, &group);
            let q_up = match (p_up > 0.0, p_down > 0.0) {
                (true, false) => 1.0,
                (false, true) => 0.0,
                _ => 0.5,
            };
            let total = n_sun + n_env;
            // This group's sun photons leave their once-scattered light to `once`.
            let once_here = once.is_some() && sun_on && group.iter().any(|&l| once_of(l));
            // Random shift of the launch sequence (Cranley & Patterson 1976), from the seed.
            let shift: [f64; 4] = {
                let mut r = Pcg64::seed_from_u64(s.seed ^ 0x1A_u64.wrapping_mul(l0 as u64 + 1));
                [r.random(), r.random(), r.random(), r.random()]
            };
            let chunk = 4096;
            let chunks = total.div_ceil(chunk);
            // Accumulators for the cells that hold cloud only (the only ones scored), then
            // the skins'; as many lanes as for the whole grid's (the same sums at any size).
            let lane_len = (coarse.cloud_cells + skin_cells) * group.len() * moments;
            let lanes =
                accumulator_lanes((cells + skin_cells) * group.len() * moments).min(chunks.max(1));
            // Each lane traces a fixed, interleaved set of photon chunks into its own
            // accumulator, and the lanes are summed in order: the result does not depend on
            // the thread count or on scheduling (a resumed frame is bit-identical), and only
            // `lanes` accumulators are ever allocated.
            // The lanes hold f32 (half the memory of f64 for the tracks' scattered writes;
            // each score is added in f64 and rounded once, and the field is stored in f32).
            let partial: Vec<(Vec<f32>, Vec<f32>)> = (0..lanes)
                .into_par_iter()
                .map(|lane| {
                    let mut acc = super::pages::take_zeroed_f32(lane_len);
                    // The sun photons' tracks between their first and second scattering (the
                    // δ-M once-scattered light), apart: `once` replaces it in the interior.
                    let mut acc_once = if once_here {
                        super::pages::take_zeroed_f32(lane_len)
                    } else {
                        Vec::new()
                    };
                    let mut env = vec![0.0; n_l];
                    let mut w = vec![0.0; group.len()];
                    let mut ylm = [0.0; (MAX_ORDER + 1) * (MAX_ORDER + 1)];
                    for ci in (lane..chunks).step_by(lanes) {
                        if cancelled.load(std::sync::atomic::Ordering::Relaxed) || cancel() {
                            cancelled.store(true, std::sync::atomic::Ordering::Relaxed);
                            break;
                        }
                        let mut rng = Pcg64::seed_from_u64(
                            s.seed
                                ^ (ci as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                                ^ (l0 as u64) << 56,
                        );
                        for i in ci * chunk..((ci + 1) * chunk).min(total) {
                            // The environment photons' launch (direction, place on the disc)
                            // from a low-discrepancy sequence, randomly shifted: every photon
                            // stays an unbiased sample, and the photons cover the sky's
                            // directions and the disc evenly instead of clumping (see
                            // `launch_point`).
                            let (u, dir_in) = if i < n_sun {
                                for (x, sw) in w.iter_mut().zip(&sun_w) {
                                    *x = sw / n_sun as f64;
                                }
                                // The disc's place pseudo-random (a low-discrepancy place
                                // on the disc measured no better for the sun's photons).
                                ([0.0, 0.0, rng.random(), rng.random()], -lighting.sun_dir)
                            } else {
                                // Uniform within the hemisphere drawn with probability q_up
                                // (upper) or 1 − q_up (lower), the weight divided by that
                                // density: unbiased wherever the environment gives light.
                                let u = launch_point(i - n_sun, &shift);
                                let (z, q) = if u[0] < q_up {
                                    (u[0] / q_up, q_up)
                                } else {
                                    (-(u[0] - q_up) / (1.0 - q_up), 1.0 - q_up)
                                };
                                let r = (1.0 - z * z).max(0.0).sqrt();
                                let phi = 2.0 * PI * u[1];
                                let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                                lighting.env(d, &mut env);
                                let f = 2.0 * PI * disc_area / (q * n_env as f64);
                                for (x, &l) in w.iter_mut().zip(group.iter()) {
                                    *x = env[l] * f;
                                }
                                (u, -d)
                            };
                            if w.iter().all(|&x| x <= 0.0) {
                                continue;
                            }
                            // Start on the disc perpendicular to the direction, outside the box.
                            let (t, b) = orthonormal_basis(dir_in);
                            let r = radius * u[2].sqrt();
                            let phi = 2.0 * PI * u[3];
                            let start = centre + (t * phi.cos() + b * phi.sin()) * r
                                - dir_in * (2.0 * radius);
                            let mut ph = Photon {
                                pos: start,
                                dir: dir_in,
                                scattered: false,
                            };
                            let mut bounces = 0usize;
                            let mut smooth = 0usize;
                            let sun_once = once_here && i < n_sun;
                            let mut thick_events = 0usize;
                            let mut surv = 1.0f64;
                            loop {
                                let tau = -(1.0 - rng.random::<f64>()).ln();
                                if ph.scattered {
                                    real_sh(ph.dir, order, &mut ylm);
                                }
                                let target = if sun_once && smooth == 1 {
                                    &mut acc_once
                                } else {
                                    &mut acc
                                };
                                if !fly_f32(
                                    &coarse,
                                    lo,
                                    hi,
                                    &mut ph,
                                    tau,
                                    k * scale,
                                    cell_volume,
                                    &w,
                                    target,
                                    group.len(),
                                    &ylm[..moments],
                                ) {
                                    break;
                                }
                                let a = albedo_scaled;
                                for x in w.iter_mut() {
                                    *x *= a;
                                }
                                // In a thick cell: collisions are not counted by the
                                // roulette below (the light that diffuses deep comes back
                                // out), only bounded; deep inside one, a diffusion jump.
                                let thick = match &jump {
                                    Some(j) => match j.thick_at(&coarse, ph.pos) {
                                        Thick::No => false,
                                        Thick::Near => true,
                                        Thick::Deep(c, r, sigma_tr) => {
                                            j.walk(
                                                &mut ph,
                                                (c, r, sigma_tr),
                                                &w,
                                                &mut acc,
                                                moments,
                                                cell_volume,
                                                &mut rng,
                                            );
                                            // The walk stands for many scatterings: no
                                            // longer once-scattered light.
                                            smooth = smooth.max(2);
                                            if !thick_roulette(&mut thick_events, &mut w, &mut rng)
                                            {
                                                break;
                                            }
                                            continue;
                                        }
                                    },
                                    None => false,
                                };
                                ph.dir = {
                                    let mut more = || rng.random::<f64>();
                                    let (u1, u2) = (more(), more());
                                    phase.sample(ph.dir, u1, u2, &mut more).0
                                };
                                smooth += 1;
                                ph.scattered = true;
                                if thick {
                                    if !thick_roulette(&mut thick_events, &mut w, &mut rng) {
                                        break;
                                    }
                                    continue;
                                }
                                bounces += 1;
                                // Absorption by weight (implicit capture): the weights carry
                                // ω*ⁿ and the photon flies on, instead of surviving each
                                // collision with probability ω* at its weight; Russian
                                // roulette (unbiased) only once ω*ⁿ is low and on very long
                                // paths.
                                surv *= a;
                                if surv <= 0.0 {
                                    // ω* = 0: nothing more to score.
                                    break;
                                }
                                let keep = if bounces > ROULETTE_BOUNCES {
                                    ROULETTE_KEEP
                                } else if surv < WEIGHT_FLOOR {
                                    WEIGHT_KEEP
                                } else {
                                    1.0
                                };
                                if keep < 1.0 {
                                    if rng.random::<f64>() >= keep {
                                        break;
                                    }
                                    surv /= keep;
                                    for x in w.iter_mut() {
                                        *x /= keep;
                                    }
                                }
                            }
                        }
                    }
                    (acc, acc_once)
                })
                .collect();
            if cancelled.load(std::sync::atomic::Ordering::Relaxed) {
                return Err(crate::Error::Cancelled);
            }
            // The lanes summed in order per cell (cells in parallel: the same sums).
            let ng = group.len();
            data.par_chunks_mut(n_l * moments)
                .zip(once_dm.par_chunks_mut(n_l * moments))
                .enumerate()
                .filter(|(c, _)| coarse.rho[*c] > 0.0)
                .for_each(|(c, (cell, dm))| {
                    // Empty cells are not scored: they have no accumulators.
                    let k = coarse.compact[c] as usize;
                    for (p, q) in &partial {
                        for (gi, &l) in group.iter().enumerate() {
                            for m in 0..moments {
                                let i = (k * ng + gi) * moments + m;
                                let o = q.get(i).map_or(0.0, |&o| o as f64);
                                cell[l * moments + m] += (p[i] as f64 + o) as f32;
                                dm[l * moments + m] += o as f32;
                            }
                        }
                    }
                });
            skin_data
                .par_chunks_mut(n_l * moments)
                .enumerate()
                .for_each(|(s, cell)| {
                    for (p, q) in &partial {
                        for (gi, &l) in group.iter().enumerate() {
                            for m in 0..moments {
                                let i = ((coarse.cloud_cells + s) * ng + gi) * moments + m;
                                cell[l * moments + m] +=
                                    (p[i] as f64 + q.get(i).map_or(0.0, |&o| o as f64)) as f32;
                            }
                        }
                    }
                });
            for (p, q) in partial {
                super::pages::give_back_f32(p);
                if !q.is_empty() {
                    super::pages::give_back_f32(q);
                }
            }
            if let Some(o) = once.as_mut().filter(|_| once_here) {
                let g = once::Group {
                    phase: &optics.phase[l0],
                    truncation: &tr,
                    k,
                    travel: -lighting.sun_dir,
                    photons: n_sun.div_ceil(once::SUN_PHOTONS_PER_PHOTON),
                    seed: s.seed ^ (l0 as u64) << 56,
                };
                let len = (cells + skin_cells) * once::ONCE_MOMENTS;
                o.set_group(
                    gi,
                    &g,
                    &once::trace(&coarse, &g, accumulator_lanes(len).min(4)),
                );
            }
        }
        let phase_moments: Vec<Vec<f64>> = truncation
            .iter()
            .map(|t| scaled_moments(t, order))
            .collect();
        if let Some(o) = once.as_mut() {
            o.finish(&once_dm, moments, &phase_moments, &coarse.rho);
        }
        Ok(Self {
            dims: coarse.dims,
            cell_m: coarse.cell_m,
            origin_m: coarse.origin_m,
            n_l,
            data,
            phase_moments,
            extinction_scale: truncation.iter().map(|t| t.extinction_scale).collect(),
            albedo_scaled: truncation.iter().map(|t| t.albedo_scaled).collect(),
            rho: coarse.rho,
            skin: coarse
                .skin
                .map(|sk| SkinField::new(sk, skin_data, skin_depth)),
            angular_order: order,
            moments,
            once,
        })
    }

    /// In-scattered radiance of orders ≥ 2 of the scaled problem towards a viewer looking along
    /// `d`, at `p`, the phase convolution done exactly in the spherical-harmonic basis up to the
    /// angular order L (addition theorem, ω_o = −d): J* = Σ_l p*_l Σ_m L_lm Y_lm(ω_o).
    ///
    /// Between coarse cell centres the field is interpolated trilinearly over the cells that
    /// hold cloud ([`Self::cell_weights`]).
    pub fn inscatter(&self, p: DVec3, d: DVec3, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let mut ylm = [0.0; (MAX_ORDER + 1) * (MAX_ORDER + 1)];
        real_sh(-d, self.angular_order, &mut ylm);
        // The usual wavelength counts get their sums side by side (each in its own order, so
        // the same values): one chain of additions per wavelength, not one after the other.
        match self.n_l {
            1 => self.inscatter_n::<1>(p, &ylm, out),
            3 => self.inscatter_n::<3>(p, &ylm, out),
            4 => self.inscatter_n::<4>(p, &ylm, out),
            _ => self.inscatter_each(p, &ylm, out),
        }
        for o in out.iter_mut() {
            *o = o.max(0.0);
        }
    }

    /// [`Self::inscatter`]'s sums for `N` wavelengths side by side, and the 8 cells' sums side
    /// by side too: each cell's sum per wavelength is the same chain of additions in the same
    /// order (the same values), but the 8 × `N` chains are independent, so the additions no
    /// longer wait on one another's latency (one chain after the other, this was 9 % of a
    /// sequence frame's CPU). A cell of weight 0 is summed and not added, as before.
    #[inline(always)]
    fn inscatter_n<const N: usize>(&self, p: DVec3, ylm: &[f64], out: &mut [f64]) {
        let n = self.moments;
        let pm: [&[f64]; N] = std::array::from_fn(|l| &self.phase_moments[l][..]);
        let cells = self.cell_weights(p);
        let data: [&[f32]; 8] = std::array::from_fn(|k| {
            let c = cells[k].0;
            &self.data[c * N * n..(c + 1) * N * n]
        });
        let mut sums = [[0.0f64; N]; 8];
        for order in 0..=self.angular_order {
            for m in order * order..(order + 1) * (order + 1) {
                let y = ylm[m];
                for (sum, cell) in sums.iter_mut().zip(&data) {
                    for l in 0..N {
                        sum[l] += pm[l][order] * cell[l * n + m] as f64 * y;
                    }
                }
            }
        }
        for ((_, w), sum) in cells.iter().zip(&sums) {
            if *w == 0.0 {
                continue;
            }
            for l in 0..N {
                out[l] += w * sum[l];
            }
        }
    }

    /// [`Self::inscatter`]'s sums one wavelength after the other (any number of wavelengths).
    fn inscatter_each(&self, p: DVec3, ylm: &[f64], out: &mut [f64]) {
        let n = self.moments;
        for (c, w) in self.cell_weights(p) {
            if w == 0.0 {
                continue;
            }
            for (l, o) in out.iter_mut().enumerate() {
                let v = &self.data[(c * self.n_l + l) * n..(c * self.n_l + l + 1) * n];
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
    }

    /// Angular order L of the field's harmonics.
    pub fn angular_order(&self) -> usize {
        self.angular_order
    }

    /// The phase-convolved coefficients p*_l·L_lm at `p` with [`Self::inscatter`]'s weights,
    /// `[λ][(L + 1)²]` into `out`: [`Self::inscatter`] towards `d` is max(0, Σ_lm out_lm
    /// Y_lm(−d)) per wavelength (what an export of the field per voxel holds).
    pub fn convolved_coefficients(&self, p: DVec3, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let n = self.moments;
        for (c, w) in self.cell_weights(p) {
            if w == 0.0 {
                continue;
            }
            for l in 0..self.n_l {
                let v = &self.data[(c * self.n_l + l) * n..(c * self.n_l + l + 1) * n];
                let pl = &self.phase_moments[l];
                for (order, p_l) in pl.iter().enumerate() {
                    for m in order * order..(order + 1) * (order + 1) {
                        out[l * n + m] += w * p_l * v[m] as f64;
                    }
                }
            }
        }
    }

    /// The 8 coarse cells around `p` and their weights: trilinear between cell centres over
    /// the cells that hold cloud (renormalised), plain trilinear where none of them does.
    ///
    /// An empty cell holds the fluence of light leaving the cloud (outward only, about half
    /// the fluence just inside a lit surface), which would dim the cloud's surface voxels, so
    /// it is left out. The cells that hold cloud keep their trilinear weights whatever their
    /// density: weights in proportion to the density (used before) pulled a voxel at a thin
    /// edge towards the denser interior cells, whose fluence is higher than the edge's (where
    /// light escapes), and the field read +16…+27 % against a path tracer's orders ≥ 2 where
    /// the view ray's optical depth is 1–2 on the Mitsuba 3 cumulus (docs/frames.md, "Accuracy").
    pub fn cell_weights(&self, p: DVec3) -> [(usize, f64); 8] {
        let local = (p - self.origin_m) / self.cell_m - DVec3::splat(0.5);
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut f = [0f64; 3];
        for a in 0..3 {
            let c = local[a].clamp(0.0, (self.dims[a] - 1) as f64);
            i0[a] = super::volume::floor(c) as usize;
            i1[a] = (i0[a] + 1).min(self.dims[a] - 1);
            f[a] = c - i0[a] as f64;
        }
        let mut cells = [(0usize, 0f64, false); 8];
        let (mut sum_w, mut sum_cloud) = (0.0, 0.0);
        for (corner, cell) in cells.iter_mut().enumerate() {
            let ix = if corner & 1 == 0 { i0[0] } else { i1[0] };
            let iy = if corner & 2 == 0 { i0[1] } else { i1[1] };
            let iz = if corner & 4 == 0 { i0[2] } else { i1[2] };
            let w = (if corner & 1 == 0 { 1.0 - f[0] } else { f[0] })
                * (if corner & 2 == 0 { 1.0 - f[1] } else { f[1] })
                * (if corner & 4 == 0 { 1.0 - f[2] } else { f[2] });
            let c = (iz * self.dims[1] + iy) * self.dims[0] + ix;
            let cloud = self.rho[c] > 0.0;
            *cell = (c, w, cloud);
            sum_w += w;
            if cloud {
                sum_cloud += w;
            }
        }
        // One divisor for all 8 (the same quotients as dividing by either sum per corner), so
        // the divisions need no branch per corner.
        let in_cloud = sum_cloud > 0.0;
        let sum = if in_cloud {
            sum_cloud
        } else {
            sum_w.max(1e-300)
        };
        cells.map(|(c, w, cloud)| (c, if in_cloud && !cloud { 0.0 } else { w / sum }))
    }
}

/// Largest angular order of the field.
pub const MAX_ORDER: usize = 4;

/// Largest coarse cell, in transport mean free paths at the cloud's mean density, before
/// [`Coarse::new`] makes the cells smaller (down to half the edge `max_coarse_dim` gives,
/// where one voxel is within it).
/// Below a lit face the diffuse radiance builds up and falls over a few transport mean free
/// paths ℓ_tr = 1/(σ_t(1 − ωg)) (the Milne problem, Chandrasekhar 1960 ch. IV), and the
/// field's cells, interpolated trilinearly, smooth that profile over about two cells. With
/// `standard`'s 32 cells per axis the Mitsuba 3 cloud's cells are 60 m: 0.11 ℓ_tr for g 0.85
/// but 0.38 ℓ_tr for g 0.5, whose 8-seed mean frame read the sunlit limb −8…−10 % of the
/// cloud's mean and the middle +3…+6 % (block NRMSE 4.08 % raw); with 30 m cells 2.38 %
/// (docs/frames.md, "Accuracy"). The g 0.85 cases' 0.11 ℓ_tr (0.18 with albedo 0.9) were the
/// largest part of their mean frames' error too (see [`REFINED_PHOTONS`]), so the cells are
/// held within 0.1 ℓ_tr (the bench cumulus's 48 m cells, 0.086 ℓ_tr, are kept).
pub const CELL_TRANSPORT_FRACTION: f64 = 0.1;

/// Where not even one voxel is within [`CELL_TRANSPORT_FRACTION`] of ℓ_tr, the widest block
/// within this fraction (engine18's rule: the Mitsuba 3 g 0.5 cloud, 30 m voxels, 0.19 ℓ_tr).
pub const CELL_TRANSPORT_FRACTION_COARSE: f64 = 0.25;

/// Photon budget factor of a field whose cells [`Coarse::new`] made smaller than
/// `max_coarse_dim` gives ([`CELL_TRANSPORT_FRACTION`]): halving a cell's edge leaves each cell
/// ⅛ of the tracks, and the finer cells' smaller error (the Mitsuba 3 g 0.85 cloud's 16-seed
/// mean frames, 60 → 30 m cells: `below_sun` 5.68 → 4.41 %, `sun_albedo09` 4.34 → 3.09 %,
/// `sun` 3.93 → 2.43 % block NRMSE) is lost in the photon noise at the same budget (seed noise
/// 3.32 → 4.86 %, `below_sun` worst of 16 seeds unchanged at 6.50 %). With 2× the photons the
/// worst of 16 seeds read `below_sun` 5.18 %, `sun_albedo09` 5.32 % (2 seeds each past 5 %),
/// with 3× 4.66 and 4.41 % (none; 6.50 and 6.61 % before), for about 4× that frame's CPU
/// (docs/frames.md, "Photon seeds").
pub const REFINED_PHOTONS: usize = 3;

/// The transport mean free path 1/(σ_t(1 − ωg)) at the mean density of the voxels that hold
/// cloud, m, the shortest over the wavelengths (∞ for an empty grid).
pub fn transport_mean_free_path(grid: &DensityGrid, optics: &Optics) -> f64 {
    let (sum, n) = grid
        .data
        .iter()
        .filter(|&&v| v > 0.0)
        .fold((0.0f64, 0usize), |(s, n), &v| (s + v as f64, n + 1));
    if n == 0 {
        return f64::INFINITY;
    }
    let mean = sum / n as f64;
    let k_tr = optics
        .extinction_per_density_m
        .iter()
        .zip(&optics.albedo)
        .zip(&optics.phase)
        .map(|((&k, &w), p)| k * (1.0 - w * p.mean_cosine()))
        .fold(0.0f64, f64::max);
    if k_tr * mean > 0.0 {
        1.0 / (k_tr * mean)
    } else {
        f64::INFINITY
    }
}

/// Collisions (outside thick cells) after which every photon plays a Russian roulette at each
/// further collision, surviving with [`ROULETTE_KEEP`] at a raised weight: it bounds the run
/// time of walks in large clouds of moderately thick cells. Each survivor's weight grows as
/// 1/0.95ⁿ, a heavy tail: after 20 collisions it was most of the Mitsuba 3 g 0.5 cloud's photon
/// noise (each block's spread between 16 photon seeds 3.85 %, 3.12 % after 60 collisions, 2.92 %
/// with none, for +9 % of that frame's collisions; the g 0.85 frames and the bench frame
/// unchanged: their walks end sooner; docs/frames.md).
const ROULETTE_BOUNCES: usize = 60;
/// Survival probability of that roulette per further collision.
const ROULETTE_KEEP: f64 = 0.95;

/// A photon whose weight has fallen to this fraction of its launch weight by absorption (ω*ⁿ)
/// plays a Russian roulette, surviving with [`WEIGHT_KEEP`] at a raised weight (unbiased).
/// Absorption by weight instead of by survival at every collision (implicit capture, e.g.
/// Lux & Koblinger 1991, "Monte Carlo particle transport methods", ch. 6): measured on the
/// Mitsuba cloud with ω = 0.9 (ω* 0.80), block NRMSE over 4 photon seeds 8.4 → 6.1 %, the bias's
/// spread over the seeds −1.0…+3.9 → −0.7…+1.2 %, for about +10 % of that frame's CPU.
const WEIGHT_FLOOR: f64 = 0.1;
/// Survival probability of that roulette.
const WEIGHT_KEEP: f64 = 0.5;

/// Smallest radius of a diffusion jump, transport mean free paths.
const JUMP_MIN_MFP: f64 = 3.0;
/// Collisions in thick cells before a photon is subject to a roulette there (run time bound).
const THICK_EVENTS: usize = 20_000;
/// Survival probability of that roulette per further collision.
const THICK_KEEP: f64 = 0.99;

/// Counts a collision in a thick cell and, after [`THICK_EVENTS`] of them, plays the roulette
/// that bounds their number (survival [`THICK_KEEP`], the survivor's weights raised to keep the
/// estimate unbiased). Returns whether the photon lives on.
fn thick_roulette<R: Rng>(events: &mut usize, w: &mut [f64], rng: &mut R) -> bool {
    *events += 1;
    if *events > THICK_EVENTS {
        if rng.random::<f64>() >= THICK_KEEP {
            return false;
        }
        for x in w.iter_mut() {
            *x /= THICK_KEEP;
        }
    }
    true
}

/// Diffusion jumps of photons deep inside optically thick cells of a conservative scaled medium
/// (ω* = 1): the random-walk-on-spheres acceleration of Monte Carlo transport in the diffusion
/// limit (Müller 1956 for the walk on spheres; Fleck & Canfield 1984, "A random walk procedure
/// for improving the computational efficiency of the implicit Monte Carlo method for nonlinear
/// radiation transport", J. Comput. Phys. 54, for radiative transfer).
///
/// A photon that collides at a distance R ≥ [`JUMP_MIN_MFP`] transport mean free paths
/// ℓ_tr = 1/(σ*(1 − g*)) from every face of its (homogeneous) cell moves to a uniformly
/// distributed point of the sphere of radius R round it, where diffusion (diffusion
/// coefficient ℓ_tr/3 per unit path length) first reaches that sphere, having travelled the
/// mean path length R²/(2ℓ_tr) inside it (the mean first-exit time of Brownian motion from
/// the centre of a sphere, R²/(6D)); that path is scored as isotropic radiance (the diffuse
/// field's fluence; its flux and higher moments average to 0 over the sphere by symmetry) in
/// the cell, and the photon leaves in an isotropic direction. Weights are unchanged (no
/// absorption). Without the jumps, a photon needs about (depth/ℓ_tr)² collisions to
/// diffuse into a cell of many optical depths and back out, and the roulette that bounds run
/// time (then after 20 collisions) removed them: the light that diffuses deep into a thick cloud
/// and back was lost (a τ 1000 ball in voxels of 51 optical depths returned under half its
/// light). Collisions in thick cells are therefore left out of that roulette and bounded by
/// their own, after [`THICK_EVENTS`].
struct DiffusionJump {
    /// Transport coefficient per density, σ*(1 − g*)/ρ, 1/m.
    transport_per_density: f64,
    /// Density above which a cell is thick enough for a jump somewhere inside.
    rho_min: f64,
}

/// Where a collision happened, for [`DiffusionJump`].
enum Thick {
    /// In a cell not thick enough for jumps.
    No,
    /// In a thick cell, too near its faces for a jump.
    Near,
    /// Deep in a thick cell: its index among the cells that hold cloud, the distance to its nearest face (m) and σ*(1 − g*) (1/m).
    Deep(usize, f64, f64),
}

impl DiffusionJump {
    fn new(coarse: &Coarse, k_scaled: f64, g: f64, albedo: f64) -> Option<Self> {
        // Conservative to rounding (ω* = ω(1 − f)/(1 − ωf) with ω = 1).
        if albedo < 1.0 - 1e-12 || k_scaled.is_nan() || k_scaled <= 0.0 {
            return None;
        }
        let transport_per_density = k_scaled * (1.0 - g);
        let edge = coarse.cell_m.min_element();
        // A sphere of the smallest radius fits in the cell with some room.
        let rho_min = 2.5 * JUMP_MIN_MFP / (transport_per_density * edge);
        coarse
            .rho
            .iter()
            .any(|&r| r as f64 >= rho_min)
            .then_some(Self {
                transport_per_density,
                rho_min,
            })
    }

    /// The cell at `p` and the radius of the largest sphere round `p` inside it, when that
    /// cell is thick and the radius is at least [`JUMP_MIN_MFP`] transport mean free paths.
    #[inline]
    fn thick_at(&self, g: &Coarse, p: DVec3) -> Thick {
        let local = (p - g.origin_m) / g.cell_m;
        let mut idx = [0usize; 3];
        let mut dist = f64::INFINITY;
        for a in 0..3 {
            let f = super::volume::floor(local[a]);
            if !(f >= 0.0 && f < g.dims[a] as f64) {
                return Thick::No;
            }
            idx[a] = f as usize;
            let lo = g.origin_m[a] + f * g.cell_m[a];
            dist = dist.min(p[a] - lo).min(lo + g.cell_m[a] - p[a]);
        }
        let c = (idx[2] * g.dims[1] + idx[1]) * g.dims[0] + idx[0];
        let rho = g.rho[c] as f64;
        if rho < self.rho_min {
            return Thick::No;
        }
        let sigma_tr = self.transport_per_density * rho;
        if dist * sigma_tr >= JUMP_MIN_MFP {
            // A thick cell holds cloud: it has accumulators.
            Thick::Deep(g.compact[c] as usize, dist, sigma_tr)
        } else {
            Thick::Near
        }
    }

    /// One jump from the photon's position (which [`Self::thick_at`] accepted).
    #[allow(clippy::too_many_arguments)]
    fn walk(
        &self,
        ph: &mut Photon,
        (c, r, sigma_tr): (usize, f64, f64),
        w: &[f64],
        acc: &mut [impl Tally],
        moments: usize,
        cell_volume: f64,
        rng: &mut Pcg64,
    ) {
        let ng = w.len();
        // Just inside the faces (rounding).
        let r = r * (1.0 - 1e-9);
        let path = 0.5 * r * r * sigma_tr;
        let y00 = 0.282_094_791_773_878_14;
        let s = path * y00 / cell_volume;
        for (gi, wi) in w.iter().enumerate() {
            acc[(c * ng + gi) * moments].add(wi * s);
        }
        ph.pos += uniform_sphere(rng.random(), rng.random()) * r;
        ph.dir = uniform_sphere(rng.random(), rng.random());
        ph.scattered = true;
    }
}

/// Legendre moments p*_0 … p*_L of the scaled phase function the reconstruction uses: the δ-M
/// moments (χ_l − f)/(1 − f) (Wiscombe 1977, eq 13) with χ_l = g₁^l (Henyey-Greenstein moments
/// for any phase function), clamped at 0 where the truncated fraction f exceeds χ_l (f = g₁^3.5:
/// from l = 4 on the truncated expansion has no such moments). Measured against DISORT slabs
/// (τ 1–32) and Mitsuba 3: the moments g*^l of the transport's Henyey-Greenstein g* overshoot the
/// reflected radiance at nadir by up to 19 % at τ 1 (see docs/frames.md).
pub fn scaled_moments(t: &Truncation, order: usize) -> Vec<f64> {
    (0..=order)
        .map(|l| {
            if l == 0 {
                1.0
            } else if t.fraction <= 0.0 {
                t.g_original.powi(l as i32)
            } else {
                ((t.g_original.powi(l as i32) - t.fraction) / (1.0 - t.fraction)).max(0.0)
            }
        })
        .collect()
}

/// Real orthonormal spherical harmonics Y_lm of unit `d` for l ≤ `order` (≤ 4), in the order
/// l², …, l² + 2l (m = −l … l) (the standard Cartesian forms, e.g. Sloan 2008, appendix A2).
pub fn real_sh(d: DVec3, order: usize, out: &mut [f64]) {
    let (x, y, z) = (d.x, d.y, d.z);
    out[0] = 0.282_094_791_773_878_14;
    if order >= 1 {
        let c = 0.488_602_511_902_919_9;
        out[1] = c * y;
        out[2] = c * z;
        out[3] = c * x;
    }
    if order >= 2 {
        out[4] = 1.092_548_430_592_079_2 * x * y;
        out[5] = 1.092_548_430_592_079_2 * y * z;
        out[6] = 0.315_391_565_252_520_05 * (3.0 * z * z - 1.0);
        out[7] = 1.092_548_430_592_079_2 * x * z;
        out[8] = 0.546_274_215_296_039_6 * (x * x - y * y);
    }
    if order >= 3 {
        out[9] = 0.590_043_589_926_643_5 * y * (3.0 * x * x - y * y);
        out[10] = 2.890_611_442_640_554 * x * y * z;
        out[11] = 0.457_045_799_464_465_8 * y * (5.0 * z * z - 1.0);
        out[12] = 0.373_176_332_590_115_4 * z * (5.0 * z * z - 3.0);
        out[13] = 0.457_045_799_464_465_8 * x * (5.0 * z * z - 1.0);
        out[14] = 1.445_305_721_320_277 * z * (x * x - y * y);
        out[15] = 0.590_043_589_926_643_5 * x * (x * x - 3.0 * y * y);
    }
    if order >= 4 {
        let (x2, y2, z2) = (x * x, y * y, z * z);
        out[16] = 2.503_342_941_796_704_6 * x * y * (x2 - y2);
        out[17] = 1.770_130_769_779_930_4 * y * z * (3.0 * x2 - y2);
        out[18] = 0.946_174_695_757_560_1 * x * y * (7.0 * z2 - 1.0);
        out[19] = 0.669_046_543_557_289_2 * y * z * (7.0 * z2 - 3.0);
        out[20] = 0.105_785_546_915_204_31 * (35.0 * z2 * z2 - 30.0 * z2 + 3.0);
        out[21] = 0.669_046_543_557_289_2 * x * z * (7.0 * z2 - 3.0);
        out[22] = 0.473_087_347_878_780_04 * (x2 - y2) * (7.0 * z2 - 1.0);
        out[23] = 1.770_130_769_779_930_4 * x * z * (x2 - 3.0 * y2);
        out[24] = 0.625_835_735_449_176_1 * (x2 * (x2 - 3.0 * y2) - y2 * (3.0 * x2 - y2));
    }
}

/// δ-M scaling of one wavelength's optics (Wiscombe 1977 eqs 13–15, f = g₁^p, p = 2 the
/// δ-Eddington choice of Joseph et al. 1976; backward-peaked phase functions, g₁ ≤ 0, and p ≤ 0
/// are not truncated).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truncation {
    /// The truncated fraction f of every scattering (the forward peak f·δ).
    pub fraction: f64,
    pub g_scaled: f64,
    pub p2_scaled: f64,
    pub extinction_scale: f64,
    pub albedo_scaled: f64,
    /// The true single-scattering albedo ω.
    pub albedo: f64,
    /// The true phase function's first moment g₁.
    pub g_original: f64,
}

impl Truncation {
    pub fn new(g1: f64, albedo: f64, power: f64) -> Self {
        let f = if power > 0.0 {
            g1.max(0.0).powf(power)
        } else {
            0.0
        };
        let scale = 1.0 - albedo * f;
        Self {
            fraction: f,
            g_scaled: (g1 - f) / (1.0 - f),
            p2_scaled: (g1 * g1 - f) / (1.0 - f),
            extinction_scale: scale,
            albedo_scaled: if scale > 0.0 {
                albedo * (1.0 - f) / scale
            } else {
                0.0
            },
            albedo,
            g_original: g1,
        }
    }
}

/// A direction uniform over the unit sphere from two uniform numbers (z uniform in [−1, 1]).
fn uniform_sphere(u1: f64, u2: f64) -> DVec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Whether the environment (sky above, ground light below) gives the cloud any light: false
/// when both hemispheres are absent or constant at zero.
fn environment_gives_light(lighting: &Lighting) -> bool {
    let lit = |h: &Hemisphere| match h {
        Hemisphere::Zero => false,
        Hemisphere::Constant(v) => v.iter().any(|&x| x > 0.0),
        Hemisphere::Table(_) => true,
    };
    lit(&lighting.sky) || lit(&lighting.below)
}

/// Photons from the sun and from the environment: each source's own budget, and a source that
/// gives no light hands its budget to the other, so every frame traces the photons of a frame
/// lit by both and none are spent on a source that scores nothing.
///
/// Without the sun's light its photons go to the environment: the field of a sky-lit frame is
/// photon noise for the most part (Mitsuba `sky` case, 3 seeds: block NRMSE 5.9 % with 2^18
/// environment photons, 5.5 % with 2^19, 4.8 % with 2^21). Without sky and ground light the
/// environment's photons go to the sun: they were launched, found no light and ended at once,
/// and the sun-lit frames' field is photon noise in large part (Mitsuba `sun` case, 4 seeds:
/// block NRMSE 6.65 % with 2^18 sun photons, 5.0 % with 2^20, 4.5 % with 2^22; docs/frames.md).
fn photon_budget(s: &PhotonSettings, sun_on: bool, env_on: bool) -> (usize, usize) {
    match (sun_on, env_on) {
        (true, true) => (s.sun_photons, s.env_photons),
        (true, false) => (s.sun_photons.saturating_add(s.env_photons), 0),
        (false, _) => (0, s.env_photons.saturating_add(s.sun_photons)),
    }
}

/// Point `i` of the launch sequence in [0, 1)⁴: the Halton sequence (radical inverses of `i` in
/// bases 2, 3, 5, 7; Halton 1960), whose low-dimensional projections are evenly spread,
/// shifted by `shift` mod 1 (Cranley & Patterson 1976: with a uniform random shift each point
/// is uniform, so every estimate stays unbiased). Used for the photons' launch only; their
/// walks stay pseudo-random.
fn launch_point(i: usize, shift: &[f64; 4]) -> [f64; 4] {
    let mut u = [0.0; 4];
    for (j, base) in [2usize, 3, 5, 7].into_iter().enumerate() {
        let (mut n, mut f, mut r) = (i, 1.0, 0.0);
        while n > 0 {
            f /= base as f64;
            r += f * (n % base) as f64;
            n /= base;
        }
        let x = shift[j] + r;
        u[j] = x - x.floor();
    }
    u
}

/// Mean radiance summed over the wavelengths of `group`, over the upper and the lower
/// hemisphere of the environment (sky and ground light), by a Fibonacci quadrature of 2048
/// directions: which hemispheres give the environment photons light.
fn hemisphere_power(lighting: &Lighting, group: &[usize]) -> (f64, f64) {
    let n = 2048;
    let mut rad = vec![0.0; lighting.wavelengths_nm.len()];
    let (mut up, mut down) = (0.0, 0.0);
    for i in 0..n {
        let d = super::light::fibonacci(i, n);
        lighting.env(d, &mut rad);
        let s: f64 = group.iter().map(|&l| rad[l].max(0.0)).sum();
        if d.z >= 0.0 {
            up += s;
        } else {
            down += s;
        }
    }
    (up, down)
}

skybake_physics::simd_dispatch! {
    /// Moves the photon through the coarse grid until optical depth `tau` is used up (a
    /// collision: returns true) or it leaves the cells that hold cloud ([`Span`]: false).
    /// Scattered photons score their tracks in the cells that hold cloud into the `f32`
    /// accumulators `acc` (each score added in f64 and rounded once).
    /// Compiled twice (generic and AVX2 + FMA, chosen by the CPU's features): the same IEEE
    /// operations in both (Rust contracts no multiply-add), so the same field.
    fn fly_f32(
        g: &Coarse,
        lo: DVec3,
        hi: DVec3,
        ph: &mut Photon,
        tau_in: f64,
        k: f64,
        cell_volume: f64,
        w: &[f64],
        acc: &mut [f32],
        ng: usize,
        ylm: &[f64],
    ) -> bool {
        fly_in(g, lo, hi, ph, tau_in, k, cell_volume, w, acc, ng, ylm)
    }
}

/// The body of [`fly_f32`], generic over the accumulators' precision.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn fly_in<T: Tally>(
    g: &Coarse,
    lo: DVec3,
    hi: DVec3,
    ph: &mut Photon,
    tau_in: f64,
    k: f64,
    cell_volume: f64,
    w: &[f64],
    acc: &mut [T],
    ng: usize,
    ylm: &[f64],
) -> bool {
    let mut tau = tau_in;
    // A photon from outside whose line misses the cells that hold cloud meets nothing.
    if !ph.scattered && !g.span.meets(ph.pos, ph.dir) {
        return false;
    }
    let Some((t0, t1)) = super::camera::box_interval(ph.pos, ph.dir, lo, hi) else {
        return false;
    };
    let d = ph.dir;
    let mut t = t0;
    // DDA through the cells.
    let DdaStart {
        mut cell,
        step,
        mut t_next,
        t_delta,
    } = g.dda_start(lo, ph.pos, d, t0);
    // A second cursor runs [`LOOKAHEAD`] cells ahead of the track along the same cells and
    // fetches their accumulators (a lane's accumulators are larger than the caches, and a
    // track crosses few cells: fetched one cell ahead, most of the wait remained; a hint, no
    // change in value).
    let block = ng * ylm.len();
    let mut ahead = (cell, t_next);
    let mut ahead_live = ph.scattered;
    for _ in 0..LOOKAHEAD {
        if ahead_live {
            ahead_live = ahead_step(g, &mut ahead, &step, &t_delta, acc, block);
        }
    }
    loop {
        let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
            0
        } else if t_next[1] <= t_next[2] {
            1
        } else {
            2
        };
        let t_exit = t_next[a].min(t1);
        let c = ((cell[2] as usize * g.dims[1]) + cell[1] as usize) * g.dims[0] + cell[0] as usize;
        if ahead_live {
            ahead_live = ahead_step(g, &mut ahead, &step, &t_delta, acc, block);
        }
        let sigma = k * g.rho[c] as f64;
        let len = (t_exit - t).max(0.0);
        let (used, hit) = if sigma * len >= tau && sigma > 0.0 {
            (tau / sigma, true)
        } else {
            (len, false)
        };
        if ph.scattered && used > 0.0 && g.rho[c] > 0.0 {
            let s = used / cell_volume;
            let n = ylm.len();
            let k = g.compact[c] as usize;
            for gi in 0..ng {
                let b = (k * ng + gi) * n;
                let ws = w[gi] * s;
                for (a, y) in acc[b..b + n].iter_mut().zip(ylm) {
                    a.add(ws * y);
                }
            }
            if let Some(sk) = &g.skin {
                sk.score(c, g.cloud_cells, ph.pos + d * t, d, used, w, acc, ylm);
            }
        }
        if hit {
            ph.pos += d * (t + used);
            return true;
        }
        tau -= sigma * len;
        t = t_exit;
        if t >= t1 {
            return false;
        }
        cell[a] += step[a];
        if cell[a] < 0 || cell[a] >= g.dims[a] as i64 || g.span.passed(a, cell[a], step[a]) {
            return false;
        }
        t_next[a] += t_delta[a];
    }
}

/// An accumulator of the photon pass: [`fly_f32`] adds each track's scores to one (`f32`;
/// `f64` where a unit test sums a track exactly). A lane holds the accumulators of the cells
/// that hold cloud only, in their [`Coarse::compact`] order, then the skins'.
pub(super) trait Tally: Copy {
    /// Adds `v` (computed in f64).
    fn add(&mut self, v: f64);
}

impl Tally for f64 {
    #[inline(always)]
    fn add(&mut self, v: f64) {
        *self += v;
    }
}

impl Tally for f32 {
    /// The sum in f64, rounded once to f32.
    #[inline(always)]
    fn add(&mut self, v: f64) {
        *self = (*self as f64 + v) as f32;
    }
}

/// The skins of the coarse grid's optically thick cells (see [`SkinField`]), at the lowest
/// scaled extinction of the wavelengths: sets `coarse.skin` and returns the number of skin
/// cells and the skin's depth per wavelength in scaled optical depths.
fn skin_setup(
    coarse: &mut Coarse,
    grid: &DensityGrid,
    optics: &Optics,
    truncation: &[Truncation],
) -> (usize, Vec<f64>) {
    let k: Vec<f64> = optics
        .extinction_per_density_m
        .iter()
        .zip(truncation)
        .map(|(k, t)| k * t.extinction_scale)
        .collect();
    let k_min = k.iter().copied().fold(f64::INFINITY, f64::min);
    coarse.skin = skin::Skin::new(coarse, k_min, grid.voxel_size_m, THICK_STEP);
    let n = coarse.skin.as_ref().map_or(0, skin::Skin::len);
    (n, k.iter().map(|k| SKIN_TAU * k / k_min).collect())
}

/// Cells ahead of a scoring track whose accumulators [`fly_f32`] fetches.
const LOOKAHEAD: usize = 3;

/// Moves [`fly_f32`]'s look-ahead cursor (cell, next crossing distances per axis) one cell on
/// along the track's cells (the same choice of axis as the track's) and fetches that cell's
/// accumulators (`block` values per cell); false when it has left the grid.
#[inline(always)]
fn ahead_step<T>(
    g: &Coarse,
    (cell, t_next): &mut ([i64; 3], [f64; 3]),
    step: &[i64; 3],
    t_delta: &[f64; 3],
    acc: &[T],
    block: usize,
) -> bool {
    let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
        0
    } else if t_next[1] <= t_next[2] {
        1
    } else {
        2
    };
    cell[a] += step[a];
    if cell[a] < 0 || cell[a] >= g.dims[a] as i64 || g.span.passed(a, cell[a], step[a]) {
        return false;
    }
    t_next[a] += t_delta[a];
    let c = ((cell[2] as usize * g.dims[1]) + cell[1] as usize) * g.dims[0] + cell[0] as usize;
    // Only the cells that hold cloud are scored.
    if g.rho[c] > 0.0 {
        let k = g.compact[c] as usize;
        prefetch(&acc[k * block..(k + 1) * block]);
    }
    true
}

/// Asks the processor to bring `block` into its caches (a hint: no effect on any value).
#[inline(always)]
fn prefetch<T>(block: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = block.as_ptr() as *const i8;
        let bytes = std::mem::size_of_val(block);
        let mut off = 0;
        while off < bytes {
            // SAFETY: a prefetch reads nothing and cannot fault; the addresses lie in `block`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(off)) };
            off += 64;
        }
        if bytes > 0 {
            // SAFETY: as above (the block's last byte).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(bytes - 1)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = block;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The harmonics against the addition theorem, Σ_m Y_lm(a) Y_lm(b) = (2l + 1)/(4π) P_l(a·b)
    /// (which fixes every normalisation constant and sign pattern), for pairs of directions.
    #[test]
    fn real_sh_satisfy_the_addition_theorem() {
        let n = (MAX_ORDER + 1) * (MAX_ORDER + 1);
        let (mut ya, mut yb) = (vec![0.0; n], vec![0.0; n]);
        for i in 0..40 {
            let a = uniform_sphere((i as f64 + 0.3) / 40.0, (i as f64 * 0.618_034).fract());
            let b = uniform_sphere((i as f64 * 0.414_214).fract(), (i as f64 + 0.7) / 40.0);
            real_sh(a, MAX_ORDER, &mut ya);
            real_sh(b, MAX_ORDER, &mut yb);
            let mu = a.dot(b);
            let p = [
                1.0,
                mu,
                0.5 * (3.0 * mu * mu - 1.0),
                0.5 * (5.0 * mu.powi(3) - 3.0 * mu),
                (35.0 * mu.powi(4) - 30.0 * mu * mu + 3.0) / 8.0,
            ];
            for l in 0..=MAX_ORDER {
                let sum: f64 = (l * l..(l + 1) * (l + 1)).map(|m| ya[m] * yb[m]).sum();
                let expected = (2 * l + 1) as f64 / (4.0 * PI) * p[l];
                assert!((sum - expected).abs() < 1e-12, "l {l}: {sum} vs {expected}");
            }
        }
    }

    /// Each source's photon budget, and a source without light hands it to the other: a frame
    /// lit by the sun alone (no sky, ground light zero) traces both budgets from the sun, one
    /// without sunlight both from the environment, one lit by both each its own.
    #[test]
    fn a_source_without_light_hands_its_photons_to_the_other() {
        let s = PhotonSettings {
            sun_photons: 1000,
            env_photons: 300,
            max_coarse_dim: 8,
            transport_cells: true,
            seed: 1,
            angular_order: 3,
            truncation_power: 3.5,
            peak_spread: 0.0,
        };
        let lighting = |sky: Hemisphere, below: Hemisphere| Lighting {
            wavelengths_nm: vec![550.0],
            sun_dir: DVec3::Z,
            sun_irradiance: vec![1.0],
            sky,
            below,
            ground: None,
            background: None,
            aerial: None,
            notes: Vec::new(),
        };
        let dark = lighting(Hemisphere::Zero, Hemisphere::Constant(vec![0.0]));
        let sky = lighting(Hemisphere::Constant(vec![0.2]), Hemisphere::Zero);
        let ground = lighting(Hemisphere::Zero, Hemisphere::Constant(vec![0.1]));
        assert!(!environment_gives_light(&dark));
        assert!(environment_gives_light(&sky) && environment_gives_light(&ground));
        assert_eq!(photon_budget(&s, true, false), (1300, 0));
        assert_eq!(photon_budget(&s, true, true), (1000, 300));
        assert_eq!(photon_budget(&s, false, true), (0, 1300));
        assert_eq!(photon_budget(&s, false, false), (0, 1300));
    }

    /// The field's interpolation weights: trilinear over the cells that hold cloud, whatever
    /// their density (a denser neighbour does not pull a thin edge's voxel towards it), empty
    /// cells left out, plain trilinear where no cell round the point holds cloud.
    #[test]
    fn the_field_interpolates_over_the_cells_that_hold_cloud() {
        let field = |rho: Vec<f32>| MsField {
            dims: [2, 2, 2],
            cell_m: DVec3::splat(10.0),
            origin_m: DVec3::ZERO,
            n_l: 1,
            data: vec![0.0; 8],
            phase_moments: vec![vec![1.0]],
            extinction_scale: vec![1.0],
            albedo_scaled: vec![1.0],
            rho,
            skin: None,
            angular_order: 0,
            once: None,
            moments: 1,
        };
        // A quarter of a cell from cell 0's centre towards cell 1 along x, at the centres'
        // height and depth: trilinear weights 0.75 / 0.25 on cells 0 and 1.
        let p = DVec3::new(7.5, 5.0, 5.0);
        let weight = |f: &MsField, c: usize| -> f64 {
            f.cell_weights(p)
                .iter()
                .filter(|&&(i, _)| i == c)
                .map(|&(_, w)| w)
                .sum()
        };
        let mut rho = vec![0.0f32; 8];
        rho[0] = 0.1;
        rho[1] = 10.0;
        let f = field(rho.clone());
        assert!((weight(&f, 0) - 0.75).abs() < 1e-12 && (weight(&f, 1) - 0.25).abs() < 1e-12);
        // The same with the denser neighbour 100× denser still.
        rho[1] = 1000.0;
        let f = field(rho.clone());
        assert!((weight(&f, 0) - 0.75).abs() < 1e-12 && (weight(&f, 1) - 0.25).abs() < 1e-12);
        // An empty neighbour is left out: the whole weight on the cell with cloud.
        rho[1] = 0.0;
        let f = field(rho);
        assert!((weight(&f, 0) - 1.0).abs() < 1e-12 && weight(&f, 1) == 0.0);
        // No cloud round the point: plain trilinear.
        let f = field(vec![0.0; 8]);
        assert!((weight(&f, 0) - 0.75).abs() < 1e-12 && (weight(&f, 1) - 0.25).abs() < 1e-12);
    }

    /// Flights that end where they leave the cells that hold cloud ([`Span`]) and score into
    /// accumulators for those cells only ([`Coarse::compact`]) against flights through the
    /// whole grid (a span of every cell) scoring into accumulators for every cell: the same
    /// collisions (places, bit for bit) and the same scores in every cell that holds cloud, for
    /// photons from outside (most of them missing the cloud) and scattered photons inside it,
    /// in every direction.
    #[test]
    fn flights_within_the_cloud_s_span_are_the_whole_grid_s() {
        let n = [12usize, 10, 9];
        let mut rho = vec![0f32; n[0] * n[1] * n[2]];
        let mut r = Pcg64::seed_from_u64(7);
        for z in 3..7 {
            for y in 2..6 {
                for x in 4..9 {
                    if r.random::<f64>() < 0.8 {
                        rho[(z * n[1] + y) * n[0] + x] = r.random::<f32>() * 2.0;
                    }
                }
            }
        }
        let cell_m = DVec3::new(10.0, 12.0, 8.0);
        let origin_m = DVec3::new(-40.0, 5.0, 100.0);
        let coarse = Coarse::from_cells(n, cell_m, origin_m, rho.clone());
        assert_eq!((coarse.span.lo, coarse.span.hi), ([4, 2, 3], [8, 5, 6]));
        let cloud = rho.iter().filter(|&&r| r > 0.0).count();
        assert_eq!(coarse.cloud_cells, cloud);
        // Every cell scored, with accumulators for every cell of the grid in its order.
        let whole = Coarse {
            span: Span {
                lo: [0; 3],
                hi: [n[0] as i64 - 1, n[1] as i64 - 1, n[2] as i64 - 1],
                box_lo: DVec3::splat(-1e9),
                box_hi: DVec3::splat(1e9),
            },
            rho: rho.clone(),
            skin: None,
            compact: (0..rho.len() as u32).collect(),
            cloud_cells: rho.len(),
            ..coarse
        };
        let (lo, hi) = (coarse.origin_m, coarse.hi());
        let centre = 0.5 * (lo + hi);
        let moments = 9;
        let (mut acc_a, mut acc_b) = (vec![0f32; cloud * moments], vec![0f32; rho.len() * moments]);
        let mut ylm = [0.0; 9];
        let (mut hits, mut misses) = (0, 0);
        for i in 0..4000 {
            let dir = uniform_sphere(r.random(), r.random());
            let scattered = i % 2 == 1;
            let pos = if scattered {
                // Inside the cloud's box.
                origin_m
                    + DVec3::new(
                        (4.0 + 5.0 * r.random::<f64>()) * cell_m.x,
                        (2.0 + 4.0 * r.random::<f64>()) * cell_m.y,
                        (3.0 + 4.0 * r.random::<f64>()) * cell_m.z,
                    )
            } else {
                // Outside the grid, aimed anywhere across it.
                let off = DVec3::new(r.random(), r.random(), r.random()) - DVec3::splat(0.5);
                centre + off * 150.0 - dir * 400.0
            };
            real_sh(dir, 2, &mut ylm);
            let tau = -(1.0 - r.random::<f64>()).ln() * 3.0;
            let w = [1.5];
            let mut a = Photon {
                pos,
                dir,
                scattered,
            };
            let mut b = Photon {
                pos,
                dir,
                scattered,
            };
            let ha = fly_in(
                &coarse, lo, hi, &mut a, tau, 0.1, 1.0, &w, &mut acc_a, 1, &ylm,
            );
            let hb = fly_in(
                &whole, lo, hi, &mut b, tau, 0.1, 1.0, &w, &mut acc_b, 1, &ylm,
            );
            assert_eq!(ha, hb, "photon {i}");
            if ha {
                assert_eq!(a.pos, b.pos, "photon {i}");
                hits += 1;
            } else {
                misses += 1;
            }
        }
        assert!(hits > 500 && misses > 500, "{hits} {misses}");
        let mut scored = 0;
        let mut k = 0;
        for (c, &density) in rho.iter().enumerate() {
            let b = &acc_b[c * moments..][..moments];
            if density > 0.0 {
                // The cells that hold cloud have their accumulators in the grid's order.
                assert_eq!(coarse.compact[c] as usize, k, "cell {c}");
                assert_eq!(&acc_a[k * moments..][..moments], b, "cell {c}");
                scored += usize::from(b[0] > 0.0);
                k += 1;
            } else {
                assert_eq!(coarse.compact[c], u32::MAX, "cell {c}");
                assert!(b.iter().all(|&v| v == 0.0), "cell {c}");
            }
        }
        assert!(scored > 50, "{scored}");
    }

    /// The reconstruction's phase moments: the δ-M moments, never negative, and the true moments
    /// without truncation.
    #[test]
    fn scaled_moments_are_the_delta_m_moments() {
        let t = Truncation::new(0.85, 1.0, 3.5);
        let p = scaled_moments(&t, 4);
        let f = 0.85f64.powf(3.5);
        assert!((p[1] - t.g_scaled).abs() < 1e-12 && (p[2] - t.p2_scaled).abs() < 1e-12);
        assert!((p[3] - (0.85f64.powi(3) - f) / (1.0 - f)).abs() < 1e-12);
        assert_eq!(p[4], 0.0);
        let none = scaled_moments(&Truncation::new(0.5, 1.0, 0.0), 4);
        assert!((none[3] - 0.125).abs() < 1e-12);
    }
}
