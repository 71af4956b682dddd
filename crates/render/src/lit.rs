//! The camera-independent part of the fast method's per-voxel light (Nishita et al. 1996, §3.2–3.4):
//! the cloud as a medium, the sun's optical path per voxel, the cumulative paths to the 14 lattice
//! directions and the sky elements, the all-order multiple-scattering field, the sun's shadow map
//! and the truncated peak's spread. None of it depends on the camera, so a camera path (fly-around,
//! approach) lights the cloud once and [`super::march::Prepared::with_lit`] adds only what each
//! camera needs (the source towards the camera per voxel, then the pixels). A [`LitVolume`] is a
//! function of its [`LitInputs`] alone: a sequence reuses one where the inputs are equal, so its
//! frames are the frames rendered alone.

use super::light::{lattice_density_integrals, sun_density_integrals_in, SkyElements, LATTICE};
use super::lighting::Lighting;
use super::multiple::{ConvolvedCells, MsField, Truncation};
use super::peak::PeakSpread;
use super::scene::{CloudMsMethod, FrameScene, LightingSwitches, Optics};
use super::volume::CloudVolume;
use super::{Method, RenderSettings};
use glam::DVec3;
use rayon::prelude::*;
use skybake_physics::cloud::DensityGrid;
use std::sync::Arc;
use std::time::Instant;

/// Everything a [`LitVolume`] is computed from (compared whole: equal inputs, equal volume).
#[derive(Debug, Clone, PartialEq)]
pub struct LitInputs {
    pub grid: Arc<DensityGrid>,
    pub optics: Optics,
    pub wavelengths_nm: Vec<f64>,
    pub switches: LightingSwitches,
    pub ms_method: CloudMsMethod,
    pub settings: RenderSettings,
    /// The light from outside the cloud as the cloud receives it: the scene's lighting without
    /// what only the camera sees (its background and aerial perspective) and without notes.
    pub cloud_lighting: Lighting,
    /// Whether the camera has aerial perspective (shafts of light then need the shadow map).
    pub has_aerial: bool,
}

impl LitInputs {
    pub fn new(
        scene: &FrameScene,
        grid: Arc<DensityGrid>,
        lighting: &Lighting,
        settings: RenderSettings,
    ) -> Self {
        let mut cloud_lighting = lighting.clone();
        cloud_lighting.background = None;
        cloud_lighting.aerial = None;
        cloud_lighting.notes = Vec::new();
        Self {
            grid,
            optics: scene.optics.clone(),
            wavelengths_nm: scene.wavelengths.as_nm().to_vec(),
            switches: scene.lighting,
            ms_method: scene.multiple_scattering_method,
            settings,
            cloud_lighting,
            has_aerial: lighting.aerial.is_some(),
        }
    }

    /// Equal inputs; the grid compared by pointer first, then by value.
    pub fn same_as(&self, other: &Self) -> bool {
        (Arc::ptr_eq(&self.grid, &other.grid) || self.grid == other.grid)
            && self.optics == other.optics
            && self.wavelengths_nm == other.wavelengths_nm
            && self.switches == other.switches
            && self.ms_method == other.ms_method
            && self.settings == other.settings
            && self.cloud_lighting == other.cloud_lighting
            && self.has_aerial == other.has_aerial
    }
}

/// The lit cloud, for any camera (see the module's documentation).
pub struct LitVolume {
    pub inputs: LitInputs,
    pub vol: CloudVolume,
    /// The sun's density integral per voxel, m (empty when the cloud gets no per-voxel light).
    pub d_sun: Vec<f32>,
    /// Voxels whose 3×3×3 neighbourhood holds any density (where per-voxel light is needed).
    pub mask: Vec<bool>,
    /// Density integrals towards the 14 lattice directions (sky and ground light), m.
    pub lattice: Vec<Vec<f32>>,
    pub sky_elements: Option<SkyElements>,
    pub ms: Option<MsField>,
    pub shadow: Option<ShadowMap>,
    pub peak: Option<PeakSpread>,
    /// σ_t*/σ_t, ω* and ω·f·spread per wavelength (TMS, see `multiple`).
    pub ms_extinction_scale: Vec<f64>,
    pub ms_albedo: Vec<f64>,
    pub peak_rate: Vec<f64>,
    /// s⁺ = σ_t⁺/σ_t = 1 − ωf⁺ per wavelength (f⁺ the truncated peak's integral,
    /// [`PeakSpread::peak_fraction`]): the extinction of light that scatters only within the
    /// peak r⁺ as it travels, through which the sun's single scattering is attenuated on both
    /// its paths (`march`); s where no peak is spread.
    pub first_extinction_scale: Vec<f64>,
    pub sun_on: bool,
    pub env_on: bool,
    /// Orders 2–3 by the reference pattern: computed per camera (its views are the camera's).
    pub pattern_on: bool,
    /// The per-voxel light runs (fast method, a cloud in view).
    pub per_voxel: bool,
    /// The sky light's camera-independent transmittances per voxel, filled at the volume's first
    /// reuse by another camera ([`SkyTransmittances`]).
    pub sky_trans: std::sync::OnceLock<SkyTransmittances>,
    /// The multiple-scattering field's coefficients laid out for the reconstruction, filled by the first
    /// camera ([`ConvolvedCells`]).
    pub ms_cells: std::sync::OnceLock<ConvolvedCells>,
    /// Stage timings of the computation, ms (volume, peak_spread, then sun_paths, sky_light,
    /// multiple_scattering and shadow_map, which run side by side: each its own wall time).
    pub timing_ms: Vec<(String, f64)>,
    /// Approximate bytes held (for a cache's budget).
    pub bytes: usize,
}

/// √D of a sun's path as the voxel records store it.
#[inline(always)]
pub(crate) fn sun_root(d: f32) -> f32 {
    d.max(0.0).sqrt()
}

/// The sky light's transmittances that do not depend on the camera: per voxel of the lit
/// volume's mask, for each wavelength whose extinction differs from the previous one's,
/// e^{−k D} of the sun's path and of the 14 lattice paths (f64, the values
/// [`Prepared::with_lit`](super::march::Prepared::with_lit) computes). A camera path reads them instead of computing 15
/// exponentials per voxel and camera; computed at the lit volume's first reuse (a single
/// frame does not pay for them).
pub struct SkyTransmittances {
    /// Per z-layer, the index of its first masked voxel in the mask's order.
    pub(crate) first: Vec<usize>,
    /// Values per masked voxel: `per_voxel` = (distinct wavelengths) × (1 + paths).
    per_voxel: usize,
    values: Vec<f64>,
}

impl SkyTransmittances {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        8 * (self.values.len() + self.first.len())
    }

    /// The values of masked voxel number `i` (in the mask's order).
    #[inline(always)]
    pub(crate) fn of(&self, i: usize) -> &[f64] {
        &self.values[i * self.per_voxel..(i + 1) * self.per_voxel]
    }
}

impl LitVolume {
    /// [`SkyTransmittances`] of this volume for the extinctions per density `k` (`fresh`: the
    /// wavelengths whose extinction differs from the previous one's), the z-layers in parallel.
    pub(crate) fn sky_transmittances(&self, k: &[f64], fresh: &[bool]) -> SkyTransmittances {
        let grid = &*self.inputs.grid;
        let [nx, ny, _] = grid.dims;
        let layer = nx * ny;
        let paths = &self.lattice;
        let per_voxel = fresh.iter().filter(|&&f| f).count() * (paths.len() + 1);
        let mut first = Vec::with_capacity(grid.dims[2] + 1);
        let mut count = 0;
        for z in 0..grid.dims[2] {
            first.push(count);
            count += self.mask[z * layer..(z + 1) * layer]
                .iter()
                .filter(|&&m| m)
                .count();
        }
        first.push(count);
        let mut values = vec![0f64; count * per_voxel];
        let mut slabs = Vec::with_capacity(grid.dims[2]);
        let mut rest = &mut values[..];
        for z in 0..grid.dims[2] {
            let (a, b) = rest.split_at_mut((first[z + 1] - first[z]) * per_voxel);
            slabs.push((z, a));
            rest = b;
        }
        slabs.into_par_iter().for_each(|(z, slab)| {
            let mut out = slab.chunks_mut(per_voxel);
            for idx in z * layer..(z + 1) * layer {
                if !self.mask[idx] {
                    continue;
                }
                let Some(row) = out.next() else { break };
                let d_sun = (sun_root(self.d_sun[idx]) as f64).powi(2);
                let mut row = row.chunks_mut(paths.len() + 1);
                for l in (0..k.len()).filter(|&l| fresh[l]) {
                    if let Some(t) = row.next() {
                        t[0] = (-k[l] * d_sun).exp();
                        for (e, path) in paths.iter().enumerate() {
                            t[e + 1] = (-k[l] * path[idx] as f64).exp();
                        }
                    }
                }
            }
        });
        SkyTransmittances {
            first,
            per_voxel,
            values,
        }
    }
}

/// The sun's and the lattice paths go back to the working-buffer pool for the next frame's
/// (the same sizes: [`pages::take_f32`](super::pages::take_f32)).
impl Drop for LitVolume {
    fn drop(&mut self) {
        super::pages::give_back_f32(std::mem::take(&mut self.d_sun));
        for path in std::mem::take(&mut self.lattice) {
            super::pages::give_back_f32(path);
        }
    }
}

impl LitVolume {
    /// Lights the cloud of `inputs`; `cancel` is polled between stages.
    pub fn new(inputs: LitInputs, cancel: &(dyn Fn() -> bool + Sync)) -> crate::Result<Self> {
        let settings = inputs.settings;
        let mut timing_ms = Vec::new();
        let mut clock = Instant::now();
        let mut lap = |name: &str, timing: &mut Vec<(String, f64)>| {
            timing.push((name.to_string(), clock.elapsed().as_secs_f64() * 1e3));
            clock = Instant::now();
        };
        let vol = CloudVolume::new(inputs.grid.clone());
        let grid = &*inputs.grid;
        lap("volume", &mut timing_ms);
        let lighting = &inputs.cloud_lighting;
        let sun_on = lighting.sun_irradiance.iter().any(|&e| e > 0.0);
        let optics = &inputs.optics;
        let sw = inputs.switches;
        // The planner's hooks: sky or ground light left out on the cloud (not the background).
        let masked = lighting.masked(settings.sky_light, settings.ground_light);
        let cloud_lighting = masked.as_ref().unwrap_or(lighting);
        let env_on = !(cloud_lighting.sky.is_zero() && cloud_lighting.below.is_zero());
        let scattering = settings.method == Method::Fast
            && vol.rho_max > 0.0
            && sw.multiple_scattering
            && optics.albedo.iter().any(|&a| a > 0.0);
        // Orders 2–3 of sunlight by the reference pattern (Nishita et al. 1996, §3.4), with the true phase
        // function and no δ-M scaling; or the all-order field.
        let pattern_on = scattering && inputs.ms_method == CloudMsMethod::ReferencePattern;
        let ms_on = scattering && !pattern_on && (sun_on || env_on);
        // δ-M scaling when the multiple-scattering field runs; none otherwise.
        let trunc: Vec<Truncation> = optics
            .phase
            .iter()
            .zip(&optics.albedo)
            .map(|(p, &a)| {
                let power = if ms_on {
                    settings.photons.truncation_power
                } else {
                    0.0
                };
                Truncation::new(p.mean_cosine(), a, power)
            })
            .collect();
        let ms_extinction_scale: Vec<f64> = trunc.iter().map(|t| t.extinction_scale).collect();
        let ms_albedo: Vec<f64> = trunc.iter().map(|t| t.albedo_scaled).collect();
        let peak_rate: Vec<f64> = trunc
            .iter()
            .map(|t| settings.photons.peak_spread * t.albedo * t.fraction)
            .collect();
        // The peak's tables: the sun's single scattering spreads over them; the sky's first
        // order takes only the peak's integral f⁺ (its paths' extinction σ_t⁺).
        let spread = if (sun_on || env_on) && settings.method == Method::Fast {
            PeakSpread::new(&optics.phase, &trunc)
        } else {
            None
        };
        let first_extinction_scale: Vec<f64> = trunc
            .iter()
            .enumerate()
            .map(|(l, t)| match &spread {
                Some(p) if p.peak_fraction(l) > 0.0 => 1.0 - t.albedo * p.peak_fraction(l),
                _ => t.extinction_scale,
            })
            .collect();
        let peak = if sun_on { spread } else { None };
        let per_voxel =
            settings.method == Method::Fast && vol.rho_max > 0.0 && settings.cloud_in_view;
        let needs_shadow = sun_on
            && vol.rho_max > 0.0
            && ((sw.cloud_shadows && lighting.ground.is_some())
                || (sw.shafts_of_light && inputs.has_aerial));
        lap("peak_spread", &mut timing_ms);
        // The sun's paths, the sky light's paths, the photon pass and the shadow map read the
        // volume and the light, not each other: they run side by side (rayon's joins), so a
        // core that one of them leaves idle (the sun's paths wait for every layer's rows, the
        // photon pass for its last lanes) takes work from another. Each stage's time is its
        // own wall time, overlapping the others'.
        let sun_stage = || {
            if !per_voxel {
                Vec::new()
            } else if sun_on || env_on {
                // The sky element round the sun uses the sun's path too.
                sun_density_integrals_in(&vol, lighting.sun_dir)
            } else {
                vec![0f32; grid.data.len()]
            }
        };
        let sky_stage = || {
            if !per_voxel {
                return (Vec::new(), None, Vec::new());
            }
            let mask = dilated_mask(grid);
            if !env_on {
                return (mask, None, Vec::new());
            }
            let truncated: Vec<f64> = trunc.iter().map(|t| t.fraction).collect();
            let elements = SkyElements::kept(
                cloud_lighting,
                &optics.phase,
                &truncated,
                settings.sky_quadrature,
                settings.sky_table[0],
                settings.sky_table[1],
            );
            let lattice: Vec<Vec<f32>> = LATTICE
                .par_iter()
                .map(|e| lattice_density_integrals(grid, *e))
                .collect();
            (mask, Some(elements), lattice)
        };
        let ms_stage = || {
            (per_voxel && ms_on)
                .then(|| MsField::compute(grid, optics, cloud_lighting, &settings.photons, cancel))
                .transpose()
        };
        let shadow_stage = || {
            needs_shadow
                .then(|| ShadowMap::new(&vol, lighting.sun_dir, grid.voxel_size_m))
                .flatten()
        };
        let (((d_sun, t_sun), (shadow, t_shadow)), ((sky, t_sky), (ms, t_ms))) = rayon::join(
            || rayon::join(|| timed(sun_stage), || timed(shadow_stage)),
            || rayon::join(|| timed(sky_stage), || timed(ms_stage)),
        );
        let (mask, sky_elements, lattice) = sky;
        let ms = ms?;
        check(cancel)?;
        if per_voxel {
            timing_ms.push(("sun_paths".into(), t_sun));
            timing_ms.push(("sky_light".into(), t_sky));
            if ms.is_some() {
                timing_ms.push(("multiple_scattering".into(), t_ms));
            }
        }
        timing_ms.push(("shadow_map".into(), t_shadow));
        let bytes = 4 * d_sun.len()
            + mask.len()
            + 4 * lattice.iter().map(Vec::len).sum::<usize>()
            + ms.as_ref().map_or(0, MsField::bytes)
            + ms.as_ref().map_or(0, MsField::convolved_bytes)
            + shadow.as_ref().map_or(0, |s| 4 * s.d.len())
            + 4 * grid.data.len()
            + sky_trans_bytes(
                &mask,
                &lattice,
                &optics.extinction_per_density_m,
                &first_extinction_scale,
            );
        Ok(Self {
            inputs,
            vol,
            d_sun,
            mask,
            lattice,
            sky_elements,
            ms,
            shadow,
            peak,
            ms_extinction_scale,
            ms_albedo,
            peak_rate,
            first_extinction_scale,
            sun_on,
            env_on,
            pattern_on,
            per_voxel,
            sky_trans: std::sync::OnceLock::new(),
            ms_cells: std::sync::OnceLock::new(),
            timing_ms,
            bytes,
        })
    }

    /// The light the cloud receives: the scene's, less what the planner's hooks left out.
    pub fn cloud_lighting(&self) -> std::borrow::Cow<'_, Lighting> {
        let s = &self.inputs.settings;
        match self
            .inputs
            .cloud_lighting
            .masked(s.sky_light, s.ground_light)
        {
            Some(l) => std::borrow::Cow::Owned(l),
            None => std::borrow::Cow::Borrowed(&self.inputs.cloud_lighting),
        }
    }
}

/// `f()` and its wall time, ms.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = Instant::now();
    let v = f();
    (v, t.elapsed().as_secs_f64() * 1e3)
}

/// The bytes the sky light's transmittances take once a second camera fills them
/// ([`SkyTransmittances`]): 8 per masked voxel, path (the sun's and the lattice
/// paths) and wavelength whose extinction differs from the previous one's.
fn sky_trans_bytes(mask: &[bool], lattice: &[Vec<f32>], k: &[f64], scale: &[f64]) -> usize {
    if lattice.is_empty() {
        return 0;
    }
    let ks: Vec<f64> = k.iter().zip(scale).map(|(k, s)| k * s).collect();
    let distinct = (0..ks.len())
        .filter(|&l| l == 0 || ks[l] != ks[l - 1])
        .count();
    8 * mask.iter().filter(|&&m| m).count() * distinct * (lattice.len() + 1)
}

pub(crate) fn check(cancel: &(dyn Fn() -> bool + Sync)) -> crate::Result<()> {
    if cancel() {
        Err(crate::Error::Cancelled)
    } else {
        Ok(())
    }
}

/// The sun's shadow map on the plane of the box's bottom face (Dobashi et al. 2000, §5.2.1): density
/// integral towards the sun from each point of the plane.
pub struct ShadowMap {
    pub z_m: f64,
    pub origin_xy: [f64; 2],
    pub cell_m: f64,
    pub dims: [usize; 2],
    pub d: Vec<f32>,
    /// Map coordinates `[u_lo, u_hi, v_lo, v_hi]` outside which every [`Self::lookup`] returns
    /// 0 (its four cells all 0); `None`: the whole map is 0 ([`Self::may_shade`]).
    nonzero: Option<[f64; 4]>,
}

impl ShadowMap {
    pub(crate) fn new(vol: &CloudVolume, sun: DVec3, step_m: f64) -> Option<Self> {
        if sun.z < 0.02 {
            return None;
        }
        let z = vol.lo.z;
        // Footprint: the box's corners projected along the sun onto the plane.
        let (mut min, mut max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for c in 0..8 {
            let p = DVec3::new(
                if c & 1 == 0 { vol.lo.x } else { vol.hi.x },
                if c & 2 == 0 { vol.lo.y } else { vol.hi.y },
                if c & 4 == 0 { vol.lo.z } else { vol.hi.z },
            );
            let q = p - sun * ((p.z - z) / sun.z);
            for a in 0..2 {
                min[a] = min[a].min(q[a]);
                max[a] = max[a].max(q[a]);
            }
        }
        let h = vol.grid.voxel_size_m;
        let extent = (max[0] - min[0]).max(max[1] - min[1]);
        let cell = h.max(extent / 1024.0);
        let dims = [
            ((max[0] - min[0]) / cell).ceil() as usize + 1,
            ((max[1] - min[1]) / cell).ceil() as usize + 1,
        ];
        let mut d = vec![0f32; dims[0] * dims[1]];
        d.par_chunks_mut(dims[0]).enumerate().for_each(|(j, row)| {
            for (i, v) in row.iter_mut().enumerate() {
                let p = DVec3::new(min[0] + i as f64 * cell, min[1] + j as f64 * cell, z);
                *v = vol.density_integral(p, sun, step_m) as f32;
            }
        });
        let nonzero = nonzero_bounds(&d, dims);
        Some(Self {
            z_m: z,
            origin_xy: min,
            cell_m: cell,
            dims,
            d,
            nonzero,
        })
    }

    /// Whether [`Self::lookup`] can return anything but 0 at a point `o + d·t`, t in
    /// `[t0, t1]`, at or below the map's plane (where `march`'s shafts of light look the map
    /// up): false where that part of the ray, projected along the sun onto the plane, misses
    /// the cells that hold density by more than a cell (the margin covers the rounding of
    /// this test's arithmetic against the look-up's). Conservative: true when unsure.
    pub(crate) fn may_shade(&self, o: DVec3, d: DVec3, t0: f64, t1: f64, sun: DVec3) -> bool {
        let Some([u_lo, u_hi, v_lo, v_hi]) = self.nonzero else {
            return false;
        };
        let (mut lo, mut hi) = (t0, t1);
        // At or below the plane (a metre's margin).
        let z_top = self.z_m + 1.0;
        if d.z == 0.0 {
            if o.z > z_top {
                return false;
            }
        } else {
            let t = (z_top - o.z) / d.z;
            if d.z > 0.0 {
                hi = hi.min(t);
            } else {
                lo = lo.max(t);
            }
        }
        // The projection q = p + sun·(z − p.z)/sun.z in map coordinates, affine in t.
        let s = sun / sun.z;
        let q0 = o + s * (self.z_m - o.z);
        let dq = d - s * d.z;
        let axes = [
            (q0.x - self.origin_xy[0], dq.x, u_lo, u_hi),
            (q0.y - self.origin_xy[1], dq.y, v_lo, v_hi),
        ];
        for (a0, da, c_lo, c_hi) in axes {
            let (a0, da) = (a0 / self.cell_m, da / self.cell_m);
            let (c_lo, c_hi) = (c_lo - 1.0, c_hi + 1.0);
            if da == 0.0 {
                if !(a0 >= c_lo && a0 <= c_hi) {
                    return false;
                }
                continue;
            }
            let (ta, tb) = ((c_lo - a0) / da, (c_hi - a0) / da);
            lo = lo.max(ta.min(tb));
            hi = hi.min(ta.max(tb));
        }
        // Not `lo > hi` (a NaN bound leaves it true: unsure).
        lo <= hi || lo.is_nan() || hi.is_nan()
    }

    /// Density integral towards the sun from `p` below the plane (bilinear).
    pub(crate) fn lookup(&self, p: DVec3, sun: DVec3) -> f64 {
        let q = p + sun * ((self.z_m - p.z) / sun.z);
        let u = (q.x - self.origin_xy[0]) / self.cell_m;
        let v = (q.y - self.origin_xy[1]) / self.cell_m;
        if !(u >= 0.0
            && v >= 0.0
            && u <= (self.dims[0] - 1) as f64
            && v <= (self.dims[1] - 1) as f64)
        {
            return 0.0;
        }
        let (i0, j0) = (
            super::volume::floor(u) as usize,
            super::volume::floor(v) as usize,
        );
        let (i1, j1) = (
            (i0 + 1).min(self.dims[0] - 1),
            (j0 + 1).min(self.dims[1] - 1),
        );
        let (fu, fv) = (u - i0 as f64, v - j0 as f64);
        let g = |i: usize, j: usize| self.d[j * self.dims[0] + i] as f64;
        (g(i0, j0) * (1.0 - fu) + g(i1, j0) * fu) * (1.0 - fv)
            + (g(i0, j1) * (1.0 - fu) + g(i1, j1) * fu) * fv
    }
}

/// [`ShadowMap::nonzero`] of the map `d` (`dims` cells): the map coordinates round its cells
/// that hold density within which a bilinear look-up reads one of them (cell i is read for
/// u in (i − 1, i + 1)).
fn nonzero_bounds(d: &[f32], dims: [usize; 2]) -> Option<[f64; 4]> {
    let (mut i_lo, mut i_hi, mut j_lo, mut j_hi) = (usize::MAX, 0, usize::MAX, 0);
    for (j, row) in d.chunks(dims[0]).enumerate() {
        for (i, v) in row.iter().enumerate() {
            if *v != 0.0 {
                i_lo = i_lo.min(i);
                i_hi = i_hi.max(i);
                j_lo = j_lo.min(j);
                j_hi = j_hi.max(j);
            }
        }
    }
    (i_lo <= i_hi).then_some([
        i_lo as f64 - 1.0,
        i_hi as f64 + 1.0,
        j_lo as f64 - 1.0,
        j_hi as f64 + 1.0,
    ])
}

/// Voxels whose 3×3×3 neighbourhood holds any density (where per-voxel light is needed); the
/// z-layers in parallel, each from the three input layers round it.
fn dilated_mask(grid: &DensityGrid) -> Vec<bool> {
    let [nx, ny, nz] = grid.dims;
    let mut m = vec![false; grid.data.len()];
    m.par_chunks_mut(nx * ny).enumerate().for_each(|(z, out)| {
        for zz in z.saturating_sub(1)..=(z + 1).min(nz - 1) {
            for y in 0..ny {
                for x in 0..nx {
                    if grid.at(x, y, zz) <= 0.0 {
                        continue;
                    }
                    for yy in y.saturating_sub(1)..=(y + 1).min(ny - 1) {
                        for xx in x.saturating_sub(1)..=(x + 1).min(nx - 1) {
                            out[yy * nx + xx] = true;
                        }
                    }
                }
            }
        }
    });
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Where [`ShadowMap::may_shade`] says a ray's part below the map's plane passes beside the
    /// cloud's shadow, the look-ups the shafts of light make along it all return 0; and it says
    /// so for many rays (the test is not vacuous).
    #[test]
    fn rays_beside_the_shadow_read_no_shadow() {
        let grid = DensityGrid::from_fn([24, 20, 12], 10.0, DVec3::new(-100.0, 40.0, 800.0), |p| {
            let c = DVec3::new(20.0, 140.0, 860.0);
            let r = (p - c).length();
            if r < 55.0 {
                (1.0 - r / 55.0) as f32
            } else {
                0.0
            }
        })
        .expect("grid");
        let vol = CloudVolume::new(Arc::new(grid));
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let (mut beside, mut shaded) = (0, 0);
        for sun in [
            DVec3::new(0.4, -0.3, 0.6).normalize(),
            DVec3::new(-0.7, 0.1, 0.3).normalize(),
            DVec3::Z,
        ] {
            let map = ShadowMap::new(&vol, sun, 10.0).expect("sun above the horizon");
            for _ in 0..3000 {
                let o = DVec3::new(
                    rng.random_range(-600.0..600.0),
                    rng.random_range(-500.0..700.0),
                    rng.random_range(0.0..1200.0),
                );
                let d = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize_or(DVec3::X);
                let tx = rng.random_range(10.0..3000.0);
                let any = (0..400).any(|k| {
                    let p = o + d * (tx * (k as f64 + 0.5) / 400.0);
                    p.z <= map.z_m && map.lookup(p, sun) != 0.0
                });
                if any {
                    shaded += 1;
                }
                if !map.may_shade(o, d, 0.0, tx, sun) {
                    assert!(!any, "{o} {d} {tx}");
                    beside += 1;
                }
            }
        }
        assert!(beside > 3000 && shaded > 300, "{beside} {shaded}");
    }
}
