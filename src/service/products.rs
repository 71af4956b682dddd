//! Request → product, shared by the HTTP routes, bake jobs and (for its defaults) the CLI: parse and
//! validate the parameters into a canonical [`ProductRequest`], hash it into a cache key, compute it
//! into a spectral image (the canonical artifact that the cache stores), and render a response body
//! (`json`, `exr` or `png`) from that artifact.
//!
//! Caching choice: one artifact per product, format-independent — the tiled spectral EXR written by
//! [`crate::export`], plus an attribute `skybakeResponse` holding the JSON response *without* its big
//! arrays (the "envelope"). A `json` body is the envelope with the arrays re-read from the EXR planes
//! (f32 values, so the numbers are bit-identical to the CLI's), a `png` body is rendered from the
//! planes, and an `exr` body is the cached file itself. So a product is computed once whatever
//! formats are asked for.

use crate::atmosphere::sky::DomeTable;
use crate::engine::{DomeShape, Engine, ENGINE_VERSION};
use crate::output::{dome_png, AerialJson, DomeJson, Projection};
use crate::spec::{
    parse_f64, parse_probes, parse_usize, CommonSpec, RequestParams, MAX_AERIAL_CELLS,
    MAX_TABLE_CELLS,
};
use crate::store::{cache_key, layout, SpectralImage};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

/// Attribute holding the JSON response envelope (the response without its big arrays).
pub const ATTR_RESPONSE_JSON: &str = "skybakeResponse";
/// PNG preview height in pixels (fisheye, as the CLI's default).
pub const PNG_SIZE: usize = 512;
/// Default sky table shape (CLI and HTTP).
pub const SKY_SHAPE: DomeShape = DomeShape {
    elevation_count: 129,
    azimuth_count: 64,
};
/// Default ground table shape.
pub const GROUND_SHAPE: DomeShape = DomeShape {
    elevation_count: 65,
    azimuth_count: 64,
};
/// Default aerial-perspective shape.
pub const AERIAL_SHAPE: DomeShape = DomeShape {
    elevation_count: 33,
    azimuth_count: 16,
};
/// Default aerial distances per ray.
pub const AERIAL_DISTANCE_COUNT: usize = 32;
/// Default largest aerial distance, m.
pub const AERIAL_MAX_DISTANCE_M: f64 = 100_000.0;

/// The atmosphere products served under `/v1/`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProductKind {
    Sun,
    Sky,
    Ground,
    Aerial,
}

impl ProductKind {
    /// All kinds, in route order.
    pub const ALL: [ProductKind; 4] = [Self::Sun, Self::Sky, Self::Ground, Self::Aerial];

    pub fn name(self) -> &'static str {
        match self {
            Self::Sun => "sun",
            Self::Sky => "sky",
            Self::Ground => "ground",
            Self::Aerial => "aerial",
        }
    }

    /// Parses a product name (`product` member of plan and job bodies).
    pub fn parse(s: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                Error::invalid(
                    "product",
                    format!("'{s}' is not one of sun, sky, ground, aerial"),
                )
            })
    }

    /// Lowest sun elevation the product accepts, degrees: the end of astronomical twilight for
    /// every product (below it no sunlight reaches the sky; issue 14).
    pub fn min_sun_elevation_deg(self) -> f64 {
        -18.0
    }
}

/// Response body format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Format {
    Json,
    Exr,
    Png,
}

impl Format {
    pub fn content_type(self) -> &'static str {
        match self {
            Self::Json => "application/json",
            Self::Exr => "image/x-exr",
            Self::Png => "image/png",
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Json => "json",
            Self::Exr => "exr",
            Self::Png => "png",
        }
    }
}

/// A validated, canonical product request. Everything that changes the numbers is in
/// [`Self::canonical_json`]; the response format is not (it is derived from the same artifact).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProductRequest {
    pub product: ProductKind,
    pub spec: CommonSpec,
    /// Table shape (sky, ground, aerial).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shape: Option<DomeShape>,
    /// Exact directions (view zenith, view azimuth), degrees (sky, ground).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub probes: Vec<(f64, f64)>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distance_count: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_distance_m: Option<f64>,
    #[serde(skip)]
    pub format: Format,
}

fn not_for(field: &str, product: ProductKind) -> Error {
    Error::invalid(
        field,
        format!("not a parameter of the {} product", product.name()),
    )
}

impl ProductRequest {
    /// Validates `p` for `product` with the CLI's defaults (sky 129×64, ground 65×64, aerial
    /// 33×16×32 up to 100 km; format json). Parameters that do not apply to the product are refused.
    pub fn from_params(product: ProductKind, p: &RequestParams) -> Result<Self> {
        let spec = CommonSpec::from_params(p, product.min_sun_elevation_deg())?;
        let format = match p.format.as_deref().map(str::trim) {
            None | Some("json") => Format::Json,
            Some("exr") if product != ProductKind::Sun => Format::Exr,
            Some("png") if matches!(product, ProductKind::Sky | ProductKind::Ground) => Format::Png,
            Some(other) => {
                let allowed = match product {
                    ProductKind::Sun => "json",
                    ProductKind::Aerial => "json, exr",
                    _ => "json, exr, png",
                };
                return Err(Error::invalid(
                    "format",
                    format!(
                        "'{other}' is not a format of the {} product (allowed: {allowed})",
                        product.name()
                    ),
                ));
            }
        };
        let count = |field: &str, v: &Option<String>, default: usize| -> Result<usize> {
            v.as_deref()
                .map(|v| {
                    parse_usize(
                        field,
                        v,
                        if field == "elevation_count" { 2 } else { 1 },
                        4096,
                    )
                })
                .transpose()
                .map(|o| o.unwrap_or(default))
        };
        let mut req = Self {
            product,
            spec,
            shape: None,
            probes: Vec::new(),
            distance_count: None,
            max_distance_m: None,
            format,
        };
        match product {
            ProductKind::Sun => {
                for (name, v) in [
                    ("elevation_count", &p.elevation_count),
                    ("azimuth_count", &p.azimuth_count),
                    ("distance_count", &p.distance_count),
                    ("max_distance_m", &p.max_distance_m),
                    ("probe", &p.probe),
                ] {
                    if v.is_some() {
                        return Err(not_for(name, product));
                    }
                }
            }
            ProductKind::Sky | ProductKind::Ground => {
                for (name, v) in [
                    ("distance_count", &p.distance_count),
                    ("max_distance_m", &p.max_distance_m),
                ] {
                    if v.is_some() {
                        return Err(not_for(name, product));
                    }
                }
                let d = if product == ProductKind::Sky {
                    SKY_SHAPE
                } else {
                    GROUND_SHAPE
                };
                let shape = DomeShape {
                    elevation_count: count(
                        "elevation_count",
                        &p.elevation_count,
                        d.elevation_count,
                    )?,
                    azimuth_count: count("azimuth_count", &p.azimuth_count, d.azimuth_count)?,
                };
                let cells = shape.elevation_count * shape.azimuth_count;
                if cells > MAX_TABLE_CELLS {
                    return Err(Error::too_large(
                        "elevation_count",
                        format!("{cells} table cells (elevations × azimuths)"),
                        MAX_TABLE_CELLS,
                    ));
                }
                req.shape = Some(shape);
                req.probes = p
                    .probe
                    .as_deref()
                    .map(parse_probes)
                    .transpose()?
                    .unwrap_or_default();
                if product == ProductKind::Ground {
                    if let Some(&(vz, _)) = req.probes.iter().find(|(vz, _)| *vz < 90.0) {
                        return Err(Error::out_of_range(
                            "probe",
                            vz,
                            "90 to 180 deg view zenith (ground looks down)",
                        ));
                    }
                }
            }
            ProductKind::Aerial => {
                if p.probe.is_some() {
                    return Err(not_for("probe", product));
                }
                let shape = DomeShape {
                    elevation_count: count(
                        "elevation_count",
                        &p.elevation_count,
                        AERIAL_SHAPE.elevation_count,
                    )?,
                    azimuth_count: count(
                        "azimuth_count",
                        &p.azimuth_count,
                        AERIAL_SHAPE.azimuth_count,
                    )?,
                };
                let n_d = count("distance_count", &p.distance_count, AERIAL_DISTANCE_COUNT)?;
                let cells = shape.elevation_count * shape.azimuth_count * n_d;
                if cells > MAX_AERIAL_CELLS {
                    return Err(Error::too_large(
                        "distance_count",
                        format!("{cells} cells (elevations × azimuths × distances)"),
                        MAX_AERIAL_CELLS,
                    ));
                }
                req.shape = Some(shape);
                req.distance_count = Some(n_d);
                req.max_distance_m = Some(
                    p.max_distance_m
                        .as_deref()
                        .map(|v| parse_f64("max_distance_m", v, 1.0, 1.0e7, "m"))
                        .transpose()?
                        .unwrap_or(AERIAL_MAX_DISTANCE_M),
                );
            }
        }
        // Samples of the EXR artifact (spectral layers + RGB) must fit the store's image limits.
        let pixels = req.pixel_count();
        let planes =
            req.spec.wavelengths_nm.len() * if product == ProductKind::Aerial { 2 } else { 1 } + 3;
        if pixels.saturating_mul(planes) > crate::store::spectral_image::MAX_TOTAL_SAMPLES {
            return Err(Error::too_large(
                "wavelengths",
                format!("{} samples in the product", pixels * planes),
                crate::store::spectral_image::MAX_TOTAL_SAMPLES,
            ));
        }
        Ok(req)
    }

    /// Checks that the product fits one cache artifact: its JSON envelope (probes included) must
    /// fit one EXR attribute. The service calls this; the CLI, which writes no artifact, need not.
    pub fn check_cacheable(&self) -> Result<()> {
        let probe_values = self.probes.len() * self.spec.wavelengths_nm.len();
        if probe_values > MAX_PROBE_VALUES {
            return Err(Error::too_large(
                "probe",
                format!("{probe_values} values (directions × wavelengths)"),
                MAX_PROBE_VALUES,
            ));
        }
        Ok(())
    }

    fn pixel_count(&self) -> usize {
        match (self.shape, self.distance_count) {
            (Some(s), Some(d)) => s.elevation_count * s.azimuth_count * d,
            (Some(s), None) => s.elevation_count * s.azimuth_count,
            _ => 1,
        }
    }

    /// The canonical spec JSON (product, resolved atmosphere, wavelengths, sun, shape, probes…).
    pub fn canonical_json(&self) -> String {
        // Serialising plain data structs cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }

    /// The cache key: blake3 of the canonical spec and the engine version.
    pub fn cache_key(&self) -> String {
        cache_key(&self.canonical_json(), ENGINE_VERSION)
    }

    /// Rough cost in engine work units, for the plan response (table cells × wavelengths).
    pub fn work_cells(&self) -> usize {
        (self.pixel_count() + self.probes.len()) * self.spec.wavelengths_nm.len()
    }

    /// Computes the product and returns its canonical artifact (spectral image with the JSON
    /// envelope). CPU-heavy: call from a blocking thread.
    pub fn compute(&self, engine: &Engine) -> Result<SpectralImage> {
        let spec = &self.spec;
        let mut envelope;
        let mut image = match self.product {
            ProductKind::Sun => {
                let p = engine.sun(spec)?;
                envelope = to_object(&p)?;
                let t: Vec<Vec<f32>> = p.transmittance.iter().map(|&t| vec![t as f32]).collect();
                let mut img = SpectralImage::new(1, 1, &p.wavelengths_nm)?;
                img.add_layer(layout::TRANSMITTANCE_LAYER, t)?;
                let error_json = serde_json::to_string(&p.meta.error_estimate).unwrap_or_default();
                img.set_product_metadata(
                    &self.canonical_json(),
                    ENGINE_VERSION,
                    &error_json,
                    p.meta.timing_ms,
                )?;
                img
            }
            ProductKind::Sky | ProductKind::Ground => {
                let shape = self.shape.unwrap_or(SKY_SHAPE);
                let p = if self.product == ProductKind::Sky {
                    engine.sky(spec, shape, &self.probes)?
                } else {
                    engine.ground(spec, shape, &self.probes)?
                };
                envelope = to_object(&DomeJson::new(self.product.name(), &p, spec))?;
                envelope.remove("radiance_w_m2_sr_nm");
                crate::export::dome_image(&p, spec, self.product.name())?
            }
            ProductKind::Aerial => {
                let p = engine.aerial(
                    spec,
                    self.shape.unwrap_or(AERIAL_SHAPE),
                    self.distance_count.unwrap_or(AERIAL_DISTANCE_COUNT),
                    self.max_distance_m.unwrap_or(AERIAL_MAX_DISTANCE_M),
                )?;
                envelope = to_object(&AerialJson::new(&p, spec))?;
                envelope.remove("transmittance");
                envelope.remove("inscatter_w_m2_sr_nm");
                crate::export::aerial_image(&p, spec)?
            }
        };
        image.set_attribute("skybakeRequest", self.canonical_json())?;
        image.set_attribute(ATTR_RESPONSE_JSON, Value::Object(envelope).to_string())?;
        Ok(image)
    }
}

/// Most probe values (directions × wavelengths) per request, so the JSON envelope fits the
/// artifact's 1 MiB attribute limit.
pub const MAX_PROBE_VALUES: usize = 32_768;

fn to_object<T: Serialize>(v: &T) -> Result<Map<String, Value>> {
    match serde_json::to_value(v) {
        Ok(Value::Object(m)) => Ok(m),
        Ok(_) => Err(Error::invalid(
            "format",
            "product did not serialise to an object",
        )),
        Err(e) => Err(Error::invalid(
            "format",
            format!("JSON encoding failed: {e}"),
        )),
    }
}

fn artifact_err(what: &str) -> Error {
    Error::invalid("artifact", format!("cached artifact is malformed: {what}"))
}

fn envelope(image: &SpectralImage) -> Result<Map<String, Value>> {
    let text = image
        .attribute(ATTR_RESPONSE_JSON)
        .ok_or_else(|| artifact_err("no response envelope"))?;
    match serde_json::from_str(text) {
        Ok(Value::Object(m)) => Ok(m),
        _ => Err(artifact_err("response envelope is not a JSON object")),
    }
}

fn f64_array(env: &Map<String, Value>, key: &str) -> Result<Vec<f64>> {
    env.get(key)
        .and_then(Value::as_array)
        .ok_or_else(|| artifact_err(key))?
        .iter()
        .map(|v| v.as_f64().ok_or_else(|| artifact_err(key)))
        .collect()
}

/// `[pixel][λ]` interleaved values of one spectral layer (pixels in image order).
fn interleaved(image: &SpectralImage, layer: &str) -> Result<Vec<f32>> {
    let planes = image
        .layer(layer)
        .ok_or_else(|| artifact_err(layer))?
        .planes();
    let n_l = planes.len();
    let n_px = image.pixel_count();
    let mut out = vec![0f32; n_px * n_l];
    for (i, plane) in planes.iter().enumerate() {
        for (px, v) in plane.iter().enumerate() {
            out[px * n_l + i] = *v;
        }
    }
    Ok(out)
}

/// The dome table stored in an artifact (rows back in ascending elevation).
fn dome_table(image: &SpectralImage, env: &Map<String, Value>) -> Result<DomeTable> {
    let elevation_deg = f64_array(env, "elevation_deg")?;
    let azimuth_deg = f64_array(env, "azimuth_deg")?;
    let wavelengths_nm = f64_array(env, "wavelengths_nm")?;
    let (w, h, n_l) = (image.width(), image.height(), wavelengths_nm.len());
    if w != azimuth_deg.len() || h != elevation_deg.len() || image.wavelengths_nm().len() != n_l {
        return Err(artifact_err("table axes do not match the image"));
    }
    let flipped = interleaved(image, layout::EMISSIVE_LAYER)?;
    let mut radiance = vec![0f32; w * h * n_l];
    for row in 0..h {
        let src = (h - 1 - row) * w * n_l;
        radiance[row * w * n_l..(row + 1) * w * n_l].copy_from_slice(&flipped[src..src + w * n_l]);
    }
    Ok(DomeTable {
        wavelengths_nm,
        elevation_deg,
        azimuth_deg,
        radiance,
    })
}

#[derive(Serialize)]
struct Body<'a> {
    #[serde(flatten)]
    envelope: &'a Map<String, Value>,
    #[serde(flatten)]
    arrays: Map<String, Value>,
    #[serde(skip_serializing_if = "Option::is_none")]
    radiance_w_m2_sr_nm: Option<Vec<Vec<&'a [f32]>>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    transmittance: Option<Vec<Vec<Vec<&'a [f32]>>>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    inscatter_w_m2_sr_nm: Option<Vec<Vec<Vec<&'a [f32]>>>>,
}

/// Renders a response body in `format` from the artifact `image` of a `product`.
pub fn render(product: ProductKind, format: Format, image: &SpectralImage) -> Result<Vec<u8>> {
    let env = envelope(image)?;
    let json =
        |body: &Body| serde_json::to_vec(body).map_err(|e| Error::invalid("format", e.to_string()));
    let empty = Map::new();
    let mut body = Body {
        envelope: &env,
        arrays: empty,
        radiance_w_m2_sr_nm: None,
        transmittance: None,
        inscatter_w_m2_sr_nm: None,
    };
    match (product, format) {
        (ProductKind::Sun, Format::Json) => json(&body),
        (ProductKind::Sky | ProductKind::Ground, Format::Json) => {
            if !env.contains_key("elevation_deg") {
                return json(&body); // probe request: the envelope is the whole response
            }
            let t = dome_table(image, &env)?;
            let n_l = t.wavelengths_nm.len();
            let rows: Vec<Vec<&[f32]>> = t
                .radiance
                .chunks(t.azimuth_deg.len() * n_l)
                .map(|row| row.chunks(n_l).collect())
                .collect();
            body.radiance_w_m2_sr_nm = Some(rows);
            json(&body)
        }
        (ProductKind::Sky | ProductKind::Ground, Format::Png) => {
            if !env.contains_key("elevation_deg") {
                return Err(Error::invalid(
                    "format",
                    "png needs the table: leave out probe for a PNG preview",
                ));
            }
            dome_png(&dome_table(image, &env)?, Projection::Fisheye, PNG_SIZE)
        }
        (ProductKind::Aerial, Format::Json) => {
            let n_az = f64_array(&env, "azimuth_deg")?.len();
            let n_d = f64_array(&env, "distance_m")?.len();
            let n_l = image.wavelengths_nm().len();
            if n_az == 0 || n_d == 0 || n_l == 0 {
                return Err(artifact_err("empty aerial axes"));
            }
            let s0 = interleaved(image, layout::EMISSIVE_LAYER)?;
            let t = interleaved(image, layout::TRANSMITTANCE_LAYER)?;
            body.transmittance = Some(crate::output::nest4(&t, n_az, n_d, n_l));
            body.inscatter_w_m2_sr_nm = Some(crate::output::nest4(&s0, n_az, n_d, n_l));
            json(&body)
        }
        (_, Format::Exr) => {
            crate::store::encode_exr(image).map_err(|e| artifact_err(&e.to_string()))
        }
        (p, f) => Err(Error::invalid(
            "format",
            format!("'{}' is not a format of the {} product", f.name(), p.name()),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> RequestParams {
        let v: Map<String, Value> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), Value::String(v.to_string())))
            .collect();
        serde_json::from_value(Value::Object(v)).unwrap()
    }

    #[test]
    fn defaults_match_the_cli() {
        let sky = ProductRequest::from_params(ProductKind::Sky, &params(&[])).unwrap();
        assert_eq!(sky.shape, Some(SKY_SHAPE));
        let ground = ProductRequest::from_params(ProductKind::Ground, &params(&[])).unwrap();
        assert_eq!(ground.shape, Some(GROUND_SHAPE));
        let aerial = ProductRequest::from_params(ProductKind::Aerial, &params(&[])).unwrap();
        assert_eq!(aerial.shape, Some(AERIAL_SHAPE));
        assert_eq!(aerial.distance_count, Some(32));
        assert_eq!(aerial.max_distance_m, Some(100_000.0));
        assert_eq!(sky.format, Format::Json);
    }

    #[test]
    fn key_ignores_format_but_not_numbers() {
        let a = ProductRequest::from_params(ProductKind::Sky, &params(&[("format", "exr")]));
        let b = ProductRequest::from_params(ProductKind::Sky, &params(&[("format", "png")]));
        let c = ProductRequest::from_params(ProductKind::Ground, &params(&[]));
        let d = ProductRequest::from_params(ProductKind::Sky, &params(&[("ground_albedo", "0.2")]));
        let (a, b, c, d) = (a.unwrap(), b.unwrap(), c.unwrap(), d.unwrap());
        assert_eq!(a.cache_key(), b.cache_key());
        assert_ne!(a.cache_key(), c.cache_key());
        assert_ne!(a.cache_key(), d.cache_key());
    }

    #[test]
    fn misplaced_parameters_are_named() {
        let cases = [
            (ProductKind::Sun, "probe", "30:0"),
            (ProductKind::Sun, "format", "exr"),
            (ProductKind::Aerial, "format", "png"),
            (ProductKind::Sky, "distance_count", "3"),
            (ProductKind::Ground, "probe", "30:0"),
            (ProductKind::Sky, "elevation_count", "1"),
            (ProductKind::Sky, "elevation_count", "5000"),
            (ProductKind::Aerial, "distance_count", "4096"),
        ];
        for (kind, k, v) in cases {
            let e = ProductRequest::from_params(kind, &params(&[(k, v)])).unwrap_err();
            assert_eq!(e.field(), k, "{kind:?} {k}={v}: {e}");
        }
    }

    #[test]
    fn json_from_the_artifact_equals_the_cli_json() {
        let engine = Engine::new();
        let p = params(&[
            ("method", "fast"),
            ("quality", "draft"),
            ("wavelengths", "440,550,680"),
            ("elevation_count", "9"),
            ("azimuth_count", "5"),
        ]);
        let req = ProductRequest::from_params(ProductKind::Sky, &p).unwrap();
        let image = req.compute(&engine).unwrap();
        // Round trip through the EXR file, as the cache does.
        let bytes = crate::store::encode_exr(&image).unwrap();
        let image = crate::store::decode_exr(&bytes).unwrap();
        let served: Value =
            serde_json::from_slice(&render(ProductKind::Sky, Format::Json, &image).unwrap())
                .unwrap();
        let product = engine.sky(&req.spec, req.shape.unwrap(), &[]).unwrap();
        // Compare as the CLI prints it (text), parsed the same way.
        let cli: Value = serde_json::from_str(
            &serde_json::to_string(&DomeJson::new("sky", &product, &req.spec)).unwrap(),
        )
        .unwrap();
        assert_eq!(served["radiance_w_m2_sr_nm"], cli["radiance_w_m2_sr_nm"]);
        assert_eq!(served["elevation_deg"], cli["elevation_deg"]);
        assert_eq!(served["spec"], cli["spec"]);
        let png = render(ProductKind::Sky, Format::Png, &image).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
