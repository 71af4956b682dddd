//! RGB-only frames (issue 15 point 3): what the planner's wavelength rule
//! ([`crate::plan::rgb_wavelengths_rule`]) decides on. A request whose only output is the RGB
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
use crate::atmosphere::sun_transmittance::sun_transmittance;
use crate::atmosphere::Medium;
use crate::plan::{RgbFacts, WavelengthCandidate, MIN_RGB_WAVELENGTHS};
use crate::spectrum::colour::xyz_to_linear_srgb;
use crate::spectrum::data::cie1931_cmfs;
use crate::Result;

/// The CIE 1931 colour-matching functions on the 1 nm grid 360–830 nm.
fn cmf_grid() -> Vec<[f64; 3]> {
    let cmfs = cie1931_cmfs();
    (0..=470)
        .map(|k| {
            let l = 360.0 + k as f64;
            [cmfs[0].eval(l), cmfs[1].eval(l), cmfs[2].eval(l)]
        })
        .collect()
}

/// Linear sRGB of each proxy known at the wavelengths `keep` (indices into `nm`, ascending),
/// linear between them and constant beyond the ends, as `spectrum::colour::XyzWeights`.
fn rgb_at(nm: &[f64], keep: &[usize], proxies: &[Vec<f64>], cmf: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut xyz = vec![[0.0f64; 3]; proxies.len()];
    let mut j = 0;
    for (k, c) in cmf.iter().enumerate() {
        let l = 360.0 + k as f64;
        while j + 1 < keep.len() && nm[keep[j + 1]] <= l {
            j += 1;
        }
        let (i0, i1, t) = if l <= nm[keep[0]] || j + 1 >= keep.len() {
            (keep[j], keep[j], 0.0)
        } else {
            let (a, b) = (keep[j], keep[j + 1]);
            (a, b, (l - nm[a]) / (nm[b] - nm[a]))
        };
        for (acc, p) in xyz.iter_mut().zip(proxies) {
            let v = p[i0] * (1.0 - t) + p[i1] * t;
            for ch in 0..3 {
                acc[ch] += v * c[ch];
            }
        }
    }
    xyz.into_iter().map(xyz_to_linear_srgb).collect()
}

/// The largest change of any proxy's RGB against `full`, relative to its mean |channel|.
fn worst_change(rgb: &[[f64; 3]], full: &[[f64; 3]]) -> f64 {
    rgb.iter()
        .zip(full)
        .map(|(a, f)| {
            let scale = (f[0].abs() + f[1].abs() + f[2].abs()) / 3.0;
            let d = (0..3).map(|c| (a[c] - f[c]).abs()).fold(0.0, f64::max);
            if scale > 0.0 {
                d / scale
            } else {
                0.0
            }
        })
        .fold(0.0, f64::max)
}

/// The scene's proxy spectra at its wavelengths (see the module docs); those that are zero
/// everywhere are dropped.
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
    let mut lights: Vec<Vec<f64>> = Vec::new();
    let ground_albedo = scene.ground.as_ref().map(|g| g.albedo.clone());
    match &scene.atmosphere {
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
            if let Some(g) = &ground_albedo {
                lights.push(
                    (0..n)
                        .map(|l| g[l] * (sun[l] * mu_s + std::f64::consts::PI * sky[l]))
                        .collect(),
                );
            }
            lights.push(sun);
            lights.push(sky);
        }
        Some(params) => {
            let m = Medium::new(params, &scene.wavelengths, None)?;
            let e0 = m.solar_irradiance.clone();
            let scattering: Vec<f64> = (0..n)
                .map(|l| m.rayleigh_scattering_per_m[l] + m.mie_scattering_per_m[l])
                .collect();
            let elevation = scene.sun.elevation_deg.to_radians();
            let camera_altitude = scene.camera.position_m.z.clamp(0.0, 1e6);
            lights.push(e0.clone());
            lights.push(times(&e0, &scattering));
            for altitude in [0.0, camera_altitude] {
                let t = sun_transmittance(&m, altitude, elevation);
                let beam = times(&e0, &t);
                lights.push(times(&beam, &scattering));
                if let Some(g) = &ground_albedo {
                    lights.push(times(&beam, g));
                }
                lights.push(beam);
            }
        }
    }
    let mut proxies = Vec::new();
    for light in lights {
        proxies.push(times(&light, albedo));
        proxies.push(times(&times(&light, albedo), &relative_k));
        proxies.push(light);
    }
    proxies.retain(|p| p.iter().any(|v| *v > 0.0) && p.iter().all(|v| v.is_finite()));
    Ok(proxies)
}

/// The facts of an RGB-only request for `scene`: its wavelengths and the subsets it could run
/// at with their proxies' change, fewest wavelengths first (none with fewer than
/// [`MIN_RGB_WAVELENGTHS`] wavelengths requested or without a lit proxy).
pub fn rgb_facts(scene: &FrameScene) -> Result<RgbFacts> {
    let nm = scene.wavelengths.as_nm().to_vec();
    let proxies = proxy_spectra(scene)?;
    let mut candidates = Vec::new();
    if nm.len() > MIN_RGB_WAVELENGTHS && !proxies.is_empty() {
        let cmf = cmf_grid();
        let all: Vec<usize> = (0..nm.len()).collect();
        let full = rgb_at(&nm, &all, &proxies, &cmf);
        let mut keep = all;
        while keep.len() > MIN_RGB_WAVELENGTHS {
            // Drop the interior wavelength whose loss changes the worst proxy least (the first
            // and last stay: beyond them the spectrum is held constant).
            let mut best: Option<(usize, f64)> = None;
            for j in 1..keep.len() - 1 {
                let mut trial = keep.clone();
                trial.remove(j);
                let e = worst_change(&rgb_at(&nm, &trial, &proxies, &cmf), &full);
                if best.is_none_or(|(_, b)| e < b) {
                    best = Some((j, e));
                }
            }
            let Some((j, e)) = best else { break };
            keep.remove(j);
            candidates.push(WavelengthCandidate {
                internal_nm: keep.iter().map(|&i| nm[i]).collect(),
                proxy_error: e,
            });
        }
        candidates.reverse();
    }
    Ok(RgbFacts {
        requested_nm: nm,
        candidates,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(wavelengths: &str, atmosphere: bool) -> FrameScene {
        let mut v: serde_json::Value =
            serde_json::from_str(include_str!("../../config/scenes/validation-frame.json"))
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
    fn the_full_set_reproduces_the_colour_module_and_subsets_are_ordered() {
        let s = scene(
            "[380, 405, 430, 455, 480, 505, 530, 555, 580, 605, 630, 655, 680, 705, 730, 755]",
            true,
        );
        let proxies = proxy_spectra(&s).unwrap();
        assert!(proxies.len() >= 6);
        let nm = s.wavelengths.as_nm();
        let all: Vec<usize> = (0..nm.len()).collect();
        let ours = rgb_at(nm, &all, &proxies, &cmf_grid());
        let w = crate::spectrum::colour::XyzWeights::new(nm);
        for (p, rgb) in proxies.iter().zip(&ours) {
            let theirs = w.linear_srgb(p);
            for c in 0..3 {
                assert!((rgb[c] - theirs[c]).abs() <= 1e-9 * theirs[c].abs().max(1e-30));
            }
        }
        let f = rgb_facts(&s).unwrap();
        assert_eq!(f.candidates.len(), 16 - MIN_RGB_WAVELENGTHS);
        assert_eq!(f.candidates[0].internal_nm.len(), MIN_RGB_WAVELENGTHS);
        for c in &f.candidates {
            assert_eq!(c.internal_nm.first(), Some(&380.0));
            assert_eq!(c.internal_nm.last(), Some(&755.0));
            assert!(c.proxy_error.is_finite() && c.proxy_error >= 0.0);
        }
        // Three wavelengths cannot hold a sky's colour to a per cent; fifteen of sixteen can.
        assert!(f.candidates[0].proxy_error > 0.01);
        assert!(f.candidates.last().unwrap().proxy_error < 0.02);
    }

    #[test]
    fn three_wavelengths_or_fewer_have_no_subset() {
        let f = rgb_facts(&scene("[440, 550, 680]", false)).unwrap();
        assert!(f.candidates.is_empty());
    }
}
