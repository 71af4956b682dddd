//! The frame part of `skybake-harness report`: error against run time of the cloud
//! renderer, for a few representative frames, against a converged path-traced reference.
//!
//! Per case (a cloud, a camera, a light), three curves:
//! - **fast, all orders**: the per-voxel light + the all-order multiple-scattering field + the ray
//!   march (`multiple_scattering_method: all_orders`), its settings from each quality preset
//!   ([`RenderSettings::for_quality`]), against the path tracer at [`FrameCase::reference_spp`]
//!   samples per pixel (all orders);
//! - **reference pattern, orders 2–3** (Nishita et al. 1996, §3.4; thin cases only): the pattern's image of
//!   orders 2 + 3 (the frame with the pattern minus the frame with multiple scattering switched
//!   off, the same exact single scattering), each preset, against the path tracer restricted to
//!   orders 2 and 3 (`min_orders` 2, `max_orders` 3), the independent estimate of exactly what the
//!   pattern approximates (as tests/clouds/render_pattern.rs);
//! - **path tracer** at increasing samples per pixel (4, 16, 64, 256; the presets' own counts are
//!   16, 64, 256, 1024), all orders, with its own random streams, against the same reference with
//!   other streams (seed [`REFERENCE_SEED`]), so its curve is its noise.
//!
//! The reference is the path tracer itself, converged; it is validated against DISORT (slabs) and
//! Mitsuba 3 (a 3-D grid cloud) in tests/clouds/render_validation.rs. Its own noise is reported: block
//! errors below about twice its block noise (pixel noise / 8) are not resolved.
//!
//! Every render goes through [`render_frame`], the renderer's entry point the product runs; the
//! light from outside the cloud ([`lighting_for`], the engine's sun/sky/ground/aerial products at
//! the scene's quality) is built once per case and shared by every point and the reference, so the
//! curves measure the cloud renderer alone (the atmosphere products' errors are the report's other
//! sections). Times: wall-clock and process CPU ms of `render_frame` (preparation + pixels).
//!
//! Error measures ([`image_errors`], over the reference's cloud pixels, transmittance < 0.99, of
//! the mean over wavelengths): NRMSE of 8×8-pixel block means (all-cloud blocks), per-pixel NRMSE,
//! and the cloud-mean bias, each relative to the reference's mean cloud radiance.
//!
//! A converged reference of a full run takes minutes, so [`run`] keeps each case's reference as
//! `frames-reference-<case>.npy` (radiance and transmittance, f32) with a `.json` note of its key
//! (blake3 of the scene, the grid, the reference settings and the engine version) in the output
//! directory, and reuses it while the key matches.

use super::process_cpu_ms;
use crate::frame_bench::{bench_cumulus, bench_scene};
use crate::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use skybake_engine::engine::Engine;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::cloud::DensityGrid;
use skybake_render::compare::{image_errors, ImageErrors};
use skybake_render::{
    lighting_for, render_frame, CloudMsMethod, Frame, FrameScene, Lighting, Method, RenderSettings,
};
use std::path::Path;
use std::time::Instant;

/// Random streams of the converged references (the measured path-tracer points use the presets'
/// default seed, so the two are independent).
pub const REFERENCE_SEED: u64 = 0x0C0F_FEED_15C0;

/// Samples per pixel of the path tracer's points.
pub const PATH_TRACER_SPP: [usize; 4] = [4, 16, 64, 256];

/// The method of a frame curve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameMethod {
    /// The fast method with the all-order multiple-scattering field.
    FastAllOrders,
    /// Orders 2 + 3 of the reference pattern (against the path tracer's orders 2 + 3).
    PatternOrders23,
    /// The path tracer at increasing samples per pixel.
    PathTracer,
}

impl FrameMethod {
    pub fn name(self) -> &'static str {
        match self {
            Self::FastAllOrders => "fast, all orders",
            Self::PatternOrders23 => "reference pattern, orders 2-3",
            Self::PathTracer => "path tracer",
        }
    }
}

/// One measured setting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FramePoint {
    /// The preset whose settings ran (for the path tracer: whose sample count this is, if any).
    pub quality: Option<Quality>,
    /// Path tracer: samples per pixel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spp: Option<usize>,
    /// `render_frame` wall-clock ms (preparation + pixels; the lighting is built beforehand).
    pub wall_ms: f64,
    /// Process CPU ms (all threads) of the same.
    pub cpu_ms: Option<f64>,
    pub nrmse_blocks: f64,
    pub nrmse_pixels: f64,
    pub mean_bias: f64,
}

/// Error against time for one case and method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameCurve {
    pub case: String,
    pub method: FrameMethod,
    pub points: Vec<FramePoint>,
}

/// A converged path-traced reference of a case.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferenceInfo {
    /// All orders, or orders 2–3 (for the pattern).
    pub orders: String,
    pub spp: usize,
    /// RMS over cloud pixels of each pixel's standard error, relative to the mean cloud radiance
    /// (divide by 8 for an 8×8 block mean).
    pub relative_noise: f64,
    /// Wall-clock ms of the run that made it (on the machine and load of that run).
    pub wall_ms: f64,
    /// Taken from the cached file of an earlier run.
    pub cached: bool,
    pub key: String,
}

/// What a case is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameCaseInfo {
    pub name: String,
    pub description: String,
    pub width: usize,
    pub height: usize,
    pub voxels: usize,
    pub wavelengths_nm: Vec<f64>,
    pub cloud_pixels: usize,
    /// The lighting (engine tables) built once for the case, wall ms.
    pub lighting_ms: f64,
    pub references: Vec<ReferenceInfo>,
}

/// The frame part of a report (`frames.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameReport {
    pub engine_version: String,
    pub quick: bool,
    pub threads: usize,
    #[serde(default)]
    pub machine_load: Option<String>,
    pub cases: Vec<FrameCaseInfo>,
    pub curves: Vec<FrameCurve>,
}

/// A frame of the sweep.
struct FrameCase {
    name: &'static str,
    description: String,
    scene: FrameScene,
    grid: DensityGrid,
    /// Whether the reference pattern's curve is measured (thin clouds: its domain).
    pattern: bool,
    reference_spp: usize,
    pattern_reference_spp: usize,
    /// Presets of the fast and pattern curves.
    presets: Vec<Quality>,
    /// Samples per pixel of the path tracer's points.
    spp: Vec<usize>,
}

/// The thin side-lit case: a 20³ blob (1 − r²/R²) with ±30 % waves, optical diameter 3 through the
/// centre, HG g 0.85, albedo 1, in vacuum, a collimated sun of normal irradiance 1 from the side
/// (elevation 30°, scattering angle about 90°), no sky, no ground (tests/clouds/render_pattern.rs's).
fn thin_case(px: usize) -> Result<(FrameScene, DensityGrid)> {
    const H: f64 = 20.0;
    const N: usize = 20;
    let centre = DVec3::new(0.0, 0.0, 1200.0);
    let r = 9.0 * H;
    let side = N as f64 * H;
    let grid = DensityGrid::from_fn([N; 3], H, centre - DVec3::splat(0.5 * side), |p| {
        let q = p - centre;
        let f = 1.0 - q.length_squared() / (r * r);
        if f <= 0.0 {
            return 0.0;
        }
        let w = (q.x / 47.0).sin() * (q.y / 61.0).sin() * (q.z / 53.0).sin();
        (f * (1.0 + 0.3 * w)) as f32
    })?;
    let tau = 3.0;
    let v = serde_json::json!({
        "name": "report-thin-side",
        "cloud": {"voxel_size_m": H, "source": {"type": "metaballs",
                  "balls": [{"centre_m": [0, 0, 1200], "radius_m": 180, "density": 1.0}]}},
        "optics": {"extinction_per_density_m": tau / (4.0 * r / 3.0), "single_scattering_albedo": 1.0,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": {"type": "pinhole", "position_m": [0, -1500, 1200], "look_at_m": [0, 0, 1200],
                   "up": [0, 0, 1], "fov_deg": 16, "width": px, "height": px},
        "sun": {"collimated": {"elevation_deg": 30, "azimuth_deg": 90,
                               "normal_irradiance_w_m2_nm": 1.0}},
        "atmosphere": null, "sky": null, "ground": null,
        "wavelengths_nm": [550], "quality": "standard"
    });
    Ok((FrameScene::parse(v.to_string().as_bytes())?, grid))
}

fn cases(quick: bool) -> Result<Vec<FrameCase>> {
    let all = skybake_engine::accuracy::PRESETS.to_vec();
    if quick {
        let (scene, grid) = thin_case(24)?;
        return Ok(vec![FrameCase {
            name: "thin-side-tiny",
            description:
                "20³ blob of optical diameter 3, HG 0.85, albedo 1, vacuum, collimated sun \
                          from the side (30°), 24×24 pinhole (--quick)"
                    .into(),
            scene,
            grid,
            pattern: true,
            reference_spp: 1024,
            pattern_reference_spp: 1024,
            presets: vec![Quality::Draft, Quality::Standard],
            spp: vec![4, 16, 64],
        }]);
    }
    let (thin, thin_grid) = thin_case(64)?;
    Ok(vec![
        FrameCase {
            name: "cumulus",
            description: "the bench cumulus (128³ voxels of 12 m, HG 0.85, albedo 1), earth \
                          atmosphere, sun 35°, sky and ground light (albedo 0.3), 440/550/680 nm, \
                          160×120 pinhole"
                .into(),
            scene: bench_scene(160, 120)?,
            grid: bench_cumulus()?,
            pattern: false,
            reference_spp: 2048,
            pattern_reference_spp: 0,
            presets: all.clone(),
            spp: PATH_TRACER_SPP.to_vec(),
        },
        FrameCase {
            name: "thin-side",
            description:
                "20³ blob of optical diameter 3 (±30 % density waves), HG 0.85, albedo 1, \
                          vacuum, collimated sun from the side (elevation 30°, scattering angle \
                          ≈ 90°), no sky, no ground, 64×64 pinhole"
                    .into(),
            scene: thin,
            grid: thin_grid,
            pattern: true,
            reference_spp: 8192,
            pattern_reference_spp: 8192,
            presets: all,
            spp: PATH_TRACER_SPP.to_vec(),
        },
    ])
}

fn quality_of_spp(spp: usize) -> Option<Quality> {
    skybake_engine::accuracy::PRESETS
        .into_iter()
        .find(|&q| RenderSettings::for_quality(q, Method::Reference).spp == spp)
}

/// One timed render.
fn timed(
    scene: &FrameScene,
    grid: &DensityGrid,
    lighting: &Lighting,
    settings: &RenderSettings,
) -> Result<(Frame, f64, Option<f64>)> {
    let cpu = process_cpu_ms();
    let start = Instant::now();
    let f = render_frame(scene, grid, lighting, settings, None, &|_| {}, &|| false)?;
    let wall = start.elapsed().as_secs_f64() * 1e3;
    let cpu = process_cpu_ms().zip(cpu).map(|(a, b)| a - b);
    Ok((f, wall, cpu))
}

/// A cached converged reference: radiance `[px][λ]` and transmittance `[px]`.
struct Reference {
    radiance: Vec<f32>,
    transmittance: Vec<f32>,
    info: ReferenceInfo,
}

/// The key of a reference: the scene, the grid, the reference's settings, the engine version.
fn reference_key(case: &FrameCase, orders: &str, settings: &RenderSettings) -> String {
    let mut h = blake3::Hasher::new();
    h.update(
        serde_json::to_string(&case.scene.source)
            .unwrap_or_default()
            .as_bytes(),
    );
    h.update(
        format!(
            "{:?}{:?}{}",
            case.grid.dims, case.grid.origin_m, case.grid.voxel_size_m
        )
        .as_bytes(),
    );
    for v in &case.grid.data {
        h.update(&v.to_le_bytes());
    }
    h.update(
        format!(
            "{orders}|{settings:?}|{}",
            skybake_engine::engine::ENGINE_VERSION
        )
        .as_bytes(),
    );
    h.finalize().to_hex().to_string()
}

/// `.npy` header of a little-endian f32 array of `shape` (format 1.0, padded to 64 bytes).
fn npy_header(shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let mut dict = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({},), }}",
        dims.join(", ")
    );
    let total = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - total % 64) % 64));
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// The reference as `[h][w][n_λ + 1]` (radiance per wavelength, then transmittance).
fn reference_npy(r: &Reference, w: usize, h: usize, n_l: usize) -> Vec<u8> {
    let mut out = npy_header(&[h, w, n_l + 1]);
    for p in 0..w * h {
        for l in 0..n_l {
            out.extend_from_slice(&r.radiance[p * n_l + l].to_le_bytes());
        }
        out.extend_from_slice(&r.transmittance[p].to_le_bytes());
    }
    out
}

fn reference_from_npy(
    bytes: &[u8],
    w: usize,
    h: usize,
    n_l: usize,
    info: ReferenceInfo,
) -> Option<Reference> {
    let header = npy_header(&[h, w, n_l + 1]);
    let body = bytes.strip_prefix(header.as_slice())?;
    if body.len() != w * h * (n_l + 1) * 4 {
        return None;
    }
    let values: Vec<f32> = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if !values.iter().all(|v| v.is_finite() && *v >= 0.0) {
        return None;
    }
    let mut radiance = Vec::with_capacity(w * h * n_l);
    let mut transmittance = Vec::with_capacity(w * h);
    for px in values.chunks_exact(n_l + 1) {
        radiance.extend_from_slice(&px[..n_l]);
        transmittance.push(px[n_l]);
    }
    Some(Reference {
        radiance,
        transmittance,
        info,
    })
}

/// The converged reference of `case` (all orders, or orders 2–3), from `dir` when a file with the
/// same key is there, else rendered (and written there).
fn reference(
    case: &FrameCase,
    lighting: &Lighting,
    orders_2_3: bool,
    dir: Option<&Path>,
) -> Result<Reference> {
    let mut s = RenderSettings::for_quality(Quality::Reference, Method::Reference);
    s.seed = REFERENCE_SEED;
    let orders = if orders_2_3 {
        s.min_orders = 2;
        s.max_orders = 3;
        s.spp = case.pattern_reference_spp;
        "2-3"
    } else {
        s.spp = case.reference_spp;
        "all"
    };
    let key = reference_key(case, orders, &s);
    let (w, h) = (case.scene.camera.width, case.scene.camera.height);
    let n_l = case.scene.wavelengths.len();
    let stem = format!(
        "frames-reference-{}{}",
        case.name,
        if orders_2_3 { "-orders23" } else { "" }
    );
    if let Some(dir) = dir {
        let note = skybake_store::files::read(&dir.join(format!("{stem}.json")))
            .ok()
            .and_then(|b| serde_json::from_slice::<ReferenceInfo>(&b).ok());
        if let Some(mut info) = note.filter(|i| i.key == key) {
            if let Some(r) = skybake_store::files::read(&dir.join(format!("{stem}.npy")))
                .ok()
                .and_then(|b| {
                    info.cached = true;
                    reference_from_npy(&b, w, h, n_l, info)
                })
            {
                return Ok(r);
            }
        }
    }
    let (f, wall_ms, _) = timed(&case.scene, &case.grid, lighting, &s)?;
    let r = Reference {
        info: ReferenceInfo {
            orders: orders.into(),
            spp: s.spp,
            relative_noise: f
                .meta
                .error_estimate
                .path_tracer_relative_noise
                .unwrap_or(0.0),
            wall_ms,
            cached: false,
            key,
        },
        radiance: f.radiance,
        transmittance: f.transmittance,
    };
    if let Some(dir) = dir {
        skybake_store::files::create_dir_all(dir)?;
        skybake_store::write_atomic(
            &dir.join(format!("{stem}.npy")),
            &reference_npy(&r, w, h, n_l),
        )?;
        let note = serde_json::to_string_pretty(&r.info)
            .map_err(|e| Error::internal("report", format!("JSON encoding: {e}")))?;
        skybake_store::write_atomic(&dir.join(format!("{stem}.json")), (note + "\n").as_bytes())?;
    }
    Ok(r)
}

fn point(
    quality: Option<Quality>,
    spp: Option<usize>,
    wall_ms: f64,
    cpu_ms: Option<f64>,
    e: ImageErrors,
) -> FramePoint {
    FramePoint {
        quality,
        spp,
        wall_ms,
        cpu_ms,
        nrmse_blocks: e.nrmse_blocks,
        nrmse_pixels: e.nrmse_pixels,
        mean_bias: e.mean_bias,
    }
}

/// Number of measured points (and references) of a run, for the progress bar.
fn steps(cases: &[FrameCase]) -> usize {
    cases
        .iter()
        .map(|c| {
            1 + c.presets.len()
                + c.spp.len()
                + if c.pattern {
                    1 + 2 * c.presets.len()
                } else {
                    0
                }
        })
        .sum()
}

/// Runs the frame sweep (`quick`: one tiny case). References are read from and written to
/// `reference_dir` (none: always rendered, never kept). `progress(done, total)` after each step.
pub fn run(
    quick: bool,
    reference_dir: Option<&Path>,
    progress: &dyn Fn(usize, usize),
) -> Result<FrameReport> {
    let cases = cases(quick)?;
    let total = steps(&cases);
    let mut done = 0;
    let mut step = || {
        done += 1;
        progress(done, total);
    };
    let mut infos = Vec::new();
    let mut curves = Vec::new();
    for case in &cases {
        let engine = Engine::new();
        let start = Instant::now();
        let lighting = lighting_for(&case.scene, &case.grid, &engine)?;
        let lighting_ms = start.elapsed().as_secs_f64() * 1e3;
        let n_l = case.scene.wavelengths.len();
        let w = case.scene.camera.width;
        let reference_all = reference(case, &lighting, false, reference_dir)?;
        step();
        let mask: Vec<bool> = reference_all
            .transmittance
            .iter()
            .map(|&t| t < 0.99)
            .collect();
        let errors = |img: &[f32], r: &[f32]| image_errors(img, r, &mask, w, n_l);
        // Fast method, all orders, over the presets.
        let mut scene = case.scene.clone();
        scene.multiple_scattering_method = CloudMsMethod::AllOrders;
        let mut points = Vec::new();
        for &q in &case.presets {
            let s = RenderSettings::for_quality(q, Method::Fast);
            let (f, wall, cpu) = timed(&scene, &case.grid, &lighting, &s)?;
            points.push(point(
                Some(q),
                None,
                wall,
                cpu,
                errors(&f.radiance, &reference_all.radiance),
            ));
            step();
        }
        curves.push(FrameCurve {
            case: case.name.into(),
            method: FrameMethod::FastAllOrders,
            points,
        });
        // The path tracer at increasing samples per pixel.
        let mut points = Vec::new();
        for &spp in &case.spp {
            let mut s = RenderSettings::for_quality(Quality::Draft, Method::Reference);
            s.spp = spp;
            let (f, wall, cpu) = timed(&scene, &case.grid, &lighting, &s)?;
            points.push(point(
                quality_of_spp(spp),
                Some(spp),
                wall,
                cpu,
                errors(&f.radiance, &reference_all.radiance),
            ));
            step();
        }
        curves.push(FrameCurve {
            case: case.name.into(),
            method: FrameMethod::PathTracer,
            points,
        });
        let mut references = vec![reference_all.info.clone()];
        // The reference pattern's orders 2 + 3 against the path tracer's.
        if case.pattern {
            let reference_23 = reference(case, &lighting, true, reference_dir)?;
            step();
            let mut with = case.scene.clone();
            with.multiple_scattering_method = CloudMsMethod::ReferencePattern;
            let mut without = with.clone();
            without.lighting.multiple_scattering = false;
            let mut points = Vec::new();
            for &q in &case.presets {
                let s = RenderSettings::for_quality(q, Method::Fast);
                let (f, wall, cpu) = timed(&with, &case.grid, &lighting, &s)?;
                step();
                let (single, _, _) = timed(&without, &case.grid, &lighting, &s)?;
                step();
                let orders: Vec<f32> = f
                    .radiance
                    .iter()
                    .zip(&single.radiance)
                    .map(|(a, b)| a - b)
                    .collect();
                points.push(point(
                    Some(q),
                    None,
                    wall,
                    cpu,
                    errors(&orders, &reference_23.radiance),
                ));
            }
            curves.push(FrameCurve {
                case: case.name.into(),
                method: FrameMethod::PatternOrders23,
                points,
            });
            references.push(reference_23.info);
        }
        infos.push(FrameCaseInfo {
            name: case.name.into(),
            description: case.description.clone(),
            width: w,
            height: case.scene.camera.height,
            voxels: case.grid.data.len(),
            wavelengths_nm: case.scene.wavelengths.as_nm().to_vec(),
            cloud_pixels: mask.iter().filter(|&&m| m).count(),
            lighting_ms,
            references,
        });
    }
    Ok(FrameReport {
        engine_version: skybake_engine::engine::ENGINE_VERSION.into(),
        quick,
        threads: rayon::current_num_threads(),
        machine_load: None,
        cases: infos,
        curves,
    })
}

fn quality_label(p: &FramePoint) -> String {
    match (p.quality, p.spp) {
        (Some(q), Some(spp)) => format!("{spp} spp ({})", super::quality_name(q)),
        (None, Some(spp)) => format!("{spp} spp"),
        (Some(q), None) => super::quality_name(q).into(),
        (None, None) => "—".into(),
    }
}

/// The frame section of the report's markdown.
pub fn markdown(frames: &FrameReport, plots: &[(String, String)]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "## Cloud frames\n");
    let _ = writeln!(
        s,
        "Made by `skybake-harness report{} --only frames` ({}, {} threads, load average {}). \
         Reference: the path tracer (all orders; validated against DISORT and Mitsuba 3 in \
         tests/clouds/render_validation.rs), converged at the samples per pixel below with its own random \
         streams; the pattern's orders 2–3 are compared with the path tracer restricted to orders \
         2–3. The lighting from the atmosphere is built once per case at the scene's quality and \
         shared, so the figures are the cloud renderer's alone; the presets set the renderer's \
         settings. Errors over the reference's cloud pixels (transmittance < 0.99), mean over \
         wavelengths, relative to the mean cloud radiance: NRMSE of 8×8 block means, per-pixel \
         NRMSE, cloud-mean bias. Times: `render_frame` (preparation + pixels), wall and process CPU \
         (all threads). Block errors below about twice the reference's block noise (its pixel \
         noise / 8) are not resolved.\n",
        if frames.quick { " --quick" } else { "" },
        frames.engine_version,
        frames.threads,
        frames.machine_load.as_deref().unwrap_or("unknown")
    );
    for c in &frames.cases {
        let _ = writeln!(s, "### {}\n", c.name);
        let _ = writeln!(
            s,
            "{}; {} voxels, {} cloud pixels; lighting built in {:.0} ms.\n",
            c.description, c.voxels, c.cloud_pixels, c.lighting_ms
        );
        for r in &c.references {
            let _ = writeln!(
                s,
                "- reference, orders {}: {} spp, pixel noise {:.2} % (block {:.2} %), {:.0} s{}",
                r.orders,
                r.spp,
                100.0 * r.relative_noise,
                100.0 * r.relative_noise / 8.0,
                r.wall_ms / 1e3,
                if r.cached {
                    " (cached from an earlier run)"
                } else {
                    ""
                }
            );
        }
        let _ = writeln!(s);
        if let Some((_, file)) = plots.iter().find(|(n, _)| *n == c.name) {
            let _ = writeln!(s, "![{} error against time]({file})\n", c.name);
        }
        let _ = writeln!(
            s,
            "| method | setting | wall ms | CPU ms | block NRMSE | pixel NRMSE | mean bias |\n|---|---|---:|---:|---:|---:|---:|"
        );
        for curve in frames.curves.iter().filter(|k| k.case == c.name) {
            for p in &curve.points {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.0} | {} | {:.2} % | {:.2} % | {:+.2} % |",
                    curve.method.name(),
                    quality_label(p),
                    p.wall_ms,
                    p.cpu_ms.map_or("—".into(), |v| format!("{v:.0}")),
                    100.0 * p.nrmse_blocks,
                    100.0 * p.nrmse_pixels,
                    100.0 * p.mean_bias
                );
            }
        }
        let _ = writeln!(s);
    }
    s
}

/// The log–log plot of a case: block NRMSE against CPU time (wall time where CPU time is not
/// known), one curve per method, the presets marked by their initial (d, s, h, r), the path
/// tracer's points by their samples per pixel.
pub fn png(frames: &FrameReport, case: &str) -> Result<Vec<u8>> {
    use plotters::style::RGBColor;
    let series: Vec<super::plot::Series> = frames
        .curves
        .iter()
        .filter(|c| c.case == case)
        .map(|c| super::plot::Series {
            label: c.method.name().into(),
            colour: match c.method {
                FrameMethod::FastAllOrders => RGBColor(30, 90, 200),
                FrameMethod::PatternOrders23 => RGBColor(30, 150, 60),
                FrameMethod::PathTracer => RGBColor(210, 50, 30),
            },
            points: c
                .points
                .iter()
                .map(|p| {
                    let mark = match (p.spp, p.quality) {
                        (Some(spp), _) => spp.to_string(),
                        (None, Some(q)) => super::quality_name(q)[..1].to_string(),
                        (None, None) => String::new(),
                    };
                    (p.cpu_ms.unwrap_or(p.wall_ms) / 1e3, p.nrmse_blocks, mark)
                })
                .collect(),
        })
        .collect();
    super::plot::log_log_png(
        &format!("frame '{case}': error against CPU time"),
        "render CPU time, s, all threads (preparation + pixels)",
        "NRMSE of 8x8 block means vs converged path tracer",
        &series,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_and_header_alignment() {
        let h = npy_header(&[3, 2, 2]);
        assert_eq!(h.len() % 64, 0);
        assert!(h.starts_with(b"\x93NUMPY\x01\x00"));
        let r = Reference {
            radiance: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            transmittance: vec![0.5, 0.25, 1.0, 0.0, 0.75, 0.125],
            info: ReferenceInfo {
                orders: "all".into(),
                spp: 1,
                relative_noise: 0.0,
                wall_ms: 0.0,
                cached: false,
                key: "k".into(),
            },
        };
        let bytes = reference_npy(&r, 2, 3, 1);
        let back = reference_from_npy(&bytes, 2, 3, 1, r.info.clone()).unwrap();
        assert_eq!(back.radiance, r.radiance);
        assert_eq!(back.transmittance, r.transmittance);
        // Another shape is refused.
        assert!(reference_from_npy(&bytes, 3, 2, 1, r.info.clone()).is_none());
    }

    #[test]
    fn preset_sample_counts_are_marked() {
        assert_eq!(quality_of_spp(16), Some(Quality::Draft));
        assert_eq!(quality_of_spp(4), None);
    }
}
