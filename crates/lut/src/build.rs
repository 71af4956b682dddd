//! Computes the bundle's tables with skybake's precise method, at the texel centres of Bruneton
//! 2017's parameterisation ([`crate::param`]):
//!
//! - transmittance to the top of the atmosphere: the density integrals of the ray, integrated
//!   directly (f64), exponentiated per channel;
//! - scattering: along each texel's ray (to the top, or to the ground for the lower half of μ),
//!   the same quadrature and sources as the `sky` product's integrator (exact single scattering,
//!   the converged multiple-scattering source J_ms of the precise table, Bruneton & Neyret 2008,
//!   eq. 7 and §4), without the ground's reflection at the end of the ray (his texture leaves it to
//!   the client). Stored as he stores it (Bruneton 2017, `ComputeMultipleScatteringTexture` and
//!   the combined layout): RGB = single Rayleigh without its phase function + multiple scattering
//!   divided by the Rayleigh phase function; single Mie divided by his Mie phase function (exact
//!   at the ν nodes when the atmosphere's aerosol phase function is another one);
//! - irradiance: the sky's irradiance on a horizontal surface at (r, μs), the `sun` product's
//!   hemisphere quadrature at that altitude and sun.
//!
//! Everything is multiplied by the extraterrestrial solar irradiance and by the bundle's unit
//! scale ([`UNIT_SCALE`]).

use std::time::Instant;

use rayon::prelude::*;
use skybake_physics::atmosphere::geometry::horizon_mu;
use skybake_physics::atmosphere::integrate::{cell_weight, ray_points, RayPoint};
use skybake_physics::atmosphere::irradiance::{SUN_PRODUCT_N_MU, SUN_PRODUCT_N_PHI};
use skybake_physics::atmosphere::kernels::exp_fast_f32;
use skybake_physics::atmosphere::medium::{Medium, CONSTITUENTS, MIE, RAYLEIGH};
use skybake_physics::atmosphere::multiple_precise::{
    source_sun_zenith_limit_rad, JSlice, PreciseMultipleScattering,
};
use skybake_physics::atmosphere::quadrature::gauss_legendre;
use skybake_physics::atmosphere::shared::SharedTables;
use skybake_physics::atmosphere::transmittance::{
    density_integrals, AtRadius, DensityIntegralTable, OpticalDepthScratch,
};
use skybake_physics::phase::Phase;

use crate::param::{self, AtmosphereParameters, *};
use crate::{ms_columns, ms_directions, ms_rows};

/// Texture values are radiometric quantities in milliwatts (mW m⁻² sr⁻¹ nm⁻¹, mW m⁻² nm⁻¹):
/// texture value = value in W × this. Keeps the half-float scattering texture in its normal
/// range from noon (≈ 2·10³) to the end of nautical twilight (≈ 10⁻⁴).
pub const UNIT_SCALE: f64 = 1.0e3;

/// Revision of the texel values both layouts compute from a given atmosphere: part of the
/// bundles' cache keys, bumped when a change of the computation changes texel values while the
/// layouts ([`crate::manifest::BUNDLE_VERSION`], `skyview::SKYVIEW_VERSION`) stay. 2: the
/// multiple-scattering lookup's twilight cells in f32
/// (`PreciseMultipleScattering::add_from_slice`); 3: the bundles' twilight lookup with a cubic
/// exponential (relative error ≤ 7.9·10⁻⁵) and the single scattering's sun transmittance in f32.
pub const TEXEL_REVISION: &str = "3";

/// Quadrature intervals of each transmittance texel's density integrals.
const TRANSMITTANCE_STEPS: usize = 1000;

/// How texture samples are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sample {
    /// 16-bit float (the scattering texture of the RGB bundle: RGBA16F filters linearly on
    /// every WebGL2 device).
    Half,
    /// 32-bit float.
    Float,
}

/// A texture: `[row][column][channel]`, row 0 at texture coordinate v = 0.5/height; 3-D
/// textures are their depth slices stacked, slice k at rows k·height … (k+1)·height − 1.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub width: usize,
    pub height: usize,
    pub depth: usize,
    pub channels: usize,
    pub sample: Sample,
    pub data: Vec<f32>,
}

impl Texture {
    pub(crate) fn new(
        width: usize,
        height: usize,
        depth: usize,
        channels: usize,
        sample: Sample,
    ) -> Self {
        Self {
            width,
            height,
            depth,
            channels,
            sample,
            data: vec![0.0; width * height * depth * channels],
        }
    }

    /// Rounds every value to what the stored sample type holds.
    pub(crate) fn round_to_sample(&mut self) {
        if self.sample == Sample::Half {
            for v in &mut self.data {
                *v = half::f16::from_f32(*v).to_f32();
            }
        }
    }

    /// Texel (x, y, z), all channels.
    pub fn texel(&self, x: usize, y: usize, z: usize) -> &[f32] {
        let i = ((z * self.height + y) * self.width + x) * self.channels;
        &self.data[i..i + self.channels]
    }

    /// One channel as a plane of width × (height · depth) values, rows in order.
    pub fn plane(&self, channel: usize) -> Vec<f32> {
        self.data
            .iter()
            .skip(channel)
            .step_by(self.channels)
            .copied()
            .collect()
    }
}

/// Which channels the bundle holds.
#[derive(Debug, Clone, PartialEq)]
pub enum Channels {
    /// Three channels at Bruneton's wavelengths (R 680, G 550, B 440 nm), the combined
    /// scattering layout (RGBA; single Mie of R in A), half-float scattering.
    Rgb,
    /// One channel per wavelength of the medium, ascending; scattering and single Mie as two
    /// separate tables (his non-combined layout), float.
    Spectral,
}

/// Bruneton's channel wavelengths, nm (R, G, B).
pub const RGB_WAVELENGTHS_NM: [f64; 3] = [680.0, 550.0, 440.0];

/// The computed bundle.
#[derive(Debug, Clone)]
pub struct Bundle {
    pub channels: Channels,
    /// Wavelength of each channel, nm.
    pub wavelengths_nm: Vec<f64>,
    pub params: AtmosphereParameters,
    pub transmittance: Texture,
    /// RGB bundle: RGBA combined; spectral: one channel per wavelength.
    pub scattering: Texture,
    /// Spectral bundle only: single Mie scattering (the RGB bundle has its red in `scattering`'s A).
    pub single_mie: Option<Texture>,
    pub irradiance: Texture,
    /// Wall-clock times, ms: the precise table (built, loaded or already in memory), the
    /// transmittance, scattering and irradiance textures.
    pub timing_ms: [f64; 4],
}

/// Computes the bundle from shared tables whose precise table is built (or is built here).
/// `steps` are the samples per ray segment of the products (`Quality::steps`). Stops with
/// [`crate::Error::Cancelled`] inside the precise table's build, or at the next row of a
/// texture, once `cancelled` returns true.
pub fn build(
    shared: &SharedTables,
    channels: Channels,
    steps: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> crate::Result<Bundle> {
    let m = &shared.medium;
    let (idx, params) = channel_setup(m, &channels)?;
    let n_c = idx.len();
    let g = params.mie_phase_function_g;
    let e0: Vec<f64> = params.solar_irradiance.clone();
    let tp = Instant::now();
    shared
        .precise_unless(cancelled)
        .ok_or(crate::Error::Cancelled)?;
    let t_precise = tp.elapsed().as_secs_f64() * 1e3;

    // Transmittance.
    let t0 = Instant::now();
    let transmittance = transmittance_texture(m, &params, &idx, cancelled);
    if cancelled() {
        return Err(crate::Error::Cancelled);
    }
    let t_transmittance = t0.elapsed().as_secs_f64() * 1e3;

    // Scattering: one task per ray family (r, μ), whose points all its (ν, μs) texels share.
    let t1 = Instant::now();
    let (sc_channels, sample) = match channels {
        Channels::Rgb => (4, Sample::Half),
        Channels::Spectral => (n_c, Sample::Float),
    };
    let mut scattering = Texture::new(
        SCATTERING_WIDTH,
        SCATTERING_MU,
        SCATTERING_R,
        sc_channels,
        sample,
    );
    let mut single_mie = Texture::new(
        SCATTERING_WIDTH,
        SCATTERING_MU,
        SCATTERING_R,
        n_c,
        Sample::Float,
    );
    let row_len_sc = SCATTERING_WIDTH * sc_channels;
    let row_len_mie = SCATTERING_WIDTH * n_c;
    scattering
        .data
        .par_chunks_mut(row_len_sc)
        .zip(single_mie.data.par_chunks_mut(row_len_mie))
        .enumerate()
        .for_each_init(
            || FamilyScratch::new(shared, m.len()),
            |scratch, (row, (sc_row, mie_row))| {
                if cancelled() {
                    return;
                }
                let (i_r, i_mu) = (row / SCATTERING_MU, row % SCATTERING_MU);
                let (r, mu, _, _, ground) = params.scattering_texel(0, 0, i_mu, i_r);
                // Grazing rays are nudged to the side of the horizon their half of μ says.
                let mu_h = horizon_mu(r, m.bottom_radius_m);
                let mu = if ground {
                    (mu.min(mu_h) - 1e-9).max(-1.0)
                } else {
                    mu.max(mu_h + 1e-9).min(1.0)
                };
                scratch.prepare(r, mu, steps);
                for i_nu in 0..SCATTERING_NU {
                    for i_mu_s in 0..SCATTERING_MU_S {
                        let (_, _, mu_s, nu, _) = params.scattering_texel(i_nu, i_mu_s, i_mu, i_r);
                        scratch.push_sun(mu_s, nu);
                    }
                }
                scratch.integrate();
                for i_nu in 0..SCATTERING_NU {
                    for i_mu_s in 0..SCATTERING_MU_S {
                        let (_, _, _, nu, _) = params.scattering_texel(i_nu, i_mu_s, i_mu, i_r);
                        let x = i_nu * SCATTERING_MU_S + i_mu_s;
                        let s = scratch.texel(x);
                        let p_r = param::rayleigh_phase(nu);
                        let mie_ratio = m.mie_phase.eval(nu) / param::mie_phase(g, nu);
                        for (c, &l) in idx.iter().enumerate() {
                            let rgb = (s.rayleigh[l] + s.multiple[l] / p_r) * e0[c];
                            sc_row[x * sc_channels + c] = rgb as f32;
                            mie_row[x * n_c + c] = (s.mie[l] * mie_ratio * e0[c]) as f32;
                        }
                        if channels == Channels::Rgb {
                            sc_row[x * sc_channels + 3] = mie_row[x * n_c];
                        }
                    }
                }
            },
        );
    if cancelled() {
        return Err(crate::Error::Cancelled);
    }
    scattering.round_to_sample();
    let t_scattering = t1.elapsed().as_secs_f64() * 1e3;

    // Irradiance: the sky's, on a horizontal surface (the direct sun is the client's).
    let t2 = Instant::now();
    let irradiance = irradiance_texture(shared, &params, &idx, &e0, steps, cancelled);
    if cancelled() {
        return Err(crate::Error::Cancelled);
    }
    let t_irradiance = t2.elapsed().as_secs_f64() * 1e3;

    Ok(Bundle {
        wavelengths_nm: idx.iter().map(|&i| m.wavelengths_nm[i]).collect(),
        single_mie: (channels == Channels::Spectral).then_some(single_mie),
        channels,
        params,
        transmittance,
        scattering,
        irradiance,
        timing_ms: [t_precise, t_transmittance, t_scattering, t_irradiance],
    })
}

/// Bruneton's transmittance texture: each texel's density integrals to the top of the
/// atmosphere, integrated directly (f64), exponentiated per channel.
pub(crate) fn transmittance_texture(
    m: &Medium,
    params: &AtmosphereParameters,
    idx: &[usize],
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Texture {
    let n_c = idx.len();
    let mut transmittance = Texture::new(
        TRANSMITTANCE_WIDTH,
        TRANSMITTANCE_HEIGHT,
        1,
        n_c,
        Sample::Float,
    );
    transmittance
        .data
        .par_chunks_mut(TRANSMITTANCE_WIDTH * n_c)
        .enumerate()
        .for_each(|(j, row)| {
            if cancelled() {
                return;
            }
            for i in 0..TRANSMITTANCE_WIDTH {
                let (r, mu) = params.transmittance_r_mu(
                    (i as f64 + 0.5) / TRANSMITTANCE_WIDTH as f64,
                    (j as f64 + 0.5) / TRANSMITTANCE_HEIGHT as f64,
                );
                let d =
                    density_integrals(m, r, mu, params.distance_to_top(r, mu), TRANSMITTANCE_STEPS);
                for (c, &l) in idx.iter().enumerate() {
                    row[i * n_c + c] = (-m.optical_depth(l, &d)).exp() as f32;
                }
            }
        });
    transmittance
}

/// Which of the medium's wavelengths each channel is, and his `AtmosphereParameters` of those
/// channels (radiometric values in the bundle's unit).
pub(crate) fn channel_setup(
    m: &Medium,
    channels: &Channels,
) -> crate::Result<(Vec<usize>, AtmosphereParameters)> {
    let idx: Vec<usize> = match *channels {
        Channels::Rgb => RGB_WAVELENGTHS_NM
            .iter()
            .map(|w| {
                m.wavelengths_nm
                    .iter()
                    .position(|x| (x - w).abs() < 1e-9)
                    .ok_or_else(|| {
                        crate::Error::invalid(
                            "wavelengths",
                            format!("the RGB bundle needs {w} nm among the medium's wavelengths"),
                        )
                    })
            })
            .collect::<crate::Result<_>>()?,
        Channels::Spectral => (0..m.len()).collect(),
    };
    let g = match m.mie_phase {
        Phase::CornetteShanks { g } | Phase::HenyeyGreenstein { g } | Phase::Mixture { g, .. } => g,
        Phase::Isotropic | Phase::Rayleigh => 0.0,
    };
    let params = AtmosphereParameters {
        solar_irradiance: idx
            .iter()
            .map(|&i| m.solar_irradiance[i] * UNIT_SCALE)
            .collect(),
        sun_angular_radius: m.sun_angular_radius_rad,
        bottom_radius: m.bottom_radius_m,
        top_radius: m.top_radius_m,
        rayleigh_scattering: idx
            .iter()
            .map(|&i| m.rayleigh_scattering_per_m[i])
            .collect(),
        mie_scattering: idx.iter().map(|&i| m.mie_scattering_per_m[i]).collect(),
        mie_phase_function_g: g,
        mu_s_min: source_sun_zenith_limit_rad(m.bottom_radius_m, m.top_radius_m).cos(),
        ground_albedo: idx.iter().map(|&i| m.ground_albedo[i]).collect(),
    };
    Ok((idx, params))
}

/// The irradiance texture: at each row's radius, the `sun` product's hemisphere quadrature
/// ([`hemisphere_irradiance`]: Gauss–Legendre in cos θ × midpoints in azimuth relative to the
/// sun) of the sky radiance, each quadrature direction's ray integrated once for the row's 64
/// suns ([`FamilyScratch`]), with the same sources and samples as the `sky` product's rays.
fn irradiance_texture(
    shared: &SharedTables,
    params: &AtmosphereParameters,
    idx: &[usize],
    e0: &[f64],
    steps: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Texture {
    let radii: Vec<f64> = (0..IRRADIANCE_HEIGHT)
        .map(|j| {
            let v = (j as f64 + 0.5) / IRRADIANCE_HEIGHT as f64;
            params.irradiance_r_mu_s(0.5 / IRRADIANCE_WIDTH as f64, v).0
        })
        .collect();
    let mu_s: Vec<f64> = (0..IRRADIANCE_WIDTH)
        .map(|i| {
            let u = (i as f64 + 0.5) / IRRADIANCE_WIDTH as f64;
            params
                .irradiance_r_mu_s(u, 0.5 / IRRADIANCE_HEIGHT as f64)
                .1
        })
        .collect();
    let sums = irradiance_grid(
        shared,
        IrradianceGrid {
            radii: &radii,
            width: IRRADIANCE_WIDTH,
            mu_s: &|_, i| mu_s[i],
            ms_columns: false,
        },
        idx,
        e0,
        steps,
        cancelled,
    );
    let mut irradiance = Texture::new(
        IRRADIANCE_WIDTH,
        IRRADIANCE_HEIGHT,
        1,
        idx.len(),
        Sample::Float,
    );
    for (o, s) in irradiance.data.iter_mut().zip(sums) {
        *o = s as f32;
    }
    irradiance
}

/// Where [`irradiance_grid`] computes the irradiance: rows at `radii`, `width` columns, the
/// sun zenith cosine of (row, column) `mu_s(row, column)`.
pub(crate) struct IrradianceGrid<'a> {
    pub radii: &'a [f64],
    pub width: usize,
    pub mu_s: &'a (dyn Fn(usize, usize) -> f64 + Sync),
    /// Whether each direction's multiple scattering is computed on every other quadrature
    /// azimuth and every other sun of the row, and interpolated to the others where smooth
    /// ([`FamilyScratch::integrate_grid`]).
    pub ms_columns: bool,
}

/// The sky's irradiance on a horizontal surface at each radius of `radii` (rows) and the
/// `width` sun zenith cosines `mu_s_of(row, column)`, `[row][column][channel]`: the `sun` product's hemisphere
/// quadrature (Gauss–Legendre in cos θ × midpoints in azimuth relative to the sun) of the sky
/// radiance, each quadrature direction's ray integrated once for all the row's suns.
pub(crate) fn irradiance_grid(
    shared: &SharedTables,
    grid: IrradianceGrid,
    idx: &[usize],
    e0: &[f64],
    steps: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Vec<f64> {
    let m = &shared.medium;
    let n_c = idx.len();
    let n_l = m.len();
    let (radii, width, mu_s_of) = (grid.radii, grid.width, grid.mu_s);
    let (x, w) = gauss_legendre(SUN_PRODUCT_N_MU);
    let n_phi = SUN_PRODUCT_N_PHI;
    // With `ms_columns`, the multiple scattering of every other direction first, then the
    // directions between from them where smooth ([`ms_directions`]): `known` holds the first
    // pass's per metre of ray, by task.
    let elevations: Vec<f64> = x.iter().map(|&x| (0.5 * (x + 1.0)).asin()).collect();
    let dir_stencils = ms_directions::stencils(&elevations);
    // One task per (row, cos θ node): that row's contributions of that direction.
    let dir_task = |scratch: &mut FamilyScratch<'_>,
                    task: usize,
                    known: &[Option<Vec<f64>>]|
     -> ((usize, Vec<f64>), Option<Vec<f64>>) {
        let (j, a) = (task / SUN_PRODUCT_N_MU, task % SUN_PRODUCT_N_MU);
        let r = radii[j];
        let mu = 0.5 * (x[a] + 1.0);
        let sin_t = (1.0 - mu * mu).max(0.0).sqrt();
        let weight = 0.5 * w[a] * mu * 2.0 * std::f64::consts::PI / n_phi as f64;
        let mut row = vec![0.0; width * n_c];
        if cancelled() {
            return ((j, row), None);
        }
        scratch.prepare(r, mu, steps);
        let mut nus = Vec::with_capacity(width * n_phi);
        for i in 0..width {
            let mu_s = mu_s_of(j, i);
            let sin_s = (1.0 - mu_s * mu_s).max(0.0).sqrt();
            for b in 0..n_phi {
                let phi = std::f64::consts::PI * (b as f64 + 0.5) / n_phi as f64;
                let nu = (mu * mu_s + sin_t * sin_s * phi.cos()).clamp(-1.0, 1.0);
                scratch.push_sun(mu_s, nu);
                nus.push(nu);
            }
        }
        let mut record = None;
        if grid.ms_columns {
            let phis: Vec<f64> = (0..n_phi)
                .map(|b| std::f64::consts::PI * (b as f64 + 0.5) / n_phi as f64)
                .collect();
            // Over the row's suns as well, by their elevation unwrapped past the
            // zenith (the nodes reach 104° above the horizon, where μs falls again).
            let mut suns = Vec::with_capacity(width);
            for i in 0..width {
                let e = mu_s_of(j, i).asin();
                let prev = if i == 0 { e } else { mu_s_of(j, i - 1).asin() };
                suns.push(suns.last().map_or(e, |&c: &f64| c + (e - prev).abs()));
            }
            // The ray's length to the top of the atmosphere (upward: μ > 0).
            let top = m.top_radius_m;
            let d = ((r * r * (mu * mu - 1.0) + top * top).max(0.0).sqrt() - r * mu).max(1.0);
            match dir_stencils[a] {
                Some(st) if !known.is_empty() => {
                    let row_of = |c: usize| known[j * SUN_PRODUCT_N_MU + c].as_deref();
                    scratch.integrate_grid_guessed(&phis, &suns, ms_rows::TOLERANCE, |t, l| {
                        let (y, rough) = ms_rows::guess(&st, |c| {
                            row_of(c).map_or(f64::NAN, |v| v[t * n_l + l])
                        })?;
                        Some((y * d, rough))
                    });
                }
                _ => scratch.integrate_grid(&phis, &suns),
            }
            if dir_stencils[a].is_none() {
                let n_t = width * n_phi;
                let mut per_m = vec![f64::NAN; n_t * n_l];
                for t in 0..n_t {
                    let ms = scratch.texel(t).multiple;
                    for l in 0..n_l {
                        per_m[t * n_l + l] = ms[l] / d;
                    }
                }
                record = Some(per_m);
            }
        } else {
            scratch.integrate();
        }
        for i in 0..width {
            for b in 0..n_phi {
                let nu = nus[i * n_phi + b];
                let (p_r, p_m) = (Phase::Rayleigh.eval(nu), m.mie_phase.eval(nu));
                let s = scratch.texel(i * n_phi + b);
                for (c, &l) in idx.iter().enumerate() {
                    let radiance = s.rayleigh[l] * p_r + s.mie[l] * p_m + s.multiple[l];
                    row[i * n_c + c] += weight * radiance * e0[c];
                }
            }
        }
        ((j, row), record)
    };
    let pass = |tasks: Vec<usize>, known: &[Option<Vec<f64>>]| -> Vec<_> {
        tasks
            .into_par_iter()
            .map_init(
                || FamilyScratch::new(shared, m.len()),
                |scratch, task| (task, dir_task(scratch, task, known)),
            )
            .collect()
    };
    let all = 0..radii.len() * SUN_PRODUCT_N_MU;
    let mut parts = Vec::with_capacity(all.len());
    if grid.ms_columns {
        let (first, others): (Vec<usize>, Vec<usize>) =
            all.partition(|&task| dir_stencils[task % SUN_PRODUCT_N_MU].is_none());
        let mut known: Vec<Option<Vec<f64>>> = vec![None; radii.len() * SUN_PRODUCT_N_MU];
        for (task, (part, record)) in pass(first, &[]) {
            known[task] = record;
            parts.push((task, part));
        }
        parts.extend(
            pass(others, &known)
                .into_iter()
                .map(|(task, (part, _))| (task, part)),
        );
        // Summed in the directions' order, as one pass gives them.
        parts.sort_by_key(|&(task, _)| task);
    } else {
        parts.extend(
            pass(all.collect(), &[])
                .into_iter()
                .map(|(task, (part, _))| (task, part)),
        );
    }
    let mut sums = vec![0.0f64; radii.len() * width * n_c];
    for (_, (j, row)) in parts {
        let k = j * width * n_c;
        for (s, v) in sums[k..k + row.len()].iter_mut().zip(row) {
            *s += v;
        }
    }
    sums
}

/// Per-wavelength integrals of one texel's ray, per unit solar irradiance: single Rayleigh and
/// single Mie without phase functions (m⁻¹·m), multiple scattering with its phases (sr⁻¹).
pub(crate) struct TexelSums<'a> {
    pub(crate) rayleigh: Column<'a>,
    pub(crate) mie: Column<'a>,
    pub(crate) multiple: &'a [f64],
}

/// One sun's values, indexed by wavelength, in a `[λ][sun]` array.
pub(crate) struct Column<'a> {
    data: &'a [f64],
    n_t: usize,
    t: usize,
}

impl std::ops::Index<usize> for Column<'_> {
    type Output = f64;
    fn index(&self, l: usize) -> &f64 {
        &self.data[l * self.n_t + self.t]
    }
}

/// What every sun on one ray shares (a ray family of the texture: fixed r and μ): the products'
/// quadrature points, their densities, each point's cell weight as the products' integrator
/// weights it ([`cell_weight`]: length × mean transmittance from the ray's origin, `[point][λ]`), the density table at each point's radius
/// and the multiple-scattering table at each point's (r, μ) ([`JSlice`]). A texel then costs
/// one sun-zenith/azimuth interpolation per point. The suns of a ray are integrated together
/// ([`Self::integrate`]), point by point: each point's tables are read once for all of them,
/// and each texel's sums are formed in the same order (the same values) as one at a time.
pub(crate) struct FamilyScratch<'a> {
    medium: &'a Medium,
    density: &'a DensityIntegralTable,
    precise: &'a PreciseMultipleScattering,
    r: f64,
    points: Vec<RayPoint>,
    rho: Vec<[f64; CONSTITUENTS]>,
    weighted_t: Vec<f64>,
    at: Vec<AtRadius<'a>>,
    slices: Vec<JSlice>,
    /// [`PreciseMultipleScattering::day_mu_s`] of the table.
    day_mu_s: f64,
    n_l: usize,
    /// The suns ([`Self::push_sun`]): zenith cosine and view–sun cosine at the ray's origin.
    mu_s: Vec<f64>,
    nu: Vec<f64>,
    /// `[sun]`: the sun's zenith cosine at the current point.
    mu_s_p: Vec<f64>,
    /// `[sun]`: the visible fraction of the sun's disk at the current point and the density
    /// integrals to the sun from there (`[constituent][sun]`).
    vis: Vec<f64>,
    d_sun: [Vec<f64>; CONSTITUENTS],
    /// `[λ][sun]`: the sun's transmittance to the current point ([`texel_sums`]), first the
    /// optical depth's negative rounded to f32, then its exponential.
    sun_t: Vec<f32>,
    /// `[λ][constituent]`: the medium's extinction, and the buffers of the sun's optical depths
    /// ([`AtRadius::neg_optical_depths_many`]).
    ext: Vec<[f64; CONSTITUENTS]>,
    od: OpticalDepthScratch,
    /// `[sun][λ]`: J_ms at the current point; the multiple-scattering sums of [`TexelSums`].
    j: Vec<f64>,
    multiple: Vec<f64>,
    /// `[λ][sun]`: the single-scattering sums of [`TexelSums`].
    rayleigh: Vec<f64>,
    mie: Vec<f64>,
    /// The suns whose multiple scattering [`texel_sums`] computes (all when empty), and their
    /// zenith cosines at the current point and view–sun cosines, gathered.
    ms_suns: Vec<usize>,
    /// [`multiple_sums`]: the suns' zenith cosines at the ray's origin, gathered.
    ms_mu_s: Vec<f64>,
    ms_mu_s_p: Vec<f64>,
    ms_nu: Vec<f64>,
    ms_j: Vec<f64>,
    /// [`texel_sums`] forms no multiple scattering at all ([`Self::integrate_grid_guessed`]).
    ms_skip: bool,
}

impl<'a> FamilyScratch<'a> {
    pub(crate) fn new(shared: &'a SharedTables, n_l: usize) -> Self {
        Self {
            medium: &shared.medium,
            density: shared.density(),
            precise: shared.precise(),
            r: 0.0,
            points: Vec::new(),
            rho: Vec::new(),
            weighted_t: Vec::new(),
            at: Vec::new(),
            slices: Vec::new(),
            day_mu_s: shared.precise().day_mu_s(),
            n_l,
            mu_s: Vec::new(),
            nu: Vec::new(),
            mu_s_p: Vec::new(),
            vis: Vec::new(),
            d_sun: std::array::from_fn(|_| Vec::new()),
            sun_t: Vec::new(),
            ext: (0..n_l)
                .map(|l| std::array::from_fn(|k| shared.medium.extinction_per_m[k][l]))
                .collect(),
            od: OpticalDepthScratch::default(),
            j: Vec::new(),
            rayleigh: Vec::new(),
            mie: Vec::new(),
            multiple: Vec::new(),
            ms_suns: Vec::new(),
            ms_mu_s: Vec::new(),
            ms_mu_s_p: Vec::new(),
            ms_nu: Vec::new(),
            ms_j: Vec::new(),
            ms_skip: false,
        }
    }

    /// The ray from radius `r` with zenith cosine `mu`, `steps` samples per segment; no suns yet.
    pub(crate) fn prepare(&mut self, r: f64, mu: f64, steps: usize) {
        let m = self.medium;
        self.r = r;
        self.mu_s.clear();
        self.nu.clear();
        ray_points(m, r, mu, steps, &mut self.points);
        self.rho.clear();
        self.weighted_t.clear();
        self.at.clear();
        self.slices.resize_with(self.points.len(), JSlice::default);
        let mut d_view = [0.0f64; CONSTITUENTS];
        for (p, slice) in self.points.iter().zip(&mut self.slices) {
            let rho = m.densities(p.r);
            for l in 0..m.len() {
                self.weighted_t
                    .push(cell_weight(m, l, &d_view, &rho, p.weight));
            }
            for k in 0..CONSTITUENTS {
                d_view[k] += rho[k] * p.weight;
            }
            self.rho.push(rho);
            self.at
                .push(self.density.at_radius(p.r, m.sun_angular_radius_rad));
            // The day cells' rows are filled in [`texel_sums`] where a sun needs them.
            self.precise.slice_corners(p.r, p.mu, slice);
        }
    }

    /// Adds a sun at (μs, ν) at the ray's origin: texel [`Self::texel`]`(n)` of the next
    /// [`Self::integrate`], n counting from 0 since [`Self::prepare`].
    pub(crate) fn push_sun(&mut self, mu_s: f64, nu: f64) {
        self.mu_s.push(mu_s);
        self.nu.push(nu);
    }

    /// Integrates the prepared ray for every sun pushed.
    pub(crate) fn integrate(&mut self) {
        self.ms_suns.clear();
        self.integrate_sums();
    }

    /// [`Self::integrate`] for suns pushed as runs of `phis.len()` azimuth columns (sun `t` at
    /// azimuth `phis[t % phis.len()]` from the sun, increasing): the multiple scattering on the
    /// columns [`ms_columns`] computes, interpolated to the others where its roughness times
    /// its share of the value (single Rayleigh without its phase function plus multiple
    /// scattering over the Rayleigh phase function, as the `skyview` texels store it; of a
    /// radiance that adds single Mie, at least its share) is within [`ms_columns::TOLERANCE`],
    /// computed at the rest. The computed suns' sums are [`Self::integrate`]'s, bit for bit.
    pub(crate) fn integrate_columns(&mut self, phis: &[f64]) {
        let n_az = phis.len();
        let n_t = self.mu_s.len();
        if n_az < 2 * ms_columns::STEP + 2 || n_t % n_az != 0 {
            return self.integrate();
        }
        self.ms_suns.clear();
        self.ms_suns
            .extend((0..n_t).filter(|&t| ms_columns::computed(t % n_az, n_az)));
        self.integrate_sums();
        self.interpolate_columns(phis, &[]);
    }

    /// [`Self::integrate_columns`] for suns pushed as `suns.len()` runs of `phis.len()` azimuth
    /// columns, run `n` at the sun node coordinate `suns[n]` (increasing; the sun's elevation,
    /// in any unit): the multiple scattering computed on every other run as well
    /// ([`ms_columns::computed`] over the runs), on the computed columns interpolated first over
    /// the sun coordinate to the other runs, as over φ, where smooth (the same test), then over
    /// φ to the other columns. With fewer than 6 runs (or coordinates not increasing),
    /// [`Self::integrate_columns`].
    pub(crate) fn integrate_grid(&mut self, phis: &[f64], suns: &[f64]) {
        let (n_az, n_s) = (phis.len(), suns.len());
        let n_t = self.mu_s.len();
        let increasing = suns.windows(2).all(|w| w[0] < w[1]);
        if n_s < 2 * ms_columns::STEP + 2 || n_t != n_az * n_s || !increasing {
            return self.integrate_columns(phis);
        }
        if n_az < 2 * ms_columns::STEP + 2 {
            return self.integrate();
        }
        self.ms_suns.clear();
        self.ms_suns.extend((0..n_t).filter(|&t| {
            ms_columns::computed(t % n_az, n_az) && ms_columns::computed(t / n_az, n_s)
        }));
        self.integrate_sums();
        self.interpolate_grid(phis, suns, &[]);
    }

    /// [`Self::integrate_grid`] where the multiple scattering may come from elsewhere:
    /// `guess(t, l)`, wavelength `l` of sun `t`'s sums and their roughness (as
    /// [`ms_columns::interpolate`]'s), is taken where its roughness times the multiple
    /// scattering's share of the value is within `tolerance` (as [`Self::interpolate_ms`]
    /// tests); the other suns are [`Self::integrate_grid`]'s: computed on every other sun node
    /// and column, interpolated from them (from guessed values too) or computed elsewhere.
    /// Where [`Self::integrate_grid`] would not interpolate over the sun, it is called instead
    /// (`guess` unused).
    pub(crate) fn integrate_grid_guessed(
        &mut self,
        phis: &[f64],
        suns: &[f64],
        tolerance: f64,
        guess: impl Fn(usize, usize) -> Option<(f64, f64)>,
    ) {
        let (n_az, n_s) = (phis.len(), suns.len());
        let n_t = self.mu_s.len();
        let increasing = suns.windows(2).all(|w| w[0] < w[1]);
        if n_s < 2 * ms_columns::STEP + 2
            || n_t != n_az * n_s
            || !increasing
            || n_az < 2 * ms_columns::STEP + 2
        {
            return self.integrate_grid(phis, suns);
        }
        let n_l = self.n_l;
        self.ms_suns.clear();
        self.ms_skip = true;
        self.integrate_sums();
        self.ms_skip = false;
        let mut known = vec![false; n_t];
        let mut values = Vec::with_capacity(n_l);
        for t in 0..n_t {
            let p_r = param::rayleigh_phase(self.nu[t]);
            values.clear();
            for l in 0..n_l {
                let Some((v, rough)) = guess(t, l) else {
                    break;
                };
                let single = self.rayleigh[l * n_t + t];
                let share = (v / p_r) / (single + v / p_r);
                // A NaN (a share of 0 / 0) is not within it either.
                let off = rough * share;
                if off > tolerance || off.is_nan() {
                    break;
                }
                values.push(v);
            }
            if values.len() == n_l {
                self.multiple[t * n_l..(t + 1) * n_l].copy_from_slice(&values);
                known[t] = true;
            }
        }
        self.ms_suns.clear();
        self.ms_suns.extend((0..n_t).filter(|&t| {
            !known[t] && ms_columns::computed(t % n_az, n_az) && ms_columns::computed(t / n_az, n_s)
        }));
        if !self.ms_suns.is_empty() {
            multiple_sums(self);
            self.ms_suns.clear();
        }
        self.interpolate_grid(phis, suns, &known);
    }

    /// The rest of [`Self::integrate_grid`] once the multiple scattering of every other sun
    /// node and column is in: over the sun coordinate, then over φ, but for the suns `known`
    /// (none where empty).
    fn interpolate_grid(&mut self, phis: &[f64], suns: &[f64], known: &[bool]) {
        let (n_az, n_t) = (phis.len(), self.mu_s.len());
        let stencils = ms_columns::stencils(suns);
        let targets: Vec<(usize, ms_columns::Stencil, usize, usize)> = (0..n_t)
            .filter(|&t| ms_columns::computed(t % n_az, n_az) && !known.get(t).is_some_and(|&k| k))
            .filter_map(|t| stencils[t / n_az].map(|s| (t, s, t % n_az, n_az)))
            .collect();
        self.interpolate_ms(&targets, ms_columns::SUN_TOLERANCE, true);
        self.interpolate_columns(phis, known);
    }

    /// The multiple scattering of the columns [`ms_columns::computed`] leaves out, from the
    /// computed ones (whose sums are complete), over φ, but for the suns `known` (none where
    /// empty).
    fn interpolate_columns(&mut self, phis: &[f64], known: &[bool]) {
        let n_az = phis.len();
        let n_t = self.mu_s.len();
        let stencils = ms_columns::stencils(phis);
        let targets: Vec<(usize, ms_columns::Stencil, usize, usize)> = (0..n_t)
            .filter(|&t| !known.get(t).is_some_and(|&k| k))
            .filter_map(|t| stencils[t % n_az].map(|s| (t, s, t - t % n_az, 1)))
            .collect();
        self.interpolate_ms(&targets, ms_columns::TOLERANCE, false);
    }

    /// The multiple-scattering sums of suns `t` from those of the suns `base + c · stride` at the
    /// stencil's nodes `c`, where their roughness ([`ms_columns::interpolate`]: its
    /// curvature part alone if `curvature_only`) times the multiple scattering's share of the
    /// value (single Rayleigh without its phase function plus multiple scattering over the
    /// Rayleigh phase function, as the `skyview` texels store it; of a radiance that adds single
    /// Mie, at least its share) is within `tolerance`; computed where it is not.
    fn interpolate_ms(
        &mut self,
        targets: &[(usize, ms_columns::Stencil, usize, usize)],
        tolerance: f64,
        curvature_only: bool,
    ) {
        let n_l = self.n_l;
        let n_t = self.mu_s.len();
        let mut refine = Vec::new();
        let mut values = Vec::with_capacity(n_l);
        for &(t, s, base, stride) in targets {
            let p_r = param::rayleigh_phase(self.nu[t]);
            let mut ok = true;
            values.clear();
            for l in 0..n_l {
                let ms = &self.multiple;
                let Some((v, step, curv)) =
                    ms_columns::interpolate(&s, |c| ms[(base + c * stride) * n_l + l])
                else {
                    ok = false;
                    break;
                };
                let rough = if curvature_only { curv } else { step.max(curv) };
                let single = self.rayleigh[l * n_t + t];
                let share = (v / p_r) / (single + v / p_r);
                if rough * share > tolerance {
                    ok = false;
                    break;
                }
                values.push(v);
            }
            if ok {
                self.multiple[t * n_l..(t + 1) * n_l].copy_from_slice(&values);
            } else {
                refine.push(t);
            }
        }
        #[cfg(feature = "lookup-counter")]
        REFINED.fetch_add(refine.len() as u64, std::sync::atomic::Ordering::Relaxed);
        #[cfg(feature = "lookup-counter")]
        for &t in &refine {
            let e = self.mu_s[t].asin().to_degrees();
            let b = [-12.0, -6.0, 0.0, 5.0, 20.0]
                .iter()
                .filter(|&&x| e >= x)
                .count();
            let b = b + if curvature_only { 0 } else { 6 };
            REFINED_BY[b].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        if !refine.is_empty() {
            self.ms_suns = refine;
            for &t in &self.ms_suns {
                self.multiple[t * n_l..(t + 1) * n_l].fill(0.0);
            }
            multiple_sums(self);
        }
        self.ms_suns.clear();
    }

    /// The sums of [`Self::integrate`], the multiple scattering for the suns `ms_suns` (all
    /// when empty).
    fn integrate_sums(&mut self) {
        let n = self.mu_s.len() * self.n_l;
        for v in [&mut self.rayleigh, &mut self.mie, &mut self.multiple] {
            v.clear();
            v.resize(n, 0.0);
        }
        self.j.resize(n, 0.0);
        let n_t = self.mu_s.len();
        for v in [&mut self.mu_s_p, &mut self.vis]
            .into_iter()
            .chain(&mut self.d_sun)
        {
            v.resize(n_t, 0.0);
        }
        texel_sums(self);
    }

    /// The integrals of sun `t` (in the order pushed) of the last [`Self::integrate`].
    pub(crate) fn texel(&self, t: usize) -> TexelSums<'_> {
        let n_t = self.mu_s.len();
        TexelSums {
            rayleigh: Column {
                data: &self.rayleigh,
                n_t,
                t,
            },
            mie: Column {
                data: &self.mie,
                n_t,
                t,
            },
            multiple: &self.multiple[t * self.n_l..(t + 1) * self.n_l],
        }
    }
}

skybake_physics::simd_dispatch_avx512! {
    /// [`FamilyScratch::integrate`]'s sums, point by point for all suns (each texel's sums over
    /// the points in the ray's order), compiled for AVX-512 or AVX2 where the CPU has it (its loops
    /// over suns and wavelengths vectorise; Rust forms no fused multiply-adds, so the values are
    /// the baseline build's).
    fn texel_sums(scratch: &mut FamilyScratch<'_>) {
            let m = scratch.medium;
            let n_l = scratch.n_l;
            let r = scratch.r;
            let n_t = scratch.mu_s.len();
            for k in 0..scratch.points.len() {
                let p = scratch.points[k];
                for ((o, &mu_s), &nu) in scratch.mu_s_p.iter_mut().zip(&scratch.mu_s).zip(&scratch.nu) {
                    *o = ((r * mu_s + p.t * nu) / p.r).clamp(-1.0, 1.0);
                }
                if !scratch.ms_suns.is_empty() {
                    multiple_at_point(scratch, k);
                }
                let wt = &scratch.weighted_t[k * n_l..(k + 1) * n_l];
                // The point's day rows, if a sun may read them (none on most points of a
                // near-horizontal ray in twilight): the same values as filled in `prepare`.
                if scratch.ms_suns.is_empty() && !scratch.ms_skip {
                    let top = scratch.mu_s_p.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
                    if top > scratch.day_mu_s {
                        scratch.precise.fill_day(&mut scratch.slices[k]);
                    }
                    scratch.j.fill(0.0);
                    scratch.precise.add_from_slice_many(
                        &scratch.slices[k],
                        &scratch.mu_s_p,
                        &scratch.nu,
                        &mut scratch.j,
                    );
                    #[cfg(feature = "lookup-counter")]
                    LOOKUPS.fetch_add(n_t as u64, std::sync::atomic::Ordering::Relaxed);
                    for (ms, j) in scratch
                        .multiple
                        .chunks_exact_mut(n_l)
                        .zip(scratch.j.chunks_exact(n_l))
                    {
                        for l in 0..n_l {
                            ms[l] += wt[l] * j[l];
                        }
                    }
                }
                let at = &scratch.at[k];
                let rho = &scratch.rho[k];
                // Each wavelength's single scattering a vector of suns at a time, only for the
                // suns from the first to the last visible (the others would add 0): the sun's
                // visibility and optical depths (f64, negated and rounded to f32), then their
                // exponentials in one run of f32 (8 lanes), then the sums. [`sun_attenuation`]
                // written out over the suns, its constants hoisted, so the loops vectorise;
                // the transmittance in f32 ([`exp_fast_f32`]: 2·10⁻⁷, plus the optical depth's
                // rounding, |τ| × 6·10⁻⁸, of the texels' half floats' 4.9·10⁻⁴), half the
                // polynomial of `exp_fast`'s 10⁻¹⁴.
                let on = at.visible_range(&scratch.mu_s_p);
                scratch.sun_t.resize(n_l * n_t, 0.0);
                if at.has_layers() {
                    let [d0, d1, d2] = &mut scratch.d_sun;
                    at.lookup_many(
                        &scratch.mu_s_p[on.clone()],
                        &mut scratch.vis[on.clone()],
                        [&mut d0[on.clone()], &mut d1[on.clone()], &mut d2[on.clone()]],
                    );
                    for l in 0..n_l {
                        let ext = scratch.ext[l];
                        let x = &mut scratch.sun_t[l * n_t..(l + 1) * n_t][on.clone()];
                        let d = d0[on.clone()].iter().zip(&d1[on.clone()]).zip(&d2[on.clone()]);
                        for (x, ((&a, &b), &c)) in x.iter_mut().zip(d) {
                            let od = ext[0] * a + ext[1] * b + ext[2] * c;
                            *x = -od as f32;
                        }
                    }
                } else {
                    // The optical depths from the table's rows turned into optical depths
                    // once per point (the same interpolation, summed in another order).
                    at.neg_optical_depths_many(
                        &scratch.mu_s_p[on.clone()],
                        &scratch.ext,
                        &mut scratch.vis[on.clone()],
                        &mut scratch.sun_t[on.start..],
                        n_t,
                        &mut scratch.od,
                    );
                }
                let vis = &scratch.vis[on.clone()];
                for l in 0..n_l {
                    for x in &mut scratch.sun_t[l * n_t..(l + 1) * n_t][on.clone()] {
                        *x = exp_fast_f32(*x);
                    }
                }
                for l in 0..n_l {
                    let (w, s_r, s_m) = (
                        wt[l],
                        m.rayleigh_scattering_per_m[l],
                        m.mie_scattering_per_m[l],
                    );
                    let (k_r, k_m) = (w * (s_r * rho[RAYLEIGH]), w * (s_m * rho[MIE]));
                    let ray = &mut scratch.rayleigh[l * n_t..(l + 1) * n_t][on.clone()];
                    let mie = &mut scratch.mie[l * n_t..(l + 1) * n_t][on.clone()];
                    let t = &scratch.sun_t[l * n_t..(l + 1) * n_t][on.clone()];
                    for (((ray, mie), &vis), &t) in
                        ray.iter_mut().zip(mie.iter_mut()).zip(vis).zip(t)
                    {
                        let sun = t as f64 * vis;
                        // Adding 0 where the sun is hidden leaves the sum as skipping would
                        // (sums of non-negative terms).
                        let on = vis > 0.0;
                        *ray += if on { sun * k_r } else { 0.0 };
                        *mie += if on { sun * k_m } else { 0.0 };
                    }
                }
            }
    }
}

/// Adds point `k`'s multiple scattering to the sums of the suns `ms_suns` (their zenith cosines
/// at the point in `mu_s_p`): the operations of [`texel_sums`] for those suns, in the same order.
#[inline(always)]
fn multiple_at_point(scratch: &mut FamilyScratch<'_>, k: usize) {
    scratch.ms_mu_s_p.clear();
    scratch.ms_nu.clear();
    for &t in &scratch.ms_suns {
        scratch.ms_mu_s_p.push(scratch.mu_s_p[t]);
        scratch.ms_nu.push(scratch.nu[t]);
    }
    multiple_at_point_gathered(scratch, k);
}

/// [`multiple_at_point`] with the suns' zenith cosines at the point and view–sun cosines
/// already gathered into `ms_mu_s_p` and `ms_nu`.
#[inline(always)]
fn multiple_at_point_gathered(scratch: &mut FamilyScratch<'_>, k: usize) {
    let n_l = scratch.n_l;
    let wt = &scratch.weighted_t[k * n_l..(k + 1) * n_l];
    let top = scratch
        .ms_mu_s_p
        .iter()
        .fold(f64::NEG_INFINITY, |a, &b| a.max(b));
    if top > scratch.day_mu_s {
        scratch.precise.fill_day(&mut scratch.slices[k]);
    }
    scratch.ms_j.clear();
    scratch.ms_j.resize(scratch.ms_suns.len() * n_l, 0.0);
    scratch.precise.add_from_slice_many(
        &scratch.slices[k],
        &scratch.ms_mu_s_p,
        &scratch.ms_nu,
        &mut scratch.ms_j,
    );
    #[cfg(feature = "lookup-counter")]
    LOOKUPS.fetch_add(
        scratch.ms_suns.len() as u64,
        std::sync::atomic::Ordering::Relaxed,
    );
    for (&t, j) in scratch.ms_suns.iter().zip(scratch.ms_j.chunks_exact(n_l)) {
        let ms = &mut scratch.multiple[t * n_l..(t + 1) * n_l];
        for l in 0..n_l {
            ms[l] += wt[l] * j[l];
        }
    }
}

/// The point × sun lookups of the multiple-scattering table made by [`FamilyScratch`] since the
/// process started (what the smoothness tests' refinements cost: `skyview_cost` probe).
#[cfg(feature = "lookup-counter")]
pub static LOOKUPS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// The suns whose multiple scattering [`FamilyScratch`] interpolated, found not smooth and
/// computed after all, since the process started.
#[cfg(feature = "lookup-counter")]
pub static REFINED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// [`REFINED`] by the sun's elevation at the ray's origin (below −12°, −6°, 0°, 5°, 20°, above),
/// over the sun axis then over the columns.
#[cfg(feature = "lookup-counter")]
pub static REFINED_BY: [std::sync::atomic::AtomicU64; 12] =
    [const { std::sync::atomic::AtomicU64::new(0) }; 12];

/// The multiple-scattering sums of the suns `ms_suns` alone (added to `multiple`), point by
/// point as [`texel_sums`] forms them (the suns' cosines gathered once for all points).
fn multiple_sums(scratch: &mut FamilyScratch<'_>) {
    let r = scratch.r;
    scratch.ms_mu_s.clear();
    scratch.ms_nu.clear();
    for &t in &scratch.ms_suns {
        scratch.ms_mu_s.push(scratch.mu_s[t]);
        scratch.ms_nu.push(scratch.nu[t]);
    }
    let n = scratch.ms_suns.len();
    scratch.ms_mu_s_p.resize(n, 0.0);
    for k in 0..scratch.points.len() {
        let p = scratch.points[k];
        let (mu_s, nu) = (&scratch.ms_mu_s[..n], &scratch.ms_nu[..n]);
        for (o, (&mu_s, &nu)) in scratch.ms_mu_s_p[..n].iter_mut().zip(mu_s.iter().zip(nu)) {
            *o = ((r * mu_s + p.t * nu) / p.r).clamp(-1.0, 1.0);
        }
        multiple_at_point_gathered(scratch, k);
    }
}

/// Rounds values of a half-float texture to `bits` (≤ 10) mantissa bits, to nearest
/// (ties to even), a relative rounding of at most 2^−(bits + 1) for normal half floats: the
/// lowest bits of the 10 are zeros, which deflate compresses (docs/lut.md, "The `skyview`
/// layout", Size).
pub(crate) fn round_to_half_bits(values: &mut [f32], bits: u32) {
    debug_assert!(bits <= 10);
    let drop = 23 - bits;
    for v in values {
        let b = v.to_bits();
        let lsb = (b >> drop) & 1;
        let rounded = (b + (1 << (drop - 1)) - 1 + lsb) & !((1u32 << drop) - 1);
        *v = half::f16::from_f32(f32::from_bits(rounded)).to_f32();
    }
}
