//! The spectral OpenEXR layout (Fichet, Pacanowski, Wilkie, "An OpenEXR Layout for Spectral Images",
//! JCGT 10(3), 2021, §3): channel names `<layer>.<value><unit>` with a comma as decimal separator,
//! e.g. `S0.550,000000nm`, and the header attributes that declare the layout.
//!
//! skybake always writes the value with six decimals and the unit `nm`, so a wavelength survives the
//! trip through a channel name exactly when it lies on the 10⁻⁶ nm grid; [`canonical_wavelength_nm`]
//! puts a wavelength on that grid.

use crate::{Error, Result};

/// Layer prefix of emissive (radiance) channels: Stokes component S0 (Fichet et al. §3.1).
pub const EMISSIVE_LAYER: &str = "S0";
/// Layer prefix of reflective/transmissive channels (Fichet et al. §3.2); skybake uses it for the
/// transmittance planes of aerial perspective.
pub const TRANSMITTANCE_LAYER: &str = "T";

/// Header attribute declaring the layout version (Fichet et al. §3).
pub const ATTR_SPECTRAL_LAYOUT_VERSION: &str = "spectralLayoutVersion";
/// Value of [`ATTR_SPECTRAL_LAYOUT_VERSION`] written by skybake.
pub const SPECTRAL_LAYOUT_VERSION: &str = "1.0";
/// Header attribute giving the units of the emissive channels (Fichet et al. §3.1).
pub const ATTR_EMISSIVE_UNITS: &str = "emissiveUnits";
/// Value of [`ATTR_EMISSIVE_UNITS`]: spectral radiance per nanometre of the channel's wavelength.
pub const EMISSIVE_UNITS: &str = "W.m^-2.sr^-1";
/// Header attribute holding the blake3 checksum of the whole file (see `store::checksum`).
pub const ATTR_FILE_CHECKSUM: &str = "skybakeFileBlake3";

/// Attribute key for the canonical product spec JSON.
pub const ATTR_SPEC_JSON: &str = "skybakeSpec";
/// Attribute key for the engine version string.
pub const ATTR_ENGINE_VERSION: &str = "skybakeEngineVersion";
/// Attribute key for the error estimate JSON.
pub const ATTR_ERROR_ESTIMATE_JSON: &str = "skybakeErrorEstimate";
/// Attribute key for the compute time in milliseconds (decimal text).
pub const ATTR_COMPUTE_TIME_MS: &str = "skybakeComputeTimeMs";
/// Attribute key for the cache key a product is stored under: a cache file carries its own key, so a
/// file copied or renamed under another key is detected on read (`store::Cache::get`).
pub const ATTR_CACHE_KEY: &str = "skybakeCacheKey";
/// Attribute key for the plan (stages run and left out) JSON.
pub const ATTR_PLAN_JSON: &str = "skybakePlan";

/// Names of the RGB preview channels.
pub const RGB_CHANNELS: [&str; 3] = ["R", "G", "B"];

/// Decimal places of the wavelength in a channel name (Fichet et al. use six in their examples).
const WAVELENGTH_DECIMALS: usize = 6;
/// Exclusive upper bound on wavelengths, so a channel name stays short.
pub const MAX_WAVELENGTH_NM: f64 = 1.0e6;
/// Longest layer prefix accepted.
pub const MAX_LAYER_NAME_LEN: usize = 16;
/// Longest custom attribute name: OpenEXR names of 32 bytes or more need the long-names flag,
/// which older readers reject.
pub const MAX_ATTRIBUTE_NAME_LEN: usize = 31;

/// Attribute names defined by OpenEXR (the standard and optional attributes) or by the spectral
/// layout. Custom attributes may not reuse them: the reader would file them elsewhere.
pub const RESERVED_ATTRIBUTE_NAMES: &[&str] = &[
    "adoptedNeutral",
    "altitude",
    "aperture",
    "capDate",
    "channels",
    "chromaticities",
    "chunkCount",
    "comments",
    "compression",
    "dataWindow",
    "deepImageState",
    "displayWindow",
    "dwaCompressionLevel",
    "envmap",
    "expTime",
    "far",
    "farClip",
    "fieldOfViewHorizontal",
    "fieldOfViewVertical",
    "focus",
    "framesPerSecond",
    "isoSpeed",
    "keyCode",
    "latitude",
    "lineOrder",
    "longitude",
    "lookModTransform",
    "maxSamplesPerPixel",
    "multiView",
    "name",
    "near",
    "nearClip",
    "originalDataWindow",
    "owner",
    "pixelAspectRatio",
    "preview",
    "renderingTransform",
    "screenWindowCenter",
    "screenWindowWidth",
    "software",
    "tiles",
    "timeCode",
    "type",
    "utcOffset",
    "version",
    "view",
    "whiteLuminance",
    "worldToCamera",
    "worldToNDC",
    "wrapmodes",
    "xDensity",
    ATTR_SPECTRAL_LAYOUT_VERSION,
    ATTR_EMISSIVE_UNITS,
    ATTR_FILE_CHECKSUM,
    "polarisationHandedness",
];

/// The wavelength as written in a channel name: six decimals, comma separator (`550,500000`).
pub fn format_wavelength_nm(wavelength_nm: f64) -> String {
    format!("{wavelength_nm:.WAVELENGTH_DECIMALS$}").replace('.', ",")
}

/// Rounds a wavelength to the 10⁻⁶ nm grid of channel names, so that
/// `parse(format(canonical(λ))) == canonical(λ)` bit for bit.
pub fn canonical_wavelength_nm(wavelength_nm: f64) -> f64 {
    // Formatting rounds to the nearest decimal; parsing returns the nearest f64 to that decimal.
    format!("{wavelength_nm:.WAVELENGTH_DECIMALS$}")
        .parse()
        .unwrap_or(wavelength_nm)
}

/// Channel name of one spectral plane: `<layer>.<λ with comma>nm`, e.g. `S0.550,000000nm`.
pub fn spectral_channel_name(layer: &str, wavelength_nm: f64) -> String {
    format!("{layer}.{}nm", format_wavelength_nm(wavelength_nm))
}

/// Parses a spectral channel name into (layer, wavelength in nm). Accepts the unit `nm` and a value
/// with a comma decimal separator and any number of decimals (Fichet et al. §3); returns `None` for
/// other channels (e.g. `R`).
pub fn parse_spectral_channel_name(name: &str) -> Option<(&str, f64)> {
    let (layer, rest) = name.split_once('.')?;
    validate_layer_name(layer).ok()?;
    let value = rest.strip_suffix("nm")?;
    let (int_part, frac_part) = match value.split_once(',') {
        Some((i, f)) => (i, f),
        None => (value, ""),
    };
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if int_part.is_empty() || !digits(int_part) || !digits(frac_part) {
        return None;
    }
    let wavelength_nm: f64 = if frac_part.is_empty() {
        int_part.parse().ok()?
    } else {
        format!("{int_part}.{frac_part}").parse().ok()?
    };
    (wavelength_nm > 0.0 && wavelength_nm < MAX_WAVELENGTH_NM).then_some((layer, wavelength_nm))
}

/// A layer prefix is 1 to [`MAX_LAYER_NAME_LEN`] ASCII letters, digits or underscores starting with
/// a letter (no dot: the dot separates the layer from the wavelength).
pub fn validate_layer_name(name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name.len() <= MAX_LAYER_NAME_LEN
        && name.as_bytes()[0].is_ascii_alphabetic()
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_');
    if ok {
        Ok(())
    } else {
        Err(Error::invalid(
            "layer",
            format!(
                "layer name {name:?} must be 1..={MAX_LAYER_NAME_LEN} ASCII letters, digits or '_', starting with a letter"
            ),
        ))
    }
}

/// A custom attribute name is 1 to [`MAX_ATTRIBUTE_NAME_LEN`] ASCII letters, digits or underscores
/// starting with a letter, and not one of [`RESERVED_ATTRIBUTE_NAMES`].
pub fn validate_attribute_name(name: &str) -> Result<()> {
    let well_formed = !name.is_empty()
        && name.len() <= MAX_ATTRIBUTE_NAME_LEN
        && name.as_bytes()[0].is_ascii_alphabetic()
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_');
    if !well_formed {
        return Err(Error::invalid(
            "attribute",
            format!(
                "attribute name {name:?} must be 1..={MAX_ATTRIBUTE_NAME_LEN} ASCII letters, digits or '_', starting with a letter"
            ),
        ));
    }
    if RESERVED_ATTRIBUTE_NAMES.contains(&name) {
        return Err(Error::invalid(
            "attribute",
            format!("attribute name {name:?} is reserved by OpenEXR or the spectral layout"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_names_follow_fichet_layout() {
        assert_eq!(spectral_channel_name("S0", 550.0), "S0.550,000000nm");
        assert_eq!(spectral_channel_name("S0", 550.5), "S0.550,500000nm");
        assert_eq!(spectral_channel_name("T", 360.25), "T.360,250000nm");
        assert_eq!(spectral_channel_name("S0", 1000.0), "S0.1000,000000nm");
    }

    #[test]
    fn channel_names_parse_back() {
        assert_eq!(
            parse_spectral_channel_name("S0.550,000000nm"),
            Some(("S0", 550.0))
        );
        assert_eq!(
            parse_spectral_channel_name("T.550,500000nm"),
            Some(("T", 550.5))
        );
        // Other decimal counts are part of the layout too.
        assert_eq!(
            parse_spectral_channel_name("S0.550,5nm"),
            Some(("S0", 550.5))
        );
        assert_eq!(parse_spectral_channel_name("S0.550nm"), Some(("S0", 550.0)));
        for bad in [
            "R",
            "S0.550.000000nm",
            "S0.550,000000",
            "S0.,5nm",
            "S0.-550,0nm",
            "S0.550,0um",
            ".550,0nm",
            "S0.0,000000nm",
            "S0.5e2nm",
        ] {
            assert_eq!(parse_spectral_channel_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn canonical_wavelengths_survive_the_channel_name() {
        for wavelength_nm in [
            360.0,
            550.5,
            412.123_456_7,
            829.999_999_9,
            0.001,
            123_456.789_012_3,
        ] {
            let canonical = canonical_wavelength_nm(wavelength_nm);
            let name = spectral_channel_name("S0", canonical);
            let (_, parsed) = parse_spectral_channel_name(&name).expect("parses");
            assert_eq!(parsed.to_bits(), canonical.to_bits(), "{name}");
            assert!((canonical - wavelength_nm).abs() <= 0.5e-6);
        }
    }

    #[test]
    fn attribute_names_are_checked() {
        assert!(validate_attribute_name(ATTR_SPEC_JSON).is_ok());
        for bad in [
            "",
            "owner",
            "channels",
            ATTR_FILE_CHECKSUM,
            "a b",
            "1x",
            "a.b",
            "x".repeat(32).as_str(),
        ] {
            assert!(validate_attribute_name(bad).is_err(), "{bad:?}");
        }
        assert!(validate_layer_name("S0").is_ok());
        for bad in ["", "S.0", "0S", "R G", "x".repeat(17).as_str()] {
            assert!(validate_layer_name(bad).is_err(), "{bad:?}");
        }
    }
}
