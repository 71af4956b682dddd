//! The physics layer's benchmarks behind `skybake-harness bench` (`ca-step`, `spheres`,
//! `metaballs`, `fractal`, `satellite`, `solar-position`; see [`crate::bench`]): each builds its
//! input with a fixed seed and times the physics crate's public API.

use chrono::{DateTime, Utc};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use skybake_physics::cloud::automaton::{Automaton, AutomatonParams};
use skybake_physics::cloud::fractal::{example_cumulus_base, grow, FractalParams};
use skybake_physics::cloud::metaballs::{Metaball, MetaballField, MAX_BALLS};
use skybake_physics::cloud::satellite::{fit, synthetic_cloud_field, SatelliteParams};
use skybake_physics::cloud::spheres::{Camera, SphereCloud, SphereCloudParams, TraceStats};
use skybake_physics::solar_position::{solar_position, SpaInput};
use skybake_physics::{Error, Result};
use std::time::{Duration, Instant};

/// Timing of [`bench_ca_step`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CaBench {
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    /// Steps timed.
    pub steps: usize,
    /// Mean wall time of one step (growth, stochastic rules, wind, obstacles, ellipsoid drift).
    pub mean_step: Duration,
    /// Median single step.
    pub median_step: Duration,
    /// Fastest single step.
    pub min_step: Duration,
    /// Cloud cover (fraction of cells) after the run, a sanity check that something happened.
    pub cloud_cover: f64,
}

/// Times `steps` automaton steps on an `nx × ny × nz` space with the `AutomatonParams::example`
/// setting (Fig. 8 probabilities, random ellipsoids, sheared wind) after a 20-step warm-up. The
/// paper reports 0.5 s per step for 256×256×20 on a Pentium III 500 MHz (§6).
pub fn bench_ca_step(nx: usize, ny: usize, nz: usize, steps: usize) -> Result<CaBench> {
    if !(1..=100_000).contains(&steps) {
        return Err(Error::out_of_range("steps", steps, "1..=100000"));
    }
    let params = AutomatonParams::example([nx, ny, nz], 1);
    params.validate()?;
    let mut sim = Automaton::new(&params)?;
    for _ in 0..20 {
        sim.step();
    }
    let mut times: Vec<Duration> = (0..steps)
        .map(|_| {
            let start = Instant::now();
            sim.step();
            start.elapsed()
        })
        .collect();
    let total: Duration = times.iter().sum();
    times.sort_unstable();
    Ok(CaBench {
        dims: [nx, ny, nz],
        steps,
        mean_step: total / steps as u32,
        median_step: times[steps / 2],
        min_step: times[0],
        cloud_cover: sim.cloud_cover(),
    })
}

/// Result of [`bench_spheres`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SpheresBench {
    /// Level K.
    pub levels: u32,
    /// Leaf spheres, 5^K.
    pub leaves: usize,
    /// Image size.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Time to build the hierarchy.
    pub build: Duration,
    /// Time to render the transmittance image (all leaves, no level of detail).
    pub render: Duration,
    /// Time to render with level of detail at one pixel.
    pub render_lod: Duration,
    /// Traversal work without level of detail.
    pub stats: TraceStats,
    /// Traversal work with level of detail.
    pub stats_lod: TraceStats,
    /// Fraction of pixels with transmittance below 0.99 (how much of the frame the cloud covers).
    pub coverage: f64,
}

/// Ostroushko et al., table 1: a `width × height` transmittance image of a cumulus with 5^`levels` leaves
/// (the paper: 800×600, K = 6, 8, 10 → 4.75 s, 9.2 s, 22.1 s on one Core 2 core). The camera sits
/// 3 km from the cloud centre with a 45° vertical field of view, so the cloud fills most of the
/// frame.
pub fn bench_spheres(levels: u32, width: usize, height: usize) -> Result<SpheresBench> {
    let params = SphereCloudParams::cumulus(levels, 2024);
    let start = Instant::now();
    let cloud = SphereCloud::new(&params)?;
    let build = start.elapsed();
    let centre = cloud.centre_m();
    let camera = Camera {
        eye_m: centre + DVec3::new(0.0, -3000.0, 300.0),
        target_m: centre,
        up: DVec3::Z,
        fov_y_deg: 45.0,
        width,
        height,
    };
    let start = Instant::now();
    let (image, stats) = cloud.render_transmittance(&camera, None)?;
    let render = start.elapsed();
    let start = Instant::now();
    let (_, stats_lod) = cloud.render_transmittance(&camera, Some(1.0))?;
    let render_lod = start.elapsed();
    let covered = image.iter().filter(|t| **t < 0.99).count();
    Ok(SpheresBench {
        levels,
        leaves: cloud.leaves().len(),
        width,
        height,
        build,
        render,
        render_lod,
        stats,
        stats_lod,
        coverage: covered as f64 / image.len() as f64,
    })
}

/// Timing of one voxelisation, for `skybake-harness bench metaball_voxelize`.
#[derive(Debug, Clone, Serialize)]
pub struct VoxelizeBench {
    /// Number of metaballs.
    pub balls: usize,
    /// Voxels written.
    pub voxels: usize,
    /// Wall-clock time of building the bins and voxelising, seconds.
    pub seconds: f64,
    /// Throughput, voxels per second.
    pub voxels_per_second: f64,
}

/// Benchmark: `n_balls` random balls (fixed seed) in a 2 km cumulus-sized box, voxelised at
/// `voxel_size_m` (e.g. 20 m ≈ 100³ voxels).
pub fn bench_metaball_voxelize(n_balls: usize, voxel_size_m: f64) -> Result<VoxelizeBench> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x5eed);
    let balls: Vec<Metaball> = (0..n_balls.min(MAX_BALLS))
        .map(|_| Metaball {
            centre_m: DVec3::new(
                rng.random_range(-800.0..800.0),
                rng.random_range(-800.0..800.0),
                rng.random_range(200.0..1400.0),
            ),
            radius_m: rng.random_range(60.0..250.0),
            density: rng.random_range(0.2..1.0),
        })
        .collect();
    let start = Instant::now();
    let field = MetaballField::new(balls)?;
    let grid = field.voxelize(voxel_size_m, 0.0)?;
    let seconds = start.elapsed().as_secs_f64();
    Ok(VoxelizeBench {
        balls: field.balls().len(),
        voxels: grid.data.len(),
        seconds,
        voxels_per_second: grid.data.len() as f64 / seconds.max(1e-12),
    })
}

/// Timing of one growth, for `skybake-harness bench fractal_grow`.
#[derive(Debug, Clone, Serialize)]
pub struct GrowBench {
    /// Balls in the grown cloud.
    pub balls: usize,
    /// Triangles extracted over all levels.
    pub triangles: usize,
    /// Wall-clock time, seconds.
    pub seconds: f64,
}

/// Benchmark: a five-ball cumulus grown over `levels` levels with default parameters.
pub fn bench_fractal_grow(levels: u32) -> Result<GrowBench> {
    let mut params = FractalParams::new(example_cumulus_base());
    params.levels = levels;
    let start = Instant::now();
    let cloud = grow(&params)?;
    Ok(GrowBench {
        balls: cloud.balls.len(),
        triangles: cloud.levels.iter().map(|l| l.triangles).sum(),
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Timing of one fit, for `skybake-harness bench satellite_fit`.
#[derive(Debug, Clone, Serialize)]
pub struct FitBench {
    /// Image side, pixels.
    pub side_px: usize,
    /// Blobs fitted.
    pub balls: usize,
    /// Final relative error.
    pub error: f64,
    /// Wall-clock time, seconds.
    pub seconds: f64,
}

/// Benchmark: fit a synthetic `side_px`² field of Gaussian cloud cells (fixed seed).
pub fn bench_satellite_fit(side_px: usize) -> Result<FitBench> {
    let img = synthetic_cloud_field(side_px, 7)?;
    let params = SatelliteParams::new("synthetic");
    let start = Instant::now();
    let fitted = fit(&img, &params)?;
    Ok(FitBench {
        side_px,
        balls: fitted.blobs.len(),
        error: fitted.error,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// `skybake-harness bench solar-position`: computes `n` positions over a year at one site and returns the
/// sum of their elevations without refraction (so the work cannot be optimised away). The inputs
/// are valid; an error would show as a NaN sum.
pub fn bench_solar_position(n: usize) -> f64 {
    let start = DateTime::<Utc>::from_timestamp(1_704_067_200, 0).unwrap_or_default();
    let step_s = 31_536_000 / n.max(1) as i64;
    (0..n)
        .map(|i| {
            let time = start + chrono::Duration::seconds(step_s * i as i64);
            solar_position(&SpaInput::new(47.37, 8.54, time)).map_or(f64::NAN, |p| p.elevation_deg)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metaball_voxelize_reports_throughput() {
        let r = bench_metaball_voxelize(200, 80.0).unwrap();
        assert_eq!(r.balls, 200);
        assert!(r.voxels > 0 && r.voxels_per_second > 0.0);
    }
}
