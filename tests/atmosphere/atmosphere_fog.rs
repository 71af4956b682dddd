//! Fog-like haze against DISORT: the layered haze `visibility_km` gives (1–2 km, boundary layer
//! 1.5 km, optical depth 2.9–5.85 at 550 nm; continental and maritime 6S types; ground albedo
//! 0.1–0.5; sun zenith 0, 40 and 75°; 440/550/680 nm), requested as a user would (`visibility_km`,
//! `boundary_layer_top_m`, `aerosol_type` over an inline Rayleigh atmosphere) and read back from the
//! `sky` and `sun` JSON bodies. Reference: tests/data/disort_fog.json (tools/disort_fog.py:
//! pydisort 1.8.13, 32 streams with delta-M and the Nakajima-Tanaka intensity correction; 48
//! streams and halved layers change it by < 6e-7 and < 3e-6 relative).

use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_product::params::RequestParams;
use skybake_product::{render, Format, ProductKind, ProductRequest};

/// DISORT is plane-parallel; on a planet ten times Earth's radius the geometry matches it at view
/// zenith ≤ 75° (as in atmosphere_aerosol.rs).
const PLANE_PARALLEL_RADIUS_M: f64 = 63_600_000.0;

pub(crate) fn load() -> Value {
    let path = format!("{}/tests/data/disort_fog.json", env!("CARGO_MANIFEST_DIR"));
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// The reference's Rayleigh air, without aerosol (the haze parameters add it).
fn rayleigh_air(albedo: f64) -> String {
    json!({
        "planet_radius_m": PLANE_PARALLEL_RADIUS_M,
        "atmosphere_height_m": 100000.0,
        "rayleigh": {"scale_height_m": 8000.0,
                     "scattering": {"table_per_m": {"440": 3.31e-5, "550": 1.3558e-5, "680": 5.802e-6}}},
        "mie": null,
        "ozone": null,
        "ground_albedo": albedo,
    })
    .to_string()
}

/// The request parameters of fog atmosphere `a` (an entry of the data's `atmospheres`), as a
/// user sends them, without the sun and the quality.
fn haze_pairs(a: &Value) -> Vec<(&'static str, String)> {
    vec![
        ("atmosphere", rayleigh_air(f(&a["albedo"]))),
        ("visibility_km", a["visibility_km"].to_string()),
        ("boundary_layer_top_m", a["top_m"].to_string()),
        ("aerosol_type", a["type"].as_str().unwrap().to_string()),
    ]
}

/// Vertical aerosol optical depth at 550 nm of fog atmosphere `a`, as the engine resolves it.
pub(crate) fn optical_depth_550(a: &Value) -> f64 {
    let p = RequestParams::from_pairs(haze_pairs(a)).unwrap();
    let spec = skybake_product::params::common_spec(&p, -90.0).unwrap();
    skybake_engine::accuracy::aerosol_optical_depth_550(&spec.atmosphere).unwrap()
}

fn body(engine: &Engine, kind: ProductKind, pairs: Vec<(&str, String)>) -> Value {
    let p = RequestParams::from_pairs(pairs).unwrap();
    let req = ProductRequest::from_params(kind, &p).unwrap();
    let image = req.compute(engine).unwrap();
    serde_json::from_slice(&render(req.kind(), Format::Json, &image).unwrap()).unwrap()
}

/// One compared value.
pub(crate) struct Point {
    pub(crate) atmosphere: String,
    pub(crate) sun_zenith_deg: f64,
    /// Angle from the sun (degrees) for a radiance, `None` for an irradiance.
    pub(crate) from_sun_deg: Option<f64>,
    pub(crate) what: String,
    pub(crate) deviation: f64,
}

/// Relative deviations from DISORT of sky radiance (view zenith ≤ 75°, scattering angle ≥ 2°) and
/// of diffuse and global horizontal irradiance, for the atmospheres named, with the precise method
/// at `quality`; prints each product's convergence.
pub(crate) fn deviations(
    engine: &Engine,
    quality: &str,
    names: &[&str],
    suns: &[f64],
) -> Vec<Point> {
    let data = load();
    let mut out = Vec::new();
    for a in data["header"]["inputs"]["atmospheres"].as_array().unwrap() {
        let name = a["name"].as_str().unwrap();
        if !names.contains(&name) {
            continue;
        }
        for &sza in suns {
            let cases: Vec<&Value> = data["cases"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|c| c["atmosphere"] == name && f(&c["sun_zenith_deg"]) == sza)
                .collect();
            let keep = |p: &Value| -> Option<Vec<f64>> {
                let p: Vec<f64> = p.as_array().unwrap().iter().map(f).collect();
                (p[0] <= 75.0 && p[2] >= 2.0).then_some(p)
            };
            let points: Vec<Vec<f64>> = cases[0]["points"]
                .as_array()
                .unwrap()
                .iter()
                .filter_map(keep)
                .collect();
            let probes: Vec<String> = points
                .iter()
                .map(|p| format!("{}:{}", p[0], p[1]))
                .collect();
            let mut common = haze_pairs(a);
            common.extend([
                ("wavelengths", "440,550,680".to_string()),
                ("sun_elevation_deg", (90.0 - sza).to_string()),
                ("method", "precise".to_string()),
                ("quality", quality.to_string()),
            ]);
            let mut sky_pairs = common.clone();
            sky_pairs.extend([
                ("probe", probes.join(",")),
                ("elevation_count", "2".to_string()),
                ("azimuth_count", "1".to_string()),
            ]);
            let sky = body(engine, ProductKind::Sky, sky_pairs);
            let sun = body(engine, ProductKind::Sun, common);
            let e = &sky["error_estimate"];
            eprintln!(
                "{name} sza {sza}: {} orders, last order {:.2e}",
                e["scattering_orders"],
                e["last_order_fraction"].as_f64().unwrap_or(f64::NAN)
            );
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
                    .filter_map(keep)
                    .collect();
                for (k, p) in all.iter().enumerate() {
                    let ours = f(&sky["probes"][k]["radiance_w_m2_sr_nm"][li]) / e0[li];
                    assert!(ours.is_finite() && ours >= 0.0, "{name} {nm} {p:?}: {ours}");
                    out.push(Point {
                        atmosphere: name.to_string(),
                        sun_zenith_deg: sza,
                        from_sun_deg: Some(p[2]),
                        what: format!(
                            "{name} {nm} nm sza {sza} vz {} az {} (scattering {:.1}°)",
                            p[0], p[1], p[2]
                        ),
                        deviation: ours / p[3] - 1.0,
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
                    assert!(ours.is_finite() && ours >= 0.0, "{name} {nm} {key}: {ours}");
                    out.push(Point {
                        atmosphere: name.to_string(),
                        sun_zenith_deg: sza,
                        from_sun_deg: None,
                        what: format!("{name} {nm} nm sza {sza} {key}"),
                        deviation: ours / f(&case[key]) - 1.0,
                    });
                }
            }
        }
    }
    out
}

/// Prints one line per atmosphere (sky radiance max and mean deviation, irradiance max, signed
/// %) and returns the largest |deviation|.
fn summarise(points: &[Point], label: &str) -> f64 {
    let mut names: Vec<&str> = Vec::new();
    for p in points {
        if !names.contains(&p.atmosphere.as_str()) {
            names.push(&p.atmosphere);
        }
    }
    let worst = |sel: &dyn Fn(&&Point) -> bool| {
        points
            .iter()
            .filter(sel)
            .max_by(|a, b| a.deviation.abs().total_cmp(&b.deviation.abs()))
    };
    for name in names {
        let sky = worst(&|p| p.atmosphere == name && p.from_sun_deg.is_some());
        let flux = worst(&|p| p.atmosphere == name && p.from_sun_deg.is_none());
        let radiances: Vec<f64> = points
            .iter()
            .filter(|p| p.atmosphere == name && p.from_sun_deg.is_some())
            .map(|p| p.deviation)
            .collect();
        let mean = radiances.iter().sum::<f64>() / radiances.len() as f64;
        eprintln!(
            "{label}: {name} | radiance max {:+.2} % ({}) | radiance mean {:+.2} % | irradiance max {:+.2} % ({})",
            100.0 * sky.map_or(f64::NAN, |p| p.deviation),
            sky.map_or("-", |p| p.what.as_str()),
            100.0 * mean,
            100.0 * flux.map_or(f64::NAN, |p| p.deviation),
            flux.map_or("-", |p| p.what.as_str()),
        );
    }
    points.iter().map(|p| p.deviation.abs()).fold(0.0, f64::max)
}

fn check(points: &[Point], label: &str, tolerance: f64) {
    let worst = summarise(points, label);
    eprintln!(
        "{label}: {} values, max |deviation| {:.2} %",
        points.len(),
        100.0 * worst
    );
    let failed: Vec<String> = points
        .iter()
        .filter(|p| p.deviation.abs() > tolerance)
        .map(|p| format!("{}: {:+.2} %", p.what, 100.0 * p.deviation))
        .collect();
    assert!(failed.is_empty(), "{label}: {}", failed.join("\n"));
}

/// Visibility 1 km in a 1.5 km boundary layer (optical depth 5.85 at 550 nm, 7.3 at 440 nm),
/// continental haze over a dark ground, sun at zenith 0 and 40°: measured (468 values) max
/// |deviation| 7.48 % (sky radiance at view zenith 75° away from the sun, sun at 40°, 440 nm:
/// the low sky on the far side reads low), +3.71 % at view zenith 75° towards a sun at the
/// zenith (550 nm), irradiance −3.08 % (440 nm, sun 40°), radiance mean −0.51 %; held to 8 % and
/// a mean within 1 % (not within 3 %). With the sun at zenith
/// 75° the fog's sky and irradiance read low, by up to −21 % (440 nm) and −7.8 % (550 nm) (the
/// ignored test below).
#[test]
fn precise_standard_fog_of_visibility_1_km_against_disort_by_day() {
    let points = deviations(
        &Engine::new(),
        "standard",
        &["fog1_continental"],
        &[0.0, 40.0],
    );
    let mean = points.iter().map(|p| p.deviation).sum::<f64>() / points.len() as f64;
    check(&points, "precise standard vs DISORT (fog)", 0.08);
    assert!(mean.abs() < 0.01, "mean bias {mean}");
}

/// All four fog atmospheres of tests/data/disort_fog.json at `standard`, sun zenith 0, 40 and 75°
/// (~1 min CPU). Measured (largest radiance / irradiance deviation): fog1_continental −21.5 /
/// −11.5 %, fog1_bright −19.7 / −10.2 %, fog1_maritime −7.8 / −6.9 %, haze2_continental (2 km,
/// optical depth 2.9) +2.65 / +0.89 %; each held to its figure plus a margin. With the sun at
/// zenith 75° the sky of 1 km fog is not within 3 % (docs/atmospheres.md); what a product states
/// there is at least these figures (report/external.json's fog rows). The measurement behind
/// docs/atmospheres.md's fog figures (`cargo test --release --test atmosphere atmosphere_fog --
/// --include-ignored --nocapture`).
#[test]
#[ignore = "all four fog atmospheres, ~2 min CPU"]
fn precise_standard_all_fog_atmospheres_against_disort() {
    let bounds = [
        ("fog1_continental", 0.225),
        ("fog1_bright", 0.205),
        ("fog1_maritime", 0.085),
        ("haze2_continental", 0.03),
    ];
    let names: Vec<&str> = bounds.iter().map(|(n, _)| *n).collect();
    let points = deviations(&Engine::new(), "standard", &names, &[0.0, 40.0, 75.0]);
    summarise(&points, "precise standard vs DISORT (all fog)");
    let failed: Vec<String> = points
        .iter()
        .filter(|p| {
            let bound = bounds.iter().find(|(n, _)| *n == p.atmosphere).unwrap().1;
            p.deviation.abs() > bound
        })
        .map(|p| format!("{}: {:+.2} %", p.what, 100.0 * p.deviation))
        .collect();
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}
