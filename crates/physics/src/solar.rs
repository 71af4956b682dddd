//! Sun position from place and time: parses the RFC 3339 time and calls the NREL solar position
//! algorithm ([`crate::solar_position`], agreeing with pvlib's SPA to 1e-8°).

use crate::solar_position::{solar_position, SpaInput};
use crate::{Error, Result};

/// Sun elevation (true, geometric: no refraction) and azimuth (east of north), degrees, at a
/// place and an RFC 3339 time (converted to UTC).
pub fn sun_elevation_azimuth_deg(
    latitude_deg: f64,
    longitude_deg: f64,
    time: &str,
) -> Result<(f64, f64)> {
    let t = chrono::DateTime::parse_from_rfc3339(time.trim()).map_err(|e| {
        Error::invalid(
            "time",
            format!("'{time}' is not an RFC 3339 time such as 2026-06-21T12:00:00Z ({e})"),
        )
    })?;
    let p = solar_position(&SpaInput::new(
        latitude_deg,
        longitude_deg,
        t.with_timezone(&chrono::Utc),
    ))?;
    Ok((p.elevation_deg, p.azimuth_deg))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_rfc3339_and_rejects_garbage() {
        // Reda & Andreas 2004 example place and time (their 50.11162° zenith includes refraction
        // at 820 mbar and 1830 m; here sea level, no refraction: 0.02° lower sun).
        let (el, az) =
            sun_elevation_azimuth_deg(39.742476, -105.1786, "2003-10-17T19:30:30Z").unwrap();
        assert!((el - (90.0 - 50.11162)).abs() < 0.05, "{el}");
        assert!((az - 194.34024).abs() < 0.05, "{az}");
        // The same instant written with an offset.
        let (el2, _) =
            sun_elevation_azimuth_deg(39.742476, -105.1786, "2003-10-17T12:30:30-07:00").unwrap();
        assert_eq!(el, el2);
        assert_eq!(
            sun_elevation_azimuth_deg(0.0, 0.0, "yesterday")
                .unwrap_err()
                .field(),
            "time"
        );
    }
}
