use skybake::atmosphere::integrate::Scratch;
use skybake::atmosphere::quadrature::gauss_legendre;
use skybake::atmosphere::{presets::preset, shared::SharedTables, sky::*, Medium};
use skybake::engine::{hemisphere_irradiance, settings_for};
use skybake::spectrum::Wavelengths;
use std::f64::consts::PI;
fn up_flux(ev: &RadianceEvaluator, e0: f64, rr: f64) -> f64 {
    let (hx, hw) = gauss_legendre(32);
    let mut s = Scratch::new(1);
    let mut o = vec![0.0];
    let mut tr = vec![0.0];
    let mut f = 0.0;
    let muh = -(1.0f64 - (rr / (rr + 100000.0)).powi(2)).sqrt();
    for (lo, hi) in [(-1.0, muh), (muh, 0.0)] {
        for (b, &y) in hx.iter().enumerate() {
            let mu = lo + (hi - lo) * 0.5 * (y + 1.0);
            for c in 0..32 {
                let phi = PI * (c as f64 + 0.5) / 32.0;
                ev.eval(mu.acos(), phi, &mut s, &mut o, &mut tr);
                f += o[0] / e0 * (-mu) * 0.5 * (hi - lo) * hw[b] * 2.0 * PI / 32.0;
            }
        }
    }
    f
}
fn main() {
    let w = Wavelengths::parse(&std::env::var("W").unwrap_or("440".into())).unwrap();
    let q = std::env::var("Q").unwrap_or("standard".into());
    let mut p = preset("rayleigh-only").unwrap();
    if let Ok(r) = std::env::var("R") {
        p.planet_radius_m = r.parse().unwrap();
    }
    let m = Medium::new(
        &p,
        &w,
        Some(
            std::env::var("A")
                .map(|s| s.parse().unwrap())
                .unwrap_or(0.0),
        ),
    )
    .unwrap();
    let (fs, ps) = settings_for(skybake::spec::Quality::parse(&q).unwrap());
    let shared = SharedTables::new(m, fs, ps);
    let e0 = shared.medium.solar_irradiance[0];
    let tau = shared.medium.vertical_optical_depth(0)[0];
    for method in [MsMethod::None, MsMethod::Precise, MsMethod::Fast] {
        let sza: f64 = 0.0;
        let obs = |alt| Observer {
            altitude_m: alt,
            sun_elevation_rad: (90.0 - sza).to_radians(),
        };
        let ev = RadianceEvaluator::new(&shared, method, obs(0.0), 64);
        let down = hemisphere_irradiance(&ev, 1, 32, 32)[0] / e0;
        let evt = RadianceEvaluator::new(&shared, method, obs(100000.0), 64);
        let up = up_flux(&evt, e0, shared.medium.bottom_radius_m);
        let direct = (-tau).exp();
        let a = shared.medium.ground_albedo[0];
        println!(
            "{method:?}: direct {direct:.5} diffuse down {down:.5} up at top {up:.5} balance {:.5}",
            direct + up + (1.0 - a) * (down + direct) - direct
        );
    }
}
