//! `skybake-harness bench frame`: a 640×480 frame of a 128³ cumulus with sky light,
//! ground light and multiple scattering at the standard quality, cold (the engine's sky and
//! ground tables built inside the timed region) and warm; `frame-accuracy` compares the fast
//! method with the path tracer on the same scene at a reduced resolution.

use crate::Result;
use glam::DVec3;
use serde::Serialize;
use skybake_engine::engine::Engine;
use skybake_physics::cloud::DensityGrid;
use skybake_render::compare::{image_errors, ImageErrors};
use skybake_render::{lighting_for, render_frame, FrameScene, Method, RenderSettings};
use std::time::Instant;

/// Voxels per axis of the benchmark cumulus.
pub const BENCH_DIM: usize = 128;

/// The benchmark cumulus: eight overlapping smooth balls (Wyvill's field, Dobashi et al. 2000, eq B.1) in a
/// 128³ grid of 12 m voxels, flat-ish base at 1 km.
pub fn bench_cumulus() -> Result<DensityGrid> {
    let h = 12.0;
    let side = BENCH_DIM as f64 * h;
    let origin = DVec3::new(-0.5 * side, -0.5 * side, 1000.0);
    let balls: [(DVec3, f64, f64); 8] = [
        (DVec3::new(0.0, 0.0, 1450.0), 420.0, 1.0),
        (DVec3::new(330.0, 80.0, 1350.0), 300.0, 0.9),
        (DVec3::new(-320.0, -60.0, 1360.0), 320.0, 0.9),
        (DVec3::new(60.0, 300.0, 1330.0), 280.0, 0.8),
        (DVec3::new(-40.0, -300.0, 1320.0), 270.0, 0.8),
        (DVec3::new(50.0, -40.0, 1760.0), 300.0, 1.0),
        (DVec3::new(-140.0, 70.0, 1980.0), 200.0, 1.0),
        (DVec3::new(190.0, 40.0, 1880.0), 190.0, 0.9),
    ];
    DensityGrid::from_fn([BENCH_DIM; 3], h, origin, |p| {
        let mut f = 0.0;
        for (c, r, d) in balls {
            let q = (p - c).length_squared() / (r * r);
            if q < 1.0 {
                // Wyvill: 1 − 22/9 q + 17/9 q² − 4/9 q³ (q = d²/r²).
                f += d * (1.0 - q * (22.0 / 9.0) + q * q * (17.0 / 9.0) - q * q * q * (4.0 / 9.0));
            }
        }
        // Flatten the base below 1.15 km.
        let base = ((p.z - 1100.0) / 60.0).clamp(0.0, 1.0);
        (f.min(1.2) * base) as f32
    })
}

/// The benchmark scene (earth atmosphere, sun at 35°, ground albedo 0.3, HG 0.85).
/// Camera `k` of an `n`-camera fly-around: `base` with its camera turned about the vertical
/// through `target` by k/n of a turn from `start` (the camera's offset from `target`), looking at
/// `target`.
pub fn fly_around_camera(
    base: &FrameScene,
    target: DVec3,
    start: DVec3,
    k: usize,
    n: usize,
) -> FrameScene {
    let (s, c) = (std::f64::consts::TAU * k as f64 / n as f64).sin_cos();
    let p = target
        + DVec3::new(
            start.x * c + start.y * s,
            start.y * c - start.x * s,
            start.z,
        );
    let mut scene = base.clone();
    let fwd = (target - p).normalize();
    let right = fwd.cross(DVec3::Z).normalize();
    scene.camera.position_m = p;
    scene.camera.forward = fwd;
    scene.camera.right = right;
    scene.camera.up = right.cross(fwd);
    scene
}

pub fn bench_scene(width: usize, height: usize) -> Result<FrameScene> {
    let json = serde_json::json!({
        "name": "bench-cumulus",
        "cloud": {"voxel_size_m": 12.0, "source": {"type": "metaballs",
                  "balls": [{"centre_m": [0, 0, 1450], "radius_m": 420, "density": 1.0}]}},
        "optics": {"extinction_per_density_m": 0.04, "single_scattering_albedo": 1.0,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": {"type": "pinhole", "position_m": [0, -3200, 1300], "look_at_m": [0, 0, 1500],
                   "up": [0, 0, 1], "fov_deg": 50, "fov_axis": "horizontal",
                   "width": width, "height": height},
        "sun": {"elevation_deg": 35, "azimuth_deg": 140},
        "atmosphere": "earth", "sky": "atmosphere", "ground": {"albedo": 0.3, "height_m": 0},
        "wavelengths_nm": [440, 550, 680], "quality": "standard"
    });
    FrameScene::parse(json.to_string().as_bytes())
}

/// Timings of one bench run.
#[derive(Debug, Clone, Serialize)]
pub struct FrameBench {
    pub cold_ms: f64,
    pub warm_ms: f64,
    /// Warm-run stage timings, ms.
    pub warm_stages_ms: Vec<(String, f64)>,
    /// Warm-run stage shares of the frame's time (the engine's lighting tables included as
    /// `lighting`), fractions summing to ≈ 1 but for the lit volume's stages that run side by
    /// side (sun paths, sky light, multiple scattering, shadow map: each its own wall time).
    pub warm_stage_shares: Vec<(String, f64)>,
    pub lighting_cold_ms: f64,
    pub lighting_warm_ms: f64,
    /// CPU time (user + system, all threads) of the warm run, ms (`None` without `/proc`).
    pub warm_cpu_ms: Option<f64>,
    pub width: usize,
    pub height: usize,
    pub voxels: usize,
}

/// Cold then warm: the cold run builds the engine's tables.
pub fn bench_frame(width: usize, height: usize) -> Result<FrameBench> {
    let grid = bench_cumulus()?;
    let scene = bench_scene(width, height)?;
    time_frame(&scene, &grid, width, height)
}

/// Cold then warm frames of `scene` (the `frame` benchmarks' timing).
pub fn time_frame(
    scene: &FrameScene,
    grid: &skybake_physics::cloud::DensityGrid,
    width: usize,
    height: usize,
) -> Result<FrameBench> {
    let settings = RenderSettings::for_quality(scene.quality, Method::Fast);
    let engine = Engine::new();
    let t = Instant::now();
    let lighting = lighting_for(scene, grid, &engine)?;
    let lighting_cold_ms = t.elapsed().as_secs_f64() * 1e3;
    render_frame(scene, grid, &lighting, &settings, None, &|_| {}, &|| false)?;
    let cold_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let cpu0 = crate::process::process_cpu_ms();
    let lighting = lighting_for(scene, grid, &engine)?;
    let lighting_warm_ms = t.elapsed().as_secs_f64() * 1e3;
    let frame = render_frame(scene, grid, &lighting, &settings, None, &|_| {}, &|| false)?;
    let warm_ms = t.elapsed().as_secs_f64() * 1e3;
    let warm_cpu_ms = cpu0
        .zip(crate::process::process_cpu_ms())
        .map(|(a, b)| b - a);
    let warm_stage_shares = std::iter::once(("lighting".to_string(), lighting_warm_ms))
        .chain(frame.meta.timing_ms.iter().cloned())
        .map(|(name, ms)| (name, ms / warm_ms.max(1e-9)))
        .collect();
    Ok(FrameBench {
        cold_ms,
        warm_ms,
        warm_stages_ms: frame.meta.timing_ms,
        warm_stage_shares,
        lighting_cold_ms,
        lighting_warm_ms,
        warm_cpu_ms,
        width,
        height,
        voxels: grid.data.len(),
    })
}

/// Fast method against the path tracer (`spp` samples) on the bench scene at `width`×`height`.
pub fn bench_frame_accuracy(
    width: usize,
    height: usize,
    spp: usize,
) -> Result<(ImageErrors, f64, f64, f64)> {
    let grid = bench_cumulus()?;
    let scene = bench_scene(width, height)?;
    let engine = Engine::new();
    let lighting = lighting_for(&scene, &grid, &engine)?;
    let fast_settings = RenderSettings::for_quality(scene.quality, Method::Fast);
    let t = Instant::now();
    let fast = render_frame(
        &scene,
        &grid,
        &lighting,
        &fast_settings,
        None,
        &|_| {},
        &|| false,
    )?;
    let fast_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut ref_settings = RenderSettings::for_quality(scene.quality, Method::Reference);
    ref_settings.spp = spp;
    let t = Instant::now();
    let reference = render_frame(
        &scene,
        &grid,
        &lighting,
        &ref_settings,
        None,
        &|_| {},
        &|| false,
    )?;
    let ref_ms = t.elapsed().as_secs_f64() * 1e3;
    let mask: Vec<bool> = reference.transmittance.iter().map(|&t| t < 0.99).collect();
    let e = image_errors(
        &fast.radiance,
        &reference.radiance,
        &mask,
        width,
        fast.wavelengths_nm.len(),
    );
    Ok((
        e,
        reference
            .meta
            .error_estimate
            .path_tracer_relative_noise
            .unwrap_or(0.0),
        fast_ms,
        ref_ms,
    ))
}

/// `skybake-harness bench frame-pattern`: the `frame` benchmark (640×480, 128³ cumulus, standard
/// quality, cold then warm) with `"multiple_scattering_method": "reference_pattern"`.
pub fn bench_frame_pattern(width: usize, height: usize) -> Result<FrameBench> {
    let grid = bench_cumulus()?;
    let mut scene = bench_scene(width, height)?;
    scene.multiple_scattering_method = skybake_render::CloudMsMethod::ReferencePattern;
    time_frame(&scene, &grid, width, height)
}

/// Timings of `skybake-harness bench frame-sequence`.
#[derive(Debug, Clone, Serialize)]
pub struct SequenceBench {
    pub frames: usize,
    pub width: usize,
    pub height: usize,
    /// The whole sequence (lighting from the engine per frame, the lit cloud once, each camera's
    /// source and pixels), ms, the engine's tables built before.
    pub total_ms: f64,
    /// `total_ms / frames`.
    pub per_frame_ms: f64,
    /// CPU time (user + system, all threads) of the whole sequence divided by `frames`, ms
    /// (`None` without `/proc`).
    pub per_frame_cpu_ms: Option<f64>,
    /// The first frame (it lights the cloud) and the median of the others, ms.
    pub first_frame_ms: f64,
    pub median_later_frame_ms: f64,
    /// Stage times summed over the sequence, ms (`lighting` is the engine's products per
    /// frame; the rest as in a frame's `timing_ms`, the lit cloud's stages counted once).
    pub stages_ms: Vec<(String, f64)>,
    /// Bytes the lit cloud holds.
    pub lit_bytes: usize,
}

/// The bench cumulus seen from `frames` cameras on a circle round it (the `frame` bench's camera
/// turned about the vertical through its target in equal steps), at `width`×`height`, standard
/// quality: the cloud is lit once ([`skybake_render::LitVolume`]) and each frame adds its
/// camera's part ([`skybake_render::Prepared::with_lit`]), as frame sequences run.
pub fn bench_frame_sequence(frames: usize, width: usize, height: usize) -> Result<SequenceBench> {
    use skybake_render::{render_tile, LitInputs, LitVolume, Prepared};
    let grid = std::sync::Arc::new(bench_cumulus()?);
    let base = bench_scene(width, height)?;
    let settings = RenderSettings::for_quality(base.quality, Method::Fast);
    let engine = Engine::new();
    // The engine's shared tables, as in a warm service.
    lighting_for(&base, &grid, &engine)?;
    let target = DVec3::new(0.0, 0.0, 1500.0);
    let start = base.camera.position_m - target;
    let mut stages: Vec<(String, f64)> = Vec::new();
    let mut add = |name: &str, ms: f64| match stages.iter_mut().find(|(n, _)| n == name) {
        Some(s) => s.1 += ms,
        None => stages.push((name.to_string(), ms)),
    };
    let mut lit: Option<std::sync::Arc<LitVolume>> = None;
    // The engine's products per camera, kept for the next camera with the same inputs (as
    // a sequence's `FrameReuse` keeps them).
    let memo = skybake_render::LightingMemo::new();
    let mut frame_ms = Vec::with_capacity(frames);
    let t_all = Instant::now();
    let cpu0 = crate::process::process_cpu_ms();
    for k in 0..frames {
        let t_frame = Instant::now();
        let scene = fly_around_camera(&base, target, start, k, frames);
        let t = Instant::now();
        let lighting =
            skybake_render::lighting_for_memo_unless(&scene, &grid, &engine, &memo, &|| false)?;
        add("lighting", t.elapsed().as_secs_f64() * 1e3);
        let shared = lit.is_some();
        let l = match &lit {
            Some(l) => l.clone(),
            None => {
                let inputs = LitInputs::new(&scene, grid.clone(), &lighting, settings);
                let l = std::sync::Arc::new(LitVolume::new(inputs, &|| false)?);
                lit = Some(l.clone());
                l
            }
        };
        let prepared = Prepared::with_lit(&scene, &lighting, settings, l, shared, &|| false)?;
        let frame = render_tile(&prepared, None, &|_| {}, &|| false)?;
        for (name, ms) in &frame.meta.timing_ms {
            add(name, *ms);
        }
        frame_ms.push(t_frame.elapsed().as_secs_f64() * 1e3);
    }
    let total_ms = t_all.elapsed().as_secs_f64() * 1e3;
    let per_frame_cpu_ms = cpu0
        .zip(crate::process::process_cpu_ms())
        .map(|(a, b)| (b - a) / frames.max(1) as f64);
    let mut later: Vec<f64> = frame_ms.iter().skip(1).cloned().collect();
    later.sort_by(f64::total_cmp);
    Ok(SequenceBench {
        frames,
        width,
        height,
        total_ms,
        per_frame_ms: total_ms / frames.max(1) as f64,
        per_frame_cpu_ms,
        first_frame_ms: frame_ms.first().copied().unwrap_or(0.0),
        median_later_frame_ms: later.get(later.len() / 2).copied().unwrap_or(0.0),
        stages_ms: stages,
        lit_bytes: lit.map_or(0, |l| l.bytes),
    })
}
