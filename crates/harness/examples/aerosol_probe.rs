//! Measures the precise method's sky radiance against the aerosol DISORT references
//! (`tests/data/disort_aerosol.json`) at table resolutions the quality presets do not offer, to
//! locate the source of a deviation (angular resolution of the tables, radius and step counts,
//! product steps, planet radius). Prints, per atmosphere and wavelength, the largest and the mean
//! relative deviation of the diffuse sky radiance at scattering angles ≥ 10° and 2–10°.
//!
//! `cargo run --release -p skybake-harness --features probes --example aerosol_probe -- \
//!    [n_r n_mu_s n_mu n_phi steps product_steps radius_m tolerance extrapolate(0|1) [atmospheres…]]`
//! (defaults: the `standard` preset, 32 product steps, ten times Earth's radius).

use serde_json::{json, Value};
use skybake_physics::atmosphere::integrate::Scratch;
use skybake_physics::atmosphere::multiple_precise::PreciseSettings;
use skybake_physics::atmosphere::params::AtmosphereParams;
use skybake_physics::atmosphere::quality::{settings_for, Quality};
use skybake_physics::atmosphere::shared::SharedTables;
use skybake_physics::atmosphere::sky::{MsMethod, Observer, RadianceEvaluator};
use skybake_physics::atmosphere::Medium;
use skybake_physics::spectrum::Wavelengths;

fn atmosphere(a: &Value, radius_m: f64) -> AtmosphereParams {
    let phase = a["phase"].as_str().unwrap();
    let v = json!({
        "planet_radius_m": radius_m,
        "atmosphere_height_m": 100000.0,
        "rayleigh": {"scale_height_m": 8000.0,
                     "scattering": {"table_per_m": {"440": 3.31e-5, "550": 1.3558e-5, "680": 5.802e-6}}},
        "mie": {"scale_height_m": 1200.0,
                "extinction": {"optical_depth": {"reference_nm": 550.0, "value": a["aod"],
                                                 "angstrom_exponent": 1.3}},
                "single_scattering_albedo": a["ssa"],
                "phase": {phase: {"g": a["g"]}}},
        "ozone": null,
        "ground_albedo": a["albedo"],
    });
    serde_json::from_value(v).unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (_, standard) = settings_for(Quality::Standard);
    let num = |i: usize, d: f64| args.get(i).and_then(|a| a.parse().ok()).unwrap_or(d);
    let s = PreciseSettings {
        n_r: num(0, standard.n_r as f64) as usize,
        n_mu_s: num(1, standard.n_mu_s as f64) as usize,
        n_mu: num(2, standard.n_mu as f64) as usize,
        n_phi: num(3, standard.n_phi as f64) as usize,
        steps: num(4, standard.steps as f64) as usize,
        tolerance: num(7, standard.tolerance),
        extrapolate_tail: num(8, 1.0) != 0.0,
        // `AEROSOL_PROBE_MAX_ORDERS=n`: stop the series after n orders (with `extrapolate` 0, the
        // table's J_ms is then J_2 + … + J_n: the orders' shares, against an order-split reference).
        max_orders: std::env::var("AEROSOL_PROBE_MAX_ORDERS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(standard.max_orders),
        // `AEROSOL_PROBE_SUBRAYS=n`: sub-rays per cell near the horizon.
        horizon_subrays: std::env::var("AEROSOL_PROBE_SUBRAYS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(standard.horizon_subrays),
        ..standard
    };
    // `AEROSOL_PROBE_SINGLE=1`: single scattering only (no table).
    let method = if std::env::var_os("AEROSOL_PROBE_SINGLE").is_some() {
        MsMethod::None
    } else {
        MsMethod::Precise
    };
    // `AEROSOL_PROBE_DUMP=path`: every compared point as JSON lines.
    let mut dump = std::env::var("AEROSOL_PROBE_DUMP")
        .ok()
        .map(|p| std::fs::File::create(p).unwrap());
    let product_steps = num(5, 32.0) as usize;
    let radius_m = num(6, 63_600_000.0);
    let only: Vec<&String> = args.iter().skip(9).collect();
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/disort_aerosol.json"
    );
    let data: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    eprintln!("{s:?} product steps {product_steps} R {radius_m}");
    let wl = Wavelengths::parse("440,550,680").unwrap();
    // `AEROSOL_PROBE_DETAIL=atmosphere,sun_zenith,nm` (e.g. `thick,75,440`) prints every point of
    // that case.
    let detail = std::env::var("AEROSOL_PROBE_DETAIL").ok();
    for a in data["header"]["inputs"]["atmospheres"].as_array().unwrap() {
        let name = a["name"].as_str().unwrap();
        if !only.is_empty() && !only.iter().any(|o| o.as_str() == name) {
            continue;
        }
        let params = atmosphere(a, radius_m);
        let medium = Medium::new(&params, &wl, None).unwrap();
        let (fast, _) = settings_for(Quality::Standard);
        let shared = SharedTables::new(medium, fast, s);
        let t = std::time::Instant::now();
        let (orders, tail_fraction) = if method == MsMethod::Precise {
            let c = &shared.precise().convergence;
            (c.orders, c.tail_fraction)
        } else {
            (1, 0.0)
        };
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut rows = Vec::new();
        for (li, nm) in [440.0, 550.0, 680.0].iter().enumerate() {
            let (mut far_max, mut far_sum, mut far_n, mut near_max) = (0.0f64, 0.0, 0, 0.0f64);
            let mut worst_at = (0.0, 0.0, 0.0);
            for case in data["cases"].as_array().unwrap() {
                if case["atmosphere"] != name || case["wavelength_nm"].as_f64() != Some(*nm) {
                    continue;
                }
                let sza = case["sun_zenith_deg"].as_f64().unwrap();
                // `AEROSOL_PROBE_GROUND=1`: the table's own sky irradiance on the ground (its
                // ground term E = Σ E_n) beside DISORT's diffuse irradiance.
                if method == MsMethod::Precise && std::env::var_os("AEROSOL_PROBE_GROUND").is_some()
                {
                    use skybake_physics::atmosphere::integrate::Source;
                    let mut e = vec![0.0; 3];
                    shared
                        .precise()
                        .add_ground_sky_irradiance(sza.to_radians().cos(), &mut e);
                    println!(
                        "  ground {name} {nm} sza {sza}: table E {:.6e} DISORT diffuse {:.6e}",
                        e[li],
                        case["diffuse_horizontal"].as_f64().unwrap()
                    );
                }
                let ev = RadianceEvaluator::new(
                    &shared,
                    method,
                    Observer {
                        altitude_m: 0.0,
                        sun_elevation_rad: (90.0 - sza).to_radians(),
                    },
                    product_steps,
                );
                let mut sc = Scratch::new(3);
                let (mut out, mut tr) = (vec![0.0; 3], vec![0.0; 3]);
                for p in case["points"].as_array().unwrap() {
                    let p: Vec<f64> = p
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|x| x.as_f64().unwrap())
                        .collect();
                    let (vz, raz, theta, reference) = (p[0], p[1], p[2], p[3]);
                    if vz > 75.0 || theta < 2.0 {
                        continue;
                    }
                    let (mu, nu) = ev.direction(vz.to_radians(), raz.to_radians());
                    ev.trace(mu, nu, product_steps, &mut sc, &mut out, &mut tr, None);
                    let d = out[li] / reference - 1.0;
                    if let Some(f) = dump.as_mut() {
                        use std::io::Write;
                        writeln!(f, "{}", json!({"atmosphere": name, "nm": nm, "sza": sza, "vz": vz, "az": raz, "theta": theta, "ours": out[li], "disort": reference})).unwrap();
                    }
                    if detail.as_deref() == Some(&format!("{name},{sza},{nm}")) {
                        println!("  vz {vz:5.1} az {raz:5.1} scattering {theta:6.2}: ours {:.5e} DISORT {reference:.5e} {:+.2} %", out[li], 100.0 * d);
                    }
                    if theta >= 10.0 {
                        far_sum += d;
                        far_n += 1;
                        if d.abs() > far_max.abs() {
                            far_max = d;
                            worst_at = (sza, vz, raz);
                        }
                    } else if d.abs() > near_max.abs() {
                        near_max = d;
                    }
                }
            }
            rows.push(format!(
                "{nm}: far max {:+.2}% (sza {} vz {} az {}) mean {:+.2}%, near max {:+.2}%",
                100.0 * far_max,
                worst_at.0,
                worst_at.1,
                worst_at.2,
                100.0 * far_sum / far_n as f64,
                100.0 * near_max
            ));
        }
        println!(
            "{name} (orders {}, tail {:.3}, build {build_ms:.0} ms): {}",
            orders,
            tail_fraction,
            rows.join("; ")
        );
    }
}
