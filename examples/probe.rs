use skybake::atmosphere::integrate::Scratch;
use skybake::atmosphere::{
    multiple_fast::FastSettings, multiple_precise::PreciseSettings, presets::preset,
    shared::SharedTables, sky::*, Medium,
};
use skybake::spectrum::Wavelengths;
use std::time::Instant;
fn main() {
    let name = std::env::args().nth(1).unwrap_or("rayleigh-only".into());
    let albedo: f64 = std::env::args()
        .nth(2)
        .map(|s| s.parse().unwrap())
        .unwrap_or(0.0);
    let w = Wavelengths::parse("440,550,680").unwrap();
    let m = Medium::new(&preset(&name).unwrap(), &w, Some(albedo)).unwrap();
    let t = Instant::now();
    let shared = SharedTables::new(m, FastSettings::default(), PreciseSettings::default());
    println!("density table {:?}", t.elapsed());
    let t = Instant::now();
    shared.fast();
    println!("fast {:?}", t.elapsed());
    let t = Instant::now();
    let p = shared.precise();
    println!("precise {:?} {:?}", t.elapsed(), p.convergence);
    for method in [MsMethod::None, MsMethod::Fast, MsMethod::Precise] {
        let ev = RadianceEvaluator::new(
            &shared,
            method,
            Observer {
                altitude_m: 0.0,
                sun_elevation_rad: 30f64.to_radians(),
            },
            48,
        );
        let mut s = Scratch::new(3);
        let mut o = vec![0.0; 3];
        let mut tr = vec![0.0; 3];
        for (vz, va) in [(0.0, 0.0), (30.0, 0.0), (60.0, 90.0), (60.0, 180.0)] {
            ev.eval(
                f64::to_radians(vz),
                f64::to_radians(va),
                &mut s,
                &mut o,
                &mut tr,
            );
            let e = &shared.medium.solar_irradiance;
            println!(
                "{method:?} vz {vz} va {va}: L/E = {:.5} {:.5} {:.5}",
                o[0] / e[0],
                o[1] / e[1],
                o[2] / e[2]
            );
        }
    }
}
