//! The product core, shared by the CLI, the HTTP service and bake jobs: request parameters (one
//! table, [`params`]) → a canonical [`ProductRequest`] ([`skybake_engine::spec::ProductSpec`] +
//! [`CommonSpec`]) → the engine's computation → one artifact, the tiled spectral EXR image
//! ([`SpectralImage`]) with the request and response in its header ([`artifact`]) → a response
//! body (`json`, `exr`, `png`) rendered from that artifact. `skybake sky -o sky.exr`, `GET
//! /v1/sky?format=exr` and a bake's EXR of the same request are the same file apart from the
//! timing attributes.
//!
//! Two ways in: [`ProductRequest::from_params`] (query strings and CLI flags, named by the
//! parameter table) and [`ProductRequest::from_object`] (a JSON object with a `product` member:
//! plan and job bodies). A product whose spec is a JSON document (the cloud frame's scene) enters
//! through `from_object` as one more [`ProductKind`]/[`ProductSpec`] variant, with an image of
//! width × height in the same channel layout as its artifact.

use crate::params::{parameter, PairsError, RequestParams};
use crate::{Error, Result};
use serde::Serialize;
use serde_json::{Map, Value};
use skybake_engine::engine::ENGINE_VERSION;
use skybake_engine::spec::{
    AerialSpec, CommonSpec, DomeShape, DomeSpec, AERIAL_DISTANCE_COUNT, AERIAL_MAX_DISTANCE_M,
    AERIAL_SHAPE, GROUND_SHAPE, SKY_SHAPE,
};
use skybake_physics::key::cache_key;

pub use crate::artifact::{
    render, ATTR_RESPONSE_JSON, ATTR_TABLES_WARM, PNG_SIZE, TIMING_ATTRIBUTES,
};
pub use skybake_engine::spec::{ProductKind, ProductSpec};

/// Response body format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Format {
    Json,
    Exr,
    /// Fisheye preview (zenith or nadir at the centre, the sun at the top).
    Png,
    /// Latitude-longitude panorama preview (azimuth −180…180° across).
    PngLatlong,
}

impl Format {
    pub fn content_type(self) -> &'static str {
        match self {
            Self::Json => "application/json",
            Self::Exr => "image/x-exr",
            Self::Png | Self::PngLatlong => "image/png",
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Json => "json",
            Self::Exr => "exr",
            Self::Png => "png",
            Self::PngLatlong => "png_latlong",
        }
    }

    /// The formats `product` can be rendered in.
    pub fn allowed(product: ProductKind) -> &'static [Format] {
        match product {
            ProductKind::Sun => &[Format::Json],
            ProductKind::Aerial => &[Format::Json, Format::Exr],
            ProductKind::Sky | ProductKind::Ground => {
                &[Format::Json, Format::Exr, Format::Png, Format::PngLatlong]
            }
        }
    }

    /// Parses `format=` for `product` (json when absent).
    pub fn parse(text: Option<&str>, product: ProductKind) -> Result<Self> {
        let Some(text) = text.map(str::trim) else {
            return Ok(Format::Json);
        };
        Self::allowed(product)
            .iter()
            .copied()
            .find(|f| f.name() == text)
            .ok_or_else(|| Self::refused(text, product))
    }

    /// The error for a format `text` that `product` does not have.
    fn refused(text: &str, product: ProductKind) -> Error {
        let names: Vec<&str> = Self::allowed(product).iter().map(|f| f.name()).collect();
        Error::invalid(
            "format",
            format!(
                "'{text}' is not a format of the {} product (allowed: {})",
                product.name(),
                names.join(", ")
            ),
        )
    }
}

/// Most probe values (directions × wavelengths) per request, so the JSON envelope fits the
/// artifact's 1 MiB attribute limit.
pub const MAX_PROBE_VALUES: usize = 32_768;

/// A validated, canonical product request. Everything that changes the numbers is in
/// [`Self::canonical_json`]; the response format is not (it is rendered from the same artifact),
/// except that a PNG is RGB-only and may run at fewer wavelengths ([`Self::rgb_only`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProductRequest {
    /// What to compute (tagged `product`, with the table shape, probes, distances).
    #[serde(flatten)]
    pub product: ProductSpec,
    /// Atmosphere, wavelengths, sun, observer, method, quality.
    pub spec: CommonSpec,
    #[serde(skip)]
    pub format: Format,
    /// A PNG preview of the sky or the ground is RGB-only: the planner may run it at fewer of the
    /// requested wavelengths (`spec.wavelengths_nm` then holds those it runs at; this records
    /// the rule, and is part of the cache key).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rgb_only: Option<skybake_engine::plan::WavelengthSubset>,
}

fn not_for(field: &str, product: ProductKind) -> Error {
    Error::invalid(
        field,
        format!("not a parameter of the {} product", product.name()),
    )
}

/// A parameter's row (the names used below are all in the table; a unit test checks it).
fn row(name: &str) -> Result<&'static crate::params::Parameter> {
    parameter(name).ok_or_else(|| Error::invalid(name, "not in the parameter table"))
}

impl ProductRequest {
    /// Validates `p` for `product` with the table's defaults (sky 129×64, ground 65×64, aerial
    /// 33×16×32 up to 100 km; format json). Parameters the product does not take are refused.
    pub fn from_params(product: ProductKind, p: &RequestParams) -> Result<Self> {
        if let Some(name) = p.not_for(product) {
            return Err(not_for(name, product));
        }
        let mut spec = crate::params::common_spec(p, product.min_sun_elevation_deg())?;
        let mut max_rel_error = None;
        if let Some(target) = p.max_rel_error.as_deref() {
            let target = row("max_rel_error")?.real(target)?;
            max_rel_error = Some(target);
            if p.quality.is_some() {
                return Err(Error::invalid(
                    "max_rel_error",
                    "give either quality or max_rel_error, not both",
                ));
            }
            spec.quality = skybake_engine::accuracy::quality_for_target(product, &spec, target)?;
        }
        let format = Format::parse(p.format.as_deref(), product)?;
        let count = |name: &str, default: usize| -> Result<usize> {
            match p.get(name) {
                Some(v) => row(name)?.whole(v),
                None => Ok(default),
            }
        };
        let shape = |d: DomeShape| -> Result<DomeShape> {
            Ok(DomeShape {
                elevation_count: count("elevation_count", d.elevation_count)?,
                azimuth_count: count("azimuth_count", d.azimuth_count)?,
            })
        };
        let probes = || -> Result<Vec<(f64, f64)>> {
            Ok(p.probe
                .as_deref()
                .map(crate::params::parse_probes)
                .transpose()?
                .unwrap_or_default())
        };
        let spec_of_product = match product {
            ProductKind::Sun => ProductSpec::Sun,
            ProductKind::Sky => ProductSpec::Sky(DomeSpec::sky(shape(SKY_SHAPE)?, probes()?)?),
            ProductKind::Ground => {
                ProductSpec::Ground(DomeSpec::ground(shape(GROUND_SHAPE)?, probes()?)?)
            }
            ProductKind::Aerial => {
                let max_distance_m = match &p.max_distance_m {
                    Some(v) => row("max_distance_m")?.real(v)?,
                    None => AERIAL_MAX_DISTANCE_M,
                };
                ProductSpec::Aerial(AerialSpec::new(
                    shape(AERIAL_SHAPE)?,
                    count("distance_count", AERIAL_DISTANCE_COUNT)?,
                    max_distance_m,
                )?)
            }
        };
        Self::new(spec, spec_of_product, format)?.planned_rgb_only(max_rel_error)
    }

    /// The same request at every requested wavelength (the spectral artifact): an RGB-only
    /// request's rule undone, in the same format.
    pub fn without_rgb_only(mut self) -> Result<Self> {
        if let Some(subset) = self.rgb_only.take() {
            self.spec.wavelengths_nm =
                skybake_physics::spectrum::Wavelengths::new(subset.requested_nm)?;
        }
        Ok(self)
    }

    /// The planner's wavelength rule on a PNG preview of the sky or the ground (an RGB-only
    /// request): it runs at the fewest of its wavelengths whose predicted RGB change
    /// ([`skybake_engine::plan::RGB_PROXY_SAFETY`] × the worst proxy's, `spectrum::subsets`, on the
    /// atmosphere's light spectra `atmosphere::sun_transmittance::light_spectra` at the observer
    /// and the ground) fits the budget: [`skybake_engine::plan::BUDGET_SHARE`] of the request's measured
    /// error in its regime (or what a `max_rel_error` target leaves over it), less what the
    /// precise orders rule spent. Nothing outside the measured regimes.
    fn planned_rgb_only(mut self, max_rel_error: Option<f64>) -> Result<Self> {
        use skybake_engine::plan::{rgb_wavelengths_rule, Budget, RgbFacts, WavelengthCandidate};
        let rgb = matches!(self.format, Format::Png | Format::PngLatlong)
            && matches!(self.kind(), ProductKind::Sky | ProductKind::Ground);
        let plan = self.plan()?;
        if !rgb || plan.ms_method() == skybake_physics::atmosphere::sky::MsMethod::None {
            return Ok(self);
        }
        let Some((measured, _)) = skybake_engine::accuracy::measured_for(
            self.kind(),
            plan.method,
            &plan.spec_for(&self.spec),
        ) else {
            return Ok(self);
        };
        let error = measured.relative_error
            + skybake_engine::accuracy::reference_error(self.spec.sun.sun_elevation_deg);
        let mut budget = match max_rel_error {
            Some(target) => Budget::for_target(target, error),
            None => Budget::new(error),
        };
        if let (skybake_physics::atmosphere::sky::MsMethod::Precise, Some(t)) =
            (plan.ms_method(), plan.precise_tolerance)
        {
            budget.spent += t;
        }
        let m = skybake_physics::atmosphere::Medium::new(
            &self.spec.atmosphere,
            &self.spec.wavelengths_nm,
            self.spec.ground_albedo,
        )?;
        let nm = self.spec.wavelengths_nm.as_nm().to_vec();
        let proxies = skybake_physics::atmosphere::sun_transmittance::light_spectra(
            &m,
            &[self.spec.observer_altitude_m.clamp(0.0, 1e6), 0.0],
            self.spec.sun.sun_elevation_deg.to_radians(),
        );
        let facts = RgbFacts {
            candidates: skybake_physics::spectrum::subsets::rgb_subsets(&nm, &proxies)
                .into_iter()
                .map(|(internal_nm, proxy_error)| WavelengthCandidate {
                    internal_nm,
                    proxy_error,
                })
                .collect(),
            requested_nm: nm,
        };
        if let Some(subset) = rgb_wavelengths_rule(&facts, &mut budget) {
            self.spec.wavelengths_nm =
                skybake_physics::spectrum::Wavelengths::new(subset.internal_nm.clone())?;
            self.rgb_only = Some(subset);
        }
        Ok(self)
    }

    /// A request from its parts, checking what the artifact must hold: the samples of the EXR
    /// (spectral layers + RGB) within the store's image limits, the JSON envelope (probes
    /// included) within one EXR attribute, and a PNG only where there is a table to show.
    pub fn new(spec: CommonSpec, product: ProductSpec, format: Format) -> Result<Self> {
        let kind = product.kind();
        if !Format::allowed(kind).contains(&format) {
            return Err(Format::refused(format.name(), kind));
        }
        let n_l = spec.wavelengths_nm.len();
        let layers = if kind == ProductKind::Aerial { 2 } else { 1 };
        let samples = product.pixel_count().saturating_mul(n_l * layers + 3);
        if samples > skybake_physics::image::spectral_image::MAX_TOTAL_SAMPLES {
            return Err(Error::too_large(
                "wavelengths",
                format!("{samples} samples in the product"),
                skybake_physics::image::spectral_image::MAX_TOTAL_SAMPLES,
            ));
        }
        let probe_values = product.probes().len() * n_l;
        if probe_values > MAX_PROBE_VALUES {
            return Err(Error::too_large(
                "probe",
                format!("{probe_values} values (directions × wavelengths)"),
                MAX_PROBE_VALUES,
            ));
        }
        if matches!(format, Format::Png | Format::PngLatlong) && !product.probes().is_empty() {
            return Err(Error::invalid(
                "format",
                "png needs the table: leave out probe for a PNG preview",
            ));
        }
        Ok(Self {
            product,
            spec,
            format,
            rgb_only: None,
        })
    }

    /// A request from a JSON object with a `product` member and the product's parameters (plan
    /// and job bodies; `skip` names members the caller handles, `prefix` goes before names in
    /// errors).
    pub fn from_object(
        obj: &Map<String, Value>,
        skip: &[&str],
        prefix: &str,
        defaults: &crate::params::Defaults,
    ) -> std::result::Result<Self, PairsError> {
        let product = product_of(obj, prefix)?;
        let mut skip = skip.to_vec();
        skip.push("product");
        let p = RequestParams::from_object(obj, &skip, prefix)?;
        Ok(Self::from_params(product, &defaults.apply(p)).map_err(|e| e.prefixed(prefix))?)
    }

    /// The product kind.
    pub fn kind(&self) -> ProductKind {
        self.product.kind()
    }

    /// The canonical spec JSON (product, shape, probes, resolved atmosphere, wavelengths, sun…).
    pub fn canonical_json(&self) -> String {
        // Serialising plain data structs cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }

    /// The cache key: blake3 of the canonical spec and the engine version.
    pub fn cache_key(&self) -> String {
        cache_key(&self.canonical_json(), ENGINE_VERSION)
    }

    /// Rough cost in engine work units, for the plan response (output cells × wavelengths).
    pub fn work_cells(&self) -> usize {
        (self.product.pixel_count() + self.product.probes().len()) * self.spec.wavelengths_nm.len()
    }

    /// The plan the engine will execute for this request (no tables built), with the
    /// wavelengths an RGB-only request left out.
    pub fn plan(&self) -> Result<skybake_engine::plan::Plan> {
        let mut plan = skybake_engine::engine::Engine::plan(&self.spec, self.kind())?;
        plan.wavelengths = self.rgb_only.clone();
        Ok(plan)
    }
}

/// The `product` member of a plan or job body.
pub fn product_of(obj: &Map<String, Value>, prefix: &str) -> Result<ProductKind> {
    match obj.get("product") {
        Some(Value::String(s)) => ProductKind::parse(s).map_err(|e| e.prefixed(prefix)),
        _ => Err(Error::invalid(
            &format!("{prefix}product"),
            "missing or not a string: one of sun, sky, ground, aerial",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> RequestParams {
        RequestParams::from_pairs(pairs.iter().copied()).unwrap()
    }

    #[test]
    fn defaults_match_the_table() {
        let sky = ProductRequest::from_params(ProductKind::Sky, &params(&[])).unwrap();
        assert!(matches!(&sky.product, ProductSpec::Sky(d) if d.shape() == SKY_SHAPE));
        let ground = ProductRequest::from_params(ProductKind::Ground, &params(&[])).unwrap();
        assert!(matches!(&ground.product, ProductSpec::Ground(d) if d.shape() == GROUND_SHAPE));
        let aerial = ProductRequest::from_params(ProductKind::Aerial, &params(&[])).unwrap();
        match &aerial.product {
            ProductSpec::Aerial(a) => {
                assert_eq!(a.shape(), AERIAL_SHAPE);
                assert_eq!(a.distance_count(), 32);
                assert_eq!(a.max_distance_m(), 100_000.0);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(sky.format, Format::Json);
        for name in [
            "elevation_count",
            "azimuth_count",
            "distance_count",
            "max_distance_m",
        ] {
            assert!(row(name).is_ok(), "{name}");
        }
    }

    #[test]
    fn key_ignores_format_but_not_numbers() {
        let sky = |pairs: &[(&str, &str)]| {
            ProductRequest::from_params(ProductKind::Sky, &params(pairs)).unwrap()
        };
        let a = sky(&[("format", "exr")]);
        let c = ProductRequest::from_params(ProductKind::Ground, &params(&[])).unwrap();
        let d = sky(&[("ground_albedo", "0.2")]);
        assert_eq!(a.cache_key(), sky(&[]).cache_key());
        assert_ne!(a.cache_key(), c.cache_key());
        assert_ne!(a.cache_key(), d.cache_key());
        // Haze parameters resolve into the atmosphere, which the key covers.
        let hazy = sky(&[("visibility_km", "10")]);
        assert_ne!(hazy.cache_key(), a.cache_key());
        for other in [
            sky(&[("visibility_km", "11")]),
            sky(&[("visibility_km", "10"), ("aerosol_type", "urban")]),
            sky(&[("visibility_km", "10"), ("boundary_layer_top_m", "1500")]),
        ] {
            assert_ne!(hazy.cache_key(), other.cache_key());
        }
        assert_eq!(
            hazy.cache_key(),
            sky(&[("visibility_km", "10"), ("aerosol_type", "continental")]).cache_key()
        );
        // A PNG is RGB-only: fewer wavelengths where the budget allows, its own key (both
        // projections share it); undone, it is the spectral request.
        let png = sky(&[("format", "png")]);
        assert!(png.rgb_only.is_some());
        assert_ne!(png.cache_key(), a.cache_key());
        assert_eq!(
            png.cache_key(),
            sky(&[("format", "png_latlong")]).cache_key()
        );
        assert_eq!(png.without_rgb_only().unwrap().cache_key(), a.cache_key());
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
            (ProductKind::Sun, "elevation_count", "9"),
        ];
        for (kind, k, v) in cases {
            let e = ProductRequest::from_params(kind, &params(&[(k, v)])).unwrap_err();
            assert_eq!(e.field(), k, "{kind:?} {k}={v}: {e}");
        }
        let e = ProductRequest::from_params(
            ProductKind::Sky,
            &params(&[("format", "png"), ("probe", "10:0")]),
        )
        .unwrap_err();
        assert_eq!(e.field(), "format");
    }
}
