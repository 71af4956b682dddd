//! The one parameter table of the atmosphere products (name, CLI flag, unit, range, default,
//! products, doc). The request struct [`RequestParams`], the query and JSON-body parsers, the CLI
//! flags (`src/main.rs` builds them from [`PARAMETERS`]) and `/openapi.json` are all generated
//! from it, so a parameter is named in exactly one place.
//!
//! Parameters arrive as strings (CLI flags, query values, JSON members spelled as text) and are
//! parsed into the canonical [`CommonSpec`] here ("parse, don't validate": the spec's constructors hold the limits, so nothing downstream checks again).

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use skybake_engine::spec::{
    CommonSpec, ProductKind, Quality, SolarLocation, SunPosition, MAX_OBSERVER_ALTITUDE_M,
    MAX_PROBES,
};
use skybake_physics::atmosphere::haze::{AerosolType, Haze};
use skybake_physics::atmosphere::params::AtmosphereParams;
use skybake_physics::atmosphere::presets;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_physics::spectrum::Wavelengths;

/// The allowed values of a parameter (used by the parser and printed in the docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Range {
    /// A real number in `[lo, hi]`.
    Real { lo: f64, hi: f64 },
    /// A whole number in `[lo, hi]`.
    Whole { lo: usize, hi: usize },
    /// One of these words.
    OneOf(&'static [&'static str]),
    /// Free text in the form described.
    Text(&'static str),
}

impl Range {
    /// Human-readable form (docs, `--help`, OpenAPI).
    pub fn describe(&self) -> String {
        match self {
            Range::Real { lo, hi } => format!("{lo} to {hi}"),
            Range::Whole { lo, hi } => format!("{lo} to {hi}"),
            Range::OneOf(words) => words.join(", "),
            Range::Text(t) => (*t).to_string(),
        }
    }
}

/// One row of the parameter table.
#[derive(Debug, Clone, Copy)]
pub struct Parameter {
    /// Query / JSON name (snake_case).
    pub name: &'static str,
    /// CLI flag without the leading `--`; `None` when the CLI spells it differently (`format`: the
    /// CLI chooses the file format from `-o FILE`).
    pub cli: Option<&'static str>,
    /// Unit ("" for none).
    pub unit: &'static str,
    pub range: Range,
    /// Default, as documented ("—" when there is none).
    pub default: &'static str,
    /// Products that take it.
    pub products: &'static [ProductKind],
    /// One-line description.
    pub doc: &'static str,
}

impl Parameter {
    /// Whether `product` takes this parameter.
    pub fn applies_to(&self, product: ProductKind) -> bool {
        self.products.contains(&product)
    }

    /// `doc (unit; range; default)` for `--help` and OpenAPI.
    pub fn help(&self) -> String {
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        format!(
            "{} (allowed: {}{unit}; default: {})",
            self.doc,
            self.range.describe(),
            self.default
        )
    }

    /// Parses `text` as a real number in this parameter's range.
    pub fn real(&self, text: &str) -> Result<f64> {
        match self.range {
            Range::Real { lo, hi } => parse_f64(self.name, text, lo, hi, self.unit),
            _ => Err(Error::invalid(self.name, "not a real-valued parameter")),
        }
    }

    /// Parses `text` as a whole number in this parameter's range.
    pub fn whole(&self, text: &str) -> Result<usize> {
        match self.range {
            Range::Whole { lo, hi } => parse_usize(self.name, text, lo, hi),
            _ => Err(Error::invalid(self.name, "not a whole-number parameter")),
        }
    }
}

use ProductKind::{Aerial, Ground, Sky, Sun};
const ALL: &[ProductKind] = &[Sun, Sky, Ground, Aerial];
const TABLES: &[ProductKind] = &[Sky, Ground, Aerial];
const DOMES: &[ProductKind] = &[Sky, Ground];
const AERIAL: &[ProductKind] = &[Aerial];

/// Declares the parameter table and the request struct with one field per row, from one list.
macro_rules! parameter_table {
    ($( $field:ident { cli: $cli:expr, unit: $unit:expr, range: $range:expr, default: $default:expr,
                       products: $products:expr, doc: $doc:expr } ),* $(,)?) => {
        /// Request parameters as they arrive (all optional strings; missing ones take defaults),
        /// one field per row of [`PARAMETERS`].
        #[derive(Debug, Clone, Default, PartialEq, Deserialize, Serialize)]
        #[serde(deny_unknown_fields)]
        pub struct RequestParams {
            $( #[serde(skip_serializing_if = "Option::is_none")] pub $field: Option<String>, )*
        }

        /// The parameter table.
        pub const PARAMETERS: &[Parameter] = &[
            $( Parameter { name: stringify!($field), cli: $cli, unit: $unit, range: $range,
                           default: $default, products: $products, doc: $doc }, )*
        ];

        impl RequestParams {
            /// The field of parameter `name` (None for a name not in the table).
            pub fn slot(&mut self, name: &str) -> Option<&mut Option<String>> {
                match name {
                    $( stringify!($field) => Some(&mut self.$field), )*
                    _ => None,
                }
            }

            /// The value given for parameter `name`, if any.
            pub fn get(&self, name: &str) -> Option<&str> {
                match name {
                    $( stringify!($field) => self.$field.as_deref(), )*
                    _ => None,
                }
            }
        }
    };
}

parameter_table! {
    sun_elevation_deg { cli: Some("sun-elevation-deg"), unit: "deg",
        range: Range::Real { lo: -90.0, hi: 90.0 }, default: "30", products: ALL,
        doc: "Sun elevation above the horizon (below the darkest twilight the products are zero)" },
    latitude_deg { cli: Some("latitude"), unit: "deg", range: Range::Real { lo: -90.0, hi: 90.0 },
        default: "—", products: ALL,
        doc: "Latitude, with longitude_deg and time instead of sun_elevation_deg" },
    longitude_deg { cli: Some("longitude"), unit: "deg",
        range: Range::Real { lo: -180.0, hi: 180.0 }, default: "—", products: ALL,
        doc: "Longitude, east positive" },
    time { cli: Some("time"), unit: "", range: Range::Text("RFC 3339 UTC, e.g. 2026-06-21T12:00:00Z"),
        default: "—", products: ALL, doc: "UTC time for the solar position" },
    observer_altitude_m { cli: Some("observer-altitude-m"), unit: "m",
        range: Range::Real { lo: 0.0, hi: MAX_OBSERVER_ALTITUDE_M }, default: "0", products: ALL,
        doc: "Observer altitude above the ground" },
    wavelengths { cli: Some("wavelengths"), unit: "nm",
        range: Range::Text("1 to 64 comma-separated values in 360 to 830"),
        default: "380,405,…,755 (16 values)", products: ALL, doc: "Wavelengths" },
    atmosphere { cli: Some("atmosphere"), unit: "",
        range: Range::Text("earth, earth-hazy, rayleigh-only, mars, or inline JSON (CLI: a file)"),
        default: "earth", products: ALL, doc: "Atmosphere preset or definition" },
    visibility_km { cli: Some("visibility-km"), unit: "km", range: Range::Real { lo: 1.0, hi: 300.0 },
        default: "the atmosphere's aerosol", products: ALL,
        doc: "Meteorological visibility at the ground (Koschmieder, 550 nm): replaces the atmosphere's aerosol by a hazy boundary layer of this visibility over free-tropospheric (optical depth 0.02) and stratospheric (0.005) background; the largest allowed is where Rayleigh extinction alone limits the visibility, the smallest where the boundary layer's optical depth at 550 nm reaches 6 (fog-like haze: 1 km for a layer up to 1540 m, 1.62 km for 2500 m, 3.23 km for 5000 m; beyond it is refused)" },
    aerosol_type { cli: Some("aerosol-type"), unit: "",
        range: Range::OneOf(skybake_physics::atmosphere::haze::AEROSOL_TYPES), default: "continental",
        products: ALL,
        doc: "Aerosol type of visibility_km's haze: spectral extinction, single-scattering albedo and asymmetry of the 6S models" },
    boundary_layer_top_m { cli: Some("boundary-layer-top-m"), unit: "m",
        range: Range::Real { lo: 100.0, hi: 5000.0 }, default: "1000", products: ALL,
        doc: "Top of visibility_km's hazy boundary layer above the ground (an aircraft above it climbs out of the haze)" },
    ground_albedo { cli: Some("ground-albedo"), unit: "", range: Range::Real { lo: 0.0, hi: 1.0 },
        default: "the atmosphere's", products: ALL,
        doc: "Lambertian ground albedo, overriding the atmosphere's" },
    method { cli: Some("method"), unit: "", range: Range::OneOf(&["precise", "fast", "none"]),
        default: "precise", products: ALL,
        doc: "Multiple scattering method: precise (successive orders of scattering) or none (single scattering only). fast is retired and accepted for compatibility: it runs the precise tables at a coarse preset (draft in clear air, standard for aerosol optical depth above 0.3; quality is then ignored), and the plan says so, because the fast method (Hillaire 2020) measured 38-170 % off DISORT in hazy air and up to 54 % low in twilight" },
    quality { cli: Some("quality"), unit: "",
        range: Range::OneOf(&["draft", "standard", "high", "reference"]), default: "standard",
        products: ALL, doc: "Quality preset (ray-marching steps, table resolutions)" },
    max_rel_error { cli: Some("max-rel-error"), unit: "", range: Range::Real { lo: 1.0e-4, hi: 1.0 },
        default: "—", products: ALL,
        doc: "Target relative error, instead of quality: the cheapest quality preset whose error measured by skybake-harness report (report/README.md) in this regime meets it" },
    elevation_count { cli: Some("elevation-count"), unit: "", range: Range::Whole { lo: 2, hi: 4096 },
        default: "sky 129, ground 65, aerial 33", products: TABLES,
        doc: "Table rows (view elevations, concentrated at the horizon)" },
    azimuth_count { cli: Some("azimuth-count"), unit: "", range: Range::Whole { lo: 1, hi: 4096 },
        default: "sky and ground 64, aerial 16", products: TABLES,
        doc: "Table columns (view azimuths 0 to 180 deg from the sun)" },
    distance_count { cli: Some("distance-count"), unit: "", range: Range::Whole { lo: 1, hi: 4096 },
        default: "32", products: AERIAL, doc: "Distances per aerial-perspective ray" },
    max_distance_m { cli: Some("max-distance-m"), unit: "m", range: Range::Real { lo: 1.0, hi: 1.0e7 },
        default: "100000", products: AERIAL, doc: "Largest aerial-perspective distance" },
    probe { cli: Some("probe"), unit: "deg",
        range: Range::Text("VZ:VA pairs, view zenith 0 to 180, view azimuth -360 to 360"),
        default: "—", products: DOMES,
        doc: "Exact directions to evaluate (view zenith, view azimuth from the sun)" },
    layout { cli: None, unit: "", range: Range::OneOf(&["bruneton2017", "skyview"]),
        default: "bruneton2017", products: &[],
        doc: "Texture-bundle layout (GET /v1/lut and bake-job bundles; the CLI's `skybake lut --layout`): Bruneton 2017's textures, or skybake's sky-view layout (docs/lut.md)" },
    format { cli: None, unit: "", range: Range::OneOf(&["json", "exr", "png", "png_latlong"]), default: "json",
        products: ALL, doc: "Response format: json (all), exr (sky, ground, aerial), png (fisheye preview; sky, ground), png_latlong (panorama preview; sky, ground); a PNG is RGB-only: the planner may run it at fewer wavelengths (its own cache key)" },
}

/// The table row of `name`.
pub fn parameter(name: &str) -> Option<&'static Parameter> {
    PARAMETERS.iter().find(|p| p.name == name)
}

fn row(name: &str) -> &'static Parameter {
    // Every name passed here is a literal of the table above (checked by a unit test).
    match parameter(name) {
        Some(p) => p,
        None => &PARAMETERS[0],
    }
}

/// Parses a float parameter, naming it in errors and checking its range.
pub fn parse_f64(field: &str, text: &str, lo: f64, hi: f64, unit: &str) -> Result<f64> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| Error::invalid(field, format!("'{text}' is not a number")))?;
    if !(v.is_finite() && v >= lo && v <= hi) {
        return Err(Error::out_of_range(
            field,
            v,
            format!("{lo} to {hi} {unit}"),
        ));
    }
    Ok(v)
}

/// Parses an integer parameter in `[lo, hi]`.
pub fn parse_usize(field: &str, text: &str, lo: usize, hi: usize) -> Result<usize> {
    let v: usize = text
        .trim()
        .parse()
        .map_err(|_| Error::invalid(field, format!("'{text}' is not a whole number")))?;
    if v < lo || v > hi {
        return Err(Error::out_of_range(field, v, format!("{lo} to {hi}")));
    }
    Ok(v)
}

/// Resolves `atmosphere=`: a preset name or inline JSON (`{...}`).
pub fn resolve_atmosphere(text: Option<&str>) -> Result<AtmosphereParams> {
    match text.map(str::trim) {
        None | Some("") => presets::preset("earth"),
        Some(t) if t.starts_with('{') => presets::parse_json("atmosphere", t),
        Some(name) => presets::preset(name),
    }
}

/// Parses `probe=VZ:VA,VZ:VA` (degrees): view zenith 0–180, view azimuth −360–360.
pub fn parse_probes(text: &str) -> Result<Vec<(f64, f64)>> {
    let probes = text
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|pair| {
            let (vz, va) = pair.split_once(':').ok_or_else(|| {
                Error::invalid("probe", format!("'{pair}' is not VZ:VA (e.g. 30:90)"))
            })?;
            Ok((
                parse_f64("probe", vz, 0.0, 180.0, "deg view zenith")?,
                parse_f64("probe", va, -360.0, 360.0, "deg view azimuth")?,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    if probes.len() > MAX_PROBES {
        return Err(Error::too_large(
            "probe",
            format!("{} directions", probes.len()),
            MAX_PROBES,
        ));
    }
    Ok(probes)
}

/// Builds the common spec; `min_sun_elevation_deg` is the product's lower limit
/// (−90° for every product: night is answered with zero products).
pub fn common_spec(p: &RequestParams, min_sun_elevation_deg: f64) -> Result<CommonSpec> {
    let mut atmosphere = resolve_atmosphere(p.atmosphere.as_deref())?;
    Haze {
        visibility_km: p
            .visibility_km
            .as_deref()
            .map(|v| row("visibility_km").real(v))
            .transpose()?,
        aerosol_type: p
            .aerosol_type
            .as_deref()
            .map(|t| AerosolType::parse("aerosol_type", t))
            .transpose()?,
        boundary_layer_top_m: p
            .boundary_layer_top_m
            .as_deref()
            .map(|v| row("boundary_layer_top_m").real(v))
            .transpose()?,
    }
    .apply(&mut atmosphere)?;
    let wavelengths_nm = match &p.wavelengths {
        Some(w) => Wavelengths::parse(w)?,
        None => Wavelengths::default_set(),
    };
    let sun = match (
        &p.sun_elevation_deg,
        &p.latitude_deg,
        &p.longitude_deg,
        &p.time,
    ) {
        (Some(e), None, None, None) => SunPosition {
            sun_elevation_deg: parse_f64(
                "sun_elevation_deg",
                e,
                min_sun_elevation_deg,
                90.0,
                "deg",
            )?,
            from_location: None,
        },
        (None, Some(lat), Some(lon), Some(time)) => {
            let lat = row("latitude_deg").real(lat)?;
            let lon = row("longitude_deg").real(lon)?;
            let (elevation, azimuth) =
                skybake_physics::solar::sun_elevation_azimuth_deg(lat, lon, time)?;
            if elevation < min_sun_elevation_deg {
                return Err(Error::out_of_range(
                    "time",
                    format!("{time} (sun elevation {elevation:.3}°)"),
                    format!("times when the sun is at least {min_sun_elevation_deg}° high at this place"),
                ));
            }
            SunPosition {
                sun_elevation_deg: elevation,
                from_location: Some(SolarLocation {
                    latitude_deg: lat,
                    longitude_deg: lon,
                    time: time.clone(),
                    sun_azimuth_deg: azimuth,
                }),
            }
        }
        (None, None, None, None) => SunPosition {
            sun_elevation_deg: 30.0,
            from_location: None,
        },
        _ => {
            return Err(Error::invalid(
                "sun_elevation_deg",
                "give either sun_elevation_deg, or all of latitude_deg, longitude_deg and time",
            ))
        }
    };
    let observer_altitude_m = match &p.observer_altitude_m {
        Some(a) => row("observer_altitude_m").real(a)?,
        None => 0.0,
    };
    let ground_albedo = p
        .ground_albedo
        .as_deref()
        .map(|a| row("ground_albedo").real(a))
        .transpose()?;
    let method = p
        .method
        .as_deref()
        .map(MsMethod::parse)
        .transpose()?
        .unwrap_or(MsMethod::Precise);
    let quality = p
        .quality
        .as_deref()
        .map(Quality::parse)
        .transpose()?
        .unwrap_or(Quality::Standard);
    // The retired fast method runs the precise tables at one preset whatever `quality` says, so
    // every `fast` request of one atmosphere has one canonical form (one cache key).
    let quality = match method {
        MsMethod::Fast => skybake_engine::plan::fast_preset(&atmosphere),
        _ => quality,
    };
    Ok(CommonSpec {
        atmosphere,
        wavelengths_nm,
        sun,
        observer_altitude_m,
        ground_albedo,
        method,
        quality,
    })
}

/// Defaults a deployment sets for requests that leave a parameter out (`[defaults]` of the
/// settings); applied once, before parsing, by the service and by offline bakes alike.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Defaults {
    /// Wavelengths when a request gives none ("" = the engine's 16-sample set).
    pub wavelengths: String,
    /// Quality when a request gives none ("" = standard).
    pub quality: String,
}

impl Defaults {
    /// The `[defaults]` section of the settings.
    pub fn from_settings(settings: &crate::config::Settings) -> Self {
        Self {
            wavelengths: settings.defaults.wavelengths.clone(),
            quality: settings.defaults.quality.clone(),
        }
    }

    /// `p` with the defaults filled in where it gives nothing.
    pub fn apply(&self, mut p: RequestParams) -> RequestParams {
        if p.wavelengths.is_none() && !self.wavelengths.trim().is_empty() {
            p.wavelengths = Some(self.wavelengths.clone());
        }
        if p.quality.is_none() && !self.quality.trim().is_empty() {
            p.quality = Some(self.quality.clone());
        }
        p
    }
}

/// Why a list of name/value pairs was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum PairsError {
    /// Names not in the table (each as given, with the caller's prefix).
    Unknown(Vec<String>),
    /// A known parameter with a bad value or given twice.
    Param(Error),
}

impl From<Error> for PairsError {
    fn from(e: Error) -> Self {
        PairsError::Param(e)
    }
}

impl RequestParams {
    /// Parameters from name/value pairs (a decoded query string or CLI matches): unknown names
    /// are collected, a name given twice is refused.
    pub fn from_pairs<K: AsRef<str>, V: Into<String>>(
        pairs: impl IntoIterator<Item = (K, V)>,
    ) -> std::result::Result<Self, PairsError> {
        let mut p = RequestParams::default();
        let mut unknown = Vec::new();
        for (k, v) in pairs {
            let k = k.as_ref();
            match p.slot(k) {
                Some(s) if s.is_some() => {
                    return Err(Error::invalid(k, "given more than once").into())
                }
                Some(s) => *s = Some(v.into()),
                None => unknown.push(k.to_string()),
            }
        }
        if unknown.is_empty() {
            Ok(p)
        } else {
            Err(PairsError::Unknown(unknown))
        }
    }

    /// Parameters from a JSON object (plan and job bodies): strings as given, numbers in their
    /// JSON spelling, `wavelengths` also as an array of numbers, `atmosphere` also as an inline
    /// object. Members named in `skip` are left for the caller; `prefix` goes in front of names in
    /// errors.
    pub fn from_object(
        obj: &Map<String, Value>,
        skip: &[&str],
        prefix: &str,
    ) -> std::result::Result<Self, PairsError> {
        let mut p = RequestParams::default();
        let mut unknown = Vec::new();
        for (k, v) in obj {
            if skip.contains(&k.as_str()) {
                continue;
            }
            let field = format!("{prefix}{k}");
            if parameter(k).is_none() {
                unknown.push(field);
                continue;
            }
            let text = match (k.as_str(), v) {
                (_, Value::Null) => continue,
                (_, Value::String(s)) => s.clone(),
                (_, Value::Number(n)) => n.to_string(),
                ("atmosphere", Value::Object(_)) => v.to_string(),
                ("wavelengths", Value::Array(a)) if a.iter().all(Value::is_number) => a
                    .iter()
                    .map(|n| n.to_string())
                    .collect::<Vec<_>>()
                    .join(","),
                _ => return Err(Error::invalid(&field, "must be a string or a number").into()),
            };
            if let Some(s) = p.slot(k) {
                *s = Some(text);
            }
        }
        if unknown.is_empty() {
            Ok(p)
        } else {
            Err(PairsError::Unknown(unknown))
        }
    }

    /// The parameters given that `product` does not take (in table order).
    pub fn not_for(&self, product: ProductKind) -> Option<&'static str> {
        PARAMETERS
            .iter()
            .find(|row| !row.applies_to(product) && self.get(row.name).is_some())
            .map(|row| row.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> RequestParams {
        RequestParams::from_pairs(pairs.iter().copied()).unwrap()
    }

    #[test]
    fn the_table_and_the_struct_agree() {
        let mut p = RequestParams::default();
        for row in PARAMETERS {
            let slot = p.slot(row.name).expect(row.name);
            *slot = Some("1".into());
        }
        // Every struct field is a table row: serialising a full struct names each row once.
        let v = serde_json::to_value(&p).unwrap();
        assert_eq!(v.as_object().unwrap().len(), PARAMETERS.len());
        for name in [
            "latitude_deg",
            "longitude_deg",
            "observer_altitude_m",
            "ground_albedo",
        ] {
            assert!(parameter(name).is_some(), "{name}");
        }
    }

    #[test]
    fn errors_name_the_parameter() {
        let bad = [
            ("sun_elevation_deg", "-30"),
            ("sun_elevation_deg", "abc"),
            ("observer_altitude_m", "-1"),
            ("wavelengths", "200"),
            ("ground_albedo", "1.5"),
            ("method", "magic"),
            ("quality", "ultra"),
            ("atmosphere", "venus"),
            ("visibility_km", "0.5"),
            ("visibility_km", "fog"),
            ("aerosol_type", "volcanic"),
            ("aerosol_type", "urban"),
            ("boundary_layer_top_m", "800"),
        ];
        for (k, v) in bad {
            let err = crate::params::common_spec(&params(&[(k, v)]), -18.0).unwrap_err();
            assert_eq!(err.field(), k, "{k}={v}: {err}");
        }
        assert_eq!(parse_probes("30:0,45").unwrap_err().field(), "probe");
        assert_eq!(parse_probes("30:0, 200:5").unwrap_err().field(), "probe");
        let twice = RequestParams::from_pairs([("quality", "high"), ("quality", "draft")]);
        assert!(matches!(twice, Err(PairsError::Param(e)) if e.field() == "quality"));
        let unknown = RequestParams::from_pairs([("colour", "red")]);
        assert_eq!(unknown, Err(PairsError::Unknown(vec!["colour".into()])));
    }

    #[test]
    fn defaults_are_sane_and_applied_once() {
        let s = crate::params::common_spec(&RequestParams::default(), -18.0).unwrap();
        assert_eq!(s.wavelengths_nm.len(), 16);
        assert_eq!(s.sun.sun_elevation_deg, 30.0);
        assert_eq!(s.method, MsMethod::Precise);
        assert_eq!(s.atmosphere.name.as_deref(), Some("earth"));
        let d = Defaults {
            wavelengths: "550".into(),
            quality: "draft".into(),
        };
        let p = d.apply(params(&[("quality", "high")]));
        assert_eq!(p.wavelengths.as_deref(), Some("550"));
        assert_eq!(p.quality.as_deref(), Some("high"));
    }
}
