//! The in-memory image that the store writes and reads: one or more spectral layers sharing a
//! wavelength list (e.g. `S0` radiance and `T` transmittance), optional RGB preview planes, and text
//! attributes. Every constructor validates, so a `SpectralImage` always encodes.

use std::collections::BTreeMap;

use super::layout::{
    canonical_wavelength_nm, validate_attribute_name, validate_layer_name, ATTR_COMPUTE_TIME_MS,
    ATTR_ENGINE_VERSION, ATTR_ERROR_ESTIMATE_JSON, ATTR_SPEC_JSON, MAX_WAVELENGTH_NM,
};
use crate::{Error, Result};

/// Largest width or height in pixels.
pub const MAX_DIMENSION: usize = 16_384;
/// Most wavelengths per image.
pub const MAX_WAVELENGTHS: usize = 256;
/// Most spectral layers per image.
pub const MAX_LAYERS: usize = 8;
/// Most samples (pixels × channels) per image: 2²⁸ f32 values, 1 GiB.
pub const MAX_TOTAL_SAMPLES: usize = 1 << 28;
/// Longest attribute value in bytes.
pub const MAX_ATTRIBUTE_VALUE_BYTES: usize = 1 << 20;
/// Most custom attributes per image.
pub const MAX_ATTRIBUTES: usize = 64;

/// One spectral layer: a plane per wavelength of the owning image, each row-major `width × height`.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralLayer {
    name: String,
    planes: Vec<Vec<f32>>,
}

impl SpectralLayer {
    /// The channel prefix (`S0`, `T`, …).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The planes, in the order of the image's wavelengths.
    pub fn planes(&self) -> &[Vec<f32>] {
        &self.planes
    }

    /// The plane at wavelength index `index`.
    pub fn plane(&self, index: usize) -> Option<&[f32]> {
        self.planes.get(index).map(Vec::as_slice)
    }
}

/// A multi-layer spectral image with optional RGB preview and text attributes.
///
/// Invariants (checked by every constructor and setter): `1 <= width, height <= MAX_DIMENSION`;
/// wavelengths strictly increasing, finite, in `(0, 10⁶)` nm, on the 10⁻⁶ nm grid of channel names;
/// every plane has `width * height` finite values; layer names unique and valid; attribute names valid
/// and not reserved; total samples at most [`MAX_TOTAL_SAMPLES`].
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralImage {
    width: usize,
    height: usize,
    wavelengths_nm: Vec<f64>,
    layers: Vec<SpectralLayer>,
    rgb: Option<[Vec<f32>; 3]>,
    attributes: BTreeMap<String, String>,
}

impl SpectralImage {
    /// An image with no layers yet. Wavelengths are rounded to the 10⁻⁶ nm grid of the channel names
    /// (see [`super::layout::canonical_wavelength_nm`]) and must then be strictly increasing.
    pub fn new(width: usize, height: usize, wavelengths_nm: &[f64]) -> Result<Self> {
        if width == 0 || width > MAX_DIMENSION {
            return Err(Error::out_of_range(
                "width",
                width,
                format!("1..={MAX_DIMENSION}"),
            ));
        }
        if height == 0 || height > MAX_DIMENSION {
            return Err(Error::out_of_range(
                "height",
                height,
                format!("1..={MAX_DIMENSION}"),
            ));
        }
        if wavelengths_nm.is_empty() || wavelengths_nm.len() > MAX_WAVELENGTHS {
            return Err(Error::out_of_range(
                "wavelengths_nm",
                format!("{} entries", wavelengths_nm.len()),
                format!("1..={MAX_WAVELENGTHS} entries"),
            ));
        }
        let mut canonical = Vec::with_capacity(wavelengths_nm.len());
        for &wavelength_nm in wavelengths_nm {
            if !(wavelength_nm.is_finite()
                && wavelength_nm > 0.0
                && wavelength_nm < MAX_WAVELENGTH_NM)
            {
                return Err(Error::out_of_range(
                    "wavelengths_nm",
                    wavelength_nm,
                    format!("finite, in (0, {MAX_WAVELENGTH_NM}) nm"),
                ));
            }
            let value = canonical_wavelength_nm(wavelength_nm);
            if canonical.last().is_some_and(|&last| value <= last) {
                return Err(Error::invalid(
                    "wavelengths_nm",
                    "must be strictly increasing and distinct at 1e-6 nm resolution",
                ));
            }
            canonical.push(value);
        }
        let image = Self {
            width,
            height,
            wavelengths_nm: canonical,
            layers: Vec::new(),
            rgb: None,
            attributes: BTreeMap::new(),
        };
        // At least one layer must fit.
        image.check_sample_budget(image.wavelengths_nm.len())?;
        Ok(image)
    }

    /// Shorthand for a radiance image: one emissive layer `S0` with one plane per wavelength.
    pub fn emissive(
        width: usize,
        height: usize,
        wavelengths_nm: &[f64],
        planes: Vec<Vec<f32>>,
    ) -> Result<Self> {
        let mut image = Self::new(width, height, wavelengths_nm)?;
        image.add_layer(super::layout::EMISSIVE_LAYER, planes)?;
        Ok(image)
    }

    /// Adds a spectral layer named `name` (channel prefix) with one plane per wavelength.
    pub fn add_layer(&mut self, name: &str, planes: Vec<Vec<f32>>) -> Result<()> {
        validate_layer_name(name)?;
        if self.layers.len() >= MAX_LAYERS {
            return Err(Error::too_large(
                "layer",
                "too many spectral layers",
                MAX_LAYERS,
            ));
        }
        if self.layer(name).is_some() {
            return Err(Error::invalid(
                "layer",
                format!("layer {name:?} already exists"),
            ));
        }
        if planes.len() != self.wavelengths_nm.len() {
            return Err(Error::invalid(
                "layer",
                format!(
                    "layer {name:?} has {} planes, expected one per wavelength ({})",
                    planes.len(),
                    self.wavelengths_nm.len()
                ),
            ));
        }
        self.check_sample_budget(planes.len())?;
        for plane in &planes {
            self.check_plane("layer", name, plane)?;
        }
        let position = self
            .layers
            .partition_point(|layer| layer.name.as_str() < name);
        self.layers.insert(
            position,
            SpectralLayer {
                name: name.to_string(),
                planes,
            },
        );
        Ok(())
    }

    /// Sets (or replaces) the R, G, B preview planes.
    pub fn set_rgb(&mut self, rgb: [Vec<f32>; 3]) -> Result<()> {
        if self.rgb.is_none() {
            self.check_sample_budget(3)?;
        }
        for plane in &rgb {
            self.check_plane("rgb", "rgb", plane)?;
        }
        self.rgb = Some(rgb);
        Ok(())
    }

    /// Sets a text attribute (stored as an OpenEXR `string` attribute of the same name): any UTF-8
    /// without NUL, at most [`MAX_ATTRIBUTE_VALUE_BYTES`].
    pub fn set_attribute(&mut self, name: &str, value: impl Into<String>) -> Result<()> {
        validate_attribute_name(name)?;
        let value = value.into();
        if value.len() > MAX_ATTRIBUTE_VALUE_BYTES {
            return Err(Error::too_large(
                name,
                "attribute value too long",
                format!("{MAX_ATTRIBUTE_VALUE_BYTES} bytes"),
            ));
        }
        if value.contains('\0') {
            // Keeps the checksum attribute's byte pattern (which contains NULs) unique in a header.
            return Err(Error::invalid(
                name,
                "attribute value must not contain NUL characters",
            ));
        }
        if !self.attributes.contains_key(name) && self.attributes.len() >= MAX_ATTRIBUTES {
            return Err(Error::too_large(
                "attribute",
                "too many attributes",
                MAX_ATTRIBUTES,
            ));
        }
        self.attributes.insert(name.to_string(), value);
        Ok(())
    }

    /// Sets the product attributes every cached product carries: the canonical
    /// spec JSON, the engine version, the error estimate JSON and the compute time in milliseconds.
    pub fn set_product_metadata(
        &mut self,
        canonical_spec_json: &str,
        engine_version: &str,
        error_estimate_json: &str,
        compute_time_ms: f64,
    ) -> Result<()> {
        if !(compute_time_ms.is_finite() && compute_time_ms >= 0.0) {
            return Err(Error::out_of_range(
                "compute_time_ms",
                compute_time_ms,
                "finite, >= 0",
            ));
        }
        self.set_attribute(ATTR_SPEC_JSON, canonical_spec_json)?;
        self.set_attribute(ATTR_ENGINE_VERSION, engine_version)?;
        self.set_attribute(ATTR_ERROR_ESTIMATE_JSON, error_estimate_json)?;
        self.set_attribute(ATTR_COMPUTE_TIME_MS, fixed_width_ms(compute_time_ms))
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Wavelengths in nm, strictly increasing, on the 10⁻⁶ nm grid.
    pub fn wavelengths_nm(&self) -> &[f64] {
        &self.wavelengths_nm
    }

    /// All spectral layers, sorted by name (the order they come back from a file).
    pub fn layers(&self) -> &[SpectralLayer] {
        &self.layers
    }

    /// The layer with channel prefix `name`.
    pub fn layer(&self, name: &str) -> Option<&SpectralLayer> {
        self.layers.iter().find(|layer| layer.name == name)
    }

    /// The R, G, B preview planes, if any.
    pub fn rgb(&self) -> Option<&[Vec<f32>; 3]> {
        self.rgb.as_ref()
    }

    /// The text attributes.
    pub fn attributes(&self) -> &BTreeMap<String, String> {
        &self.attributes
    }

    /// The attribute `name`, if set.
    pub fn attribute(&self, name: &str) -> Option<&str> {
        self.attributes.get(name).map(String::as_str)
    }

    /// Number of pixels per plane.
    pub fn pixel_count(&self) -> usize {
        self.width * self.height
    }

    /// Number of planes (spectral and RGB).
    pub fn plane_count(&self) -> usize {
        self.layers.len() * self.wavelengths_nm.len() + if self.rgb.is_some() { 3 } else { 0 }
    }

    /// Rejects adding `extra_planes` planes when that would exceed [`MAX_TOTAL_SAMPLES`].
    fn check_sample_budget(&self, extra_planes: usize) -> Result<()> {
        let planes = self.plane_count() + extra_planes;
        let samples = self.pixel_count().checked_mul(planes.max(1));
        match samples {
            Some(n) if n <= MAX_TOTAL_SAMPLES => Ok(()),
            _ => Err(Error::too_large(
                "image",
                format!("{}x{} pixels x {planes} planes", self.width, self.height),
                format!("{MAX_TOTAL_SAMPLES} samples"),
            )),
        }
    }

    fn check_plane(&self, field: &str, what: &str, plane: &[f32]) -> Result<()> {
        if plane.len() != self.pixel_count() {
            return Err(Error::invalid(
                field,
                format!(
                    "{what}: plane has {} values, expected width*height = {}",
                    plane.len(),
                    self.pixel_count()
                ),
            ));
        }
        if let Some(index) = plane.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(
                field,
                format!(
                    "{what}: non-finite value {} at pixel ({}, {})",
                    plane[index],
                    index % self.width,
                    index / self.width
                ),
            ));
        }
        Ok(())
    }
}

/// A compute time as a fixed-width decimal (12 characters, zero-padded, to the microsecond, capped
/// at 99 999 999.999 ms), so that two artifacts of one request differ only inside the bytes of
/// their timing attributes and every other byte of the files, offsets included, is the same.
pub fn fixed_width_ms(ms: f64) -> String {
    format!("{:012.3}", ms.clamp(0.0, 99_999_999.999))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::layout::{EMISSIVE_LAYER, TRANSMITTANCE_LAYER};

    #[test]
    fn validates_sizes_and_values() {
        assert_eq!(
            SpectralImage::new(0, 4, &[550.0]).unwrap_err().field(),
            "width"
        );
        assert_eq!(
            SpectralImage::new(4, 0, &[550.0]).unwrap_err().field(),
            "height"
        );
        assert_eq!(
            SpectralImage::new(4, 4, &[]).unwrap_err().field(),
            "wavelengths_nm"
        );
        assert_eq!(
            SpectralImage::new(4, 4, &[550.0, 440.0])
                .unwrap_err()
                .field(),
            "wavelengths_nm"
        );
        assert_eq!(
            SpectralImage::new(4, 4, &[f64::NAN]).unwrap_err().field(),
            "wavelengths_nm"
        );
        // Too many samples is refused before anything is allocated.
        assert_eq!(
            SpectralImage::new(MAX_DIMENSION, MAX_DIMENSION, &[500.0, 600.0])
                .unwrap_err()
                .field(),
            "image"
        );

        let mut image = SpectralImage::new(2, 2, &[440.0, 550.0]).unwrap();
        let err = image
            .add_layer(EMISSIVE_LAYER, vec![vec![0.0; 4]])
            .unwrap_err();
        assert_eq!(err.field(), "layer");
        let err = image
            .add_layer(EMISSIVE_LAYER, vec![vec![0.0; 4], vec![0.0; 3]])
            .unwrap_err();
        assert_eq!(err.field(), "layer");
        let err = image
            .add_layer(
                EMISSIVE_LAYER,
                vec![vec![0.0; 4], vec![0.0, f32::INFINITY, 0.0, 0.0]],
            )
            .unwrap_err();
        assert!(err.to_string().contains("pixel (1, 0)"), "{err}");
        image
            .add_layer(EMISSIVE_LAYER, vec![vec![1.0; 4], vec![2.0; 4]])
            .unwrap();
        image
            .add_layer(TRANSMITTANCE_LAYER, vec![vec![0.5; 4], vec![0.25; 4]])
            .unwrap();
        assert!(image
            .add_layer(EMISSIVE_LAYER, vec![vec![1.0; 4]; 2])
            .is_err());
        assert!(image
            .set_rgb([vec![0.0; 4], vec![0.0; 4], vec![0.0; 5]])
            .is_err());
        assert!(image.set_attribute("owner", "x").is_err());
        assert_eq!(
            image
                .set_attribute("skybakeSpec", "a\0b")
                .unwrap_err()
                .field(),
            "skybakeSpec"
        );
        image.set_attribute("skybakeSpec", "{}").unwrap();
        assert_eq!(image.plane_count(), 4);
        assert_eq!(
            image.layer(TRANSMITTANCE_LAYER).unwrap().plane(1),
            Some(&[0.25f32; 4][..])
        );
    }

    #[test]
    fn product_metadata_lands_in_named_attributes() {
        let mut image = SpectralImage::new(1, 1, &[550.0]).unwrap();
        image
            .set_product_metadata(r#"{"product":"sun"}"#, "0.1.0", "{}", 12.5)
            .unwrap();
        assert_eq!(
            image.attribute(ATTR_SPEC_JSON),
            Some(r#"{"product":"sun"}"#)
        );
        assert_eq!(image.attribute(ATTR_ENGINE_VERSION), Some("0.1.0"));
        assert_eq!(image.attribute(ATTR_ERROR_ESTIMATE_JSON), Some("{}"));
        assert_eq!(image.attribute(ATTR_COMPUTE_TIME_MS), Some("00000012.500"));
        let err = image
            .set_product_metadata("{}", "0.1.0", "{}", f64::NAN)
            .unwrap_err();
        assert_eq!(err.field(), "compute_time_ms");
    }

    #[test]
    fn wavelengths_are_put_on_the_channel_grid() {
        let image = SpectralImage::new(1, 1, &[550.123_456_7]).unwrap();
        assert_eq!(image.wavelengths_nm(), &[550.123_457]);
        // Distinct inputs that collide on the grid are refused rather than merged.
        assert!(SpectralImage::new(1, 1, &[550.000_000_1, 550.000_000_2]).is_err());
    }
}
