//! Energy balance of the precise method in fog-like conservative haze, at table resolutions and
//! convergence settings the quality presets do not offer, to locate where energy goes missing.
//!
//! The atmosphere is that of the energy test in tests/atmosphere/atmosphere_validation.rs:
//! Rayleigh air plus the continental layered aerosol at visibility 1 km (extinction 3.9e-3 m⁻¹ at
//! 550 nm) to `top` metres, single-scattering albedo 1, Henyey-Greenstein `g`, white ground,
//! ten times Earth's radius (plane-parallel), sun at the zenith, 440 nm. Prints the order series
//! and the outgoing flux at the top per unit incoming flux (1 when energy is conserved), plus the
//! downward and upward fluxes at the ground.
//!
//! With `FOG_PROFILE=1` it also prints the fluxes at altitudes 0–3000 m: the net flux (diffuse
//! down plus direct minus up) is zero at every level when energy is conserved, so where it changes
//! is where the discrete transfer gains or loses energy (it located the fog top's density-integral
//! error).
//!
//! `cargo run --release -p skybake-harness --features probes --example fog_probe -- \
//!    [n_r n_mu_s n_mu n_phi steps product_steps max_orders tolerance extrapolate(0|1) g top_m ext_550]`

use skybake_physics::atmosphere::haze::{default_layers, AerosolType};
use skybake_physics::atmosphere::integrate::Scratch;
use skybake_physics::atmosphere::multiple_precise::PreciseSettings;
use skybake_physics::atmosphere::params::{MiePhase, Spectral};
use skybake_physics::atmosphere::presets::preset;
use skybake_physics::atmosphere::quadrature::gauss_legendre;
use skybake_physics::atmosphere::quality::{settings_for, Quality};
use skybake_physics::atmosphere::shared::SharedTables;
use skybake_physics::atmosphere::sky::{MsMethod, Observer, RadianceEvaluator};
use skybake_physics::atmosphere::Medium;
use skybake_physics::spectrum::Wavelengths;
use std::f64::consts::PI;

/// Hemispheric flux ∫ L |μ| dω at altitude `h` over the upper (`up`) or lower hemisphere, per
/// unit solar irradiance, by Gauss-Legendre in μ (split at the local horizon) and 24 azimuths.
fn flux(shared: &SharedTables, h: f64, up: bool, product_steps: usize) -> f64 {
    let m = &shared.medium;
    let r = m.bottom_radius_m + h;
    let mu_h = -(1.0 - (m.bottom_radius_m / r).powi(2)).max(0.0).sqrt();
    let ev = RadianceEvaluator::new(
        shared,
        MsMethod::Precise,
        Observer {
            altitude_m: h,
            sun_elevation_rad: PI / 2.0,
        },
        product_steps,
    );
    let (x, w) = gauss_legendre(24);
    let spans: Vec<(f64, f64)> = if up {
        vec![(0.0, 1.0)]
    } else {
        vec![(-1.0, mu_h), (mu_h, 0.0)]
    };
    let mut sc = Scratch::new(1);
    let (mut out, mut tr) = (vec![0.0; 1], vec![0.0; 1]);
    let mut total = 0.0;
    for (lo, hi) in spans {
        if hi <= lo {
            continue;
        }
        for (a, &xa) in x.iter().enumerate() {
            let mu = lo + (hi - lo) * 0.5 * (xa + 1.0);
            // Sun at the zenith: the radiance does not depend on azimuth.
            let (mu, nu) = ev.direction(mu.acos(), 0.0);
            out[0] = 0.0;
            ev.trace(mu, nu, product_steps, &mut sc, &mut out, &mut tr, None);
            total += out[0] * mu.abs() * 0.5 * (hi - lo) * w[a] * 2.0 * PI;
        }
    }
    // `trace` gives radiance per unit solar irradiance already.
    total
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (fast, standard) = settings_for(Quality::Standard);
    let num = |i: usize, d: f64| args.get(i).and_then(|a| a.parse().ok()).unwrap_or(d);
    let s = PreciseSettings {
        n_r: num(0, standard.n_r as f64) as usize,
        n_mu_s: num(1, standard.n_mu_s as f64) as usize,
        n_mu: num(2, standard.n_mu as f64) as usize,
        n_phi: num(3, standard.n_phi as f64) as usize,
        steps: num(4, standard.steps as f64) as usize,
        max_orders: num(6, standard.max_orders as f64) as usize,
        tolerance: num(7, standard.tolerance),
        extrapolate_tail: num(8, 1.0) != 0.0,
        ..standard
    };
    let product_steps = num(5, 32.0) as usize;
    let (g, top, ext) = (num(9, 0.7), num(10, 1500.0), num(11, 3.9e-3));
    let mut p = preset("rayleigh-only").unwrap();
    p.planet_radius_m = 63_600_000.0;
    let mut mie = AerosolType::Continental.mie(ext, default_layers(top, p.atmosphere_height_m));
    mie.single_scattering_albedo = Spectral::Constant(1.0);
    mie.phase = MiePhase::HenyeyGreenstein { g };
    p.mie = Some(mie);
    p.ground_albedo = Some(Spectral::Constant(1.0));
    let wl = Wavelengths::parse("440").unwrap();
    let medium = Medium::new(&p, &wl, None).unwrap();
    let (n_r_table, n_phi_table) =
        skybake_physics::atmosphere::multiple_precise::table_radius_and_azimuth_nodes(&s, &medium);
    eprintln!("{s:?} product steps {product_steps} g {g} top {top} ext {ext}; table n_r {n_r_table} n_phi {n_phi_table}");
    let shared = SharedTables::new(medium, fast, s);
    let t = std::time::Instant::now();
    let conv = shared.precise().convergence.clone();
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let fr: Vec<String> = conv
        .order_fractions
        .iter()
        .map(|f| format!("{f:.3}"))
        .collect();
    println!(
        "orders {} tail {:.4} err {:.2e} q {:.4} build {build_ms:.0} ms; fractions {}",
        conv.orders,
        conv.tail_fraction,
        conv.series_error_estimate,
        conv.order_ratio,
        fr.join(" ")
    );
    let top_h = shared.medium.top_radius_m - shared.medium.bottom_radius_m;
    let out = flux(&shared, top_h, false, product_steps);
    let down = flux(&shared, 0.0, true, product_steps);
    let up = flux(&shared, 0.0, false, product_steps);
    println!(
        "outgoing/incoming at the top {out:.5}; at the ground: down (diffuse) {down:.5}, up {up:.5}"
    );
    // Flux profile: with no absorption over a white ground the net flux (diffuse down + direct
    // − up) is zero at every level; where it is not, the discrete transfer gains or loses energy.
    if std::env::var_os("FOG_PROFILE").is_some() {
        for h in [
            0.0, 100.0, 300.0, 600.0, 900.0, 1200.0, 1400.0, 1500.0, 1600.0, 3000.0,
        ] {
            let d = flux(&shared, h, true, product_steps);
            let u = flux(&shared, h, false, product_steps);
            let direct = skybake_physics::atmosphere::sun_transmittance::sun_transmittance(
                &shared.medium,
                h,
                PI / 2.0,
            )[0];
            println!(
                "h {h:6.0} m: down {d:.5} direct {direct:.5} up {u:.5} net {:+.5}",
                d + direct - u
            );
        }
    }
}
