//! Lit cloud frames (Nishita et al. 1996, §3; Dobashi et al. 2000, §5): the `frame` product's renderer.
//!
//! Nothing below this module imports it. It is pure: it receives a validated [`FrameScene`], the
//! cloud's [`DensityGrid`] and the [`Lighting`] (built from the engine's `sun`, `sky`, `ground`
//! and `aerial` products by [`Lighting::from_scene`], or without an atmosphere), and returns a
//! [`Frame`] of spectral radiance (W m⁻² sr⁻¹ nm⁻¹ per pixel and wavelength) for the whole image
//! or any tile of it.
//!
//! - `scene`: the scene JSON and its validation; `camera`: primary rays.
//! - `lighting`: the light from outside the cloud (engine adapter, vacuum, constant sky).
//! - `volume`: the density grid as a medium; `light`: per-voxel sun and sky-element paths.
//! - `multiple`: the all-order multiple-scattering field; `peak`: the δ-M truncated peak spread over the
//!   sun's scaled beam (its single scattering); `pattern`: orders 2 and 3 by the reference pattern of
//!   Nishita et al. 1996, §3.4; `pathtracer`: the reference.
//! - `march`: the fast method's preparation and final ray march, compositing, shafts.
//!
//! ```no_run
//! # use skybake_render::{self as render, FrameScene, RenderSettings, Method, Lighting};
//! # let json = std::fs::read("config/scenes/cumulus-frame.json").unwrap();
//! let scene = FrameScene::parse(&json)?;
//! let grid = scene.cloud.voxelize(&|_| Err(skybake_render::Error::invalid("path", "no files")))?;
//! let lighting = render::lighting_for(&scene, &grid, &skybake_engine::engine::Engine::new())?;
//! let settings = RenderSettings::for_quality(scene.quality, Method::Fast);
//! let frame = render::render_frame(&scene, &grid, &lighting, &settings, None, &|_| {}, &|| false)?;
//! # Ok::<(), skybake_render::Error>(())
//! ```

// Numeric kernels index several parallel per-wavelength arrays in one loop; an index is clearer.
#![allow(clippy::needless_range_loop)]

pub mod camera;
pub mod compare;
pub mod light;
pub mod lighting;
pub mod lighting_memo;
pub mod lit;
pub mod march;
pub mod multiple;
mod pages;
pub mod pathtracer;
pub mod pattern;
pub mod peak;
pub mod rgb_only;
pub mod scene;
pub mod volume;

pub use lighting::Lighting;
pub use lighting_memo::LightingMemo;
pub use lit::{LitInputs, LitVolume};
pub use march::Prepared;
pub use multiple::PhotonSettings;
pub use pattern::PatternSettings;
pub use scene::{CloudMsMethod, FrameScene};

use rayon::prelude::*;
use serde::Serialize;
use skybake_engine::engine::{Engine, Stages};
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::cloud::DensityGrid;
pub use skybake_physics::{Error, Result};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// Largest grid the renderer accepts, voxels (its per-voxel light needs 14 density-integral
/// grids and 1 + n_λ values per voxel: about 0.7 GiB at this size with 3 wavelengths).
pub const MAX_RENDER_VOXELS: usize = 1 << 23;

/// δ-M truncation f = g₁^p of the multiple-scattering field (see `multiple`). p = 2 (δ-Eddington)
/// truncates too much for views towards the light (Mitsuba sky case +34 %, bench cumulus +18 %),
/// p ≥ 4 too little for side-lit thin clouds (−9 %); 3.5 with the P2 reconstruction balances the
/// measured cases (README, "Cloud frames").
pub const TRUNCATION_POWER: f64 = 3.5;

/// Strength of the spread of the truncated peak over the scaled sun beam (`peak`): the peak's
/// scattering rate is taken as this fraction of ωf⁺ (0: TMS with a collimated scaled beam; 1:
/// the Goudsmit & Saunderson (1940) rate itself). With the light scattered last within the
/// peak seen through the true extinction (`march::Prepared::march`), the full rate holds the
/// Mitsuba 3 cases (docs/frames.md); before that split, TMS counted that light once per peak
/// scattering and only 0.3 of the rate balanced it on back-lit clouds.
pub const PEAK_SPREAD: f64 = 1.0;

/// Rendering method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Per-voxel light + all-order multiple-scattering field + ray march.
    Fast,
    /// The path tracer.
    Reference,
}

impl Method {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "fast" => Ok(Self::Fast),
            "reference" => Ok(Self::Reference),
            _ => Err(Error::invalid(
                "method",
                format!("'{s}' is not one of fast, reference"),
            )),
        }
    }
}

/// Settings of a render (derived from the quality preset; every field may be overridden).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    pub method: Method,
    /// Ray-march step, voxels.
    pub step_voxels: f64,
    /// Multiple-scattering photon pass.
    pub photons: PhotonSettings,
    /// Quadrature directions for the sky elements.
    pub sky_quadrature: usize,
    /// View-direction table of the sky elements (elevations, azimuths).
    pub sky_table: [usize; 2],
    /// Path-tracer samples per pixel.
    pub spp: usize,
    /// Shaft-of-light samples per ray.
    pub shaft_steps: usize,
    /// Seed of every random stream.
    pub seed: u64,
    /// Path tracer: scattering orders counted (`usize::MAX`: all), for measuring orders.
    pub max_orders: usize,
    /// Path tracer: lowest scattering order counted (0: all, including the unscattered
    /// background; 2 with `max_orders` 3 renders orders 2 and 3 only).
    pub min_orders: usize,
    /// Reference pattern of the scene's `"multiple_scattering_method": "reference_pattern"`.
    pub pattern: PatternSettings,
    /// The planner's hooks (`plan::plan_frame`, executed by `product::FrameRequest`): the fast
    /// method's per-voxel light runs only when some pixel sees the cloud, and sky or ground light
    /// reach the cloud only when the plan keeps them (the background is unchanged).
    pub cloud_in_view: bool,
    pub sky_light: bool,
    pub ground_light: bool,
}

impl RenderSettings {
    pub fn for_quality(q: Quality, method: Method) -> Self {
        let (step, sun, env, coarse, quad, table, spp) = match q {
            // Steps are integrated exactly for a density constant over the step; one voxel
            // changes the bench frame by < 0.1 % against half a voxel (measured).
            Quality::Draft => (1.5, 1 << 16, 1 << 15, 24, 1024, [24, 48], 16),
            // Sky light photons as many as sun photons: with 2^16 the sky term's photon noise
            // shifted the Mitsuba sky frame's mean by ±7 % between random streams (measured).
            Quality::Standard => (1.0, 1 << 18, 1 << 18, 32, 2048, [32, 64], 64),
            Quality::High => (0.5, 1 << 20, 1 << 18, 48, 4096, [48, 96], 256),
            Quality::Reference => (0.25, 1 << 22, 1 << 20, 64, 8192, [64, 128], 1024),
        };
        Self {
            method,
            step_voxels: step,
            photons: PhotonSettings {
                sun_photons: sun,
                env_photons: env,
                max_coarse_dim: coarse,
                transport_cells: true,
                seed: 0x5EED,
                // Order 3: every non-zero Legendre moment of the δ-M scaled phase function.
                // Its moments (g^l − f)/(1 − f) (Wiscombe 1977) with f = g^3.5 are negative from
                // l = 4 on (g^4 < g^3.5) and clamped to 0, so order 3 reconstructs J* from all
                // of them and order 2 dropped the l = 3 one (g 0.85: 0.11). That term carries
                // the side-scattered orders 2–3 of thin clouds: P2 read the side-lit thin Mitsuba
                // cloud (`sun_thin`) 3.5 % low over 4 photon seeds, P3 0.05 % (block NRMSE 7.2 →
                // 4.2 %); the thick cases stay within their seeds' spread (docs/frames.md).
                angular_order: 3,
                truncation_power: TRUNCATION_POWER,
                peak_spread: PEAK_SPREAD,
            },
            sky_quadrature: quad,
            sky_table: table,
            spp,
            shaft_steps: 16,
            seed: 0x5EED,
            max_orders: usize::MAX,
            min_orders: 0,
            pattern: PatternSettings::for_quality(q),
            cloud_in_view: true,
            sky_light: true,
            ground_light: true,
        }
    }

    fn validate(&self) -> Result<()> {
        if !(self.step_voxels.is_finite() && (0.05..=4.0).contains(&self.step_voxels)) {
            return Err(Error::out_of_range(
                "step_voxels",
                self.step_voxels,
                "0.05 to 4",
            ));
        }
        if !(1..=1 << 16).contains(&self.spp) {
            return Err(Error::out_of_range("spp", self.spp, "1 to 65536"));
        }
        let p = &self.photons;
        if p.sun_photons > 1 << 26
            || p.env_photons > 1 << 26
            || !(2..=256).contains(&p.max_coarse_dim)
            || p.angular_order > crate::multiple::MAX_ORDER
            || !(p.truncation_power.is_finite() && (0.0..=16.0).contains(&p.truncation_power))
            || !(p.peak_spread.is_finite() && (0.0..=1.0).contains(&p.peak_spread))
        {
            return Err(Error::out_of_range(
                "photons",
                "settings",
                "photons <= 2^26, coarse dim 2 to 256, angular order 0 to 4, truncation power 0 to 16, peak spread 0 to 1",
            ));
        }
        if !(64..=1 << 16).contains(&self.sky_quadrature)
            || !(4..=512).contains(&self.sky_table[0])
            || !(4..=1024).contains(&self.sky_table[1])
        {
            return Err(Error::out_of_range(
                "sky_quadrature",
                self.sky_quadrature,
                "64 to 65536 (table 4..512 x 4..1024)",
            ));
        }
        self.pattern.validate()?;
        if !(1..=1024).contains(&self.shaft_steps) {
            return Err(Error::out_of_range(
                "shaft_steps",
                self.shaft_steps,
                "1 to 1024",
            ));
        }
        Ok(())
    }
}

/// A rectangle of the image, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Tile {
    pub x0: usize,
    pub y0: usize,
    pub width: usize,
    pub height: usize,
}

/// Error estimate of a frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameError {
    /// Reference method: the path tracer's own noise, the root-mean-square over cloud pixels of
    /// the standard error of each pixel's mean relative to the mean cloud radiance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path_tracer_relative_noise: Option<f64>,
    /// What the fast method's accuracy is and where it was measured.
    pub basis: &'static str,
}

/// Metadata of a frame: stages run and left out, timings, error estimate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameMeta {
    pub method: Method,
    pub stages: Stages,
    /// Milliseconds per stage, in order.
    pub timing_ms: Vec<(String, f64)>,
    pub error_estimate: FrameError,
    pub lighting_notes: Vec<String>,
    /// The typed plan (`plan::FramePlan` as JSON: stages, left out with their rules and
    /// reasons, coarsened, budget) when the frame ran through `product::FrameRequest`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plan: Option<serde_json::Value>,
}

/// Spectral radiance of an image or a tile.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub tile: Tile,
    pub image_width: usize,
    pub image_height: usize,
    pub wavelengths_nm: Vec<f64>,
    /// `[row][col][λ]`, W m⁻² sr⁻¹ nm⁻¹.
    pub radiance: Vec<f32>,
    /// Cloud transmittance along each pixel's ray (mean over wavelengths), `[row][col]`.
    pub transmittance: Vec<f32>,
    /// Reference method: variance of each pixel's mean, `[row][col][λ]` (empty for the fast
    /// method), so tiles rendered apart combine into the frame's noise estimate.
    pub variance: Vec<f32>,
    pub meta: FrameMeta,
}

/// Lighting for a scene from the engine (or without one in vacuum), with the cloud's altitude
/// and the distances the camera sees taken from the grid.
pub fn lighting_for(scene: &FrameScene, grid: &DensityGrid, engine: &Engine) -> Result<Lighting> {
    lighting_for_unless(scene, grid, engine, &|| false)
}

/// [`lighting_for`], stopped with [`Error::Cancelled`] once `cancelled` returns true.
pub fn lighting_for_unless(
    scene: &FrameScene,
    grid: &DensityGrid,
    engine: &Engine,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<Lighting> {
    let (altitude, reach) = lighting_reach(scene, grid);
    Lighting::from_scene_unless(scene, engine, altitude, reach, cancelled)
}

/// [`lighting_for_unless`] through `memo`: the lighting an earlier frame computed with the same
/// inputs and engine (a camera path at a constant height), else computed and kept. The same
/// values as without the memo.
pub fn lighting_for_memo_unless(
    scene: &FrameScene,
    grid: &DensityGrid,
    engine: &Engine,
    memo: &LightingMemo,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<Lighting> {
    let (altitude, reach) = lighting_reach(scene, grid);
    memo.get_or(lighting_memo::key(scene, engine, altitude, reach), || {
        Lighting::from_scene_unless(scene, engine, altitude, reach, cancelled)
    })
}

/// The cloud's centre altitude and the farthest distance the camera needs aerial perspective
/// for (the box's farthest corner, or the ground's bound), m.
fn lighting_reach(scene: &FrameScene, grid: &DensityGrid) -> (f64, f64) {
    let lo = grid.origin_m;
    let hi = grid.max_corner_m();
    let centre = 0.5 * (lo + hi);
    let cam = scene.camera.position_m;
    let far = (0..8)
        .map(|c| {
            let p = glam::DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            p.distance(cam)
        })
        .fold(0.0, f64::max);
    // Rays that miss the cloud reach the ground within a few times the camera height.
    let ground_far = scene
        .ground
        .as_ref()
        .map(|g| 20.0 * (cam.z - g.height_m).max(100.0))
        .unwrap_or(0.0);
    (centre.z, far.max(ground_far).max(1000.0) * 1.05)
}

/// Checks the grid against the renderer's limits before anything is allocated.
pub fn check_grid(grid: &DensityGrid) -> Result<()> {
    let n = grid.data.len();
    if n > MAX_RENDER_VOXELS {
        return Err(Error::too_large(
            "cloud",
            format!("{:?} = {n} voxels to render", grid.dims),
            format!("{MAX_RENDER_VOXELS} voxels (use a larger voxel_size_m)"),
        ));
    }
    Ok(())
}

/// Renders the frame (or one tile of it): prepares the per-voxel light once, then renders the
/// pixels in parallel. `progress` receives the fraction done; `cancel` is polled between rows.
pub fn render_frame(
    scene: &FrameScene,
    grid: &DensityGrid,
    lighting: &Lighting,
    settings: &RenderSettings,
    tile: Option<Tile>,
    progress: &(dyn Fn(f64) + Sync),
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<Frame> {
    settings.validate()?;
    check_grid(grid)?;
    let prepared = Prepared::new(scene, grid, lighting, *settings, cancel)?;
    render_tile(&prepared, tile, progress, cancel)
}

/// Renders one tile (the whole image for `None`) from prepared per-voxel light, so a service can
/// compute and cache a frame tile by tile.
pub fn render_tile(
    p: &Prepared,
    tile: Option<Tile>,
    progress: &(dyn Fn(f64) + Sync),
    cancel: &(dyn Fn() -> bool + Sync),
) -> Result<Frame> {
    let cam = &p.scene.camera;
    let tile = tile.unwrap_or(Tile {
        x0: 0,
        y0: 0,
        width: cam.width,
        height: cam.height,
    });
    if tile.width == 0
        || tile.height == 0
        || tile.x0.saturating_add(tile.width) > cam.width
        || tile.y0.saturating_add(tile.height) > cam.height
    {
        return Err(Error::out_of_range(
            "tile",
            format!("{tile:?}"),
            format!("a non-empty rectangle inside {}x{}", cam.width, cam.height),
        ));
    }
    let n_l = p.scene.wavelengths.len();
    let start = Instant::now();
    let mut radiance = vec![0f32; tile.width * tile.height * n_l];
    let mut transmittance = vec![0f32; tile.width * tile.height];
    let mut variance = vec![0f32; tile.width * tile.height * n_l];
    let rows_done = AtomicUsize::new(0);
    let cancelled = std::sync::atomic::AtomicBool::new(false);
    let mut pt = pathtracer::PathTracer::new(p.vol(), &p.scene.optics, p.lighting, p.settings.seed);
    pt.max_orders = p.settings.max_orders;
    pt.min_orders = p.settings.min_orders;
    radiance
        .par_chunks_mut(tile.width * n_l)
        .zip(transmittance.par_chunks_mut(tile.width))
        .zip(variance.par_chunks_mut(tile.width * n_l))
        .enumerate()
        .for_each(|(row, ((rad, tr), var))| {
            if cancelled.load(Ordering::Relaxed) || cancel() {
                cancelled.store(true, Ordering::Relaxed);
                return;
            }
            let y = tile.y0 + row;
            match p.settings.method {
                Method::Fast => march::fast_row(p, y, tile.x0, rad, tr),
                Method::Reference => {
                    let mut out = vec![0.0; n_l];
                    let mut v = vec![0.0; n_l];
                    for col in 0..tile.width {
                        let x = tile.x0 + col;
                        p.path_trace_pixel(&pt, x, y, &mut out, &mut v);
                        for l in 0..n_l {
                            var[col * n_l + l] = v[l] as f32;
                        }
                        if let Some(ray) = camera::primary_ray(cam, x as f64 + 0.5, y as f64 + 0.5)
                        {
                            let tau = p.vol().density_integral(
                                ray.origin_m,
                                ray.dir,
                                0.5 * p.vol().grid.voxel_size_m,
                            );
                            tr[col] = (p
                                .scene
                                .optics
                                .extinction_per_density_m
                                .iter()
                                .map(|k| (-k * tau).exp())
                                .sum::<f64>()
                                / n_l as f64) as f32;
                        }
                        for l in 0..n_l {
                            rad[col * n_l + l] = out[l] as f32;
                        }
                    }
                }
            }
            let done = rows_done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(done as f64 / tile.height as f64);
        });
    if cancelled.load(Ordering::Relaxed) {
        return Err(Error::Cancelled);
    }
    let mut timing_ms = p.timing_ms.clone();
    timing_ms.push(("pixels".into(), start.elapsed().as_secs_f64() * 1e3));
    let noise = (p.settings.method == Method::Reference)
        .then(|| relative_noise(&radiance, &variance, &transmittance, n_l));
    if p.settings.method != Method::Reference {
        variance = Vec::new();
    }
    Ok(Frame {
        tile,
        image_width: cam.width,
        image_height: cam.height,
        wavelengths_nm: p.scene.wavelengths.as_nm().to_vec(),
        radiance,
        transmittance,
        variance,
        meta: FrameMeta {
            method: p.settings.method,
            stages: p.stages.clone(),
            timing_ms,
            error_estimate: FrameError {
                path_tracer_relative_noise: noise,
                basis: ERROR_BASIS,
            },
            lighting_notes: p.lighting.notes.clone(),
            plan: None,
        },
    })
}

/// Where a frame's error estimate comes from.
pub const ERROR_BASIS: &str = "fast method: not estimated per frame; measured against Mitsuba 3, DISORT (tests/clouds/render_validation.rs) and the path tracer on the bench cumulus (skybake-harness bench frame-accuracy), see README 'Cloud frames'; path tracer: sample variance";

/// RMS over cloud pixels (transmittance < 0.99) of the standard error of the mean, relative to
/// the mean cloud radiance.
pub fn relative_noise(rad: &[f32], var: &[f32], tr: &[f32], n_l: usize) -> f64 {
    let (mut s, mut v, mut n) = (0.0, 0.0, 0usize);
    for (i, t) in tr.iter().enumerate() {
        if *t < 0.99 {
            for l in 0..n_l {
                s += rad[i * n_l + l] as f64;
                v += var[i * n_l + l] as f64;
            }
            n += n_l;
        }
    }
    if n == 0 || s <= 0.0 {
        return 0.0;
    }
    (v / n as f64).sqrt() / (s / n as f64)
}
