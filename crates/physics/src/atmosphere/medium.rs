//! An atmosphere resolved for one wavelength list: density profiles and optical coefficients.
//!
//! Optical depth along any path is `Σ_k coefficient_k(λ) · D_k`, where `D_k = ∫ ρ_k ds` is the
//! wavelength-independent density integral of constituent k (Rayleigh, Mie, ozone), in metres.
//! Tables therefore store `D_k` once and every wavelength is a multiply away.

use super::params::*;
use crate::phase::Phase;
use crate::spectrum::{data, Wavelengths};
use crate::Result;
use serde::Serialize;

/// Number of constituents with a density profile.
pub const CONSTITUENTS: usize = 3;
/// Index of the Rayleigh constituent.
pub const RAYLEIGH: usize = 0;
/// Index of the aerosol constituent.
pub const MIE: usize = 1;
/// Index of the ozone constituent.
pub const OZONE: usize = 2;

/// One Dobson unit, molecules m⁻².
pub const DOBSON_UNIT_M2: f64 = 2.6867e20;

/// Relative density of a constituent as a function of altitude.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum Profile {
    /// Absent.
    None,
    /// `exp(-h / scale_height_m)`.
    Exponential { scale_height_m: f64 },
    /// `max(0, 1 − |h − peak_m| / half_width_m)`.
    Tent { peak_m: f64, half_width_m: f64 },
    /// Layered aerosol ([`MieLayers`]): 1 up to `top_m`, `free_ratio · exp(−(h − top_m) /
    /// free_scale_height_m)` up to `tropopause_m`, `strat_ratio` up to `strat_top_m`, 0 above.
    Layered {
        top_m: f64,
        free_ratio: f64,
        free_scale_height_m: f64,
        tropopause_m: f64,
        strat_ratio: f64,
        strat_top_m: f64,
    },
}

impl Profile {
    /// Relative density at altitude `h_m` (clamped to ≥ 0 altitude).
    #[inline]
    pub fn density(&self, h_m: f64) -> f64 {
        match *self {
            Profile::None => 0.0,
            Profile::Exponential { scale_height_m } => (-h_m.max(0.0) / scale_height_m).exp(),
            Profile::Tent {
                peak_m,
                half_width_m,
            } => (1.0 - (h_m - peak_m).abs() / half_width_m).max(0.0),
            Profile::Layered {
                top_m,
                free_ratio,
                free_scale_height_m,
                tropopause_m,
                strat_ratio,
                strat_top_m,
            } => {
                if h_m <= top_m {
                    1.0
                } else if h_m <= tropopause_m {
                    free_ratio * (-(h_m - top_m) / free_scale_height_m).exp()
                } else if h_m <= strat_top_m {
                    strat_ratio
                } else {
                    0.0
                }
            }
        }
    }

    /// Altitude, m, where the relative density jumps by a large factor, or `None` for profiles
    /// without one: the top of a layered aerosol's boundary layer (density 1 below, the free
    /// troposphere's `free_ratio` ≪ 1 above). Ray quadratures split there so that no cell
    /// straddles it (see `integrate::ray_points`). The layered profile's other steps (tropopause,
    /// stratosphere top) are between background densities whose optical depths are 0.02 and 0.005
    /// at 550 nm, and are left to the quadrature.
    pub fn jump_altitude_m(&self) -> Option<f64> {
        match *self {
            Profile::Layered { top_m, .. } => Some(top_m),
            _ => None,
        }
    }

    /// Top, m, of the layer of uniform relative density 1 at the bottom of a layered aerosol
    /// (its boundary layer), or `None` for other profiles. The integral of that part along a ray
    /// is the ray's chord through the sphere of radius bottom + top, which density integrals take
    /// exactly (`transmittance::density_integrals`, the density-integral table's lookups); only
    /// the rest ([`Self::density_above_uniform_layer`]) is integrated numerically and
    /// interpolated.
    pub fn uniform_layer_top_m(&self) -> Option<f64> {
        match *self {
            Profile::Layered { top_m, .. } => Some(top_m),
            _ => None,
        }
    }

    /// The relative density less the uniform layer of [`Self::uniform_layer_top_m`] (0 inside
    /// that layer; the density itself above it and for other profiles).
    #[inline]
    pub fn density_above_uniform_layer(&self, h_m: f64) -> f64 {
        match *self {
            Profile::Layered { top_m, .. } if h_m <= top_m => 0.0,
            _ => self.density(h_m),
        }
    }

    /// Vertical integral ∫₀^top ρ dh, m (exact).
    pub fn column_m(&self, top_m: f64) -> f64 {
        match *self {
            Profile::None => 0.0,
            Profile::Exponential { scale_height_m } => {
                scale_height_m * (1.0 - (-top_m / scale_height_m).exp())
            }
            Profile::Tent {
                peak_m,
                half_width_m,
            } => {
                // Integrate the piecewise-linear tent over [0, top] exactly with its knots.
                let knots = [
                    0.0,
                    peak_m - half_width_m,
                    peak_m,
                    peak_m + half_width_m,
                    top_m,
                ];
                let mut k: Vec<f64> = knots.iter().map(|&x| x.clamp(0.0, top_m)).collect();
                k.sort_by(f64::total_cmp);
                k.windows(2)
                    .map(|w| 0.5 * (self.density(w[0]) + self.density(w[1])) * (w[1] - w[0]))
                    .sum()
            }
            Profile::Layered {
                top_m: bl_top,
                free_ratio,
                free_scale_height_m,
                tropopause_m,
                strat_ratio,
                strat_top_m,
            } => {
                let bl = bl_top.min(top_m);
                let ft_end = tropopause_m.min(top_m);
                let ft = if ft_end > bl_top {
                    free_ratio
                        * free_scale_height_m
                        * (1.0 - (-(ft_end - bl_top) / free_scale_height_m).exp())
                } else {
                    0.0
                };
                let st = strat_ratio * (strat_top_m.min(top_m) - tropopause_m.min(top_m)).max(0.0);
                bl + ft + st
            }
        }
    }
}

/// The resolved atmosphere (engine-ready): geometry, profiles and per-wavelength coefficients.
#[derive(Debug, Clone, PartialEq)]
pub struct Medium {
    /// Ground radius, m.
    pub bottom_radius_m: f64,
    /// Radius of the top of the atmosphere, m.
    pub top_radius_m: f64,
    /// Density profiles of Rayleigh, Mie and ozone.
    pub profiles: [Profile; CONSTITUENTS],
    /// Wavelengths, nm.
    pub wavelengths_nm: Vec<f64>,
    /// Extinction per unit relative density, m⁻¹, `[constituent][λ]`.
    pub extinction_per_m: [Vec<f64>; CONSTITUENTS],
    /// Rayleigh scattering coefficient at relative density 1, m⁻¹, per λ.
    pub rayleigh_scattering_per_m: Vec<f64>,
    /// Mie scattering coefficient at relative density 1, m⁻¹, per λ.
    pub mie_scattering_per_m: Vec<f64>,
    /// Aerosol phase function.
    pub mie_phase: Phase,
    /// Lambertian ground albedo per λ.
    pub ground_albedo: Vec<f64>,
    /// Extraterrestrial solar spectral irradiance at the planet, W m⁻² nm⁻¹, per λ.
    pub solar_irradiance: Vec<f64>,
    /// Angular radius of the sun, radians.
    pub sun_angular_radius_rad: f64,
}

/// Rayleigh scattering cross-section of dry air with 360 ppm CO₂, m² per molecule
/// (Bodhaine et al. 1999, eqs. 4, 5, 18–23: Peck & Reeder refractive index, Bates King factors).
pub fn bodhaine_cross_section_m2(lambda_nm: f64) -> f64 {
    let l_um = lambda_nm * 1e-3;
    let inv2 = 1.0 / (l_um * l_um);
    // Peck & Reeder 1972 for 300 ppm CO₂, scaled to 360 ppm (Bodhaine eq. 17–18).
    let n300_minus_1 =
        (8060.51 + 2_480_990.0 / (132.274 - inv2) + 17_455.7 / (39.329_57 - inv2)) * 1e-8;
    let co2 = 0.000_36;
    let n = 1.0 + n300_minus_1 * (1.0 + 0.54 * (co2 - 0.0003));
    // King factors (Bates 1984) for N₂, O₂, Ar, CO₂, weighted by volume (Bodhaine eq. 23).
    let f_n2 = 1.034 + 3.17e-4 * inv2;
    let f_o2 = 1.096 + 1.385e-3 * inv2 + 1.448e-4 * inv2 * inv2;
    let (c_n2, c_o2, c_ar, c_co2) = (78.084, 20.946, 0.934, co2 * 100.0);
    let f_air =
        (c_n2 * f_n2 + c_o2 * f_o2 + c_ar * 1.0 + c_co2 * 1.15) / (c_n2 + c_o2 + c_ar + c_co2);
    let ns_cm3 = 2.546_899e19; // molecules cm⁻³ at 288.15 K, 1013.25 hPa
    let l_cm = lambda_nm * 1e-7;
    let n2 = n * n;
    let sigma_cm2 = 24.0 * std::f64::consts::PI.powi(3) * (n2 - 1.0).powi(2)
        / (l_cm.powi(4) * ns_cm3 * ns_cm3 * (n2 + 2.0).powi(2))
        * f_air;
    sigma_cm2 * 1e-4
}

/// The layered aerosol profile: the backgrounds' relative densities from their optical depths at
/// 550 nm and the boundary layer's extinction there.
fn layered_profile(m: &Mie, l: &MieLayers) -> Result<Profile> {
    let beta_550 = match &m.extinction {
        MieExtinction::PowerLaw {
            reference_nm,
            value_per_m,
            angstrom_exponent,
        } => value_per_m * (550.0 / reference_nm).powf(-angstrom_exponent),
        MieExtinction::TablePerM(t) => parse_table("mie.extinction.table_per_m", t)?.eval(550.0),
        MieExtinction::OpticalDepth { .. } => 0.0,
    };
    if !(beta_550.is_finite() && beta_550 > 0.0) {
        return Err(crate::Error::invalid(
            "mie.layers",
            "needs a positive boundary-layer extinction at 550 nm",
        ));
    }
    let ft_depth = l.tropopause_m - l.boundary_layer_top_m;
    let ft_shape = l.free_troposphere_scale_height_m
        * (1.0 - (-ft_depth / l.free_troposphere_scale_height_m).exp());
    let st_depth = l.stratosphere_top_m - l.tropopause_m;
    let ratio = |tau: f64, column: f64| {
        if column > 0.0 {
            tau / (beta_550 * column)
        } else {
            0.0
        }
    };
    Ok(Profile::Layered {
        top_m: l.boundary_layer_top_m,
        free_ratio: ratio(l.free_troposphere_optical_depth_550, ft_shape),
        free_scale_height_m: l.free_troposphere_scale_height_m,
        tropopause_m: l.tropopause_m,
        strat_ratio: ratio(l.stratosphere_optical_depth_550, st_depth),
        strat_top_m: l.stratosphere_top_m,
    })
}

impl Medium {
    /// Resolves validated parameters for `wavelengths`, with an optional ground-albedo override.
    pub fn new(
        params: &AtmosphereParams,
        wavelengths: &Wavelengths,
        ground_albedo_override: Option<f64>,
    ) -> Result<Self> {
        params.validate()?;
        let nm = wavelengths.as_nm();
        let n = nm.len();
        let top_m = params.atmosphere_height_m;
        let mut profiles = [Profile::None; CONSTITUENTS];
        let mut extinction = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        let mut rayleigh_scattering = vec![0.0; n];
        let mut mie_scattering = vec![0.0; n];
        let mut mie_phase = Phase::HenyeyGreenstein { g: 0.0 };

        if let Some(r) = &params.rayleigh {
            profiles[RAYLEIGH] = Profile::Exponential {
                scale_height_m: r.scale_height_m,
            };
            rayleigh_scattering = match &r.scattering {
                RayleighScattering::Bodhaine1999 { number_density_m3 } => nm
                    .iter()
                    .map(|&l| bodhaine_cross_section_m2(l) * number_density_m3)
                    .collect(),
                RayleighScattering::PowerLaw {
                    reference_nm,
                    value_per_m,
                    exponent,
                } => nm
                    .iter()
                    .map(|&l| value_per_m * (l / reference_nm).powf(-exponent))
                    .collect(),
                RayleighScattering::TablePerM(t) => {
                    let t = parse_table("rayleigh.scattering.table_per_m", t)?;
                    nm.iter().map(|&l| t.eval(l)).collect()
                }
            };
            extinction[RAYLEIGH] = rayleigh_scattering.clone();
        }
        if let Some(m) = &params.mie {
            let mut profile = Profile::Exponential {
                scale_height_m: m.scale_height_m,
            };
            extinction[MIE] = match &m.extinction {
                MieExtinction::OpticalDepth {
                    reference_nm,
                    value,
                    angstrom_exponent,
                } => {
                    let column = profile.column_m(top_m);
                    nm.iter()
                        .map(|&l| value / column * (l / reference_nm).powf(-angstrom_exponent))
                        .collect()
                }
                MieExtinction::PowerLaw {
                    reference_nm,
                    value_per_m,
                    angstrom_exponent,
                } => nm
                    .iter()
                    .map(|&l| value_per_m * (l / reference_nm).powf(-angstrom_exponent))
                    .collect(),
                MieExtinction::TablePerM(t) => {
                    let t = parse_table("mie.extinction.table_per_m", t)?;
                    nm.iter().map(|&l| t.eval(l)).collect()
                }
            };
            if let Some(l) = &m.layers {
                profile = layered_profile(m, l)?;
            }
            profiles[MIE] = profile;
            let ssa = m.single_scattering_albedo.resolve(
                "atmosphere.mie.single_scattering_albedo",
                nm,
                0.0,
                1.0,
            )?;
            mie_scattering = extinction[MIE]
                .iter()
                .zip(&ssa)
                .map(|(e, a)| e * a)
                .collect();
            mie_phase = match m.phase {
                MiePhase::CornetteShanks { g } => Phase::CornetteShanks { g },
                MiePhase::HenyeyGreenstein { g } => Phase::HenyeyGreenstein { g },
            };
        }
        if let Some(o) = &params.ozone {
            let OzoneProfile::Tent {
                peak_altitude_m,
                half_width_m,
            } = o.profile;
            let profile = Profile::Tent {
                peak_m: peak_altitude_m,
                half_width_m,
            };
            profiles[OZONE] = profile;
            let peak_density = match o.amount {
                OzoneAmount::PeakNumberDensityM3(v) => v,
                OzoneAmount::ColumnDobson(du) => {
                    let column = profile.column_m(top_m);
                    if column > 0.0 {
                        du * DOBSON_UNIT_M2 / column
                    } else {
                        0.0
                    }
                }
            };
            let sigma = data::ozone_cross_section();
            extinction[OZONE] = nm.iter().map(|&l| sigma.eval(l) * peak_density).collect();
        }
        let ground_albedo = match (ground_albedo_override, &params.ground_albedo) {
            (Some(a), _) => {
                if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
                    return Err(crate::Error::out_of_range("ground_albedo", a, "0–1"));
                }
                vec![a; n]
            }
            (None, Some(s)) => s.resolve("atmosphere.ground_albedo", nm, 0.0, 1.0)?,
            (None, None) => vec![0.0; n],
        };
        let scale = 1.0 / (params.sun_distance_au * params.sun_distance_au);
        let solar_irradiance = nm
            .iter()
            .map(|&l| data::solar_irradiance_at(l) * scale)
            .collect();
        Ok(Self {
            bottom_radius_m: params.planet_radius_m,
            top_radius_m: params.planet_radius_m + top_m,
            profiles,
            wavelengths_nm: nm.to_vec(),
            extinction_per_m: extinction,
            rayleigh_scattering_per_m: rayleigh_scattering,
            mie_scattering_per_m: mie_scattering,
            mie_phase,
            ground_albedo,
            solar_irradiance,
            sun_angular_radius_rad: params.sun_angular_radius_deg.to_radians(),
        })
    }

    /// Number of wavelengths.
    #[inline]
    pub fn len(&self) -> usize {
        self.wavelengths_nm.len()
    }

    /// Never empty.
    pub fn is_empty(&self) -> bool {
        self.wavelengths_nm.is_empty()
    }

    /// Relative densities of the three constituents at radius `r_m`.
    #[inline]
    pub fn densities(&self, r_m: f64) -> [f64; CONSTITUENTS] {
        let h = r_m - self.bottom_radius_m;
        [
            self.profiles[0].density(h),
            self.profiles[1].density(h),
            self.profiles[2].density(h),
        ]
    }

    /// Optical depth at wavelength index `i` of a path with density integrals `d` (m).
    #[inline]
    pub fn optical_depth(&self, i: usize, d: &[f64; CONSTITUENTS]) -> f64 {
        self.extinction_per_m[0][i] * d[0]
            + self.extinction_per_m[1][i] * d[1]
            + self.extinction_per_m[2][i] * d[2]
    }

    /// Vertical optical depth of the whole atmosphere at wavelength index `i`, per constituent.
    pub fn vertical_optical_depth(&self, i: usize) -> [f64; CONSTITUENTS] {
        let top = self.top_radius_m - self.bottom_radius_m;
        [0, 1, 2].map(|k| self.extinction_per_m[k][i] * self.profiles[k].column_m(top))
    }

    /// Whether nothing absorbs (all scattering coefficients equal extinction).
    pub fn is_conservative(&self) -> bool {
        self.extinction_per_m[OZONE].iter().all(|&v| v == 0.0)
            && self.extinction_per_m[MIE]
                .iter()
                .zip(&self.mie_scattering_per_m)
                .all(|(e, s)| e == s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atmosphere::presets::preset;

    #[test]
    fn bodhaine_cross_section_is_close_to_published_value() {
        // Bodhaine et al. 1999, table 3 (CO₂ 360 ppm): σ(550 nm) ≈ 4.513e-27 cm² = 4.513e-31 m².
        let s = bodhaine_cross_section_m2(550.0);
        assert!((s / 4.513e-31 - 1.0).abs() < 0.01, "{s}");
    }

    #[test]
    fn presets_resolve_with_expected_optical_depths() {
        let w = Wavelengths::parse("440,550,680").unwrap();
        let earth = Medium::new(&preset("earth").unwrap(), &w, None).unwrap();
        let tau_mie_550 = earth.vertical_optical_depth(1)[MIE];
        assert!((tau_mie_550 - 0.1).abs() < 1e-9);
        let tau_o3_550 = earth.vertical_optical_depth(1)[OZONE];
        // 300 DU × 3.16e-25 m² × 2.6867e20 m⁻²/DU ≈ 0.0255.
        assert!((tau_o3_550 - 0.0255).abs() < 0.001, "{tau_o3_550}");
        let mars = Medium::new(&preset("mars").unwrap(), &w, Some(0.2)).unwrap();
        assert_eq!(mars.ground_albedo, vec![0.2; 3]);
        assert!(mars.solar_irradiance[1] < 0.45 * earth.solar_irradiance[1]);
    }
}
