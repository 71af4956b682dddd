//! Precise multiple scattering by successive orders on the spherical planet (the method of
//! Bruneton & Neyret 2008 / Bruneton 2017, reorganised for CPUs), with ground bounce.
//!
//! Fields live on a regular grid over (r, θ, θ_s, φ): radius, view zenith, sun zenith and view
//! azimuth relative to the sun (φ ∈ [0, π] by symmetry). For order n:
//!
//! - L_n(x, ω) = ∫ T(x, y) J_n(y, ω) ds + T(x, g)(a/π) E_{n−1}(g) along the ray (L_1 is exact single
//!   scattering plus the ground's reflection of direct sun, E_0 = direct irradiance);
//! - E_n = ∫ L_n(ground, ω) cosθ dω, the sky irradiance on the ground;
//! - J_{n+1}(x, ω) = Σ_c σ_c(x) ∫ p_c(ω·ω′) L_n(x, ω′) dω′ — at fixed (r, θ_s) this is a matrix
//!   product with a phase matrix whose entries are the phase function integrated over each
//!   direction cell (rows normalised to exactly 1, so the angular quadrature conserves energy).
//!
//! J is tabulated per constituent and per unit scattering coefficient, Â_c = ∫ p_c L dω
//! (J = Σ_c σ_c(r) Â_c), and multiplied by σ_c at the radius where it is used, so the radial
//! interpolation does not have to follow the density profiles (see [`PreciseMultipleScattering`]).
//!
//! Speed comes from the layout, not from coarser physics:
//!
//! - All cells with the same (r, θ) share one ray: its points, densities and viewer-to-point
//!   transmittance T(λ) are computed once per order for the n_θs × n_φ cells of that "ray
//!   family" (only the sun-dependent lookup differs), and J_n is first interpolated in (r, θ) at
//!   each point into a (θ_s, φ) slice, so each cell's lookup is bilinear instead of 16-corner;
//! - the J pass is the phase matrix's product over directions taken in azimuthal cosine space,
//!   where it is n_φ small products of view-zenith blocks ([`AzimuthalPhase`]);
//! - the interpolation positions of the radiance pass depend on the geometry only: the first
//!   order ≥ 2 records them per ray family and later orders read them ([`PositionCache`]);
//! - inner loops run over wavelengths and are compiled for AVX2 + FMA when the CPU has them, with
//!   polynomial `exp`/`ln` in f32 in the radiance passes (J is stored in f32; optical depth itself
//!   is summed in f64);
//! - the series Σ L_n settles to a geometric one (ratio q ≈ 0.46 on `earth`, ≈ 0.69 hazy): once
//!   the ratio per (sun zenith, λ) is stable, the tail J_n q/(1 − q) is added in closed form
//!   (Aitken-style geometric extrapolation) instead of marching on. Orders stop when the last
//!   order adds less than `tolerance` (0.1 %) of the total, or earlier when the estimated error
//!   of the extrapolated tail (tail × 2|Δq|/(1 − q)) is below it; the tail's size and error
//!   estimate are reported in [`Convergence`].
//!
//! Products integrate J_ms = Σ_{n≥2} J_n along their own rays at full resolution, beside exact
//! single scattering, so the table only has to resolve the smooth multiple part.

use super::geometry::{horizon_mu, radius_at, safe_sqrt};
use super::integrate::{cell_transmittance, ray_points, RayPoint, RaySample, Source};
use super::kernels::{acos_fast, exp_fast, exp_fast_f32, ln_fast, ln_fast_f32};
use super::medium::{Medium, CONSTITUENTS, MIE, RAYLEIGH};
use super::quadrature::grid_pos;
use super::transmittance::DensityIntegralTable;
use crate::image::SpectralImage;
use crate::phase::Phase;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};

mod twilight_batch;
mod twilight_bundle;

/// Sun zenith angle, degrees, beyond which the sun-zenith nodes of the precise tables are twice as
/// dense and J and the ground's sky irradiance are interpolated over sun zenith in ln J
/// (Catmull–Rom, [`twilight_interp`]) instead of linearly in J (accuracy of the twilight sky).
///
/// Across the terminator J falls by about an order of magnitude per table step in sun zenith (the
/// lower atmosphere then sees only light scattered from the lit air above it and towards the
/// sun), so linear interpolation overestimates it between nodes: by 30–100 % in the sky away from
/// the sun at −2° to −9° (against tools/spherical_mc.py). ln J is smooth beyond the terminator
/// and nearly linear there. Near it, where each height's own sunset puts a kink in J, neither
/// interpolant is good on the uniform grid (at sunset, view zenith 89°: −3.4 % in ln J, +1.3 %
/// linear at 550 nm, +4.0 % linear at 440 nm and sun 2°), hence the denser nodes: 2.1 % max at
/// sun ≥ 0°, 3.2 % to −6° (tests/atmosphere/atmosphere_twilight.rs, quality `standard`).
///
/// By day J is smooth and nearly linear in sun zenith; there the uniform grid and the linear
/// interpolation are kept (the daytime DISORT figures are unchanged: applying ln-J Catmull–Rom
/// everywhere had moved the plane-parallel deviation from 0.26 % to 0.53 % and the energy of the
/// plane-parallel albedo-1 case to 0.998). A cell is a twilight cell when its far node lies beyond
/// this angle (sun elevation 10°); the two interpolants agree at the nodes, so the result is
/// continuous.
pub const TWILIGHT_INTERP_FROM_DEG: f64 = 80.0;

/// The largest local sun zenith angle, radians, at which the precise tables hold a source (J and
/// the ground's sky irradiance); beyond it both are zero. Beyond 12° below the top's horizon no
/// point of the atmosphere sees any light worth tabulating.
pub fn source_sun_zenith_limit_rad(bottom_radius_m: f64, top_radius_m: f64) -> f64 {
    (horizon_mu(top_radius_m, bottom_radius_m).acos() + 12f64.to_radians()).min(PI)
}

/// Resolution and convergence settings of the precise method.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PreciseSettings {
    pub n_r: usize,
    pub n_mu_s: usize,
    pub n_mu: usize,
    pub n_phi: usize,
    /// Samples per ray segment when integrating J along table rays.
    pub steps: usize,
    /// Stop when the last order adds less than this fraction of the total, or when the
    /// estimated error of the extrapolated tail is below it.
    pub tolerance: f64,
    /// Never compute more orders than this.
    pub max_orders: usize,
    /// Cells whose centre lies within this angle of the local horizon are averaged over sub-rays.
    pub horizon_band_rad: f64,
    /// Sub-rays per cell (per side of the horizon) in that band.
    pub horizon_subrays: usize,
    /// Whether the geometric tail of the series may end it early (and is added in any case).
    pub extrapolate_tail: bool,
}

impl Default for PreciseSettings {
    fn default() -> Self {
        Self {
            n_r: 20,
            n_mu_s: 28,
            n_mu: 32,
            n_phi: 12,
            steps: 20,
            tolerance: 1e-3,
            max_orders: 60,
            horizon_band_rad: 10f64.to_radians(),
            horizon_subrays: 3,
            extrapolate_tail: true,
        }
    }
}

/// Convergence record of one precise computation.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Convergence {
    /// Number of scattering orders computed explicitly (including the first).
    pub orders: usize,
    /// Fraction of the total that the last computed order added.
    pub last_order_fraction: f64,
    /// Fraction each computed order added, in order.
    pub order_fractions: Vec<f64>,
    /// Fraction of the total radiance that the extrapolated geometric tail adds (0 without one).
    pub tail_fraction: f64,
    /// Estimated relative error of the summed series (the tail's error estimate, or the last
    /// order's fraction × q/(1 − q) when nothing was extrapolated).
    pub series_error_estimate: f64,
    /// Mean ratio of the last two orders' radiance (the geometric ratio q of the tail).
    pub order_ratio: f64,
    /// Wall-clock time of each stage of the build.
    pub stage_ms: StageTimes,
}

/// Wall-clock time of the stages of one precise build, ms.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StageTimes {
    /// Phase matrices and the order-1 (single-scattering) radiance pass.
    pub single_scattering: f64,
    /// All J passes (phase-matrix products).
    pub scattering_density: f64,
    /// All radiance passes of orders ≥ 2.
    pub radiance: f64,
    /// The whole build.
    pub total: f64,
}

/// The converged multiple-scattering source J_ms = Σ_{n≥2} J_n and ground sky irradiance.
///
/// The tables hold, per constituent c (Rayleigh, Mie), the phase-weighted in-scattered radiance
/// Â_c = ∫ p_c(ω·ω′) L(ω′) dω′ (sr⁻¹ per unit solar irradiance), so J = σ_R ρ_R(r) Â_R +
/// σ_M ρ_M(r) Â_M; every lookup multiplies by the densities at the sample's own radius. Â_c is
/// smooth in r (the radiance field is), J is not: it carries the density profiles, and an aerosol
/// of scale height 1.2 km falls by a factor 2–3 between the radius nodes near the ground (0, 0.28,
/// 1.1, 2.5, 4.4 km at `standard`), where interpolating J linearly overestimated it by up to 17 %
/// (19 % for a 50/50 mixture at 2.5–4.4 km) mid-interval. That bias fed every order's radiance
/// pass and the products, and read as a hazy sky 3–5 % bright away from the sun against DISORT
/// (+2.7 % still at `high`). One table of J/σ_s (σ_s the total) is not enough: the aerosol's
/// share of σ_s changes from 0.9 to 0.4 over the same nodes, and Â_R and Â_M differ by a factor
/// ~10 away from the aureole (measured: −4.9 % low sky at 440 nm with it).
pub struct PreciseMultipleScattering {
    grid: Grid,
    n_l: usize,
    /// `[i_r][i_mu][i_mu_s][i_phi][c][λ]`, Â_R then Â_M of orders ≥ 2 (`2 n_l` lanes per cell),
    /// sr⁻¹ per unit solar irradiance.
    j_ms: Vec<f32>,
    /// σ_s(r) per λ: the scattering coefficients at relative density 1 and their profiles.
    scattering: ScatteringCoefficient,
    /// `[i_mu_s][λ]`, sky irradiance on the ground per unit solar irradiance.
    ground_sky: Vec<f64>,
    pub convergence: Convergence,
    /// `j_ms` and its logarithms ([`ln_or_zero_f32`]) on the sun-zenith nodes twilight cells
    /// interpolate, prepared once on first use by [`Self::slice`] callers ([`Self::ln_j_ms`]).
    ln_j_ms: std::sync::OnceLock<TwilightRows>,
}

/// The sun-zenith nodes twilight cells interpolate, prepared once per table for
/// [`PreciseMultipleScattering::add_from_slice`] ([`PreciseMultipleScattering::ln_j_ms`]).
#[derive(Debug, Default)]
struct TwilightRows {
    /// The first sun-zenith node a twilight cell's Catmull–Rom reads (twilight cells from
    /// `from + 1` on).
    from: usize,
    /// The first twilight cell ([`Grid::twilight_cell`] holds from there on).
    first_cell: usize,
    /// 2 n_λ ≤ [`PACKED_LANES`]: `[i_r][i_mu][i_mu_s − from][v | ln v][i_phi]`, each
    /// azimuth node's lanes of `j_ms` (then their [`ln_or_zero_f32`]) as Â_R's n_λ lanes padded
    /// with zeros to [`PACKED_HALF`], then Â_M's likewise (so Â_M is always the upper half of a
    /// node's vector): two adjacent azimuth nodes' values (or logarithms) are one run of
    /// 2 [`PACKED_LANES`] lanes ([`packed_runs`]); empty otherwise.
    packed: Vec<f32>,
    /// 2 n_λ > [`PACKED_LANES`]: [`ln_or_zero_f32`] of `j_ms`,
    /// `[i_r][i_mu][i_mu_s − from][i_phi][c][λ]`; empty otherwise.
    ln: Vec<f32>,
}

/// Lanes of one node in [`TwilightRows::packed`]: one AVX2 vector of f32.
const PACKED_LANES: usize = 8;
/// Lanes of one constituent in a node of [`TwilightRows::packed`] (Â_R in the lower half, Â_M
/// in the upper).
const PACKED_HALF: usize = PACKED_LANES / 2;

/// The table grid. Sun zenith nodes are uniform (`n_coarse` nodes over [0, θ_s max], the
/// settings' `n_mu_s`) up to the last node before [`TWILIGHT_INTERP_FROM_DEG`], then twice as dense
/// to θ_s max, where J changes fastest (across the terminator); `s.n_mu_s` is the total count.
/// The daytime nodes, and the interpolation between them, are those of the uniform grid.
#[derive(Debug, Clone)]
struct Grid {
    s: PreciseSettings,
    bottom: f64,
    top: f64,
    /// Radius nodes of the settings' uniform grid in x = ρ/H (`s.n_r` counts all nodes).
    n_r_base: usize,
    /// `[k]`: index of the node at base node k ([`Self::radius_nodes`]), `n_r_base` entries.
    r_first: Vec<usize>,
    /// `[i]`: radius of node i, m.
    r_nodes: Vec<f64>,
    theta_s_max: f64,
    /// Nodes of the uniform grid the settings ask for.
    n_coarse: usize,
    /// Index of the last uniform node; twice-as-dense nodes follow it.
    j_fine: usize,
    /// Rays per view-zenith band of the order-1 pass away from the horizon ([`single_subrays`]):
    /// [`SINGLE_SUBRAYS`] at `high` and finer ([`HIGH_FROM_N_MU`], the preset's count), else 1.
    single_subrays: usize,
}

impl Grid {
    fn new(s: PreciseSettings, medium: &Medium) -> Self {
        let (bottom, top) = (medium.bottom_radius_m, medium.top_radius_m);
        let single_subrays = if s.n_mu >= HIGH_FROM_N_MU {
            SINGLE_SUBRAYS
        } else {
            1
        };
        let s = dense_forward_settings(s, medium);
        let n_r_base = s.n_r.max(2);
        let r_first = radius_nodes(medium, n_r_base);
        let n_r = r_first[n_r_base - 1] + 1;
        let n_phi = azimuth_nodes(medium, s.n_phi);
        let r_nodes = (0..n_r_base - 1)
            .flat_map(|k| {
                let m = r_first[k + 1] - r_first[k];
                (0..m).map(move |j| (k as f64 + j as f64 / m as f64) / (n_r_base - 1) as f64)
            })
            .chain([1.0])
            .map(|x| r_of_x(x, bottom, top))
            .collect();
        let theta_s_max = source_sun_zenith_limit_rad(bottom, top);
        let n_coarse = s.n_mu_s.max(2);
        let step = theta_s_max / (n_coarse - 1) as f64;
        let j_fine =
            ((TWILIGHT_INTERP_FROM_DEG.to_radians() / step).floor() as usize).min(n_coarse - 1);
        Self {
            s: PreciseSettings {
                n_mu_s: j_fine + 1 + 2 * (n_coarse - 1 - j_fine),
                n_r,
                n_phi,
                ..s
            },
            bottom,
            top,
            n_r_base,
            r_first,
            r_nodes,
            theta_s_max,
            n_coarse,
            j_fine,
            single_subrays,
        }
    }
    /// Interpolation position `(i, f)` of sun zenith `theta_s` (radians) on the sun-zenith nodes.
    #[inline(always)]
    fn s_pos(&self, theta_s: f64) -> (usize, f64) {
        let f = (theta_s / self.theta_s_max).clamp(0.0, 1.0) * (self.n_coarse - 1) as f64;
        if f < self.j_fine as f64 {
            // By day exactly `grid_pos` on the uniform grid.
            let i = (f.floor() as usize).min(self.n_coarse.saturating_sub(2));
            return (i, f - i as f64);
        }
        let g = self.j_fine as f64 + 2.0 * (f - self.j_fine as f64);
        let i = (g.floor() as usize).min(self.s.n_mu_s.saturating_sub(2));
        (i, g - i as f64)
    }
    /// [`Self::s_pos`] with the node index as a float, branch-free (for loops that vectorise);
    /// the same values.
    #[inline(always)]
    fn s_pos_f(&self, theta_s: f64) -> (f64, f64) {
        self.sun_nodes().pos_f(theta_s)
    }
    /// The sun-zenith nodes' parameters, copied out of the grid (for loops that must not
    /// reload them through a pointer).
    #[inline(always)]
    fn sun_nodes(&self) -> SunZenithNodes {
        SunZenithNodes {
            theta_s_max: self.theta_s_max,
            n_coarse: self.n_coarse,
            j_fine: self.j_fine,
            n_mu_s: self.s.n_mu_s,
        }
    }
    fn dirs(&self) -> usize {
        self.s.n_mu * self.s.n_phi
    }
    /// Cells of one ray family (one (r, θ)): all sun zeniths and azimuths.
    fn family_cells(&self) -> usize {
        self.s.n_mu_s * self.s.n_phi
    }
    fn cells(&self) -> usize {
        self.s.n_r * self.s.n_mu_s * self.dirs()
    }
    /// Radius of node `i`, m.
    fn r(&self, i: usize) -> f64 {
        self.r_nodes[i]
    }
    /// Interpolation position `(i, f)` of radius `r` on the radius nodes: linear in x = ρ/H
    /// (ρ the distance to the horizon), as on the uniform grid of `n_r_base` nodes, whose
    /// intervals [`radius_nodes`] divides into equal parts in x.
    #[inline(always)]
    fn r_pos(&self, r: f64) -> (usize, f64) {
        let h = safe_sqrt(self.top * self.top - self.bottom * self.bottom);
        let x = safe_sqrt(r * r - self.bottom * self.bottom) / h;
        let (k, t) = grid_pos(x, self.n_r_base);
        let (i0, m) = (self.r_first[k], self.r_first[k + 1] - self.r_first[k]);
        if m == 1 {
            return (i0, t);
        }
        let g = t * m as f64;
        let j = (g.floor() as usize).min(m - 1);
        (i0 + j, g - j as f64)
    }
    fn theta_s(&self, j: usize) -> f64 {
        if j <= self.j_fine {
            self.theta_s_max * j as f64 / (self.n_coarse - 1) as f64
        } else {
            let x = self.j_fine as f64 + 0.5 * (j - self.j_fine) as f64;
            self.theta_s_max * x / (self.n_coarse - 1) as f64
        }
    }
    /// Whether the sun-zenith interval `[θ_s(is), θ_s(is + 1)]` reaches past
    /// [`TWILIGHT_INTERP_FROM_DEG`], where the tables are interpolated in ln J.
    #[inline(always)]
    fn twilight_cell(&self, is: usize) -> bool {
        self.theta_s(is + 1) > TWILIGHT_INTERP_FROM_DEG.to_radians()
    }
    /// View zenith of direction node `k` (cell centres, uniform in angle).
    fn theta(&self, k: usize) -> f64 {
        PI * (k as f64 + 0.5) / self.s.n_mu as f64
    }
    fn phi(&self, l: usize) -> f64 {
        PI * (l as f64 + 0.5) / self.s.n_phi as f64
    }
    /// [`Self::centred_pos`] with the node index as a float, branch-free; the same values.
    #[inline(always)]
    fn centred_pos_f(angle: f64, n: usize) -> (f64, f64) {
        let f = (angle / PI * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i = f.floor().min(n.saturating_sub(2) as f64);
        (i, f - i)
    }
    /// The two view-zenith corners `(node, weight, pole)` of view zenith `theta` (radians) on the
    /// cell-centred grid of `n` nodes: between two nodes, linear ([`Self::centred_pos`]); within
    /// half a step of a pole (θ < π/2n or θ > π − π/2n), linear between the first (last) node and
    /// the pole, whose value is the mean of that node's `n_φ` azimuth nodes (`pole` = true).
    ///
    /// The pole is where the view direction's azimuth is undefined and the field is a function
    /// of (r, θ_s) only: near it L(θ, φ) = L_pole + a θ cos φ + O(θ²) (the field is smooth on the
    /// sphere of directions), so the mean of the node's azimuths is L_pole to O(θ_node²) and the
    /// interpolation at the point's own azimuth is exact to first order. Holding the first node
    /// there instead (clamping) reads at the zenith the value at the first node's angle
    /// (2.8° at `standard`) on the sun's side (the azimuth is taken as 0 when undefined): with
    /// a forward-scattering aerosol J_ms grows towards the sun, and the zenith sky with the sun
    /// at 40° read +2.3 % (AOD 0.4, g 0.7) to +3.4 % (g 0.8) high against DISORT.
    #[inline(always)]
    fn theta_corners(theta: f64, n: usize) -> [(usize, f64, bool); 2] {
        let half = 0.5 * PI / n as f64;
        if theta < half {
            let t = (theta / half).max(0.0);
            [(0, t, false), (0, 1.0 - t, true)]
        } else if theta > PI - half {
            let t = ((PI - theta) / half).max(0.0);
            [(n - 1, t, false), (n - 1, 1.0 - t, true)]
        } else {
            let (i, f) = Self::centred_pos(theta, n);
            [(i, 1.0 - f, false), (i + 1, f, false)]
        }
    }
    /// Interpolation position of azimuth `phi` (radians, [0, π]) on the cell-centred azimuth grid
    /// of `n` nodes: linear between nodes ([`Self::centred_pos`]); within half a step of 0 or π,
    /// where the grid ends at a mirror plane (the field is even in φ about 0 and π), quadratic in
    /// φ through the two nearest nodes and even about the edge, so the weight goes slightly
    /// outside [0, 1] (from −1/8 at the edge to 0 at the first node).
    ///
    /// A forward-scattering aerosol's J_ms peaks in the sun's vertical plane (φ = 0) near the
    /// sun; holding the first node's value (7.5° at `standard`) across the last half step reads
    /// the flank of that peak, not its ridge: the sky 15° above a sun at 75° read −3 % (g 0.8)
    /// to −7 % (Cornette-Shanks g 0.8, optical depth 1) against DISORT.
    #[inline(always)]
    fn phi_pos(phi: f64, n: usize) -> (usize, f64) {
        let (i, f) = Self::phi_pos_f(phi, n);
        (i as usize, f)
    }
    /// [`Self::phi_pos`] with the node index as a float, branch-free; the same values.
    #[inline(always)]
    fn phi_pos_f(phi: f64, n: usize) -> (f64, f64) {
        let (i, f) = Self::centred_pos_f(phi, n);
        if n < 2 {
            return (i, f);
        }
        let h = 0.5 * PI / n as f64;
        let (lo, hi) = (phi * phi, (PI - phi) * (PI - phi));
        let inv = 1.0 / (8.0 * h * h);
        if phi < h {
            (0.0, (lo - h * h) * inv)
        } else if phi > PI - h {
            ((n - 2) as f64, 1.0 - (hi - h * h) * inv)
        } else {
            (i, f)
        }
    }
    /// Interpolation position on a cell-centred grid of `n` nodes over [0, π].
    #[inline(always)]
    fn centred_pos(angle: f64, n: usize) -> (usize, f64) {
        let f = (angle / PI * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i = (f.floor() as usize).min(n.saturating_sub(2));
        (i, f - i as f64)
    }
}

/// The sun-zenith nodes of a [`Grid`] ([`Grid::sun_nodes`]).
#[derive(Debug, Clone, Copy)]
struct SunZenithNodes {
    theta_s_max: f64,
    n_coarse: usize,
    j_fine: usize,
    n_mu_s: usize,
}

impl SunZenithNodes {
    /// [`Grid::s_pos`] with the node index as a float, branch-free (for loops that vectorise);
    /// the same values.
    #[inline(always)]
    fn pos_f(&self, theta_s: f64) -> (f64, f64) {
        let f = (theta_s / self.theta_s_max).clamp(0.0, 1.0) * (self.n_coarse - 1) as f64;
        let jf = self.j_fine as f64;
        let i_day = f.floor().min(self.n_coarse.saturating_sub(2) as f64);
        let g = jf + 2.0 * (f - jf);
        let i_dusk = g.floor().min(self.n_mu_s.saturating_sub(2) as f64);
        if f < jf {
            (i_day, f - i_day)
        } else {
            (i_dusk, g - i_dusk)
        }
    }
}

/// Radius at x = ρ/H on the grid between `bottom` and `top` (ρ the distance to the horizon, H
/// its value at the top).
fn r_of_x(x: f64, bottom: f64, top: f64) -> f64 {
    let h = safe_sqrt(top * top - bottom * bottom);
    let rho = h * x;
    safe_sqrt(rho * rho + bottom * bottom)
}

/// Vertical optical depth (extinction, at the wavelength where it is largest) above which a radius
/// interval of the uniform grid is too thick for the precise table ([`radius_nodes`]).
const THICK_INTERVAL_OPTICAL_DEPTH: f64 = 0.75;

/// Mean vertical optical depth of the parts an interval of the uniform radius grid is divided into
/// in an atmosphere with an interval thicker than [`THICK_INTERVAL_OPTICAL_DEPTH`].
const MAX_INTERVAL_OPTICAL_DEPTH: f64 = 0.15;

/// Most parts one interval of the uniform radius grid is divided into.
const MAX_INTERVAL_PARTS: usize = 16;

/// Vertical optical depth of each interval of the uniform radius grid of `n_base` nodes (x = ρ/H
/// from 0 to 1), at the wavelength where it is largest: the density integrals over the interval's
/// heights (midpoint rule, 64 samples) times the extinction coefficients.
fn interval_optical_depths(medium: &Medium, n_base: usize) -> Vec<f64> {
    let (bottom, top) = (medium.bottom_radius_m, medium.top_radius_m);
    const SAMPLES: usize = 64;
    (0..n_base - 1)
        .map(|k| {
            let x = |t: f64| (k as f64 + t) / (n_base - 1) as f64;
            let h0 = r_of_x(x(0.0), bottom, top) - bottom;
            let h1 = r_of_x(x(1.0), bottom, top) - bottom;
            let dh = (h1 - h0) / SAMPLES as f64;
            let mut d = [0.0; CONSTITUENTS];
            for i in 0..SAMPLES {
                let h = h0 + (i as f64 + 0.5) * dh;
                for (c, dc) in d.iter_mut().enumerate() {
                    *dc += medium.profiles[c].density(h) * dh;
                }
            }
            (0..medium.len())
                .map(|i| medium.optical_depth(i, &d))
                .fold(0.0, f64::max)
        })
        .collect()
}

/// The radius and azimuth node counts the precise table of `medium` is built on from the preset's
/// settings `s`: the radius grid divided where the aerosol is optically thick ([`radius_nodes`]),
/// the azimuth nodes doubled for a strongly forward aerosol ([`azimuth_nodes`]); for predicting a
/// table's cost before it is built.
pub fn table_radius_and_azimuth_nodes(s: &PreciseSettings, medium: &Medium) -> (usize, usize) {
    let s = dense_forward_settings(*s, medium);
    let n_r_base = s.n_r.max(2);
    let n_r = radius_nodes(medium, n_r_base)[n_r_base - 1] + 1;
    (n_r, azimuth_nodes(medium, s.n_phi))
}

/// The sun-zenith (the uniform grid's, as the settings' `n_mu_s`) and view-zenith node counts of
/// the precise table of `medium` from the preset's settings `s` (more for a dense strongly forward
/// aerosol, [`dense_forward_settings`]); with [`table_radius_and_azimuth_nodes`], for predicting a
/// table's cost before it is built.
pub fn table_zenith_nodes(s: &PreciseSettings, medium: &Medium) -> (usize, usize) {
    let s = dense_forward_settings(*s, medium);
    (s.n_mu_s, s.n_mu)
}

/// The radius nodes of the precise table. Returns, per node of the uniform grid in x = ρ/H of
/// `n_base` nodes, the index of that node on the table's grid (the last + 1 is the node count).
///
/// Where no interval of the uniform grid holds more than [`THICK_INTERVAL_OPTICAL_DEPTH`] of
/// vertical optical depth at any wavelength (clear air, and haze up to optical depth ~1.2 at
/// 550 nm, `earth-hazy` included: 0.62 at 380 nm), the grid is the uniform one. Otherwise every
/// interval is divided into m equal parts in x, m the least integer for which the parts hold no
/// more than [`MAX_INTERVAL_OPTICAL_DEPTH`] on average (at most [`MAX_INTERVAL_PARTS`]; h grows as
/// x², so an interval's upper parts hold more than its lower ones, up to twice the mean).
///
/// The tables hold Â_c (see [`PreciseMultipleScattering`]), smooth in r in thin air but not in
/// thick haze, where the radiance field changes over an optical depth of order 1 (divided by the
/// cosine of a low sun: the direct beam's source e^(−τ/μ_s), Chandrasekhar 1960 § 1.3). With an
/// aerosol of optical depth 2 at 550 nm (2.7 at 440 nm) and scale height 1.2 km, the lowest
/// intervals of the uniform grid at `standard` (0–0.28, 0.28–1.1, 1.1–2.5 km) hold 0.56, 1.09 and
/// 0.76; interpolating linearly across them read the low sky round a sun at zenith 75° +16 % high
/// against DISORT (+9.9 % with 30 uniform nodes, +5.6 % with 40, +3.4 % with 60). Divided into
/// parts of ≤ 0.6 on average it read +11 %, ≤ 0.4 +4.2 %, ≤ 0.2 +2.7 %, ≤ 0.15 +2.4 % (37 nodes). The
/// threshold keeps the uniform grid, and its cost, for `earth-hazy` (the precise tables' cold
/// build is budgeted there); atmospheres between it and the threshold keep the uniform grid's
/// error (≤ 0.62 per interval: measured −5 % in the AOD 1 DISORT case, the azimuth nodes').
fn radius_nodes(medium: &Medium, n_base: usize) -> Vec<usize> {
    let taus = interval_optical_depths(medium, n_base);
    let thick = taus.iter().any(|&t| t > THICK_INTERVAL_OPTICAL_DEPTH);
    let mut first = Vec::with_capacity(n_base);
    first.push(0);
    for (k, &tau) in taus.iter().enumerate() {
        let m = if thick {
            ((tau / MAX_INTERVAL_OPTICAL_DEPTH).ceil() as usize).clamp(1, MAX_INTERVAL_PARTS)
        } else {
            1
        };
        first.push(first[k] + m);
    }
    first
}

/// Mean cosine of the aerosol's phase function ([`Phase::mean_cosine`]) from which the precise
/// table's azimuth nodes are doubled ([`azimuth_nodes`]).
const FORWARD_MEAN_COSINE: f64 = 0.78;

/// Vertical aerosol scattering optical depth (at the wavelength where it is largest) from which
/// the precise table's azimuth nodes are doubled in a strongly forward aerosol ([`azimuth_nodes`]).
const FORWARD_SCATTERING_OPTICAL_DEPTH: f64 = 0.2;

/// The azimuth node count of the precise table: the settings' `n_base`, twice that where the
/// aerosol scatters strongly forward (mean cosine ≥ [`FORWARD_MEAN_COSINE`]) and enough of it
/// (vertical scattering optical depth ≥ [`FORWARD_SCATTERING_OPTICAL_DEPTH`]) that its
/// multiply-scattered light carries the forward peak.
///
/// The J pass convolves the radiance with the phase function over the table's direction cells
/// (cell-centred azimuth bins of 180°/n_φ, 15° at `standard`); light scattered a few times by a
/// peak of mean cosine 0.84 (Cornette-Shanks g 0.8, Nishita et al. 1996 eq. 5) keeps an
/// aureole narrower than a bin, which the bins smear over their neighbours. Against DISORT at
/// `standard` (Cornette-Shanks g 0.8, optical depth 1, ground 0.5, sun at zenith 75°), 12 nodes
/// read the sky 15° above the sun −5.0 % (−5.2 % at 2–10° from it), 18 nodes −3.3 % (−3.9 %), 24
/// nodes −2.9 % (−3.2 %); Henyey-Greenstein g 0.8 of optical depth 0.4 (scattering 0.32 at
/// 550 nm): +2.4 % with 12, −1.5 % with 24. `earth` and `earth-hazy` (Cornette-Shanks g 0.7, mean
/// cosine 0.76) keep the settings' nodes and cost; the table's cost grows about as n_φ (2.1× for
/// the first case).
fn azimuth_nodes(medium: &Medium, n_base: usize) -> usize {
    if aerosol_scattering_optical_depth(medium) >= FORWARD_SCATTERING_OPTICAL_DEPTH
        && medium.mie_phase.mean_cosine() >= FORWARD_MEAN_COSINE
    {
        2 * n_base
    } else {
        n_base
    }
}

/// Vertical aerosol scattering optical depth of `medium`, ground to top, at the wavelength where
/// it is largest.
fn aerosol_scattering_optical_depth(medium: &Medium) -> f64 {
    let column = medium.profiles[MIE].column_m(medium.top_radius_m - medium.bottom_radius_m);
    medium
        .mie_scattering_per_m
        .iter()
        .map(|&s| s * column)
        .fold(0.0, f64::max)
}

/// Vertical aerosol scattering optical depth (at the wavelength where it is largest) from which a
/// strongly forward aerosol's precise table gets at least [`DENSE_FORWARD_GRID`]
/// ([`dense_forward_settings`]).
const DENSE_FORWARD_SCATTERING_OPTICAL_DEPTH: f64 = 0.8;

/// Least radius nodes of the uniform grid, sun-zenith nodes (uniform part, as the settings'
/// `n_mu_s`), view-zenith nodes and ray steps of the precise table in a dense strongly forward
/// aerosol ([`dense_forward_settings`]).
const DENSE_FORWARD_GRID: PreciseSettings = PreciseSettings {
    n_r: 30,
    n_mu_s: 42,
    n_mu: 48,
    n_phi: 0,
    steps: 28,
    tolerance: 0.0,
    max_orders: 0,
    horizon_band_rad: 0.0,
    horizon_subrays: 0,
    extrapolate_tail: false,
};

/// View-zenith nodes of a preset from which [`dense_forward_settings`] applies its floor: `standard`
/// and finer. `draft` (24) keeps its grid and cost in every aerosol: it is the coarse preset, which
/// states ≥ 5 % in haze (the planner runs `standard` there for a retired `fast` request), and on
/// the floor it would cost as much as `standard` does there.
const DENSE_FORWARD_FROM_N_MU: usize = 32;

/// View-zenith nodes of a preset from which the refinements for a 1 % bound apply: `high` (40)
/// and `reference` (48). They are the radius floor [`DENSE_FORWARD_HIGH_N_R`], the azimuth and step
/// floors [`DENSE_HIGH_N_PHI`] and [`DENSE_HIGH_STEPS`] ([`dense_forward_settings`]) and the
/// order-1 pass's [`SINGLE_SUBRAYS`] rays per view-zenith band ([`single_subrays`]).
const HIGH_FROM_N_MU: usize = 40;

/// Least radius nodes (uniform grid) of the precise table at `high` and finer in a dense strongly
/// forward aerosol ([`dense_forward_settings`]).
const DENSE_FORWARD_HIGH_N_R: usize = 60;

/// Least azimuth nodes (before [`azimuth_nodes`] doubles them in a strongly forward aerosol) of
/// the precise table at `high` and finer in a dense aerosol ([`dense_forward_settings`]).
const DENSE_HIGH_N_PHI: usize = 24;

/// Least ray steps of the precise table at `high` and finer in a dense aerosol that is not
/// strongly forward ([`dense_forward_settings`]).
const DENSE_HIGH_STEPS: usize = 40;

/// The settings the precise table of `medium` is built with from the preset's `s`: `s` itself,
/// or, at `standard` and finer ([`DENSE_FORWARD_FROM_N_MU`]), where the aerosol scatters strongly forward (mean cosine ≥ [`FORWARD_MEAN_COSINE`]) and is
/// dense (vertical scattering optical depth ≥ [`DENSE_FORWARD_SCATTERING_OPTICAL_DEPTH`]), `s` with
/// at least the radius, sun-zenith and view-zenith nodes and ray steps of [`DENSE_FORWARD_GRID`]
/// (30, 42, 48, 28: `standard`'s 20, 28, 32, 20 × 1.5, 1.5, 1.5, 1.4; `high` gets 30, 42, 48, 28
/// instead of 28, 36, 40, 28).
///
/// In such an aerosol the light scattered a few times keeps the forward peak, in view zenith as in
/// azimuth ([`azimuth_nodes`]), and near a low sun in the low sky (sun and view zenith 75°) most
/// of the diffuse radiance is light scattered 2–5 times through small angles. Its source changes
/// over a few degrees of view and sun zenith and, the scattering optical depth being of order 1,
/// over the aerosol's scale height. The resolution such a peak needs is an angle and a height,
/// not a fraction of the preset's grid, hence a floor rather than a factor. Against DISORT at
/// `standard` (Cornette-Shanks g 0.8, optical depth 1, ground 0.5; ≥ 10° / 2–10° from the sun,
/// largest over 440–680 nm and sun zenith 0–75°; the probe `aerosol_probe`): the settings' grid
/// −2.88 / −3.18 %; 30 radius nodes +2.45 / −2.55 % (sun zenith 0° and 75° pulling opposite
/// ways); 48 view-zenith nodes −2.39 / −2.56 %; 42 sun-zenith nodes −2.58 / −2.94 %; 40 steps
/// −3.06 / −3.29 %; 30 radius and 48 view-zenith nodes +2.23 / −1.97 %, and 28 steps +2.15 /
/// −2.08 %, and 42 sun-zenith nodes (this floor) +1.85 / −1.79 % (through the `sky` and `sun`
/// requests, tests/atmosphere/atmosphere_aerosol.rs: +2.27 / +1.86 %, the first at 440 nm, sun
/// and view zenith 75°, 19° from the sun, where the optical depth is 1.34). No one of them closes
/// it alone; a grid beyond any preset (40, 42, 48 nodes, 48 azimuth nodes, 60 steps, orders to
/// 10⁻⁴) reads −1.26 / −1.16 %. An aerosol of mean cosine 0.84 but scattering optical depth 0.43
/// (HG g 0.8, ssa 0.8, optical depth 0.4 at 550 nm) is within 2 % on the settings' grid. `earth`
/// and `earth-hazy` (Cornette-Shanks g 0.7, mean cosine 0.76) keep the settings and their cost at
/// `standard`; the table's build costs 6.2× the CPU time at `standard` (measured, 3 wavelengths).
///
/// At `high` and finer ([`HIGH_FROM_N_MU`]), which state 1 %, three more floors apply:
/// - in a dense strongly forward aerosol, [`DENSE_FORWARD_HIGH_N_R`] (60) radius nodes instead of
///   30: near a low sun the source of the low sky changes along the slant path through the layer
///   over an optical depth of order 1 (the direct beam's e^(−τ/μ_s), Chandrasekhar 1960 § 1.3);
/// - in every dense aerosol (scattering optical depth ≥
///   [`DENSE_FORWARD_SCATTERING_OPTICAL_DEPTH`], forward or not), at least [`DENSE_HIGH_N_PHI`]
///   (24) azimuth nodes, 48 after [`azimuth_nodes`] doubles them in a forward one. The J pass and
///   the radiance read interpolate linearly between azimuth nodes 180°/n_φ apart, and beside a low
///   sun (sun zenith 75°, azimuth 5–10°, 5–11° from the sun) the light scattered a few times
///   still bends over less than a bin of 16 nodes (11.25°);
/// - in a dense aerosol that is not strongly forward, at least [`DENSE_HIGH_STEPS`] (40) ray steps:
///   its multiply-scattered source spreads over the low sky and the ray integral of J across the
///   optically thick layer (the formal solution of the transfer equation) is then the limit;
///   a strongly forward one reads worse with them (the error of its near-sun low sky changes sign
///   with the steps and the azimuth nodes together), so it keeps 28.
///
/// Together with the order-1 pass's [`SINGLE_SUBRAYS`] rays per band ([`single_subrays`]), against
/// DISORT at `high` (32 streams, delta-M; the probe `aerosol_probe` with `high`'s settings, ≥ 10° /
/// 2–10° from the sun, largest over 440/550/680 nm and sun zenith 0/40/75°): Cornette-Shanks g 0.8
/// of optical depth 1 (ground 0.5) reads 1.51 % on `high`'s grid with 30 radius nodes, 1.36 % with
/// 60 radius nodes and the order-1 rays, 0.98 % with 24 azimuth nodes too, and 1.06 % with 40
/// steps on top; HG g 0.7 of optical depth 2 (scattering 2.4 at 440 nm, mean cosine 0.7) reads
/// 1.20 % on `high`'s grid (at 680 nm, sun zenith 75°, view zenith 60°, azimuth 10°, between the
/// nodes at 0° and 11.25°), 1.09 % with 24 azimuth nodes and 0.89 % with 40 steps too (1.29 % with
/// 40 steps alone). `earth-hazy` (scattering optical depth 1.4 at 380 nm) is dense, so at `high`
/// it gets the azimuth and step floors too.
fn dense_forward_settings(s: PreciseSettings, medium: &Medium) -> PreciseSettings {
    let dense = aerosol_scattering_optical_depth(medium) >= DENSE_FORWARD_SCATTERING_OPTICAL_DEPTH;
    let forward = medium.mie_phase.mean_cosine() >= FORWARD_MEAN_COSINE;
    let high = s.n_mu >= HIGH_FROM_N_MU;
    let mut out = s;
    if s.n_mu >= DENSE_FORWARD_FROM_N_MU && dense && forward {
        let f = DENSE_FORWARD_GRID;
        let n_r_floor = if high { DENSE_FORWARD_HIGH_N_R } else { f.n_r };
        out = PreciseSettings {
            n_r: s.n_r.max(n_r_floor),
            n_mu_s: s.n_mu_s.max(f.n_mu_s),
            n_mu: s.n_mu.max(f.n_mu),
            steps: s.steps.max(f.steps),
            ..s
        };
    }
    if high && dense {
        out.n_phi = out.n_phi.max(DENSE_HIGH_N_PHI);
        if !forward {
            out.steps = out.steps.max(DENSE_HIGH_STEPS);
        }
    }
    out
}

/// The scattering coefficient σ_s(r, λ) = σ_R(λ) ρ_R(r) + σ_M(λ) ρ_M(r) that turns the tables'
/// Ĵ into J (see [`PreciseMultipleScattering`]).
#[derive(Debug, Clone)]
struct ScatteringCoefficient {
    bottom_radius_m: f64,
    profiles: [super::medium::Profile; 2],
    rayleigh_per_m: Vec<f64>,
    mie_per_m: Vec<f64>,
}

impl ScatteringCoefficient {
    fn new(medium: &Medium) -> Self {
        Self {
            bottom_radius_m: medium.bottom_radius_m,
            profiles: [medium.profiles[RAYLEIGH], medium.profiles[MIE]],
            rayleigh_per_m: medium.rayleigh_scattering_per_m.clone(),
            mie_per_m: medium.mie_scattering_per_m.clone(),
        }
    }
    /// (ρ_R, ρ_M) at radius `r_m`.
    #[inline(always)]
    fn densities(&self, r_m: f64) -> (f64, f64) {
        let h = r_m - self.bottom_radius_m;
        (self.profiles[0].density(h), self.profiles[1].density(h))
    }
}

/// The phase matrices of the J pass in azimuthal cosine space.
///
/// The phase matrix of a constituent, P[(k_o, l_o)][(k_i, l_i)] = ∫_{cell (k_i, l_i) and its
/// mirror} p(ω_o·ω) dω (6 × 6 midpoint sub-cells per half, rows normalised to 1), depends on the
/// azimuth bins only through the difference of the output azimuth and the input sub-cell's:
/// P = G(l_o − l_i) + G(−l_o − l_i − 1), with G_{k_o,k_i}(m) the sub-cell sum at azimuth offset
/// (m + ½ − u_b)Δφ, 2n_φ-periodic in m and even (the sub-cell offsets u_b are symmetric). So
/// J(l_o) = Σ_{l_i} P L(l_i) is a circular convolution of G with the mirror-extended radiance,
/// which a cosine transform over the n_φ azimuth bins diagonalises: with
/// C_q = Σ_l L(l) cos(πq(l + ½)/n_φ) and Ĝ_q = Σ_{m<2n_φ} G(m) cos(πqm/n_φ),
/// J(l_o) = (1/n_φ) Σ_{q<n_φ} ε_q Ĝ_q C_q cos(πq(l_o + ½)/n_φ), ε_0 = 1, else 2.
/// The directions × directions product becomes n_φ products of view-zenith blocks
/// (n_φ times fewer operations), and the phase functions are evaluated n_φ times less often.
/// The row sum of P is Σ_{k_i} Ĝ_0, so the normalisation is exact in this form too.
struct AzimuthalPhase {
    /// `[q][k_o][k_i]`: Ĝ_q of the Rayleigh and the Mie phase matrix, rows normalised.
    g_r: Vec<f64>,
    g_m: Vec<f64>,
    /// `[q][l]`: cos(πq(l + ½)/n_φ), the forward transform.
    fwd: Vec<f64>,
    /// `[q][l]`: ε_q/n_φ · cos(πq(l + ½)/n_φ), the inverse transform.
    inv: Vec<f64>,
}

fn azimuthal_phase(grid: &Grid, mie: Phase) -> AzimuthalPhase {
    let (n_mu, n_phi) = (grid.s.n_mu, grid.s.n_phi);
    let n = 2 * n_phi;
    let dphi = PI / n_phi as f64;
    const SUB: usize = 6;
    // `[m][b]`: cosine of the azimuth between an output direction and sub-cell b of the input
    // cell m bins before it.
    let cos_dphi: Vec<f64> = (0..n)
        .flat_map(|m| {
            (0..SUB).map(move |b| ((m as f64 + 0.5 - (b as f64 + 0.5) / SUB as f64) * dphi).cos())
        })
        .collect();
    // `[k][a]`: cosine, sine and solid-angle weight of zenith sub-cell a of bin k.
    let theta_sub: Vec<[f64; 3]> = (0..n_mu)
        .flat_map(|k| {
            let (t0, t1) = (
                PI * k as f64 / n_mu as f64,
                PI * (k + 1) as f64 / n_mu as f64,
            );
            (0..SUB).map(move |a| {
                let th = t0 + (t1 - t0) * (a as f64 + 0.5) / SUB as f64;
                let w = th.sin() * (t1 - t0) / SUB as f64 * dphi / SUB as f64;
                [th.cos(), th.sin(), w]
            })
        })
        .collect();
    // `[q][m]`: cos(πqm/n_φ).
    let dft: Vec<f64> = (0..n_phi)
        .flat_map(|q| (0..n).map(move |m| (PI * (q * m) as f64 / n_phi as f64).cos()))
        .collect();
    // Per output zenith bin: `[q][k_i]` for both phase functions.
    let rows: Vec<[Vec<f64>; 2]> = (0..n_mu)
        .into_par_iter()
        .map(|ko| {
            let th_o = grid.theta(ko);
            let (co, so) = (th_o.cos(), th_o.sin());
            let mut out = [vec![0.0; n_phi * n_mu], vec![0.0; n_phi * n_mu]];
            let (mut g_r, mut g_m) = (vec![0.0; n], vec![0.0; n]);
            for ki in 0..n_mu {
                for m in 0..n {
                    let (mut sr, mut sm) = (0.0, 0.0);
                    for &[ca, sa, w] in &theta_sub[ki * SUB..][..SUB] {
                        for &cd in &cos_dphi[m * SUB..][..SUB] {
                            let c = co * ca + so * sa * cd;
                            sr += Phase::Rayleigh.eval(c) * w;
                            sm += mie.eval(c) * w;
                        }
                    }
                    g_r[m] = sr;
                    g_m[m] = sm;
                }
                for q in 0..n_phi {
                    let d = &dft[q * n..][..n];
                    out[0][q * n_mu + ki] = g_r.iter().zip(d).map(|(g, c)| g * c).sum::<f64>();
                    out[1][q * n_mu + ki] = g_m.iter().zip(d).map(|(g, c)| g * c).sum::<f64>();
                }
            }
            for g in &mut out {
                let row_sum: f64 = g[..n_mu].iter().sum();
                if row_sum > 0.0 {
                    g.iter_mut().for_each(|v| *v /= row_sum);
                }
            }
            out
        })
        .collect();
    let mut g_r = vec![0.0; n_phi * n_mu * n_mu];
    let mut g_m = vec![0.0; n_phi * n_mu * n_mu];
    for (ko, [r, m]) in rows.iter().enumerate() {
        for q in 0..n_phi {
            g_r[(q * n_mu + ko) * n_mu..][..n_mu].copy_from_slice(&r[q * n_mu..][..n_mu]);
            g_m[(q * n_mu + ko) * n_mu..][..n_mu].copy_from_slice(&m[q * n_mu..][..n_mu]);
        }
    }
    let basis = |q: usize, l: usize| (PI * q as f64 * (l as f64 + 0.5) / n_phi as f64).cos();
    let fwd = (0..n_phi * n_phi)
        .map(|x| basis(x / n_phi, x % n_phi))
        .collect();
    let inv = (0..n_phi * n_phi)
        .map(|x| {
            let q = x / n_phi;
            let eps = if q == 0 { 1.0 } else { 2.0 };
            eps / n_phi as f64 * basis(q, x % n_phi)
        })
        .collect();
    AzimuthalPhase { g_r, g_m, fwd, inv }
}

/// Solid angle × cosθ of each upward direction cell (both mirror halves), for E = ∫ L cosθ dω.
fn upward_cosine_weights(grid: &Grid) -> Vec<f64> {
    let (n_mu, n_phi) = (grid.s.n_mu, grid.s.n_phi);
    let dphi = PI / n_phi as f64;
    let mut w = vec![0.0; grid.dirs()];
    for k in 0..n_mu {
        let (t0, t1) = (
            PI * k as f64 / n_mu as f64,
            (PI * (k + 1) as f64 / n_mu as f64).min(PI / 2.0),
        );
        if t1 <= t0 {
            continue;
        }
        // ∫ cosθ sinθ dθ = (sin²t1 − sin²t0)/2, times 2Δφ for the cell and its mirror.
        let v = (t1.sin().powi(2) - t0.sin().powi(2)) * dphi;
        for l in 0..n_phi {
            w[k * n_phi + l] = v;
        }
    }
    w
}

/// Sky irradiance on the ground, `[i_mu_s][λ]`, interpolated at sun zenith cosine `mu_s`:
/// linear by day, in ln E across the terminator ([`twilight_interp`]).
#[inline(always)]
fn lookup_ground(grid: &Grid, n_l: usize, table: &[f64], mu_s: f64, out: &mut [f64]) {
    let theta_s = acos_fast(mu_s);
    if theta_s > grid.theta_s_max {
        return;
    }
    let (is, fs) = grid.s_pos(theta_s);
    if grid.twilight_cell(is) {
        for i in 0..n_l {
            out[i] += twilight_interp(is, fs, grid.s.n_mu_s, |b| table[b * n_l + i]);
        }
        return;
    }
    let (a, b) = (&table[is * n_l..][..n_l], &table[(is + 1) * n_l..][..n_l]);
    for i in 0..n_l {
        out[i] += a[i] * (1.0 - fs) + b[i] * fs;
    }
}

/// Catmull–Rom weights and node indices for position `(i, f)` on a grid of `n` nodes (end
/// nodes repeated at the edges).
#[inline(always)]
fn catmull_rom(i: usize, f: f64, n: usize) -> ([usize; 4], [f64; 4]) {
    let (f2, f3) = (f * f, f * f * f);
    (
        [
            i.saturating_sub(1),
            i,
            (i + 1).min(n - 1),
            (i + 2).min(n - 1),
        ],
        [
            0.5 * (-f3 + 2.0 * f2 - f),
            0.5 * (3.0 * f3 - 5.0 * f2 + 2.0),
            0.5 * (-3.0 * f3 + 4.0 * f2 + f),
            0.5 * (f3 - f2),
        ],
    )
}

/// Interpolation over sun zenith in a twilight cell (see [`TWILIGHT_INTERP_FROM_DEG`]) of the
/// values `at(node)`: Catmull–Rom in ln J between nodes `is` and `is + 1` (exact for an
/// exponential decay, third order where ln J bends at the terminator); linear in J where one of
/// the four nodes is zero (deep twilight, ln J = −∞).
#[inline(always)]
fn twilight_interp(is: usize, fs: f64, n: usize, at: impl Fn(usize) -> f64) -> f64 {
    let (nodes, w) = catmull_rom(is, fs, n);
    let vals = nodes.map(&at);
    if vals.iter().all(|&x| x > 0.0) {
        (0..4).map(|q| w[q] * vals[q].ln()).sum::<f64>().exp()
    } else {
        at(is) * (1.0 - fs) + at(is + 1) * fs
    }
}

/// [`twilight_interp`] for every wavelength at once: `out[i] += w · interp(i)` for the four node
/// rows `v[q]` (`[λ]`, the Catmull–Rom nodes of `catmull_rom(is, fs, n)`) whose logarithms are
/// `ln_v[q]` (any finite value where `v ≤ 0`). Branch-free over λ with [`ln_fast`]/[`exp_fast`],
/// so the loop vectorises; the same values as [`twilight_interp`] to rounding.
#[inline(always)]
fn twilight_lanes(
    v: [&[f32]; 4],
    ln_v: [&[f64]; 4],
    wq: [f64; 4],
    fs: f64,
    w: f64,
    out: &mut [f64],
) {
    let n = out.len();
    // Written out rather than `array::map`, which was not always inlined in the hot loops.
    let v = [&v[0][..n], &v[1][..n], &v[2][..n], &v[3][..n]];
    let ln_v = [&ln_v[0][..n], &ln_v[1][..n], &ln_v[2][..n], &ln_v[3][..n]];
    for i in 0..n {
        let positive = (v[0][i] > 0.0) & (v[1][i] > 0.0) & (v[2][i] > 0.0) & (v[3][i] > 0.0);
        let ln_j =
            wq[0] * ln_v[0][i] + wq[1] * ln_v[1][i] + wq[2] * ln_v[2][i] + wq[3] * ln_v[3][i];
        let linear = v[1][i] as f64 * (1.0 - fs) + v[2][i] as f64 * fs;
        out[i] += w * if positive { exp_fast(ln_j) } else { linear };
    }
}

/// `ln v` for positive `v`, 0 otherwise (masked by [`twilight_lanes`]).
#[inline(always)]
fn ln_or_zero(v: f32) -> f64 {
    let l = ln_fast(v as f64);
    if v > 0.0 {
        l
    } else {
        0.0
    }
}

/// [`twilight_lanes`] in f32 for the radiance passes of the build (J is stored in f32): `out[i] +=
/// w · interp(i)` for the four node rows `v[q]` whose logarithms are `ln_v[q]` (from
/// [`ln_or_zero_f32`]), eight wavelengths per AVX2 instruction with [`exp_fast_f32`]. Nodes
/// below the smallest normal f32 (1.2e-38) count as zero (linear in J there). ln J rounded to f32
/// (|ln J| ≲ 40) costs at most 4e-6 of J, beside the percent-level error of the twilight tables.
#[inline(always)]
fn twilight_lanes_f32(
    v: [&[f32]; 4],
    ln_v: [&[f32]; 4],
    wq: [f32; 4],
    fs: f32,
    w: f32,
    out: &mut [f32],
) {
    let n = out.len();
    // Written out rather than `array::map`, which was not always inlined in the hot loops.
    let v = [&v[0][..n], &v[1][..n], &v[2][..n], &v[3][..n]];
    let ln_v = [&ln_v[0][..n], &ln_v[1][..n], &ln_v[2][..n], &ln_v[3][..n]];
    const MIN: f32 = f32::MIN_POSITIVE;
    for i in 0..n {
        let positive = (v[0][i] >= MIN) & (v[1][i] >= MIN) & (v[2][i] >= MIN) & (v[3][i] >= MIN);
        let ln_j =
            wq[0] * ln_v[0][i] + wq[1] * ln_v[1][i] + wq[2] * ln_v[2][i] + wq[3] * ln_v[3][i];
        let linear = v[1][i] * (1.0 - fs) + v[2][i] * fs;
        out[i] += w * if positive { exp_fast_f32(ln_j) } else { linear };
    }
}

/// [`twilight_lanes_f32`] of `N` lanes with weight 1, returned: the same values, in whole
/// vectors (no remainder loop).
#[inline(always)]
fn twilight_fixed<const N: usize>(
    v: [&[f32; N]; 4],
    ln_v: [&[f32; N]; 4],
    wq: [f32; 4],
    fs: f32,
) -> [f32; N] {
    twilight_fixed_with(v, ln_v, wq, fs, exp_fast_f32)
}

/// [`twilight_fixed`] with the exponential `exp` (the bundles' lookup passes a cheaper one,
/// [`twilight_bundle::twilight_fixed_cubic`]).
#[inline(always)]
fn twilight_fixed_with<const N: usize>(
    v: [&[f32; N]; 4],
    ln_v: [&[f32; N]; 4],
    wq: [f32; 4],
    fs: f32,
    exp: impl Fn(f32) -> f32,
) -> [f32; N] {
    const MIN: f32 = f32::MIN_POSITIVE;
    let mut out = [0.0f32; N];
    for i in 0..N {
        let positive = (v[0][i] >= MIN) & (v[1][i] >= MIN) & (v[2][i] >= MIN) & (v[3][i] >= MIN);
        let ln_j =
            wq[0] * ln_v[0][i] + wq[1] * ln_v[1][i] + wq[2] * ln_v[2][i] + wq[3] * ln_v[3][i];
        let linear = v[1][i] * (1.0 - fs) + v[2][i] * fs;
        out[i] = if positive { exp(ln_j) } else { linear };
    }
    out
}

/// `ln v` for normal positive `v`, 0 otherwise (masked by [`twilight_lanes_f32`]).
#[inline(always)]
fn ln_or_zero_f32(v: f32) -> f32 {
    let l = ln_fast_f32(v);
    if v >= f32::MIN_POSITIVE {
        l
    } else {
        0.0
    }
}

/// Cosine of the view azimuth relative to the sun from the three cosines (1 when undefined).
#[inline(always)]
fn cos_azimuth(mu: f64, mu_s: f64, nu: f64) -> f64 {
    let denom = safe_sqrt(1.0 - mu * mu) * safe_sqrt(1.0 - mu_s * mu_s);
    if denom > 1e-9 {
        ((nu - mu * mu_s) / denom).clamp(-1.0, 1.0)
    } else {
        1.0
    }
}

crate::simd_dispatch! {
    /// J_ms at a ray sample (products): 16-corner interpolation over (r, θ, θ_s, φ), multilinear by
    /// day; in a twilight cell ([`Grid::twilight_cell`]) Catmull–Rom in ln J over sun zenith
    /// ([`twilight_interp`]), multilinear in radius and direction (within half a step of the
    /// view-zenith poles, towards the pole's azimuthal mean: [`Grid::theta_corners`]).
    fn lookup_j(grid: &Grid, n_l: usize, j: &[f32], s: &RaySample, out: &mut [f64]) {
        let theta_s = acos_fast(s.mu_s);
        if theta_s > grid.theta_s_max {
            return;
        }
        let (ir, fr) = grid.r_pos(s.r);
        let (is, fs) = grid.s_pos(theta_s);
        let theta = acos_fast(s.mu);
        let cos_phi = cos_azimuth(s.mu, s.mu_s, s.nu);
        let (ip, fp) = Grid::phi_pos(acos_fast(cos_phi), grid.s.n_phi);
        let (n_mu_s, n_mu, n_phi) = (grid.s.n_mu_s, grid.s.n_mu, grid.s.n_phi);
        let corners = JCorners {
            j,
            n_l,
            n_mu,
            n_mu_s,
            n_phi,
            is,
            fs,
            twilight: grid.twilight_cell(is),
        };
        for (a, wa) in [(ir, 1.0 - fr), (ir + 1, fr)] {
            for (c, wc, pole) in Grid::theta_corners(theta, n_mu) {
                if pole {
                    // The pole: the mean of the node's azimuths (`Grid::theta_corners`).
                    let w = wa * wc / n_phi as f64;
                    for e in 0..n_phi {
                        corners.add(a, c, e, w, out);
                    }
                } else {
                    for (e, we) in [(ip, 1.0 - fp), (ip + 1, fp)] {
                        corners.add(a, c, e, wa * wc * we, out);
                    }
                }
            }
        }
    }
}

/// What the (r, θ, φ) corners of one [`lookup_j`] share: the table, its sizes and the sun
/// zenith's node and weight. A plain `#[inline(always)]` method rather than a closure: the
/// closure was compiled on its own, without the AVX2 of `lookup_j` around it, so a twilight
/// corner's logarithms and exponentials ran one lane at a time (49 % of a twilight dome's CPU).
struct JCorners<'a> {
    j: &'a [f32],
    n_l: usize,
    n_mu: usize,
    n_mu_s: usize,
    n_phi: usize,
    is: usize,
    fs: f64,
    twilight: bool,
}

impl JCorners<'_> {
    /// Adds `w` × the corner (r node `a`, θ node `c`, φ node `e`) to `out` (`[λ]`): linear in sun
    /// zenith by day, Catmull–Rom in ln J in a twilight cell ([`twilight_lanes`]).
    #[inline(always)]
    fn add(&self, a: usize, c: usize, e: usize, w: f64, out: &mut [f64]) {
        if w == 0.0 {
            return;
        }
        let (j, n_l, is, fs) = (self.j, self.n_l, self.is, self.fs);
        let base = |b: usize| (((a * self.n_mu + c) * self.n_mu_s + b) * self.n_phi + e) * n_l;
        if self.twilight {
            let (nodes, wq) = catmull_rom(is, fs, self.n_mu_s);
            // In chunks of wavelengths, with the logarithms on the stack.
            const CHUNK: usize = crate::spectrum::wavelengths::MAX_WAVELENGTHS;
            let mut ln_v = [[0.0f64; CHUNK]; 4];
            for i0 in (0..n_l).step_by(CHUNK) {
                let m = CHUNK.min(n_l - i0);
                let v = nodes.map(|b| &j[base(b) + i0..][..m]);
                for q in 0..4 {
                    for (l, &x) in ln_v[q].iter_mut().zip(v[q]) {
                        *l = ln_or_zero(x);
                    }
                }
                twilight_lanes(
                    v,
                    ln_v.each_ref().map(|x| &x[..m]),
                    wq,
                    fs,
                    w,
                    &mut out[i0..][..m],
                );
            }
            return;
        }
        for (b, wb) in [(is, 1.0 - fs), (is + 1, fs)] {
            let (w, base) = (w * wb, base(b));
            if w == 0.0 {
                continue;
            }
            for i in 0..n_l {
                out[i] += w * j[base + i] as f64;
            }
        }
    }
}

/// What one radiance pass integrates.
#[derive(Clone, Copy)]
enum PassInput<'a> {
    /// Order 1: exact single scattering and the ground's reflection of direct sun.
    Single,
    /// Order n ≥ 2: the order's scattering source J_n (family layout) and the previous order's
    /// ground sky irradiance E_{n−1}, `[i_mu_s][λ]`.
    Order { j: &'a [f32], ground: &'a [f64] },
}

/// Everything a radiance pass reads.
struct PassCtx<'a> {
    grid: &'a Grid,
    medium: &'a Medium,
    table: &'a DensityIntegralTable,
    n_l: usize,
}

/// Per-thread buffers of the radiance pass.
struct FamilyScratch {
    points: Vec<RayPoint>,
    /// `[point][λ]`: sub-ray weight × quadrature weight × transmittance viewer → point (order 1);
    /// `[point][c][λ]`: the same times σ_c ρ_c at the point (orders ≥ 2), each point's lanes
    /// padded with zeros to [`twilight_batch::CELL_LANES`] where they fit in it.
    tw: Vec<f32>,
    /// `[point]`: relative densities (order 1).
    rho: Vec<[f64; CONSTITUENTS]>,
    /// `[i_mu_s][i_phi][c][λ]`: Â_R, Â_M at one point's (r, θ), all sun zeniths and azimuths.
    slice: Vec<f32>,
    /// `[i_mu_s][i_phi][c][λ]`: ln of `slice` (0 where it is 0) from sun-zenith node `ln_from` on,
    /// the nodes of twilight cells ([`Grid::twilight_cell`]).
    ln_slice: Vec<f32>,
    ln_from: usize,
    /// `[i_mu_s]`: [`Grid::twilight_cell`] of each sun-zenith node.
    twilight: Vec<bool>,
    /// `[c][λ]`: one twilight cell's interpolated Â.
    tv: Vec<f32>,
    /// `[cell]`: interpolation positions at one point (sun-zenith node, −1 for none, and
    /// weight; azimuth node and weight), see [`Grid::s_pos_f`].
    pos_s: Vec<f64>,
    pos_fs: Vec<f64>,
    pos_p: Vec<f64>,
    pos_fp: Vec<f64>,
    /// `[cell]`: the same positions as the radiance passes use them ([`PositionCache`]).
    q_idx: Vec<[u16; 2]>,
    q_w: Vec<[f32; 2]>,
    /// `[cell]`: sun zenith cosine at the ray origin, view–sun cosine, √(1 − μ_s²).
    cell_mu_s: Vec<f64>,
    cell_nu: Vec<f64>,
    /// `[cell]`: Rayleigh and Mie phase functions at ν (order 1).
    cell_phase: Vec<[f64; 2]>,
    /// `[λ]`: transmittance of the whole ray, a ground irradiance.
    t_total: Vec<f64>,
    e: Vec<f64>,
    /// Order 1 at one point: `[cell]` the sun's zenith cosine, visibility and density integrals
    /// (`[constituent][cell]`); `[λ][cell]` its transmittance.
    sun_mu: Vec<f64>,
    sun_vis: Vec<f64>,
    sun_d: [Vec<f64>; CONSTITUENTS],
    sun_e: Vec<f32>,
}

impl FamilyScratch {
    fn new(grid: &Grid, n_l: usize) -> Self {
        let fc = grid.family_cells();
        Self {
            points: Vec::with_capacity(2 * grid.s.steps),
            tw: Vec::with_capacity(2 * grid.s.steps * n_l),
            rho: Vec::with_capacity(2 * grid.s.steps),
            slice: vec![0.0; fc * 2 * n_l],
            ln_slice: vec![0.0; fc * 2 * n_l],
            ln_from: (0..grid.s.n_mu_s.saturating_sub(1))
                .find(|&is| grid.twilight_cell(is))
                .unwrap_or(grid.s.n_mu_s)
                .saturating_sub(1),
            twilight: (0..grid.s.n_mu_s)
                .map(|is| is + 1 < grid.s.n_mu_s && grid.twilight_cell(is))
                .collect(),
            tv: vec![0.0; 2 * n_l],
            pos_s: vec![0.0; fc],
            pos_fs: vec![0.0; fc],
            pos_p: vec![0.0; fc],
            pos_fp: vec![0.0; fc],
            q_idx: vec![[0; 2]; fc],
            q_w: vec![[0.0; 2]; fc],
            cell_mu_s: vec![0.0; fc],
            cell_nu: vec![0.0; fc],
            cell_phase: vec![[0.0; 2]; fc],
            t_total: vec![0.0; n_l],
            e: vec![0.0; n_l],
            sun_mu: vec![0.0; fc],
            sun_vis: vec![0.0; fc],
            sun_d: std::array::from_fn(|_| vec![0.0; fc]),
            sun_e: vec![0.0; n_l * fc],
        }
    }
}

/// Upper bound of the memory all ray families of one build may hold in [`PositionCache`]s
/// (12 bytes per cell and ray point: about 90 MB at `standard`; at `high` and `reference` the
/// families that do not fit compute their positions in every order).
const POSITION_CACHE_BYTES: usize = 256 << 20;

/// Node index meaning "no source" (the sun beyond the tables' last node) in [`PositionCache`].
const NO_NODE: u16 = u16::MAX;

/// The interpolation positions of one ray family's cells at each of its ray points (sun-zenith
/// node and weight, azimuth node and weight): they depend on the geometry only, so the first
/// radiance pass of orders ≥ 2 records them and the later orders read them instead of
/// recomputing them (two `acos`, two square roots and two divisions per cell and point).
#[derive(Default)]
struct PositionCache {
    state: CacheState,
    /// `[subray][point][cell]`: sun-zenith node ([`NO_NODE`]: no source) and azimuth node.
    idx: Vec<[u16; 2]>,
    /// `[subray][point][cell]`: their interpolation weights.
    w: Vec<[f32; 2]>,
}

#[derive(Default, Clone, Copy, PartialEq, Eq)]
enum CacheState {
    /// Not recorded yet: the next order ≥ 2 pass records it.
    #[default]
    Empty,
    Recording,
    Ready,
    /// Over [`POSITION_CACHE_BYTES`]: computed in every pass.
    Off,
}

impl PositionCache {
    const CELL_BYTES: usize = std::mem::size_of::<[u16; 2]>() + std::mem::size_of::<[f32; 2]>();

    /// Appends one point's positions if the build's budget (`left`, bytes) still has room; else
    /// frees the recorded ones, gives their bytes back and stops recording.
    fn record(&mut self, idx: &[[u16; 2]], w: &[[f32; 2]], left: &AtomicUsize) {
        let bytes = idx.len() * Self::CELL_BYTES;
        let reserved = left
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| {
                v.checked_sub(bytes)
            })
            .is_ok();
        if reserved {
            self.idx.extend_from_slice(idx);
            self.w.extend_from_slice(w);
        } else {
            left.fetch_add(self.idx.len() * Self::CELL_BYTES, Ordering::Relaxed);
            *self = Self {
                state: CacheState::Off,
                ..Self::default()
            };
        }
    }
}

/// Sub-rays of the family (r, θ bin `k`) with normalised weights: the cell centre, or near the
/// local horizon the solid-angle average of sub-rays split at the horizon, since L changes fast
/// there (long grazing paths on both sides, ground on one).
fn family_subrays(grid: &Grid, r: f64, k: usize) -> Vec<(f64, f64)> {
    let s = grid.s;
    let th = grid.theta(k);
    let (t0, t1) = (
        PI * k as f64 / s.n_mu as f64,
        PI * (k + 1) as f64 / s.n_mu as f64,
    );
    let theta_h = horizon_mu(r, grid.bottom).acos();
    let straddles = theta_h > t0 + 1e-9 && theta_h < t1 - 1e-9;
    let near = (th - theta_h).abs() < s.horizon_band_rad;
    if !(straddles || near) {
        return vec![(th, 1.0)];
    }
    let pieces: &[(f64, f64)] = if straddles {
        &[(t0, theta_h), (theta_h, t1)]
    } else {
        &[(t0, t1)]
    };
    let sub = s.horizon_subrays;
    let mut rays = Vec::with_capacity(2 * sub);
    for &(a, b) in pieces {
        for q in 0..sub {
            let theta = a + (b - a) * (q as f64 + 0.5) / sub as f64;
            rays.push((theta, theta.sin() * (b - a)));
        }
    }
    let wsum: f64 = rays.iter().map(|r| r.1).sum();
    rays.iter_mut().for_each(|r| r.1 /= wsum);
    rays
}

/// Sub-rays equal in solid angle per view-zenith band in the order-1 pass at `high` and finer
/// ([`HIGH_FROM_N_MU`]).
const SINGLE_SUBRAYS: usize = 3;

/// The sub-rays of the order-1 pass for the ray family (r, θ index `k`): those of
/// [`family_subrays`] near the horizon or at `standard` and coarser, elsewhere the grid's
/// [`SINGLE_SUBRAYS`] rays at the midpoints of equal steps in cos θ across the band (equal solid
/// angles, equal weights). Orders ≥ 2 keep [`family_subrays`].
///
/// The tables hold each band's mean radiance: the ground term weights a band by its whole solid
/// angle and the J pass integrates the phase function over the input band. A single ray at the
/// band's middle angle samples a field peaked at the pole (a high sun's aureole) above that
/// mean, since near the pole a band's solid angle lies mostly in its outer part (the sin θ
/// weight): with 48 bands, +3.1 / +2.0 / +0.8 % in the three bands round the zenith, which made
/// the diffuse ground irradiance of a Cornette-Shanks g 0.8 aerosol (optical depth 1) at sun
/// zenith 0° +0.44 % high in order 1 against the exact integral; three rays equal in solid angle
/// leave −0.17 % (the composite midpoint rule in μ, whose error falls as the square of the
/// step). It costs about 10 % of the CPU time of a table at `standard` (earth-hazy, 16
/// wavelengths), whose 2–3 % bound does not need it, so only `high` and finer take it.
fn single_subrays(grid: &Grid, r: f64, k: usize) -> Vec<(f64, f64)> {
    let base = family_subrays(grid, r, k);
    if grid.single_subrays <= 1 || base.len() > 1 {
        return base;
    }
    let n_mu = grid.s.n_mu as f64;
    let (m0, m1) = (
        (PI * k as f64 / n_mu).cos(),
        (PI * (k + 1) as f64 / n_mu).cos(),
    );
    let n = grid.single_subrays as f64;
    (0..grid.single_subrays)
        .map(|j| ((m0 + (m1 - m0) * (j as f64 + 0.5) / n).acos(), 1.0 / n))
        .collect()
}

crate::simd_dispatch_avx512! {
    /// Radiance of one order for the ray family (r index `ir`, θ index `k`): writes `out`,
    /// `[i_mu_s][i_phi][λ]` (zeroed here).
    fn family_pass(
        ctx: &PassCtx,
        input: PassInput,
        ir: usize,
        k: usize,
        sc: &mut FamilyScratch,
        cache: &mut PositionCache,
        cache_left: &AtomicUsize,
        out: &mut [f32],
    ) {
        let (grid, medium, n_l) = (ctx.grid, ctx.medium, ctx.n_l);
        let s = grid.s;
        let (n_mu_s, n_phi) = (s.n_mu_s, s.n_phi);
        let fc = grid.family_cells();
        let bottom = medium.bottom_radius_m;
        let r = grid.r(ir);
        let r0 = r.max(bottom);
        // Lanes per cell of the Â tables (both constituents).
        let n_j = 2 * n_l;
        out.fill(0.0);
        // Per-λ arrays sliced to exactly n_l, so the λ loops need no bounds checks and vectorise.
        let ext = [0, 1, 2].map(|c| &medium.extinction_per_m[c][..n_l]);
        let sig_r = &medium.rayleigh_scattering_per_m[..n_l];
        let sig_m = &medium.mie_scattering_per_m[..n_l];
        let albedo = &medium.ground_albedo[..n_l];
        let t_total = &mut sc.t_total[..n_l];
        // Orders ≥ 2 read the positions recorded by the first of them when there is room.
        if let (PassInput::Order { .. }, CacheState::Empty) = (input, cache.state) {
            cache.state = if n_mu_s < NO_NODE as usize && n_phi < NO_NODE as usize {
                CacheState::Recording
            } else {
                CacheState::Off
            };
        }
        let mut cursor = 0;
        let rays = match input {
            PassInput::Single => single_subrays(grid, r, k),
            PassInput::Order { .. } => family_subrays(grid, r, k),
        };
        for (theta, w_ray) in rays {
            let (mu, sin_t) = (theta.cos(), theta.sin());
            for is in 0..n_mu_s {
                let ts = grid.theta_s(is);
                let (mu_s0, sin_s0) = (ts.cos(), ts.sin());
                for l in 0..n_phi {
                    let c = is * n_phi + l;
                    let nu = mu * mu_s0 + sin_t * sin_s0 * grid.phi(l).cos();
                    sc.cell_mu_s[c] = mu_s0;
                    sc.cell_nu[c] = nu;
                    if matches!(input, PassInput::Single) {
                        sc.cell_phase[c] = [Phase::Rayleigh.eval(nu), medium.mie_phase.eval(nu)];
                    }
                }
            }
            let Some(seg) = ray_points(medium, r, mu, s.steps, &mut sc.points) else {
                continue;
            };
            // Viewer-to-point transmittance at each point's midpoint (f64 density integrals).
            sc.tw.clear();
            sc.rho.clear();
            // Orders ≥ 2 read Â_R and Â_M: their weights carry σ_R ρ_R and σ_M ρ_M at the point
            // itself (`2 n_l` lanes per point), order 1 only the transmittance (`n_l`).
            let order = matches!(input, PassInput::Order { .. });
            let n_tw = if order { n_j } else { n_l };
            let tw_stride = if order && n_j <= twilight_batch::CELL_LANES {
                twilight_batch::CELL_LANES
            } else {
                n_tw
            };
            let mut d_view = [0.0f64; CONSTITUENTS];
            for p in &sc.points {
                let rho = medium.densities(p.r);
                let w = w_ray * p.weight;
                let tw_at = |i: usize| {
                    let tau = ext[0][i] * d_view[0] + ext[1][i] * d_view[1] + ext[2][i] * d_view[2];
                    let dtau = (ext[0][i] * rho[0] + ext[1][i] * rho[1] + ext[2][i] * rho[2]) * p.weight;
                    w * cell_transmittance(tau, dtau)
                };
                if order {
                    sc.tw.extend((0..n_l).map(|i| (tw_at(i) * sig_r[i] * rho[RAYLEIGH]) as f32));
                    sc.tw.extend((0..n_l).map(|i| (tw_at(i) * sig_m[i] * rho[MIE]) as f32));
                    sc.tw.extend(std::iter::repeat_n(0.0, tw_stride - n_tw));
                } else {
                    sc.tw.extend((0..n_l).map(|i| tw_at(i) as f32));
                }
                for c in 0..CONSTITUENTS {
                    d_view[c] += rho[c] * p.weight;
                }
                sc.rho.push(rho);
            }
            for i in 0..n_l {
                let tau = ext[0][i] * d_view[0] + ext[1][i] * d_view[1] + ext[2][i] * d_view[2];
                t_total[i] = exp_fast(-tau);
            }
            for (pi, p) in sc.points.iter().enumerate() {
                let tw = &sc.tw[pi * tw_stride..][..tw_stride];
                // The padded lanes of the cells added in whole vectors (`n_j` ≤ CELL_LANES).
                let tw_lanes: Option<&[f32; twilight_batch::CELL_LANES]> = tw.try_into().ok();
                let sin_mu = safe_sqrt(1.0 - p.mu * p.mu);
                match input {
                    PassInput::Single => {
                        let rho = sc.rho[pi];
                        let at = ctx.table.at_radius(p.r, medium.sun_angular_radius_rad);
                        // Every cell's sun zenith at the point, then the table's values for the
                        // cells from the first to the last the sun lights
                        // ([`AtRadius::lookup_many`]: `lookup`'s values, as vectors), then each
                        // wavelength's transmittance (f32 exponentials, 16 lanes), then the sums:
                        // each cell's operations as one cell at a time.
                        let mu_c = &mut sc.sun_mu[..fc];
                        for c in 0..fc {
                            mu_c[c] = ((r0 * sc.cell_mu_s[c] + p.t * sc.cell_nu[c]) / p.r)
                                .clamp(-1.0, 1.0);
                        }
                        let lit = at.visible_range(mu_c);
                        let [d0, d1, d2] = &mut sc.sun_d;
                        let vis = &mut sc.sun_vis[lit.clone()];
                        let (d0, d1, d2) =
                            (&mut d0[lit.clone()], &mut d1[lit.clone()], &mut d2[lit.clone()]);
                        at.lookup_many(&mu_c[lit.clone()], vis, [&mut *d0, &mut *d1, &mut *d2]);
                        let n = lit.len();
                        for i in 0..n_l {
                            let (e0, e1, e2) = (ext[0][i], ext[1][i], ext[2][i]);
                            let e = &mut sc.sun_e[i * fc..][..n];
                            let d = d0.iter().zip(d1.iter()).zip(d2.iter());
                            for (e, ((&a, &b), &c)) in e.iter_mut().zip(d) {
                                let tau = e0 * a + e1 * b + e2 * c;
                                *e = exp_fast_f32(-tau as f32);
                            }
                        }
                        for q in 0..n {
                            let vis = vis[q];
                            if vis <= 0.0 {
                                continue;
                            }
                            let c = lit.start + q;
                            let [ph_r, ph_m] = sc.cell_phase[c];
                            let (ar, am) = (rho[RAYLEIGH] * ph_r * vis, rho[MIE] * ph_m * vis);
                            let o = &mut out[c * n_l..][..n_l];
                            for i in 0..n_l {
                                let single = (sig_r[i] * ar + sig_m[i] * am) as f32;
                                o[i] += tw[i] * single * sc.sun_e[i * fc + q];
                            }
                        }
                    }
                    PassInput::Order { j, .. } => {
                        // J at this point's (r, θ) for every (θ_s, φ): bilinear in (r, θ).
                        let (ia, fa) = grid.r_pos(p.r);
                        let [(ic, w0, _), (ic1, w1, pole)] =
                            Grid::theta_corners(acos_fast(p.mu), s.n_mu);
                        let block = |a: usize, c: usize| &j[(a * s.n_mu + c) * fc * n_j..][..fc * n_j];
                        let (b00, b01, b10, b11) =
                            (block(ia, ic), block(ia, ic1), block(ia + 1, ic), block(ia + 1, ic1));
                        let (w00, w01, w10, w11) = (
                            ((1.0 - fa) * w0) as f32,
                            ((1.0 - fa) * w1) as f32,
                            (fa * w0) as f32,
                            (fa * w1) as f32,
                        );
                        if pole {
                            // Within half a step of a pole: towards the mean of the node's
                            // azimuths (`Grid::theta_corners`).
                            let inv = 1.0 / n_phi as f32;
                            for is in 0..n_mu_s {
                                let at = |b: &[f32], l: usize, x: usize| b[(is * n_phi + l) * n_j + x];
                                for x in 0..n_j {
                                    let (mut m0, mut m1) = (0.0f32, 0.0f32);
                                    for l in 0..n_phi {
                                        m0 += at(b01, l, x);
                                        m1 += at(b11, l, x);
                                    }
                                    let pole_v = inv * (w01 * m0 + w11 * m1);
                                    for l in 0..n_phi {
                                        let k = (is * n_phi + l) * n_j + x;
                                        sc.slice[k] = w00 * b00[k] + w10 * b10[k] + pole_v;
                                    }
                                }
                            }
                        } else {
                            for (x, slice) in sc.slice.iter_mut().enumerate() {
                                *slice = w00 * b00[x] + w01 * b01[x] + w10 * b10[x] + w11 * b11[x];
                            }
                        }
                        // ln J of the sun-zenith nodes that twilight cells interpolate over.
                        let from = sc.ln_from * n_phi * n_j;
                        for (lv, &v) in sc.ln_slice[from..].iter_mut().zip(&sc.slice[from..]) {
                            *lv = ln_or_zero_f32(v);
                        }
                        // Every cell's interpolation position at this point first, in a
                        // branch-free loop over cells that vectorises: sun-zenith node and
                        // weight, azimuth node and weight (node −1: the sun is beyond the
                        // tables' last node, no source there); or recorded by an earlier order.
                        // The arrays sliced to the cells and the grid copied first, so that
                        // the loop holds no bounds check and no reload through `sc`.
                        let ready = cache.state == CacheState::Ready;
                        if !ready {
                            let g = grid.sun_nodes();
                            let (cell_mu_s, cell_nu) = (&sc.cell_mu_s[..fc], &sc.cell_nu[..fc]);
                            let (pos_s, pos_fs) = (&mut sc.pos_s[..fc], &mut sc.pos_fs[..fc]);
                            let (pos_p, pos_fp) = (&mut sc.pos_p[..fc], &mut sc.pos_fp[..fc]);
                            for c in 0..fc {
                                let mu_s =
                                    ((r0 * cell_mu_s[c] + p.t * cell_nu[c]) / p.r).clamp(-1.0, 1.0);
                                let theta_s = acos_fast(mu_s);
                                let (js, fs) = g.pos_f(theta_s);
                                let denom = sin_mu * safe_sqrt(1.0 - mu_s * mu_s);
                                let cos_phi = if denom > 1e-9 {
                                    ((cell_nu[c] - p.mu * mu_s) / denom).clamp(-1.0, 1.0)
                                } else {
                                    1.0
                                };
                                let (jp, fp) = Grid::phi_pos_f(acos_fast(cos_phi), n_phi);
                                pos_s[c] = if theta_s > g.theta_s_max { -1.0 } else { js };
                                pos_fs[c] = fs;
                                pos_p[c] = jp;
                                pos_fp[c] = fp;
                            }
                            let (q_idx, q_w) = (&mut sc.q_idx[..fc], &mut sc.q_w[..fc]);
                            for c in 0..fc {
                                q_idx[c] = if pos_s[c] < 0.0 {
                                    [NO_NODE, 0]
                                } else {
                                    [pos_s[c] as u16, pos_p[c] as u16]
                                };
                                q_w[c] = [pos_fs[c] as f32, pos_fp[c] as f32];
                            }
                            if cache.state == CacheState::Recording {
                                cache.record(&sc.q_idx, &sc.q_w, cache_left);
                            }
                        }
                        let (q_idx, q_w) = if ready {
                            (&cache.idx[cursor..][..fc], &cache.w[cursor..][..fc])
                        } else {
                            (&sc.q_idx[..fc], &sc.q_w[..fc])
                        };
                        cursor += fc;
                        for c in 0..fc {
                            let [js, jp] = q_idx[c];
                            if js == NO_NODE {
                                continue;
                            }
                            let (js, jp) = (js as usize, jp as usize);
                            let [fs, fp] = q_w[c];
                            if sc.twilight[js] {
                                // In ln J over sun zenith (`twilight_interp`), linear in azimuth.
                                let (nodes, wq) = catmull_rom(js, fs as f64, n_mu_s);
                                if let Some(tw) = tw_lanes {
                                    twilight_batch::twilight_cell_pair_add(
                                        &sc.slice,
                                        &sc.ln_slice,
                                        nodes,
                                        n_phi,
                                        n_j,
                                        jp,
                                        wq.map(|w| w as f32),
                                        fs,
                                        fp,
                                        tw,
                                        &mut out[c * n_l..][..n_l],
                                    );
                                    continue;
                                }
                                let tv = &mut sc.tv[..n_j];
                                tv.fill(0.0);
                                {
                                    for (e, we) in [(jp, 1.0 - fp), (jp + 1, fp)] {
                                        let row = nodes.map(|b| (b * n_phi + e) * n_j);
                                        twilight_lanes_f32(
                                            row.map(|x| &sc.slice[x..][..n_j]),
                                            row.map(|x| &sc.ln_slice[x..][..n_j]),
                                            wq.map(|w| w as f32),
                                            fs,
                                            we,
                                            tv,
                                        );
                                    }
                                }
                                let o = &mut out[c * n_l..][..n_l];
                                for i in 0..n_l {
                                    o[i] += tw[i] * tv[i] + tw[n_l + i] * tv[n_l + i];
                                }
                                continue;
                            }
                            let (c00, c01, c10, c11) =
                                ((1.0 - fs) * (1.0 - fp), (1.0 - fs) * fp, fs * (1.0 - fp), fs * fp);
                            if let Some(tw) = tw_lanes {
                                twilight_batch::day_cell_add(
                                    &sc.slice,
                                    (js * n_phi + jp) * n_j,
                                    ((js + 1) * n_phi + jp) * n_j,
                                    n_j,
                                    [c00, c01, c10, c11],
                                    tw,
                                    &mut out[c * n_l..][..n_l],
                                );
                                continue;
                            }
                            let (s00, s01) =
                                sc.slice[(js * n_phi + jp) * n_j..][..2 * n_j].split_at(n_j);
                            let (s10, s11) =
                                sc.slice[((js + 1) * n_phi + jp) * n_j..][..2 * n_j].split_at(n_j);
                            let o = &mut out[c * n_l..][..n_l];
                            for i in 0..n_l {
                                let (m, v) = (n_l + i, |q: usize| {
                                    c00 * s00[q] + c01 * s01[q] + c10 * s10[q] + c11 * s11[q]
                                });
                                o[i] += tw[i] * v(i) + tw[m] * v(m);
                            }
                        }
                    }
                }
            }
            if !seg.hits_ground {
                continue;
            }
            // Lambertian ground at the ray's end: (a/π)(E_direct + E_sky), attenuated.
            let r_end = radius_at(r0, mu, seg.t_end).max(bottom);
            for c in 0..fc {
                let mu_s_g = ((r0 * sc.cell_mu_s[c] + seg.t_end * sc.cell_nu[c]) / r_end)
                    .clamp(-1.0, 1.0);
                sc.e.fill(0.0);
                match input {
                    PassInput::Single => {
                        if mu_s_g <= -0.02 {
                            continue;
                        }
                        let vis =
                            ctx.table.sun_visibility(bottom, mu_s_g, medium.sun_angular_radius_rad);
                        if vis <= 0.0 {
                            continue;
                        }
                        let d = ctx.table.lookup(bottom, mu_s_g);
                        let e = &mut sc.e[..n_l];
                        for i in 0..n_l {
                            let tau = ext[0][i] * d[0] + ext[1][i] * d[1] + ext[2][i] * d[2];
                            e[i] = mu_s_g.max(0.0) * exp_fast(-tau) * vis;
                        }
                    }
                    PassInput::Order { ground, .. } => {
                        lookup_ground(grid, n_l, ground, mu_s_g, &mut sc.e)
                    }
                }
                let o = &mut out[c * n_l..][..n_l];
                let e = &sc.e[..n_l];
                for i in 0..n_l {
                    o[i] += (w_ray * t_total[i] * albedo[i] / PI * e[i]) as f32;
                }
            }
        }
        if cache.state == CacheState::Recording {
            cache.state = CacheState::Ready;
        }
    }
}

/// Output zenith bins the J product accumulates at once.
const J_ROWS: usize = 4;

/// Per-thread scratch of the J pass, f64: `[q][k][i_mu_s][λ]` twice (the transformed radiance
/// and the transformed Â, both constituents), and the accumulators of [`J_ROWS`] rows for both
/// phase functions.
struct JScratch {
    spec: Vec<f64>,
    y: Vec<f64>,
    acc: Vec<f64>,
}

impl JScratch {
    fn new(grid: &Grid, n_l: usize) -> Self {
        let w = grid.s.n_mu_s * n_l;
        let n = grid.s.n_phi * grid.s.n_mu * w;
        Self {
            spec: vec![0.0; n],
            y: vec![0.0; 2 * n],
            acc: vec![0.0; 2 * J_ROWS * w],
        }
    }
}

crate::simd_dispatch_avx512! {
    /// Â_R and Â_M of the next order for every cell of radius index `ir` (`out`:
    /// `[i_mu][i_mu_s][i_phi][c][λ]`, see [`PreciseMultipleScattering`]) from one order's radiance
    /// there (`l`: `[i_mu][i_mu_s][i_phi][λ]`), in azimuthal cosine space ([`AzimuthalPhase`]): the
    /// radiance transformed over azimuth, per frequency q the product of the view-zenith blocks
    /// Ĝ_q (Rayleigh and Mie) with it, transformed back (Â_M stays 0 without aerosol). In f64 (the transforms take differences; J in f32 after,
    /// clamped at 0 against rounding where J vanishes).
    fn scattering_density_at_radius(
        grid: &Grid,
        n_l: usize,
        ap: &AzimuthalPhase,
        with_mie: bool,
        l: &[f32],
        sc: &mut JScratch,
        out: &mut [f32],
    ) {
        let s = grid.s;
        let (n_mu, n_mu_s, n_phi) = (s.n_mu, s.n_mu_s, s.n_phi);
        let w = n_mu_s * n_l;
        let (n_j, w_j) = (2 * n_l, 2 * w);
        // Forward: spec[q][k][is][λ] = Σ_l L[k][is][l][λ] cos(πq(l + ½)/n_φ).
        let spec = &mut sc.spec[..n_phi * n_mu * w];
        spec.fill(0.0);
        for k in 0..n_mu {
            for is in 0..n_mu_s {
                for ph in 0..n_phi {
                    let src = &l[((k * n_mu_s + is) * n_phi + ph) * n_l..][..n_l];
                    for q in 0..n_phi {
                        let c = ap.fwd[q * n_phi + ph];
                        let dst = &mut spec[(q * n_mu + k) * w + is * n_l..][..n_l];
                        for i in 0..n_l {
                            dst[i] += c * src[i] as f64;
                        }
                    }
                }
            }
        }
        // Per frequency: y[q][k_o] = σ_R Σ_{k_i} Ĝ^R_q[k_o][k_i] spec[q][k_i] + σ_M (same with Ĝ^M).
        let spec = &sc.spec[..n_phi * n_mu * w];
        for q in 0..n_phi {
            let mut o0 = 0;
            while o0 < n_mu {
                let rows = J_ROWS.min(n_mu - o0);
                let (acc_r, acc_m) = sc.acc.split_at_mut(J_ROWS * w);
                acc_r.fill(0.0);
                acc_m.fill(0.0);
                for ki in 0..n_mu {
                    let src = &spec[(q * n_mu + ki) * w..][..w];
                    for b in 0..rows {
                        let g = (q * n_mu + o0 + b) * n_mu + ki;
                        let (gr, gm) = (ap.g_r[g], ap.g_m[g]);
                        let ar = &mut acc_r[b * w..][..w];
                        for x in 0..w {
                            ar[x] += gr * src[x];
                        }
                        if with_mie {
                            let am = &mut acc_m[b * w..][..w];
                            for x in 0..w {
                                am[x] += gm * src[x];
                            }
                        }
                    }
                }
                for b in 0..rows {
                    let dst = &mut sc.y[(q * n_mu + o0 + b) * w_j..][..w_j];
                    let (ar, am) = (&acc_r[b * w..][..w], &acc_m[b * w..][..w]);
                    for is in 0..n_mu_s {
                        let x0 = is * n_l;
                        let (dr, dm) = dst[is * n_j..][..n_j].split_at_mut(n_l);
                        dr.copy_from_slice(&ar[x0..][..n_l]);
                        dm.copy_from_slice(&am[x0..][..n_l]);
                    }
                }
                o0 += rows;
            }
        }
        // Inverse: Â[k][is][l][c][λ] = Σ_q ε_q/n_φ cos(πq(l + ½)/n_φ) y[q][k][is][c][λ].
        let y = &sc.y[..n_phi * n_mu * w_j];
        for k in 0..n_mu {
            for is in 0..n_mu_s {
                for lo in 0..n_phi {
                    let dst = &mut out[((k * n_mu_s + is) * n_phi + lo) * n_j..][..n_j];
                    let acc = &mut sc.acc[..n_j];
                    acc.fill(0.0);
                    for q in 0..n_phi {
                        let c = ap.inv[q * n_phi + lo];
                        let src = &y[(q * n_mu + k) * w_j + is * n_j..][..n_j];
                        for i in 0..n_j {
                            acc[i] += c * src[i];
                        }
                    }
                    for i in 0..n_j {
                        dst[i] = acc[i].max(0.0) as f32;
                    }
                }
            }
        }
    }
}

/// The largest ratio of successive orders a geometric tail is extrapolated with ([`Series`]).
///
/// In optically thick conservative haze over a bright ground almost no light escapes per order:
/// fog of optical depth 12 at 440 nm (visibility 1 km, 2.5 km deep, single-scattering albedo 1)
/// over a white ground settles to q ≈ 0.989. Below 0.98, as it was, no tail was usable there and
/// the series stopped at 60 orders with 1 % of it missing and the order count at its cap. The
/// tail's error estimate ([`Series::tail`], 2|Δq|/(1 − q) of it) still decides when to stop.
const TAIL_RATIO_MAX: f64 = 0.995;

/// Geometric extrapolation state: per (sun zenith, λ) sums of the last orders' radiance.
struct Series {
    n_mu_s: usize,
    n_l: usize,
    /// Running total of all computed orders, `[i_mu_s][λ]`.
    total: Vec<f64>,
    /// Sums of the last three orders (oldest first), `[i_mu_s][λ]`.
    last: Vec<Vec<f64>>,
    /// How many of the stored orders are multiple-scattering orders (n ≥ 2).
    multiple: usize,
}

impl Series {
    fn push(&mut self, sums: Vec<f64>, multiple: bool) {
        self.total.iter_mut().zip(&sums).for_each(|(t, s)| *t += s);
        self.last.push(sums);
        if self.last.len() > 3 {
            self.last.remove(0);
        }
        if multiple {
            self.multiple += 1;
        }
    }
    /// Ratio of the last two orders per (sun zenith, λ), when both are multiple orders and
    /// the ratio is usable for a geometric tail (0 < q < [`TAIL_RATIO_MAX`]).
    fn ratio(&self, back: usize) -> Option<Vec<Option<f64>>> {
        let n = self.last.len();
        if self.multiple < back + 2 || n < back + 2 {
            return None;
        }
        let (a, b) = (&self.last[n - 2 - back], &self.last[n - 1 - back]);
        Some(
            a.iter()
                .zip(b)
                .map(|(&a, &b)| (a > 0.0 && b > 0.0 && b / a < TAIL_RATIO_MAX).then(|| b / a))
                .collect(),
        )
    }
    /// (tail, error estimate, mean ratio) as fractions of the total, for a geometric tail
    /// after the last order: tail_x = S_x q/(1 − q); its error is estimated as
    /// tail_x · 2|q − q_prev|/(1 − q) (the ratio's drift over the tail), summed over x.
    fn tail(&self) -> Option<(f64, f64, f64, Vec<f64>)> {
        let q = self.ratio(0)?;
        let q_prev = self.ratio(1)?;
        let last = self.last.last()?;
        let total: f64 = self.total.iter().sum();
        if total <= 0.0 {
            return None;
        }
        let (mut tail, mut err, mut qsum, mut wsum) = (0.0, 0.0, 0.0, 0.0);
        let mut factors = vec![0.0; self.n_mu_s * self.n_l];
        for x in 0..factors.len() {
            match (q[x], q_prev[x]) {
                (Some(qx), Some(qp)) => {
                    let t = last[x] * qx / (1.0 - qx);
                    factors[x] = qx / (1.0 - qx);
                    tail += t;
                    err += t * (2.0 * (qx - qp).abs() / (1.0 - qx)).min(1.0);
                    qsum += qx * last[x];
                    wsum += last[x];
                }
                // No usable ratio: no tail there; everything past this order counts as error.
                _ => err += last[x],
            }
        }
        let q_mean = if wsum > 0.0 { qsum / wsum } else { 0.0 };
        Some((tail / total, err / total, q_mean, factors))
    }
}

impl PreciseMultipleScattering {
    /// Computes orders of scattering until convergence (see the module documentation).
    pub fn new(medium: &Medium, table: &DensityIntegralTable, s: PreciseSettings) -> Self {
        Self::build(medium, table, s, &|| false).unwrap_or_else(|| unreachable!("never cancelled"))
    }

    /// [`Self::new`], stopped (`None`) when `cancelled` returns true between two orders (every waiting client has gone).
    pub fn build(
        medium: &Medium,
        table: &DensityIntegralTable,
        s: PreciseSettings,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<Self> {
        let t_start = std::time::Instant::now();
        let ms = |t: std::time::Instant| t.elapsed().as_secs_f64() * 1e3;
        let mut stage_ms = StageTimes::default();
        let grid = Grid::new(s, medium);
        // The grid's settings: `n_mu_s` counts the denser twilight nodes too.
        let s = grid.s;
        let n_l = medium.len();
        let fc = grid.family_cells();
        let family_len = fc * n_l;
        let per_r = s.n_mu * family_len;
        // Â tables: both constituents per cell.
        let n_j = 2 * n_l;
        let (family_len_j, per_r_j) = (fc * n_j, s.n_mu * fc * n_j);
        let with_mie = medium.mie_scattering_per_m.iter().any(|&v| v > 0.0);
        let phase = azimuthal_phase(&grid, medium.mie_phase);
        let up_w = upward_cosine_weights(&grid);
        let ctx = PassCtx {
            grid: &grid,
            medium,
            table,
            n_l,
        };

        // Radiance of one order on every cell, family by family.
        // (Per family, the interpolation positions that orders ≥ 2 share.)
        let mut positions: Vec<PositionCache> = (0..s.n_r * s.n_mu)
            .map(|_| PositionCache::default())
            .collect();
        let positions_left = AtomicUsize::new(POSITION_CACHE_BYTES);
        let radiance = |input: PassInput, positions: &mut [PositionCache]| -> Vec<f32> {
            let mut l = vec![0.0f32; grid.cells() * n_l];
            l.par_chunks_mut(family_len)
                .zip(positions.par_iter_mut())
                .enumerate()
                .for_each_init(
                    || FamilyScratch::new(&grid, n_l),
                    |sc, (f, (out, cache))| {
                        let (ir, k) = (f / s.n_mu, f % s.n_mu);
                        family_pass(&ctx, input, ir, k, sc, cache, &positions_left, out)
                    },
                );
            l
        };
        // Sky irradiance on the ground from one order's radiance at r = bottom, `[i_mu_s][λ]`.
        let ground_of = |l: &[f32]| -> Vec<f64> {
            let mut e = vec![0.0; s.n_mu_s * n_l];
            for k in 0..s.n_mu {
                for is in 0..s.n_mu_s {
                    for ph in 0..s.n_phi {
                        let w = up_w[k * s.n_phi + ph];
                        if w == 0.0 {
                            continue;
                        }
                        let src = &l[((k * s.n_mu_s + is) * s.n_phi + ph) * n_l..][..n_l];
                        for i in 0..n_l {
                            e[is * n_l + i] += w * src[i] as f64;
                        }
                    }
                }
            }
            e
        };
        // Sums of one order's radiance per (sun zenith, λ).
        let sums_of = |l: &[f32]| -> Vec<f64> {
            let parts: Vec<Vec<f64>> = l
                .par_chunks(per_r)
                .map(|block| {
                    let mut out = vec![0.0; s.n_mu_s * n_l];
                    for fam in block.chunks(family_len) {
                        for (is, row) in fam.chunks(s.n_phi * n_l).enumerate() {
                            let o = &mut out[is * n_l..][..n_l];
                            for cell in row.chunks(n_l) {
                                o.iter_mut().zip(cell).for_each(|(o, v)| *o += *v as f64);
                            }
                        }
                    }
                    out
                })
                .collect();
            let mut out = vec![0.0; s.n_mu_s * n_l];
            for p in parts {
                out.iter_mut().zip(&p).for_each(|(o, v)| *o += v);
            }
            out
        };
        // J of the next order from one order's radiance, radius by radius.
        let scattering_density = |l: &[f32]| -> Vec<f32> {
            let mut j = vec![0.0f32; grid.cells() * n_j];
            j.par_chunks_mut(per_r_j).enumerate().for_each_init(
                || JScratch::new(&grid, n_l),
                |sc, (ir, out)| {
                    scattering_density_at_radius(
                        &grid,
                        n_l,
                        &phase,
                        with_mie,
                        &l[ir * per_r..][..per_r],
                        sc,
                        out,
                    );
                },
            );
            j
        };

        let t0 = std::time::Instant::now();
        let mut l_n = radiance(PassInput::Single, &mut positions);
        tracing::debug!(
            radiance_ms = t0.elapsed().as_secs_f64() * 1e3,
            "precise order 1"
        );
        let mut series = Series {
            n_mu_s: s.n_mu_s,
            n_l,
            total: vec![0.0; s.n_mu_s * n_l],
            last: Vec::new(),
            multiple: 0,
        };
        series.push(sums_of(&l_n), false);
        let mut e_n = ground_of(&l_n);
        let mut ground_sky = e_n.clone();
        stage_ms.single_scattering = ms(t_start);
        let mut j_ms = vec![0.0f32; grid.cells() * n_j];
        let mut j_n = Vec::new();
        let mut fractions = vec![1.0];
        let mut orders = 1;
        while orders < s.max_orders {
            if cancelled() {
                return None;
            }
            let t_j = std::time::Instant::now();
            j_n = scattering_density(&l_n);
            let j_ms_elapsed = ms(t_j);
            stage_ms.scattering_density += j_ms_elapsed;
            let t_l = std::time::Instant::now();
            l_n = radiance(
                PassInput::Order {
                    j: &j_n,
                    ground: &e_n,
                },
                &mut positions,
            );
            e_n = ground_of(&l_n);
            let l_elapsed = ms(t_l);
            stage_ms.radiance += l_elapsed;
            j_ms.par_iter_mut().zip(&j_n).for_each(|(a, b)| *a += b);
            ground_sky.iter_mut().zip(&e_n).for_each(|(a, b)| *a += b);
            let sums = sums_of(&l_n);
            let added: f64 = sums.iter().sum();
            series.push(sums, true);
            orders += 1;
            let total: f64 = series.total.iter().sum();
            let fraction = if total > 0.0 { added / total } else { 0.0 };
            fractions.push(fraction);
            let tail_error = series.tail().map(|t| t.1);
            tracing::debug!(
                order = orders,
                fraction,
                tail_error,
                scattering_density_ms = j_ms_elapsed,
                radiance_ms = l_elapsed,
                "precise multiple scattering order"
            );
            if fraction < s.tolerance
                || (s.extrapolate_tail && tail_error.is_some_and(|e| e < s.tolerance))
            {
                break;
            }
        }
        let last_fraction = *fractions.last().unwrap_or(&0.0);
        let (tail_fraction, series_error_estimate, order_ratio) = match series.tail() {
            Some((tail, err, q, factors)) if s.extrapolate_tail => {
                // Σ_{m>n} J_m ≈ J_n q/(1 − q), Σ_{m>n} E_m ≈ E_n q/(1 − q), per (θ_s, λ).
                j_ms.par_chunks_mut(family_len_j)
                    .zip(j_n.par_chunks(family_len_j))
                    .for_each(|(acc, jn)| {
                        let rows = acc.chunks_mut(s.n_phi * n_j).zip(jn.chunks(s.n_phi * n_j));
                        for (is, (acc, jn)) in rows.enumerate() {
                            // The same factor for both constituents' lanes.
                            let f: Vec<f32> = factors[is * n_l..][..n_l]
                                .iter()
                                .chain(&factors[is * n_l..][..n_l])
                                .map(|&f| f as f32)
                                .collect();
                            for (a, b) in acc.chunks_mut(n_j).zip(jn.chunks(n_j)) {
                                a.iter_mut()
                                    .zip(b)
                                    .zip(&f)
                                    .for_each(|((a, b), f)| *a += b * f);
                            }
                        }
                    });
                for (x, (g, e)) in ground_sky.iter_mut().zip(&e_n).enumerate() {
                    *g += e * factors[x];
                }
                (tail / (1.0 + tail), err / (1.0 + tail), q)
            }
            Some((_, _, q, _)) => (0.0, last_fraction * q / (1.0 - q), q),
            None => (0.0, last_fraction, 0.0),
        };
        stage_ms.total = ms(t_start);
        tracing::debug!(
            position_cache_mb =
                (POSITION_CACHE_BYTES - positions_left.load(Ordering::Relaxed)) as f64 / 1048576.0,
            families_computing_positions = positions
                .iter()
                .filter(|p| p.state == CacheState::Off)
                .count(),
            total_ms = stage_ms.total,
            "precise build done"
        );
        Some(Self {
            grid,
            n_l,
            j_ms,
            scattering: ScatteringCoefficient::new(medium),
            ground_sky,
            ln_j_ms: std::sync::OnceLock::new(),
            convergence: Convergence {
                orders,
                last_order_fraction: last_fraction,
                order_fractions: fractions,
                tail_fraction,
                series_error_estimate,
                order_ratio,
                stage_ms,
            },
        })
    }
}

/// Version of the stored table layout (part of its store key).
/// (2: twice-as-dense sun-zenith nodes beyond 80°, for twilight; 3: f32 exp/ln in the build;
/// 4: Â_R and Â_M per constituent instead of J; 5: the view-zenith poles' azimuthal mean in the
/// radiance passes, [`Grid::theta_corners`]; 6: radius nodes added in optically thick haze,
/// [`radius_nodes`], the stored `n_r` counting them; 7: azimuth nodes doubled in strongly
/// forward aerosols, [`azimuth_nodes`], the stored `n_phi` counting them; 8: a layered aerosol's
/// boundary layer taken exactly in the density integrals and with equal ray steps inside it,
/// `transmittance::DensityIntegralTable`, `integrate::ray_points`; 9: at least
/// [`DENSE_FORWARD_GRID`] in dense strongly forward aerosols, [`dense_forward_settings`]; 10: at
/// `high` and finer, [`SINGLE_SUBRAYS`] rays per band in the order-1 pass, [`single_subrays`], and
/// the radius, azimuth and step floors of dense aerosols, [`dense_forward_settings`].)
pub const TABLE_FORMAT: &str = "precise-table-10";
/// Header attribute holding the stored table's description ([`StoredPrecise`] as JSON).
const ATTR_TABLE: &str = "skybakeSharedTable";

/// What a stored precise table says about itself; it is used only if all of it matches.
#[derive(serde::Serialize, serde::Deserialize)]
struct StoredPrecise {
    kind: String,
    settings: PreciseSettings,
    bottom_radius_m: f64,
    top_radius_m: f64,
    wavelengths_nm: Vec<f64>,
    /// `[i_mu_s][λ]`, exact (JSON numbers round-trip f64).
    ground_sky: Vec<f64>,
    convergence: Convergence,
}

impl PreciseMultipleScattering {
    /// The table as a spectral image for the table store: pixel (x, y) = (i_mu_s · n_φ + i_φ,
    /// c · n_r · n_μ + i_r · n_μ + i_μ) for constituent c (Â_R, then Â_M), one plane per wavelength
    /// (f32, as computed), and the ground sky
    /// irradiance, settings and convergence record as a JSON header attribute.
    pub fn to_image(&self, medium: &Medium) -> crate::Result<SpectralImage> {
        let s = self.grid.s;
        let (w, h) = (self.grid.family_cells(), s.n_r * s.n_mu);
        let n_l = self.n_l;
        // Rows [0, h): Â_R; rows [h, 2h): Â_M.
        let planes = (0..n_l)
            .map(|i| {
                (0..2 * w * h)
                    .map(|px| self.j_ms[(px % (w * h)) * 2 * n_l + (px / (w * h)) * n_l + i])
                    .collect()
            })
            .collect();
        let mut image = SpectralImage::emissive(w, 2 * h, &medium.wavelengths_nm, planes)?;
        let meta = StoredPrecise {
            kind: "precise".into(),
            settings: s,
            bottom_radius_m: self.grid.bottom,
            top_radius_m: self.grid.top,
            wavelengths_nm: medium.wavelengths_nm.clone(),
            ground_sky: self.ground_sky.clone(),
            convergence: self.convergence.clone(),
        };
        let json = serde_json::to_string(&meta)
            .map_err(|e| crate::Error::invalid("precise_table", e.to_string()))?;
        image.set_attribute(ATTR_TABLE, json)?;
        Ok(image)
    }

    /// The table stored by [`Self::to_image`], if it was made for exactly this medium's geometry
    /// and wavelengths with these settings and holds only finite, non-negative values.
    pub fn from_image(image: &SpectralImage, medium: &Medium, s: PreciseSettings) -> Option<Self> {
        let meta: StoredPrecise = serde_json::from_str(image.attribute(ATTR_TABLE)?).ok()?;
        let n_l = medium.len();
        let grid = Grid::new(s, medium);
        // The grid's settings (`n_mu_s` counts the denser twilight nodes), as `to_image` stores.
        let s = grid.s;
        let (w, h) = (grid.family_cells(), s.n_r * s.n_mu);
        let planes = image.layers().first()?.planes();
        let valid = |v: f64| v.is_finite() && v >= 0.0;
        let matches = meta.kind == "precise"
            && meta.settings == s
            && meta.bottom_radius_m == medium.bottom_radius_m
            && meta.top_radius_m == medium.top_radius_m
            && meta.wavelengths_nm == medium.wavelengths_nm
            && image.width() == w
            && image.height() == 2 * h
            && planes.len() == n_l
            && planes.iter().all(|p| p.len() == 2 * w * h)
            && meta.ground_sky.len() == s.n_mu_s * n_l
            && meta.ground_sky.iter().all(|&v| valid(v));
        if !matches {
            return None;
        }
        // Interleaved [pixel][c][λ], written in order (Â_M's rows follow Â_R's).
        let mut j_ms = Vec::with_capacity(2 * w * h * n_l);
        for px in 0..w * h {
            j_ms.extend(planes.iter().map(|p| p[px]));
            j_ms.extend(planes.iter().map(|p| p[w * h + px]));
        }
        if !j_ms.iter().all(|&v| valid(v as f64)) {
            return None;
        }
        Some(Self {
            grid,
            n_l,
            j_ms,
            scattering: ScatteringCoefficient::new(medium),
            ground_sky: meta.ground_sky,
            convergence: meta.convergence,
            ln_j_ms: std::sync::OnceLock::new(),
        })
    }
}

/// J_ms at one ray point for every sun, for callers that evaluate many suns on the same rays
/// (the texture bundle: 256 suns per ray): the table interpolated once to the point's radius and
/// view zenith for the day cells, and the point's (r, θ) corners whose logarithms (taken once per
/// table, `ln_j_ms`) the products' twilight interpolation uses. Filled by
/// [`PreciseMultipleScattering::slice`], read by [`PreciseMultipleScattering::add_from_slice`].
#[derive(Debug, Clone, Default)]
pub struct JSlice {
    /// Radius and view zenith cosine of the point.
    r: f64,
    mu: f64,
    /// Relative densities of the Rayleigh and aerosol scatterers there.
    rho: (f64, f64),
    /// `[i_mu_s][i_phi][c][λ]`: Â_R and Â_M interpolated to the point, on the sun-zenith rows
    /// the day cells read (up to the first twilight cell's, [`TwilightRows::first_cell`]).
    per_constituent: Vec<f64>,
    /// `[i_mu_s][i_phi][λ]`: J at the point (day cells only, the same rows).
    lin: Vec<f64>,
    /// Whether `per_constituent` and `lin` are filled ([`PreciseMultipleScattering::fill_day`]).
    day: bool,
    /// The (r, θ) corners of the point with a non-zero weight: (r node, θ node, weight, whether
    /// it is a pole's azimuthal mean, [`Grid::theta_corners`]), in the order the products' lookup
    /// visits them.
    corners: Vec<(usize, usize, f64, bool)>,
}

impl PreciseMultipleScattering {
    /// The twilight rows ([`TwilightRows`]) of the table, computed on first use: the logarithms
    /// the products' twilight interpolation takes at each lookup, in f32 as the table's own
    /// radiance passes take them, taken once per table; for up to four wavelengths (RGB) with
    /// the node's values beside them, each padded to one vector.
    fn ln_j_ms(&self) -> &TwilightRows {
        self.ln_j_ms.get_or_init(|| {
            let grid = &self.grid;
            let n_mu_s = grid.s.n_mu_s;
            let first_cell = (0..n_mu_s.saturating_sub(1))
                .find(|&is| grid.twilight_cell(is))
                .unwrap_or(n_mu_s);
            let from = first_cell.saturating_sub(1);
            let lanes = 2 * self.n_l;
            let per_node = grid.s.n_phi * lanes;
            // Serial (a few ms): a parallel loop here could let this thread steal a task that
            // waits on this same initialisation.
            let families = self.j_ms.chunks(n_mu_s * per_node);
            let mut rows = TwilightRows {
                from,
                first_cell,
                ..TwilightRows::default()
            };
            if lanes <= PACKED_LANES {
                let mut packed = Vec::with_capacity(
                    self.j_ms.len() / lanes * (n_mu_s - from) / n_mu_s * 2 * PACKED_LANES,
                );
                // Each constituent's n_λ lanes (`[c][λ]` in `j_ms`) padded to its half.
                let pad = PACKED_HALF - self.n_l;
                for family in families {
                    for node in family[from * per_node..].chunks(per_node) {
                        for c in node.chunks(self.n_l) {
                            packed.extend_from_slice(c);
                            packed.extend((0..pad).map(|_| 0.0));
                        }
                        for c in node.chunks(self.n_l) {
                            packed.extend(c.iter().map(|&v| ln_or_zero_f32(v)));
                            packed.extend((0..pad).map(|_| 0.0));
                        }
                    }
                }
                rows.packed = packed;
            } else {
                rows.ln = families
                    .flat_map(|family| family[from * per_node..].iter().map(|&v| ln_or_zero_f32(v)))
                    .collect();
            }
            rows
        })
    }

    /// The slice of the table at radius `r` and view zenith cosine `mu`: Â_R and Â_M
    /// multilinear in (r, θ) as [`Source::add_scattering`] interpolates, then weighted by the
    /// point's scattering coefficients σ_c ρ_c(r) into J ([`Self::slice_corners`], then
    /// [`Self::fill_day`]).
    pub fn slice(&self, r: f64, mu: f64, out: &mut JSlice) {
        self.slice_corners(r, mu, out);
        self.fill_day(out);
    }

    /// The part of [`Self::slice`] every lookup reads: the point's (r, θ) corners and
    /// densities. The day cells' rows are left empty until [`Self::fill_day`]; a twilight
    /// lookup reads the corners' own rows of the table ([`PackedPoint`]), so a point whose
    /// suns are all beyond [`Self::day_mu_s`] needs no more.
    pub fn slice_corners(&self, r: f64, mu: f64, out: &mut JSlice) {
        self.ln_j_ms();
        let grid = &self.grid;
        out.r = r;
        out.mu = mu;
        out.per_constituent.clear();
        out.lin.clear();
        out.day = false;
        out.corners.clear();
        let (ir, fr) = grid.r_pos(r);
        let theta = acos_fast(mu);
        for (a, wa) in [(ir, 1.0 - fr), (ir + 1, fr)] {
            for (c, wc, pole) in Grid::theta_corners(theta, grid.s.n_mu) {
                let w = wa * wc;
                if w == 0.0 {
                    continue;
                }
                out.corners.push((a, c, w, pole));
            }
        }
        out.rho = self.scattering.densities(r);
    }

    /// Fills the day cells' rows of a slice from [`Self::slice_corners`] (nothing if filled):
    /// only the sun-zenith rows the day cells read (0 ..= the first twilight cell's,
    /// [`TwilightRows::first_cell`]), each corner added in the corners' order.
    pub fn fill_day(&self, out: &mut JSlice) {
        if out.day {
            return;
        }
        let first_cell = self.ln_j_ms().first_cell;
        let grid = &self.grid;
        let (n_l, n_mu_s, n_mu, n_phi) = (self.n_l, grid.s.n_mu_s, grid.s.n_mu, grid.s.n_phi);
        // The day cells `is < first_cell` read rows `is` and `is + 1`.
        let n_day = (first_cell + 1).min(n_mu_s);
        let cells = n_day * n_phi;
        let lanes = 2 * n_l;
        // The family's rows in the table, of which the first `n_day` are read.
        let fam = n_mu_s * n_phi * lanes;
        let day = cells * lanes;
        out.per_constituent.clear();
        out.per_constituent.resize(day, 0.0);
        for &(a, c, w, pole) in &out.corners {
            // Family layout: (r, θ) rows of [i_mu_s][i_phi][c][λ].
            let base = (a * n_mu + c) * fam;
            let row = &self.j_ms[base..base + day];
            if pole {
                // The mean of the node's azimuths in every azimuth (`Grid::theta_corners`).
                let w = w / n_phi as f64;
                for is in 0..n_day {
                    let block = is * n_phi * lanes;
                    for x in 0..lanes {
                        let m: f64 = (0..n_phi).map(|l| row[block + l * lanes + x] as f64).sum();
                        for l in 0..n_phi {
                            out.per_constituent[block + l * lanes + x] += w * m;
                        }
                    }
                }
            } else {
                for (o, v) in out.per_constituent.iter_mut().zip(row) {
                    *o += w * *v as f64;
                }
            }
        }
        let sc = &self.scattering;
        let (rho_r, rho_m) = out.rho;
        out.lin.clear();
        out.lin.resize(cells * n_l, 0.0);
        for (cell, j) in out.lin.chunks_exact_mut(n_l).enumerate() {
            let a = &out.per_constituent[cell * lanes..][..lanes];
            for i in 0..n_l {
                j[i] = sc.rayleigh_per_m[i] * rho_r * a[i] + sc.mie_per_m[i] * rho_m * a[n_l + i];
            }
        }
        out.day = true;
    }

    /// A sun zenith cosine above which a lookup may read a slice's day cells
    /// ([`Self::fill_day`]): the first twilight cell's lower node less 10⁻³ rad in angle (far
    /// beyond the error of `acos_fast` and of the node position's rounding). A slice whose
    /// suns are all at or below it needs only [`Self::slice_corners`].
    pub fn day_mu_s(&self) -> f64 {
        let first_cell = self.ln_j_ms().first_cell;
        if first_cell >= self.grid.s.n_mu_s.saturating_sub(1) {
            return -2.0;
        }
        (self.grid.theta_s(first_cell) + 1e-3).cos()
    }

    /// Adds J_ms (m⁻¹ sr⁻¹ per unit solar irradiance) for the sun at zenith cosine `mu_s` and
    /// view–sun cosine `nu` at the slice's point, as [`Source::add_scattering`] computes it: by
    /// day bilinear over sun zenith and azimuth in the slice (the products' 16-corner
    /// interpolation, summed in another order); in twilight cells the products' interpolation
    /// (Catmull–Rom in ln Â_c at each (r, θ, φ) corner) in f32 as the table's own radiance passes
    /// compute it ([`twilight_lanes_f32`]: within 4·10⁻⁶ of the products' f64 [`twilight_lanes`],
    /// at a third of the cost; for up to four wavelengths with a cubic exponential,
    /// [`PackedPoint`]: within 8·10⁻⁵), with the logarithms taken once per table (`ln_j_ms`).
    pub fn add_from_slice(&self, slice: &JSlice, mu_s: f64, nu: f64, out: &mut [f64]) {
        add_from_slice_kernel(
            self,
            slice,
            std::slice::from_ref(&mu_s),
            std::slice::from_ref(&nu),
            out,
        );
    }

    /// [`Self::add_from_slice`] for the suns (`mu_s[t]`, `nu[t]`) at the slice's point, adding
    /// to `out[t·n_λ ..][.. n_λ]`: the same values, with what the suns share (the twilight rows,
    /// the point's densities) fetched once and their angles computed a vector at a time.
    pub fn add_from_slice_many(&self, slice: &JSlice, mu_s: &[f64], nu: &[f64], out: &mut [f64]) {
        add_from_slice_kernel(self, slice, mu_s, nu, out);
    }
}

/// What the twilight (r, θ, φ) corners of one [`PreciseMultipleScattering::add_from_slice`]
/// lookup share: the table, its logarithms (`ln_j_ms`) and the sun zenith's Catmull–Rom nodes and
/// weights. A plain `#[inline(always)]` method rather than a closure: the closure was compiled
/// on its own, without the AVX2 of the kernel around it, so its exponentials ran one lane at a
/// time (63 % of the bundle's CPU time).
struct TwilightCorners<'a> {
    j_ms: &'a [f32],
    ln_j: &'a [f32],
    ln_from: usize,
    per_family: usize,
    n_mu: usize,
    n_mu_s: usize,
    n_phi: usize,
    lanes: usize,
    nodes: [usize; 4],
    wq: [f32; 4],
    fs: f32,
}

/// The four Catmull–Rom nodes' rows of `N` lanes: values and logarithms.
type NodeRows<'a, const N: usize> = ([&'a [f32; N]; 4], [&'a [f32; N]; 4]);

impl TwilightCorners<'_> {
    /// Adds `w` × the corner (r node `ir`, θ node `im`, φ node `e`) interpolated over sun zenith
    /// ([`twilight_lanes_f32`]) to `a` (`[c][λ]`).
    #[inline(always)]
    fn add(&self, ir: usize, im: usize, e: usize, w: f32, a: &mut [f32]) {
        if w == 0.0 {
            return;
        }
        let lanes = self.lanes;
        if lanes <= 8 {
            if let Some((v, ln_v)) = self.rows_fixed::<8>(ir, im, e) {
                let x = twilight_fixed(v, ln_v, self.wq, self.fs);
                for (o, v) in a.iter_mut().zip(&x[..lanes]) {
                    *o += w * *v;
                }
                return;
            }
        }
        let (v, ln_v) = self.rows(ir, im, e, lanes);
        twilight_lanes_f32(v, ln_v, self.wq, self.fs, w, a);
    }

    /// [`Self::add`] of the azimuth nodes `e` and `e + 1` with weights `w0` and `w1`, in that
    /// order (the same values): the two nodes' lanes are adjacent in the table, so they are
    /// interpolated as one run of 2 × 2n_λ lanes (12 for RGB).
    #[inline(always)]
    fn add_pair(&self, ir: usize, im: usize, e: usize, w0: f32, w1: f32, a: &mut [f32]) {
        const MAX: usize = crate::spectrum::wavelengths::MAX_WAVELENGTHS;
        let lanes = self.lanes;
        // Up to 16 lanes (RGB: 12) as two whole AVX2 vectors, reading past the two nodes'
        // lanes into the table's next values (computed and dropped) where the table has them.
        if 2 * lanes <= 16 {
            if let Some((v, ln_v)) = self.rows_fixed::<16>(ir, im, e) {
                let x = twilight_fixed(v, ln_v, self.wq, self.fs);
                for (o, v) in a.iter_mut().zip(&x[..lanes]) {
                    *o += w0 * *v;
                }
                for (o, v) in a.iter_mut().zip(&x[lanes..2 * lanes]) {
                    *o += w1 * *v;
                }
                return;
            }
        }
        let (v, ln_v) = self.rows(ir, im, e, 2 * lanes);
        let mut x = [0.0f32; 4 * MAX];
        let x = &mut x[..2 * lanes];
        twilight_lanes_f32(v, ln_v, self.wq, self.fs, 1.0, x);
        for (o, v) in a.iter_mut().zip(&x[..lanes]) {
            *o += w0 * *v;
        }
        for (o, v) in a.iter_mut().zip(&x[lanes..]) {
            *o += w1 * *v;
        }
    }

    /// [`Self::rows`] of `N` lanes as arrays, if the table holds them.
    #[inline(always)]
    fn rows_fixed<const N: usize>(
        &self,
        ir: usize,
        im: usize,
        e: usize,
    ) -> Option<NodeRows<'_, N>> {
        let lanes = self.lanes;
        let family = ir * self.n_mu + im;
        let [b0, b1, b2, b3] = self.nodes;
        let base = |b: usize| ((family * self.n_mu_s + b) * self.n_phi + e) * lanes;
        let ln_at =
            |b: usize| family * self.per_family + ((b - self.ln_from) * self.n_phi + e) * lanes;
        fn row<const N: usize>(t: &[f32], i: usize) -> Option<&[f32; N]> {
            t.get(i..i + N)?.try_into().ok()
        }
        Some((
            [
                row(self.j_ms, base(b0))?,
                row(self.j_ms, base(b1))?,
                row(self.j_ms, base(b2))?,
                row(self.j_ms, base(b3))?,
            ],
            [
                row(self.ln_j, ln_at(b0))?,
                row(self.ln_j, ln_at(b1))?,
                row(self.ln_j, ln_at(b2))?,
                row(self.ln_j, ln_at(b3))?,
            ],
        ))
    }

    /// The four Catmull–Rom nodes' rows of `n` lanes from azimuth node `e` of the corner: values
    /// and logarithms.
    #[inline(always)]
    fn rows(&self, ir: usize, im: usize, e: usize, n: usize) -> ([&[f32]; 4], [&[f32]; 4]) {
        let lanes = self.lanes;
        let family = ir * self.n_mu + im;
        let [b0, b1, b2, b3] = self.nodes;
        let base = |b: usize| ((family * self.n_mu_s + b) * self.n_phi + e) * lanes;
        let ln_at =
            |b: usize| family * self.per_family + ((b - self.ln_from) * self.n_phi + e) * lanes;
        let (i0, i1, i2, i3) = (base(b0), base(b1), base(b2), base(b3));
        let (l0, l1, l2, l3) = (ln_at(b0), ln_at(b1), ln_at(b2), ln_at(b3));
        (
            [
                &self.j_ms[i0..i0 + n],
                &self.j_ms[i1..i1 + n],
                &self.j_ms[i2..i2 + n],
                &self.j_ms[i3..i3 + n],
            ],
            [
                &self.ln_j[l0..l0 + n],
                &self.ln_j[l1..l1 + n],
                &self.ln_j[l2..l2 + n],
                &self.ln_j[l3..l3 + n],
            ],
        )
    }
}

/// The four Catmull–Rom nodes' runs of `N` lanes of [`TwilightRows::packed`] at offsets `o`
/// (values) and `o + ln_at` (logarithms): one azimuth node's, `N` = [`PACKED_LANES`], or two
/// adjacent nodes', 2 [`PACKED_LANES`]. One bounds check for the eight runs instead of one each
/// (two compares and branches a run).
#[inline(always)]
fn packed_runs<const N: usize>(
    packed: &[f32],
    o: [usize; 4],
    ln_at: usize,
) -> ([&[f32; N]; 4], [&[f32; N]; 4]) {
    /// # Safety
    /// `o + N ≤ packed.len()`.
    #[inline(always)]
    unsafe fn run<const N: usize>(packed: &[f32], o: usize) -> &[f32; N] {
        // SAFETY: the N lanes from `o` are inside the slice (the caller's contract), and
        // [f32; N] has the alignment of f32.
        unsafe { &*packed.as_ptr().add(o).cast::<[f32; N]>() }
    }
    let hi = o[0].max(o[1]).max(o[2]).max(o[3]);
    assert!(
        hi <= packed.len() && packed.len() - hi >= ln_at + N,
        "twilight rows out of range"
    );
    // SAFETY: every run ends at or before hi + ln_at + N ≤ packed.len() (asserted just above,
    // without overflow).
    unsafe {
        (
            [
                run(packed, o[0]),
                run(packed, o[1]),
                run(packed, o[2]),
                run(packed, o[3]),
            ],
            [
                run(packed, o[0] + ln_at),
                run(packed, o[1] + ln_at),
                run(packed, o[2] + ln_at),
                run(packed, o[3] + ln_at),
            ],
        )
    }
}

/// What the twilight lookups of one point share in [`TwilightRows::packed`] (2 n_λ ≤
/// [`PACKED_LANES`]), taken once for all its suns ([`add_from_slice_kernel`]): each (r, θ)
/// corner's first record, weight and whether it is a pole's azimuthal mean. Its methods are
/// `#[inline(always)]`, so they are compiled into each copy of the kernel (AVX-512, AVX2) with no
/// call per sun.
struct PackedPoint<'a> {
    packed: &'a [f32],
    from: usize,
    n_phi: usize,
    /// Lanes of one sun-zenith node's record (its azimuth nodes' values, then their
    /// logarithms), and the logarithms' offset in it.
    block: usize,
    ln_at: usize,
    /// The slice's corners ([`JSlice::corners`]): the offset of the record of sun-zenith node
    /// `from`, the weight, whether a pole's mean; the first `n` are set.
    corners: [(usize, f64, bool); 4],
    n: usize,
    /// Four corners, none a pole's (the case of almost every point): the corners' loop then
    /// has a fixed count and no branch.
    plain: bool,
}

impl<'a> PackedPoint<'a> {
    #[inline(always)]
    fn new(
        rows: &'a TwilightRows,
        slice: &JSlice,
        n_mu: usize,
        n_mu_s: usize,
        n_phi: usize,
    ) -> Self {
        let block = 2 * n_phi * PACKED_LANES;
        let n_tw = n_mu_s - rows.from;
        let mut corners = [(0, 0.0, false); 4];
        // Two radius nodes × two view-zenith nodes at most ([`Grid::theta_corners`]).
        assert!(slice.corners.len() <= corners.len());
        for (c, &(ir, im, wc, pole)) in corners.iter_mut().zip(&slice.corners) {
            *c = ((ir * n_mu + im) * n_tw * block, wc, pole);
        }
        Self {
            packed: &rows.packed,
            from: rows.from,
            n_phi,
            block,
            ln_at: n_phi * PACKED_LANES,
            corners,
            n: slice.corners.len(),
            plain: slice.corners.len() == 4 && slice.corners.iter().all(|c| !c.3),
        }
    }

    /// The offsets of the Catmull–Rom `nodes`' records from a corner's first.
    #[inline(always)]
    fn node_offsets(&self, nodes: [usize; 4]) -> [usize; 4] {
        let (from, block) = (self.from, self.block);
        [
            (nodes[0] - from) * block,
            (nodes[1] - from) * block,
            (nodes[2] - from) * block,
            (nodes[3] - from) * block,
        ]
    }

    /// The twilight interpolation of [`add_from_slice_kernel`]: Â_R and Â_M (each n_λ lanes of
    /// its half, [`TwilightRows::packed`]) summed
    /// over the point's (r, θ) corners and the azimuth nodes `ip`, `ip + 1` (weights 1 − `fp`,
    /// `fp`), each corner and node interpolated over sun zenith on the Catmull–Rom `nodes` and
    /// weights `wq`, `fs`: lane by lane the operations of [`TwilightCorners`] in the same order,
    /// each node in one whole vector, but the exponential the cubic
    /// [`twilight_bundle::exp_cubic_f32`] (relative error ≤ 8·10⁻⁵, below the bundles' half
    /// floats) instead of [`exp_fast_f32`].
    #[inline(always)]
    fn interp(
        &self,
        nodes: [usize; 4],
        wq: [f32; 4],
        fs: f32,
        ip: usize,
        fp: f64,
    ) -> [f32; PACKED_LANES] {
        const L: usize = PACKED_LANES;
        let (p, ln_at, n_phi) = (self.packed, self.ln_at, self.n_phi);
        let [b0, b1, b2, b3] = self.node_offsets(nodes);
        let mut a = [0.0f32; L];
        for &(base, wc, pole) in &self.corners[..self.n] {
            if !pole {
                // Azimuth nodes `ip` and `ip + 1`, adjacent: each sun-zenith node's pair of
                // values (and of logarithms) read as one run.
                let o = base + ip * L;
                let (v, ln) = packed_runs(p, [o + b0, o + b1, o + b2, o + b3], ln_at);
                twilight_bundle::add_pair(
                    v,
                    ln,
                    [(wc * (1.0 - fp)) as f32, (wc * fp) as f32],
                    wq,
                    fs,
                    &mut a,
                );
                continue;
            }
            let w = (wc / n_phi as f64) as f32;
            if w == 0.0 {
                continue;
            }
            for e in 0..n_phi {
                let o = base + e * L;
                let (v, ln) = packed_runs::<L>(p, [o + b0, o + b1, o + b2, o + b3], ln_at);
                let x = twilight_bundle::twilight_fixed_cubic(v, ln, wq, fs);
                for (o, v) in a.iter_mut().zip(&x) {
                    *o += w * *v;
                }
            }
        }
        a
    }

    /// Adds to `a` the terms of two adjacent azimuth nodes (one run of 2 [`PACKED_LANES`] from
    /// offset `o` of a corner's records, the Catmull–Rom nodes at `b` from it) with weights `w`:
    /// one [`twilight_bundle::twilight_fixed_cubic`] of 16 lanes, then the first node's term and
    /// the second's added in that order.
    #[inline(always)]
    fn add_pair_wide(
        &self,
        a: &mut [f32; PACKED_LANES],
        o: usize,
        b: [usize; 4],
        w: [f32; 2],
        wq: [f32; 4],
        fs: f32,
    ) {
        const L: usize = PACKED_LANES;
        let o = [o + b[0], o + b[1], o + b[2], o + b[3]];
        let (v, ln) = packed_runs::<{ 2 * L }>(self.packed, o, self.ln_at);
        let x = twilight_bundle::twilight_fixed_cubic(v, ln, wq, fs);
        let (lo, hi) = x.split_at(L);
        for i in 0..L {
            a[i] += w[0] * lo[i];
        }
        for i in 0..L {
            a[i] += w[1] * hi[i];
        }
    }

    /// [`Self::interp`] for the AVX-512 copy of the kernel: two azimuth nodes of a corner (`e`,
    /// `e + 1`, one run of [`TwilightRows::packed`]) in one 16-lane vector, so each corner's pair
    /// of nodes costs one [`twilight_bundle::twilight_fixed_cubic`] of 16 lanes instead of two of
    /// 8 (the RGB case uses 6 lanes of each node). Lane by lane the same operations, and each
    /// node's term is added to the sum in the same order (node `e`, then `e + 1`), so the values
    /// are those of [`Self::interp`].
    #[inline(always)]
    fn interp_wide(
        &self,
        nodes: [usize; 4],
        wq: [f32; 4],
        fs: f32,
        ip: usize,
        fp: f64,
    ) -> [f32; PACKED_LANES] {
        const L: usize = PACKED_LANES;
        let (p, ln_at, n_phi) = (self.packed, self.ln_at, self.n_phi);
        let b = self.node_offsets(nodes);
        let [b0, b1, b2, b3] = b;
        let mut a = [0.0f32; L];
        if self.plain {
            // A fixed count, no branch: the usual case, where the four corners' work overlaps.
            for &(base, wc, _) in &self.corners {
                let w = [(wc * (1.0 - fp)) as f32, (wc * fp) as f32];
                self.add_pair_wide(&mut a, base + ip * L, b, w, wq, fs);
            }
            return a;
        }
        for &(base, wc, pole) in &self.corners[..self.n] {
            // (first node of the pair, its weight, the next node's weight)
            let (e_from, e_to, w_pole) = if pole {
                (0, n_phi, (wc / n_phi as f64) as f32)
            } else {
                (ip, ip + 2, 0.0)
            };
            if pole && w_pole == 0.0 {
                continue;
            }
            let (w0, w1) = if pole {
                (w_pole, w_pole)
            } else {
                ((wc * (1.0 - fp)) as f32, (wc * fp) as f32)
            };
            let mut e = e_from;
            while e < e_to {
                let o = base + e * L;
                if e + 1 < e_to {
                    self.add_pair_wide(&mut a, o, b, [w0, w1], wq, fs);
                    e += 2;
                } else {
                    // An odd pole count's last node.
                    let (v, ln) = packed_runs::<L>(p, [o + b0, o + b1, o + b2, o + b3], ln_at);
                    let x = twilight_bundle::twilight_fixed_cubic(v, ln, wq, fs);
                    for (o, v) in a.iter_mut().zip(&x) {
                        *o += w0 * *v;
                    }
                    e += 1;
                }
            }
        }
        a
    }
}

crate::simd_dispatch_avx512! {
    /// [`PreciseMultipleScattering::add_from_slice_many`], compiled for AVX-512 or AVX2 where the
    /// CPU has it (the same IEEE operations in the same order: no fused multiply-adds are formed,
    /// so the values are those of the baseline build).
    fn add_from_slice_kernel(
        table: &PreciseMultipleScattering,
        slice: &JSlice,
        mu_s: &[f64],
        nu: &[f64],
        out: &mut [f64],
    ) {
            const MAX: usize = crate::spectrum::wavelengths::MAX_WAVELENGTHS;
            // Suns per pass of the angle loop.
            const CHUNK: usize = 64;
            let grid = &table.grid;
            let (n_l, n_mu_s, n_mu, n_phi) = (table.n_l, grid.s.n_mu_s, grid.s.n_mu, grid.s.n_phi);
            let rows = table.ln_j_ms();
            let avx512 = crate::atmosphere::kernels::has_avx512();
            let lanes = 2 * n_l;
            let packed = (lanes <= PACKED_LANES)
                .then(|| PackedPoint::new(rows, slice, n_mu, n_mu_s, n_phi));
            let sc = &table.scattering;
            let (rho_r, rho_m) = slice.rho;
            let n_t = mu_s.len().min(nu.len());
            let mut theta_s = [0.0f64; CHUNK];
            let mut phi = [0.0f64; CHUNK];
            // Sun-zenith and azimuth positions ([`Grid::s_pos_f`], [`Grid::phi_pos_f`]: the values
            // of `s_pos` and `phi_pos`) and the Catmull–Rom weights of the sun-zenith fraction.
            let (mut is_f, mut fs_v) = ([0.0f64; CHUNK], [0.0f64; CHUNK]);
            let (mut ip_f, mut fp_v) = ([0.0f64; CHUNK], [0.0f64; CHUNK]);
            let mut wq_v = [[0.0f32; 4]; CHUNK];
            // σ_c ρ_c at the point, per wavelength.
            let mut ray_rho = [0.0f64; MAX];
            let mut mie_rho = [0.0f64; MAX];
            for i in 0..n_l {
                ray_rho[i] = sc.rayleigh_per_m[i] * rho_r;
                mie_rho[i] = sc.mie_per_m[i] * rho_m;
            }
            for t0 in (0..n_t).step_by(CHUNK) {
                let n = CHUNK.min(n_t - t0);
                let (mu_s, nu) = (&mu_s[t0..t0 + n], &nu[t0..t0 + n]);
                // Branch-free: a vector of suns at a time.
                for q in 0..n {
                    theta_s[q] = acos_fast(mu_s[q]);
                    phi[q] = acos_fast(cos_azimuth(slice.mu, mu_s[q], nu[q]));
                }
                for q in 0..n {
                    (is_f[q], fs_v[q]) = grid.s_pos_f(theta_s[q]);
                    (ip_f[q], fp_v[q]) = Grid::phi_pos_f(phi[q], n_phi);
                    // `catmull_rom`'s weights.
                    let f = fs_v[q];
                    let (f2, f3) = (f * f, f * f * f);
                    wq_v[q] = [
                        (0.5 * (-f3 + 2.0 * f2 - f)) as f32,
                        (0.5 * (3.0 * f3 - 5.0 * f2 + 2.0)) as f32,
                        (0.5 * (-3.0 * f3 + 4.0 * f2 + f)) as f32,
                        (0.5 * (f3 - f2)) as f32,
                    ];
                }
                for q in 0..n {
                    if theta_s[q] > grid.theta_s_max {
                        continue;
                    }
                    let out = &mut out[(t0 + q) * n_l..][..n_l];
                    // Exact small non-negative integers.
                    let (is, fs) = (is_f[q] as usize, fs_v[q]);
                    let (ip, fp) = (ip_f[q] as usize, fp_v[q]);
                    if is >= rows.first_cell {
                        // A twilight cell (`Grid::twilight_cell`).
                        let (nodes, _) = catmull_rom(is, fs, n_mu_s);
                        let wq = wq_v[q];
                        let mut large;
                        if let Some(point) = &packed {
                            let a = if avx512 {
                                point.interp_wide(nodes, wq, fs as f32, ip, fp)
                            } else {
                                point.interp(nodes, wq, fs as f32, ip, fp)
                            };
                            // Four wavelengths at once (n_λ ≤ 4): lane i < n_λ as below, Â_M
                            // in the upper half ([`TwilightRows::packed`]), so both halves are
                            // read from the registers (an offset n_λ read them back from memory
                            // across two stores, which stalled each sun by its store forwarding).
                            let (ray_a, mie_a) = a.split_at(PACKED_HALF);
                            let mut y = [0.0f64; PACKED_HALF];
                            for i in 0..PACKED_HALF {
                                y[i] = (ray_rho[i] * ray_a[i] as f64
                                    + mie_rho[i] * mie_a[i] as f64)
                                    .max(0.0);
                            }
                            for i in 0..n_l {
                                out[i] += y[i];
                            }
                            continue;
                        }
                        let a: &[f32] = {
                            large = [0.0f32; 2 * MAX];
                            let a = &mut large[..lanes];
                            let corners = TwilightCorners {
                                j_ms: &table.j_ms,
                                ln_j: &rows.ln,
                                ln_from: rows.from,
                                per_family: (n_mu_s - rows.from) * n_phi * lanes,
                                n_mu,
                                n_mu_s,
                                n_phi,
                                lanes,
                                nodes,
                                wq,
                                fs: fs as f32,
                            };
                            for &(ir, im, wc, pole) in &slice.corners {
                                if pole {
                                    let w = (wc / n_phi as f64) as f32;
                                    for e in 0..n_phi {
                                        corners.add(ir, im, e, w, a);
                                    }
                                } else {
                                    let (w0, w1) = (wc * (1.0 - fp), wc * fp);
                                    corners.add_pair(ir, im, ip, w0 as f32, w1 as f32, a);
                                }
                            }
                            a
                        };
                        for i in 0..n_l {
                            // Never below 0: the azimuth interpolation's even extrapolation at the
                            // mirror planes ([`Grid::phi_pos`]) has a weight of −1/8 at most.
                            out[i] += (ray_rho[i] * a[i] as f64 + mie_rho[i] * a[n_l + i] as f64)
                                .max(0.0);
                        }
                        continue;
                    }
                    // A day cell: its rows are filled ([`PreciseMultipleScattering::fill_day`];
                    // `lin` is empty otherwise, and the indexing below would panic).
                    debug_assert!(slice.day);
                    let row = n_phi * n_l;
                    let a = is * row + ip * n_l;
                    let (v00, v01) = (&slice.lin[a..a + n_l], &slice.lin[a + n_l..a + 2 * n_l]);
                    let (v10, v11) = (
                        &slice.lin[a + row..a + row + n_l],
                        &slice.lin[a + row + n_l..a + row + 2 * n_l],
                    );
                    let (w00, w01) = ((1.0 - fs) * (1.0 - fp), (1.0 - fs) * fp);
                    let (w10, w11) = (fs * (1.0 - fp), fs * fp);
                    for i in 0..n_l {
                        out[i] += (w00 * v00[i] + w01 * v01[i] + w10 * v10[i] + w11 * v11[i]).max(0.0);
                    }
                }
            }
    }
}

impl Source for PreciseMultipleScattering {
    fn add_scattering(&self, s: &RaySample, out: &mut [f64]) {
        const MAX: usize = crate::spectrum::wavelengths::MAX_WAVELENGTHS;
        let n_l = self.n_l;
        let mut a = [0.0f64; 2 * MAX];
        let a = &mut a[..2 * n_l];
        lookup_j(&self.grid, 2 * n_l, &self.j_ms, s, a);
        let sc = &self.scattering;
        let (rho_r, rho_m) = sc.densities(s.r);
        for i in 0..n_l {
            // Never below 0 (as `add_from_slice`): see [`Grid::phi_pos`].
            out[i] += (sc.rayleigh_per_m[i] * rho_r * a[i] + sc.mie_per_m[i] * rho_m * a[n_l + i])
                .max(0.0);
        }
    }
    fn add_ground_sky_irradiance(&self, mu_s: f64, out: &mut [f64]) {
        lookup_ground(&self.grid, self.n_l, &self.ground_sky, mu_s, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atmosphere::integrate::RaySample;
    use crate::atmosphere::presets::preset;
    use crate::atmosphere::quality::{settings_for, Quality};
    use crate::atmosphere::shared::SharedTables;
    use crate::spectrum::Wavelengths;

    #[test]
    fn view_zenith_corners_go_to_the_pole_mean_within_half_a_step() {
        let n = 32;
        let half = 0.5 * PI / n as f64;
        for theta in [0.0, 0.3 * half, 0.999 * half, PI - 0.5 * half, PI] {
            let c = Grid::theta_corners(theta, n);
            assert!((c[0].1 + c[1].1 - 1.0).abs() < 1e-12, "{theta}: {c:?}");
            assert!(c[1].2 && c[0].0 == c[1].0, "{theta}: {c:?}");
        }
        // At the pole only the azimuthal mean counts; at the first node only the node.
        assert_eq!(Grid::theta_corners(0.0, n)[0].1, 0.0);
        assert_eq!(Grid::theta_corners(PI, n)[0].1, 0.0);
        let at_node = Grid::theta_corners(half, n);
        assert_eq!((at_node[0].0, at_node[0].1, at_node[1].1), (0, 1.0, 0.0));
        // Between nodes: plain linear interpolation.
        let mid = Grid::theta_corners(2.0 * half, n);
        assert_eq!((mid[0].0, mid[1].0, mid[1].2), (0, 1, false));
        assert!((mid[1].1 - 0.5).abs() < 1e-12);
    }

    #[test]
    fn azimuth_interpolation_is_even_about_the_mirror_planes() {
        let n = 12;
        let node = |l: usize| PI * (l as f64 + 0.5) / n as f64;
        // a + bφ² (even about 0) and a + b(π − φ)² (even about π) are interpolated exactly over
        // the last half step; clamping would give the first node's value.
        for (edge, f) in [
            (
                0.0,
                Box::new(|p: f64| 1.0 + 3.0 * p * p) as Box<dyn Fn(f64) -> f64>,
            ),
            (PI, Box::new(|p: f64| 1.0 + 3.0 * (PI - p) * (PI - p))),
        ] {
            for t in [0.0, 0.25, 0.5, 0.99] {
                let phi = if edge == 0.0 {
                    t * node(0)
                } else {
                    PI - t * (PI - node(n - 1))
                };
                let (i, w) = Grid::phi_pos(phi, n);
                let got = (1.0 - w) * f(node(i)) + w * f(node(i + 1));
                assert!((got - f(phi)).abs() < 1e-12, "φ {phi}: {got} vs {}", f(phi));
            }
        }
        // Continuous at the first and last nodes, and linear in between.
        for phi in [node(0), node(n - 1)] {
            let (i, w) = Grid::phi_pos(phi, n);
            let (j, v) = Grid::centred_pos(phi, n);
            assert!(i == j && (w - v).abs() < 1e-12, "{phi}: {i} {w} vs {j} {v}");
        }
        assert_eq!(
            Grid::phi_pos(node(3) + 0.01, n),
            Grid::centred_pos(node(3) + 0.01, n)
        );
        let (i, w) = Grid::phi_pos_f(0.0, n);
        assert!(i == 0.0 && (w + 0.125).abs() < 1e-12, "{i} {w}");
    }

    /// The multiple-scattering source seen straight up does not depend on which side of the
    /// zenith a direction comes from: at 0.01° from the zenith towards and away from the sun it
    /// matches the zenith's own value. (Clamping the view zenith below the first node, 5.6° with
    /// the 16 nodes here, read that node's value towards or away from the sun, which differ by
    /// more than 1 % in hazy air, and the zenith itself on the sun's side.)
    /// The radius grid keeps the uniform nodes for `earth-hazy` (its cost is budgeted) and divides
    /// the intervals of thick haze into parts of 0.15 optical depths on average, checked against
    /// the exponential profiles' closed-form column, τ_c H_c (e^(−h0/H_c) − e^(−h1/H_c)).
    /// The azimuth nodes stay the settings' for `earth` and `earth-hazy` (Cornette-Shanks g 0.7,
    /// mean cosine 0.76: their cost is budgeted) and for a thin forward aerosol, and double for
    /// Cornette-Shanks g 0.8 (mean cosine 0.84) of optical depth 1.
    #[test]
    fn azimuth_grid_doubles_only_in_strongly_forward_aerosols() {
        let wl = Wavelengths::parse("380,440,550,680").unwrap();
        let (_, standard) = settings_for(Quality::Standard);
        for name in ["earth", "earth-hazy"] {
            let m = Medium::new(&preset(name).unwrap(), &wl, None).unwrap();
            assert_eq!(Grid::new(standard, &m).s.n_phi, standard.n_phi, "{name}");
        }
        // `earth-hazy` with its text replaced as `edits` say.
        let with = |edits: &[(&str, &str)]| {
            let mut text = serde_json::to_string(&preset("earth-hazy").unwrap()).unwrap();
            for (from, to) in edits {
                assert!(text.contains(from), "{from}");
                text = text.replace(from, to);
            }
            let params: crate::atmosphere::params::AtmosphereParams =
                serde_json::from_str(&text).unwrap();
            Medium::new(&params, &wl, None).unwrap()
        };
        let g08 = ("\"g\":0.7", "\"g\":0.8");
        let forward = with(&[g08]);
        assert_eq!(Grid::new(standard, &forward).s.n_phi, 2 * standard.n_phi);
        // The cost prediction's count is the built grid's.
        assert_eq!(
            table_radius_and_azimuth_nodes(&standard, &forward).1,
            2 * standard.n_phi
        );
        let thin = with(&[g08, ("\"value\":1.0", "\"value\":0.05")]);
        assert_eq!(Grid::new(standard, &thin).s.n_phi, standard.n_phi);
    }

    /// The radius, view-zenith, azimuth and step counts stay the settings' for `earth` and a
    /// strongly forward aerosol of scattering optical depth 0.43 at 380 nm at every preset, and for
    /// `earth-hazy` (Cornette-Shanks g 0.7, scattering optical depth 1.4 at 380 nm, mean cosine
    /// 0.76: dense but not strongly forward) at `draft` and `standard` (their cost is budgeted);
    /// at `high` and `reference` `earth-hazy` gets at least [`DENSE_HIGH_N_PHI`] azimuth nodes and
    /// [`DENSE_HIGH_STEPS`] steps and nothing else. Cornette-Shanks g 0.8 (mean cosine 0.84) of
    /// scattering optical depth 1.4 reaches at least [`DENSE_FORWARD_GRID`] at `standard` and
    /// finer (`draft` keeps its grid), with [`DENSE_FORWARD_HIGH_N_R`] radius nodes and
    /// [`DENSE_HIGH_N_PHI`] azimuth nodes (doubled) at `high` and finer but not the step floor of
    /// the aerosols that are not strongly forward; the cost prediction's counts are the built
    /// grid's.
    #[test]
    fn table_grid_grows_only_in_dense_aerosols() {
        let wl = Wavelengths::parse("380,440,550,680").unwrap();
        let with = |edits: &[(&str, &str)]| {
            let mut text = serde_json::to_string(&preset("earth-hazy").unwrap()).unwrap();
            for (from, to) in edits {
                assert!(text.contains(from), "{from}");
                text = text.replace(from, to);
            }
            let params: crate::atmosphere::params::AtmosphereParams =
                serde_json::from_str(&text).unwrap();
            Medium::new(&params, &wl, None).unwrap()
        };
        let g08 = ("\"g\":0.7", "\"g\":0.8");
        let earth = Medium::new(&preset("earth").unwrap(), &wl, None).unwrap();
        let hazy = with(&[]);
        let forward_thin = with(&[
            g08,
            ("\"value\":1.0", "\"value\":0.4"),
            (
                "\"single_scattering_albedo\":0.95",
                "\"single_scattering_albedo\":0.8",
            ),
        ]);
        let dense = with(&[g08]);
        assert!(aerosol_scattering_optical_depth(&forward_thin) < 0.5);
        assert!(aerosol_scattering_optical_depth(&hazy) > 1.3);
        assert!(aerosol_scattering_optical_depth(&dense) > 1.3);
        // `draft` keeps its grid even there.
        let (_, draft) = settings_for(Quality::Draft);
        assert_eq!(dense_forward_settings(draft, &dense), draft);
        assert_eq!(dense_forward_settings(draft, &hazy), draft);
        for q in [
            Quality::Draft,
            Quality::Standard,
            Quality::High,
            Quality::Reference,
        ] {
            let (_, s) = settings_for(q);
            let high = matches!(q, Quality::High | Quality::Reference);
            for m in [&earth, &hazy, &forward_thin] {
                assert_eq!(Grid::new(s, m).n_coarse, s.n_mu_s, "{q:?}");
                let g = Grid::new(s, m).s;
                // `earth-hazy` is dense: the azimuth and step floors at `high` and finer.
                let (n_phi, steps) = if high && std::ptr::eq(m, &hazy) {
                    (s.n_phi.max(DENSE_HIGH_N_PHI), s.steps.max(DENSE_HIGH_STEPS))
                } else {
                    (s.n_phi, s.steps)
                };
                assert_eq!(
                    (g.n_mu, g.steps, g.n_phi),
                    (s.n_mu, steps, azimuth_nodes(m, n_phi)),
                    "{q:?}"
                );
                // The radius grid of the settings' base count (divided in thick haze as before).
                assert_eq!(g.n_r, radius_nodes(m, s.n_r)[s.n_r - 1] + 1, "{q:?}");
                assert_eq!(table_zenith_nodes(&s, m), (s.n_mu_s, s.n_mu));
                assert_eq!(table_radius_and_azimuth_nodes(&s, m), (g.n_r, g.n_phi));
            }
            // The floors bite: `high` has 16 azimuth nodes and 28 steps, `reference` 20 and 40.
            if high {
                let g = Grid::new(s, &hazy).s;
                assert!(g.n_phi > s.n_phi, "{q:?}");
                assert!(q == Quality::Reference || g.steps > s.steps, "{q:?}");
            }
            if q == Quality::Draft {
                continue;
            }
            let g = Grid::new(s, &dense).s;
            let f = DENSE_FORWARD_GRID;
            // Strongly forward: no step floor beyond the dense-forward grid's.
            assert_eq!(
                (g.n_mu, g.steps),
                (s.n_mu.max(f.n_mu), s.steps.max(f.steps)),
                "{q:?}"
            );
            assert!(g.n_mu >= f.n_mu, "{q:?}");
            assert_eq!(
                Grid::new(s, &dense).n_coarse,
                s.n_mu_s.max(f.n_mu_s),
                "{q:?}"
            );
            // `high` and finer: the radius floor of a low sun's slant path through the layer and
            // the azimuth floor (doubled for the forward peak).
            let (floor, n_phi) = if high {
                (DENSE_FORWARD_HIGH_N_R, s.n_phi.max(DENSE_HIGH_N_PHI))
            } else {
                (f.n_r, s.n_phi)
            };
            assert_eq!(g.n_phi, 2 * n_phi, "{q:?}");
            let base = s.n_r.max(floor);
            assert_eq!(g.n_r, radius_nodes(&dense, base)[base - 1] + 1, "{q:?}");
            assert!(g.n_r >= base, "{q:?}");
            assert_eq!(
                table_zenith_nodes(&s, &dense),
                (Grid::new(s, &dense).n_coarse, g.n_mu)
            );
            assert_eq!(table_radius_and_azimuth_nodes(&s, &dense), (g.n_r, g.n_phi));
        }
    }

    /// The order-1 pass samples each view-zenith band at rays whose mean is the band's mean
    /// radiance over its solid angle (what the ground term and the J pass take it for), also for
    /// a field peaked at the zenith, where one ray at the band's middle angle reads high.
    #[test]
    fn single_scattering_rays_average_a_band_over_its_solid_angle() {
        let wl = Wavelengths::parse("550").unwrap();
        let earth = Medium::new(&preset("earth").unwrap(), &wl, None).unwrap();
        let (_, high) = settings_for(Quality::High);
        let grid = Grid::new(high, &earth);
        let n_mu = grid.s.n_mu;
        let r = grid.r(0);
        // An aureole round the zenith, 6° wide (a high sun's forward peak).
        let width = 6f64.to_radians();
        let field = |theta: f64| (-0.5 * (theta / width).powi(2)).exp() + 0.05;
        // The two bands round the zenith (40 at `high`), where the sin θ weight changes most.
        for k in 0..2 {
            let (t0, t1) = (
                PI * k as f64 / n_mu as f64,
                PI * (k + 1) as f64 / n_mu as f64,
            );
            // The band's mean over solid angle: ∫ L sinθ dθ / ∫ sinθ dθ, 4000-point midpoint rule.
            let n = 4000;
            let (mut num, mut den) = (0.0, 0.0);
            for j in 0..n {
                let t = t0 + (t1 - t0) * (j as f64 + 0.5) / n as f64;
                num += field(t) * t.sin();
                den += t.sin();
            }
            let mean = num / den;
            let rays = single_subrays(&grid, r, k);
            assert!((rays.iter().map(|r| r.1).sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(rays.iter().all(|&(t, _)| t > t0 && t < t1), "{rays:?}");
            let sampled: f64 = rays.iter().map(|&(t, w)| w * field(t)).sum();
            // Rays at the midpoints of equal steps in μ: −0.03 / −0.30 %.
            assert!(
                (sampled / mean - 1.0).abs() < 5e-3,
                "band {k}: rays {sampled} band mean {mean}"
            );
            // The band's middle angle alone reads +6.6 / +3.8 % (the error this avoids).
            let middle = field(grid.theta(k));
            assert!(middle / mean - 1.0 > 2e-2, "band {k}: {middle} {mean}");
        }
        // `standard` and `draft` keep the single ray at the band's middle angle (their cost).
        for q in [Quality::Draft, Quality::Standard] {
            let (_, s) = settings_for(q);
            let grid = Grid::new(s, &earth);
            let k = 1;
            assert_eq!(
                single_subrays(&grid, grid.r(0), k),
                vec![(grid.theta(k), 1.0)],
                "{q:?}"
            );
        }
    }

    #[test]
    fn radius_grid_divides_only_optically_thick_intervals() {
        let wl = Wavelengths::parse("380,440,550,680").unwrap();
        let (_, standard) = settings_for(Quality::Standard);
        let hazy = Medium::new(&preset("earth-hazy").unwrap(), &wl, None).unwrap();
        let grid = Grid::new(standard, &hazy);
        assert_eq!(grid.s.n_r, standard.n_r);
        let mut params = preset("earth-hazy").unwrap();
        params.ozone = None;
        let text = serde_json::to_string(&params)
            .unwrap()
            .replace("\"value\":1.0", "\"value\":2.0");
        let params: crate::atmosphere::params::AtmosphereParams =
            serde_json::from_str(&text).unwrap();
        let thick = Medium::new(&params, &wl, None).unwrap();
        let grid = Grid::new(standard, &thick);
        assert!(grid.s.n_r > standard.n_r + 10, "{} nodes", grid.s.n_r);
        // The cost prediction's count is the built grid's.
        assert_eq!(
            table_radius_and_azimuth_nodes(&standard, &thick).0,
            grid.s.n_r
        );
        let column = |h0: f64, h1: f64, i: usize| {
            [(RAYLEIGH, 8000.0), (MIE, 1200.0)]
                .iter()
                .map(|&(c, sh)| {
                    thick.extinction_per_m[c][i] * sh * ((-h0 / sh).exp() - (-h1 / sh).exp())
                })
                .sum::<f64>()
        };
        let b = thick.bottom_radius_m;
        // Each interval of the uniform grid holds at most 0.15 per part (on average: the parts
        // are equal in x, and h grows as x², so an interval's upper parts hold more, at most twice
        // the mean here) and is divided no more than it needs.
        for k in 0..standard.n_r - 1 {
            let (i0, i1) = (grid.r_first[k], grid.r_first[k + 1]);
            let tau = (0..thick.len())
                .map(|l| column(grid.r(i0) - b, grid.r(i1) - b, l))
                .fold(0.0, f64::max);
            let m = (i1 - i0) as f64;
            assert!(tau / m <= 0.15 * 1.001, "{k}: {tau} in {m} parts");
            assert!(tau > 0.15 * (m - 1.0) * 0.999, "{k}: {tau} in {m} parts");
        }
        for i in 0..grid.s.n_r - 1 {
            let (h0, h1) = (grid.r(i) - b, grid.r(i + 1) - b);
            assert!(h1 > h0);
            let tau = (0..thick.len())
                .map(|l| column(h0, h1, l))
                .fold(0.0, f64::max);
            assert!(tau <= 0.3, "interval {i} ({h0}–{h1} m): {tau}");
            // The position of a node and of a point inside an interval.
            let (j, f) = grid.r_pos(grid.r(i));
            assert!((j == i && f.abs() < 1e-9) || (j + 1 == i && (f - 1.0).abs() < 1e-9));
            let (j, f) = grid.r_pos(0.5 * (grid.r(i) + grid.r(i + 1)));
            assert!(j == i && f > 0.0 && f < 1.0, "{i}: {j} {f}");
        }
    }

    /// `preset`'s shared tables at `wavelengths` on a planet of 10 times the Earth's radius,
    /// the precise table on a small grid (10 radii, 12 sun zeniths, 16 view zeniths, 8
    /// azimuths, 8 steps), and the planet's radius.
    fn small_tables(preset_name: &str, wavelengths: &str) -> (SharedTables, f64) {
        let mut params = preset(preset_name).unwrap();
        params.planet_radius_m = 63_600_000.0;
        let medium = Medium::new(&params, &Wavelengths::parse(wavelengths).unwrap(), None).unwrap();
        let (fast, standard) = settings_for(Quality::Standard);
        let s = PreciseSettings {
            n_r: 10,
            n_mu_s: 12,
            n_mu: 16,
            n_phi: 8,
            steps: 8,
            tolerance: 1e-2,
            ..standard
        };
        let bottom = medium.bottom_radius_m;
        (SharedTables::new(medium, fast, s), bottom)
    }

    #[test]
    fn multiple_scattering_source_is_continuous_at_the_zenith_in_hazy_air() {
        let (shared, bottom) = small_tables("earth-hazy", "440,680");
        let r = bottom + 500.0;
        let table = shared.precise();
        let mu_s = 40f64.to_radians().cos();
        let sin_s = (1.0 - mu_s * mu_s).sqrt();
        let j = |theta: f64, cos_phi: f64| {
            let (mu, sin) = (theta.cos(), theta.sin());
            let sample = RaySample {
                t: 0.0,
                weight: 1.0,
                r,
                mu,
                mu_s,
                nu: mu * mu_s + sin * sin_s * cos_phi,
            };
            let mut out = vec![0.0; 2];
            table.add_scattering(&sample, &mut out);
            out
        };
        let zenith = j(0.0, 1.0);
        let eps = 0.01f64.to_radians();
        // And how much J_ms changes over the first node's angle (the size of the old error).
        let first = PI / 32.0;
        for i in 0..2 {
            assert!(zenith[i] > 0.0);
            for cos_phi in [1.0, -1.0] {
                let near = j(eps, cos_phi)[i];
                assert!(
                    (near / zenith[i] - 1.0).abs() < 1e-3,
                    "λ {i} cos φ {cos_phi}: {near} vs {}",
                    zenith[i]
                );
            }
            let (towards, away) = (j(first, 1.0)[i], j(first, -1.0)[i]);
            assert!(towards / away > 1.01, "λ {i}: {towards} {away}");
        }
    }

    /// [`PreciseMultipleScattering::add_from_slice_many`] (the bundle's lookup: many suns at one
    /// ray point) against the products' per-sample lookup, for both twilight paths (two
    /// wavelengths: the packed rows of one vector per node; five: the table's rows), at points
    /// between nodes and within half a step of the view-zenith poles, more suns than one pass of
    /// its angle loop: each sun equal to its own [`PreciseMultipleScattering::add_from_slice`],
    /// equal to rounding by day, within the f32 interpolation's few 10⁻⁶ in twilight.
    #[test]
    fn twilight_lookups_need_only_the_slice_corners() {
        let (shared, bottom) = small_tables("earth", "440,680");
        let table = shared.precise();
        // Day cells end at the sun-zenith node below 80° (76.5° with these settings).
        let day_mu_s = table.day_mu_s();
        assert!(
            day_mu_s < 70f64.to_radians().cos() && day_mu_s > 80f64.to_radians().cos(),
            "{day_mu_s}"
        );
        let (mut full, mut lazy) = (JSlice::default(), JSlice::default());
        let mut n_twilight = 0;
        for h in [10.0, 3_000.0, 30_000.0] {
            for mu in [-0.999, -0.6, -0.05, 0.02, 0.5, 0.9995] {
                let r = bottom + h;
                table.slice(r, mu, &mut full);
                table.slice_corners(r, mu, &mut lazy);
                for i in 0..200 {
                    let m_s = -0.35 + 1.35 * i as f64 / 199.0;
                    let sin = ((1.0 - mu * mu) * (1.0 - m_s * m_s)).max(0.0).sqrt();
                    for cos_phi in [1.0, 0.3, -1.0] {
                        let nu = (mu * m_s + sin * cos_phi).clamp(-1.0, 1.0);
                        let (mut want, mut got) = ([0.0; 2], [0.0; 2]);
                        table.add_from_slice(&full, m_s, nu, &mut want);
                        if m_s <= day_mu_s {
                            table.add_from_slice(&lazy, m_s, nu, &mut got);
                            assert_eq!(got, want, "{h} {mu} {m_s}");
                            n_twilight += 1;
                        }
                    }
                }
                // Filled afterwards: the rows of `slice`, so every sun's value.
                table.fill_day(&mut lazy);
                assert_eq!(lazy.per_constituent, full.per_constituent);
                assert_eq!(lazy.lin, full.lin);
            }
        }
        assert!(n_twilight > 1000, "{n_twilight}");
    }

    /// The packed rows' twilight interpolation in 8 lanes (the AVX2 and generic copies of
    /// [`add_from_slice_kernel`]) and in 16 (its AVX-512 copy) are the same operations lane by
    /// lane in the same order: the same bits, at points between nodes and within half a step of
    /// the view-zenith poles (every azimuth node read), for every twilight cell and azimuth cell.
    #[test]
    fn packed_twilight_lookup_is_the_same_in_8_and_16_lanes() {
        let (shared, bottom) = small_tables("earth", "440,550,680");
        let table = shared.precise();
        let rows = table.ln_j_ms();
        let (n_mu_s, n_mu, n_phi) = (table.grid.s.n_mu_s, table.grid.s.n_mu, table.grid.s.n_phi);
        assert!(!rows.packed.is_empty() && rows.first_cell + 1 < n_mu_s);
        let mut slice = JSlice::default();
        let (mut n, mut poles) = (0, 0);
        for h in [10.0, 3_000.0, 30_000.0] {
            for mu in [-0.999, -0.6, -0.05, 0.02, 0.5, 0.9995] {
                table.slice_corners(bottom + h, mu, &mut slice);
                poles += slice.corners.iter().filter(|c| c.3).count();
                let point = PackedPoint::new(rows, &slice, n_mu, n_mu_s, n_phi);
                for is in rows.first_cell..n_mu_s - 1 {
                    for fs in [0.0, 0.37, 0.999] {
                        let (nodes, w) = catmull_rom(is, fs, n_mu_s);
                        let wq = w.map(|x| x as f32);
                        for ip in 0..n_phi - 1 {
                            for fp in [0.0, 0.61, -0.12] {
                                let narrow = point.interp(nodes, wq, fs as f32, ip, fp);
                                let wide = point.interp_wide(nodes, wq, fs as f32, ip, fp);
                                assert_eq!(
                                    narrow.map(f32::to_bits),
                                    wide.map(f32::to_bits),
                                    "{h} {mu} {is} {fs} {ip} {fp}"
                                );
                                n += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(n > 1000 && poles > 0, "{n} {poles}");
    }

    #[test]
    fn slice_lookups_of_many_suns_match_the_products_lookup() {
        for (wl, n_l) in [("440,680", 2), ("400,450,500,600,700", 5)] {
            let (shared, bottom) = small_tables("earth", wl);
            let table = shared.precise();
            let (mut day, mut dusk, mut n_dusk) = (0.0f64, 0.0f64, 0);
            let mut slice = JSlice::default();
            for h in [10.0, 3_000.0, 30_000.0] {
                for mu in [-0.999, -0.6, -0.05, 0.02, 0.5, 0.9995] {
                    let r = bottom + h;
                    table.slice(r, mu, &mut slice);
                    let (mut mu_s, mut nu) = (Vec::new(), Vec::new());
                    for i in 0..40 {
                        let m_s = -0.35 + 1.35 * i as f64 / 39.0;
                        let sin = ((1.0 - mu * mu) * (1.0 - m_s * m_s)).max(0.0).sqrt();
                        for cos_phi in [1.0, 0.97, 0.3, -0.5, -1.0] {
                            mu_s.push(m_s);
                            nu.push((mu * m_s + sin * cos_phi).clamp(-1.0, 1.0));
                        }
                    }
                    let mut many = vec![0.0; mu_s.len() * n_l];
                    table.add_from_slice_many(&slice, &mu_s, &nu, &mut many);
                    for (t, (&m_s, &n)) in mu_s.iter().zip(&nu).enumerate() {
                        let mut one = vec![0.0; n_l];
                        table.add_from_slice(&slice, m_s, n, &mut one);
                        assert_eq!(one[..], many[t * n_l..(t + 1) * n_l], "{wl} {h} {mu} {t}");
                        let mut want = vec![0.0; n_l];
                        let sample = RaySample {
                            t: 0.0,
                            weight: 1.0,
                            r,
                            mu,
                            mu_s: m_s,
                            nu: n,
                        };
                        table.add_scattering(&sample, &mut want);
                        for (g, w) in one.iter().zip(&want) {
                            let e = if *w > 0.0 { (g - w).abs() / w } else { g.abs() };
                            // Day cells end at the node below 80° (78.5° here).
                            if m_s > 78f64.to_radians().cos() {
                                day = day.max(e);
                            } else if *w > 0.0 {
                                dusk = dusk.max(e);
                                n_dusk += 1;
                            }
                        }
                    }
                }
            }
            // Measured: day 7.9e-16 and 1.1e-15, twilight 7.5e-5 and 4.5e-6 (f32: ln Â rounded
            // to f32 and its f32 exponential; for the two wavelengths of the packed rows the
            // cubic `twilight_bundle::exp_cubic_f32`, 7.9e-5).
            eprintln!("{wl}: day {day:.2e}, twilight {dusk:.2e} ({n_dusk} values)");
            assert!(day < 1e-12, "{wl}: day {day}");
            let bound = if n_l <= PACKED_LANES / 2 { 9e-5 } else { 1e-5 };
            assert!(
                n_dusk > 1000 && dusk < bound,
                "{wl}: twilight {dusk}, {n_dusk}"
            );
        }
    }
}
