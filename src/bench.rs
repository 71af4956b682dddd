//! In-process benchmarks behind `skybake bench NAME…` (median wall-clock times), so users can
//! size their machines with the same code paths the service runs.

use crate::engine::{DomeShape, Engine};
use crate::spec::{CommonSpec, RequestParams};
use crate::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// One benchmark's result.
#[derive(Debug, Clone, Serialize)]
pub struct BenchResult {
    pub name: String,
    /// `cold`: shared tables built inside the timed region; `warm`: already built.
    pub variant: &'static str,
    pub runs: usize,
    pub median_ms: f64,
    pub min_ms: f64,
    pub description: String,
}

/// Named benchmarks and what they measure.
pub const BENCHMARKS: &[(&str, &str)] = &[
    (
        "sun",
        "sun product (transmittance, DNI, DHI, GHI), 16 wavelengths, precise method",
    ),
    (
        "sky-fast",
        "sky table 129×64, 16 wavelengths, fast multiple scattering",
    ),
    (
        "sky-precise",
        "sky table 129×64, 16 wavelengths, precise multiple scattering",
    ),
];

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
    CommonSpec::from_params(&p, -18.0)
}

/// Runs the named benchmarks (all when `names` is empty); `cold_runs`/`warm_runs` repetitions.
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
    let shape = DomeShape {
        elevation_count: 129,
        azimuth_count: 64,
    };
    let mut out = Vec::new();
    for name in selected {
        let desc = BENCHMARKS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, d)| d.to_string())
            .unwrap_or_default();
        let (method, is_sun) = match name {
            "sun" => ("precise", true),
            "sky-fast" => ("fast", false),
            _ => ("precise", false),
        };
        let s = spec(method)?;
        let run_once = |engine: &Engine| -> Result<()> {
            if is_sun {
                engine.sun(&s).map(|_| ())
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
            description: desc.clone(),
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
            description: desc,
        });
    }
    Ok(out)
}
