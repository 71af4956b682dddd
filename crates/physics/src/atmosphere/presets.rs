//! Named atmosphere presets, compiled in from `config/atmospheres/*.json`.

use super::params::AtmosphereParams;
use crate::{Error, Result};

/// (name, JSON) of every built-in preset.
pub const PRESETS: &[(&str, &str)] = &[
    (
        "earth",
        include_str!("../../../../config/atmospheres/earth.json"),
    ),
    (
        "earth-hazy",
        include_str!("../../../../config/atmospheres/earth-hazy.json"),
    ),
    (
        "rayleigh-only",
        include_str!("../../../../config/atmospheres/rayleigh-only.json"),
    ),
    (
        "mars",
        include_str!("../../../../config/atmospheres/mars.json"),
    ),
];

/// Names of the built-in presets.
pub fn preset_names() -> Vec<&'static str> {
    PRESETS.iter().map(|(n, _)| *n).collect()
}

/// Parses atmosphere JSON text (validated).
pub fn parse_json(field: &str, text: &str) -> Result<AtmosphereParams> {
    let params: AtmosphereParams = serde_json::from_str(text)
        .map_err(|e| Error::invalid(field, format!("not a valid atmosphere JSON: {e}")))?;
    // An inline atmosphere's fields are named under the parameter that holds it
    // (`atmosphere.ground_albedo`, not the query parameter `ground_albedo`).
    params
        .validate()
        .map_err(|e| e.prefixed(&format!("{field}.")))?;
    Ok(params)
}

/// The built-in preset called `name`.
pub fn preset(name: &str) -> Result<AtmosphereParams> {
    let (_, text) = PRESETS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
        Error::invalid(
            "atmosphere",
            format!(
                "unknown preset '{name}' (known: {})",
                preset_names().join(", ")
            ),
        )
    })?;
    parse_json("atmosphere", text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_parses_and_validates() {
        for name in preset_names() {
            let p = preset(name).unwrap();
            assert_eq!(p.name.as_deref(), Some(name));
        }
        assert_eq!(preset("venus").unwrap_err().field(), "atmosphere");
    }

    #[test]
    fn out_of_range_fields_are_named() {
        let mut p = preset("earth").unwrap();
        p.atmosphere_height_m = -5.0;
        assert_eq!(p.validate().unwrap_err().field(), "atmosphere_height_m");
        let text =
            include_str!("../../../../config/atmospheres/earth.json").replace("0.7 }", "1.5 }");
        assert_eq!(
            parse_json("atmosphere", &text).unwrap_err().field(),
            "atmosphere.mie.phase.g"
        );
    }
}
