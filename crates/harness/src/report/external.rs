//! The external references beside the report's own comparison: the precise method's measured
//! distance from DISORT (Rayleigh, and with aerosol) per preset and regime
//! (`report/external.json`, measured by `tests/atmosphere/external.rs`), next to what the report
//! measures for the same preset against the precise method at `reference` in the same bands; the
//! spherical Monte Carlo's twilight figures; and what exists of Bruneton.

use skybake_engine::accuracy::{
    external, measured, preset_name, reference_error, stated_twilight_error, RegimeBands, Report,
};
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_product::ProductKind;

/// The section as markdown.
pub fn markdown(report: &Report) -> String {
    use std::fmt::Write;
    let ext = external();
    let mut s = String::new();
    let _ = writeln!(s, "## External references\n");
    let _ = writeln!(
        s,
        "Every product's `error_estimate.relative_error` is at least the distance of its preset from these \
         references in its regime (docs/planner.md). DISORT rows: {}. Regenerate: `{}`.\n",
        ext.source, ext.command
    );
    let _ = writeln!(
        s,
        "| reference | atmosphere | AOD 550 | aerosol band | sun band | preset | radiance max | irradiance max | report: sky vs reference (same bands, ground) + reference error |\n|---|---|---:|---|---|---|---:|---:|---:|"
    );
    for r in &ext.rows {
        let bands = RegimeBands {
            sun: match r.sun_band.as_str() {
                "high" => Some("high"),
                "low" => Some("low"),
                _ => None,
            },
            altitude: Some("ground"),
            aerosol: match r.aerosol_band.as_deref() {
                Some("clear") => Some("clear"),
                Some("hazy") => Some("hazy"),
                _ => None,
            },
        };
        let internal = measured(
            report,
            ProductKind::Sky,
            MsMethod::Precise,
            r.quality,
            &bands,
        )
        .map_or("— (not measured)".to_string(), |m| {
            // The report's regimes measure the high band at 45° and the low one at 10°.
            let sun = if r.sun_band == "high" { 45.0 } else { 10.0 };
            format!("{:.2} %", 100.0 * (m.relative_error + reference_error(sun)))
        });
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {:.2} % | {:.2} % | {} |",
            r.reference,
            r.case,
            r.aerosol_optical_depth_550,
            r.aerosol_band.as_deref().unwrap_or("above 6"),
            r.sun_band,
            preset_name(r.quality),
            100.0 * r.radiance_max,
            100.0 * r.irradiance_max,
            internal
        );
    }
    let _ = writeln!(
        s,
        "\nSpherical-shell Monte Carlo (Rayleigh, 440–680 nm, observers at 0, 10 and 400 km, albedo 0 and \
         0.3; tests/atmosphere/atmosphere_twilight.rs, precise `standard`; the reference error the report's \
         figures add below 30°):\n"
    );
    let _ = writeln!(
        s,
        "| sun elevation | stated (measured, rounded up) |\n|---|---:|"
    );
    for (band, e) in [
        ("0° to 30°", 0.0),
        ("−6° to 0°", -3.0),
        ("−12° to −6°", -9.0),
    ] {
        let _ = writeln!(
            s,
            "| {band} | {:.1} % |",
            100.0 * stated_twilight_error(MsMethod::Precise, e)
        );
    }
    let _ = writeln!(
        s,
        "\nBruneton: no radiance reference of Bruneton's model is committed; his layout is the texture \
         bundle's (`skybake lut`), whose tables are checked against skybake's own products \
         (tests/atmosphere/lut.rs, docs/validation.md), not against an external truth, so it bounds no \
         product's error.\n\nThe retired fast method (Hillaire 2020) against the same DISORT aerosol \
         references: −38 … +170 % on radiance, −17 … −74 % on irradiance (`standard`, \
         tests/atmosphere/atmosphere_aerosol.rs); a `method=fast` request runs the precise tables at \
         `draft` in clear air and `standard` in haze.\n"
    );
    s
}
