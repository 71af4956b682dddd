//! Spectral data compiled into the binary, with their sources (see `data/*.csv` headers).
//!
//! - Solar spectral irradiance at the top of the atmosphere: ASTM G173-03 extraterrestrial
//!   spectrum (Gueymard SMARTS2), W m⁻² nm⁻¹ at 1 AU.
//! - Ozone absorption: SPECTRL2 (Bird & Riordan 1986) cross-sections, m² per molecule.
//! - CIE 1931 2° colour-matching functions, 1 nm, 360–830 nm (CIE 018:2019).

use super::Tabulated;
use std::sync::OnceLock;

const SOLAR_CSV: &str = include_str!("../../../../data/astm_g173_extraterrestrial.csv");
const OZONE_CSV: &str = include_str!("../../../../data/ozone_absorption_spectrl2.csv");
const CMF_CSV: &str = include_str!("../../../../data/cie1931_2deg_cmf_1nm.csv");

fn embedded(
    cell: &'static OnceLock<Tabulated>,
    name: &str,
    csv: &str,
    col: usize,
) -> &'static Tabulated {
    cell.get_or_init(|| {
        Tabulated::from_csv(name, csv, col)
            .unwrap_or_else(|e| panic!("embedded table {name} is malformed: {e}"))
    })
}

/// Extraterrestrial solar spectral irradiance at 1 AU, W m⁻² nm⁻¹ (ASTM G173-03).
pub fn solar_irradiance() -> &'static Tabulated {
    static T: OnceLock<Tabulated> = OnceLock::new();
    embedded(&T, "solar_irradiance", SOLAR_CSV, 1)
}

/// Solar spectral irradiance at 1 AU averaged over a 1 nm band centred on `nm`, W m⁻² nm⁻¹.
/// (The table resolves Fraunhofer lines at 0.5 nm; a 1 nm mean is what a sampled spectrum means.)
pub fn solar_irradiance_at(nm: f64) -> f64 {
    solar_irradiance().mean_over(nm - 0.5, nm + 0.5)
}

/// Ozone absorption cross-section, m² per molecule (SPECTRL2, zero where the table is zero).
pub fn ozone_cross_section() -> &'static Tabulated {
    static T: OnceLock<Tabulated> = OnceLock::new();
    embedded(&T, "ozone_cross_section", OZONE_CSV, 2)
}

/// CIE 1931 2° colour-matching functions x̄, ȳ, z̄ at 1 nm from 360 to 830 nm.
pub fn cie1931_cmfs() -> &'static [Tabulated; 3] {
    static T: OnceLock<[Tabulated; 3]> = OnceLock::new();
    T.get_or_init(|| {
        [1, 2, 3].map(|c| {
            Tabulated::from_csv("cie1931", CMF_CSV, c)
                .unwrap_or_else(|e| panic!("embedded CIE table is malformed: {e}"))
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_tables_parse_with_plausible_values() {
        // ASTM G173 ETR: 1348 W/m² over 280–4000 nm (the solar constant 1366 W/m² includes the far tails).
        let s = solar_irradiance();
        let total: f64 = s
            .xs()
            .windows(2)
            .zip(s.ys().windows(2))
            .map(|(x, y)| 0.5 * (y[0] + y[1]) * (x[1] - x[0]))
            .sum();
        assert!((total - 1348.0).abs() < 3.0, "total {total}");
        assert!((solar_irradiance_at(550.0) - 1.86).abs() < 0.1);
        assert!(ozone_cross_section().eval(600.0) > 4e-25);
        assert_eq!(ozone_cross_section().eval(400.0), 0.0);
        let [_, y, _] = cie1931_cmfs();
        assert!((y.eval(555.0) - 1.0).abs() < 1e-3);
        assert_eq!(y.xs().len(), 471);
    }
}
