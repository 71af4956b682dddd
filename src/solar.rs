//! Sun position from place and time (wraps the solar position algorithm).

use crate::{Error, Result};

/// Sun elevation (true, no refraction) and azimuth (east of north), degrees, at a place and an
/// RFC 3339 UTC time.
pub fn sun_elevation_azimuth_deg(
    _latitude_deg: f64,
    _longitude_deg: f64,
    time: &str,
) -> Result<(f64, f64)> {
    Err(Error::invalid(
        "time",
        format!("'{time}': solar position not wired yet"),
    ))
}
