//! Measured accuracy: the data of `skybake-harness report` (`report/report.json`,
//! compiled into the binary), the regime bands it was measured in, every product's measured error
//! for its regime, and quality chosen by a target error (`max_rel_error`).
//!
//! The error a product states is the largest `rel_max` measured at its quality preset over the
//! report's regimes in the same bands (sun elevation, observer altitude, aerosol load), plus the
//! reference's own error against the independent codes ([`REFERENCE_ERROR`]). Outside the
//! measured bands there is no figure and the product says `validated: false`.
//! `src/report/` makes the data; this module only reads it (the engine may use it).

use crate::spec::{CommonSpec, ProductKind, Quality};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use skybake_physics::atmosphere::params::{AtmosphereParams, MieExtinction};
use skybake_physics::atmosphere::sky::MsMethod;
use std::sync::OnceLock;

/// Sun elevation below which the fast method's (Hillaire 2020) measured error against the
/// spherical Monte Carlo exceeds 10 % (−6°: up to 54 % low, −9°: 81 %, −12°: 96 %;
/// tests/atmosphere/atmosphere_twilight.rs). The method is retired for products
/// ([`fast_preset`]); the limit bounds its measured figures in [`stated_twilight_error`].
pub const FAST_TWILIGHT_LIMIT_DEG: f64 = -4.0;

/// The quality preset of the precise tables a `fast` request runs on (the fast method, Hillaire
/// 2020, is retired: its isotropic orders ≥ 2 are [`FAST_MEASURED_ERROR`] off DISORT with
/// aerosol): the coarsest preset whose measured distance from DISORT in the atmosphere's aerosol
/// band is within 5 % (report/external.json): `draft` in clear air (optical depth at 550 nm ≤ 0.3;
/// draft measures ≤ 2.5 %), `standard` in hazier air (draft measures 3.7–4.7 % at optical depth
/// 0.4 and 6.9 % at optical depth 1 with a strongly forward aerosol, standard 1.3–1.9 % and 3.2 %;
/// at optical depth 2 draft 18.5 %, standard 2.7 %).
pub fn fast_preset(atmosphere: &AtmosphereParams) -> Quality {
    match aerosol_optical_depth_550(atmosphere).and_then(band_of_aerosol) {
        Some("clear") => Quality::Draft,
        _ => Quality::Standard,
    }
}

/// The fast method's measured error against DISORT with aerosol (the eight atmospheres of
/// tests/data/disort_aerosol.json, standard preset; docs/validation.md).
pub const FAST_MEASURED_ERROR: &str =
    "−38 … +170 % on sky radiance and −17 … −74 % on irradiance for aerosol optical depth 0.05–2";

/// What the precise tables measure against DISORT at the preset a `fast` request runs at, and
/// what they cost cold against the fast method (report/external.json, docs/performance.md).
pub fn fast_preset_evidence(q: Quality) -> &'static str {
    match q {
        Quality::Draft => "at most 2.5 % in clear air (aerosol optical depth ≤ 0.3), at 0.56 s cold for a 16-wavelength sky against the fast method's 0.83 s (skybake-harness bench sky-fast sky-hillaire)",
        _ => "1.3–1.9 % at aerosol optical depth 0.4 (draft: 3.7–4.7 %), 3.2 % at optical depth 1 with a strongly forward aerosol (draft: 6.9 %), 2.7 % at optical depth 2 (draft: 18.5 %), at 2.7 s cold for a hazy 16-wavelength sky against the fast method's 0.83 s",
    }
}

/// A quality preset's name as requests spell it.
pub fn preset_name(q: Quality) -> &'static str {
    match q {
        Quality::Draft => "draft",
        Quality::Standard => "standard",
        Quality::High => "high",
        Quality::Reference => "reference",
    }
}

/// Relative error of each method against DISORT for the Rayleigh validation cases
/// (tests/atmosphere/atmosphere_validation.rs measures it; keep these in step with that test).
pub fn stated_relative_error(method: MsMethod) -> f64 {
    match method {
        MsMethod::Precise => 0.02,
        MsMethod::Fast => 0.06,
        MsMethod::None => 0.5,
    }
}

/// Bound on the relative sky-radiance error of `method` at `sun_elevation_deg`, measured against
/// DISORT (sun ≥ 30°, tests/atmosphere/atmosphere_validation.rs) and the spherical-shell Monte Carlo
/// (sun 10° to −12°, observers at 0, 10 and 400 km, 440–680 nm, albedo 0 and 0.3,
/// tests/atmosphere/atmosphere_twilight.rs, quality `standard`); keep these in step with those tests. Below
/// −12° nothing is validated and the −12° figure is given.
pub fn stated_twilight_error(method: MsMethod, sun_elevation_deg: f64) -> f64 {
    let e = sun_elevation_deg;
    match method {
        MsMethod::Precise if e >= 30.0 => stated_relative_error(MsMethod::Precise),
        // Measured: 2.08 % max, at view zenith 89° away from the sun at sunset (MC noise 0.4 %).
        MsMethod::Precise if e >= 0.0 => 0.025,
        // 3.2 % max (−6°, nadir from 400 km; MC noise 1.5 %).
        MsMethod::Precise if e >= -6.0 => 0.04,
        // 7.0 % max at −9°, 16.7 % at −12° where the Monte Carlo's own noise is 5–17 %.
        MsMethod::Precise => 0.17,
        MsMethod::Fast if e >= 30.0 => stated_relative_error(MsMethod::Fast),
        // Measured: 8.9 % max (10° to 0°).
        MsMethod::Fast if e >= 0.0 => 0.10,
        // 10.0 % max (−2° to −4°).
        MsMethod::Fast if e >= FAST_TWILIGHT_LIMIT_DEG => 0.11,
        // Computed with the precise tables (see [`crate::plan::effective_method`]).
        MsMethod::Fast => stated_twilight_error(MsMethod::Precise, e),
        MsMethod::None => 1.0,
    }
}

/// The quality presets, cheapest first.
pub const PRESETS: [Quality; 4] = [
    Quality::Draft,
    Quality::Standard,
    Quality::High,
    Quality::Reference,
];

/// Sun elevation bands, degrees: (name, lower bound inclusive).
pub const SUN_BANDS: [(&str, f64); 3] = [("high", 30.0), ("low", 0.0), ("twilight", -6.0)];
/// Observer altitude bands, metres: (name, upper bound exclusive).
pub const ALTITUDE_BANDS: [(&str, f64); 2] = [("ground", 2_000.0), ("aloft", 20_000.0)];
/// Aerosol bands by optical depth at 550 nm: (name, upper bound inclusive). The report's regimes
/// measure `clear` and `hazy`; `thick` (DISORT's optical depth 2) and `fog` (DISORT's fog of
/// visibility 1–2 km, optical depth 2.9–5.9, the largest `visibility_km` gives) have external rows
/// only (report/external.json).
pub const AEROSOL_BANDS: [(&str, f64); 4] =
    [("clear", 0.3), ("hazy", 1.0), ("thick", 2.0), ("fog", 6.0)];

/// One measured regime: where in the sun/altitude/aerosol space the curves were taken.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Regime {
    /// `<aerosol>/<sun band>/<altitude band>`, e.g. `clear/high/ground`.
    pub name: String,
    pub atmosphere: String,
    pub sun_elevation_deg: f64,
    pub observer_altitude_m: f64,
    pub sun_band: String,
    pub altitude_band: String,
    pub aerosol_band: String,
}

/// One quality setting's measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub quality: Quality,
    /// Shared tables built + the product, wall-clock ms.
    pub cold_ms: f64,
    /// The product with its tables built, wall-clock ms.
    pub warm_ms: f64,
    /// Process CPU time (all threads) of `cold_ms`, ms: steadier than wall time on a shared
    /// machine; divide by the thread count for the wall time of an idle machine.
    #[serde(default)]
    pub cold_cpu_ms: Option<f64>,
    pub rel_rms: f64,
    pub rel_max: f64,
}

/// Error against time for one product, method and regime, over the presets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Curve {
    pub product: ProductKind,
    pub method: MsMethod,
    pub regime: String,
    pub points: Vec<Point>,
}

/// A whole report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub engine_version: String,
    /// `true` for `--quick` (one regime, three wavelengths, small tables).
    pub quick: bool,
    pub threads: usize,
    /// One-minute load average of the machine when the report was written (timings are
    /// inflated under load), when known.
    #[serde(default)]
    pub machine_load: Option<String>,
    pub wavelengths_nm: String,
    /// Table shape of the sky and ground products (elevations × azimuths).
    pub dome_shape: [usize; 2],
    pub reference: String,
    pub regimes: Vec<Regime>,
    pub curves: Vec<Curve>,
}

/// The sun band of an elevation (`None` below civil twilight, −6°: not measured).
pub fn band_of_sun(elevation_deg: f64) -> Option<&'static str> {
    SUN_BANDS
        .iter()
        .find(|(_, lo)| elevation_deg >= *lo)
        .map(|(n, _)| *n)
}

/// The altitude band of an observer altitude (`None` above the highest measured band).
pub fn band_of_altitude(altitude_m: f64) -> Option<&'static str> {
    ALTITUDE_BANDS
        .iter()
        .find(|(_, hi)| altitude_m < *hi)
        .map(|(n, _)| *n)
}

/// The aerosol band of an optical depth at 550 nm (`None` above the haziest measured band).
pub fn band_of_aerosol(tau_550: f64) -> Option<&'static str> {
    AEROSOL_BANDS
        .iter()
        .find(|(_, hi)| tau_550 <= *hi + 1e-9)
        .map(|(n, _)| *n)
}

/// The committed full report.
static REPORT_JSON: &str = include_str!("../../../report/report.json");

/// The reference's own relative error (the precise method at the `reference` preset) against
/// DISORT in the plane-parallel limit through the product path (README "Measured accuracy":
/// 0.25 % radiance, 0.41 % diffuse flux), rounded up.
pub const REFERENCE_ERROR: f64 = 0.005;

/// The reference preset's own relative error against the independent codes at a sun
/// elevation: DISORT above 30° ([`REFERENCE_ERROR`]), the spherical Monte Carlo's stated
/// figures below ([`stated_twilight_error`]).
pub fn reference_error(sun_elevation_deg: f64) -> f64 {
    if sun_elevation_deg >= 30.0 {
        REFERENCE_ERROR
    } else {
        stated_twilight_error(MsMethod::Precise, sun_elevation_deg)
    }
}

/// The committed report, parsed once (`None` if it does not parse, which a unit test rules out).
pub fn committed() -> Option<&'static Report> {
    static REPORT: OnceLock<Option<Report>> = OnceLock::new();
    REPORT
        .get_or_init(|| serde_json::from_str(REPORT_JSON).ok())
        .as_ref()
}

/// Where a request lies: its bands, or `None` for a quantity outside every measured band.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegimeBands {
    pub sun: Option<&'static str>,
    pub altitude: Option<&'static str>,
    pub aerosol: Option<&'static str>,
}

impl RegimeBands {
    pub fn of(atmosphere: &AtmosphereParams, sun_elevation_deg: f64, altitude_m: f64) -> Self {
        Self {
            sun: band_of_sun(sun_elevation_deg),
            altitude: band_of_altitude(altitude_m),
            aerosol: aerosol_optical_depth_550(atmosphere).and_then(band_of_aerosol),
        }
    }

    /// `aerosol/sun/altitude`, with `?` for a band outside the measured ones.
    pub fn name(&self) -> String {
        format!(
            "{}/{}/{}",
            self.aerosol.unwrap_or("?"),
            self.sun.unwrap_or("?"),
            self.altitude.unwrap_or("?")
        )
    }
}

/// Vertical aerosol optical depth at 550 nm (`None` if the extinction table does not cover
/// 550 nm). No aerosol: 0.
pub fn aerosol_optical_depth_550(a: &AtmosphereParams) -> Option<f64> {
    let Some(mie) = &a.mie else {
        return Some(0.0);
    };
    if mie.layers.is_some() {
        // A layered profile: the resolved medium's column (boundary layer and backgrounds).
        let at_550 = skybake_physics::spectrum::Wavelengths::parse("550").ok()?;
        let m = skybake_physics::atmosphere::Medium::new(a, &at_550, None).ok()?;
        return Some(m.vertical_optical_depth(0)[skybake_physics::atmosphere::medium::MIE]);
    }
    // ∫₀^top exp(−h/H) dh for the sea-level coefficient forms.
    let column = mie.scale_height_m * (1.0 - (-a.atmosphere_height_m / mie.scale_height_m).exp());
    match &mie.extinction {
        MieExtinction::OpticalDepth {
            reference_nm,
            value,
            angstrom_exponent,
        } => Some(value * (550.0 / reference_nm).powf(-angstrom_exponent)),
        MieExtinction::PowerLaw {
            reference_nm,
            value_per_m,
            angstrom_exponent,
        } => Some(value_per_m * (550.0 / reference_nm).powf(-angstrom_exponent) * column),
        MieExtinction::TablePerM(table) => {
            let points: Vec<(f64, f64)> = table
                .iter()
                .filter_map(|(k, v)| Some((k.parse::<f64>().ok()?, *v)))
                .collect();
            let lo = points.iter().rfind(|(nm, _)| *nm <= 550.0)?;
            let hi = points.iter().find(|(nm, _)| *nm >= 550.0)?;
            let t = if hi.0 > lo.0 {
                (550.0 - lo.0) / (hi.0 - lo.0)
            } else {
                0.0
            };
            Some((lo.1 + t * (hi.1 - lo.1)) * column)
        }
    }
}

/// The committed distances from the external references (`report/external.json`, written by
/// `tests/atmosphere/external.rs`, whose module doc gives the command).
static EXTERNAL_JSON: &str = include_str!("../../../report/external.json");

/// One measured distance of the precise method at one quality preset from an external reference
/// in one case (an atmosphere, a sun band).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExternalRow {
    /// `disort_aerosol` (tests/data/disort_aerosol.json) or `disort_rayleigh`
    /// (tests/data/disort_rayleigh.json).
    pub reference: String,
    /// The reference's atmosphere.
    pub case: String,
    pub aerosol_optical_depth_550: f64,
    /// [`AEROSOL_BANDS`] name; `None` above the haziest band (optical depth above 6).
    pub aerosol_band: Option<String>,
    /// [`SUN_BANDS`] name of the compared sun positions.
    pub sun_band: String,
    pub quality: Quality,
    /// Largest |relative deviation| of the sky radiance.
    pub radiance_max: f64,
    /// Largest |relative deviation| of the diffuse (and global) horizontal irradiance.
    pub irradiance_max: f64,
    /// The worst compared value, for people.
    #[serde(default)]
    pub worst: Option<String>,
}

/// The whole external-reference file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct External {
    pub source: String,
    pub command: String,
    pub rows: Vec<ExternalRow>,
}

/// The committed external distances, parsed once (empty if the file does not parse, which a unit
/// test rules out).
pub fn external() -> &'static External {
    static EXTERNAL: OnceLock<External> = OnceLock::new();
    EXTERNAL.get_or_init(|| {
        serde_json::from_str(EXTERNAL_JSON).unwrap_or(External {
            source: String::new(),
            command: String::new(),
            rows: Vec::new(),
        })
    })
}

/// The measured distance of the precise method at a quality from the external references in a
/// regime: the largest over the committed rows of that quality, sun band and aerosol band.
#[derive(Debug, Clone, PartialEq)]
pub struct ExternalDistance {
    pub relative_error: f64,
    /// Rows the figure is the largest of.
    pub rows: usize,
    /// The row that gives it (`reference: case`).
    pub worst: String,
}

/// The precise method's measured distance from DISORT (Rayleigh, and with aerosol) at `quality`
/// in the bands `aerosol` (`None`: optical depth above the haziest band) and `sun` (`None`
/// below −6°: no DISORT row; the spherical Monte Carlo's figures are [`reference_error`]'s). The
/// `reference` preset takes the `high` rows (its distance from DISORT is the bias all presets
/// share; `high` is within 0.2–1 % of it in the report). `None` where no row matches.
pub fn external_distance(
    quality: Quality,
    aerosol: Option<&str>,
    sun: Option<&str>,
) -> Option<ExternalDistance> {
    let quality = match quality {
        Quality::Reference => Quality::High,
        q => q,
    };
    let sun = sun?;
    let rows: Vec<&ExternalRow> = external()
        .rows
        .iter()
        .filter(|r| r.quality == quality && r.sun_band == sun)
        .filter(|r| r.aerosol_band.as_deref() == aerosol)
        .collect();
    let worst = rows.iter().max_by(|a, b| {
        a.radiance_max
            .max(a.irradiance_max)
            .total_cmp(&b.radiance_max.max(b.irradiance_max))
    })?;
    Some(ExternalDistance {
        relative_error: worst.radiance_max.max(worst.irradiance_max),
        rows: rows.len(),
        worst: format!("{}: {}", worst.reference, worst.case),
    })
}

/// The error a product by the precise method at the spec's quality states in its regime, and why:
/// the larger of the report's figure plus the reference's own error (`report`, when the regime was
/// measured) or the fallback `stated`, and the distance from the external references in that
/// regime ([`external_distance`]). Returns (relative error, basis, regime name).
pub fn combined_error(
    spec: &CommonSpec,
    report: Option<(Measured, RegimeBands)>,
    reference_error: f64,
    stated: f64,
    independent: &str,
) -> (f64, String, Option<String>) {
    let bands = RegimeBands::of(
        &spec.atmosphere,
        spec.sun.sun_elevation_deg,
        spec.observer_altitude_m,
    );
    let (internal, basis, regime) = match report {
        Some((m, bands)) => (
            m.relative_error + reference_error,
            format!(
                "skybake-harness report (report/README.md): largest deviation of this quality preset from the precise method at the reference preset over {} measured regime(s) in band {}, plus the reference's own deviation from {independent} ({:.2} %)",
                m.regimes,
                bands.name(),
                reference_error * 100.0
            ),
            Some(bands.name()),
        ),
        None => (
            stated,
            format!("max relative deviation from {independent} (no report data for this regime)"),
            None,
        ),
    };
    match external_distance(spec.quality, bands.aerosol, bands.sun) {
        Some(x) if x.relative_error > internal => (
            x.relative_error,
            format!(
                "external reference dominates: the largest measured deviation of the precise method at this quality preset from DISORT in this regime ({:.2} %, {} of {} row(s) of report/external.json) exceeds the report's figure ({:.2} %: {basis})",
                x.relative_error * 100.0,
                x.worst,
                x.rows,
                internal * 100.0
            ),
            regime,
        ),
        Some(x) => (
            internal,
            format!(
                "{basis}; at least the measured deviation from DISORT in this regime ({:.2} %, {}, report/external.json)",
                x.relative_error * 100.0,
                x.worst
            ),
            regime,
        ),
        None => (internal, basis, regime),
    }
}

/// A product's measured error at one quality in one regime.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    /// Largest `rel_max` over the matching regimes: the deviation from the reference preset
    /// (0 for the reference itself); add [`reference_error`] for the error against the truth.
    pub relative_error: f64,
    /// Cold CPU time, ms (the largest over the matching regimes).
    pub cold_cpu_ms: f64,
    /// Regimes the figure is taken over.
    pub regimes: usize,
}

fn matching<'a>(
    report: &'a Report,
    product: ProductKind,
    method: MsMethod,
    bands: &RegimeBands,
) -> Vec<&'a Curve> {
    let (Some(sun), Some(altitude), Some(aerosol)) = (bands.sun, bands.altitude, bands.aerosol)
    else {
        return Vec::new();
    };
    report
        .curves
        .iter()
        .filter(|c| c.product == product && c.method == method)
        .filter(|c| {
            report.regimes.iter().any(|r| {
                r.name == c.regime
                    && r.sun_band == sun
                    && r.altitude_band == altitude
                    && r.aerosol_band == aerosol
            })
        })
        .collect()
}

/// The measured error of `product` by `method` at `quality` in `bands`, from `report`.
pub fn measured(
    report: &Report,
    product: ProductKind,
    method: MsMethod,
    quality: Quality,
    bands: &RegimeBands,
) -> Option<Measured> {
    let curves = matching(report, product, method, bands);
    let points: Vec<_> = curves
        .iter()
        .filter_map(|c| c.points.iter().find(|p| p.quality == quality))
        .collect();
    if points.is_empty() {
        return None;
    }
    let worst = points.iter().fold(0.0f64, |m, p| m.max(p.rel_max));
    let cpu = points
        .iter()
        .fold(0.0f64, |m, p| m.max(p.cold_cpu_ms.unwrap_or(p.cold_ms)));
    worst.is_finite().then_some(Measured {
        relative_error: worst,
        cold_cpu_ms: cpu,
        regimes: points.len(),
    })
}

/// The cheapest preset (by measured cold CPU time) whose measured error in `bands` (the report's
/// figure plus `reference_error`, at least the distance from the external references,
/// [`external_distance`]) is at most `target`. Errors name `max_rel_error` with the best achievable figure, or say that the regime
/// was not measured.
pub fn choose_quality(
    report: &Report,
    product: ProductKind,
    method: MsMethod,
    bands: &RegimeBands,
    reference_error: f64,
    target: f64,
) -> Result<Quality> {
    let options: Vec<(Quality, Measured)> = PRESETS
        .iter()
        .filter_map(|&q| {
            let mut m = measured(report, product, method, q, bands)?;
            m.relative_error += reference_error;
            if let Some(x) = external_distance(q, bands.aerosol, bands.sun) {
                m.relative_error = m.relative_error.max(x.relative_error);
            }
            Some((q, m))
        })
        .collect();
    if options.is_empty() {
        return Err(Error::invalid(
            "max_rel_error",
            format!(
                "no measured error for the {} product by the {} method in regime {} (measured: sun \
                 elevation ≥ −6°, observer below 20 km, aerosol optical depth at 550 nm ≤ 1); give \
                 quality instead",
                product.name(),
                method_label(method),
                bands.name()
            ),
        ));
    }
    let best = options
        .iter()
        .map(|(_, m)| m.relative_error)
        .fold(f64::INFINITY, f64::min);
    options
        .iter()
        .filter(|(_, m)| m.relative_error <= target)
        .min_by(|a, b| a.1.cold_cpu_ms.total_cmp(&b.1.cold_cpu_ms))
        .map(|(q, _)| *q)
        .ok_or_else(|| {
            Error::invalid(
                "max_rel_error",
                format!(
                    "{target} is below the best measured error of the {} product by the {} method in \
                     regime {}: {best:.4} (allowed: {best:.4} to 1)",
                    product.name(),
                    method_label(method),
                    bands.name()
                ),
            )
        })
}

/// The measured error of `product` by `method` at the request's quality in the request's
/// regime, with the bands (`None` outside the measured bands or without data).
pub fn measured_for(
    product: ProductKind,
    method: MsMethod,
    spec: &CommonSpec,
) -> Option<(Measured, RegimeBands)> {
    let report = committed()?;
    let bands = RegimeBands::of(
        &spec.atmosphere,
        spec.sun.sun_elevation_deg,
        spec.observer_altitude_m,
    );
    let m = measured(report, product, method, spec.quality, &bands)?;
    Some((m, bands))
}

/// The quality for a request's `max_rel_error` target, from the committed report.
pub fn quality_for_target(product: ProductKind, spec: &CommonSpec, target: f64) -> Result<Quality> {
    if spec.method == MsMethod::None {
        return Err(Error::invalid(
            "max_rel_error",
            "needs method fast or precise (single scattering alone is not measured)",
        ));
    }
    let report = committed()
        .ok_or_else(|| Error::internal("max_rel_error", "the compiled-in report does not parse"))?;
    let bands = RegimeBands::of(
        &spec.atmosphere,
        spec.sun.sun_elevation_deg,
        spec.observer_altitude_m,
    );
    let reference = reference_error(spec.sun.sun_elevation_deg);
    if spec.method == MsMethod::Fast {
        // The retired fast method runs the precise tables at one preset: the target is met there
        // or refused.
        let preset = fast_preset(&spec.atmosphere);
        let at_preset = measured(report, product, MsMethod::Precise, preset, &bands).map(|m| {
            let e = m.relative_error + reference;
            external_distance(preset, bands.aerosol, bands.sun)
                .map_or(e, |x| e.max(x.relative_error))
        });
        return match at_preset {
            Some(e) if e <= target => Ok(preset),
            Some(e) => Err(Error::invalid(
                "max_rel_error",
                format!(
                    "method fast is retired and runs the precise tables at the {} preset, whose measured error in regime {} is {e:.4}, above {target}; ask method precise, whose quality the target then chooses",
                    preset_name(preset),
                    bands.name()
                ),
            )),
            None => choose_quality(report, product, MsMethod::Precise, &bands, reference, target),
        };
    }
    choose_quality(report, product, spec.method, &bands, reference, target)
}

fn method_label(m: MsMethod) -> &'static str {
    match m {
        MsMethod::Fast => "fast",
        MsMethod::Precise => "precise",
        MsMethod::None => "none",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use skybake_physics::atmosphere::presets::preset;

    #[test]
    fn the_committed_report_parses_and_covers_every_product_and_method() {
        let report = committed().expect("report/report.json parses");
        assert!(!report.quick, "the committed report is the full one");
        for product in ProductKind::ALL {
            for method in [MsMethod::Fast, MsMethod::Precise] {
                assert!(
                    report
                        .curves
                        .iter()
                        .any(|c| c.product == product && c.method == method),
                    "{} {:?}",
                    product.name(),
                    method
                );
            }
        }
    }

    #[test]
    fn the_committed_external_distances_parse_and_cover_every_measured_preset() {
        let ext = external();
        assert!(!ext.command.is_empty());
        for q in [Quality::Draft, Quality::Standard, Quality::High] {
            for (aerosol, sun) in [
                (Some("clear"), "high"),
                (Some("clear"), "low"),
                (Some("hazy"), "high"),
                (Some("hazy"), "low"),
                (Some("thick"), "high"),
                (Some("thick"), "low"),
                (Some("fog"), "high"),
                (Some("fog"), "low"),
            ] {
                let d = external_distance(q, aerosol, Some(sun))
                    .unwrap_or_else(|| panic!("{q:?} {aerosol:?} {sun}"));
                assert!(d.relative_error > 0.0 && d.relative_error < 1.0, "{d:?}");
            }
        }
        // Fog states at least its measured distance: at `standard`, 1 km fog under a low sun.
        let fog = external_distance(Quality::Standard, Some("fog"), Some("low")).unwrap();
        assert!(fog.relative_error > 0.15, "{fog:?}");
        // Above the fog band there is no row.
        assert_eq!(
            external_distance(Quality::Standard, None, Some("high")),
            None
        );
        // Twilight has no DISORT row (the spherical Monte Carlo's figures are the reference
        // error there).
        assert_eq!(
            external_distance(Quality::Standard, Some("clear"), Some("twilight")),
            None
        );
    }

    #[test]
    fn aerosol_bands_of_the_presets() {
        let earth = preset("earth").unwrap();
        let hazy = preset("earth-hazy").unwrap();
        assert!((aerosol_optical_depth_550(&earth).unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(
            RegimeBands::of(&earth, 45.0, 0.0).name(),
            "clear/high/ground"
        );
        assert_eq!(
            RegimeBands::of(&hazy, -4.0, 10_000.0).name(),
            "hazy/twilight/aloft"
        );
        assert_eq!(RegimeBands::of(&earth, 45.0, 400_000.0).altitude, None);
    }

    #[test]
    fn a_tighter_target_never_picks_a_cheaper_preset() {
        let report = committed().expect("report parses");
        let earth = preset("earth").unwrap();
        let bands = RegimeBands::of(&earth, 45.0, 0.0);
        let mut last_cpu = 0.0;
        for target in [0.5, 0.2, 0.1, 0.05, 0.03, 0.02, 0.01] {
            let Ok(q) = choose_quality(
                report,
                ProductKind::Sky,
                MsMethod::Precise,
                &bands,
                REFERENCE_ERROR,
                target,
            ) else {
                break;
            };
            let m = measured(report, ProductKind::Sky, MsMethod::Precise, q, &bands).unwrap();
            assert!(m.relative_error + REFERENCE_ERROR <= target);
            assert!(m.cold_cpu_ms >= last_cpu);
            last_cpu = m.cold_cpu_ms;
        }
        let err = choose_quality(
            report,
            ProductKind::Sky,
            MsMethod::Precise,
            &bands,
            REFERENCE_ERROR,
            1e-6,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("max_rel_error") && err.contains("best measured"),
            "{err}"
        );
    }
}
