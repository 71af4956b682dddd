//! `skybake-harness report`: error against run time for every atmosphere product and
//! method, over the quality presets, in several regimes (sun elevation band, observer altitude
//! band, aerosol load).
//!
//! Every point runs the product through the same path a user's request runs
//! ([`ProductRequest::from_params`] → [`Engine::compute`]) and is compared with the converged
//! reference: the **precise** method at the `reference` preset, in the same regime, on the same
//! table shape and wavelengths. That reference is itself checked against independent codes by
//! `tests/atmosphere/atmosphere_validation.rs` (DISORT) and `tests/atmosphere/atmosphere_twilight.rs` (spherical Monte
//! Carlo). So the fast method's curve levels off at its model error, which is what a user pays.
//!
//! Error measures, over every table cell (or spectral value) `x` against its reference `r`:
//! - `rel_rms = sqrt(Σ(x − r)² / Σ r²)`, the normalised RMS;
//! - `rel_max = max |x − r| / max(|r|, 10⁻³·max|r|)`, the largest relative deviation, with a floor
//!   so the few near-zero cells (below the horizon at twilight) do not dominate.
//!
//! Time: `cold_ms` = building the shared tables the method needs + `warm_ms`, the product itself
//! with the tables built (what a flight simulator's repeated requests pay).
//!
//! Output (`write`): `report.json` (the data, also compiled into the binary for quality-by-target,
//! see [`skybake_engine::accuracy`]), `README.md` (tables) and one log–log PNG of error against time per
//! product ([`plot`]); the cloud frames' part ([`frames`]) in `frames.json` and one PNG per frame.

pub mod external;
pub mod frames;
pub mod planner;
pub mod plot;

use skybake_engine::accuracy::{band_of_altitude, band_of_sun};
pub use skybake_engine::accuracy::{Curve, Point, Regime, Report, PRESETS};

use crate::{Error, Result};
use skybake_engine::engine::{Engine, Product};
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_product::params::RequestParams;
use skybake_product::{ProductKind, ProductRequest};
use std::path::Path;
use std::time::Instant;

/// What `skybake-harness report` runs.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    pub quick: bool,
}

/// Products, methods and regimes of a run.
struct Sweep {
    wavelengths: &'static str,
    dome: [usize; 2],
    aerial_distances: usize,
    regimes: Vec<Regime>,
    products: Vec<ProductKind>,
}

fn regime(atmosphere: &str, aerosol: &str, sun: f64, altitude: f64) -> Regime {
    let sun_band = band_of_sun(sun).unwrap_or("night");
    let altitude_band = band_of_altitude(altitude).unwrap_or("space");
    Regime {
        name: format!("{aerosol}/{sun_band}/{altitude_band}"),
        atmosphere: atmosphere.into(),
        sun_elevation_deg: sun,
        observer_altitude_m: altitude,
        sun_band: sun_band.into(),
        altitude_band: altitude_band.into(),
        aerosol_band: aerosol.into(),
    }
}

impl Sweep {
    fn new(quick: bool) -> Self {
        if quick {
            return Self {
                wavelengths: "440,550,680",
                dome: [33, 32],
                aerial_distances: 16,
                regimes: vec![regime("earth", "clear", 45.0, 0.0)],
                products: vec![ProductKind::Sun, ProductKind::Sky],
            };
        }
        let mut regimes = Vec::new();
        for (atmosphere, aerosol) in [("earth", "clear"), ("earth-hazy", "hazy")] {
            for sun in [45.0, 10.0, -4.0] {
                for altitude in [0.0, 10_000.0] {
                    regimes.push(regime(atmosphere, aerosol, sun, altitude));
                }
            }
        }
        Self {
            wavelengths: "440,550,680",
            dome: [65, 64],
            aerial_distances: 32,
            regimes,
            products: ProductKind::ALL.to_vec(),
        }
    }

    fn params(&self, r: &Regime, method: MsMethod, quality: Quality) -> RequestParams {
        let name = |q: Quality| match q {
            Quality::Draft => "draft",
            Quality::Standard => "standard",
            Quality::High => "high",
            Quality::Reference => "reference",
        };
        RequestParams {
            atmosphere: Some(r.atmosphere.clone()),
            wavelengths: Some(self.wavelengths.into()),
            sun_elevation_deg: Some(r.sun_elevation_deg.to_string()),
            observer_altitude_m: Some(r.observer_altitude_m.to_string()),
            method: Some(method_name(method).into()),
            quality: Some(name(quality).into()),
            ..Default::default()
        }
    }

    fn request(
        &self,
        product: ProductKind,
        r: &Regime,
        method: MsMethod,
        quality: Quality,
    ) -> Result<ProductRequest> {
        let mut p = self.params(r, method, quality);
        match product {
            ProductKind::Sky | ProductKind::Ground => {
                p.elevation_count = Some(self.dome[0].to_string());
                p.azimuth_count = Some(self.dome[1].to_string());
            }
            ProductKind::Aerial => {
                p.elevation_count = Some("9".into());
                p.azimuth_count = Some("8".into());
                p.distance_count = Some(self.aerial_distances.to_string());
            }
            ProductKind::Sun => {}
        }
        ProductRequest::from_params(product, &p)
    }
}

fn method_name(m: MsMethod) -> &'static str {
    match m {
        MsMethod::Fast => "fast",
        MsMethod::Precise => "precise",
        MsMethod::None => "none",
    }
}

/// The values a product is compared on: radiance tables, irradiance spectra, or aerial
/// in-scattered radiance and transmittance (as two series, the worse error counts).
fn series(product: &Product) -> Vec<Vec<f64>> {
    match product {
        Product::Sun(p) => vec![
            p.direct_normal_irradiance_w_m2_nm.clone(),
            p.diffuse_horizontal_irradiance_w_m2_nm.clone(),
        ],
        Product::Sky(p) | Product::Ground(p) => {
            vec![p.table.radiance.iter().map(|&v| f64::from(v)).collect()]
        }
        Product::Aerial(p) => vec![
            p.inscatter.iter().map(|&v| f64::from(v)).collect(),
            p.transmittance.iter().map(|&v| f64::from(v)).collect(),
        ],
    }
}

/// `(rel_rms, rel_max)` of `x` against `reference` (module docs); a series whose reference is
/// zero throughout (the direct sun below the horizon) counts only if `x` is not zero too.
pub fn errors(x: &[f64], reference: &[f64]) -> (f64, f64) {
    let peak = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if peak == 0.0 {
        let worst = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        return if worst == 0.0 {
            (0.0, 0.0)
        } else {
            (f64::INFINITY, f64::INFINITY)
        };
    }
    let floor = 1e-3 * peak;
    let (mut num, mut den, mut max) = (0.0, 0.0, 0.0f64);
    for (a, r) in x.iter().zip(reference) {
        num += (a - r) * (a - r);
        den += r * r;
        max = max.max((a - r).abs() / r.abs().max(floor));
    }
    ((num / den).sqrt(), max)
}

fn compare(x: &Product, reference: &Product) -> Result<(f64, f64)> {
    let (a, b) = (series(x), series(reference));
    if a.len() != b.len() || a.iter().zip(&b).any(|(u, v)| u.len() != v.len()) {
        return Err(Error::internal(
            "report",
            "a product and its reference differ in shape",
        ));
    }
    Ok(a.iter()
        .zip(&b)
        .map(|(u, v)| errors(u, v))
        .fold((0.0f64, 0.0f64), |(r, m), (r2, m2)| (r.max(r2), m.max(m2))))
}

/// Runs the sweep. `progress(done, total)` is called after every measured point.
pub fn run(options: &ReportOptions, progress: &dyn Fn(usize, usize)) -> Result<Report> {
    let sweep = Sweep::new(options.quick);
    let methods = [MsMethod::Fast, MsMethod::Precise];
    let atmospheres: Vec<String> = {
        let mut a: Vec<String> = sweep.regimes.iter().map(|r| r.atmosphere.clone()).collect();
        a.dedup();
        a
    };
    // The reference first, then every method and preset, each on a fresh engine so the table
    // build is timed. `--quick` leaves out the fast method at the reference preset (the slowest
    // fast table, and no closer to the reference than `high`).
    let runs: Vec<(Quality, MsMethod)> = PRESETS
        .iter()
        .rev()
        .flat_map(|&q| [(q, MsMethod::Precise), (q, MsMethod::Fast)])
        .filter(|&(q, m)| !(options.quick && q == Quality::Reference && m == MsMethod::Fast))
        .collect();
    let total = sweep.regimes.len() * sweep.products.len() * runs.len();
    let mut done = 0;
    // reference[(regime, product)], the precise method at the reference preset.
    let mut references: Vec<((usize, ProductKind), Product)> = Vec::new();
    let mut measured: Vec<(usize, ProductKind, MsMethod, Point)> = Vec::new();
    for &(quality, method) in &runs {
        {
            for atmosphere in &atmospheres {
                let engine = Engine::new();
                let regimes: Vec<usize> = (0..sweep.regimes.len())
                    .filter(|&i| &sweep.regimes[i].atmosphere == atmosphere)
                    .collect();
                let cpu_start = process_cpu_ms();
                let tables_ms = {
                    let req = sweep.request(
                        ProductKind::Sun,
                        &sweep.regimes[regimes[0]],
                        MsMethod::Precise,
                        quality,
                    )?;
                    let start = Instant::now();
                    let shared = engine.shared(&req.spec)?;
                    match method {
                        MsMethod::Precise => {
                            shared.precise();
                        }
                        MsMethod::Fast => {
                            shared.fast();
                        }
                        MsMethod::None => {}
                    }
                    start.elapsed().as_secs_f64() * 1e3
                };
                let tables_cpu = process_cpu_ms().zip(cpu_start).map(|(a, b)| a - b);
                for &ri in &regimes {
                    for &kind in &sweep.products {
                        // The fast rows are the paper's method (Hillaire 2020) run on the same
                        // spec: a `method=fast` request itself runs the precise tables now.
                        let req =
                            sweep.request(kind, &sweep.regimes[ri], MsMethod::Precise, quality)?;
                        let plan = Engine::plan(&req.spec, kind)?;
                        let plan = match method {
                            MsMethod::Fast => plan.with_paper_fast_method(quality),
                            _ => plan,
                        };
                        let cpu_before = process_cpu_ms();
                        let start = Instant::now();
                        let product = engine.execute(&req.spec, &req.product, &plan)?;
                        let warm_ms = start.elapsed().as_secs_f64() * 1e3;
                        let warm_cpu = process_cpu_ms().zip(cpu_before).map(|(a, b)| a - b);
                        let is_reference =
                            quality == Quality::Reference && method == MsMethod::Precise;
                        let (rel_rms, rel_max) = if is_reference {
                            (0.0, 0.0)
                        } else {
                            let reference = references
                                .iter()
                                .find(|((i, k), _)| *i == ri && *k == kind)
                                .map(|(_, p)| p)
                                .ok_or_else(|| Error::internal("report", "reference missing"))?;
                            compare(&product, reference)?
                        };
                        measured.push((
                            ri,
                            kind,
                            method,
                            Point {
                                quality,
                                cold_ms: tables_ms + warm_ms,
                                warm_ms,
                                cold_cpu_ms: tables_cpu.zip(warm_cpu).map(|(a, b)| a + b),
                                rel_rms,
                                rel_max,
                            },
                        ));
                        if is_reference {
                            references.push(((ri, kind), product));
                        }
                        done += 1;
                        progress(done, total);
                    }
                }
            }
        }
    }
    let mut curves = Vec::new();
    for (ri, r) in sweep.regimes.iter().enumerate() {
        for &kind in &sweep.products {
            for method in methods {
                let mut points: Vec<Point> = measured
                    .iter()
                    .filter(|(i, k, m, _)| *i == ri && *k == kind && *m == method)
                    .map(|(_, _, _, p)| p.clone())
                    .collect();
                points.sort_by_key(|p| PRESETS.iter().position(|q| *q == p.quality));
                curves.push(Curve {
                    product: kind,
                    method,
                    regime: r.name.clone(),
                    points,
                });
            }
        }
    }
    Ok(Report {
        engine_version: skybake_engine::engine::ENGINE_VERSION.into(),
        quick: options.quick,
        threads: rayon::current_num_threads(),
        machine_load: None,
        wavelengths_nm: sweep.wavelengths.into(),
        dome_shape: sweep.dome,
        reference: "precise method at the reference preset, same regime, shape and wavelengths"
            .into(),
        regimes: sweep.regimes,
        curves,
    })
}

pub(crate) use crate::process::process_cpu_ms;

/// Writes into `dir` what there is of the atmosphere part (`report.json`, one PNG per product) and
/// of the frame part (`frames.json`, `frames-<case>.png`), and `README.md` with both.
pub fn write(
    report: Option<&Report>,
    frames: Option<&frames::FrameReport>,
    dir: &Path,
) -> Result<Vec<std::path::PathBuf>> {
    skybake_store::files::create_dir_all(dir)?;
    let mut written = Vec::new();
    let mut put = |name: &str, bytes: &[u8]| -> Result<()> {
        let path = dir.join(name);
        skybake_store::write_atomic(&path, bytes)?;
        written.push(path);
        Ok(())
    };
    let mut readme = String::new();
    if let Some(report) = report {
        put("report.json", (pretty(report)? + "\n").as_bytes())?;
        let mut plots = Vec::new();
        for kind in products_of(report) {
            let name = format!("{}.png", kind.name());
            put(&name, &plot::error_time_png(report, kind)?)?;
            plots.push((kind, name));
        }
        readme.push_str(&markdown(report, &plots));
        readme.push_str(&external::markdown(report));
    } else {
        readme.push_str("# Error against run time\n\n");
    }
    if let Some(frames) = frames {
        put("frames.json", (pretty(frames)? + "\n").as_bytes())?;
        let mut plots = Vec::new();
        for case in &frames.cases {
            let name = format!("frames-{}.png", case.name);
            put(&name, &frames::png(frames, &case.name)?)?;
            plots.push((case.name.clone(), name));
        }
        readme.push_str(&frames::markdown(frames, &plots));
    }
    put("README.md", readme.as_bytes())?;
    Ok(written)
}

/// Pretty JSON of either part of a report.
fn pretty<T: serde::Serialize>(v: &T) -> Result<String> {
    serde_json::to_string_pretty(v)
        .map_err(|e| Error::internal("report", format!("JSON encoding: {e}")))
}

/// The products a report has curves for, in route order.
fn products_of(report: &Report) -> Vec<ProductKind> {
    ProductKind::ALL
        .into_iter()
        .filter(|k| report.curves.iter().any(|c| c.product == *k))
        .collect()
}

fn quality_name(q: Quality) -> &'static str {
    match q {
        Quality::Draft => "draft",
        Quality::Standard => "standard",
        Quality::High => "high",
        Quality::Reference => "reference",
    }
}

/// The report as markdown: how it was made, then a table per product.
pub fn markdown(report: &Report, plots: &[(ProductKind, String)]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "# Error against run time\n");
    let _ = writeln!(
        s,
        "Made by `skybake-harness report{}` ({}, {} threads, load average {}). Regenerate it whenever a \
         method changes.\n",
        if report.quick { " --quick" } else { "" },
        report.engine_version,
        report.threads,
        report.machine_load.as_deref().unwrap_or("unknown")
    );
    let _ = writeln!(
        s,
        "Reference: the {}. That reference is checked against DISORT (tests/atmosphere/atmosphere_validation.rs) \
         and a spherical-shell Monte Carlo (tests/atmosphere/atmosphere_twilight.rs). Wavelengths {} nm; sky and \
         ground tables {}×{}; aerial 9×8 directions. `rel_rms` = √(Σ(x−r)²/Σr²); `rel_max` = max |x−r| / \
         max(|r|, 10⁻³·max|r|), over every value of the product (sun: direct normal and diffuse \
         horizontal irradiance spectra; aerial: in-scattered radiance and transmittance, the worse). \
         Cold = shared tables built + product; warm = product only.\n",
        report.reference,
        report.wavelengths_nm,
        report.dome_shape[0],
        report.dome_shape[1]
    );
    let _ = writeln!(
        s,
        "Regimes (aerosol / sun band / observer altitude band):\n"
    );
    for r in &report.regimes {
        let _ = writeln!(
            s,
            "- `{}`: atmosphere `{}`, sun {}°, observer {} m",
            r.name, r.atmosphere, r.sun_elevation_deg, r.observer_altitude_m
        );
    }
    let _ = writeln!(s);
    for kind in products_of(report) {
        let _ = writeln!(s, "## {}\n", kind.name());
        if let Some((_, file)) = plots.iter().find(|(k, _)| *k == kind) {
            let _ = writeln!(s, "![{} error against time]({file})\n", kind.name());
        }
        let _ = writeln!(
            s,
            "| regime | method | quality | cold ms | cold CPU ms | warm ms | rel RMS | rel max |\n|---|---|---|---:|---:|---:|---:|---:|"
        );
        for c in report.curves.iter().filter(|c| c.product == kind) {
            for p in &c.points {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {:.0} | {} | {:.1} | {} | {} |",
                    c.regime,
                    method_name(c.method),
                    quality_name(p.quality),
                    p.cold_ms,
                    p.cold_cpu_ms.map_or("—".into(), |v| format!("{v:.0}")),
                    p.warm_ms,
                    percent(p.rel_rms),
                    percent(p.rel_max)
                );
            }
        }
        let _ = writeln!(s);
    }
    s
}

fn percent(v: f64) -> String {
    if v == 0.0 {
        "(reference)".into()
    } else {
        format!("{:.3} %", v * 100.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use skybake_engine::accuracy::band_of_aerosol;

    #[test]
    fn errors_are_normalised_rms_and_floored_max() {
        let r = [1.0, 2.0, 0.0];
        let x = [1.1, 2.0, 0.001];
        let (rms, max) = errors(&x, &r);
        assert!((rms - (0.01f64 + 1e-6).sqrt() / 5f64.sqrt()).abs() < 1e-12);
        // The zero cell is measured against the floor 10⁻³ × 2: 0.001 / 0.002 = 0.5.
        assert!((max - 0.5).abs() < 1e-12);
        assert_eq!(errors(&[0.0, 0.0], &[0.0, 0.0]), (0.0, 0.0));
        assert!(errors(&[1.0], &[0.0]).0.is_infinite());
    }

    #[test]
    fn bands_cover_every_elevation_and_stop_at_the_measured_range() {
        assert_eq!(band_of_sun(90.0), Some("high"));
        assert_eq!(band_of_sun(30.0), Some("high"));
        assert_eq!(band_of_sun(0.0), Some("low"));
        assert_eq!(band_of_sun(-0.1), Some("twilight"));
        assert_eq!(band_of_sun(-6.0), Some("twilight"));
        assert_eq!(band_of_sun(-6.1), None);
        assert_eq!(band_of_altitude(0.0), Some("ground"));
        assert_eq!(band_of_altitude(10_000.0), Some("aloft"));
        assert_eq!(band_of_altitude(400_000.0), None);
        assert_eq!(band_of_aerosol(0.1), Some("clear"));
        assert_eq!(band_of_aerosol(1.0), Some("hazy"));
        assert_eq!(band_of_aerosol(1.5), Some("thick"));
        assert_eq!(band_of_aerosol(5.0), Some("fog"));
        assert_eq!(band_of_aerosol(7.0), None);
    }
}
