//! The multiple-scattering part of the irradiance quadrature's directions from the directions
//! around them.
//!
//! The `skyview` irradiance table integrates the sky radiance over the hemisphere with the
//! `sun` product's quadrature: Gauss–Legendre nodes in cos θ (Abramowitz & Stegun 1964, eq.
//! 25.4.29) × midpoints in azimuth, one ray per (altitude, cos θ node) for all its suns and
//! azimuths. The multiple scattering along those rays, per metre of ray, varies smoothly with
//! the direction's elevation (its source, the precise table's J, is smooth in the view
//! direction: Bruneton & Neyret 2008, §4). So at each altitude it is computed on every other
//! cos θ node and the last ([`crate::ms_columns::computed`]) and, on the others, taken as the Lagrange cubic in ln
//! over the elevation through the 4 nearest computed directions where the roughness test of
//! [`crate::ms_columns`] allows ([`crate::ms_rows::TOLERANCE`]), as [`crate::ms_rows`] does
//! over the sky view's rows; computed where it does not.

use crate::ms_columns::{self, Stencil};

/// The stencils of the directions of elevations `elevations` (increasing, radians) over the
/// elevation, `None` where computed (every other direction and the last).
pub fn stencils(elevations: &[f64]) -> Vec<Option<Stencil>> {
    ms_columns::stencils(elevations)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_between_are_interpolated_from_the_computed_ones() {
        // The 16 Gauss–Legendre directions of the irradiance quadrature: 9 computed.
        let (x, _) = skybake_physics::atmosphere::quadrature::gauss_legendre(16);
        let elev: Vec<f64> = x.iter().map(|&x| (0.5 * (x + 1.0)).asin()).collect();
        let st = stencils(&elev);
        assert_eq!(st.iter().filter(|s| s.is_none()).count(), 9);
        assert!(st[15].is_none() && st[0].is_none() && st[1].is_some());
        // The exponential of a cubic in the elevation: exact.
        let f = |e: f64| (-1.0 + 0.8 * e - 0.6 * e * e + 0.2 * e * e * e).exp();
        for (a, s) in st.iter().enumerate() {
            let Some(s) = s else { continue };
            let (y, rough) = crate::ms_rows::guess(s, |c| f(elev[c])).expect("positive");
            assert!((y / f(elev[a]) - 1.0).abs() < 1e-12, "direction {a}");
            assert!(rough < 0.2, "{rough}");
        }
    }
}
