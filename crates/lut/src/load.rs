//! A bundle read back from its files — the manifest (parsed JSON) and each texture's decoded
//! channels — the way a client loads it (docs/lut.md): channels, wavelengths and his
//! `AtmosphereParameters` from the manifest, texture sizes and channel order from its
//! `textures` entries. Pure: the caller reads and decodes the files.

use serde_json::Value;

use crate::build::{Bundle, Channels, Sample, Texture};
use crate::manifest::BUNDLE_VERSION;
use crate::param::{AtmosphereParameters, TRANSMITTANCE_HEIGHT, TRANSMITTANCE_WIDTH};
use crate::skyview::{self, SkyViewBundle};
use crate::{Error, Result};

/// A decoded texture file: width, height (all stacked slices) and its channels by name.
pub type DecodedFile = (usize, usize, Vec<(String, Vec<f32>)>);

fn field<'a>(v: &'a Value, path: &str) -> Result<&'a Value> {
    path.split('.')
        .try_fold(v, |v, k| v.get(k))
        .ok_or_else(|| Error::invalid("manifest", format!("has no `{path}`")))
}

fn number(v: &Value, path: &str) -> Result<f64> {
    field(v, path)?
        .as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| Error::invalid("manifest", format!("`{path}` is not a finite number")))
}

fn numbers(v: &Value, path: &str, n: usize) -> Result<Vec<f64>> {
    let list = field(v, path)?
        .as_array()
        .ok_or_else(|| Error::invalid("manifest", format!("`{path}` is not a list")))?;
    let out: Vec<f64> = list
        .iter()
        .filter_map(|x| x.as_f64().filter(|x| x.is_finite()))
        .collect();
    if out.len() != n || list.len() != n {
        return Err(Error::invalid(
            "manifest",
            format!("`{path}` must hold {n} finite numbers (one per channel)"),
        ));
    }
    Ok(out)
}

fn size(v: &Value, path: &str) -> Result<usize> {
    field(v, path)?
        .as_u64()
        .filter(|&x| (1..=1 << 16).contains(&x))
        .map(|x| x as usize)
        .ok_or_else(|| Error::invalid("manifest", format!("`{path}` is not a texture size")))
}

/// One texture of the manifest (`textures.<name>`), its values interleaved in the manifest's
/// channel order, from `read(file name)`.
fn texture(
    manifest: &Value,
    name: &str,
    read: &mut dyn FnMut(&str) -> Result<DecodedFile>,
) -> Result<Texture> {
    let entry = field(manifest, &format!("textures.{name}"))?;
    let file = field(entry, "file")?
        .as_str()
        .ok_or_else(|| Error::invalid("manifest", format!("textures.{name}.file")))?;
    let (width, height, depth) = (
        size(entry, "width")?,
        size(entry, "height")?,
        size(entry, "depth")?,
    );
    let sample = match field(entry, "sample")?.as_str() {
        Some("half") => Sample::Half,
        Some("float") => Sample::Float,
        _ => {
            return Err(Error::invalid(
                "manifest",
                format!("textures.{name}.sample must be half or float"),
            ))
        }
    };
    let names: Vec<&str> = field(entry, "channels")?
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    let (w, h, decoded) = read(file)?;
    if (w, h) != (width, height * depth) {
        return Err(Error::invalid(
            file,
            format!(
                "is {w}×{h}, the manifest says {width}×{} ({height} rows × {depth} slices)",
                height * depth
            ),
        ));
    }
    let planes: Vec<&Vec<f32>> = names
        .iter()
        .map(|n| {
            decoded
                .iter()
                .find(|(c, v)| c == n && v.len() == w * h)
                .map(|(_, v)| v)
                .ok_or_else(|| Error::invalid(file, format!("has no full channel `{n}`")))
        })
        .collect::<Result<_>>()?;
    if planes.is_empty() {
        return Err(Error::invalid(
            "manifest",
            format!("textures.{name}.channels is empty"),
        ));
    }
    let channels = planes.len();
    let mut data = vec![0.0f32; w * h * channels];
    for (c, plane) in planes.iter().enumerate() {
        for (i, v) in plane.iter().enumerate() {
            data[i * channels + c] = *v;
        }
    }
    Ok(Texture {
        width,
        height,
        depth,
        channels,
        sample,
        data,
    })
}

/// The channels' wavelengths and his `AtmosphereParameters` of a manifest (both layouts).
fn channels_and_parameters(manifest: &Value) -> Result<(Vec<f64>, AtmosphereParameters)> {
    let wavelengths_nm: Vec<f64> = field(manifest, "channels")?
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|c| c.get("wavelength_nm")?.as_f64())
                .collect()
        })
        .unwrap_or_default();
    let n = wavelengths_nm.len();
    if n == 0 {
        return Err(Error::invalid("manifest", "`channels` lists no wavelength"));
    }
    let a = "atmosphere_parameters";
    let params = AtmosphereParameters {
        solar_irradiance: numbers(manifest, &format!("{a}.solar_irradiance"), n)?,
        sun_angular_radius: number(manifest, &format!("{a}.sun_angular_radius"))?,
        bottom_radius: number(manifest, &format!("{a}.bottom_radius"))?,
        top_radius: number(manifest, &format!("{a}.top_radius"))?,
        rayleigh_scattering: numbers(manifest, &format!("{a}.rayleigh_scattering"), n)?,
        mie_scattering: numbers(manifest, &format!("{a}.mie_scattering"), n)?,
        mie_phase_function_g: number(manifest, &format!("{a}.mie_phase_function_g"))?,
        mu_s_min: number(manifest, &format!("{a}.mu_s_min"))?,
        ground_albedo: numbers(manifest, &format!("{a}.ground_albedo"), n)?,
    };
    if !(params.bottom_radius > 0.0 && params.top_radius > params.bottom_radius) {
        return Err(Error::invalid(
            "manifest",
            "atmosphere_parameters needs 0 < bottom_radius < top_radius",
        ));
    }
    Ok((wavelengths_nm, params))
}

/// The bundle's layout, the manifest's `format` (`bruneton2017` or `skyview`).
pub fn format(manifest: &Value) -> Result<&str> {
    field(manifest, "format")?
        .as_str()
        .ok_or_else(|| Error::invalid("manifest", "`format` is not a string"))
}

/// The bundle described by `manifest`, its textures read by `read(file name)`.
pub fn from_files(
    manifest: &Value,
    read: &mut dyn FnMut(&str) -> Result<DecodedFile>,
) -> Result<Bundle> {
    if format(manifest)? != "bruneton2017"
        || field(manifest, "bundle_version")?.as_str() != Some(BUNDLE_VERSION)
    {
        return Err(Error::invalid(
            "manifest",
            format!("is not a bruneton2017 bundle of layout version {BUNDLE_VERSION}"),
        ));
    }
    let (wavelengths_nm, params) = channels_and_parameters(manifest)?;
    let combined = field(manifest, "parameterisation.combined_scattering_textures")?
        .as_bool()
        .unwrap_or(false);
    let channels = if combined {
        Channels::Rgb
    } else {
        Channels::Spectral
    };
    let single_mie = if combined {
        None
    } else {
        Some(texture(manifest, "single_mie_scattering", read)?)
    };
    Ok(Bundle {
        channels,
        wavelengths_nm,
        params,
        transmittance: texture(manifest, "transmittance", read)?,
        scattering: texture(manifest, "scattering", read)?,
        single_mie,
        irradiance: texture(manifest, "irradiance", read)?,
        timing_ms: [0.0; 4],
    })
}

/// The `skyview` bundle (docs/lut.md, "The `skyview` layout") described by `manifest`, its
/// textures read by `read(file name)`: the same manifest fields as [`from_files`] plus the
/// aerosol's phase function; the node counts of the manifest's `parameterisation.sizes` must be
/// this version's ([`crate::skyview`]).
pub fn skyview_from_files(
    manifest: &Value,
    read: &mut dyn FnMut(&str) -> Result<DecodedFile>,
) -> Result<SkyViewBundle> {
    if format(manifest)? != skyview::LAYOUT
        || field(manifest, "bundle_version")?.as_str() != Some(skyview::SKYVIEW_VERSION)
    {
        return Err(Error::invalid(
            "manifest",
            format!(
                "is not a {} bundle of layout version {}",
                skyview::LAYOUT,
                skyview::SKYVIEW_VERSION
            ),
        ));
    }
    let sizes = [
        ("N_ALT", skyview::N_ALT),
        ("N_SUN", skyview::N_SUN),
        ("N_VIEW_SKY", skyview::N_VIEW_SKY),
        ("N_VIEW_LIMB", skyview::N_VIEW_LIMB),
        ("N_VIEW_DOWN", skyview::N_VIEW_DOWN),
        ("N_AZ", skyview::N_AZ),
    ];
    for (name, n) in sizes {
        if size(manifest, &format!("parameterisation.sizes.{name}"))? != n {
            return Err(Error::invalid(
                "manifest",
                format!(
                    "parameterisation.sizes.{name} must be {n} in layout version {}",
                    skyview::SKYVIEW_VERSION
                ),
            ));
        }
    }
    let (wavelengths_nm, params) = channels_and_parameters(manifest)?;
    let aerosol_phase = skyview::phase_from_json(field(manifest, "aerosol_phase_function")?)?;
    let n = wavelengths_nm.len();
    let rgb = field(manifest, "request.form").ok().and_then(Value::as_str) == Some("rgb");
    let transmittance = texture(manifest, "transmittance", read)?;
    let rayleigh = texture(manifest, "rayleigh", read)?;
    let mie = texture(manifest, "mie", read)?;
    let scale = texture(manifest, "scale", read)?;
    let irradiance = texture(manifest, "irradiance", read)?;
    let view = (
        skyview::N_AZ,
        skyview::N_VIEW,
        skyview::N_ALT * skyview::N_SUN,
        n,
    );
    let nodes = (skyview::N_SUN, skyview::N_ALT, 1);
    let shape = |t: &Texture| (t.width, t.height, t.depth, t.channels);
    let checks = [
        ("rayleigh", shape(&rayleigh), view),
        ("mie", shape(&mie), view),
        ("scale", shape(&scale), (nodes.0, nodes.1, nodes.2, 2 * n)),
        (
            "irradiance",
            shape(&irradiance),
            (nodes.0, nodes.1, nodes.2, n),
        ),
        (
            "transmittance",
            shape(&transmittance),
            (TRANSMITTANCE_WIDTH, TRANSMITTANCE_HEIGHT, 1, n),
        ),
    ];
    for (name, got, want) in checks {
        if got != want {
            return Err(Error::invalid(
                "manifest",
                format!(
                    "textures.{name} is {}×{}×{} with {} channels; this layout needs {}×{}×{} with {}",
                    got.0, got.1, got.2, got.3, want.0, want.1, want.2, want.3
                ),
            ));
        }
    }
    Ok(SkyViewBundle {
        channels: if rgb {
            Channels::Rgb
        } else {
            Channels::Spectral
        },
        wavelengths_nm,
        params,
        aerosol_phase,
        transmittance,
        rayleigh,
        mie,
        scale,
        irradiance,
        timing_ms: [0.0; 4],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::manifest::manifest;
    use crate::param::*;

    fn texture(width: usize, height: usize, depth: usize, channels: usize, seed: f32) -> Texture {
        let n = width * height * depth * channels;
        Texture {
            width,
            height,
            depth,
            channels,
            sample: if channels == 4 {
                Sample::Half
            } else {
                Sample::Float
            },
            data: (0..n).map(|i| seed + (i % 977) as f32 * 0.125).collect(),
        }
    }

    fn rgb_bundle() -> Bundle {
        Bundle {
            channels: Channels::Rgb,
            wavelengths_nm: vec![680.0, 550.0, 440.0],
            params: AtmosphereParameters {
                solar_irradiance: vec![1500.0, 1850.0, 1800.0],
                sun_angular_radius: 0.00465,
                bottom_radius: 6_360_000.0,
                top_radius: 6_460_000.0,
                rayleigh_scattering: vec![5.8e-6, 1.35e-5, 3.31e-5],
                mie_scattering: vec![4.0e-6, 4.0e-6, 4.0e-6],
                mie_phase_function_g: 0.8,
                mu_s_min: -0.376,
                ground_albedo: vec![0.1, 0.1, 0.1],
            },
            transmittance: texture(TRANSMITTANCE_WIDTH, TRANSMITTANCE_HEIGHT, 1, 3, 0.5),
            scattering: texture(SCATTERING_WIDTH, SCATTERING_MU, SCATTERING_R, 4, 2.0),
            single_mie: None,
            irradiance: texture(IRRADIANCE_WIDTH, IRRADIANCE_HEIGHT, 1, 3, 7.0),
            timing_ms: [0.0; 4],
        }
    }

    /// The files as a decoder returns them: each channel a plane, in name order.
    fn decoded(t: &Texture, names: &[&str]) -> DecodedFile {
        let mut channels: Vec<(String, Vec<f32>)> = (0..t.channels)
            .map(|c| (names[c].to_string(), t.plane(c)))
            .collect();
        channels.sort_by(|a, b| a.0.cmp(&b.0));
        (t.width, t.height * t.depth, channels)
    }

    #[test]
    fn a_bundle_loads_back_from_its_manifest_and_files() {
        let b = rgb_bundle();
        let m = manifest(&b, serde_json::json!({}), "test");
        let mut read = |file: &str| -> Result<DecodedFile> {
            Ok(match file {
                "transmittance.exr" => decoded(&b.transmittance, &["R", "G", "B"]),
                "scattering.exr" => decoded(&b.scattering, &["R", "G", "B", "A"]),
                "irradiance.exr" => decoded(&b.irradiance, &["R", "G", "B"]),
                other => return Err(Error::invalid("bundle", format!("no {other}"))),
            })
        };
        let loaded = from_files(&m, &mut read).unwrap();
        assert_eq!(loaded.channels, Channels::Rgb);
        assert_eq!(loaded.wavelengths_nm, b.wavelengths_nm);
        // (JSON numbers: equal to the last digit or so.)
        let (p, q) = (&loaded.params, &b.params);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b.abs();
        let all_close = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y))
        };
        assert!(close(p.bottom_radius, q.bottom_radius) && close(p.top_radius, q.top_radius));
        assert!(close(p.mu_s_min, q.mu_s_min) && close(p.sun_angular_radius, q.sun_angular_radius));
        assert!(close(p.mie_phase_function_g, q.mie_phase_function_g));
        assert!(all_close(&p.solar_irradiance, &q.solar_irradiance));
        assert!(all_close(&p.rayleigh_scattering, &q.rayleigh_scattering));
        assert!(all_close(&p.mie_scattering, &q.mie_scattering));
        assert!(all_close(&p.ground_albedo, &q.ground_albedo));
        assert_eq!(loaded.transmittance, b.transmittance);
        assert_eq!(loaded.scattering, b.scattering);
        assert_eq!(loaded.irradiance, b.irradiance);

        // A file whose size disagrees with the manifest is refused, naming the file.
        let mut short = |file: &str| -> Result<DecodedFile> {
            let (w, h, c) = read(file)?;
            Ok(if file == "irradiance.exr" {
                (w, h - 1, c)
            } else {
                (w, h, c)
            })
        };
        let e = from_files(&m, &mut short).unwrap_err();
        assert_eq!(e.field(), "irradiance.exr", "{e}");
        // A manifest of another layout is refused.
        let mut other = m.clone();
        other["bundle_version"] = "0".into();
        assert_eq!(
            from_files(&other, &mut read).unwrap_err().field(),
            "manifest"
        );
    }

    #[test]
    fn a_skyview_bundle_loads_back_from_its_manifest_and_files() {
        use crate::skyview::{self, N_ALT, N_AZ, N_SUN, N_VIEW};
        use skybake_physics::phase::Phase;
        let b = rgb_bundle();
        let half = |t: Texture| Texture {
            sample: Sample::Half,
            ..t
        };
        let sv = SkyViewBundle {
            channels: Channels::Rgb,
            wavelengths_nm: b.wavelengths_nm.clone(),
            params: b.params.clone(),
            aerosol_phase: Phase::HenyeyGreenstein { g: 0.75 },
            transmittance: b.transmittance.clone(),
            rayleigh: half(texture(N_AZ, N_VIEW, N_ALT * N_SUN, 3, 1.0)),
            mie: half(texture(N_AZ, N_VIEW, N_ALT * N_SUN, 3, 3.0)),
            scale: texture(N_SUN, N_ALT, 1, 6, 5.0),
            irradiance: texture(N_SUN, N_ALT, 1, 3, 9.0),
            timing_ms: [0.0; 4],
        };
        let names = ["R", "G", "B"].map(String::from);
        let scale_names = [
            "rayleigh.R",
            "rayleigh.G",
            "rayleigh.B",
            "mie.R",
            "mie.G",
            "mie.B",
        ]
        .map(String::from);
        let m = skyview::manifest(
            &sv,
            &names,
            &scale_names,
            serde_json::json!({"form": "rgb"}),
            "test",
        );
        let rgb = ["R", "G", "B"];
        let mut read = |file: &str| -> Result<DecodedFile> {
            Ok(match file {
                "transmittance.exr" => decoded(&sv.transmittance, &rgb),
                skyview::RAYLEIGH_FILE => decoded(&sv.rayleigh, &rgb),
                skyview::MIE_FILE => decoded(&sv.mie, &rgb),
                skyview::SCALE_FILE => decoded(
                    &sv.scale,
                    &[
                        "rayleigh.R",
                        "rayleigh.G",
                        "rayleigh.B",
                        "mie.R",
                        "mie.G",
                        "mie.B",
                    ],
                ),
                skyview::IRRADIANCE_FILE => decoded(&sv.irradiance, &rgb),
                other => return Err(Error::invalid("bundle", format!("no {other}"))),
            })
        };
        let loaded = skyview_from_files(&m, &mut read).unwrap();
        assert_eq!(loaded.channels, Channels::Rgb);
        assert_eq!(loaded.aerosol_phase, sv.aerosol_phase);
        assert_eq!(loaded.rayleigh, sv.rayleigh);
        assert_eq!(loaded.mie, sv.mie);
        // The scale file's channels sorted by name (mie.* first) come back in manifest order.
        assert_eq!(loaded.scale, sv.scale);
        assert_eq!(loaded.irradiance, sv.irradiance);
        assert_eq!(loaded.transmittance, sv.transmittance);
        // Bruneton's loader refuses it, and this one refuses his layout, naming the manifest.
        assert_eq!(from_files(&m, &mut read).unwrap_err().field(), "manifest");
        let his = manifest(&b, serde_json::json!({}), "test");
        assert_eq!(
            skyview_from_files(&his, &mut read).unwrap_err().field(),
            "manifest"
        );
    }
}
