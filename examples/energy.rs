use skybake::atmosphere::integrate::Scratch;
use skybake::atmosphere::quadrature::gauss_legendre;
use skybake::atmosphere::{
    multiple_fast::FastSettings, multiple_precise::PreciseSettings, presets::preset,
    shared::SharedTables, sky::*, Medium,
};
use skybake::spectrum::Wavelengths;
use std::f64::consts::PI;
fn main() {
    let method = match std::env::args().nth(1).as_deref() {
        Some("fast") => MsMethod::Fast,
        _ => MsMethod::Precise,
    };
    let w = Wavelengths::parse("440").unwrap();
    let p = preset("rayleigh-only").unwrap();
    let m = Medium::new(&p, &w, Some(1.0)).unwrap();
    let t = std::time::Instant::now();
    let q = std::env::var("Q").unwrap_or("standard".into());
    let (fs, ps) = skybake::engine::settings_for(skybake::spec::Quality::parse(&q).unwrap());
    let shared = SharedTables::new(m, fs, ps);
    if method == MsMethod::Precise {
        println!("{:?} {:?}", shared.precise().convergence, t.elapsed());
    }
    let top = p.atmosphere_height_m;
    let e0 = shared.medium.solar_irradiance[0];
    let (gx, gw) = gauss_legendre(48);
    let mut total = 0.0;
    let (hx, hw) = gauss_legendre(24);
    for (a, &x) in gx.iter().enumerate() {
        let theta_s = 0.5 * (x + 1.0) * PI;
        let ev = RadianceEvaluator::new(
            &shared,
            method,
            Observer {
                altitude_m: top,
                sun_elevation_rad: PI / 2.0 - theta_s,
            },
            48,
        );
        let mut s = Scratch::new(1);
        let mut o = vec![0.0];
        let mut tr = vec![0.0];
        let mut f = 0.0;
        for (b, &y) in hx.iter().enumerate() {
            let mu = -0.5 * (y + 1.0);
            for c in 0..24 {
                let phi = PI * (c as f64 + 0.5) / 24.0;
                ev.eval(mu.acos(), phi, &mut s, &mut o, &mut tr);
                f += o[0] / e0 * (-mu) * 0.5 * hw[b] * 2.0 * PI / 24.0;
            }
        }
        total += f * theta_s.sin() * 0.5 * PI * gw[a];
        if a % 6 == 0 {
            println!("theta_s {:.1} F_up {:.4}", theta_s.to_degrees(), f);
        }
    }
    println!("outgoing / incoming = {:.5}", 2.0 * total);
}
