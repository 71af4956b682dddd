//! Pre-lit cloud volumes for real-time clients: what the fast cloud method computed per voxel
//! (the renderer's [`LitVolume`]: the sun's density integral, the density integrals towards the
//! 14 lattice directions that carry sky and ground light, and the all-order multiple-scattering
//! field's spherical-harmonic moments, with those of its skin tallies of optically thick cells),
//! exported with the direction tables that turn them into
//! the source towards any viewer (the sky elements of Nishita et al. 1996, eq 7, the phase
//! function, the truncated peak's spread), so a client ray-marches a lit cloud without computing
//! any light. `docs/cloud-light.md` documents the layout; [`marcher`] is the reference client.
//!
//! - [`CloudLight`]: the export in memory; [`CloudLight::from_lit`] builds it (pure).
//! - [`CloudLight::files`] / [`CloudLight::from_files`]: OpenEXR 3-D textures (z-slices stacked
//!   vertically) + `manifest.json`, encoded and decoded through the store (no file I/O here).
//! - [`CloudLightRequest`]: a frame scene → its lit volume → the export.
//! - [`marcher`]: the reference marcher of a decoded export.

pub mod marcher;

use glam::DVec3;
use serde_json::{json, Value};
use skybake_engine::engine::{Engine, ENGINE_VERSION};
use skybake_physics::cloud::scene::MAX_SCENE_FILE_BYTES;
use skybake_physics::image::layout::spectral_channel_name;
use skybake_render::light::{LATTICE, SUN_CAP_DEG, VIEW_CAP_DEG};
use skybake_render::march::{MARCH_CUTOFF, THICK_STEP};
use skybake_render::scene::CloudMsMethod;
use skybake_render::{peak, FrameScene, LitInputs, LitVolume, Method, RenderSettings};
use skybake_store::texture::{decode_texture_exr, encode_texture_exr, TextureImage};
use std::f64::consts::PI;
use std::sync::Arc;
use std::time::Instant;

use crate::{Error, Result};

/// Layout version of the export (bumped when a file, channel or field changes meaning).
pub const LAYOUT_VERSION: &str = "8";
pub const MANIFEST_FILE: &str = "manifest.json";
pub const DENSITY_FILE: &str = "density.exr";
pub const SUN_PATH_FILE: &str = "sun_path.exr";
pub const SKY_PATHS_FILE: &str = "sky_paths.exr";
pub const MS_FILE: &str = "multiple_scattering.exr";
pub const SKIN_FILE: &str = "multiple_scattering_skin.exr";
pub const FACES_FILE: &str = "multiple_scattering_faces.exr";
pub const ONCE_FILE: &str = "once_scattered.exr";
pub const SKY_ELEMENTS_FILE: &str = "sky_elements.exr";
pub const PHASE_FILE: &str = "phase.exr";
pub const PEAK_FILE: &str = "peak_spread.exr";
/// Most sub-steps of one thick march step (the fast frame's).
pub const MAX_SUB_STEPS: usize = 64;
/// A thick step's sun path is integrated from the density over this many voxels towards the sun.
pub const SUN_NEAR_VOXELS: f64 = 2.0;
/// ... in this many composite-Simpson intervals.
pub const SUN_NEAR_INTERVALS: usize = 16;
/// Nodes of the phase-function table (node i at θ = π·(i/(N − 1))², dense at the forward peak).
pub const PHASE_NODES: usize = 2048;
/// Sky-element table entries: the sun cap (0), the 14 lattice elements (1–14), the view cap
/// (15) and the environment radiance from the view direction itself (16).
pub const SKY_ELEMENTS: usize = 17;
/// Largest export held in memory, bytes (32-bit values: density, sun path, 14 sky paths, the
/// face cells' density and 25 multiple-scattering moments (angular order 4) per wavelength,
/// three times (the cells' convolved, the skins' and the surface voxels' radiance), per voxel):
/// 1 GiB, e.g. 1.1 M voxels at 3 wavelengths.
pub const MAX_EXPORT_BYTES: usize = 1 << 30;

/// Bytes an export of `voxels` voxels and `n_l` wavelengths holds in memory (see
/// [`MAX_EXPORT_BYTES`]).
pub fn export_bytes(voxels: usize, n_l: usize) -> usize {
    let moments = (skybake_render::multiple::MAX_ORDER + 1).pow(2);
    let once = skybake_render::multiple::ONCE_MOMENTS;
    voxels.saturating_mul(4 * (3 + LATTICE.len() + (3 * moments + once) * n_l))
}

/// Whether voxel `ijk` of a grid of `dims` with `density` holds cloud and borders empty space
/// (a face neighbour of density ≤ 0, or the grid's edge): where the fast frame sees the
/// multiple-scattering field through the voxel's face (docs/cloud-light.md, "Faces").
pub fn surface_voxel(density: &[f32], dims: [usize; 3], ijk: [usize; 3]) -> bool {
    let at = |q: [usize; 3]| density[(q[2] * dims[1] + q[1]) * dims[0] + q[0]];
    if at(ijk) <= 0.0 {
        return false;
    }
    (0..3).any(|a| {
        let (mut lo, mut hi) = (ijk, ijk);
        lo[a] = lo[a].wrapping_sub(1);
        hi[a] += 1;
        ijk[a] == 0 || ijk[a] + 1 >= dims[a] || at(lo) <= 0.0 || at(hi) <= 0.0
    })
}

/// Refuses an export larger than [`MAX_EXPORT_BYTES`] before it is computed, naming the cloud.
pub fn check_export_size(dims: [usize; 3], n_l: usize) -> Result<()> {
    let voxels = dims[0] * dims[1] * dims[2];
    let bytes = export_bytes(voxels, n_l);
    if bytes > MAX_EXPORT_BYTES {
        return Err(Error::too_large(
            "cloud",
            format!(
                "{dims:?} = {voxels} voxels at {n_l} wavelengths make a {} MiB pre-lit volume",
                bytes >> 20
            ),
            format!(
                "{} MiB (use a larger voxel_size_m or fewer wavelengths)",
                MAX_EXPORT_BYTES >> 20
            ),
        ));
    }
    Ok(())
}

/// Largest manifest accepted when decoding, bytes.
const MAX_MANIFEST_BYTES: usize = 1 << 20;

/// `v` as the 16-bit float the file holds (the in-memory export is what a client decodes).
fn to_half(v: f32) -> f32 {
    half::f16::from_f32(v).to_f32()
}

/// A wavelength-dependent directional table: one channel per (entry, wavelength).
#[derive(Debug, Clone, PartialEq)]
pub struct SkyTable {
    /// Rows: elevation −90° … 90° inclusive; columns: azimuth 2π·c/n_az from +y towards +x.
    pub n_elev: usize,
    pub n_az: usize,
    /// `[entry·n_λ + λ][row·n_az + col]`, W m⁻² nm⁻¹ (entries 0–15: phase-weighted radiance
    /// ∫ p L dω, sr⁻¹ integrated away) and W m⁻² sr⁻¹ nm⁻¹ (entry 16: radiance).
    pub values: Vec<Vec<f32>>,
}

/// The truncated peak's spread p_eff/p of the sun's single scattering, per wavelength.
#[derive(Debug, Clone, PartialEq)]
pub struct PeakTable {
    /// Rows: scattering angle 0 … 180° in 180/(n_theta − 1)° steps; columns: λ = ωfτ from 0 to
    /// `lambda_max`.
    pub n_theta: usize,
    pub n_lambda: usize,
    pub lambda_max: f64,
    /// `[λ][row·n_lambda + col]`.
    pub values: Vec<Vec<f32>>,
    /// The part of `values` scattered last within the truncated peak (r⁺_eff/p, seen through
    /// the true extinction instead of the scaled one), `[λ][row·n_lambda + col]`.
    pub last_in_peak: Vec<Vec<f32>>,
}

/// The multiple-scattering field in the skin of optically thick cells (the first
/// `depth_scaled_tau` of scaled optical depth below a face that borders thinner cloud or the
/// grid's edge, tallied on its own by the photon pass): what the march's thick steps use for
/// the first optical depths along a view ray (docs/cloud-light.md, "Thick steps").
#[derive(Debug, Clone, PartialEq)]
pub struct SkinMoments {
    /// The skin's depth per wavelength, scaled optical depths along the view ray.
    pub depth_scaled_tau: Vec<f64>,
    /// C_skin,lm − C_lm per voxel, `[λ·(L+1)² + lm][voxel]` as [`CloudLight::ms`]: the skin's
    /// moments minus the cell's (as stored), 0 where no coarse cell round the voxel has a skin.
    pub delta: Vec<Vec<f32>>,
}

/// What a client needs to see the multiple-scattering field through a surface voxel's face
/// ([`surface_voxel`]): the inward light builds up with depth below a face bordering empty
/// space, so a view entering there sees less of it than the coarse cell's mean (the formal
/// solution, Chandrasekhar 1960 §1.8; docs/cloud-light.md, "Faces").
#[derive(Debug, Clone, PartialEq)]
pub struct FaceField {
    /// The field's coarse cells' edges along x, y, z, m.
    pub cell_size_m: [f64; 3],
    /// ω*, the δ-M scaled albedo, per wavelength (C_lm = ω*·p*_l·L_lm).
    pub scaled_albedo: Vec<f64>,
    /// p*_l, the δ-M scaled phase function's Legendre moments (p*_0 = 1), `[λ][l]`, l = 0 … L.
    pub scaled_phase_moments: Vec<Vec<f64>>,
    /// ρ_cell: the mean density of the coarse cell holding the voxel's centre, at surface
    /// voxels (0 elsewhere).
    pub cell_density: Vec<f32>,
    /// L_lm: the field's radiance moments (not convolved), `[λ·(L+1)² + lm][voxel]`,
    /// W m⁻² nm⁻¹, at surface voxels (0 elsewhere).
    pub radiance: Vec<Vec<f32>>,
}

/// The export of a lit cloud (see the module's documentation and docs/cloud-light.md).
#[derive(Debug, Clone, PartialEq)]
pub struct CloudLight {
    /// Voxels along x, y, z; voxel (i, j, k) is the cube [origin + h·(i, j, k), origin + h·(i+1, j+1, k+1)]
    /// and its values are at its centre; per-voxel arrays are indexed (k·ny + j)·nx + i.
    pub dims: [usize; 3],
    pub origin_m: [f64; 3],
    pub voxel_size_m: f64,
    pub wavelengths_nm: Vec<f64>,
    /// σ_t = k·ρ, m⁻¹ per unit density, per wavelength.
    pub extinction_per_density_m: Vec<f64>,
    /// Single-scattering albedo ω per wavelength.
    pub albedo: Vec<f64>,
    /// s = σ_t*/σ_t = 1 − ω f per wavelength (δ-M scaled extinction; 1 without truncation).
    pub extinction_scale: Vec<f64>,
    /// Rate of the peak spread per unit true optical depth towards the sun, per wavelength.
    pub peak_rate: Vec<f64>,
    /// s⁺ = 1 − ωf⁺ per wavelength (f⁺ the truncated peak's integral): the extinction of the
    /// sun's once-scattered light on its paths (s without a peak table).
    pub first_extinction_scale: Vec<f64>,
    /// Unit vector from the cloud towards the sun.
    pub sun_direction: [f64; 3],
    /// Sun's irradiance normal to the beam at the cloud, W m⁻² nm⁻¹, per wavelength.
    pub sun_irradiance: Vec<f64>,
    /// March step the fast frame used, voxels.
    pub step_voxels: f64,
    /// Density per voxel (dimensionless).
    pub density: Vec<f32>,
    /// D_sun: density integral from the voxel centre towards the sun to the box, m.
    pub sun_path: Vec<f32>,
    /// D_e: density integrals towards the 14 lattice directions (sky and ground light), m; empty
    /// when no sky or ground light reaches the cloud.
    pub sky_paths: Vec<Vec<f32>>,
    /// Angular order L of the multiple-scattering moments (`None`: no field).
    pub ms_order: Option<usize>,
    /// Multiple-scattering moments C_lm = ω*·p*_l·L_lm per voxel, `[λ·(L+1)² + lm][voxel]`,
    /// W m⁻² nm⁻¹ (the source of orders ≥ 2 towards a viewer looking along d is
    /// max(0, Σ C_lm Y_lm(−d)), W m⁻² sr⁻¹ nm⁻¹ per unit scaled extinction).
    pub ms: Vec<Vec<f32>>,
    /// The field's skin tallies of optically thick cells, where any cell has one.
    pub skin: Option<SkinMoments>,
    /// The field at the surface voxels, seen through their faces (with `ms`).
    pub faces: Option<FaceField>,
    /// The sun's once-scattered light in place of the field's, K_lm = ω*·(k_l·E_sun·L₁,lm −
    /// p*_l·L*₁,lm) per voxel to order [`ONCE_ORDER`](skybake_render::multiple::ONCE_ORDER),
    /// `[λ·(L₁+1)² + lm][voxel]`, W m⁻² nm⁻¹: Σ K_lm Y_lm(−d) is added to the field's source
    /// where the voxel is not seen through a face (docs/cloud-light.md); empty without it.
    pub once: Vec<Vec<f32>>,
    pub sky: Option<SkyTable>,
    /// The true phase function p(θ), sr⁻¹, `[λ][node]`, node i at θ = π·(i/(N−1))².
    pub phase: Vec<Vec<f32>>,
    pub peak: Option<PeakTable>,
    /// What made it: the scene's name, quality, the fast method's settings.
    pub settings: Value,
}

impl CloudLight {
    pub fn voxels(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    pub fn n_l(&self) -> usize {
        self.wavelengths_nm.len()
    }

    /// Builds the export of a lit volume computed by the fast method with per-voxel light
    /// (refused otherwise, naming what is missing).
    pub fn from_lit(lit: &LitVolume, scene_name: Option<&str>) -> Result<Self> {
        let inputs = &lit.inputs;
        let settings = &inputs.settings;
        if settings.method != Method::Fast || !lit.per_voxel {
            return Err(Error::invalid(
                "method",
                "a pre-lit volume is the fast method's per-voxel light (method fast, a cloud with density)",
            ));
        }
        if lit.pattern_on || inputs.ms_method == CloudMsMethod::ReferencePattern {
            return Err(Error::invalid(
                "multiple_scattering_method",
                "the reference pattern is computed per camera; a pre-lit volume needs \"all_orders\"",
            ));
        }
        let grid = &*inputs.grid;
        let n_l = inputs.wavelengths_nm.len();
        check_export_size(grid.dims, n_l)?;
        let n = grid.data.len();
        let lighting = lit.cloud_lighting();
        // Only voxels whose 3×3×3 neighbourhood holds cloud are ever interpolated where there
        // is density: the rest are written as 0 (they compress to nothing).
        let in_mask = |idx: usize| lit.mask.get(idx).copied().unwrap_or(false);
        let sky_paths = if lit.sky_elements.is_some() && lit.env_on {
            lit.lattice
                .iter()
                .map(|p| {
                    p.iter()
                        .enumerate()
                        .map(|(i, &v)| if in_mask(i) { to_half(v) } else { 0.0 })
                        .collect()
                })
                .collect()
        } else {
            Vec::new()
        };
        let sky = match (&lit.sky_elements, lit.env_on) {
            (Some(e), true) => {
                let cells = e.n_elev * e.n_az;
                let mut values = vec![vec![0f32; cells]; SKY_ELEMENTS * n_l];
                for cell in 0..cells {
                    for el in 0..SKY_ELEMENTS {
                        for l in 0..n_l {
                            values[el * n_l + l][cell] =
                                e.table[(cell * e.elements + el) * n_l + l];
                        }
                    }
                }
                Some(SkyTable {
                    n_elev: e.n_elev,
                    n_az: e.n_az,
                    values,
                })
            }
            _ => None,
        };
        let (ms_order, ms, skin, faces, once) = match &lit.ms {
            Some(f) => {
                let order = f.angular_order();
                let moments = (order + 1) * (order + 1);
                let per = n_l * moments;
                let [nx, ny, _] = grid.dims;
                let mut planes = vec![vec![0f32; n]; per];
                let mut skin_planes = vec![vec![0f32; if f.has_skin() { n } else { 0 }]; per];
                let mut c = vec![0.0; per];
                let mut c_skin = vec![0.0; per];
                let mut face_planes = vec![vec![0f32; n]; per];
                let mut cell_density = vec![0f32; n];
                let once_per = if f.has_once() {
                    n_l * skybake_render::multiple::ONCE_MOMENTS
                } else {
                    0
                };
                let mut once_planes = vec![vec![0f32; n]; once_per];
                let mut k1 = vec![0.0; once_per];
                for idx in (0..n).filter(|&i| in_mask(i)) {
                    let (x, y, z) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
                    let p = grid.voxel_centre(x, y, z);
                    if surface_voxel(&grid.data, grid.dims, [x, y, z]) {
                        f.coefficients(p, &mut c);
                        for (plane, v) in face_planes.iter_mut().zip(&c) {
                            plane[idx] = to_half(*v as f32);
                        }
                        cell_density[idx] = to_half(f.cell_density(p) as f32);
                    }
                    if once_per > 0 {
                        f.once_coefficients(p, &mut k1);
                        let per = skybake_render::multiple::ONCE_MOMENTS;
                        for (i, (plane, v)) in once_planes.iter_mut().zip(&k1).enumerate() {
                            plane[idx] = to_half((lit.ms_albedo[i / per] * v) as f32);
                        }
                    }
                    f.convolved_coefficients(p, &mut c);
                    for l in 0..n_l {
                        for m in 0..moments {
                            planes[l * moments + m][idx] =
                                to_half((lit.ms_albedo[l] * c[l * moments + m]) as f32);
                        }
                    }
                    if f.has_skin() && f.convolved_skin_coefficients(p, &mut c_skin) {
                        for l in 0..n_l {
                            for m in 0..moments {
                                let i = l * moments + m;
                                let cell = planes[i][idx] as f64;
                                skin_planes[i][idx] =
                                    to_half((lit.ms_albedo[l] * c_skin[i] - cell) as f32);
                            }
                        }
                    }
                }
                let skin = f.has_skin().then(|| SkinMoments {
                    depth_scaled_tau: (0..n_l).map(|l| f.skin_depth_tau(l)).collect(),
                    delta: skin_planes,
                });
                let faces = FaceField {
                    cell_size_m: f.cell_m.to_array(),
                    scaled_albedo: lit.ms_albedo.clone(),
                    scaled_phase_moments: f.phase_moments.clone(),
                    cell_density,
                    radiance: face_planes,
                };
                (Some(order), planes, skin, Some(faces), once_planes)
            }
            None => (None, Vec::new(), None, None, Vec::new()),
        };
        let phase = inputs
            .optics
            .phase
            .iter()
            .map(|p| {
                (0..PHASE_NODES)
                    .map(|i| {
                        let x = i as f64 / (PHASE_NODES - 1) as f64;
                        p.eval((PI * x * x).cos()) as f32
                    })
                    .collect()
            })
            .collect();
        let peak = lit.peak.as_ref().map(|p| PeakTable {
            n_theta: peak::N_THETA,
            n_lambda: peak::N_LAMBDA,
            lambda_max: peak::LAMBDA_MAX,
            values: (0..n_l).map(|l| p.table(l).to_vec()).collect(),
            last_in_peak: (0..n_l).map(|l| p.peak_table(l).to_vec()).collect(),
        });
        let s = lighting.sun_dir.normalize();
        let photons = settings.photons;
        Ok(Self {
            dims: grid.dims,
            origin_m: grid.origin_m.to_array(),
            voxel_size_m: grid.voxel_size_m,
            wavelengths_nm: inputs.wavelengths_nm.clone(),
            extinction_per_density_m: inputs.optics.extinction_per_density_m.clone(),
            albedo: inputs.optics.albedo.clone(),
            extinction_scale: lit.ms_extinction_scale.clone(),
            peak_rate: lit.peak_rate.clone(),
            first_extinction_scale: lit.first_extinction_scale.clone(),
            sun_direction: s.to_array(),
            sun_irradiance: if lit.sun_on {
                lighting.sun_irradiance.clone()
            } else {
                vec![0.0; n_l]
            },
            step_voxels: settings.step_voxels,
            density: grid.data.clone(),
            sun_path: lit.d_sun.clone(),
            sky_paths,
            ms_order,
            ms,
            skin,
            faces,
            once,
            sky,
            phase,
            peak,
            settings: json!({
                "scene": scene_name,
                "method": "fast",
                "multiple_scattering_method": "all_orders",
                // The photons the pass traced: a scene whose sun gives no light spends the
                // sun's share on the environment (`PhotonSettings::env_photons`).
                "sun_photons": if lit.sun_on { photons.sun_photons } else { 0 },
                "env_photons": if lit.sun_on {
                    photons.env_photons
                } else {
                    photons.env_photons.saturating_add(photons.sun_photons)
                },
                "coarse_grid_max_dim": photons.max_coarse_dim,
                "angular_order": photons.angular_order,
                "truncation_power": photons.truncation_power,
                "peak_spread": photons.peak_spread,
                "seed": photons.seed,
                "sky_quadrature": settings.sky_quadrature,
                "sky_table": settings.sky_table,
                "step_voxels": settings.step_voxels,
                "engine_version": ENGINE_VERSION,
            }),
        })
    }

    /// Per-wavelength channel name of `layer`.
    fn channel(layer: &str, nm: f64) -> String {
        spectral_channel_name(layer, nm)
    }

    /// One channel per (wavelength l, moment m) of `planes` (index l · `moments` + m), named
    /// `{prefix}{m:02}` per wavelength ([`Self::channel`]).
    fn moment_channels<'a>(
        &self,
        prefix: &str,
        planes: &'a [Vec<f32>],
        moments: usize,
    ) -> Vec<(String, &'a [f32])> {
        (0..self.n_l())
            .flat_map(|l| (0..moments).map(move |m| (l, m)))
            .map(|(l, m)| {
                (
                    Self::channel(&format!("{prefix}{m:02}"), self.wavelengths_nm[l]),
                    planes[l * moments + m].as_slice(),
                )
            })
            .collect()
    }

    /// The files of the export: (name, bytes), the manifest last.
    pub fn files(&self) -> Result<Vec<(&'static str, Vec<u8>)>> {
        let [nx, ny, nz] = self.dims;
        let n_l = self.n_l();
        let enc = |width: usize, height: usize, channels: Vec<(String, &[f32])>, half: bool| {
            encode_texture_exr(TextureImage {
                width,
                height,
                channels: channels
                    .iter()
                    .map(|(n, v)| (n.as_str(), v.to_vec()))
                    .collect(),
                half,
            })
            .map_err(|e| Error::internal("cloud_light", e))
        };
        let mut files = vec![
            (
                DENSITY_FILE,
                enc(nx, ny * nz, vec![("density".into(), &self.density)], false)?,
            ),
            (
                SUN_PATH_FILE,
                enc(nx, ny * nz, vec![("D_sun".into(), &self.sun_path)], false)?,
            ),
        ];
        if !self.sky_paths.is_empty() {
            let ch = self
                .sky_paths
                .iter()
                .enumerate()
                .map(|(e, v)| (format!("D_{e:02}"), v.as_slice()))
                .collect();
            files.push((SKY_PATHS_FILE, enc(nx, ny * nz, ch, true)?));
        }
        if let Some(order) = self.ms_order {
            let moments = (order + 1) * (order + 1);
            let moment_channels =
                |prefix: &str, planes| self.moment_channels(prefix, planes, moments);
            files.push((
                MS_FILE,
                enc(nx, ny * nz, moment_channels("C", &self.ms), true)?,
            ));
            if let Some(skin) = &self.skin {
                let ch = moment_channels("dC", &skin.delta);
                files.push((SKIN_FILE, enc(nx, ny * nz, ch, true)?));
            }
            if let Some(faces) = &self.faces {
                let mut ch = vec![("rho_cell".to_string(), faces.cell_density.as_slice())];
                ch.extend(moment_channels("L", &faces.radiance));
                files.push((FACES_FILE, enc(nx, ny * nz, ch, true)?));
            }
            if !self.once.is_empty() {
                let ch =
                    self.moment_channels("K", &self.once, skybake_render::multiple::ONCE_MOMENTS);
                files.push((ONCE_FILE, enc(nx, ny * nz, ch, true)?));
            }
        }
        if let Some(sky) = &self.sky {
            let mut ch = Vec::new();
            for e in 0..SKY_ELEMENTS {
                for l in 0..n_l {
                    ch.push((
                        Self::channel(&format!("E{e:02}"), self.wavelengths_nm[l]),
                        sky.values[e * n_l + l].as_slice(),
                    ));
                }
            }
            files.push((SKY_ELEMENTS_FILE, enc(sky.n_az, sky.n_elev, ch, false)?));
        }
        let ch = (0..n_l)
            .map(|l| {
                (
                    Self::channel("phase", self.wavelengths_nm[l]),
                    self.phase[l].as_slice(),
                )
            })
            .collect();
        files.push((PHASE_FILE, enc(PHASE_NODES, 1, ch, false)?));
        if let Some(p) = &self.peak {
            let ch = (0..n_l)
                .map(|l| {
                    (
                        Self::channel("peak", self.wavelengths_nm[l]),
                        p.values[l].as_slice(),
                    )
                })
                .chain((0..n_l).map(|l| {
                    (
                        Self::channel("peak_last", self.wavelengths_nm[l]),
                        p.last_in_peak[l].as_slice(),
                    )
                }))
                .collect();
            files.push((PEAK_FILE, enc(p.n_lambda, p.n_theta, ch, false)?));
        }
        let text = serde_json::to_string_pretty(&self.manifest(&files))
            .map_err(|e| Error::internal("cloud_light", e))?;
        files.push((MANIFEST_FILE, text.into_bytes()));
        Ok(files)
    }

    /// `manifest.json`: everything a client needs without reading our code.
    pub fn manifest(&self, files: &[(&str, Vec<u8>)]) -> Value {
        let [nx, ny, nz] = self.dims;
        let n_l = self.n_l();
        let o = self.origin_m;
        let h = self.voxel_size_m;
        let volume = |file: &str, channels: Value, content: &str, unit: &str, half: bool| {
            json!({
                "file": file,
                "layout": "3-D texture: z-slices stacked vertically (file row k·ny + j holds voxels (·, j, k)), ZIP",
                "sample": if half { "half" } else { "float" },
                "width": nx, "height": ny * nz, "depth": nz,
                "channels": channels, "content": content, "unit": unit,
            })
        };
        let spectral = |layer: &str| -> Vec<String> {
            self.wavelengths_nm
                .iter()
                .map(|w| Self::channel(layer, *w))
                .collect()
        };
        let mut textures = serde_json::Map::new();
        textures.insert(
            "density".into(),
            volume(
                DENSITY_FILE,
                json!(["density"]),
                "density rho at voxel centres; extinction sigma_t = extinction_per_density_m[λ]·rho",
                "1",
                false,
            ),
        );
        textures.insert(
            "sun_path".into(),
            volume(
                SUN_PATH_FILE,
                json!(["D_sun"]),
                "density integral from the voxel centre towards the sun to the box's face: the sun's transmittance is exp(-k·s·D_sun) (scaled) or exp(-k·D_sun) (true); between the outermost voxel centres and the box's faces continued linearly from the two outermost centres along each axis that lies beyond them (not below 0), not held (march.sun_path_beyond_edge_centres)",
                "m",
                false,
            ),
        );
        if !self.sky_paths.is_empty() {
            textures.insert(
                "sky_paths".into(),
                volume(
                    SKY_PATHS_FILE,
                    json!((0..self.sky_paths.len()).map(|e| format!("D_{e:02}")).collect::<Vec<_>>()),
                    "density integrals from the voxel centre along lattice direction e (lattice_directions[e]) to the box's face (0 where no voxel of the 3×3×3 neighbourhood holds cloud)",
                    "m",
                    true,
                ),
            );
        }
        if let Some(order) = self.ms_order {
            let moments = (order + 1) * (order + 1);
            let names: Vec<String> = (0..moments)
                .flat_map(|m| spectral(&format!("C{m:02}")))
                .collect();
            textures.insert(
                "multiple_scattering".into(),
                volume(
                    MS_FILE,
                    json!(names),
                    "C_lm = omega*·p*_l·L_lm: the all-order field's real spherical-harmonic radiance moments L_lm (index lm = l² + l + m), convolved with the delta-M scaled phase function's Legendre moments p*_l and multiplied by the scaled albedo omega* (0 where no voxel of the 3×3×3 neighbourhood holds cloud)",
                    "W m-2 nm-1",
                    true,
                ),
            );
            if self.skin.is_some() {
                let names: Vec<String> = (0..moments)
                    .flat_map(|m| spectral(&format!("dC{m:02}")))
                    .collect();
                textures.insert(
                    "multiple_scattering_skin".into(),
                    volume(
                        SKIN_FILE,
                        json!(names),
                        "dC_lm = C_skin,lm - C_lm: the moments of the field in the skin of optically thick cells (the first skin.depth_scaled_optical_depth[λ] below a face that borders thinner cloud or the grid's edge, tallied on its own) minus the multiple_scattering texture's, as C_lm; 0 where no cell round the voxel has a skin. Used by thick steps only (march.thick_steps): the source in a sub-step's part within the skin's depth of the ray's scaled optical depth is omega/s·Σ_e E_e(d)·exp(-k·s·D_e) + max(0, Σ (C_lm + dC_lm)·Y_lm(-d))",
                        "W m-2 nm-1",
                        true,
                    ),
                );
            }
            if self.faces.is_some() {
                let names: Vec<String> = std::iter::once("rho_cell".to_string())
                    .chain((0..moments).flat_map(|m| spectral(&format!("L{m:02}"))))
                    .collect();
                textures.insert(
                    "multiple_scattering_faces".into(),
                    volume(
                        FACES_FILE,
                        json!(names),
                        "at surface voxels (density > 0 with a face neighbour of density <= 0 or on the grid's edge; 0 elsewhere): rho_cell, the mean density of the field's coarse cell holding the voxel's centre (faces.cell_size_m its edges), and L_lm, the field's radiance moments not convolved (C_lm = omega*·p*_l·L_lm, faces.scaled_albedo and faces.scaled_phase_moments). Used to see the field through the face (march.faces)",
                        "1 (rho_cell), W m-2 nm-1 (L_lm)",
                        true,
                    ),
                );
            }
            if !self.once.is_empty() {
                let names: Vec<String> = (0..skybake_render::multiple::ONCE_MOMENTS)
                    .flat_map(|m| spectral(&format!("K{m:02}")))
                    .collect();
                textures.insert(
                    "once_scattered".into(),
                    volume(
                        ONCE_FILE,
                        json!(names),
                        "K_lm = omega*·(k_l·E_sun·L1_lm - p*_l·L1*_lm), k_l = (p*_l + kappa_l)/2 with kappa_l the Legendre moments of p - r+ per 1 - f: the sun's once-scattered light L1 (transported in the true medium, every collision classed as within the truncated peak r+ = max(p - (1 - f)·HG(g*), 0) or smooth; tallied after exactly one smooth scattering) in real spherical harmonics to the field's order per unit sun irradiance times E_sun, less the field's own once-scattered light L1* (its sun photons' tracks between their first and second scattering, which C_lm hold, convolved with the scaled phase moments p*_l); 0 in coarse cells without cloud. Where a voxel is not seen through a face (see faces), its source towards a viewer looking along d adds Σ K_lm·Y_lm(-d) to the field's (kept ≥ 0); at voxels seen through a face, and in the skins, the field's alone",
                        "W m-2 nm-1",
                        true,
                    ),
                );
            }
        }
        if let Some(sky) = &self.sky {
            let names: Vec<String> = (0..SKY_ELEMENTS)
                .flat_map(|e| spectral(&format!("E{e:02}")))
                .collect();
            textures.insert(
                "sky_elements".into(),
                json!({
                    "file": SKY_ELEMENTS_FILE,
                    "sample": "float",
                    "layout": "2-D latitude-longitude table: row r at elevation -90° + 180°·r/(height-1), column c at azimuth 360°·c/width (from +y towards +x, wraps); bilinear, elevation clamped",
                    "width": sky.n_az, "height": sky.n_elev,
                    "channels": names,
                    "content": "per view direction d (camera → point): E00 the phase-weighted sky radiance ∫p(d·ω)L(ω)dω over the sun cap, E01–E14 over the lattice elements (nearest lattice direction), E15 the view cap's δ-M share, E16 the environment radiance L(d) itself",
                    "unit": "W m-2 nm-1 (E00-E15), W m-2 sr-1 nm-1 (E16)",
                }),
            );
        }
        textures.insert(
            "phase".into(),
            json!({
                "file": PHASE_FILE,
                "sample": "float",
                "layout": format!("1 row of {PHASE_NODES} nodes: node i at scattering angle theta = pi·(i/{})², linear in sqrt(theta/pi)", PHASE_NODES - 1),
                "width": PHASE_NODES, "height": 1,
                "channels": spectral("phase"),
                "content": "the true phase function p(cos theta), normalised to 1 over the sphere",
                "unit": "sr-1",
            }),
        );
        if let Some(p) = &self.peak {
            let peak_channels = [spectral("peak"), spectral("peak_last")].concat();
            textures.insert(
                "peak_spread".into(),
                json!({
                    "file": PEAK_FILE,
                    "sample": "float",
                    "layout": format!("row r at scattering angle 180°·r/{}, column c at lambda = {}·c/{}; bilinear, lambda held beyond the last column", p.n_theta - 1, p.lambda_max, p.n_lambda - 1),
                    "width": p.n_lambda, "height": p.n_theta,
                    "channels": peak_channels,
                    "content": "peak: p_eff/p, the sun's single-scattering phase function spread by the delta-M truncated peak (Goudsmit & Saunderson 1940), at lambda = peak_rate[λ]·k[λ]·D_sun; peak_last: the part of it scattered last within the peak (seen through the true extinction, the rest through the scaled one)",
                    "unit": "1",
                }),
            );
        }
        let listed: Vec<Value> = files
            .iter()
            .map(|(n, b)| json!({"file": n, "bytes": b.len()}))
            .collect();
        json!({
            "product": "cloud_light",
            "layout_version": LAYOUT_VERSION,
            "world": "metres, right-handed, z up (altitude above sea level); azimuths from +y towards +x",
            "grid": {
                "dims": self.dims,
                "origin_m": o,
                "max_corner_m": [o[0] + nx as f64 * h, o[1] + ny as f64 * h, o[2] + nz as f64 * h],
                "voxel_size_m": h,
                "voxel_to_world": "centre of voxel (i, j, k) = origin_m + voxel_size_m·(i + 0.5, j + 0.5, k + 0.5); trilinear between centres, clamped to the outermost centres inside the box (D_sun: continued beyond them, march.sun_path_beyond_edge_centres), nothing outside it",
            },
            "wavelengths_nm": self.wavelengths_nm,
            "per_wavelength": {
                "extinction_per_density_m": self.extinction_per_density_m,
                "single_scattering_albedo": self.albedo,
                "extinction_scale": self.extinction_scale,
                "peak_rate": self.peak_rate,
                "first_extinction_scale": self.first_extinction_scale,
                "sun_irradiance_w_m2_nm": self.sun_irradiance,
            },
            "sun": {"direction": self.sun_direction, "to": "from the cloud towards the sun (unit)"},
            "sky_caps": {"sun_cap_deg": SUN_CAP_DEG, "view_cap_deg": VIEW_CAP_DEG},
            "lattice_directions": LATTICE,
            "spherical_harmonics": "real, orthonormal, lm = l² + l + m (m = -l..l): Y00 = 0.28209479; Y1-1 = 0.48860251·y, Y10 = 0.48860251·z, Y11 = 0.48860251·x; Y2-2 = 1.09254843·xy, Y2-1 = 1.09254843·yz, Y20 = 0.31539157·(3z²-1), Y21 = 1.09254843·xz, Y22 = 0.54627422·(x²-y²); Y3-3 = 0.59004359·y(3x²-y²), Y3-2 = 2.89061144·xyz, Y3-1 = 0.45704580·y(5z²-1), Y30 = 0.37317633·z(5z²-3), Y31 = 0.45704580·x(5z²-1), Y32 = 1.44530572·z(x²-y²), Y33 = 0.59004359·x(x²-3y²) (Sloan 2008, appendix A2)",
            "faces": self.faces.as_ref().map(|f| json!({
                "cell_size_m": f.cell_size_m,
                "scaled_albedo": f.scaled_albedo,
                "scaled_phase_moments": f.scaled_phase_moments,
                "texture": "multiple_scattering_faces",
            })),
            "skin": self.skin.as_ref().map(|sk| json!({
                "depth_scaled_optical_depth": sk.depth_scaled_tau,
                "texture": "multiple_scattering_skin",
            })),
            "march": {
                "step_voxels": self.step_voxels,
                "cutoff_scaled_transmittance": MARCH_CUTOFF,
                "sun_path_beyond_edge_centres": "D_sun(p) = D(p) + Σ_a e_a·(D(p) - D(p + i_a·(e_a + 1)·h·x_a)) over the axes a along which p lies beyond the outermost voxel centres (e_a voxels beyond, i_a = ±1 inwards, D trilinear and clamped as the other textures), not below 0",
                "thick_steps": {
                    "scaled_optical_depth": THICK_STEP,
                    "max_sub_steps": MAX_SUB_STEPS,
                    "sun_path_near_voxels": SUN_NEAR_VOXELS,
                    "sun_path_near_intervals": SUN_NEAR_INTERVALS,
                    "recipe": "docs/cloud-light.md, 'Thick steps': a step whose densest of the 8 voxels round its midpoint holds max_λ(k·s)·rho·dt > scaled_optical_depth is taken in n = clamp(ceil(that), 2, max_sub_steps) sub-steps, each with the density-weighted interpolation of the textures (weights w_i·rho_i/Σ w_i·rho_i), the sun's path integrated from the density over sun_path_near_voxels towards the sun (composite Simpson, sun_path_near_intervals) plus D_sun beyond, and the skin's source over the first skin.depth_scaled_optical_depth of the ray's scaled optical depth",
                },
                "faces": "docs/cloud-light.md, 'Faces': per camera, at each surface voxel whose face neighbour towards the viewer is empty (of several, the face the view crosses most squarely), the field's source is lowered by omega*·(max(0, J) - max(0, J - Δ)), J = Σ p*_l·L_lm·Y_lm(-d), Δ the inward hemisphere's radiance weighted by the scaled phase function and by 1 - r(μ'), r the view-weighted build-up below the face over the cell's mean (8-point Gauss-Legendre in μ' × 16 azimuths), and in voxels under 1 scaled optical depth the outward hemisphere's radiance weighted by 1 - r_out(μ'), r_out the diffusion (Milne) profile at the view's mean depth over the cell's; the lowering is interpolated trilinearly as the textures and subtracted from S(d) outside the skin's depth",
                "source": "docs/cloud-light.md, 'Marching the volume': per step of length dt at density rho (midpoint), k = extinction_per_density_m, s = extinction_scale: a = 1-exp(-k·rho·dt) (true), a* = 1-exp(-k·s·rho·dt) (scaled); I += T*·a*·S(d) + T+·omega/s+·E_sun·p(theta)·W_sun·(spread - spread_last) + T_c·(the peak's part); T_c *= 1-a; T* *= 1-a*; T+ *= 1-exp(-k·s+·rho·dt) (s+ = first_extinction_scale; spread at the sun's and the view's true optical depths together, spread_last at the sun's), with S(d) = omega/s·Σ_e E_e(d)·exp(-k·s+·D_e) + max(0, Σ C_lm·Y_lm(-d)) (D_0 = D_sun, D_1..14 = the sky paths) and W_sun the exact step integral of the sun's scaled transmittance; then the view cap; pixel = I + T_c·background",
            },
            "settings": self.settings,
            "textures": textures,
            "files": listed,
            "n_wavelengths": n_l,
        })
    }

    /// Decodes an export from its files (`read` returns a file's bytes by name), checking the
    /// manifest, every texture's size and channels; an error names the file and what is wrong.
    pub fn from_files(read: &dyn Fn(&str) -> Result<Vec<u8>>) -> Result<Self> {
        let text = read(MANIFEST_FILE)?;
        if text.len() > MAX_MANIFEST_BYTES {
            return Err(Error::too_large(
                MANIFEST_FILE,
                format!("{} bytes", text.len()),
                format!("{MAX_MANIFEST_BYTES} bytes"),
            ));
        }
        let m: Value = serde_json::from_slice(&text)
            .map_err(|e| Error::invalid(MANIFEST_FILE, format!("not JSON: {e}")))?;
        let bad = |field: &str, why: &str| {
            Error::invalid(&format!("{MANIFEST_FILE}.{field}"), why.to_string())
        };
        if m["product"] != "cloud_light" {
            return Err(bad("product", "must be \"cloud_light\""));
        }
        if m["layout_version"] != LAYOUT_VERSION {
            return Err(bad(
                "layout_version",
                &format!(
                    "{} is not the version this reader knows ({LAYOUT_VERSION})",
                    m["layout_version"]
                ),
            ));
        }
        let nums = |v: &Value, field: &str| -> Result<Vec<f64>> {
            v.as_array()
                .ok_or_else(|| bad(field, "must be an array of numbers"))?
                .iter()
                .map(|x| {
                    x.as_f64()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| bad(field, "must be an array of finite numbers"))
                })
                .collect()
        };
        let dims_f = nums(&m["grid"]["dims"], "grid.dims")?;
        if dims_f.len() != 3
            || dims_f
                .iter()
                .any(|&d| !(1.0..=4096.0).contains(&d) || d.fract() != 0.0)
        {
            return Err(bad("grid.dims", "must be 3 whole numbers in 1 to 4096"));
        }
        let dims = [dims_f[0] as usize, dims_f[1] as usize, dims_f[2] as usize];
        let voxels = dims[0] * dims[1] * dims[2];
        if voxels > skybake_render::MAX_RENDER_VOXELS {
            return Err(Error::too_large(
                &format!("{MANIFEST_FILE}.grid.dims"),
                format!("{dims:?} = {voxels} voxels"),
                format!("{} voxels", skybake_render::MAX_RENDER_VOXELS),
            ));
        }
        let origin = nums(&m["grid"]["origin_m"], "grid.origin_m")?;
        if origin.len() != 3 {
            return Err(bad("grid.origin_m", "must be 3 numbers"));
        }
        let h = m["grid"]["voxel_size_m"]
            .as_f64()
            .filter(|h| h.is_finite() && *h > 0.0)
            .ok_or_else(|| bad("grid.voxel_size_m", "must be a positive number"))?;
        let wl = nums(&m["wavelengths_nm"], "wavelengths_nm")?;
        if wl.is_empty() || wl.len() > 64 {
            return Err(bad("wavelengths_nm", "must hold 1 to 64 wavelengths"));
        }
        let n_l = wl.len();
        if export_bytes(voxels, n_l) > MAX_EXPORT_BYTES {
            return Err(Error::too_large(
                &format!("{MANIFEST_FILE}.grid.dims"),
                format!("{dims:?} voxels at {n_l} wavelengths"),
                format!("{} MiB in memory", MAX_EXPORT_BYTES >> 20),
            ));
        }
        let pw = &m["per_wavelength"];
        let per = |name: &str| -> Result<Vec<f64>> {
            let v = nums(&pw[name], &format!("per_wavelength.{name}"))?;
            if v.len() != n_l {
                return Err(bad(
                    &format!("per_wavelength.{name}"),
                    &format!("must hold {n_l} values (one per wavelength)"),
                ));
            }
            Ok(v)
        };
        let sun = nums(&m["sun"]["direction"], "sun.direction")?;
        if sun.len() != 3 || (DVec3::from_slice(&sun).length() - 1.0).abs() > 1e-3 {
            return Err(bad("sun.direction", "must be a unit vector of 3 numbers"));
        }
        let step_voxels = m["march"]["step_voxels"]
            .as_f64()
            .filter(|s| (0.05..=4.0).contains(s))
            .ok_or_else(|| bad("march.step_voxels", "must be a number in 0.05 to 4"))?;
        let textures = &m["textures"];
        // A texture's channels by name, checked against its stated size.
        let load = |key: &str,
                    width: usize,
                    height: usize,
                    names: &[String]|
         -> Result<Option<Vec<Vec<f32>>>> {
            let entry = &textures[key];
            if entry.is_null() {
                return Ok(None);
            }
            let file = entry["file"]
                .as_str()
                .ok_or_else(|| bad(&format!("textures.{key}.file"), "must be a file name"))?;
            if file.contains('/') || file.contains('\\') || file.starts_with('.') {
                return Err(bad(
                    &format!("textures.{key}.file"),
                    "must be a plain file name in the export's directory",
                ));
            }
            let bytes = read(file)?;
            let (w, hgt, channels) = decode_texture_exr(&bytes)
                .map_err(|e| Error::invalid(file, format!("not a readable texture: {e}")))?;
            if (w, hgt) != (width, height) {
                return Err(Error::invalid(
                    file,
                    format!("{w}×{hgt} texels where the manifest needs {width}×{height}"),
                ));
            }
            names
                .iter()
                .map(|n| {
                    channels
                        .iter()
                        .find(|(c, _)| c == n)
                        .map(|(_, v)| v.clone())
                        .ok_or_else(|| Error::invalid(file, format!("channel {n} is missing")))
                })
                .collect::<Result<Vec<_>>>()
                .map(Some)
        };
        let [nx, ny, nz] = dims;
        let spectral =
            |layer: &str| -> Vec<String> { wl.iter().map(|w| Self::channel(layer, *w)).collect() };
        let missing = |key: &str| bad(&format!("textures.{key}"), "is missing");
        let density = load("density", nx, ny * nz, &["density".to_string()])?
            .ok_or_else(|| missing("density"))?
            .remove(0);
        let sun_path = load("sun_path", nx, ny * nz, &["D_sun".to_string()])?
            .ok_or_else(|| missing("sun_path"))?
            .remove(0);
        let path_names: Vec<String> = (0..LATTICE.len()).map(|e| format!("D_{e:02}")).collect();
        let sky_paths = load("sky_paths", nx, ny * nz, &path_names)?.unwrap_or_default();
        let ms_order = match m["settings"]["angular_order"].as_u64() {
            Some(o) if o <= 4 => o as usize,
            _ => return Err(bad("settings.angular_order", "must be 0 to 4")),
        };
        let moments = (ms_order + 1) * (ms_order + 1);
        let ms_names: Vec<String> = (0..n_l)
            .flat_map(|l| (0..moments).map(move |m| (l, m)))
            .map(|(l, m)| Self::channel(&format!("C{m:02}"), wl[l]))
            .collect();
        let ms = load("multiple_scattering", nx, ny * nz, &ms_names)?;
        let skin_names: Vec<String> = (0..n_l)
            .flat_map(|l| (0..moments).map(move |m| (l, m)))
            .map(|(l, m)| Self::channel(&format!("dC{m:02}"), wl[l]))
            .collect();
        let skin_delta = load("multiple_scattering_skin", nx, ny * nz, &skin_names)?;
        let once_names: Vec<String> = (0..n_l)
            .flat_map(|l| (0..skybake_render::multiple::ONCE_MOMENTS).map(move |m| (l, m)))
            .map(|(l, m)| Self::channel(&format!("K{m:02}"), wl[l]))
            .collect();
        let once = match load("once_scattered", nx, ny * nz, &once_names)? {
            Some(_) if ms.is_none() => {
                return Err(bad(
                    "textures.once_scattered",
                    "needs the multiple_scattering texture",
                ))
            }
            o => o.unwrap_or_default(),
        };
        let face_names: Vec<String> = std::iter::once("rho_cell".to_string())
            .chain(
                (0..n_l)
                    .flat_map(|l| (0..moments).map(move |m| (l, m)))
                    .map(|(l, m)| Self::channel(&format!("L{m:02}"), wl[l])),
            )
            .collect();
        let faces = match load("multiple_scattering_faces", nx, ny * nz, &face_names)? {
            None => None,
            Some(_) if ms.is_none() => {
                return Err(bad(
                    "textures.multiple_scattering_faces",
                    "needs the multiple_scattering texture",
                ))
            }
            Some(mut planes) => {
                let f = &m["faces"];
                let cell = nums(&f["cell_size_m"], "faces.cell_size_m")?;
                if cell.len() != 3 || cell.iter().any(|&c| c <= 0.0) {
                    return Err(bad("faces.cell_size_m", "must be 3 positive numbers"));
                }
                let albedo = nums(&f["scaled_albedo"], "faces.scaled_albedo")?;
                if albedo.len() != n_l {
                    return Err(bad(
                        "faces.scaled_albedo",
                        &format!("must hold {n_l} values (one per wavelength)"),
                    ));
                }
                let moments_of = f["scaled_phase_moments"]
                    .as_array()
                    .filter(|a| a.len() == n_l)
                    .ok_or_else(|| {
                        bad(
                            "faces.scaled_phase_moments",
                            &format!("must hold {n_l} arrays (one per wavelength)"),
                        )
                    })?
                    .iter()
                    .map(|v| {
                        let p = nums(v, "faces.scaled_phase_moments")?;
                        if p.len() != ms_order + 1 {
                            return Err(bad(
                                "faces.scaled_phase_moments",
                                &format!("must hold {} moments per wavelength", ms_order + 1),
                            ));
                        }
                        Ok(p)
                    })
                    .collect::<Result<Vec<_>>>()?;
                let radiance = planes.split_off(1);
                Some(FaceField {
                    cell_size_m: [cell[0], cell[1], cell[2]],
                    scaled_albedo: albedo,
                    scaled_phase_moments: moments_of,
                    cell_density: planes.remove(0),
                    radiance,
                })
            }
        };
        let skin = match skin_delta {
            None => None,
            Some(_) if ms.is_none() => {
                return Err(bad(
                    "textures.multiple_scattering_skin",
                    "needs the multiple_scattering texture",
                ))
            }
            Some(delta) => {
                let depth = nums(
                    &m["skin"]["depth_scaled_optical_depth"],
                    "skin.depth_scaled_optical_depth",
                )?;
                if depth.len() != n_l || depth.iter().any(|&d| d <= 0.0) {
                    return Err(bad(
                        "skin.depth_scaled_optical_depth",
                        &format!("must hold {n_l} positive values (one per wavelength)"),
                    ));
                }
                Some(SkinMoments {
                    depth_scaled_tau: depth,
                    delta,
                })
            }
        };
        let sky = if textures["sky_elements"].is_null() {
            None
        } else {
            let dim = |f: &str| {
                textures["sky_elements"][f]
                    .as_u64()
                    .filter(|v| (4..=4096).contains(v))
                    .map(|v| v as usize)
                    .ok_or_else(|| bad(&format!("textures.sky_elements.{f}"), "must be 4 to 4096"))
            };
            let (w, hgt) = (dim("width")?, dim("height")?);
            let names: Vec<String> = (0..SKY_ELEMENTS)
                .flat_map(|e| (0..n_l).map(move |l| (e, l)))
                .map(|(e, l)| Self::channel(&format!("E{e:02}"), wl[l]))
                .collect();
            load("sky_elements", w, hgt, &names)?.map(|values| SkyTable {
                n_elev: hgt,
                n_az: w,
                values,
            })
        };
        if sky.is_some() != (sky_paths.len() == LATTICE.len()) {
            return Err(bad(
                "textures",
                "sky_paths and sky_elements come together (both or neither)",
            ));
        }
        let phase =
            load("phase", PHASE_NODES, 1, &spectral("phase"))?.ok_or_else(|| missing("phase"))?;
        let peak = load(
            "peak_spread",
            peak::N_LAMBDA,
            peak::N_THETA,
            &[spectral("peak"), spectral("peak_last")].concat(),
        )?
        .map(|mut values| {
            let last_in_peak = values.split_off(n_l);
            PeakTable {
                n_theta: peak::N_THETA,
                n_lambda: peak::N_LAMBDA,
                lambda_max: peak::LAMBDA_MAX,
                values,
                last_in_peak,
            }
        });
        let out = Self {
            dims,
            origin_m: [origin[0], origin[1], origin[2]],
            voxel_size_m: h,
            extinction_per_density_m: per("extinction_per_density_m")?,
            albedo: per("single_scattering_albedo")?,
            extinction_scale: per("extinction_scale")?,
            peak_rate: per("peak_rate")?,
            first_extinction_scale: per("first_extinction_scale")?,
            sun_irradiance: per("sun_irradiance_w_m2_nm")?,
            wavelengths_nm: wl,
            sun_direction: [sun[0], sun[1], sun[2]],
            step_voxels,
            density,
            sun_path,
            sky_paths,
            ms_order: ms.as_ref().map(|_| ms_order),
            ms: ms.unwrap_or_default(),
            skin,
            faces,
            once,
            sky,
            phase,
            peak,
            settings: m["settings"].clone(),
        };
        if out.extinction_scale.iter().any(|&s| !(s > 0.0 && s <= 1.0)) {
            return Err(bad("per_wavelength.extinction_scale", "must be in (0, 1]"));
        }
        if out
            .first_extinction_scale
            .iter()
            .any(|&s| !(s > 0.0 && s <= 1.0))
        {
            return Err(bad(
                "per_wavelength.first_extinction_scale",
                "must be in (0, 1]",
            ));
        }
        Ok(out)
    }
}

/// A pre-lit volume's request: a frame scene (its cloud, optics, sun, sky, ground, wavelengths
/// and quality; the camera is not used) lit by the fast method with every light on (no
/// planner shortcut: a client may look from anywhere).
#[derive(Debug, Clone)]
pub struct CloudLightRequest {
    pub scene: FrameScene,
    /// The scene as given (parsed JSON), for the canonical request.
    pub scene_json: Value,
}

/// The export and what it cost.
pub struct CloudLightOutput {
    pub light: CloudLight,
    /// Stage timings, ms (voxelize, lighting, then the lit volume's stages, export).
    pub timing_ms: Vec<(String, f64)>,
}

impl CloudLightRequest {
    /// The canonical request (a bake's manifest `request`, the cache key's text): the scene as
    /// parsed JSON (object keys sorted) and the layout version.
    pub fn canonical(&self) -> Value {
        json!({
            "product": "cloud_light",
            "scene": self.scene_json,
            "layout_version": LAYOUT_VERSION,
        })
    }

    pub fn cache_key(&self) -> String {
        skybake_physics::key::cache_key(&self.canonical().to_string(), ENGINE_VERSION)
    }

    /// Parses a frame scene (the scene file's JSON).
    pub fn parse(scene_json: &[u8]) -> Result<Self> {
        if scene_json.len() > MAX_SCENE_FILE_BYTES {
            return Err(Error::too_large(
                "scene",
                format!("{} bytes", scene_json.len()),
                format!("{MAX_SCENE_FILE_BYTES} bytes"),
            ));
        }
        let scene = FrameScene::parse(scene_json)?;
        let scene_json: Value = serde_json::from_slice(scene_json)
            .map_err(|e| Error::invalid("scene", format!("not JSON: {e}")))?;
        if scene.multiple_scattering_method == CloudMsMethod::ReferencePattern {
            return Err(Error::invalid(
                "multiple_scattering_method",
                "the reference pattern is computed per camera; a pre-lit volume needs \"all_orders\"",
            ));
        }
        Ok(Self { scene, scene_json })
    }

    /// The fast method's settings for the scene (its quality), every light kept.
    pub fn settings(&self) -> RenderSettings {
        RenderSettings::for_quality(self.scene.quality, Method::Fast)
    }

    /// Voxelises the cloud, gets the light from outside it (the engine's products or vacuum),
    /// lights it and builds the export. `loader` reads the files the scene names.
    pub fn compute(
        &self,
        engine: &Engine,
        loader: &dyn Fn(&str) -> Result<Vec<u8>>,
        cancel: &(dyn Fn() -> bool + Sync),
    ) -> Result<CloudLightOutput> {
        let mut timing_ms = Vec::new();
        let mut clock = Instant::now();
        let grid = Arc::new(self.scene.cloud.voxelize_unless(
            loader,
            skybake_render::MAX_RENDER_VOXELS,
            cancel,
        )?);
        skybake_render::check_grid(&grid)?;
        check_export_size(grid.dims, self.scene.wavelengths.len())?;
        timing_ms.push(("voxelize".to_string(), clock.elapsed().as_secs_f64() * 1e3));
        clock = Instant::now();
        let lighting = skybake_render::lighting_for_unless(&self.scene, &grid, engine, cancel)?;
        timing_ms.push(("lighting".to_string(), clock.elapsed().as_secs_f64() * 1e3));
        let inputs = LitInputs::new(&self.scene, grid, &lighting, self.settings());
        let lit = LitVolume::new(inputs, cancel)?;
        timing_ms.extend(lit.timing_ms.iter().cloned());
        clock = Instant::now();
        let light = CloudLight::from_lit(&lit, self.scene.name.as_deref())?;
        timing_ms.push(("export".to_string(), clock.elapsed().as_secs_f64() * 1e3));
        Ok(CloudLightOutput { light, timing_ms })
    }
}
