//! The real-time texture bundle (Bruneton 2017's layout) read with his functions
//! (`skybake_lut::Reader`: `GetSkyRadiance`, `GetSkyRadianceToPoint`, `GetSunAndSkyIrradiance`)
//! against skybake's own `sky`, `aerial` and `sun` products at random observers (0–100 km), view
//! directions and sun elevations (−12°…90°), on `earth` at quality `standard`, RGB form (half-float
//! scattering). One bundle per test binary (a OnceLock): its build dominates the cost.
//!
//! Each test prints its largest relative error per band and asserts the measured bound (with
//! a little margin, so a regression fails); docs/lut.md states them against the targets.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use skybake_engine::engine::Engine;
use skybake_engine::spec::{CommonSpec, DomeShape};
use skybake_lut::{Bundle, Reader, UNIT_SCALE};
use skybake_product::lut::LutRequest;
use skybake_product::params::RequestParams;
use std::sync::OnceLock;

struct Fixture {
    engine: Engine,
    request: LutRequest,
    bundle: Bundle,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let engine = Engine::new();
        let request = LutRequest::from_params(&RequestParams::default()).unwrap();
        let bundle = request.compute(&engine).unwrap();
        eprintln!(
            "lut build ms (precise table, transmittance, scattering, irradiance): {:?}",
            bundle.timing_ms
        );
        Fixture {
            engine,
            request,
            bundle,
        }
    })
}

/// The product spec at this observer and sun.
fn spec_at(f: &Fixture, altitude_m: f64, sun_deg: f64) -> CommonSpec {
    let mut s = f.request.spec.clone();
    s.observer_altitude_m = altitude_m;
    s.sun.sun_elevation_deg = sun_deg;
    s
}

/// Index of each bundle channel among the product's (ascending) wavelengths.
fn channel_index(f: &Fixture, product_nm: &[f64]) -> Vec<usize> {
    f.bundle
        .wavelengths_nm
        .iter()
        .map(|w| product_nm.iter().position(|x| x == w).unwrap())
        .collect()
}

fn rel(a: f64, b: f64) -> f64 {
    if b == 0.0 {
        if a == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    } else {
        (a - b).abs() / b.abs()
    }
}

/// Largest error per band, printed and returned.
#[derive(Default, Debug)]
struct Bands {
    names: Vec<&'static str>,
    max: Vec<f64>,
    count: Vec<usize>,
}

impl Bands {
    fn add(&mut self, band: &'static str, e: f64) {
        let i = match self.names.iter().position(|n| *n == band) {
            Some(i) => i,
            None => {
                self.names.push(band);
                self.max.push(0.0);
                self.count.push(0);
                self.names.len() - 1
            }
        };
        self.max[i] = self.max[i].max(e);
        self.count[i] += 1;
    }

    fn get(&self, band: &str) -> f64 {
        self.names
            .iter()
            .position(|n| *n == band)
            .map_or(0.0, |i| self.max[i])
    }

    fn print(&self, what: &str) {
        for ((n, m), c) in self.names.iter().zip(&self.max).zip(&self.count) {
            eprintln!(
                "{what}: {n}: max relative error {:.3} % over {c} samples",
                m * 100.0
            );
        }
    }
}

fn sun_band(sun_deg: f64) -> &'static str {
    if sun_deg >= 5.0 {
        "sun >= 5"
    } else if sun_deg >= -6.0 {
        "sun -6..5"
    } else {
        "sun -12..-6"
    }
}

fn sun_dir(sun_deg: f64) -> [f64; 3] {
    let e = sun_deg.to_radians();
    [e.cos(), 0.0, e.sin()]
}

fn view_dir(zenith_deg: f64, azimuth_deg: f64) -> [f64; 3] {
    let (t, p) = (zenith_deg.to_radians(), azimuth_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

#[test]
fn sky_radiance_matches_the_sky_product() {
    let f = fixture();
    let reader = Reader::new(&f.bundle);
    let mut rng = Pcg64::seed_from_u64(27);
    let mut bands = Bands::default();
    let bottom = f.bundle.params.bottom_radius;
    for case in 0..24 {
        let altitude = if case % 3 == 0 {
            0.0
        } else {
            rng.random_range(0.0..100_000.0f64)
        };
        let sun_deg = if case % 2 == 0 {
            rng.random_range(-12.0..5.0f64)
        } else {
            rng.random_range(5.0..90.0f64)
        };
        let spec = spec_at(f, altitude, sun_deg);
        let dip = (bottom / (bottom + altitude)).acos().to_degrees();
        // Views above the geometric horizon (the bundle leaves the ground to the client).
        let probes: Vec<(f64, f64)> = (0..12)
            .map(|k| {
                let elevation = if k < 4 {
                    -dip + rng.random_range(0.2..10.0f64)
                } else {
                    rng.random_range((-dip + 10.0)..90.0f64)
                };
                (90.0 - elevation, rng.random_range(0.0..180.0f64))
            })
            .collect();
        let product = f
            .engine
            .sky(
                &spec,
                DomeShape {
                    elevation_count: 2,
                    azimuth_count: 1,
                },
                &probes,
            )
            .unwrap();
        let idx = channel_index(f, &product.table.wavelengths_nm);
        let camera = [0.0, 0.0, bottom + altitude];
        for p in &product.probes {
            let (radiance, _) = reader.sky_radiance(
                camera,
                view_dir(p.view_zenith_deg, p.view_azimuth_deg),
                sun_dir(sun_deg),
            );
            let near_horizon = 90.0 - p.view_zenith_deg < -dip + 10.0;
            let band = match (sun_band(sun_deg), near_horizon) {
                ("sun >= 5", false) => "sun >= 5, view > 10 deg above horizon",
                ("sun >= 5", true) => "sun >= 5, view < 10 deg above horizon",
                ("sun -6..5", _) => "sun -6..5",
                _ => "sun -12..-6",
            };
            for (c, &i) in idx.iter().enumerate() {
                let want = p.radiance_w_m2_sr_nm[i];
                let got = radiance[c] / UNIT_SCALE;
                bands.add(band, rel(got, want));
            }
        }
    }
    bands.print("sky");
    assert!(
        bands.get("sun >= 5, view > 10 deg above horizon") < 0.05,
        "{bands:?}"
    );
}

#[test]
fn sun_and_sky_irradiance_match_the_sun_product() {
    let f = fixture();
    let reader = Reader::new(&f.bundle);
    let mut rng = Pcg64::seed_from_u64(2027);
    let mut direct = Bands::default();
    let mut sky = Bands::default();
    let bottom = f.bundle.params.bottom_radius;
    for case in 0..24 {
        let altitude = if case % 3 == 0 {
            0.0
        } else {
            rng.random_range(0.0..100_000.0f64)
        };
        let sun_deg = if case % 2 == 0 {
            rng.random_range(-12.0..5.0f64)
        } else {
            rng.random_range(5.0..90.0f64)
        };
        let product = f.engine.sun(&spec_at(f, altitude, sun_deg)).unwrap();
        let idx = channel_index(f, &product.wavelengths_nm);
        let point = [0.0, 0.0, bottom + altitude];
        let sun = sun_dir(sun_deg);
        // Normal towards the sun: the direct part is the direct normal irradiance.
        let (dni, _) = reader.sun_and_sky_irradiance(point, sun, sun);
        let (_, dhi) = reader.sun_and_sky_irradiance(point, [0.0, 0.0, 1.0], sun);
        for (c, &i) in idx.iter().enumerate() {
            let want = product.direct_normal_irradiance_w_m2_nm[i];
            // Where the disk is partly below the horizon both are a smoothstep of the same width.
            if want > 1e-3 * product.solar_irradiance_w_m2_nm[i] {
                direct.add(sun_band(sun_deg), rel(dni[c] / UNIT_SCALE, want));
            }
            sky.add(
                sun_band(sun_deg),
                rel(
                    dhi[c] / UNIT_SCALE,
                    product.diffuse_horizontal_irradiance_w_m2_nm[i],
                ),
            );
        }
    }
    direct.print("sun direct normal");
    sky.print("sky diffuse horizontal");
    assert!(direct.get("sun >= 5") < 0.01, "{direct:?}");
    assert!(sky.get("sun >= 5") < 0.05, "{sky:?}");
}

#[test]
fn aerial_perspective_matches_the_aerial_product() {
    let f = fixture();
    let reader = Reader::new(&f.bundle);
    let mut rng = Pcg64::seed_from_u64(72);
    let mut inscatter = Bands::default();
    let mut transmittance = Bands::default();
    let bottom = f.bundle.params.bottom_radius;
    for case in 0..8 {
        let altitude = if case % 2 == 0 {
            rng.random_range(0.0..3000.0f64)
        } else {
            rng.random_range(0.0..100_000.0f64)
        };
        let sun_deg = if case % 2 == 0 {
            rng.random_range(-12.0..5.0f64)
        } else {
            rng.random_range(5.0..90.0f64)
        };
        let product = f
            .engine
            .aerial(
                &spec_at(f, altitude, sun_deg),
                DomeShape {
                    elevation_count: 9,
                    azimuth_count: 5,
                },
                5,
                50_000.0,
            )
            .unwrap();
        let idx = channel_index(f, &product.wavelengths_nm);
        let n_l = product.wavelengths_nm.len();
        let (n_az, n_d) = (product.azimuth_deg.len(), product.distance_m.len());
        let camera = [0.0, 0.0, bottom + altitude];
        for (row, &el) in product.elevation_deg.iter().enumerate() {
            for (col, &az) in product.azimuth_deg.iter().enumerate() {
                let v = view_dir(90.0 - el, az);
                for (k, &d) in product.distance_m.iter().enumerate() {
                    if d < 1000.0 {
                        continue;
                    }
                    let point = [
                        camera[0] + v[0] * d,
                        camera[1] + v[1] * d,
                        camera[2] + v[2] * d,
                    ];
                    // Points below the ground are not points a client shades.
                    if (point[0].powi(2) + point[1].powi(2) + point[2].powi(2)).sqrt() < bottom {
                        continue;
                    }
                    let (l, t) = reader.sky_radiance_to_point(camera, point, sun_dir(sun_deg));
                    let at = ((row * n_az + col) * n_d + k) * n_l;
                    for (c, &i) in idx.iter().enumerate() {
                        let want_l = product.inscatter[at + i] as f64;
                        let want_t = product.transmittance[at + i] as f64;
                        inscatter.add(sun_band(sun_deg), rel(l[c] / UNIT_SCALE, want_l));
                        transmittance.add(sun_band(sun_deg), (t[c] - want_t).abs());
                    }
                }
            }
        }
    }
    inscatter.print("aerial in-scattered radiance");
    transmittance.print("aerial transmittance (absolute)");
    assert!(transmittance.get("sun >= 5") < 0.01, "{transmittance:?}");
    assert!(inscatter.get("sun >= 5") < 0.2, "{inscatter:?}");
}
