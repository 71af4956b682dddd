//! Hazy air against DISORT: layered Rayleigh + exponential aerosol (Henyey-Greenstein and
//! Cornette-Shanks, aerosol optical depth 0.05–2 at 550 nm, g 0.6–0.8, single-scattering albedo
//! 0.8–1, ground albedo 0–0.5, sun zenith 0–75°, 440/550/680 nm), through the product path: each
//! check builds the `sky` request with probes and the `sun` request a user would send and reads
//! the numbers back from the JSON bodies. Reference: tests/data/disort_aerosol.json
//! (tools/disort_aerosol.py: pydisort 1.8.13, 32 streams with delta-M and the Nakajima-Tanaka
//! intensity correction; 48 streams and halved layers change it by the figures in its header).

use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_product::params::RequestParams;
use skybake_product::{render, Format, ProductKind, ProductRequest};

/// DISORT is plane-parallel; on a planet ten times Earth's radius the geometry matches it to
/// < 0.1 % at view zenith ≤ 75° (as in atmosphere_validation.rs).
const PLANE_PARALLEL_RADIUS_M: f64 = 63_600_000.0;

pub(crate) fn load() -> Value {
    let path = format!(
        "{}/tests/data/disort_aerosol.json",
        env!("CARGO_MANIFEST_DIR")
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// The reference's atmosphere as an inline `atmosphere=` value.
fn atmosphere_json(a: &Value) -> String {
    json!({
        "planet_radius_m": PLANE_PARALLEL_RADIUS_M,
        "atmosphere_height_m": 100000.0,
        "rayleigh": {"scale_height_m": 8000.0,
                     "scattering": {"table_per_m": {"440": 3.31e-5, "550": 1.3558e-5, "680": 5.802e-6}}},
        "mie": {"scale_height_m": 1200.0,
                "extinction": {"optical_depth": {"reference_nm": 550.0, "value": a["aod"],
                                                 "angstrom_exponent": 1.3}},
                "single_scattering_albedo": a["ssa"],
                "phase": {a["phase"].as_str().unwrap(): {"g": a["g"]}}},
        "ozone": null,
        "ground_albedo": a["albedo"],
    })
    .to_string()
}

fn body(engine: &Engine, kind: ProductKind, pairs: Vec<(&str, String)>) -> Value {
    let p = RequestParams::from_pairs(pairs).unwrap();
    let req = ProductRequest::from_params(kind, &p).unwrap();
    let image = req.compute(engine).unwrap();
    serde_json::from_slice(&render(req.kind(), Format::Json, &image).unwrap()).unwrap()
}

/// One compared value: which, where, its relative deviation and the tolerance it must meet.
pub(crate) struct Point {
    pub(crate) atmosphere: String,
    /// Angle from the sun (degrees) for a radiance, `None` for an irradiance.
    pub(crate) from_sun_deg: Option<f64>,
    /// Sun zenith angle of the case, degrees.
    pub(crate) sun_zenith_deg: f64,
    pub(crate) what: String,
    pub(crate) deviation: f64,
    tolerance: f64,
}

/// Relative deviations of sky radiance (view zenith ≤ 75°, scattering angle ≥ 2°) and of diffuse
/// and global horizontal irradiance from DISORT, for the atmospheres named in `names`, with
/// `method` at `quality`. Tolerances: `base` everywhere, `near` within 10° of the sun and for aerosol optical
/// depth above 1.
pub(crate) fn deviations(
    method: &str,
    quality: &str,
    names: &[&str],
    base: f64,
    near: f64,
) -> Vec<Point> {
    deviations_on(&Engine::new(), method, quality, names, base, near)
}

/// [`deviations`] on `engine` (its shared tables reused).
fn deviations_on(
    engine: &Engine,
    method: &str,
    quality: &str,
    names: &[&str],
    base: f64,
    near: f64,
) -> Vec<Point> {
    let data = load();
    let mut out = Vec::new();
    for a in data["header"]["inputs"]["atmospheres"].as_array().unwrap() {
        let name = a["name"].as_str().unwrap();
        if !names.contains(&name) {
            continue;
        }
        let atmosphere = atmosphere_json(a);
        let thick = f(&a["aod"]) > 1.0;
        for sza in [0.0, 40.0, 75.0] {
            let cases: Vec<&Value> = data["cases"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|c| c["atmosphere"] == name && f(&c["sun_zenith_deg"]) == sza)
                .collect();
            let points: Vec<Vec<f64>> = cases[0]["points"]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| p.as_array().unwrap().iter().map(f).collect::<Vec<f64>>())
                .filter(|p| p[0] <= 75.0 && p[2] >= 2.0)
                .collect();
            let probes: Vec<String> = points
                .iter()
                .map(|p| format!("{}:{}", p[0], p[1]))
                .collect();
            let common = vec![
                ("atmosphere", atmosphere.clone()),
                ("wavelengths", "440,550,680".to_string()),
                ("sun_elevation_deg", (90.0 - sza).to_string()),
                ("method", method.to_string()),
                ("quality", quality.to_string()),
            ];
            let mut sky_pairs = common.clone();
            sky_pairs.extend([
                ("probe", probes.join(",")),
                ("elevation_count", "2".to_string()),
                ("azimuth_count", "1".to_string()),
            ]);
            let sky = body(engine, ProductKind::Sky, sky_pairs);
            let sun = body(engine, ProductKind::Sun, common);
            let first = out.len();
            let e0: Vec<f64> = sun["solar_irradiance_w_m2_nm"]
                .as_array()
                .unwrap()
                .iter()
                .map(f)
                .collect();
            for case in cases {
                let nm = f(&case["wavelength_nm"]);
                let li = [440.0, 550.0, 680.0].iter().position(|&l| l == nm).unwrap();
                let all: Vec<Vec<f64>> = case["points"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|p| p.as_array().unwrap().iter().map(f).collect::<Vec<f64>>())
                    .filter(|p| p[0] <= 75.0 && p[2] >= 2.0)
                    .collect();
                for (k, p) in all.iter().enumerate() {
                    let ours = f(&sky["probes"][k]["radiance_w_m2_sr_nm"][li]) / e0[li];
                    out.push(Point {
                        atmosphere: name.to_string(),
                        from_sun_deg: Some(p[2]),
                        sun_zenith_deg: sza,
                        what: format!(
                            "{name} {nm} nm sza {sza} vz {} az {} (scattering {:.1}°)",
                            p[0], p[1], p[2]
                        ),
                        deviation: ours / p[3] - 1.0,
                        tolerance: if thick || p[2] < 10.0 { near } else { base },
                    });
                }
                for (key, ours) in [
                    (
                        "diffuse_horizontal",
                        "diffuse_horizontal_irradiance_w_m2_nm",
                    ),
                    ("global_horizontal", "global_horizontal_irradiance_w_m2_nm"),
                ] {
                    let ours = f(&sun[ours][li]) / e0[li];
                    out.push(Point {
                        atmosphere: name.to_string(),
                        from_sun_deg: None,
                        sun_zenith_deg: sza,
                        what: format!("{name} {nm} nm sza {sza} {key}"),
                        deviation: ours / f(&case[key]) - 1.0,
                        tolerance: if thick { near } else { base },
                    });
                }
            }
            // No product states less than its measured distance from DISORT in its regime (not
            // while that distance is being measured again, external.rs).
            let remeasuring = std::env::var_os("SKYBAKE_WRITE_EXTERNAL").is_some();
            let worst = out[first..]
                .iter()
                .map(|p| p.deviation.abs())
                .fold(0.0, f64::max);
            for product in [&sky, &sun].into_iter().filter(|_| !remeasuring) {
                let stated = f(&product["error_estimate"]["relative_error"]);
                assert!(
                    stated >= worst,
                    "{name} sza {sza} {method} {quality}: states {stated}, measured {worst} ({})",
                    product["error_estimate"]["basis"]
                );
            }
        }
    }
    out
}

/// The value of largest magnitude among `points` (signed, in %), or `None` if there are none.
fn worst<'a>(points: impl Iterator<Item = &'a Point>) -> Option<&'a Point> {
    points.max_by(|a, b| a.deviation.abs().total_cmp(&b.deviation.abs()))
}

/// Prints one line per atmosphere: sky radiance max deviation ≥ 10° from the sun, within 2–10° of
/// the sun, the radiance mean, and the irradiances' max (all signed, %). The rows of
/// docs/validation.md's aerosol table.
fn summarise(points: &[Point], label: &str) {
    let mut names: Vec<&str> = Vec::new();
    for p in points {
        if !names.contains(&p.atmosphere.as_str()) {
            names.push(&p.atmosphere);
        }
    }
    let pct = |p: Option<&Point>| p.map_or(f64::NAN, |p| 100.0 * p.deviation);
    eprintln!("{label}: atmosphere | far (>= 10 deg) max | near (2-10 deg) max | radiance mean | irradiance max | worst far | worst near");
    for name in names {
        let of = || points.iter().filter(move |p| p.atmosphere == name);
        let far = worst(of().filter(|p| p.from_sun_deg.is_some_and(|a| a >= 10.0)));
        let near = worst(of().filter(|p| p.from_sun_deg.is_some_and(|a| a < 10.0)));
        let flux = worst(of().filter(|p| p.from_sun_deg.is_none()));
        let radiances: Vec<f64> = of()
            .filter(|p| p.from_sun_deg.is_some())
            .map(|p| p.deviation)
            .collect();
        let mean = radiances.iter().sum::<f64>() / radiances.len() as f64;
        eprintln!(
            "{label}: {name} | {:+.2} % | {:+.2} % | {:+.2} % | {:+.2} % | {} | {}",
            pct(far),
            pct(near),
            100.0 * mean,
            pct(flux),
            far.map_or("-", |p| p.what.as_str()),
            near.map_or("-", |p| p.what.as_str())
        );
    }
}

fn check(points: &[Point], label: &str) {
    summarise(points, label);
    let worst = worst(points.iter()).unwrap();
    let mean = points.iter().map(|p| p.deviation).sum::<f64>() / points.len() as f64;
    eprintln!(
        "{label}: {} values, max |deviation| {:+.2} % at {}, mean {:+.2} %",
        points.len(),
        100.0 * worst.deviation,
        worst.what,
        100.0 * mean
    );
    let failed: Vec<String> = points
        .iter()
        .filter(|p| p.deviation.abs() > p.tolerance)
        .map(|p| format!("{}: {:+.2} %", p.what, 100.0 * p.deviation))
        .collect();
    assert!(failed.is_empty(), "{label}: {}", failed.join("\n"));
}

#[test]
fn precise_standard_hazy_sky_is_within_its_measured_error_of_disort() {
    // Three atmospheres keep the test cheap (AOD 0.4 HG 0.7; AOD 0.05; AOD 0.4 HG 0.8 ssa 0.8).
    // Measured through this path (all eight: the ignored test below): base, thin and
    // absorbing_g08 within the 2 % aimed for (1.56 %, 0.71 %, 1.69 %; 2–10° from the sun 1.18 %,
    // 0.58 %, 1.33 %). absorbing_g08 read +2.42 % at view zenith 75° with the sun at 75° (680 nm)
    // and −2.52 % 2.8° from the sun on 12 azimuth nodes, before they were doubled in strongly
    // forward aerosols (`azimuth_nodes` in crates/physics/src/atmosphere/multiple_precise.rs).
    // Before the view-zenith pole and azimuth mirror-plane interpolation were fixed, the zenith
    // with the sun at 40° read +2.26 % (base) and +3.37 % (absorbing_g08), and 2.8° from the sun
    // −3.38 %.
    let points = deviations(
        "precise",
        "standard",
        &["base", "thin", "absorbing_g08"],
        0.02,
        0.03,
    );
    let mean = points.iter().map(|p| p.deviation).sum::<f64>() / points.len() as f64;
    check(&points, "precise standard vs DISORT (aerosol)");
    assert!(mean.abs() < 0.003, "mean bias {mean}");
}

/// Thick haze (AOD 2 at 550 nm, 2.7 at 440 nm): within the 3 % aimed for above optical depth 1
/// (measured +2.37 % ≥ 10° from the sun, +2.72 % within 2–10°, irradiance +0.79 %, all at sun
/// zenith 75°, 440 nm). On the uniform radius grid of `standard` the low sky round a low sun read
/// +16.35 % / +17.43 % and the irradiance +3.53 %: the grid's lowest intervals held 0.56–1.09
/// optical depths (see `radius_nodes` in crates/physics/src/atmosphere/multiple_precise.rs).
#[test]
fn precise_standard_thick_haze_is_within_3_percent_of_disort() {
    let points = deviations("precise", "standard", &["thick"], 0.03, 0.03);
    check(&points, "precise standard vs DISORT (thick haze)");
}

/// Measured bounds per atmosphere at `standard` (%, magnitudes, the figures of docs/validation.md
/// rounded up by 0.2–0.3, or the 2 % aimed for where that holds): sky radiance ≥ 10° from the
/// sun, within 2–10° of the sun, the radiance mean, and diffuse/global irradiance. cs_g08_bright
/// (AOD 1, Cornette-Shanks g 0.8) reads +1.95 % ≥ 10° from the sun (440 nm; sun and view zenith
/// 75°, 19° from the sun) and −1.78 % within 2–10°, on the grid of a dense strongly forward aerosol (`dense_forward_settings` in
/// crates/physics/src/atmosphere/multiple_precise.rs); on the preset's grid −2.86 % / −3.17 % (sun
/// zenith 75°, view zenith 73°, 680 nm), on 12 azimuth nodes, before they were doubled in strongly
/// forward aerosols, −5.02 % / −5.23 % (absorbing_g08 +2.42 % / −2.52 %). thick (AOD 2) holds 3 %
/// on the radius grid divided where the aerosol is optically thick (+16.35 % / +17.43 % /
/// irradiance +3.53 % on the uniform grid).
const MEASURED_BOUNDS: [(&str, f64, f64, f64, f64); 8] = [
    ("base", 1.8, 1.4, 0.2, 0.8),
    ("thin", 0.9, 0.8, 0.2, 0.6),
    ("thick", 2.6, 3.0, 0.5, 1.0),
    ("conservative_g06", 1.6, 1.1, 0.2, 0.8),
    ("absorbing_g08", 1.9, 1.6, 0.2, 1.0),
    ("black_ground", 1.9, 1.5, 0.2, 1.0),
    ("cornette_shanks", 2.0, 1.7, 0.2, 0.9),
    ("cs_g08_bright", 2.0, 2.0, 0.4, 1.1),
];

/// All eight atmospheres with `method` at `standard`, each held to its measured `bounds` (%,
/// magnitudes: ≥ 10° from the sun, 2–10° from the sun, radiance mean, irradiance).
fn hold_all_eight(method: &str, bounds: &[(&str, f64, f64, f64, f64)]) {
    let names: Vec<&str> = bounds.iter().map(|b| b.0).collect();
    let points = deviations(method, "standard", &names, 1.0, 1.0);
    summarise(&points, &format!("{method} standard vs DISORT, all eight"));
    let mut failed = Vec::new();
    for &(name, far, near, mean, flux) in bounds {
        let of = || points.iter().filter(move |p| p.atmosphere == name);
        let max = |sel: &dyn Fn(&Point) -> bool| {
            of().filter(|p| sel(p))
                .map(|p| 100.0 * p.deviation.abs())
                .fold(0.0, f64::max)
        };
        let radiances: Vec<f64> = of()
            .filter(|p| p.from_sun_deg.is_some())
            .map(|p| 100.0 * p.deviation)
            .collect();
        assert!(!radiances.is_empty(), "{name}: no values");
        let measured = [
            (
                "far",
                max(&|p| p.from_sun_deg.is_some_and(|a| a >= 10.0)),
                far,
            ),
            (
                "near",
                max(&|p| p.from_sun_deg.is_some_and(|a| a < 10.0)),
                near,
            ),
            (
                "mean",
                (radiances.iter().sum::<f64>() / radiances.len() as f64).abs(),
                mean,
            ),
            ("irradiance", max(&|p| p.from_sun_deg.is_none()), flux),
        ];
        for (what, value, bound) in measured {
            if value > bound {
                failed.push(format!("{name} {what}: {value:.2} % > {bound} %"));
            }
        }
    }
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}

/// All eight DISORT atmospheres at `standard`: the per-atmosphere table of docs/validation.md
/// (`cargo test --release --locked --test atmosphere atmosphere_aerosol -- --include-ignored
/// --nocapture`). Ignored because it costs ~40 s CPU; each atmosphere is held to its measured
/// bounds (`MEASURED_BOUNDS`), so a regression in any of them fails it.
#[test]
#[ignore = "all eight atmospheres, ~40 s CPU: the measurement behind docs/validation.md's aerosol table"]
fn precise_standard_all_eight_hazy_atmospheres_against_disort() {
    hold_all_eight("precise", &MEASURED_BOUNDS);
}

/// A `method=fast` request in hazy air (the fast method is retired): the precise tables at the
/// coarse preset of haze (`standard`; `draft` measures 4.0 % here, up to 6.9 % at optical depth 1), the same numbers as
/// `method=precise&quality=standard`, stating at least their measured distance from DISORT
/// (report/external.json). One atmosphere keeps it cheap.
#[test]
fn a_fast_request_in_haze_is_the_precise_standard_product() {
    // One engine: the fast request reuses the precise request's tables.
    let engine = Engine::new();
    let precise = deviations_on(&engine, "precise", "standard", &["base"], 1.0, 1.0);
    let fast = deviations_on(&engine, "fast", "draft", &["base"], 1.0, 1.0);
    assert_eq!(fast.len(), precise.len());
    for (a, b) in fast.iter().zip(&precise) {
        assert_eq!(a.deviation, b.deviation, "{}", a.what);
    }
    let worst = fast.iter().map(|p| p.deviation.abs()).fold(0.0, f64::max);
    eprintln!(
        "fast (precise standard) vs DISORT, base: max |deviation| {:.2} %",
        100.0 * worst
    );
    assert!(worst < 0.05, "{worst}");
}
