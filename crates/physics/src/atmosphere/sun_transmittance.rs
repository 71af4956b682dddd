//! Direct sunlight at the observer: the visible fraction of the sun's disk above the observer's
//! geometric horizon, and the spectral transmittance from the top of the atmosphere along the sun
//! direction (exact integration in f64, not the table; valid from the ground to space).
//!
//! The planner ([`skybake_engine::plan`]) uses [`sun_disk_visible_fraction`] to decide whether the direct-sun
//! stage runs at all, so the plan and the numbers use one geometric test.

use super::geometry;
use super::transmittance::density_integrals;
use super::Medium;

/// Fraction (0…1) of the sun's disk above the geometric horizon of an observer at `altitude_m`,
/// for a sun centre at `sun_elevation_rad` above the observer's horizontal plane: the horizon
/// cosine μ_h = −√(1 − (R/r)²) (the horizon dips below the horizontal aloft), a smoothstep across
/// the disk's angular diameter around it.
pub fn sun_disk_visible_fraction(m: &Medium, altitude_m: f64, sun_elevation_rad: f64) -> f64 {
    let r = m.bottom_radius_m + altitude_m;
    let mu_s = sun_elevation_rad.sin();
    let mu_h = geometry::horizon_mu(r, m.bottom_radius_m);
    let width = (m.sun_angular_radius_rad * (1.0 - mu_h * mu_h).max(0.0).sqrt()).max(1e-9);
    let x = ((mu_s - mu_h) / width * 0.5 + 0.5).clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Spectral transmittance from the top of the atmosphere to an observer at `altitude_m` along
/// the sun direction (elevation `sun_elevation_rad`), times the visible fraction of the sun's
/// disk ([`sun_disk_visible_fraction`]); T = exp(−τ) with τ the optical depth of the
/// density integrals along the path (trapezoid rule, 4000 intervals per piece, f64).
pub fn sun_transmittance(m: &Medium, altitude_m: f64, sun_elevation_rad: f64) -> Vec<f64> {
    let vis = sun_disk_visible_fraction(m, altitude_m, sun_elevation_rad);
    if vis == 0.0 {
        return vec![0.0; m.len()];
    }
    let r = m.bottom_radius_m + altitude_m;
    let mu_h = geometry::horizon_mu(r, m.bottom_radius_m);
    let mu = sun_elevation_rad.sin().max(mu_h);
    let d = match geometry::atmosphere_segment(r, mu, m.bottom_radius_m, m.top_radius_m) {
        None => [0.0; 3],
        Some(seg) => {
            // Integrate from the observer outward, in two halves around the perigee when it lies
            // on the path (the inbound half mirrors the outbound one from the perigee).
            let r0 = r.max(m.bottom_radius_m);
            let perigee = -r0 * mu;
            let piece = |a: f64, b: f64| -> [f64; 3] {
                if b <= a {
                    return [0.0; 3];
                }
                let ra = geometry::radius_at(r0, mu, a);
                let mu_a = ((r0 * mu + a) / ra).clamp(-1.0, 1.0);
                density_integrals(m, ra, mu_a, b - a, 4000)
            };
            let (a, b) = (seg.t_start, seg.t_end);
            if perigee > a && perigee < b {
                let p1 = piece(perigee, b);
                let rp = geometry::radius_at(r0, mu, perigee);
                let p0 = density_integrals(m, rp, 0.0, perigee - a, 4000);
                [p0[0] + p1[0], p0[1] + p1[1], p0[2] + p1[2]]
            } else {
                piece(a, b)
            }
        }
    };
    (0..m.len())
        .map(|i| (-m.optical_depth(i, &d)).exp() * vis)
        .collect()
}

/// Air masses of the view paths [`light_spectra`] sees the lit air through: a high view, one
/// 6° above the horizon and the horizon itself (about 38 in the earth's atmosphere).
pub const VIEW_AIR_MASSES: [f64; 3] = [2.0, 10.0, 38.0];

/// Spectra of the light an atmosphere puts on a scene, known at every wavelength of `m` without
/// a table (the planner's RGB-only rule, `spectrum::subsets`): the sun above the atmosphere E₀
/// and the colour of the air it lights E₀·(β_R + β_M); at each of `altitudes_m` the sun's beam
/// E₀·T ([`sun_transmittance`]), the air it lights E₀·T·(β_R + β_M), that air seen through
/// [`VIEW_AIR_MASSES`] of the vertical optical depth τ (× e^(−τ m), the reddened and
/// ozone-coloured light of long view paths) and, when the ground reflects, the ground under that
/// beam E₀·T·a.
pub fn light_spectra(m: &Medium, altitudes_m: &[f64], sun_elevation_rad: f64) -> Vec<Vec<f64>> {
    let n = m.len();
    let times = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).collect::<Vec<_>>();
    let e0 = m.solar_irradiance.clone();
    let scattering: Vec<f64> = (0..n)
        .map(|l| m.rayleigh_scattering_per_m[l] + m.mie_scattering_per_m[l])
        .collect();
    let tau: Vec<f64> = (0..n)
        .map(|l| m.vertical_optical_depth(l).iter().sum::<f64>())
        .collect();
    let mut out = vec![e0.clone(), times(&e0, &scattering)];
    for &altitude in altitudes_m {
        let beam = times(&e0, &sun_transmittance(m, altitude, sun_elevation_rad));
        let air = times(&beam, &scattering);
        for air_mass in VIEW_AIR_MASSES {
            let seen: Vec<f64> = (0..n).map(|l| (-tau[l] * air_mass).exp()).collect();
            out.push(times(&air, &seen));
        }
        out.push(air);
        if m.ground_albedo.iter().any(|&a| a > 0.0) {
            out.push(times(&beam, &m.ground_albedo));
        }
        out.push(beam);
    }
    out
}
