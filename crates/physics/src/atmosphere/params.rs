//! Atmosphere parameters as JSON (every field in SI units; see `config/atmospheres/*.json`).
//!
//! Any component (`rayleigh`, `mie`, `ozone`, `ground_albedo`) may be `null` to leave it out.
//! Wavelength tables are objects keyed by wavelength in nm (`{"440": 3.31e-5, "550": 1.3558e-5}`),
//! interpolated linearly in wavelength and held constant beyond their ends.

use crate::spectrum::Tabulated;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A spherical planet's atmosphere.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AtmosphereParams {
    /// Human-readable name (not part of the physics).
    #[serde(default)]
    pub name: Option<String>,
    /// Planet (ground) radius, m.
    pub planet_radius_m: f64,
    /// Height of the top of the atmosphere above the ground, m; nothing scatters above it.
    pub atmosphere_height_m: f64,
    /// Distance from the sun, astronomical units; the solar spectrum scales as 1/d².
    #[serde(default = "one")]
    pub sun_distance_au: f64,
    /// Angular radius of the sun's disk, degrees (softens the terminator at sunset).
    #[serde(default = "default_sun_radius")]
    pub sun_angular_radius_deg: f64,
    /// Molecular (Rayleigh) scattering, or `null`.
    pub rayleigh: Option<Rayleigh>,
    /// Aerosol (Mie) scattering and absorption, or `null`.
    pub mie: Option<Mie>,
    /// Ozone absorption, or `null`.
    pub ozone: Option<Ozone>,
    /// Lambertian ground albedo (a number or a wavelength table), or `null` for a black ground.
    pub ground_albedo: Option<Spectral>,
}

fn one() -> f64 {
    1.0
}
fn default_sun_radius() -> f64 {
    0.2666
}

/// Rayleigh scattering: density `exp(-h / scale_height_m)` times a sea-level coefficient.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rayleigh {
    /// Exponential scale height, m.
    pub scale_height_m: f64,
    /// Sea-level scattering coefficient as a function of wavelength.
    pub scattering: RayleighScattering,
}

/// How the sea-level Rayleigh scattering coefficient depends on wavelength.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum RayleighScattering {
    /// Bodhaine et al. 1999 cross-section of dry air (360 ppm CO₂) times a sea-level number
    /// density in molecules m⁻³ (2.69e25 with an 8 km scale height gives Bodhaine's column).
    Bodhaine1999 { number_density_m3: f64 },
    /// `value_per_m · (λ / reference_nm)^(−exponent)`.
    PowerLaw {
        reference_nm: f64,
        value_per_m: f64,
        exponent: f64,
    },
    /// Explicit table, m⁻¹, keyed by wavelength in nm.
    TablePerM(BTreeMap<String, f64>),
}

/// Aerosol: density `exp(-h / scale_height_m)` (or `layers`), extinction, single-scattering
/// albedo, phase.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mie {
    /// Exponential scale height, m (not used when `layers` is given).
    pub scale_height_m: f64,
    /// Sea-level extinction coefficient as a function of wavelength.
    pub extinction: MieExtinction,
    /// Single-scattering albedo (scattering / extinction), 0–1, number or table.
    pub single_scattering_albedo: Spectral,
    /// Phase function.
    pub phase: MiePhase,
    /// A layered profile instead of the exponential one: the extinction is the boundary layer's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layers: Option<MieLayers>,
}

/// A layered aerosol profile (`haze.rs`): uniform boundary layer from the ground to
/// `boundary_layer_top_m` (relative density 1), a free troposphere above it to `tropopause_m`
/// (density falling with `free_troposphere_scale_height_m`), a uniform stratospheric background
/// from the tropopause to `stratosphere_top_m`; the two backgrounds given by their vertical
/// optical depths at 550 nm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MieLayers {
    pub boundary_layer_top_m: f64,
    pub free_troposphere_optical_depth_550: f64,
    pub free_troposphere_scale_height_m: f64,
    pub tropopause_m: f64,
    pub stratosphere_optical_depth_550: f64,
    pub stratosphere_top_m: f64,
}

/// How the aerosol extinction depends on wavelength.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum MieExtinction {
    /// Vertical optical depth of the whole aerosol layer at `reference_nm`, Ångström law
    /// `τ(λ) = value · (λ / reference_nm)^(−angstrom_exponent)`.
    OpticalDepth {
        reference_nm: f64,
        value: f64,
        angstrom_exponent: f64,
    },
    /// Sea-level extinction coefficient `value_per_m · (λ / reference_nm)^(−angstrom_exponent)`.
    PowerLaw {
        reference_nm: f64,
        value_per_m: f64,
        angstrom_exponent: f64,
    },
    /// Explicit sea-level extinction table, m⁻¹, keyed by wavelength in nm.
    TablePerM(BTreeMap<String, f64>),
}

/// Aerosol phase function.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum MiePhase {
    /// Cornette-Shanks (Nishita et al. 1996, eq 5), asymmetry parameter `g` in (−1, 1).
    CornetteShanks { g: f64 },
    /// Henyey-Greenstein, asymmetry parameter `g` in (−1, 1).
    HenyeyGreenstein { g: f64 },
}

/// Ozone: an absorbing layer with SPECTRL2 cross-sections.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ozone {
    /// Vertical shape of the layer.
    pub profile: OzoneProfile,
    /// Amount: total column (Dobson units) or peak number density (molecules m⁻³).
    pub amount: OzoneAmount,
}

/// Vertical shape of the ozone layer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum OzoneProfile {
    /// Density `max(0, 1 − |h − peak_altitude_m| / half_width_m)`.
    Tent {
        peak_altitude_m: f64,
        half_width_m: f64,
    },
}

/// Amount of ozone.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum OzoneAmount {
    /// Total vertical column, Dobson units (1 DU = 2.6867e20 molecules m⁻²).
    ColumnDobson(f64),
    /// Number density at the profile's peak, molecules m⁻³.
    PeakNumberDensityM3(f64),
}

/// A dimensionless spectral quantity: one number for all wavelengths, or a table keyed by nm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Spectral {
    Constant(f64),
    Table(BTreeMap<String, f64>),
}

/// Parses a wavelength-keyed table into a [`Tabulated`].
pub(crate) fn parse_table(field: &str, table: &BTreeMap<String, f64>) -> Result<Tabulated> {
    let mut pairs = table
        .iter()
        .map(|(k, &v)| {
            let nm: f64 = k.trim().parse().map_err(|_| {
                Error::invalid(field, format!("key '{k}' is not a wavelength in nm"))
            })?;
            if !(nm.is_finite() && nm > 0.0) {
                return Err(Error::invalid(
                    field,
                    format!("key '{k}' is not a positive wavelength"),
                ));
            }
            Ok((nm, v))
        })
        .collect::<Result<Vec<_>>>()?;
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (x, y) = pairs.into_iter().unzip();
    Tabulated::new(field, x, y)
}

impl Spectral {
    /// Value at `nm`.
    pub fn resolve(&self, field: &str, nm: &[f64], lo: f64, hi: f64) -> Result<Vec<f64>> {
        let values = match self {
            Spectral::Constant(v) => vec![*v; nm.len()],
            Spectral::Table(t) => {
                let t = parse_table(field, t)?;
                nm.iter().map(|&l| t.eval(l)).collect()
            }
        };
        for &v in &values {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(Error::out_of_range(field, v, format!("{lo}–{hi}")));
            }
        }
        Ok(values)
    }
}

fn check(field: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<()> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(Error::out_of_range(field, v, format!("{lo}–{hi} {unit}")))
    }
}

impl AtmosphereParams {
    /// Checks every scalar field's range (wavelength-dependent values are checked on resolution).
    pub fn validate(&self) -> Result<()> {
        check("planet_radius_m", self.planet_radius_m, 1.0e3, 1.0e8, "m")?;
        check(
            "atmosphere_height_m",
            self.atmosphere_height_m,
            100.0,
            (0.5 * self.planet_radius_m).min(2.0e6),
            "m",
        )?;
        check("sun_distance_au", self.sun_distance_au, 0.01, 100.0, "AU")?;
        check(
            "sun_angular_radius_deg",
            self.sun_angular_radius_deg,
            0.0,
            5.0,
            "deg",
        )?;
        let h = self.atmosphere_height_m;
        if let Some(r) = &self.rayleigh {
            check(
                "rayleigh.scale_height_m",
                r.scale_height_m,
                1.0,
                10.0 * h,
                "m",
            )?;
            match &r.scattering {
                RayleighScattering::Bodhaine1999 { number_density_m3 } => check(
                    "rayleigh.scattering.bodhaine1999.number_density_m3",
                    *number_density_m3,
                    0.0,
                    1.0e30,
                    "m^-3",
                )?,
                RayleighScattering::PowerLaw {
                    reference_nm,
                    value_per_m,
                    exponent,
                } => {
                    check(
                        "rayleigh.scattering.power_law.reference_nm",
                        *reference_nm,
                        100.0,
                        5000.0,
                        "nm",
                    )?;
                    check(
                        "rayleigh.scattering.power_law.value_per_m",
                        *value_per_m,
                        0.0,
                        1.0,
                        "m^-1",
                    )?;
                    check(
                        "rayleigh.scattering.power_law.exponent",
                        *exponent,
                        -10.0,
                        10.0,
                        "",
                    )?;
                }
                RayleighScattering::TablePerM(t) => {
                    let t = parse_table("rayleigh.scattering.table_per_m", t)?;
                    for &v in t.ys() {
                        check("rayleigh.scattering.table_per_m", v, 0.0, 1.0, "m^-1")?;
                    }
                }
            }
        }
        if let Some(m) = &self.mie {
            check("mie.scale_height_m", m.scale_height_m, 1.0, 10.0 * h, "m")?;
            match &m.extinction {
                MieExtinction::OpticalDepth {
                    reference_nm,
                    value,
                    angstrom_exponent,
                } => {
                    check(
                        "mie.extinction.optical_depth.reference_nm",
                        *reference_nm,
                        100.0,
                        5000.0,
                        "nm",
                    )?;
                    check("mie.extinction.optical_depth.value", *value, 0.0, 100.0, "")?;
                    check(
                        "mie.extinction.optical_depth.angstrom_exponent",
                        *angstrom_exponent,
                        -4.0,
                        4.0,
                        "",
                    )?;
                }
                MieExtinction::PowerLaw {
                    reference_nm,
                    value_per_m,
                    angstrom_exponent,
                } => {
                    check(
                        "mie.extinction.power_law.reference_nm",
                        *reference_nm,
                        100.0,
                        5000.0,
                        "nm",
                    )?;
                    check(
                        "mie.extinction.power_law.value_per_m",
                        *value_per_m,
                        0.0,
                        1.0,
                        "m^-1",
                    )?;
                    check(
                        "mie.extinction.power_law.angstrom_exponent",
                        *angstrom_exponent,
                        -4.0,
                        4.0,
                        "",
                    )?;
                }
                MieExtinction::TablePerM(t) => {
                    let t = parse_table("mie.extinction.table_per_m", t)?;
                    for &v in t.ys() {
                        check("mie.extinction.table_per_m", v, 0.0, 1.0, "m^-1")?;
                    }
                }
            }
            let g = match m.phase {
                MiePhase::CornetteShanks { g } | MiePhase::HenyeyGreenstein { g } => g,
            };
            check("mie.phase.g", g, -0.999, 0.999, "")?;
            if let Some(l) = &m.layers {
                if matches!(m.extinction, MieExtinction::OpticalDepth { .. }) {
                    return Err(Error::invalid(
                        "mie.layers",
                        "needs the boundary layer's extinction (power_law or table_per_m), not optical_depth",
                    ));
                }
                check(
                    "mie.layers.boundary_layer_top_m",
                    l.boundary_layer_top_m,
                    10.0,
                    h,
                    "m",
                )?;
                check(
                    "mie.layers.tropopause_m",
                    l.tropopause_m,
                    l.boundary_layer_top_m,
                    h,
                    "m",
                )?;
                check(
                    "mie.layers.stratosphere_top_m",
                    l.stratosphere_top_m,
                    l.tropopause_m,
                    h,
                    "m",
                )?;
                check(
                    "mie.layers.free_troposphere_scale_height_m",
                    l.free_troposphere_scale_height_m,
                    10.0,
                    10.0 * h,
                    "m",
                )?;
                check(
                    "mie.layers.free_troposphere_optical_depth_550",
                    l.free_troposphere_optical_depth_550,
                    0.0,
                    10.0,
                    "",
                )?;
                check(
                    "mie.layers.stratosphere_optical_depth_550",
                    l.stratosphere_optical_depth_550,
                    0.0,
                    10.0,
                    "",
                )?;
            }
        }
        if let Some(o) = &self.ozone {
            let OzoneProfile::Tent {
                peak_altitude_m,
                half_width_m,
            } = o.profile;
            check(
                "ozone.profile.tent.peak_altitude_m",
                peak_altitude_m,
                0.0,
                h,
                "m",
            )?;
            check("ozone.profile.tent.half_width_m", half_width_m, 1.0, h, "m")?;
            match o.amount {
                OzoneAmount::ColumnDobson(v) => {
                    check("ozone.amount.column_dobson", v, 0.0, 10_000.0, "DU")?
                }
                OzoneAmount::PeakNumberDensityM3(v) => check(
                    "ozone.amount.peak_number_density_m3",
                    v,
                    0.0,
                    1.0e22,
                    "m^-3",
                )?,
            }
        }
        Ok(())
    }
}
