//! Parsing at the edge: the parameters of a request (CLI flags or an HTTP query string, both as
//! strings) become one canonical, validated, hashable spec (STYLE.md §3). Errors name the
//! parameter and its allowed range.

use crate::atmosphere::params::AtmosphereParams;
use crate::atmosphere::presets;
use crate::atmosphere::sky::MsMethod;
use crate::spectrum::Wavelengths;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Highest observer altitude accepted, m (geostationary orbit and a bit).
pub const MAX_OBSERVER_ALTITUDE_M: f64 = 40_000_000.0;
/// Most table cells (rows × columns) in one sky/ground table: with 64 wavelengths, 64 MiB of
/// radiance, so no single request can take a large share of the machine's memory.
pub const MAX_TABLE_CELLS: usize = 512 * 512;
/// Most probe directions in one request.
pub const MAX_PROBES: usize = 4096;
/// Most aerial-perspective cells (azimuths × elevations × distances): with 64 wavelengths and
/// two layers (transmittance, in-scattered radiance), 128 MiB.
pub const MAX_AERIAL_CELLS: usize = 256 * 1024;

/// Request parameters as they arrive (all optional strings; missing ones take defaults).
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RequestParams {
    pub sun_elevation_deg: Option<String>,
    pub latitude_deg: Option<String>,
    pub longitude_deg: Option<String>,
    pub time: Option<String>,
    pub observer_altitude_m: Option<String>,
    pub wavelengths: Option<String>,
    pub atmosphere: Option<String>,
    pub ground_albedo: Option<String>,
    pub method: Option<String>,
    pub quality: Option<String>,
    pub elevation_count: Option<String>,
    pub azimuth_count: Option<String>,
    pub distance_count: Option<String>,
    pub max_distance_m: Option<String>,
    pub probe: Option<String>,
    pub format: Option<String>,
}

/// Quality presets: ray-marching steps and table resolutions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Quality {
    Draft,
    Standard,
    High,
    Reference,
}

impl Quality {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "draft" => Ok(Self::Draft),
            "standard" => Ok(Self::Standard),
            "high" => Ok(Self::High),
            "reference" => Ok(Self::Reference),
            _ => Err(Error::invalid(
                "quality",
                format!("'{s}' is not one of draft, standard, high, reference"),
            )),
        }
    }

    /// Samples per ray segment for product rays.
    pub fn steps(self) -> usize {
        match self {
            Self::Draft => 16,
            Self::Standard => 32,
            Self::High => 64,
            Self::Reference => 160,
        }
    }
}

/// Where the sun is: given directly, or from a place and a time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SunPosition {
    /// Sun elevation above the observer's horizontal plane, degrees.
    pub sun_elevation_deg: f64,
    /// When computed from a place and time: the inputs and the sun's azimuth.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub from_location: Option<SolarLocation>,
}

/// Place and time a sun position was computed from.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SolarLocation {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub time: String,
    pub sun_azimuth_deg: f64,
}

/// Everything sun/sky/ground/aerial share, canonical and validated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CommonSpec {
    pub atmosphere: AtmosphereParams,
    pub wavelengths_nm: Wavelengths,
    pub sun: SunPosition,
    pub observer_altitude_m: f64,
    /// Overrides the atmosphere's ground albedo when set.
    pub ground_albedo: Option<f64>,
    pub method: MsMethod,
    pub quality: Quality,
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

/// Solar position hook: (latitude, longitude, RFC 3339 time) → (elevation, azimuth), degrees.
pub type SolarPositionFn = fn(f64, f64, &str) -> Result<(f64, f64)>;

impl CommonSpec {
    /// Builds the common spec; `min_sun_elevation_deg` is the product's lower limit
    /// (−18° for every product).
    pub fn from_params(p: &RequestParams, min_sun_elevation_deg: f64) -> Result<Self> {
        let atmosphere = resolve_atmosphere(p.atmosphere.as_deref())?;
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
                let lat = parse_f64("latitude_deg", lat, -90.0, 90.0, "deg")?;
                let lon = parse_f64("longitude_deg", lon, -180.0, 180.0, "deg")?;
                let (elevation, azimuth) = crate::solar::sun_elevation_azimuth_deg(lat, lon, time)?;
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
            Some(a) => parse_f64("observer_altitude_m", a, 0.0, MAX_OBSERVER_ALTITUDE_M, "m")?,
            None => 0.0,
        };
        let ground_albedo = p
            .ground_albedo
            .as_deref()
            .map(|a| parse_f64("ground_albedo", a, 0.0, 1.0, ""))
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
        Ok(Self {
            atmosphere,
            wavelengths_nm,
            sun,
            observer_altitude_m,
            ground_albedo,
            method,
            quality,
        })
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

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> RequestParams {
        let v: serde_json::Map<String, serde_json::Value> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), serde_json::Value::String(v.to_string())))
            .collect();
        serde_json::from_value(serde_json::Value::Object(v)).unwrap()
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
        ];
        for (k, v) in bad {
            let err = CommonSpec::from_params(&params(&[(k, v)]), -18.0).unwrap_err();
            let field = if k == "wavelengths" || k == "atmosphere" {
                k
            } else {
                err.field()
            };
            assert!(err.field().starts_with(field), "{k}={v}: {err}");
            assert_eq!(err.field(), k, "{k}={v}: {err}");
        }
        assert_eq!(parse_probes("30:0,45").unwrap_err().field(), "probe");
        assert_eq!(parse_probes("30:0, 200:5").unwrap_err().field(), "probe");
    }

    #[test]
    fn defaults_are_sane() {
        let s = CommonSpec::from_params(&RequestParams::default(), -18.0).unwrap();
        assert_eq!(s.wavelengths_nm.len(), 16);
        assert_eq!(s.sun.sun_elevation_deg, 30.0);
        assert_eq!(s.method, MsMethod::Precise);
        assert_eq!(s.atmosphere.name.as_deref(), Some("earth"));
    }
}
