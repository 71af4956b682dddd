//! RGB-only frames: what the planner's wavelength rule
//! ([`skybake_engine::plan::rgb_wavelengths_rule`]) decides on. A request whose only output is the RGB
//! image (a PNG) needs the spectrum only as far as the colour-matching functions see it; the
//! frame's RGB planes interpolate its spectral planes linearly onto the 1 nm grid
//! (`spectrum::colour`), so a subset of the requested wavelengths changes the RGB by the
//! interpolation error of the spectra between them.
//!
//! That error is predicted on **proxy spectra** of the scene, known at every requested
//! wavelength before anything is computed: the light reaching the cloud (the sun's beam at the
//! ground and at the camera's altitude through the atmosphere, with its 1 nm solar spectrum and
//! the ozone and Rayleigh extinction; a vacuum scene's given sun, sky and ground light), the sky
//! (the sunlit air's scattering coefficient), and each of those times the cloud's albedo and its
//! relative extinction (a thin cloud's colour). Backward elimination then drops, one at a time,
//! the interior wavelength whose loss changes the worst proxy least.

use super::scene::{FrameScene, SkySpec};
use crate::Result;
use skybake_engine::plan::{RgbFacts, WavelengthCandidate};
use skybake_physics::atmosphere::sun_transmittance::light_spectra;
use skybake_physics::atmosphere::Medium;
use skybake_physics::spectrum::subsets::rgb_subsets;

/// The scene's proxy spectra at its wavelengths (see the module docs).
pub fn proxy_spectra(scene: &FrameScene) -> Result<Vec<Vec<f64>>> {
    let n = scene.wavelengths.len();
    let albedo = &scene.optics.albedo;
    let k = &scene.optics.extinction_per_density_m;
    let k_mean = k.iter().sum::<f64>() / n.max(1) as f64;
    let relative_k: Vec<f64> = k
        .iter()
        .map(|v| if k_mean > 0.0 { v / k_mean } else { 1.0 })
        .collect();
    let times = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).collect::<Vec<_>>();
    let lights: Vec<Vec<f64>> = match &scene.atmosphere {
        None => {
            let sun = scene
                .sun
                .collimated_irradiance
                .clone()
                .unwrap_or_else(|| vec![1.0; n]);
            let sky = match &scene.sky {
                SkySpec::Constant(v) => v.clone(),
                _ => vec![0.0; n],
            };
            let mu_s = scene.sun.direction().z.max(0.0);
            let mut lights = Vec::new();
            if let Some(g) = &scene.ground {
                lights.push(
                    (0..n)
                        .map(|l| g.albedo[l] * (sun[l] * mu_s + std::f64::consts::PI * sky[l]))
                        .collect(),
                );
            }
            lights.push(sun);
            lights.push(sky);
            lights
        }
        Some(params) => {
            let mut m = Medium::new(params, &scene.wavelengths, None)?;
            m.ground_albedo = match &scene.ground {
                Some(g) => g.albedo.clone(),
                None => vec![0.0; n],
            };
            let camera_altitude = scene.camera.position_m.z.clamp(0.0, 1e6);
            let mut lights = light_spectra(
                &m,
                &[0.0, camera_altitude],
                scene.sun.elevation_deg.to_radians(),
            );
            // A collimated sun lights the cloud with its given spectrum (the atmosphere's
            // products keep the solar one).
            if let Some(e) = &scene.sun.collimated_irradiance {
                lights.push(e.clone());
            }
            lights
        }
    };
    let mut proxies = Vec::new();
    for light in lights {
        proxies.push(times(&light, albedo));
        proxies.push(times(&times(&light, albedo), &relative_k));
        proxies.push(light);
    }
    Ok(proxies)
}

/// The facts of an RGB-only request for `scene`: its wavelengths and the subsets it could run
/// at with their proxies' change, fewest wavelengths first (`spectrum::subsets::rgb_subsets`).
pub fn rgb_facts(scene: &FrameScene) -> Result<RgbFacts> {
    let nm = scene.wavelengths.as_nm().to_vec();
    let candidates = rgb_subsets(&nm, &proxy_spectra(scene)?)
        .into_iter()
        .map(|(internal_nm, proxy_error)| WavelengthCandidate {
            internal_nm,
            proxy_error,
        })
        .collect();
    Ok(RgbFacts {
        requested_nm: nm,
        candidates,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use skybake_physics::spectrum::subsets::MIN_RGB_WAVELENGTHS;

    fn scene(wavelengths: &str, atmosphere: bool) -> FrameScene {
        let mut v: serde_json::Value =
            serde_json::from_str(include_str!("../../../config/scenes/validation-frame.json"))
                .unwrap();
        v["wavelengths_nm"] = serde_json::from_str(wavelengths).unwrap();
        if atmosphere {
            v["atmosphere"] = serde_json::json!("earth");
            v["sky"] = serde_json::json!("atmosphere");
            v["sun"] = serde_json::json!({"elevation_deg": 35, "azimuth_deg": 140});
        }
        FrameScene::parse(&serde_json::to_vec(&v).unwrap()).unwrap()
    }

    #[test]
    fn an_atmosphere_scene_has_subsets_down_to_three_wavelengths() {
        let s = scene(
            "[380, 405, 430, 455, 480, 505, 530, 555, 580, 605, 630, 655, 680, 705, 730, 755]",
            true,
        );
        assert!(proxy_spectra(&s).unwrap().len() >= 15);
        let f = rgb_facts(&s).unwrap();
        assert_eq!(f.candidates.len(), 16 - MIN_RGB_WAVELENGTHS);
        assert_eq!(f.candidates[0].internal_nm.len(), MIN_RGB_WAVELENGTHS);
        // Three wavelengths cannot hold the sunlit sky's colour to a per cent (20 % measured);
        // fifteen of sixteen can (705 nm, where the colour-matching functions are small).
        assert!(f.candidates[0].proxy_error > 0.05);
        assert!(f.candidates.last().unwrap().proxy_error < 1e-3);
    }

    #[test]
    fn three_wavelengths_or_fewer_have_no_subset() {
        let f = rgb_facts(&scene("[440, 550, 680]", false)).unwrap();
        assert!(f.candidates.is_empty());
    }
}
