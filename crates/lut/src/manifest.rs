//! `manifest.json`: everything a client needs to load the bundle without reading our code — the
//! parameterisation, the files and their layout, units, how channels were formed from the
//! spectrum, his `AtmosphereParameters`, the request and engine version it was computed for, and
//! the stated error of each table (measured by the reader against skybake's products,
//! tests/atmosphere/lut.rs, docs/lut.md).

use serde_json::{json, Value};

use crate::build::{Bundle, Channels, Sample, Texture, UNIT_SCALE};
use crate::param::*;

/// Layout version of the bundle (bumped when a file or a field changes meaning).
pub const BUNDLE_VERSION: &str = "1";

/// File names of the bundle's textures.
pub const TRANSMITTANCE_FILE: &str = "transmittance.exr";
pub const SCATTERING_FILE: &str = "scattering.exr";
pub const SINGLE_MIE_FILE: &str = "single_mie_scattering.exr";
pub const IRRADIANCE_FILE: &str = "irradiance.exr";
pub const MANIFEST_FILE: &str = "manifest.json";

/// Stated error of each table: the largest relative error of what his functions compute from
/// it against skybake's own product, measured by tests/atmosphere/lut.rs (`earth`, quality
/// `standard`, RGB form, random observers, views and suns; docs/lut.md has every band).
pub const STATED_ERRORS: &[(&str, &str, f64)] = &[
    ("transmittance", "direct normal irradiance (sun product), sun >= 5 deg, 0-100 km", 0.0001),
    ("transmittance", "direct normal irradiance (sun product), sun -6..5 deg", 0.004),
    ("scattering", "sky radiance (sky product), ground observer, sun >= 5 deg, view > 10 deg above the horizon", 0.11),
    ("scattering", "sky radiance (sky product), ground observer, sun >= 5 deg, view < 10 deg above the horizon", 0.075),
    ("scattering", "sky radiance (sky product), observer 0-20 km, sun >= 5 deg", 0.08),
    ("scattering", "sky radiance (sky product), sun -6..5 deg, 0-20 km", 0.20),
    ("scattering", "sky radiance (sky product), sun -12..-6 deg, 0-100 km", 1.54),
    ("irradiance", "diffuse horizontal irradiance (sun product), ground, sun >= 5 deg", 0.003),
    ("irradiance", "diffuse horizontal irradiance (sun product), observer aloft (rows linear in altitude), sun >= 5 deg", 0.31),
];

fn sample_name(s: Sample) -> &'static str {
    match s {
        Sample::Half => "half",
        Sample::Float => "float",
    }
}

fn texture_entry(t: &Texture, file: &str, channels: &[String], what: &str) -> Value {
    json!({
        "file": file,
        "width": t.width,
        "height": t.height,
        "depth": t.depth,
        "sample": sample_name(t.sample),
        "channels": channels,
        "content": what,
    })
}

/// The manifest of `bundle`, computed for the canonical request `request` (a JSON object).
pub fn manifest(bundle: &Bundle, request: Value, engine_version: &str) -> Value {
    let rgb = bundle.channels == Channels::Rgb;
    let names: Vec<String> = if rgb {
        vec!["R".into(), "G".into(), "B".into()]
    } else {
        bundle
            .wavelengths_nm
            .iter()
            .map(|w| skybake_physics::image::layout::format_wavelength_nm(*w))
            .collect()
    };
    let channels: Vec<Value> = names
        .iter()
        .zip(&bundle.wavelengths_nm)
        .map(|(n, w)| json!({"name": n, "wavelength_nm": w}))
        .collect();
    let p = &bundle.params;
    let mut textures = serde_json::Map::new();
    textures.insert(
        "transmittance".into(),
        texture_entry(
            &bundle.transmittance,
            TRANSMITTANCE_FILE,
            &names,
            "transmittance to the top of the atmosphere, (u, v) = GetTransmittanceTextureUvFromRMu(r, mu)",
        ),
    );
    let sc_names = if rgb {
        let mut v = names.clone();
        v.push("A".into());
        v
    } else {
        names.clone()
    };
    textures.insert(
        "scattering".into(),
        texture_entry(
            &bundle.scattering,
            SCATTERING_FILE,
            &sc_names,
            if rgb {
                "combined layout: RGB = single Rayleigh scattering without its phase function + multiple scattering divided by RayleighPhaseFunction(nu); A = single Mie scattering of R divided by MiePhaseFunction(g, nu)"
            } else {
                "single Rayleigh scattering without its phase function + multiple scattering divided by RayleighPhaseFunction(nu)"
            },
        ),
    );
    if let Some(mie) = &bundle.single_mie {
        textures.insert(
            "single_mie_scattering".into(),
            texture_entry(
                mie,
                SINGLE_MIE_FILE,
                &names,
                "single Mie scattering divided by MiePhaseFunction(g, nu) (non-combined layout)",
            ),
        );
    }
    textures.insert(
        "irradiance".into(),
        texture_entry(
            &bundle.irradiance,
            IRRADIANCE_FILE,
            &names,
            "sky (indirect) irradiance on a horizontal surface, (u, v) = GetIrradianceTextureUvFromRMuS(r, mu_s); the sun's direct irradiance is computed from the transmittance texture",
        ),
    );
    json!({
        "format": "bruneton2017",
        "bundle_version": BUNDLE_VERSION,
        "software": concat!("skybake ", env!("CARGO_PKG_VERSION")),
        "engine_version": engine_version,
        "request": request,
        "mode": "radiance",
        "channels": channels,
        "channel_formation": if rgb {
            "each channel is the spectral quantity at its wavelength (Bruneton's radiance mode at his 680, 550, 440 nm), not a band average or a colour-space conversion"
        } else {
            "one channel per requested wavelength (the spectral OpenEXR layout's channel names)"
        },
        "units": {
            "length": "m",
            "radiance": "mW m^-2 sr^-1 nm^-1",
            "irradiance": "mW m^-2 nm^-1",
            "texture_value_per_watt": UNIT_SCALE,
        },
        "parameterisation": {
            "reference": "Bruneton 2017, Precomputed Atmospheric Scattering: a New Implementation (functions.glsl)",
            "transmittance_texture": [TRANSMITTANCE_WIDTH, TRANSMITTANCE_HEIGHT],
            "scattering_texture_nu_mu_s_mu_r": [SCATTERING_NU, SCATTERING_MU_S, SCATTERING_MU, SCATTERING_R],
            "irradiance_texture": [IRRADIANCE_WIDTH, IRRADIANCE_HEIGHT],
            "combined_scattering_textures": rgb,
            "file_rows": "row 0 of every file is texture coordinate v = 0.5/height (upload rows in file order); the 3-D scattering texture's r slices are stacked vertically: file row = r_index * 128 + mu_index, column = nu_index * 32 + mu_s_index",
        },
        "atmosphere_parameters": p,
        "sun": {
            "angular_radius_rad": p.sun_angular_radius,
            "radiance": "solar_irradiance / (pi * sun_angular_radius^2) per channel, times the transmittance to the sun, inside the disk",
        },
        "textures": textures,
        "stated_error": STATED_ERRORS.iter().map(|(t, what, e)| json!({"table": t, "measure": what, "max_relative_error": e})).collect::<Vec<_>>(),
    })
}
