//! The canonical, validated, hashable specs of the atmosphere products (parse, don't validate): what the
//! planner plans and the engine executes. `skybake_product::params` parses request parameters
//! (CLI flags, query strings, JSON bodies) into these; the constructors here hold the limits, so a
//! spec that exists is valid and nothing downstream checks again.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use skybake_physics::atmosphere::params::AtmosphereParams;
pub use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_physics::spectrum::Wavelengths;

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

/// Solar position hook: (latitude, longitude, RFC 3339 time) → (elevation, azimuth), degrees.
pub type SolarPositionFn = fn(f64, f64, &str) -> Result<(f64, f64)>;

/// The products. A product whose spec comes from a JSON body rather than query parameters (the
/// cloud `Frame(Scene)` to come) is one more variant here and in [`ProductSpec`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProductKind {
    Sun,
    Sky,
    Ground,
    Aerial,
}

impl ProductKind {
    /// All kinds, in route order.
    pub const ALL: [ProductKind; 4] = [Self::Sun, Self::Sky, Self::Ground, Self::Aerial];

    pub fn name(self) -> &'static str {
        match self {
            Self::Sun => "sun",
            Self::Sky => "sky",
            Self::Ground => "ground",
            Self::Aerial => "aerial",
        }
    }

    /// Parses a product name (`product` member of plan and job bodies).
    pub fn parse(s: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                Error::invalid(
                    "product",
                    format!("'{s}' is not one of sun, sky, ground, aerial"),
                )
            })
    }

    /// Lowest sun elevation the product accepts, degrees: any (night and polar cases are answered). Below the darkest
    /// modelled twilight the plan leaves the scattering stages out and the products are zero
    /// (`plan::darkest_twilight_deg`).
    pub fn min_sun_elevation_deg(self) -> f64 {
        -90.0
    }
}

/// Table shape of a sky/ground/aerial request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DomeShape {
    pub elevation_count: usize,
    pub azimuth_count: usize,
}

/// Default sky table shape (CLI and HTTP).
pub const SKY_SHAPE: DomeShape = DomeShape {
    elevation_count: 129,
    azimuth_count: 64,
};
/// Default ground table shape.
pub const GROUND_SHAPE: DomeShape = DomeShape {
    elevation_count: 65,
    azimuth_count: 64,
};
/// Default aerial-perspective shape.
pub const AERIAL_SHAPE: DomeShape = DomeShape {
    elevation_count: 33,
    azimuth_count: 16,
};
/// Default aerial distances per ray.
pub const AERIAL_DISTANCE_COUNT: usize = 32;
/// Default largest aerial distance, m.
pub const AERIAL_MAX_DISTANCE_M: f64 = 100_000.0;

impl DomeShape {
    /// Checks the shape: 2–4096 rows, 1–4096 columns, at most [`MAX_TABLE_CELLS`] cells.
    pub fn checked(self) -> Result<Self> {
        if !(2..=4096).contains(&self.elevation_count) {
            return Err(Error::out_of_range(
                "elevation_count",
                self.elevation_count,
                "2 to 4096",
            ));
        }
        if !(1..=4096).contains(&self.azimuth_count) {
            return Err(Error::out_of_range(
                "azimuth_count",
                self.azimuth_count,
                "1 to 4096",
            ));
        }
        let cells = self.elevation_count * self.azimuth_count;
        if cells > MAX_TABLE_CELLS {
            return Err(Error::too_large(
                "elevation_count",
                format!("{cells} table cells (elevations × azimuths)"),
                MAX_TABLE_CELLS,
            ));
        }
        Ok(self)
    }
}

/// A sky or ground table and exact probe directions (view zenith, view azimuth), degrees.
/// Construct with [`DomeSpec::sky`] or [`DomeSpec::ground`], which check the limits.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DomeSpec {
    shape: DomeShape,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    probes: Vec<(f64, f64)>,
}

impl DomeSpec {
    /// A sky table (view elevation −90…90°) of `shape` and probes anywhere on the sphere.
    pub fn sky(shape: DomeShape, probes: Vec<(f64, f64)>) -> Result<Self> {
        Self::checked(shape, probes, 0.0)
    }

    /// A ground table (view elevation −90…0°): probes must look down (view zenith ≥ 90°).
    pub fn ground(shape: DomeShape, probes: Vec<(f64, f64)>) -> Result<Self> {
        Self::checked(shape, probes, 90.0)
    }

    fn checked(shape: DomeShape, probes: Vec<(f64, f64)>, min_zenith_deg: f64) -> Result<Self> {
        let shape = shape.checked()?;
        if probes.len() > MAX_PROBES {
            return Err(Error::too_large(
                "probe",
                format!("{} directions", probes.len()),
                MAX_PROBES,
            ));
        }
        for &(vz, va) in &probes {
            if !(vz.is_finite() && (min_zenith_deg..=180.0).contains(&vz)) {
                let allowed = if min_zenith_deg > 0.0 {
                    "90 to 180 deg view zenith (ground looks down)"
                } else {
                    "0 to 180 deg view zenith"
                };
                return Err(Error::out_of_range("probe", vz, allowed));
            }
            if !(va.is_finite() && (-360.0..=360.0).contains(&va)) {
                return Err(Error::out_of_range(
                    "probe",
                    va,
                    "-360 to 360 deg view azimuth",
                ));
            }
        }
        Ok(Self { shape, probes })
    }

    pub fn shape(&self) -> DomeShape {
        self.shape
    }

    pub fn probes(&self) -> &[(f64, f64)] {
        &self.probes
    }
}

/// An aerial-perspective table: directions × distances from 0 to `max_distance_m`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AerialSpec {
    shape: DomeShape,
    distance_count: usize,
    max_distance_m: f64,
}

impl AerialSpec {
    /// Checks the limits: 1–4096 distances, 1 m–10 000 km, at most [`MAX_AERIAL_CELLS`] cells.
    pub fn new(shape: DomeShape, distance_count: usize, max_distance_m: f64) -> Result<Self> {
        let shape = shape.checked()?;
        if !(1..=4096).contains(&distance_count) {
            return Err(Error::out_of_range(
                "distance_count",
                distance_count,
                "1 to 4096",
            ));
        }
        if !(max_distance_m.is_finite() && (1.0..=1.0e7).contains(&max_distance_m)) {
            return Err(Error::out_of_range(
                "max_distance_m",
                max_distance_m,
                "1 to 10000000 m",
            ));
        }
        let cells = shape.elevation_count * shape.azimuth_count * distance_count;
        if cells > MAX_AERIAL_CELLS {
            return Err(Error::too_large(
                "distance_count",
                format!("{cells} cells (elevations × azimuths × distances)"),
                MAX_AERIAL_CELLS,
            ));
        }
        Ok(Self {
            shape,
            distance_count,
            max_distance_m,
        })
    }

    pub fn shape(&self) -> DomeShape {
        self.shape
    }

    pub fn distance_count(&self) -> usize {
        self.distance_count
    }

    pub fn max_distance_m(&self) -> f64 {
        self.max_distance_m
    }
}

/// What to compute, beyond the [`CommonSpec`]: one variant per product. Serialised with a
/// `product` tag (part of the canonical request and so of the cache key).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "product", rename_all = "snake_case")]
pub enum ProductSpec {
    Sun,
    Sky(DomeSpec),
    Ground(DomeSpec),
    Aerial(AerialSpec),
}

impl ProductSpec {
    pub fn kind(&self) -> ProductKind {
        match self {
            Self::Sun => ProductKind::Sun,
            Self::Sky(_) => ProductKind::Sky,
            Self::Ground(_) => ProductKind::Ground,
            Self::Aerial(_) => ProductKind::Aerial,
        }
    }

    /// Output cells (pixels of the artifact).
    pub fn pixel_count(&self) -> usize {
        match self {
            Self::Sun => 1,
            Self::Sky(d) | Self::Ground(d) => d.shape.elevation_count * d.shape.azimuth_count,
            Self::Aerial(a) => a.shape.elevation_count * a.shape.azimuth_count * a.distance_count,
        }
    }

    /// Probe directions (sky and ground).
    pub fn probes(&self) -> &[(f64, f64)] {
        match self {
            Self::Sky(d) | Self::Ground(d) => d.probes(),
            _ => &[],
        }
    }
}
