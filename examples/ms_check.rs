use skybake::atmosphere::integrate::Scratch;
use skybake::atmosphere::{presets::preset, shared::SharedTables, sky::*, Medium};
use skybake::engine::settings_for;
use skybake::spectrum::Wavelengths;
fn main() {
    let w = Wavelengths::parse("680").unwrap();
    let mut p = preset("rayleigh-only").unwrap();
    if let Ok(r) = std::env::var("R") {
        p.planet_radius_m = r.parse().unwrap();
    }
    let m = Medium::new(&p, &w, Some(0.0)).unwrap();
    let q = std::env::var("Q").unwrap_or("standard".into());
    let (fs, ps) = settings_for(skybake::spec::Quality::parse(&q).unwrap());
    let shared = SharedTables::new(m, fs, ps);
    let e0 = shared.medium.solar_irradiance[0];
    println!("{:?}", shared.precise().convergence.orders);
    for method in [MsMethod::None, MsMethod::Precise, MsMethod::Fast] {
        let ev = RadianceEvaluator::new(
            &shared,
            method,
            Observer {
                altitude_m: 0.0,
                sun_elevation_rad: 60f64.to_radians(),
            },
            128,
        );
        let mut s = Scratch::new(1);
        let mut o = vec![0.0];
        let mut tr = vec![0.0];
        for (vz, va) in [(60.0f64, 180.0f64), (0.0, 0.0), (60.0, 0.0)] {
            ev.eval(vz.to_radians(), va.to_radians(), &mut s, &mut o, &mut tr);
            println!("{method:?} vz {vz} va {va}: {:.6}", o[0] / e0);
        }
    }
}
