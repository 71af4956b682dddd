//! Solar position by the NREL Solar Position Algorithm (SPA): Reda, I. & Andreas, A. (2004), "Solar
//! position algorithm for solar radiation applications", Solar Energy 76, 577-589 (corrigendum 2007;
//! NREL/TP-560-34302 rev. 2008). Valid for years -2000..6000 with an uncertainty of +-0.0003 deg.
//!
//! Pure computation in `f64`: latitude, longitude, a UTC instant, the observer's elevation, delta T and
//! the local pressure/temperature (for refraction) give the topocentric zenith, elevation (without and
//! with refraction) and azimuth (eastward from north). Section numbers below are the paper's §3.x.
//!
//! ```
//! use chrono::{TimeZone, Utc};
//! use skybake_physics::solar_position::{solar_position, SpaInput};
//! let time = Utc.with_ymd_and_hms(2024, 6, 21, 12, 0, 0).unwrap();
//! let sun = solar_position(&SpaInput::new(48.14, 11.58, time)).unwrap();
//! assert!(sun.elevation_deg > 60.0 && sun.elevation_deg < 70.0);
//! ```

use chrono::{DateTime, Datelike, Utc};

use crate::{Error, Result};

/// Default TT - UT1 in seconds (about its 2024-2026 value, IERS Bulletin A). Pass the value for the epoch
/// of interest when it matters: one second of delta T moves the sun by about 0.004 deg.
pub const DEFAULT_DELTA_T_S: f64 = 69.0;
/// Default surface pressure for refraction, Pa (standard atmosphere).
pub const DEFAULT_PRESSURE_PA: f64 = 101_325.0;
/// Default surface air temperature for refraction, degrees Celsius (the SPA/pvlib default).
pub const DEFAULT_TEMPERATURE_C: f64 = 12.0;
/// Default atmospheric refraction at sunrise/sunset, deg (SPA's `atmos_refract`).
pub const DEFAULT_ATMOS_REFRACT_DEG: f64 = 0.5667;
/// Angular radius of the sun used by SPA's refraction cut-off, deg (§3.14.1).
const SUN_RADIUS_DEG: f64 = 0.26667;

/// Inputs of [`solar_position`]. Build with [`SpaInput::new`] and override fields as needed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpaInput {
    /// Geodetic latitude, deg, north positive; -90..=90.
    pub latitude_deg: f64,
    /// Longitude, deg, east positive; -180..=180.
    pub longitude_deg: f64,
    /// The instant (UTC; SPA treats it as UT1, the difference is below 0.9 s).
    pub time: DateTime<Utc>,
    /// Observer elevation above the ellipsoid, m; >= -6 500 000 (SPA's limit).
    pub elevation_m: f64,
    /// Delta T = TT - UT1, s; -8000..=8000.
    pub delta_t_s: f64,
    /// Annual mean local pressure for refraction, Pa; 0 < p <= 500 000 (SPA: up to 5000 mbar).
    pub pressure_pa: f64,
    /// Annual mean local temperature for refraction, degrees Celsius; -273 < t <= 6000.
    pub temperature_c: f64,
    /// Refraction at sunrise/sunset, deg (sets the refraction cut-off); -1..=2. SPA allows +-5; the
    /// narrower range keeps the refraction formula (eq. 42) finite for every elevation it is applied to.
    pub atmos_refract_deg: f64,
}

impl SpaInput {
    /// Observer at sea level with the default delta T, pressure, temperature and refraction.
    pub fn new(latitude_deg: f64, longitude_deg: f64, time: DateTime<Utc>) -> Self {
        Self {
            latitude_deg,
            longitude_deg,
            time,
            elevation_m: 0.0,
            delta_t_s: DEFAULT_DELTA_T_S,
            pressure_pa: DEFAULT_PRESSURE_PA,
            temperature_c: DEFAULT_TEMPERATURE_C,
            atmos_refract_deg: DEFAULT_ATMOS_REFRACT_DEG,
        }
    }

    /// Checks every field against SPA's documented input ranges (spa.c `validate_inputs`).
    pub fn validate(&self) -> Result<()> {
        check_range("latitude_deg", self.latitude_deg, -90.0, 90.0, "-90..=90")?;
        check_range(
            "longitude_deg",
            self.longitude_deg,
            -180.0,
            180.0,
            "-180..=180",
        )?;
        let year = self.time.year();
        if !(-2000..=6000).contains(&year) {
            return Err(Error::out_of_range(
                "time",
                format!("year {year}"),
                "years -2000..=6000",
            ));
        }
        check_range(
            "elevation_m",
            self.elevation_m,
            -6_500_000.0,
            f64::MAX,
            ">= -6500000",
        )?;
        check_range("delta_t_s", self.delta_t_s, -8000.0, 8000.0, "-8000..=8000")?;
        check_range(
            "pressure_pa",
            self.pressure_pa,
            f64::MIN_POSITIVE,
            500_000.0,
            "0 < p <= 500000",
        )?;
        if !(self.temperature_c > -273.0 && self.temperature_c <= 6000.0) {
            return Err(Error::out_of_range(
                "temperature_c",
                self.temperature_c,
                "-273 < t <= 6000",
            ));
        }
        check_range(
            "atmos_refract_deg",
            self.atmos_refract_deg,
            -1.0,
            2.0,
            "-1..=2",
        )
    }
}

/// Topocentric sun position for one observer and instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolarPosition {
    /// Topocentric zenith angle without refraction, deg (90 - `elevation_deg`).
    pub zenith_deg: f64,
    /// Topocentric elevation angle without refraction, deg (§3.14.1, e0).
    pub elevation_deg: f64,
    /// Zenith angle including refraction, deg (§3.14.5, theta; SPA's "topocentric zenith angle").
    pub apparent_zenith_deg: f64,
    /// Elevation angle including refraction, deg (§3.14.4, e).
    pub apparent_elevation_deg: f64,
    /// Topocentric azimuth, deg eastward from north, 0..360 (§3.15.2, Phi).
    pub azimuth_deg: f64,
}

/// Computes the topocentric solar position (Reda & Andreas 2004, §3.1-3.15) after validating `input`.
pub fn solar_position(input: &SpaInput) -> Result<SolarPosition> {
    input.validate()?;
    let s = spa_terms(input);
    Ok(SolarPosition {
        zenith_deg: 90.0 - s.e0_deg,
        elevation_deg: s.e0_deg,
        apparent_zenith_deg: 90.0 - s.e_deg,
        apparent_elevation_deg: s.e_deg,
        azimuth_deg: s.azimuth_deg,
    })
}

fn check_range(field: &str, value: f64, lo: f64, hi: f64, allowed: &str) -> Result<()> {
    // NaN fails both comparisons and is rejected.
    if value >= lo && value <= hi {
        Ok(())
    } else {
        Err(Error::out_of_range(field, value, allowed))
    }
}

/// Intermediate SPA quantities, in degrees unless noted (names follow the paper's symbols). The ones
/// not needed for [`SolarPosition`] are kept to check them against the paper's worked example.
#[derive(Debug, Clone, Copy)]
#[cfg_attr(not(test), allow(dead_code))]
struct SpaTerms {
    jd: f64,
    /// Earth heliocentric longitude L, latitude B (deg) and radius vector R (AU), §3.2.
    l_deg: f64,
    b_deg: f64,
    r_au: f64,
    /// Nutation in longitude and obliquity, §3.4.
    delta_psi_deg: f64,
    delta_epsilon_deg: f64,
    /// True obliquity of the ecliptic, §3.5.
    epsilon_deg: f64,
    /// Geocentric right ascension and declination, §3.9-3.10.
    alpha_deg: f64,
    delta_deg: f64,
    /// Observer local hour angle, §3.11.
    h_deg: f64,
    /// Topocentric elevation without / with refraction, §3.14.
    e0_deg: f64,
    e_deg: f64,
    /// Topocentric azimuth eastward from north, §3.15.
    azimuth_deg: f64,
}

/// Julian day of a UTC instant (§3.1.1, via the Unix epoch JD 2440587.5; proleptic Gregorian).
fn julian_day(time: &DateTime<Utc>) -> f64 {
    let secs = time.timestamp() as f64 + f64::from(time.timestamp_subsec_nanos()) * 1e-9;
    secs / 86_400.0 + 2_440_587.5
}

/// Reduces an angle to [0, 360) deg (SPA's `limit_degrees`).
fn limit_degrees(deg: f64) -> f64 {
    let r = deg.rem_euclid(360.0);
    // rem_euclid can round up to exactly 360 for tiny negative inputs.
    if r >= 360.0 {
        0.0
    } else {
        r
    }
}

/// Sum over one periodic-term table: sum A cos(B + C jme) (§3.2.1, eq. 9).
fn periodic_sum(table: &[[f64; 3]], jme: f64) -> f64 {
    table.iter().map(|[a, b, c]| a * (b + c * jme).cos()).sum()
}

/// Combines the series L0..Ln as (sum_i Li jme^i) / 1e8, in radians (§3.2.4, eq. 11).
fn series(tables: &[&[[f64; 3]]], jme: f64) -> f64 {
    let mut power = 1.0;
    let mut total = 0.0;
    for table in tables {
        total += periodic_sum(table, jme) * power;
        power *= jme;
    }
    total / 1e8
}

/// Third-order polynomial a + b t + c t^2 + t^3 / d (the nutation arguments, §3.4.1-3.4.5).
fn cubic(a: f64, b: f64, c: f64, d: f64, t: f64) -> f64 {
    a + t * (b + t * (c + t / d))
}

/// SPA steps §3.1-3.15 for validated input.
fn spa_terms(input: &SpaInput) -> SpaTerms {
    // §3.1: Julian day, ephemeris day, centuries and millennium.
    let jd = julian_day(&input.time);
    let jde = jd + input.delta_t_s / 86_400.0;
    let jc = (jd - 2_451_545.0) / 36_525.0;
    let jce = (jde - 2_451_545.0) / 36_525.0;
    let jme = jce / 10.0;

    // §3.2: Earth heliocentric longitude, latitude and radius vector.
    let l_deg = limit_degrees(series(&[&L0, &L1, &L2, &L3, &L4, &L5], jme).to_degrees());
    let b_deg = series(&[&B0, &B1], jme).to_degrees();
    let r_au = series(&[&R0, &R1, &R2, &R3, &R4], jme);

    // §3.3: geocentric longitude and latitude.
    let theta_deg = limit_degrees(l_deg + 180.0);
    let beta_deg = -b_deg;

    // §3.4: nutation in longitude and obliquity.
    let x = [
        cubic(297.85036, 445_267.111_480, -0.001_914_2, 189_474.0, jce),
        cubic(357.52772, 35_999.050_340, -0.000_160_3, -300_000.0, jce),
        cubic(134.96298, 477_198.867_398, 0.008_697_2, 56_250.0, jce),
        cubic(93.27191, 483_202.017_538, -0.003_682_5, 327_270.0, jce),
        cubic(125.04452, -1_934.136_261, 0.002_070_8, 450_000.0, jce),
    ];
    let (mut sum_psi, mut sum_eps) = (0.0, 0.0);
    for (y, [a, b, c, d]) in NUTATION_Y.iter().zip(NUTATION_ABCD.iter()) {
        let arg = x
            .iter()
            .zip(y.iter())
            .map(|(xj, &yj)| xj * f64::from(yj))
            .sum::<f64>()
            .to_radians();
        sum_psi += (a + b * jce) * arg.sin();
        sum_eps += (c + d * jce) * arg.cos();
    }
    let delta_psi_deg = sum_psi / 36_000_000.0;
    let delta_epsilon_deg = sum_eps / 36_000_000.0;

    // §3.5: true obliquity of the ecliptic (eq. 24, U = JME / 10, arcsec).
    let u = jme / 10.0;
    const EPS0_ARCSEC: [f64; 11] = [
        84_381.448, -4_680.93, -1.55, 1_999.25, -51.38, -249.67, -39.05, 7.12, 27.87, 5.79, 2.45,
    ];
    let epsilon0_arcsec = EPS0_ARCSEC.iter().rev().fold(0.0, |acc, c| acc * u + c);
    let epsilon_deg = epsilon0_arcsec / 3600.0 + delta_epsilon_deg;

    // §3.6-3.7: aberration correction and apparent sun longitude.
    let delta_tau_deg = -20.4898 / (3600.0 * r_au);
    let lambda_deg = theta_deg + delta_psi_deg + delta_tau_deg;

    // §3.8: apparent sidereal time at Greenwich.
    let nu0_deg = limit_degrees(
        280.460_618_37
            + 360.985_647_366_29 * (jd - 2_451_545.0)
            + jc * jc * (0.000_387_933 - jc / 38_710_000.0),
    );
    let epsilon = epsilon_deg.to_radians();
    let nu_deg = nu0_deg + delta_psi_deg * epsilon.cos();

    // §3.9-3.10: geocentric sun right ascension and declination.
    let lambda = lambda_deg.to_radians();
    let beta = beta_deg.to_radians();
    let alpha_deg = limit_degrees(
        (lambda.sin() * epsilon.cos() - beta.tan() * epsilon.sin())
            .atan2(lambda.cos())
            .to_degrees(),
    );
    let delta = (beta.sin() * epsilon.cos() + beta.cos() * epsilon.sin() * lambda.sin())
        .clamp(-1.0, 1.0)
        .asin();

    // §3.11: observer local hour angle.
    let h_deg = limit_degrees(nu_deg + input.longitude_deg - alpha_deg);
    let h = h_deg.to_radians();

    // §3.12: topocentric right ascension (parallax) and declination.
    let xi = (8.794 / (3600.0 * r_au)).to_radians();
    let phi = input.latitude_deg.to_radians();
    let u_term = (0.996_647_19 * phi.tan()).atan();
    let x_term = u_term.cos() + input.elevation_m / 6_378_140.0 * phi.cos();
    let y_term = 0.996_647_19 * u_term.sin() + input.elevation_m / 6_378_140.0 * phi.sin();
    let denom = delta.cos() - x_term * xi.sin() * h.cos();
    let delta_alpha = (-x_term * xi.sin() * h.sin()).atan2(denom);
    let delta_prime = ((delta.sin() - y_term * xi.sin()) * delta_alpha.cos()).atan2(denom);

    // §3.13: topocentric local hour angle.
    let h_prime = h - delta_alpha;

    // §3.14: topocentric elevation without refraction, refraction correction (eq. 42), elevation.
    let e0_deg = (phi.sin() * delta_prime.sin() + phi.cos() * delta_prime.cos() * h_prime.cos())
        .clamp(-1.0, 1.0)
        .asin()
        .to_degrees();
    let delta_e_deg = if e0_deg >= -(SUN_RADIUS_DEG + input.atmos_refract_deg) {
        let pressure_mbar = input.pressure_pa / 100.0;
        (pressure_mbar / 1010.0) * (283.0 / (273.0 + input.temperature_c)) * 1.02
            / (60.0 * (e0_deg + 10.3 / (e0_deg + 5.11)).to_radians().tan())
    } else {
        0.0
    };
    let e_deg = e0_deg + delta_e_deg;

    // §3.15: topocentric astronomers' azimuth, then azimuth eastward from north.
    let gamma_deg = h_prime
        .sin()
        .atan2(h_prime.cos() * phi.sin() - delta_prime.tan() * phi.cos())
        .to_degrees();
    let azimuth_deg = limit_degrees(limit_degrees(gamma_deg) + 180.0);

    SpaTerms {
        jd,
        l_deg,
        b_deg,
        r_au,
        delta_psi_deg,
        delta_epsilon_deg,
        epsilon_deg,
        alpha_deg,
        delta_deg: delta.to_degrees(),
        h_deg,
        e0_deg,
        e_deg,
        azimuth_deg,
    }
}

// Periodic terms of Reda & Andreas (2004), Tables A4.2 and A4.3 (as in NREL spa.c).

/// Earth heliocentric longitude terms L0 (A, B, C), Reda & Andreas (2004) Table A4.2.
const L0: [[f64; 3]; 64] = [
    [175347046.0, 0.0, 0.0],
    [3341656.0, 4.6692568, 6283.07585],
    [34894.0, 4.6261, 12566.1517],
    [3497.0, 2.7441, 5753.3849],
    [3418.0, 2.8289, 3.5231],
    [3136.0, 3.6277, 77713.7715],
    [2676.0, 4.4181, 7860.4194],
    [2343.0, 6.1352, 3930.2097],
    [1324.0, 0.7425, 11506.7698],
    [1273.0, 2.0371, 529.691],
    [1199.0, 1.1096, 1577.3435],
    [990.0, 5.233, 5884.927],
    [902.0, 2.045, 26.298],
    [857.0, 3.508, 398.149],
    [780.0, 1.179, 5223.694],
    [753.0, 2.533, 5507.553],
    [505.0, 4.583, 18849.228],
    [492.0, 4.205, 775.523],
    [357.0, 2.92, 0.067],
    [317.0, 5.849, 11790.629],
    [284.0, 1.899, 796.298],
    [271.0, 0.315, 10977.079],
    [243.0, 0.345, 5486.778],
    [206.0, 4.806, 2544.314],
    [205.0, 1.869, 5573.143],
    [202.0, 2.458, 6069.777],
    [156.0, 0.833, 213.299],
    [132.0, 3.411, 2942.463],
    [126.0, 1.083, 20.775],
    [115.0, 0.645, 0.98],
    [103.0, 0.636, 4694.003],
    [102.0, 0.976, 15720.839],
    [102.0, 4.267, 7.114],
    [99.0, 6.21, 2146.17],
    [98.0, 0.68, 155.42],
    [86.0, 5.98, 161000.69],
    [85.0, 1.3, 6275.96],
    [85.0, 3.67, 71430.7],
    [80.0, 1.81, 17260.15],
    [79.0, 3.04, 12036.46],
    [75.0, 1.76, 5088.63],
    [74.0, 3.5, 3154.69],
    [74.0, 4.68, 801.82],
    [70.0, 0.83, 9437.76],
    [62.0, 3.98, 8827.39],
    [61.0, 1.82, 7084.9],
    [57.0, 2.78, 6286.6],
    [56.0, 4.39, 14143.5],
    [56.0, 3.47, 6279.55],
    [52.0, 0.19, 12139.55],
    [52.0, 1.33, 1748.02],
    [51.0, 0.28, 5856.48],
    [49.0, 0.49, 1194.45],
    [41.0, 5.37, 8429.24],
    [41.0, 2.4, 19651.05],
    [39.0, 6.17, 10447.39],
    [37.0, 6.04, 10213.29],
    [37.0, 2.57, 1059.38],
    [36.0, 1.71, 2352.87],
    [36.0, 1.78, 6812.77],
    [33.0, 0.59, 17789.85],
    [30.0, 0.44, 83996.85],
    [30.0, 2.74, 1349.87],
    [25.0, 3.16, 4690.48],
];

/// Earth heliocentric longitude terms L1 (A, B, C), Reda & Andreas (2004) Table A4.2.
const L1: [[f64; 3]; 34] = [
    [628331966747.0, 0.0, 0.0],
    [206059.0, 2.678235, 6283.07585],
    [4303.0, 2.6351, 12566.1517],
    [425.0, 1.59, 3.523],
    [119.0, 5.796, 26.298],
    [109.0, 2.966, 1577.344],
    [93.0, 2.59, 18849.23],
    [72.0, 1.14, 529.69],
    [68.0, 1.87, 398.15],
    [67.0, 4.41, 5507.55],
    [59.0, 2.89, 5223.69],
    [56.0, 2.17, 155.42],
    [45.0, 0.4, 796.3],
    [36.0, 0.47, 775.52],
    [29.0, 2.65, 7.11],
    [21.0, 5.34, 0.98],
    [19.0, 1.85, 5486.78],
    [19.0, 4.97, 213.3],
    [17.0, 2.99, 6275.96],
    [16.0, 0.03, 2544.31],
    [16.0, 1.43, 2146.17],
    [15.0, 1.21, 10977.08],
    [12.0, 2.83, 1748.02],
    [12.0, 3.26, 5088.63],
    [12.0, 5.27, 1194.45],
    [12.0, 2.08, 4694.0],
    [11.0, 0.77, 553.57],
    [10.0, 1.3, 6286.6],
    [10.0, 4.24, 1349.87],
    [9.0, 2.7, 242.73],
    [9.0, 5.64, 951.72],
    [8.0, 5.3, 2352.87],
    [6.0, 2.65, 9437.76],
    [6.0, 4.67, 4690.48],
];

/// Earth heliocentric longitude terms L2 (A, B, C), Reda & Andreas (2004) Table A4.2.
const L2: [[f64; 3]; 20] = [
    [52919.0, 0.0, 0.0],
    [8720.0, 1.0721, 6283.0758],
    [309.0, 0.867, 12566.152],
    [27.0, 0.05, 3.52],
    [16.0, 5.19, 26.3],
    [16.0, 3.68, 155.42],
    [10.0, 0.76, 18849.23],
    [9.0, 2.06, 77713.77],
    [7.0, 0.83, 775.52],
    [5.0, 4.66, 1577.34],
    [4.0, 1.03, 7.11],
    [4.0, 3.44, 5573.14],
    [3.0, 5.14, 796.3],
    [3.0, 6.05, 5507.55],
    [3.0, 1.19, 242.73],
    [3.0, 6.12, 529.69],
    [3.0, 0.31, 398.15],
    [3.0, 2.28, 553.57],
    [2.0, 4.38, 5223.69],
    [2.0, 3.75, 0.98],
];

/// Earth heliocentric longitude terms L3 (A, B, C), Reda & Andreas (2004) Table A4.2.
const L3: [[f64; 3]; 7] = [
    [289.0, 5.844, 6283.076],
    [35.0, 0.0, 0.0],
    [17.0, 5.49, 12566.15],
    [3.0, 5.2, 155.42],
    [1.0, 4.72, 3.52],
    [1.0, 5.3, 18849.23],
    [1.0, 5.97, 242.73],
];

/// Earth heliocentric longitude terms L4 (A, B, C), Reda & Andreas (2004) Table A4.2.
#[allow(clippy::approx_constant)] // the paper prints this phase as 3.14 / 3.142 rad, not pi
const L4: [[f64; 3]; 3] = [
    [114.0, 3.142, 0.0],
    [8.0, 4.13, 6283.08],
    [1.0, 3.84, 12566.15],
];

/// Earth heliocentric longitude terms L5 (A, B, C), Reda & Andreas (2004) Table A4.2.
#[allow(clippy::approx_constant)] // the paper prints this phase as 3.14 / 3.142 rad, not pi
const L5: [[f64; 3]; 1] = [[1.0, 3.14, 0.0]];

/// Earth heliocentric latitude terms B0 (A, B, C), Reda & Andreas (2004) Table A4.2.
const B0: [[f64; 3]; 5] = [
    [280.0, 3.199, 84334.662],
    [102.0, 5.422, 5507.553],
    [80.0, 3.88, 5223.69],
    [44.0, 3.7, 2352.87],
    [32.0, 4.0, 1577.34],
];

/// Earth heliocentric latitude terms B1 (A, B, C), Reda & Andreas (2004) Table A4.2.
const B1: [[f64; 3]; 2] = [[9.0, 3.9, 5507.55], [6.0, 1.73, 5223.69]];

/// Earth radius vector terms R0 (A, B, C), Reda & Andreas (2004) Table A4.2.
const R0: [[f64; 3]; 40] = [
    [100013989.0, 0.0, 0.0],
    [1670700.0, 3.0984635, 6283.07585],
    [13956.0, 3.05525, 12566.1517],
    [3084.0, 5.1985, 77713.7715],
    [1628.0, 1.1739, 5753.3849],
    [1576.0, 2.8469, 7860.4194],
    [925.0, 5.453, 11506.77],
    [542.0, 4.564, 3930.21],
    [472.0, 3.661, 5884.927],
    [346.0, 0.964, 5507.553],
    [329.0, 5.9, 5223.694],
    [307.0, 0.299, 5573.143],
    [243.0, 4.273, 11790.629],
    [212.0, 5.847, 1577.344],
    [186.0, 5.022, 10977.079],
    [175.0, 3.012, 18849.228],
    [110.0, 5.055, 5486.778],
    [98.0, 0.89, 6069.78],
    [86.0, 5.69, 15720.84],
    [86.0, 1.27, 161000.69],
    [65.0, 0.27, 17260.15],
    [63.0, 0.92, 529.69],
    [57.0, 2.01, 83996.85],
    [56.0, 5.24, 71430.7],
    [49.0, 3.25, 2544.31],
    [47.0, 2.58, 775.52],
    [45.0, 5.54, 9437.76],
    [43.0, 6.01, 6275.96],
    [39.0, 5.36, 4694.0],
    [38.0, 2.39, 8827.39],
    [37.0, 0.83, 19651.05],
    [37.0, 4.9, 12139.55],
    [36.0, 1.67, 12036.46],
    [35.0, 1.84, 2942.46],
    [33.0, 0.24, 7084.9],
    [32.0, 0.18, 5088.63],
    [32.0, 1.78, 398.15],
    [28.0, 1.21, 6286.6],
    [28.0, 1.9, 6279.55],
    [26.0, 4.59, 10447.39],
];

/// Earth radius vector terms R1 (A, B, C), Reda & Andreas (2004) Table A4.2.
#[allow(clippy::approx_constant)] // the paper prints this phase as 3.14 / 3.142 rad, not pi
const R1: [[f64; 3]; 10] = [
    [103019.0, 1.10749, 6283.07585],
    [1721.0, 1.0644, 12566.1517],
    [702.0, 3.142, 0.0],
    [32.0, 1.02, 18849.23],
    [31.0, 2.84, 5507.55],
    [25.0, 1.32, 5223.69],
    [18.0, 1.42, 1577.34],
    [10.0, 5.91, 10977.08],
    [9.0, 1.42, 6275.96],
    [9.0, 0.27, 5486.78],
];

/// Earth radius vector terms R2 (A, B, C), Reda & Andreas (2004) Table A4.2.
#[allow(clippy::approx_constant)] // the paper prints this phase as 3.14 / 3.142 rad, not pi
const R2: [[f64; 3]; 6] = [
    [4359.0, 5.7846, 6283.0758],
    [124.0, 5.579, 12566.152],
    [12.0, 3.14, 0.0],
    [9.0, 3.63, 77713.77],
    [6.0, 1.87, 5573.14],
    [3.0, 5.47, 18849.23],
];

/// Earth radius vector terms R3 (A, B, C), Reda & Andreas (2004) Table A4.2.
const R3: [[f64; 3]; 2] = [[145.0, 4.273, 6283.076], [7.0, 3.92, 12566.15]];

/// Earth radius vector terms R4 (A, B, C), Reda & Andreas (2004) Table A4.2.
const R4: [[f64; 3]; 1] = [[4.0, 2.56, 6283.08]];

/// Nutation argument multipliers Y0..Y4 of X0..X4, Reda & Andreas (2004) Table A4.3.
const NUTATION_Y: [[i8; 5]; 63] = [
    [0, 0, 0, 0, 1],
    [-2, 0, 0, 2, 2],
    [0, 0, 0, 2, 2],
    [0, 0, 0, 0, 2],
    [0, 1, 0, 0, 0],
    [0, 0, 1, 0, 0],
    [-2, 1, 0, 2, 2],
    [0, 0, 0, 2, 1],
    [0, 0, 1, 2, 2],
    [-2, -1, 0, 2, 2],
    [-2, 0, 1, 0, 0],
    [-2, 0, 0, 2, 1],
    [0, 0, -1, 2, 2],
    [2, 0, 0, 0, 0],
    [0, 0, 1, 0, 1],
    [2, 0, -1, 2, 2],
    [0, 0, -1, 0, 1],
    [0, 0, 1, 2, 1],
    [-2, 0, 2, 0, 0],
    [0, 0, -2, 2, 1],
    [2, 0, 0, 2, 2],
    [0, 0, 2, 2, 2],
    [0, 0, 2, 0, 0],
    [-2, 0, 1, 2, 2],
    [0, 0, 0, 2, 0],
    [-2, 0, 0, 2, 0],
    [0, 0, -1, 2, 1],
    [0, 2, 0, 0, 0],
    [2, 0, -1, 0, 1],
    [-2, 2, 0, 2, 2],
    [0, 1, 0, 0, 1],
    [-2, 0, 1, 0, 1],
    [0, -1, 0, 0, 1],
    [0, 0, 2, -2, 0],
    [2, 0, -1, 2, 1],
    [2, 0, 1, 2, 2],
    [0, 1, 0, 2, 2],
    [-2, 1, 1, 0, 0],
    [0, -1, 0, 2, 2],
    [2, 0, 0, 2, 1],
    [2, 0, 1, 0, 0],
    [-2, 0, 2, 2, 2],
    [-2, 0, 1, 2, 1],
    [2, 0, -2, 0, 1],
    [2, 0, 0, 0, 1],
    [0, -1, 1, 0, 0],
    [-2, -1, 0, 2, 1],
    [-2, 0, 0, 0, 1],
    [0, 0, 2, 2, 1],
    [-2, 0, 2, 0, 1],
    [-2, 1, 0, 2, 1],
    [0, 0, 1, -2, 0],
    [-1, 0, 1, 0, 0],
    [-2, 1, 0, 0, 0],
    [1, 0, 0, 0, 0],
    [0, 0, 1, 2, 0],
    [0, 0, -2, 2, 2],
    [-1, -1, 1, 0, 0],
    [0, 1, 1, 0, 0],
    [0, -1, 1, 2, 2],
    [2, -1, -1, 2, 2],
    [0, 0, 3, 2, 2],
    [2, -1, 0, 2, 2],
];

/// Nutation coefficients (a, b, c, d) in 0.0001 arcsec, Reda & Andreas (2004) Table A4.3.
const NUTATION_ABCD: [[f64; 4]; 63] = [
    [-171996.0, -174.2, 92025.0, 8.9],
    [-13187.0, -1.6, 5736.0, -3.1],
    [-2274.0, -0.2, 977.0, -0.5],
    [2062.0, 0.2, -895.0, 0.5],
    [1426.0, -3.4, 54.0, -0.1],
    [712.0, 0.1, -7.0, 0.0],
    [-517.0, 1.2, 224.0, -0.6],
    [-386.0, -0.4, 200.0, 0.0],
    [-301.0, 0.0, 129.0, -0.1],
    [217.0, -0.5, -95.0, 0.3],
    [-158.0, 0.0, 0.0, 0.0],
    [129.0, 0.1, -70.0, 0.0],
    [123.0, 0.0, -53.0, 0.0],
    [63.0, 0.0, 0.0, 0.0],
    [63.0, 0.1, -33.0, 0.0],
    [-59.0, 0.0, 26.0, 0.0],
    [-58.0, -0.1, 32.0, 0.0],
    [-51.0, 0.0, 27.0, 0.0],
    [48.0, 0.0, 0.0, 0.0],
    [46.0, 0.0, -24.0, 0.0],
    [-38.0, 0.0, 16.0, 0.0],
    [-31.0, 0.0, 13.0, 0.0],
    [29.0, 0.0, 0.0, 0.0],
    [29.0, 0.0, -12.0, 0.0],
    [26.0, 0.0, 0.0, 0.0],
    [-22.0, 0.0, 0.0, 0.0],
    [21.0, 0.0, -10.0, 0.0],
    [17.0, -0.1, 0.0, 0.0],
    [16.0, 0.0, -8.0, 0.0],
    [-16.0, 0.1, 7.0, 0.0],
    [-15.0, 0.0, 9.0, 0.0],
    [-13.0, 0.0, 7.0, 0.0],
    [-12.0, 0.0, 6.0, 0.0],
    [11.0, 0.0, 0.0, 0.0],
    [-10.0, 0.0, 5.0, 0.0],
    [-8.0, 0.0, 3.0, 0.0],
    [7.0, 0.0, -3.0, 0.0],
    [-7.0, 0.0, 0.0, 0.0],
    [-7.0, 0.0, 3.0, 0.0],
    [-7.0, 0.0, 3.0, 0.0],
    [6.0, 0.0, 0.0, 0.0],
    [6.0, 0.0, -3.0, 0.0],
    [6.0, 0.0, -3.0, 0.0],
    [-6.0, 0.0, 3.0, 0.0],
    [-6.0, 0.0, 3.0, 0.0],
    [5.0, 0.0, 0.0, 0.0],
    [-5.0, 0.0, 3.0, 0.0],
    [-5.0, 0.0, 3.0, 0.0],
    [-5.0, 0.0, 3.0, 0.0],
    [4.0, 0.0, 0.0, 0.0],
    [4.0, 0.0, 0.0, 0.0],
    [4.0, 0.0, 0.0, 0.0],
    [-4.0, 0.0, 0.0, 0.0],
    [-4.0, 0.0, 0.0, 0.0],
    [-4.0, 0.0, 0.0, 0.0],
    [3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
    [-3.0, 0.0, 0.0, 0.0],
];

#[cfg(test)]
mod tests {
    use super::*;
    use chrono::TimeZone;
    use proptest::prelude::*;

    /// Reda & Andreas (2004) worked example (Table A4.1 inputs, Table A5.1 results).
    fn paper_example() -> SpaInput {
        SpaInput {
            latitude_deg: 39.742476,
            longitude_deg: -105.1786,
            // 2003-10-17 12:30:30 local time, UTC-7.
            time: Utc.with_ymd_and_hms(2003, 10, 17, 19, 30, 30).unwrap(),
            elevation_m: 1830.14,
            delta_t_s: 67.0,
            pressure_pa: 82_000.0,
            temperature_c: 11.0,
            atmos_refract_deg: 0.5667,
        }
    }

    #[test]
    fn intermediate_values_match_reda_andreas_example() {
        let s = spa_terms(&paper_example());
        // Tolerances: half a unit in the last digit the paper prints (a little more for JD).
        assert!((s.jd - 2_452_930.312_847).abs() < 1e-6, "jd {}", s.jd);
        assert!((s.l_deg - 24.018_261_691_7).abs() < 1e-9, "L {}", s.l_deg);
        assert!((s.b_deg - -0.000_101_121_9).abs() < 1e-10, "B {}", s.b_deg);
        assert!((s.r_au - 0.996_542_297_4).abs() < 1e-10, "R {}", s.r_au);
        assert!(
            (s.delta_psi_deg - -0.003_998_40).abs() < 1e-8,
            "dpsi {}",
            s.delta_psi_deg
        );
        assert!(
            (s.delta_epsilon_deg - 0.001_666_57).abs() < 1e-8,
            "deps {}",
            s.delta_epsilon_deg
        );
        assert!(
            (s.epsilon_deg - 23.440_465).abs() < 1e-6,
            "eps {}",
            s.epsilon_deg
        );
        assert!(
            (s.alpha_deg - 202.227_41).abs() < 1e-5,
            "alpha {}",
            s.alpha_deg
        );
        assert!(
            (s.delta_deg - -9.314_34).abs() < 1e-5,
            "delta {}",
            s.delta_deg
        );
        assert!((s.h_deg - 11.105_900).abs() < 1e-5, "H {}", s.h_deg);
    }

    #[test]
    fn zenith_and_azimuth_match_reda_andreas_example() {
        let sun = solar_position(&paper_example()).unwrap();
        assert!(
            (sun.apparent_zenith_deg - 50.111_62).abs() < 1e-5,
            "{sun:?}"
        );
        assert!((sun.azimuth_deg - 194.340_24).abs() < 1e-5, "{sun:?}");
    }

    #[test]
    fn refraction_is_off_well_below_the_horizon() {
        // Local midnight in Zurich in winter: the sun is far below the horizon.
        let time = Utc.with_ymd_and_hms(2024, 12, 21, 23, 30, 0).unwrap();
        let sun = solar_position(&SpaInput::new(47.37, 8.54, time)).unwrap();
        assert!(sun.elevation_deg < -60.0);
        assert_eq!(sun.apparent_elevation_deg, sun.elevation_deg);
    }

    #[test]
    fn rejects_out_of_range_inputs_naming_the_field() {
        let ok = SpaInput::new(
            10.0,
            20.0,
            Utc.with_ymd_and_hms(2020, 1, 1, 0, 0, 0).unwrap(),
        );
        let cases: [(&str, SpaInput); 9] = [
            (
                "latitude_deg",
                SpaInput {
                    latitude_deg: 90.5,
                    ..ok
                },
            ),
            (
                "latitude_deg",
                SpaInput {
                    latitude_deg: f64::NAN,
                    ..ok
                },
            ),
            (
                "longitude_deg",
                SpaInput {
                    longitude_deg: -180.01,
                    ..ok
                },
            ),
            (
                "time",
                SpaInput {
                    time: Utc.with_ymd_and_hms(6001, 1, 1, 0, 0, 0).unwrap(),
                    ..ok
                },
            ),
            (
                "elevation_m",
                SpaInput {
                    elevation_m: -7.0e6,
                    ..ok
                },
            ),
            (
                "delta_t_s",
                SpaInput {
                    delta_t_s: 9000.0,
                    ..ok
                },
            ),
            (
                "pressure_pa",
                SpaInput {
                    pressure_pa: 0.0,
                    ..ok
                },
            ),
            (
                "temperature_c",
                SpaInput {
                    temperature_c: -300.0,
                    ..ok
                },
            ),
            (
                "atmos_refract_deg",
                SpaInput {
                    atmos_refract_deg: 5.0,
                    ..ok
                },
            ),
        ];
        for (field, input) in cases {
            let err = solar_position(&input).unwrap_err();
            assert_eq!(err.field(), field, "{err}");
        }
        assert!(solar_position(&ok).is_ok());
    }

    #[test]
    fn accepts_the_ends_of_the_year_range() {
        for year in [-2000, 6000] {
            let time = Utc.with_ymd_and_hms(year, 6, 1, 12, 0, 0).unwrap();
            let sun = solar_position(&SpaInput::new(0.0, 0.0, time)).unwrap();
            assert!(sun.zenith_deg.is_finite() && sun.azimuth_deg.is_finite());
        }
    }

    proptest! {
        #[test]
        fn outputs_are_finite_and_in_range(
            lat in -90.0f64..=90.0,
            lon in -180.0f64..=180.0,
            secs in -125_000_000_000i64..127_000_000_000i64, // years -1991..6000
            elevation_m in -500.0f64..9000.0,
            refract in -1.0f64..=2.0,
        ) {
            let time = DateTime::<Utc>::from_timestamp(secs, 0).unwrap();
            let input = SpaInput { elevation_m, atmos_refract_deg: refract, ..SpaInput::new(lat, lon, time) };
            let sun = solar_position(&input).unwrap();
            prop_assert!(sun.zenith_deg.is_finite() && (0.0..=180.0).contains(&sun.zenith_deg));
            prop_assert!(sun.apparent_zenith_deg.is_finite());
            prop_assert!((0.0..360.0).contains(&sun.azimuth_deg));
            prop_assert!((sun.zenith_deg + sun.elevation_deg - 90.0).abs() < 1e-9);
            // Refraction lifts the sun by less than a degree (and near the zenith may be a hair negative).
            let lift = sun.apparent_elevation_deg - sun.elevation_deg;
            prop_assert!((-1e-3..1.0).contains(&lift), "lift {}", lift);
        }
    }
}
