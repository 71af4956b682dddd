//! `skybake lut-eval DIR QUERIES`: evaluates a texture bundle written by `skybake lut` (or
//! downloaded from `GET /v1/lut`) with the reference reader of its layout (the manifest's
//! `format`): for `bruneton2017`, Bruneton 2017's `GetSkyRadiance`, `GetSkyRadianceToPoint`
//! and `GetSunAndSkyIrradiance` (crates/lut/src/reader.rs); for `skyview`, the same three
//! functions on skybake's second layout (`SkyViewReader`, crates/lut/src/skyview.rs); at the
//! queries of a JSON file; prints the values. What a port of the shader is checked against
//! (docs/lut.md; the viewer's WebGL clients are, by tools/browser/lut_test.mjs).

use std::path::Path;

use serde_json::{json, Value};
use skybake_lut::load::{self, from_files, skyview_from_files, DecodedFile};
use skybake_lut::manifest::MANIFEST_FILE;
use skybake_lut::{Bundle, Reader, SkyViewBundle, SkyViewReader};
use skybake_physics::Error;

use crate::error::{CliError, Result};
use crate::io::{print_json, read_input, read_input_bytes};

/// Most queries one call evaluates.
const MAX_QUERIES: usize = 1_000_000;

fn vector(q: &Value, i: usize, name: &str, unit: bool) -> Result<[f64; 3]> {
    let field = format!("queries[{i}].{name}");
    let v: Vec<f64> = q
        .get(name)
        .and_then(Value::as_array)
        .map(|a| a.iter().filter_map(Value::as_f64).collect())
        .unwrap_or_default();
    if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
        return Err(Error::invalid(&field, "must be a list of 3 finite numbers").into());
    }
    let mut v = [v[0], v[1], v[2]];
    if unit {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n < 1e-9 {
            return Err(Error::invalid(&field, "must be a non-zero direction").into());
        }
        v = [v[0] / n, v[1] / n, v[2] / n];
    }
    Ok(v)
}

/// A bundle of either layout, loaded from its files.
enum Loaded {
    Bruneton(Bundle),
    SkyView(SkyViewBundle),
}

/// Its reader: the same three functions on either layout.
enum AnyReader<'a> {
    Bruneton(Reader<'a>),
    SkyView(SkyViewReader<'a>),
}

type Vec3 = [f64; 3];
type Pair = (Vec<f64>, Vec<f64>);

impl AnyReader<'_> {
    fn sky_radiance(&self, camera: Vec3, view: Vec3, sun: Vec3) -> Pair {
        match self {
            Self::Bruneton(r) => r.sky_radiance(camera, view, sun),
            Self::SkyView(r) => r.sky_radiance(camera, view, sun),
        }
    }

    fn sky_radiance_to_point(&self, camera: Vec3, point: Vec3, sun: Vec3) -> Pair {
        match self {
            Self::Bruneton(r) => r.sky_radiance_to_point(camera, point, sun),
            Self::SkyView(r) => r.sky_radiance_to_point(camera, point, sun),
        }
    }

    fn sun_and_sky_irradiance(&self, point: Vec3, normal: Vec3, sun: Vec3) -> Pair {
        match self {
            Self::Bruneton(r) => r.sun_and_sky_irradiance(point, normal, sun),
            Self::SkyView(r) => r.sun_and_sky_irradiance(point, normal, sun),
        }
    }
}

/// Evaluates the queries of `queries_path` on the bundle in `dir` and prints the results.
pub fn lut_eval(dir: &Path, queries_path: &Path) -> Result<()> {
    let manifest: Value = serde_json::from_str(&read_input(&dir.join(MANIFEST_FILE), "bundle")?)
        .map_err(|e| Error::invalid("bundle", format!("{MANIFEST_FILE} is not JSON: {e}")))?;
    let mut failure: Option<CliError> = None;
    let mut read = |file: &str| -> skybake_lut::Result<DecodedFile> {
        let bytes = read_input_bytes(&dir.join(file), "bundle").map_err(|e| {
            let msg = format!("{e:?}");
            failure = Some(e);
            Error::invalid("bundle", msg)
        })?;
        skybake_store::texture::decode_texture_exr(&bytes)
            .map_err(|e| Error::invalid("bundle", format!("{file}: {e}")))
    };
    let loaded = match load::format(&manifest).and_then(|f| match f {
        "bruneton2017" => from_files(&manifest, &mut read).map(Loaded::Bruneton),
        "skyview" => skyview_from_files(&manifest, &mut read).map(Loaded::SkyView),
        other => Err(Error::invalid(
            "manifest",
            format!("`format` '{other}' is not one of bruneton2017, skyview"),
        )),
    }) {
        Ok(b) => b,
        Err(e) => return Err(failure.unwrap_or(e.into())),
    };
    let (reader, params, wavelengths_nm) = match &loaded {
        Loaded::Bruneton(b) => (
            AnyReader::Bruneton(Reader::new(b)),
            &b.params,
            &b.wavelengths_nm,
        ),
        Loaded::SkyView(b) => (
            AnyReader::SkyView(SkyViewReader::new(b)),
            &b.params,
            &b.wavelengths_nm,
        ),
    };
    let queries: Value = serde_json::from_str(&read_input(queries_path, "queries")?)
        .map_err(|e| Error::invalid("queries", format!("not JSON: {e}")))?;
    let list = queries
        .get("queries")
        .and_then(Value::as_array)
        .ok_or_else(|| Error::invalid("queries", "must be an object with a `queries` list"))?;
    if list.len() > MAX_QUERIES {
        return Err(Error::too_large("queries", list.len(), MAX_QUERIES).into());
    }
    let (bottom, top) = (params.bottom_radius, params.top_radius);
    let mut results = Vec::with_capacity(list.len());
    for (i, q) in list.iter().enumerate() {
        let function = q.get("function").and_then(Value::as_str).unwrap_or("");
        let above_ground = |p: [f64; 3], name: &str| -> Result<[f64; 3]> {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            // (A point computed on the ground may round a nanometre below it.)
            if r < bottom * (1.0 - 1e-9) {
                return Err(Error::out_of_range(
                    &format!("queries[{i}].{name}"),
                    format!("radius {r} m"),
                    format!("≥ bottom_radius {bottom} m (positions from the planet's centre)"),
                )
                .into());
            }
            Ok(p)
        };
        let result = match function {
            "sky_radiance" => {
                let camera = above_ground(vector(q, i, "camera", false)?, "camera")?;
                let (l, t) =
                    reader.sky_radiance(camera, vector(q, i, "view", true)?, vector(q, i, "sun", true)?);
                json!({"radiance": l, "transmittance": t})
            }
            "sky_radiance_to_point" => {
                let camera = above_ground(vector(q, i, "camera", false)?, "camera")?;
                let point = above_ground(vector(q, i, "point", false)?, "point")?;
                let d = (0..3).map(|k| (point[k] - camera[k]).powi(2)).sum::<f64>();
                if d < 1e-6 {
                    return Err(Error::invalid(
                        &format!("queries[{i}].point"),
                        "must differ from the camera",
                    )
                    .into());
                }
                let (l, t) = reader.sky_radiance_to_point(camera, point, vector(q, i, "sun", true)?);
                json!({"radiance": l, "transmittance": t})
            }
            "sun_and_sky_irradiance" => {
                let point = above_ground(vector(q, i, "point", false)?, "point")?;
                let r = (point[0] * point[0] + point[1] * point[1] + point[2] * point[2]).sqrt();
                if r > top {
                    return Err(Error::out_of_range(
                        &format!("queries[{i}].point"),
                        format!("radius {r} m"),
                        format!("≤ top_radius {top} m (the irradiance texture's range)"),
                    )
                    .into());
                }
                let (sun, sky) = reader.sun_and_sky_irradiance(
                    point,
                    vector(q, i, "normal", true)?,
                    vector(q, i, "sun", true)?,
                );
                json!({"sun_irradiance": sun, "sky_irradiance": sky})
            }
            other => {
                return Err(Error::invalid(
                    &format!("queries[{i}].function"),
                    format!(
                        "'{other}' is not one of sky_radiance, sky_radiance_to_point, sun_and_sky_irradiance"
                    ),
                )
                .into())
            }
        };
        results.push(result);
    }
    print_json(&json!({
        "format": load::format(&manifest)?,
        "wavelengths_nm": wavelengths_nm,
        "units": manifest.get("units"),
        "results": results,
    }))
}
