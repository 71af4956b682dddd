//! Haze as users describe it: a meteorological visibility, an aerosol type and a boundary layer.
//!
//! - Visibility → extinction by Koschmieder's law at 550 nm: V = ln(1/0.02) / β = 3.912 / β for
//!   the total extinction β of the air (Koschmieder 1924); the aerosol
//!   extinction is β minus the atmosphere's own sea-level Rayleigh extinction at 550 nm.
//! - Aerosol types: the spectral extinction (relative to 550 nm), single-scattering albedo and
//!   asymmetry parameter of the 6S code's standard models (Vermote et al. 1997; Kotchenova et al.
//!   2006), tabulated at 350–860 nm in `data/aerosol_types_6sv.csv` with their sources. The phase
//!   function is Henyey-Greenstein with the type's asymmetry parameter at 550 nm (its mean cosine is
//!   the model's; over 400–700 nm the models' asymmetry parameter varies by ≤ 0.04).
//! - Layers ([`MieLayers`]): a boundary layer of uniform extinction up to its top, a free
//!   troposphere above it (exponential, given optical depth) and a stratospheric background (uniform,
//!   given optical depth), all of the boundary layer's type.

use super::medium::Medium;
use super::params::{AtmosphereParams, Mie, MieExtinction, MieLayers, MiePhase, Spectral};
use crate::spectrum::Wavelengths;
use crate::{Error, Result};
use std::collections::BTreeMap;
use std::sync::OnceLock;

const TYPES_CSV: &str = include_str!("../../../../data/aerosol_types_6sv.csv");

/// Koschmieder's constant ln(1/0.02): visibility × extinction for a 2 % contrast threshold.
pub const KOSCHMIEDER: f64 = 3.912;

/// The aerosol types' names, as the `aerosol_type` parameter spells them.
pub const AEROSOL_TYPES: &[&str] = &["continental", "maritime", "urban", "desert"];

/// Default boundary-layer top, m.
pub const DEFAULT_BOUNDARY_LAYER_TOP_M: f64 = 1000.0;
/// Largest optical depth at 550 nm of the boundary layer (aerosol extinction × depth) a
/// visibility may give: fog-like haze up to optical depth 6 (visibility 1 km in a boundary layer
/// up to 1.54 km deep, 3.1 km in a 5 km one). Up to it the precise method conserves energy
/// within ~1 % (conservative haze over a white ground, 440 nm, 1.5 km layer, outgoing/incoming at
/// visibility 1, 2, 3, 5 and 10 km: tests/atmosphere/atmosphere_validation.rs) and its sky and
/// irradiance are within 3 % of DISORT in fog of visibility 1 km (tests/atmosphere/atmosphere_fog.rs;
/// docs/atmospheres.md). Beyond it the energy error grows with the number of orders the light
/// survives: 1.098 at optical depth 9.75 (visibility 1 km in a 2.5 km layer, 12.1 at 440 nm).
pub const MAX_BOUNDARY_LAYER_OPTICAL_DEPTH_550: f64 = 6.0;

/// Free-tropospheric background above the boundary layer: optical depth at 550 nm (skybake's
/// choice of a clean background, not a climatology), scale height and top (the tropopause), m.
pub const FREE_TROPOSPHERE: (f64, f64, f64) = (0.02, 2000.0, 12_000.0);
/// Stratospheric background: optical depth at 550 nm and top, m (uniform from the tropopause).
pub const STRATOSPHERE: (f64, f64) = (0.005, 30_000.0);

/// One of the 6S standard aerosol models.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AerosolType {
    Continental,
    Maritime,
    Urban,
    Desert,
}

/// One row of a type's table: wavelength (nm), extinction relative to 550 nm, single-scattering
/// albedo, asymmetry parameter.
pub type TypeRow = [f64; 4];

fn tables() -> &'static BTreeMap<String, Vec<TypeRow>> {
    static T: OnceLock<BTreeMap<String, Vec<TypeRow>>> = OnceLock::new();
    T.get_or_init(|| {
        let mut out: BTreeMap<String, Vec<TypeRow>> = BTreeMap::new();
        for line in TYPES_CSV.lines() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') || line.starts_with("type,") {
                continue;
            }
            let cols: Vec<&str> = line.split(',').collect();
            let num = |i: usize| -> f64 {
                cols.get(i)
                    .and_then(|c| c.trim().parse().ok())
                    .unwrap_or_else(|| panic!("embedded aerosol table is malformed: '{line}'"))
            };
            out.entry(cols[0].to_string())
                .or_default()
                .push([num(1), num(2), num(3), num(4)]);
        }
        out
    })
}

impl AerosolType {
    /// Parses a type name; the error names `field` and lists the types.
    pub fn parse(field: &str, text: &str) -> Result<Self> {
        match text.trim() {
            "continental" => Ok(Self::Continental),
            "maritime" => Ok(Self::Maritime),
            "urban" => Ok(Self::Urban),
            "desert" => Ok(Self::Desert),
            other => Err(Error::out_of_range(field, other, AEROSOL_TYPES.join(", "))),
        }
    }

    /// The type's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Continental => "continental",
            Self::Maritime => "maritime",
            Self::Urban => "urban",
            Self::Desert => "desert",
        }
    }

    /// The type's rows, by wavelength.
    pub fn rows(self) -> &'static [TypeRow] {
        tables().get(self.name()).map(Vec::as_slice).unwrap_or(&[])
    }

    /// Asymmetry parameter at 550 nm.
    pub fn asymmetry_550(self) -> f64 {
        self.rows()
            .iter()
            .find(|r| r[0] == 550.0)
            .map_or(0.7, |r| r[3])
    }

    /// The aerosol section for a sea-level (boundary-layer) extinction at 550 nm, m⁻¹, and layers.
    pub fn mie(self, extinction_550_per_m: f64, layers: MieLayers) -> Mie {
        let key = |nm: f64| format!("{nm}");
        Mie {
            scale_height_m: layers.boundary_layer_top_m,
            extinction: MieExtinction::TablePerM(
                self.rows()
                    .iter()
                    .map(|r| (key(r[0]), r[1] * extinction_550_per_m))
                    .collect(),
            ),
            single_scattering_albedo: Spectral::Table(
                self.rows().iter().map(|r| (key(r[0]), r[2])).collect(),
            ),
            phase: MiePhase::HenyeyGreenstein {
                g: self.asymmetry_550(),
            },
            layers: Some(layers),
        }
    }
}

/// The default layers above a boundary layer of top `boundary_layer_top_m`, within an atmosphere
/// `atmosphere_height_m` high.
pub fn default_layers(boundary_layer_top_m: f64, atmosphere_height_m: f64) -> MieLayers {
    let (ft_tau, ft_h, tropopause) = FREE_TROPOSPHERE;
    let (st_tau, st_top) = STRATOSPHERE;
    let tropopause_m = tropopause
        .min(atmosphere_height_m)
        .max(boundary_layer_top_m);
    MieLayers {
        boundary_layer_top_m,
        free_troposphere_optical_depth_550: ft_tau,
        free_troposphere_scale_height_m: ft_h,
        tropopause_m,
        stratosphere_optical_depth_550: st_tau,
        stratosphere_top_m: st_top.min(atmosphere_height_m).max(tropopause_m),
    }
}

/// Haze given by the user: visibility (km) with an optional type and boundary-layer top (m).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Haze {
    pub visibility_km: Option<f64>,
    pub aerosol_type: Option<AerosolType>,
    pub boundary_layer_top_m: Option<f64>,
}

impl Haze {
    /// Replaces the aerosol of `atmosphere` by this haze (nothing given: unchanged). The type and
    /// the boundary-layer top need a visibility; a visibility the air's own Rayleigh extinction
    /// already limits is refused, naming `visibility_km` and the largest allowed.
    pub fn apply(&self, atmosphere: &mut AtmosphereParams) -> Result<()> {
        let Some(visibility_km) = self.visibility_km else {
            if self.aerosol_type.is_some() {
                return Err(Error::invalid("aerosol_type", "needs visibility_km"));
            }
            if self.boundary_layer_top_m.is_some() {
                return Err(Error::invalid(
                    "boundary_layer_top_m",
                    "needs visibility_km",
                ));
            }
            return Ok(());
        };
        let top = self
            .boundary_layer_top_m
            .unwrap_or(DEFAULT_BOUNDARY_LAYER_TOP_M);
        if top >= atmosphere.atmosphere_height_m {
            return Err(Error::out_of_range(
                "boundary_layer_top_m",
                top,
                format!(
                    "below the atmosphere's top ({} m)",
                    atmosphere.atmosphere_height_m
                ),
            ));
        }
        let mut clear = atmosphere.clone();
        clear.mie = None;
        let at_550 = Wavelengths::parse("550")?;
        let rayleigh_550 = Medium::new(&clear, &at_550, None)?.rayleigh_scattering_per_m[0];
        let total = KOSCHMIEDER / (visibility_km * 1000.0);
        // Rayleigh alone: visibility 3.912/β_R; require an aerosol extinction of at least 1 % of it.
        let largest_km = KOSCHMIEDER / (1.01 * rayleigh_550.max(1e-30)) / 1000.0;
        if total <= 1.01 * rayleigh_550 {
            return Err(Error::out_of_range(
                "visibility_km",
                visibility_km,
                format!(
                    "1 to {largest_km:.0} km (this atmosphere's Rayleigh extinction alone gives {:.0} km)",
                    KOSCHMIEDER / rayleigh_550 / 1000.0
                ),
            ));
        }
        let aerosol = total - rayleigh_550;
        if aerosol * top > MAX_BOUNDARY_LAYER_OPTICAL_DEPTH_550 {
            let smallest_km =
                KOSCHMIEDER / (MAX_BOUNDARY_LAYER_OPTICAL_DEPTH_550 / top + rayleigh_550) / 1000.0;
            return Err(Error::out_of_range(
                "visibility_km",
                visibility_km,
                format!(
                    "at least {smallest_km:.2} km with a boundary layer {top} m deep (boundary_layer_top_m): its optical depth at 550 nm, {:.2} here, is limited to {MAX_BOUNDARY_LAYER_OPTICAL_DEPTH_550}, where energy conservation is measured",
                    aerosol * top
                ),
            ));
        }
        let kind = self.aerosol_type.unwrap_or(AerosolType::Continental);
        atmosphere.mie =
            Some(kind.mie(aerosol, default_layers(top, atmosphere.atmosphere_height_m)));
        atmosphere.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atmosphere::medium::MIE;
    use crate::atmosphere::presets::preset;

    #[test]
    fn types_are_tabulated_from_350_to_860_nm_normalised_at_550() {
        for name in AEROSOL_TYPES {
            let t = AerosolType::parse("aerosol_type", name).unwrap();
            let rows = t.rows();
            assert_eq!(rows.len(), 14, "{name}");
            assert_eq!((rows[0][0], rows[13][0]), (350.0, 860.0));
            let at550 = rows.iter().find(|r| r[0] == 550.0).unwrap();
            assert_eq!(at550[1], 1.0, "{name}");
            for r in rows {
                assert!(r[1] > 0.0 && (0.0..=1.0).contains(&r[2]) && r[3] > 0.5 && r[3] < 0.8);
            }
        }
        // 6S's urban model absorbs most, its maritime one least (ssa at 550 nm 0.6888, 0.9890).
        assert!(AerosolType::Urban.rows()[7][2] < 0.7);
        assert!(AerosolType::Maritime.rows()[7][2] > 0.98);
        assert_eq!(
            AerosolType::parse("aerosol_type", "volcanic")
                .unwrap_err()
                .field(),
            "aerosol_type"
        );
    }

    #[test]
    fn visibility_gives_the_koschmieder_extinction_at_550_nm() {
        let w = Wavelengths::parse("550").unwrap();
        for (v_km, top) in [(1.0, 500.0), (10.0, 1000.0), (50.0, 2500.0)] {
            let mut a = preset("earth").unwrap();
            Haze {
                visibility_km: Some(v_km),
                aerosol_type: Some(AerosolType::Maritime),
                boundary_layer_top_m: Some(top),
            }
            .apply(&mut a)
            .unwrap();
            let m = Medium::new(&a, &w, None).unwrap();
            // Total extinction at the ground: Rayleigh + aerosol (+ no ozone at the ground).
            let beta = m.rayleigh_scattering_per_m[0]
                + m.extinction_per_m[MIE][0] * m.densities(m.bottom_radius_m)[MIE];
            assert!(
                (KOSCHMIEDER / beta / 1000.0 / v_km - 1.0).abs() < 1e-9,
                "{v_km}"
            );
            // Column: boundary layer + the backgrounds' optical depths.
            let tau = m.vertical_optical_depth(0)[MIE];
            let bl = (beta - m.rayleigh_scattering_per_m[0]) * top;
            let want = bl + FREE_TROPOSPHERE.0 + STRATOSPHERE.0;
            assert!((tau / want - 1.0).abs() < 1e-9, "{tau} {want}");
            // The aircraft climbs out of the haze: 100 m above the top of a hazy layer (visibility
            // ≤ 10 km) less than a tenth of its aerosol (at 50 km the clean layer holds little
            // more than the background: 0.145 of it above).
            let above = m.densities(m.bottom_radius_m + top + 100.0)[MIE];
            assert!(above < if v_km <= 10.0 { 0.1 } else { 0.2 }, "{above}");
        }
    }

    #[test]
    fn fog_beyond_the_measured_optical_depth_is_refused_naming_visibility() {
        let haze = |v_km: f64, top: f64| Haze {
            visibility_km: Some(v_km),
            aerosol_type: None,
            boundary_layer_top_m: Some(top),
        };
        // 1 km in a 1 km and a 1.5 km layer: optical depth 3.9 and 5.85 at 550 nm, allowed;
        // 1 km in a 2.5 km layer (9.75) and 1.5 km in a 5 km layer (13.0) are not, and the
        // message gives the smallest visibility for the depth (1.62 and 3.23 km).
        for top in [1000.0, 1500.0] {
            assert!(haze(1.0, top).apply(&mut preset("earth").unwrap()).is_ok());
        }
        for (v, top, smallest) in [(1.0, 2500.0, "at least 1.6"), (1.5, 5000.0, "at least 3.2")] {
            let err = haze(v, top)
                .apply(&mut preset("earth").unwrap())
                .unwrap_err();
            assert_eq!(err.field(), "visibility_km");
            assert!(err.to_string().contains(smallest), "{err}");
        }
    }

    #[test]
    fn bad_haze_names_the_parameter() {
        let cases = [
            (
                Haze {
                    visibility_km: Some(400.0),
                    ..Haze::default()
                },
                "visibility_km",
            ),
            (
                Haze {
                    aerosol_type: Some(AerosolType::Urban),
                    ..Haze::default()
                },
                "aerosol_type",
            ),
            (
                Haze {
                    boundary_layer_top_m: Some(500.0),
                    ..Haze::default()
                },
                "boundary_layer_top_m",
            ),
            (
                Haze {
                    visibility_km: Some(5.0),
                    boundary_layer_top_m: Some(200_000.0),
                    ..Haze::default()
                },
                "boundary_layer_top_m",
            ),
        ];
        for (haze, field) in cases {
            let mut a = preset("earth").unwrap();
            assert_eq!(haze.apply(&mut a).unwrap_err().field(), field);
        }
    }
}
