//! In-process benchmarks behind `skybake-harness bench NAME…` (median wall-clock times), so users can
//! size their machines with the same code paths the service runs: the atmosphere products, the
//! cloud density sources (the automaton step of Dobashi et al. 2000, Ostroushko et al.'s table 1, metaballs, fractal growth,
//! satellite fitting), the solar position and the tile store.

use skybake_engine::engine::{DomeShape, Engine};
use skybake_engine::spec::{CommonSpec, DomeSpec, ProductKind, ProductSpec};
use skybake_product::params::RequestParams;

use crate::physics_bench::{
    bench_ca_step, bench_fractal_grow, bench_metaball_voxelize, bench_satellite_fit,
    bench_solar_position, bench_spheres, SpheresBench,
};

use crate::process::{load_average, process_cpu_ms};
use crate::{Error, Result};
use serde::Serialize;
use serde_json::json;
use std::time::{Duration, Instant};

/// One benchmark's result.
#[derive(Debug, Clone, Serialize)]
pub struct BenchResult {
    pub name: String,
    /// Atmosphere products: `cold`, shared tables built inside the timed region, or `warm`,
    /// already built. Others: what one timed run is (`step`, `K6`, `encode`, `run`, …).
    pub variant: &'static str,
    pub runs: usize,
    pub median_ms: f64,
    pub min_ms: f64,
    pub description: String,
    /// Benchmark-specific figures (sizes, counts, the paper's times); absent for the atmosphere.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub details: Option<serde_json::Value>,
}

/// Named benchmarks and what they measure.
pub const BENCHMARKS: &[(&str, &str)] = &[
    (
        "sun",
        "sun product (transmittance, DNI, DHI, GHI), 16 wavelengths, precise method",
    ),
    (
        "sky-fast",
        "sky table 129×64, 16 wavelengths, a method=fast request (the fast method is retired: the precise tables at the draft preset)",
    ),
    (
        "sky-hillaire",
        "sky table 129×64, 16 wavelengths, the retired fast method itself (Hillaire 2020, standard preset), for comparison",
    ),
    (
        "sky-precise",
        "sky table 129×64, 16 wavelengths, precise multiple scattering",
    ),
    (
        "precise-tables",
        "precise multiple-scattering tables + sky 129×64: cold (built), stored (loaded from the table cache, as a second process sees it), warm; 1/16/47/64 wavelengths, every quality, earth-hazy",
    ),
    (
        "ca-step",
        "cloud automaton step, 256×256×20 cells, median of 100 steps after 20 (Dobashi et al. 2000: 500 ms)",
    ),
    (
        "spheres",
        "sphere-hierarchy 800×600 transmittance, K = 6, 8, 10 (Ostroushko et al., table 1: 4.75, 9.2, 22.1 s)",
    ),
    (
        "metaballs",
        "voxelise 1000 random metaballs in a 2 km box at 20 m (bins + parallel evaluation)",
    ),
    (
        "fractal",
        "fractal growth of a five-ball cumulus over 3 levels (marching cubes + new balls)",
    ),
    (
        "satellite",
        "greedy metaball fit to a synthetic 128×128 satellite image",
    ),
    (
        "solar-position",
        "100 000 SPA solar positions over a year at one site",
    ),
    (
        "frame",
        "lit cloud frame 640×480, 128³ cumulus, sky + ground light + multiple scattering, standard quality, cold and warm",
    ),
    (
        "frame-pattern",
        "the frame benchmark with multiple scattering of orders 2 and 3 by the reference pattern (Nishita et al. 1996, §3.4) instead of all orders",
    ),
    (
        "frame-sequence",
        "60-frame fly-around of the frame benchmark's cumulus, 640×480, standard quality: the cloud lit once, each camera's source and pixels per frame (per-frame time and stage split)",
    ),
    (
        "frame-accuracy",
        "fast frame method against the path tracer (1024 spp), bench cumulus at 160×120 (slow: minutes)",
    ),
    (
        "store",
        "EXR encode/decode/verify and cache put/get, 256×128 px, 16 wavelengths + RGB, zip; with SKYBAKE_BENCH_BUCKET=s3://… (AWS_* variables) also put/get through that bucket",
    ),
];

/// Cells of the `ca-step` benchmark (Dobashi et al. 2000, §6) and steps timed.
const CA_DIMS: [usize; 3] = [256, 256, 20];
const CA_STEPS: usize = 100;
/// Image and levels of the `spheres` benchmark (Ostroushko et al., table 1) and the paper's times, ms.
const SPHERES_IMAGE: (usize, usize) = (800, 600);
const SPHERES_LEVELS: [(u32, &str, f64); 3] =
    [(6, "K6", 4750.0), (8, "K8", 9200.0), (10, "K10", 22100.0)];

fn median(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[0])
}

fn time_runs(runs: usize, mut f: impl FnMut() -> Result<()>) -> Result<(f64, f64)> {
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        let t = Instant::now();
        f()?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(times))
}

fn spec(method: &str) -> Result<CommonSpec> {
    let p = RequestParams {
        method: Some(method.into()),
        sun_elevation_deg: Some("20".into()),
        ..Default::default()
    };
    skybake_product::params::common_spec(&p, -18.0)
}

/// Runs the named benchmarks (all when `names` is empty). The atmosphere products run `cold_runs`
/// times on fresh engines and `warm_runs` times on a warm one; every other benchmark runs
/// `warm_runs` times (`ca-step` always times 100 steps).
pub fn run(names: &[String], cold_runs: usize, warm_runs: usize) -> Result<Vec<BenchResult>> {
    let known: Vec<&str> = BENCHMARKS.iter().map(|(n, _)| *n).collect();
    let selected: Vec<&str> = if names.is_empty() {
        known.clone()
    } else {
        names
            .iter()
            .map(|n| {
                known.iter().copied().find(|k| k == n).ok_or_else(|| {
                    Error::invalid(
                        "name",
                        format!("unknown benchmark '{n}' (known: {})", known.join(", ")),
                    )
                })
            })
            .collect::<Result<_>>()?
    };
    let mut out = Vec::new();
    for name in selected {
        let desc = BENCHMARKS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, d)| d.to_string())
            .unwrap_or_default();
        // One result from per-run times in ms (median and minimum taken here).
        let entry = |variant: &'static str, runs: usize, times_ms: Vec<f64>, details| {
            let (median_ms, min_ms) = median(times_ms);
            BenchResult {
                name: name.into(),
                variant,
                runs,
                median_ms,
                min_ms,
                description: desc.clone(),
                details: Some(details),
            }
        };
        match name {
            "ca-step" => {
                let [nx, ny, nz] = CA_DIMS;
                let b = bench_ca_step(nx, ny, nz, CA_STEPS)?;
                // The automaton reports the median and minimum of its per-step times.
                out.push(BenchResult {
                    min_ms: ms(b.min_step),
                    ..entry(
                        "step",
                        b.steps,
                        vec![ms(b.median_step)],
                        json!({
                            "dims": b.dims,
                            "mean_step_ms": ms(b.mean_step),
                            "cloud_cover": b.cloud_cover,
                            "paper_step_ms": 500.0,
                            "target_step_ms": 1.0,
                        }),
                    )
                });
            }
            "spheres" => {
                let (w, h) = SPHERES_IMAGE;
                for (levels, variant, paper_ms) in SPHERES_LEVELS {
                    let runs: Vec<_> = (0..warm_runs)
                        .map(|_| bench_spheres(levels, w, h))
                        .collect::<Result<_>>()?;
                    let pick = |f: fn(&SpheresBench) -> Duration| {
                        median(runs.iter().map(|b| ms(f(b))).collect()).0
                    };
                    let last = &runs[runs.len() - 1];
                    out.push(entry(
                        variant,
                        warm_runs,
                        runs.iter().map(|b| ms(b.render)).collect(),
                        json!({
                            "levels": levels,
                            "leaves": last.leaves,
                            "image": [w, h],
                            "build_ms": pick(|b| b.build),
                            "render_lod_ms": pick(|b| b.render_lod),
                            "spheres_tested": last.stats.spheres_tested,
                            "spheres_tested_lod": last.stats_lod.spheres_tested,
                            "coverage": last.coverage,
                            "paper_ms": paper_ms,
                        }),
                    ));
                }
            }
            "metaballs" => {
                let (times, last) = repeat(
                    warm_runs,
                    || bench_metaball_voxelize(1000, 20.0),
                    |b| b.seconds,
                )?;
                out.push(entry(
                    "run",
                    warm_runs,
                    times,
                    json!({
                        "balls": last.balls,
                        "voxels": last.voxels,
                        "voxels_per_second": last.voxels_per_second,
                    }),
                ));
            }
            "fractal" => {
                let (times, last) = repeat(warm_runs, || bench_fractal_grow(3), |b| b.seconds)?;
                out.push(entry(
                    "run",
                    warm_runs,
                    times,
                    json!({"levels": 3, "balls": last.balls, "triangles": last.triangles}),
                ));
            }
            "satellite" => {
                let (times, last) = repeat(warm_runs, || bench_satellite_fit(128), |b| b.seconds)?;
                out.push(entry(
                    "run",
                    warm_runs,
                    times,
                    json!({"side_px": last.side_px, "balls": last.balls, "error": last.error}),
                ));
            }
            "solar-position" => {
                const N: usize = 100_000;
                let mut checksum = 0.0;
                let times: Vec<f64> = (0..warm_runs)
                    .map(|_| {
                        let t = Instant::now();
                        checksum += bench_solar_position(N);
                        ms(t.elapsed())
                    })
                    .collect();
                let per_position_ns = median(times.clone()).0 * 1e6 / N as f64;
                out.push(entry(
                    "run",
                    warm_runs,
                    times,
                    json!({
                        "positions": N,
                        "median_ns_per_position": per_position_ns,
                        "checksum_deg": checksum,
                    }),
                ));
            }
            "store" => out.extend(bench_store_stages(&entry, warm_runs)?),
            "precise-tables" => out.extend(precise_tables(&desc, cold_runs, warm_runs)?),
            "frame" | "frame-pattern" => {
                let runs: Vec<_> = (0..warm_runs.max(1))
                    .map(|_| {
                        if name == "frame" {
                            crate::frame_bench::bench_frame(640, 480)
                        } else {
                            crate::frame_bench::bench_frame_pattern(640, 480)
                        }
                    })
                    .collect::<Result<_>>()?;
                let last = &runs[runs.len() - 1];
                out.push(entry(
                    "cold",
                    runs.len(),
                    runs.iter().map(|b| b.cold_ms).collect(),
                    json!({"lighting_ms": last.lighting_cold_ms, "image": [last.width, last.height], "voxels": last.voxels}),
                ));
                out.push(entry(
                    "warm",
                    runs.len(),
                    runs.iter().map(|b| b.warm_ms).collect(),
                    json!({"lighting_ms": last.lighting_warm_ms, "stages_ms": last.warm_stages_ms,
                           "cpu_ms": runs.iter().map(|b| b.warm_cpu_ms).collect::<Vec<_>>(),
                           "image": [last.width, last.height], "voxels": last.voxels}),
                ));
            }
            "frame-sequence" => {
                let runs: Vec<_> = (0..warm_runs.max(1))
                    .map(|_| crate::frame_bench::bench_frame_sequence(60, 640, 480))
                    .collect::<Result<_>>()?;
                let last = &runs[runs.len() - 1];
                out.push(entry(
                    "per_frame",
                    runs.len(),
                    runs.iter().map(|b| b.per_frame_ms).collect(),
                    json!({"frames": last.frames, "image": [last.width, last.height],
                           "per_frame_cpu_ms": runs.iter().map(|b| b.per_frame_cpu_ms).collect::<Vec<_>>(),
                           "total_ms": last.total_ms, "first_frame_ms": last.first_frame_ms,
                           "median_later_frame_ms": last.median_later_frame_ms,
                           "stages_ms": last.stages_ms, "lit_bytes": last.lit_bytes}),
                ));
            }
            "frame-accuracy" => {
                let (e, noise, fast_ms, ref_ms) =
                    crate::frame_bench::bench_frame_accuracy(160, 120, 1024)?;
                out.push(entry(
                    "run",
                    1,
                    vec![fast_ms],
                    json!({"errors": e, "reference_noise": noise, "reference_ms": ref_ms, "image": [160, 120]}),
                ));
            }
            _ => out.extend(atmosphere(name, &desc, cold_runs, warm_runs)?),
        }
    }
    Ok(out)
}

/// Calls `bench` `runs` (>= 1) times: the times in ms (from each result's own `seconds`, which
/// leaves out building the inputs) and the last result.
fn repeat<B>(
    runs: usize,
    bench: impl Fn() -> Result<B>,
    seconds: impl Fn(&B) -> f64,
) -> Result<(Vec<f64>, B)> {
    let mut times = Vec::with_capacity(runs);
    let mut last = bench()?;
    times.push(seconds(&last) * 1e3);
    for _ in 1..runs {
        last = bench()?;
        times.push(seconds(&last) * 1e3);
    }
    Ok((times, last))
}

/// Milliseconds in a duration.
fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// `store`: each stage of [`skybake_store::bench_store`] as its own entry, medians over `runs` calls of
/// one repetition each, in a scratch directory under the system temp directory.
fn bench_store_stages(
    entry: &dyn Fn(&'static str, usize, Vec<f64>, serde_json::Value) -> BenchResult,
    runs: usize,
) -> Result<Vec<BenchResult>> {
    let dir = std::env::temp_dir();
    let bucket = match std::env::var("SKYBAKE_BENCH_BUCKET") {
        Ok(url) if !url.trim().is_empty() => Some(std::sync::Arc::new(
            skybake_store::Bucket::open(url.trim(), &[], skybake_store::RetryPolicy::default())
                .map_err(|e| Error::invalid("SKYBAKE_BENCH_BUCKET", e.to_string()))?,
        )),
        _ => None,
    };
    let runs_out: Vec<crate::store_bench::StoreBench> = (0..runs)
        .map(|_| {
            crate::store_bench::bench_store(
                &dir,
                256,
                128,
                16,
                skybake_store::ExrCompression::Zip,
                1,
                bucket.as_ref(),
            )
            .map_err(|e| match e {
                skybake_store::StoreError::Invalid(e) => e,
                other => Error::invalid("store", other.to_string()),
            })
        })
        .collect::<Result<_>>()?;
    let last = &runs_out[runs_out.len() - 1];
    let details = json!({
        "image": [last.width, last.height],
        "wavelengths": last.wavelengths,
        "payload_bytes": last.payload_bytes,
        "file_bytes": last.file_bytes,
    });
    type Stage = (&'static str, fn(&crate::store_bench::StoreBench) -> f64);
    let stages: [Stage; 6] = [
        ("encode", |b| b.encode_ms),
        ("decode", |b| b.decode_ms),
        ("verify", |b| b.verify_ms),
        ("cache-put", |b| b.cache_put_ms),
        ("cache-disk-get", |b| b.cache_disk_get_ms),
        ("cache-memory-get", |b| b.cache_memory_get_ms),
    ];
    let mut out: Vec<BenchResult> = stages
        .into_iter()
        .map(|(variant, f)| {
            entry(
                variant,
                runs,
                runs_out.iter().map(f).collect(),
                details.clone(),
            )
        })
        .collect();
    if let Some(bucket) = &bucket {
        let details = json!({"bucket": bucket.url(), "file_bytes": last.file_bytes});
        type BucketStage = (
            &'static str,
            fn(&crate::store_bench::StoreBench) -> Option<f64>,
        );
        let stages: [BucketStage; 2] = [
            ("bucket-put", |b| b.bucket_put_ms),
            ("bucket-get", |b| b.bucket_get_ms),
        ];
        for (variant, f) in stages {
            let times = runs_out.iter().filter_map(f).collect();
            out.push(entry(variant, runs, times, details.clone()));
        }
    }
    Ok(out)
}

/// Cases of `precise-tables`: atmosphere, quality, number of wavelengths.
const PRECISE_CASES: &[(&str, &str, usize)] = &[
    ("earth", "standard", 1),
    ("earth", "standard", 16),
    ("earth", "standard", 47),
    ("earth", "standard", 64),
    ("earth", "draft", 16),
    ("earth", "high", 16),
    ("earth", "reference", 16),
    ("earth-hazy", "standard", 16),
];

/// `n` wavelengths evenly spread over 380–755 nm (the default set's span) for n ≤ 16, else over
/// 370–830 nm (47 at 10 nm) or 360–826 nm (64).
fn wavelength_list(n: usize) -> String {
    let (from, to) = match n {
        1 => return "550".into(),
        2..=16 => (380.0, 755.0),
        17..=47 => (370.0, 830.0),
        _ => (360.0, 826.2),
    };
    (0..n)
        .map(|i| format!("{:.2}", from + (to - from) * i as f64 / (n - 1) as f64))
        .collect::<Vec<_>>()
        .join(",")
}

/// Wall and CPU time of one run of `f`, ms.
fn timed<T>(f: impl FnOnce() -> Result<T>) -> Result<(T, f64, Option<f64>)> {
    let (t, cpu) = (Instant::now(), process_cpu_ms());
    let out = f()?;
    let wall = ms(t.elapsed());
    Ok((out, wall, cpu.zip(process_cpu_ms()).map(|(a, b)| b - a)))
}

/// Median of CPU times (when every run has one).
fn median_cpu(v: &[Option<f64>]) -> Option<f64> {
    let v: Option<Vec<f64>> = v.iter().copied().collect();
    v.filter(|v| !v.is_empty()).map(|v| median(v).0)
}

/// `precise-tables`: per case, the cold build (fresh engine on an empty table store: build and
/// save, what a first CLI call does), a fresh engine on the store that now holds the tables (what
/// a second CLI call or a restarted server does: density and precise tables loaded), and a warm
/// engine; details carry the orders, the extrapolated tail, the time per stage, the CPU time
/// (user + system, all threads) beside the wall time, and the load average while measuring.
fn precise_tables(desc: &str, cold_runs: usize, warm_runs: usize) -> Result<Vec<BenchResult>> {
    use skybake_store::tables::CacheTableStore;
    use skybake_store::{Cache, CacheConfig};
    use std::sync::Arc;
    let shape = DomeShape {
        elevation_count: 129,
        azimuth_count: 64,
    };
    let dir = std::env::temp_dir().join(format!("skybake-bench-tables-{}", std::process::id()));
    let open_store = || -> Result<Arc<CacheTableStore>> {
        let cache = Cache::open(CacheConfig::new(&dir, 16 << 30, 1 << 30))
            .map_err(|e| Error::invalid("bench", e.to_string()))?;
        Ok(Arc::new(CacheTableStore::new(Arc::new(cache))))
    };
    let mut out = Vec::new();
    for &(atmosphere, quality, n) in PRECISE_CASES {
        let p = RequestParams {
            method: Some("precise".into()),
            sun_elevation_deg: Some("20".into()),
            atmosphere: Some(atmosphere.into()),
            quality: Some(quality.into()),
            wavelengths: Some(wavelength_list(n)),
            ..Default::default()
        };
        let s = skybake_product::params::common_spec(&p, -18.0)?;
        let name = format!("precise-tables {atmosphere} {quality} {n}λ");
        let load_before = load_average();
        let (mut cold, mut cold_cpu) = (Vec::new(), Vec::new());
        let mut details = serde_json::Value::Null;
        for _ in 0..cold_runs {
            let _ = std::fs::remove_dir_all(&dir);
            let engine = Engine::with_table_store(open_store()?);
            let t = Instant::now();
            let cpu0 = process_cpu_ms();
            // The medium, the density-integral table (built and saved), then the precise table
            // (built and saved) and the dome.
            let shared = engine.shared(&s)?;
            shared.density();
            let density_ms = ms(t.elapsed());
            engine.sky(&s, shape, &[])?;
            let total_ms = ms(t.elapsed());
            cold.push(total_ms);
            cold_cpu.push(cpu0.zip(process_cpu_ms()).map(|(a, b)| b - a));
            let c = &shared.precise().convergence;
            details = json!({
                "atmosphere": atmosphere,
                "quality": quality,
                "wavelengths": n,
                "orders": c.orders,
                "last_order_fraction": c.last_order_fraction,
                "tail_fraction": c.tail_fraction,
                "series_error_estimate": c.series_error_estimate,
                "order_ratio": c.order_ratio,
                "stage_ms": {
                    "density_table": density_ms,
                    "precise_single_scattering": c.stage_ms.single_scattering,
                    "precise_scattering_density": c.stage_ms.scattering_density,
                    "precise_radiance": c.stage_ms.radiance,
                    "precise_total": c.stage_ms.total,
                    // The dome table, and saving the table to the store.
                    "dome_and_save": total_ms - density_ms - c.stage_ms.total,
                },
            });
        }
        // Fresh engines that load the tables the cold run stored.
        let (mut stored, mut stored_cpu) = (Vec::new(), Vec::new());
        for _ in 0..cold_runs {
            let ((), wall, cpu) = timed(|| {
                Engine::with_table_store(open_store()?)
                    .sky(&s, shape, &[])
                    .map(|_| ())
            })?;
            stored.push(wall);
            stored_cpu.push(cpu);
        }
        let engine = Engine::new();
        engine.sky(&s, shape, &[])?;
        let (mut warm, mut warm_cpu) = (Vec::new(), Vec::new());
        for _ in 0..warm_runs {
            let ((), wall, cpu) = timed(|| engine.sky(&s, shape, &[]).map(|_| ()))?;
            warm.push(wall);
            warm_cpu.push(cpu);
        }
        let load_after = load_average();
        for (variant, runs, times, cpu) in [
            ("cold", cold_runs, cold, cold_cpu),
            ("stored", cold_runs, stored, stored_cpu),
            ("warm", warm_runs, warm, warm_cpu),
        ] {
            let (median_ms, min_ms) = median(times);
            let mut d = details.clone();
            if let Some(m) = d.as_object_mut() {
                m.insert("cpu_ms_median".into(), json!(median_cpu(&cpu)));
                m.insert(
                    "load_average".into(),
                    json!({"before": load_before, "after": load_after}),
                );
            }
            out.push(BenchResult {
                name: name.clone(),
                variant,
                runs,
                median_ms,
                min_ms,
                description: desc.to_string(),
                details: Some(d),
            });
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(out)
}

/// The atmosphere products `sun`, `sky-fast`, `sky-hillaire`, `sky-precise`: cold and warm engines.
fn atmosphere(
    name: &str,
    desc: &str,
    cold_runs: usize,
    warm_runs: usize,
) -> Result<Vec<BenchResult>> {
    let shape = DomeShape {
        elevation_count: 129,
        azimuth_count: 64,
    };
    let mut out = Vec::new();
    let (method, is_sun) = match name {
        "sun" => ("precise", true),
        "sky-fast" => ("fast", false),
        _ => ("precise", false),
    };
    let s = spec(method)?;
    // `sky-hillaire`: the paper's method on the precise request's spec (no request runs it).
    let hillaire = (name == "sky-hillaire")
        .then(|| Engine::plan(&s, ProductKind::Sky).map(|p| p.with_paper_fast_method(s.quality)))
        .transpose()?;
    let sky = ProductSpec::Sky(DomeSpec::sky(shape, Vec::new())?);
    let run_once = |engine: &Engine| -> Result<()> {
        if is_sun {
            engine.sun(&s).map(|_| ())
        } else if let Some(plan) = &hillaire {
            engine.execute(&s, &sky, plan).map(|_| ())
        } else {
            engine.sky(&s, shape, &[]).map(|_| ())
        }
    };
    let (cold, cold_min) = time_runs(cold_runs, || run_once(&Engine::new()))?;
    out.push(BenchResult {
        name: name.into(),
        variant: "cold",
        runs: cold_runs,
        median_ms: cold,
        min_ms: cold_min,
        description: desc.to_string(),
        details: None,
    });
    let engine = Engine::new();
    run_once(&engine)?;
    let (warm, warm_min) = time_runs(warm_runs, || run_once(&engine))?;
    out.push(BenchResult {
        name: name.into(),
        variant: "warm",
        runs: warm_runs,
        median_ms: warm,
        min_ms: warm_min,
        description: desc.to_string(),
        details: None,
    });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_are_refused_listing_the_known_ones() {
        let err = run(&["ca_step".to_string()], 1, 1).unwrap_err();
        assert_eq!(err.field(), "name");
        assert!(err.to_string().contains("ca-step"), "{err}");
    }

    /// Each selected benchmark reports timed runs and its own figures; the store benchmark
    /// reports every stage and leaves no scratch directory behind.
    #[test]
    fn cloud_and_store_benchmarks_report_runs_and_figures() {
        let names: Vec<String> = ["fractal", "satellite", "store"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let results = run(&names, 1, 2).unwrap();
        let variants: Vec<(&str, &str)> = results
            .iter()
            .map(|r| (r.name.as_str(), r.variant))
            .collect();
        assert_eq!(
            variants,
            [
                ("fractal", "run"),
                ("satellite", "run"),
                ("store", "encode"),
                ("store", "decode"),
                ("store", "verify"),
                ("store", "cache-put"),
                ("store", "cache-disk-get"),
                ("store", "cache-memory-get"),
            ]
        );
        for r in &results {
            assert_eq!(r.runs, 2);
            assert!(r.min_ms > 0.0 && r.min_ms <= r.median_ms, "{r:?}");
            assert!(r.details.is_some());
        }
        let fractal = results[0].details.as_ref().unwrap();
        assert!(fractal["balls"].as_u64().unwrap() > 5);
        let fit_error = results[1].details.as_ref().unwrap()["error"]
            .as_f64()
            .unwrap();
        assert!((0.0..1.0).contains(&fit_error));
        let scratch = std::env::temp_dir().join(format!("skybake-bench-{}", std::process::id()));
        assert!(!scratch.exists());
    }
}
