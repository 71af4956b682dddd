//! The product artifact: the one format a product is kept in, whoever asked for it. The tiled
//! spectral EXR image ([`crate::export`]) plus header attributes: `skybakeSpec` (the canonical
//! request), `skybakeResponse` (the JSON response without its big arrays and without timing, the
//! "envelope"), `skybakePlan`, the error estimate, the engine version, and the timing attributes
//! ([`TIMING_ATTRIBUTES`]: compute time, whether the shared tables were warm), the only ones that
//! differ between two computations of the same request.
//!
//! A `json` body is the envelope with the arrays re-read from the EXR planes (f32 values, so the
//! numbers are bit-identical whoever computed them) and the timing put back; a `png` body is
//! rendered from the planes; an `exr` body is the artifact file itself. A malformed artifact is an
//! [`Error::Internal`] (a server fault), never a request error.

use super::{Format, ProductKind, ProductRequest};
use crate::{Error, Result};
use serde::Serialize;
use serde_json::{Map, Value};
use skybake_engine::engine::{Engine, Product, ENGINE_VERSION};
use skybake_engine::output::{dome_png, AerialJson, DomeJson, Projection};
use skybake_physics::atmosphere::sky::DomeTable;
use skybake_render::{Frame, FrameMeta};
use skybake_store::{layout, SpectralImage};

/// Attribute holding the JSON response envelope (the response without its big arrays).
pub const ATTR_RESPONSE_JSON: &str = "skybakeResponse";
/// Attribute: "1" when the shared tables were already built when the product was computed, else "0".
pub const ATTR_TABLES_WARM: &str = "skybakeTablesWarm";
/// The attributes that change from one computation of a request to the next.
pub const TIMING_ATTRIBUTES: [&str; 2] = [layout::ATTR_COMPUTE_TIME_MS, ATTR_TABLES_WARM];
/// PNG preview height in pixels (fisheye, as the CLI's default).
pub const PNG_SIZE: usize = 512;

impl ProductRequest {
    /// Computes the product (the engine plans and executes) and returns its artifact.
    /// CPU-heavy: call from a blocking thread.
    pub fn compute(&self, engine: &Engine) -> Result<SpectralImage> {
        self.compute_cancellable(engine, &|| false)
    }

    /// [`Self::compute`], stopped with [`Error::Cancelled`] at the engine's next stage boundary
    /// once `cancelled` returns true (nobody wants the result any more).
    pub fn compute_cancellable(
        &self,
        engine: &Engine,
        cancelled: skybake_engine::engine::CancelCheck,
    ) -> Result<SpectralImage> {
        let plan = self.plan()?;
        let product = engine.execute_cancellable(&self.spec, &self.product, &plan, cancelled)?;
        let spec = &self.spec;
        let name = self.kind().name();
        let (mut image, mut envelope) = match &product {
            Product::Sun(p) => (crate::export::sun_image(p)?, to_object(p)?),
            Product::Sky(p) | Product::Ground(p) => {
                let mut env = to_object(&DomeJson::new(name, p, spec))?;
                env.remove("radiance_w_m2_sr_nm");
                (crate::export::dome_image(p)?, env)
            }
            Product::Aerial(p) => {
                let mut env = to_object(&AerialJson::new(p, spec))?;
                env.remove("transmittance");
                env.remove("inscatter_w_m2_sr_nm");
                (crate::export::aerial_image(p)?, env)
            }
        };
        // Timing lives in its own attributes, so the rest of the artifact is a pure function of
        // the request.
        envelope.remove("timing_ms");
        if let Some(Value::Object(meta)) = envelope.get_mut("meta") {
            meta.remove("timing_ms");
            meta.remove("shared_tables_warm");
        }
        let meta = product.meta();
        let canonical = self.canonical_json();
        let error_json = to_json(&meta.error_estimate)?;
        image.set_product_metadata(&canonical, ENGINE_VERSION, &error_json, meta.timing_ms)?;
        image.set_attribute(layout::ATTR_PLAN_JSON, to_json(&meta.plan)?)?;
        // One byte either way, like the fixed-width compute time: timing never moves other bytes.
        image.set_attribute(
            ATTR_TABLES_WARM,
            if meta.shared_tables_warm { "1" } else { "0" },
        )?;
        image.set_attribute(ATTR_RESPONSE_JSON, Value::Object(envelope).to_string())?;
        // The artifact carries its cache key wherever it is written (CLI, service, bake), so the
        // cache can tell a file under another key's name (store::Cache::get).
        image.set_attribute(layout::ATTR_CACHE_KEY, self.cache_key())?;
        Ok(image)
    }
}

fn to_json<T: Serialize>(v: &T) -> Result<String> {
    serde_json::to_string(v).map_err(|e| Error::internal("artifact", format!("JSON encoding: {e}")))
}

/// The timing of an artifact (compute time in ms, tables warm) for the JSON body.
fn timing(image: &SpectralImage) -> Result<(f64, bool)> {
    let ms = image
        .attribute(layout::ATTR_COMPUTE_TIME_MS)
        .and_then(|t| t.parse::<f64>().ok())
        .ok_or_else(|| artifact_err("no compute time"))?;
    // "true" in artifacts written before the value became one byte.
    let warm = matches!(image.attribute(ATTR_TABLES_WARM), Some("1" | "true"));
    Ok((ms, warm))
}

fn to_object<T: Serialize>(v: &T) -> Result<Map<String, Value>> {
    match serde_json::to_value(v) {
        Ok(Value::Object(m)) => Ok(m),
        Ok(_) => Err(Error::internal(
            "artifact",
            "product did not serialise to an object",
        )),
        Err(e) => Err(Error::internal(
            "artifact",
            format!("JSON encoding failed: {e}"),
        )),
    }
}

fn artifact_err(what: &str) -> Error {
    Error::internal("artifact", format!("the artifact is malformed: {what}"))
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

/// The sky or ground table stored in an artifact (for previews in other projections).
pub fn dome_table_of(image: &SpectralImage) -> Result<DomeTable> {
    let env = envelope(image)?;
    if !env.contains_key("elevation_deg") {
        return Err(Error::invalid(
            "format",
            "png needs the table: leave out probe for a PNG preview",
        ));
    }
    dome_table(image, &env)
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
    let mut env = envelope(image)?;
    if format == Format::Json {
        let (ms, warm) = timing(image)?;
        env.insert("timing_ms".into(), Value::from(ms));
        if let Some(Value::Object(meta)) = env.get_mut("meta") {
            meta.insert("timing_ms".into(), Value::from(ms));
            meta.insert("shared_tables_warm".into(), Value::from(warm));
        }
    }
    let env = env;
    let json = |body: &Body| {
        serde_json::to_vec(body).map_err(|e| Error::internal("artifact", e.to_string()))
    };
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
        (ProductKind::Sky | ProductKind::Ground, Format::Png | Format::PngLatlong) => {
            if !env.contains_key("elevation_deg") {
                // Requests refuse png with probes, so a probe artifact never gets here.
                return Err(Error::invalid(
                    "format",
                    "png needs the table: leave out probe for a PNG preview",
                ));
            }
            let projection = if format == Format::Png {
                Projection::Fisheye
            } else {
                Projection::LatLong
            };
            dome_png(&dome_table(image, &env)?, projection, PNG_SIZE)
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
            body.transmittance = Some(skybake_engine::output::nest4(&t, n_az, n_d, n_l));
            body.inscatter_w_m2_sr_nm = Some(skybake_engine::output::nest4(&s0, n_az, n_d, n_l));
            json(&body)
        }
        (_, Format::Exr) => {
            skybake_store::encode_exr(image).map_err(|e| artifact_err(&e.to_string()))
        }
        (p, f) => Err(Error::invalid(
            "format",
            format!("'{}' is not a format of the {} product", f.name(), p.name()),
        )),
    }
}

/// Header attribute of the assembled frame: how many tiles there are, how many this run
/// computed and how many it took from an earlier run.
pub const ATTR_FRAME_TILES: &str = "skybakeFrameTiles";

/// Tiles of an assembled frame: how many there are, how many this run computed and how many it
/// took from an earlier run ([`ATTR_FRAME_TILES`]; members in name order, as stored).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct FrameTileCounts {
    pub computed: usize,
    pub reused: usize,
    pub tile_size: usize,
    pub total: usize,
}

/// A rendered frame's artifact: its spectral image ([`crate::export::frame_image`]) with the
/// canonical request, the engine version, the error estimate, the compute time, the stages, the
/// metadata with fixed-width timings ([`frame_meta_json`]), the cache key and the tile counts.
pub fn frame_artifact(
    frame: &Frame,
    canonical_json: &str,
    cache_key: &str,
    tiles: FrameTileCounts,
) -> Result<SpectralImage> {
    let mut image = crate::export::frame_image(frame)?;
    let meta = &frame.meta;
    let error_json = serde_json::to_string(&meta.error_estimate).unwrap_or_default();
    let total_ms: f64 = meta.timing_ms.iter().map(|(_, ms)| ms).sum();
    image.set_product_metadata(canonical_json, ENGINE_VERSION, &error_json, total_ms)?;
    image.set_attribute(
        layout::ATTR_PLAN_JSON,
        serde_json::to_string(&meta.stages).unwrap_or_default(),
    )?;
    // Timings at a fixed width, so two computations of a request (CLI, service, bake) differ
    // only in those values' bytes.
    image.set_attribute(ATTR_FRAME_META, frame_meta_json(meta)?)?;
    image.set_attribute(layout::ATTR_CACHE_KEY, cache_key)?;
    image.set_attribute(ATTR_FRAME_TILES, to_json(&tiles)?)?;
    Ok(image)
}

/// Header attribute of a frame artifact: its [`FrameMeta`] as JSON, the timings at a fixed width
/// ([`frame_meta_json`]).
pub const ATTR_FRAME_META: &str = "skybakeFrameMeta";

/// Width of a timing value in [`ATTR_FRAME_META`]: milliseconds to the microsecond, right-aligned
/// with spaces (JSON whitespace), capped at 99 999 999.999.
pub const FRAME_TIMING_WIDTH: usize = 12;

/// A frame's metadata as JSON whose `timing_ms` values all have [`FRAME_TIMING_WIDTH`] characters
/// (`["pixels",     1234.567]`), so the attribute's length and every byte outside those values
/// depend on the request only.
pub fn frame_meta_json(meta: &FrameMeta) -> Result<String> {
    fn json<T: Serialize + ?Sized>(v: &T) -> Result<String> {
        serde_json::to_string(v)
            .map_err(|e| Error::internal("frame", format!("JSON encoding: {e}")))
    }
    let text = json(&FrameMeta {
        timing_ms: Vec::new(),
        ..meta.clone()
    })?;
    let mut timings = Vec::with_capacity(meta.timing_ms.len());
    for (stage, ms) in &meta.timing_ms {
        let ms = if ms.is_finite() {
            ms.clamp(0.0, 99_999_999.999)
        } else {
            0.0
        };
        timings.push(format!(
            "[{},{:>w$.3}]",
            json(stage)?,
            ms,
            w = FRAME_TIMING_WIDTH
        ));
    }
    // `timing_ms` is serialised before the fields that hold free text (notes, plan).
    let empty = "\"timing_ms\":[]";
    if !text.contains(empty) {
        return Err(Error::internal("frame", "metadata without timing_ms"));
    }
    Ok(text.replacen(empty, &format!("\"timing_ms\":[{}]", timings.join(",")), 1))
}

/// The JSON summary of a frame artifact (`skybake render --format json`, `POST /v1/render`
/// with `format=json`): size, wavelengths, cache key, method, the stages that ran and those left
/// out, the time of each stage and in total, the error estimate and the tiles.
pub fn frame_summary(image: &SpectralImage) -> serde_json::Value {
    use serde_json::{json, Value};
    let attr = |name: &str| -> Value {
        image
            .attribute(name)
            .and_then(|t| serde_json::from_str(t).ok())
            .unwrap_or(Value::Null)
    };
    let meta = attr(ATTR_FRAME_META);
    let stages: Vec<Value> = meta["timing_ms"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|pair| json!({"stage": pair[0], "ms": pair[1]}))
                .collect()
        })
        .unwrap_or_default();
    let total_ms: f64 = stages.iter().filter_map(|s| s["ms"].as_f64()).sum();
    json!({
        "product": "frame",
        "width": image.width(),
        "height": image.height(),
        "wavelengths_nm": image.wavelengths_nm(),
        "cache_key": image.attribute(skybake_physics::image::layout::ATTR_CACHE_KEY),
        "method": meta["method"],
        "stages": meta["stages"],
        "plan": meta["plan"],
        "timing_ms": total_ms,
        "timing_ms_by_stage": stages,
        "error_estimate": meta["error_estimate"],
        "lighting_notes": meta["lighting_notes"],
        "tiles": attr(ATTR_FRAME_TILES),
    })
}

/// A frame's response body in `format`, rendered from its artifact: the EXR itself, the
/// tone-mapped PNG of its RGB planes, or its JSON summary ([`frame_summary`]).
pub fn render_frame(format: Format, image: &SpectralImage) -> Result<Vec<u8>> {
    match format {
        Format::Exr => skybake_store::encode_exr(image).map_err(|e| artifact_err(&e.to_string())),
        Format::Png => {
            let rgb = image
                .rgb()
                .ok_or_else(|| artifact_err("a frame without RGB planes"))?;
            skybake_engine::output::frame_png(image.width(), image.height(), rgb)
        }
        Format::Json => serde_json::to_vec(&frame_summary(image))
            .map_err(|e| Error::internal("artifact", format!("encoding the summary: {e}"))),
        other => Err(Error::invalid(
            "format",
            format!(
                "'{}' is not a format of the frame product (allowed: json, exr, png)",
                other.name()
            ),
        )),
    }
}
