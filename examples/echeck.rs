use skybake::atmosphere::integrate::Source;
use skybake::atmosphere::{presets::preset, shared::SharedTables, sky::*, Medium};
use skybake::engine::{hemisphere_irradiance, settings_for};
use skybake::spectrum::Wavelengths;
fn main() {
    let w = Wavelengths::parse("440").unwrap();
    let albedo: f64 = std::env::args()
        .nth(1)
        .map(|s| s.parse().unwrap())
        .unwrap_or(1.0);
    let m = Medium::new(&preset("rayleigh-only").unwrap(), &w, Some(albedo)).unwrap();
    let (fs, ps) = settings_for(skybake::spec::Quality::Standard);
    let shared = SharedTables::new(m, fs, ps);
    let e0 = shared.medium.solar_irradiance[0];
    for sza in [0.0f64, 30.0, 60.0, 85.0] {
        let ev = RadianceEvaluator::new(
            &shared,
            MsMethod::Precise,
            Observer {
                altitude_m: 0.0,
                sun_elevation_rad: (90.0 - sza).to_radians(),
            },
            64,
        );
        let dhi = hemisphere_irradiance(&ev, 1, 32, 32)[0] / e0;
        let mut t = vec![0.0];
        shared
            .precise()
            .add_ground_sky_irradiance(sza.to_radians().cos(), &mut t);
        let mut f = vec![0.0];
        shared
            .fast()
            .add_ground_sky_irradiance(sza.to_radians().cos(), &mut f);
        let evf = RadianceEvaluator::new(
            &shared,
            MsMethod::Fast,
            Observer {
                altitude_m: 0.0,
                sun_elevation_rad: (90.0 - sza).to_radians(),
            },
            64,
        );
        let dhif = hemisphere_irradiance(&evf, 1, 32, 32)[0] / e0;
        println!("sza {sza}: precise hemisphere {dhi:.5} table {:.5} | fast hemisphere {dhif:.5} table {:.5}", t[0], f[0]);
    }
}
