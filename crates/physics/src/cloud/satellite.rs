//! Clouds from a satellite image (Nishita & Dobashi 2001, §3.1).
//!
//! The image is reduced to grey levels; pixels brighter than a threshold form the cloud mask.
//! Assuming, as the paper does, no multiple scattering and constant attenuation, a pixel's
//! brightness is proportional to the column density above it, so the approximated image of a set
//! of metaballs is the sum of their vertical projections (the column integral of Wyvill's field,
//! [`wyvill::column_integral_m`]). Metaballs are added greedily at the brightest unexplained
//! pixel; for each, the radius is searched (geometric scan, then golden section) and the centre
//! density is the least-squares amplitude for that radius, so every accepted ball strictly lowers
//! the image error. Fitting stops when the relative error falls below a threshold, at a ball
//! budget, or when no ball can lower the error.
//!
//! The image fixes neither the balls' heights nor their depths: each ball rests on a common base
//! plane (`cloud_base_m`), giving flat bases, and its centre density is set so the column density
//! of the 3-D cloud reproduces the fitted image times `column_density_m`.

use super::metaballs::{validate_balls, Metaball, MetaballField};
use super::wyvill;
use super::DensityGrid;
use crate::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Largest accepted image side, pixels.
pub const MAX_IMAGE_SIDE: usize = 2048;
/// Most metaballs one fit may place (bounds the fitting time).
pub const MAX_FIT_BALLS: usize = 20_000;

/// A grey-level image, row-major with row 0 at the top (north), values in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct GrayImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixel values, index `y * width + x`.
    pub data: Vec<f32>,
}

impl GrayImage {
    /// An image from values in [0, 1], validating the size first.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        check_dims(width, height)?;
        if data.len() != width * height {
            return Err(Error::invalid(
                "image",
                format!(
                    "has {} pixels, {width} × {height} needs {}",
                    data.len(),
                    width * height
                ),
            ));
        }
        if let Some(bad) = data.iter().find(|v| !(0.0..=1.0).contains(*v)) {
            return Err(Error::invalid(
                "image",
                format!("pixel values must lie in [0, 1], found {bad}"),
            ));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Decodes a PNG (grey or colour, 8 or 16 bit; colour is reduced to luma), checking the
    /// dimensions from the header before decoding the pixels.
    pub fn from_png_bytes(bytes: &[u8]) -> Result<Self> {
        use image::{ImageFormat, ImageReader, Limits};
        let open = || ImageReader::with_format(std::io::Cursor::new(bytes), ImageFormat::Png);
        let (w, h) = open()
            .into_dimensions()
            .map_err(|e| Error::invalid("image", format!("not a readable PNG: {e}")))?;
        check_dims(w as usize, h as usize)?;
        let mut reader = open();
        let mut limits = Limits::default();
        limits.max_image_width = Some(w);
        limits.max_image_height = Some(h);
        limits.max_alloc = Some((MAX_IMAGE_SIDE * MAX_IMAGE_SIDE * 16) as u64);
        reader.limits(limits);
        let decoded = reader
            .decode()
            .map_err(|e| Error::invalid("image", format!("cannot decode PNG: {e}")))?;
        let luma = decoded.to_luma32f();
        let data = luma
            .into_raw()
            .into_iter()
            .map(|v| v.clamp(0.0, 1.0))
            .collect();
        Self::new(w as usize, h as usize, data)
    }

    /// Pixel value at column `x`, row `y`.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }
}

fn check_dims(width: usize, height: usize) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::out_of_range(
            "image",
            format!("{width} × {height} pixels"),
            "at least 1 × 1",
        ));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(Error::too_large(
            "image",
            format!("{width} × {height} pixels"),
            format!("{MAX_IMAGE_SIDE} pixels per side"),
        ));
    }
    Ok(())
}

/// Parameters of the `"satellite"` cloud source. Defaults in brackets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SatelliteParams {
    /// Path of the grey-level PNG, resolved by the caller's loader (relative to the scene file).
    pub image: String,
    /// Ground size of one pixel, metres, in (0, 100 000] [250].
    #[serde(default = "default_pixel_size_m")]
    pub pixel_size_m: f64,
    /// Height of the common base plane the balls rest on, metres, in [0, 20 000] [1000].
    #[serde(default = "default_cloud_base_m")]
    pub cloud_base_m: f64,
    /// Column density `∫ρ dz` of a pixel of brightness 1, metres, in (0, 1e6] [400].
    #[serde(default = "default_column_density_m")]
    pub column_density_m: f64,
    /// Pixels brighter than this are cloud, in [0, 1) [0.25].
    #[serde(default = "default_cloud_threshold")]
    pub cloud_threshold: f64,
    /// Stop when the relative L2 image error falls below this, in (0, 1] [0.1].
    #[serde(default = "default_error_threshold")]
    pub error_threshold: f64,
    /// Most metaballs, 1..=20 000 [4000].
    #[serde(default = "default_max_balls")]
    pub max_balls: usize,
    /// Smallest ball radius, pixels, in [0.5, max_radius_px] [1].
    #[serde(default = "default_min_radius_px")]
    pub min_radius_px: f64,
    /// Largest ball radius, pixels, in [min_radius_px, 64] [24] (bounds the fitting time).
    #[serde(default = "default_max_radius_px")]
    pub max_radius_px: f64,
}

fn default_pixel_size_m() -> f64 {
    250.0
}
fn default_cloud_base_m() -> f64 {
    1000.0
}
fn default_column_density_m() -> f64 {
    400.0
}
fn default_cloud_threshold() -> f64 {
    0.25
}
fn default_error_threshold() -> f64 {
    0.1
}
fn default_max_balls() -> usize {
    4000
}
fn default_min_radius_px() -> f64 {
    1.0
}
fn default_max_radius_px() -> f64 {
    24.0
}

impl SatelliteParams {
    /// Parameters with the documented defaults for the image at `image`.
    pub fn new(image: impl Into<String>) -> Self {
        Self {
            image: image.into(),
            pixel_size_m: default_pixel_size_m(),
            cloud_base_m: default_cloud_base_m(),
            column_density_m: default_column_density_m(),
            cloud_threshold: default_cloud_threshold(),
            error_threshold: default_error_threshold(),
            max_balls: default_max_balls(),
            min_radius_px: default_min_radius_px(),
            max_radius_px: default_max_radius_px(),
        }
    }

    /// Checks every parameter against its documented range.
    pub fn validate(&self) -> Result<()> {
        let check = |field: &str, v: f64, ok: bool, allowed: &str| {
            if ok && v.is_finite() {
                Ok(())
            } else {
                Err(Error::out_of_range(field, v, allowed))
            }
        };
        let p = self.pixel_size_m;
        check("pixel_size_m", p, p > 0.0 && p <= 1e5, "(0, 100000]")?;
        let b = self.cloud_base_m;
        check("cloud_base_m", b, (0.0..=2e4).contains(&b), "[0, 20000]")?;
        let c = self.column_density_m;
        check("column_density_m", c, c > 0.0 && c <= 1e6, "(0, 1e6]")?;
        let t = self.cloud_threshold;
        check("cloud_threshold", t, (0.0..1.0).contains(&t), "[0, 1)")?;
        let e = self.error_threshold;
        check("error_threshold", e, e > 0.0 && e <= 1.0, "(0, 1]")?;
        if !(1..=MAX_FIT_BALLS).contains(&self.max_balls) {
            return Err(Error::out_of_range(
                "max_balls",
                self.max_balls,
                format!("1..={MAX_FIT_BALLS}"),
            ));
        }
        let (lo, hi) = (self.min_radius_px, self.max_radius_px);
        check(
            "min_radius_px",
            lo,
            lo >= 0.5 && lo <= hi,
            "[0.5, max_radius_px]",
        )?;
        check("max_radius_px", hi, hi <= 64.0, "[min_radius_px, 64]")?;
        Ok(())
    }
}

/// One fitted blob in image space.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Blob {
    /// Column of the centre pixel.
    pub x_px: usize,
    /// Row of the centre pixel.
    pub y_px: usize,
    /// Radius, pixels.
    pub radius_px: f64,
    /// Peak image brightness contributed (at the centre).
    pub amplitude: f64,
}

/// Result of fitting metaballs to an image.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FitResult {
    /// Fitted blobs, in the order added.
    pub blobs: Vec<Blob>,
    /// Final relative L2 error `‖T − M‖ / ‖T‖` of the approximated image `M` against the masked
    /// image `T`.
    pub error: f64,
    /// The error before the first blob and after each blob (with its amplitude refit; the last
    /// entry after the final refit); strictly decreasing.
    pub error_history: Vec<f64>,
    /// Whether the error fell below `error_threshold`.
    pub converged: bool,
}

/// Samples of the profile table over `u² ∈ [0, 1]`.
const PROFILE_SAMPLES: usize = 4096;

/// Normalised projected profile `g = P(u)/P(0)` of a unit ball, from the squared normalised
/// distance `u²` (table of the closed form, linear in `u²`; error below 1e-6).
#[inline]
fn profile(u2: f64) -> f64 {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let p0 = wyvill::column_integral_m(0.0, 1.0);
        (0..=PROFILE_SAMPLES)
            .map(|i| {
                wyvill::column_integral_m((i as f64 / PROFILE_SAMPLES as f64).sqrt(), 1.0) / p0
            })
            .collect()
    });
    if u2 >= 1.0 {
        return 0.0;
    }
    let t = u2.max(0.0) * PROFILE_SAMPLES as f64;
    let i = (t as usize).min(PROFILE_SAMPLES - 1);
    let f = t - i as f64;
    table[i] * (1.0 - f) + table[i + 1] * f
}

/// Pixel window `[x0, x1) × [y0, y1)` covered by a blob.
fn window(img: &GrayImage, x: usize, y: usize, r: f64) -> (usize, usize, usize, usize) {
    let reach = r.ceil() as usize;
    (
        x.saturating_sub(reach),
        (x + reach + 1).min(img.width),
        y.saturating_sub(reach),
        (y + reach + 1).min(img.height),
    )
}

/// The approximated image of `blobs` on a `width × height` raster (sum of projected profiles).
pub fn approximated_image(width: usize, height: usize, blobs: &[Blob]) -> Result<Vec<f64>> {
    check_dims(width, height)?;
    let mut out = vec![0.0; width * height];
    for b in blobs {
        let reach = b.radius_px.ceil() as usize;
        for py in b.y_px.saturating_sub(reach)..(b.y_px + reach + 1).min(height) {
            let dy = py as f64 - b.y_px as f64;
            for px in b.x_px.saturating_sub(reach)..(b.x_px + reach + 1).min(width) {
                let dx = px as f64 - b.x_px as f64;
                out[py * width + px] +=
                    b.amplitude * profile((dx * dx + dy * dy) / (b.radius_px * b.radius_px));
            }
        }
    }
    Ok(out)
}

/// `(Σ res·g, Σ g²)` over the disc of `blob`.
fn correlate(img: &GrayImage, res: &[f64], blob: &Blob) -> (f64, f64) {
    let (mut rg, mut gg) = (0.0, 0.0);
    for_disc(img, blob, |i, g| {
        rg += res[i] * g;
        gg += g * g;
    });
    (rg, gg)
}

/// Calls `f(pixel index, profile)` for every pixel inside the blob's disc.
fn for_disc(img: &GrayImage, blob: &Blob, mut f: impl FnMut(usize, f64)) {
    let (x0, x1, y0, y1) = window(img, blob.x_px, blob.y_px, blob.radius_px);
    let inv_r2 = 1.0 / (blob.radius_px * blob.radius_px);
    for py in y0..y1 {
        let dy = py as f64 - blob.y_px as f64;
        for px in x0..x1 {
            let dx = px as f64 - blob.x_px as f64;
            let u2 = (dx * dx + dy * dy) * inv_r2;
            if u2 < 1.0 {
                f(py * img.width + px, profile(u2));
            }
        }
    }
}

/// Edge of the tiles over which the residual's maximum is cached, pixels.
const TILE_PX: usize = 32;

/// The residual image `T − M`, its squared norm (tracked incrementally) and the maximum over
/// the cloud pixels of each tile (refreshed lazily), so a fitting step costs in proportion to
/// the pixels it touches rather than to the image.
struct Residual<'a> {
    img: &'a GrayImage,
    cloud: Vec<bool>,
    res: Vec<f64>,
    err2: f64,
    tiles_x: usize,
    tile_max: Vec<Option<(f64, usize)>>,
    dirty: Vec<bool>,
}

impl<'a> Residual<'a> {
    fn new(img: &'a GrayImage, target: Vec<f64>) -> Self {
        let tiles_x = img.width.div_ceil(TILE_PX);
        let tiles = tiles_x * img.height.div_ceil(TILE_PX);
        Self {
            img,
            cloud: target.iter().map(|&t| t > 0.0).collect(),
            err2: target.iter().map(|t| t * t).sum(),
            res: target,
            tiles_x,
            tile_max: vec![None; tiles],
            dirty: vec![true; tiles],
        }
    }

    /// Changes a blob's amplitude, updating the residual, its norm and the dirty tiles.
    fn set_amplitude(&mut self, blob: &mut Blob, amplitude: f64) {
        let delta = amplitude - blob.amplitude;
        if delta == 0.0 {
            return;
        }
        let (res, err2) = (&mut self.res, &mut self.err2);
        for_disc(self.img, blob, |i, g| {
            let old = res[i];
            let new = old - delta * g;
            *err2 += new * new - old * old;
            res[i] = new;
        });
        blob.amplitude = amplitude;
        let (x0, x1, y0, y1) = window(self.img, blob.x_px, blob.y_px, blob.radius_px);
        for ty in y0 / TILE_PX..=(y1 - 1) / TILE_PX {
            for tx in x0 / TILE_PX..=(x1 - 1) / TILE_PX {
                self.dirty[ty * self.tiles_x + tx] = true;
            }
        }
    }

    /// Least-squares coordinate step on one blob's amplitude, kept non-negative.
    fn refit(&mut self, blob: &mut Blob) {
        let (rg, gg) = correlate(self.img, &self.res, blob);
        if gg > 0.0 {
            self.set_amplitude(blob, (blob.amplitude + rg / gg).max(0.0));
        }
    }

    /// Recomputes the squared norm exactly (removes accumulated rounding).
    fn resum(&mut self) {
        self.err2 = self.res.iter().map(|r| r * r).sum();
    }

    /// The cloud pixel with the largest residual, as (index, residual).
    fn brightest(&mut self) -> Option<(usize, f64)> {
        let w = self.img.width;
        for t in 0..self.tile_max.len() {
            if !self.dirty[t] {
                continue;
            }
            let (tx, ty) = (t % self.tiles_x, t / self.tiles_x);
            let mut best: Option<(f64, usize)> = None;
            for y in ty * TILE_PX..((ty + 1) * TILE_PX).min(self.img.height) {
                for x in tx * TILE_PX..((tx + 1) * TILE_PX).min(w) {
                    let i = y * w + x;
                    if self.cloud[i] && best.is_none_or(|(v, _)| self.res[i] > v) {
                        best = Some((self.res[i], i));
                    }
                }
            }
            self.tile_max[t] = best;
            self.dirty[t] = false;
        }
        self.tile_max
            .iter()
            .flatten()
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
            .map(|&(v, i)| (i, v))
    }
}

/// Least-squares amplitude and error reduction of a blob of radius `r` at (x, y) against `res`.
fn score(img: &GrayImage, res: &[f64], x: usize, y: usize, r: f64) -> (f64, f64) {
    let blob = Blob {
        x_px: x,
        y_px: y,
        radius_px: r,
        amplitude: 0.0,
    };
    let (rg, gg) = correlate(img, res, &blob);
    if rg <= 0.0 || gg <= 0.0 {
        return (0.0, 0.0);
    }
    (rg / gg, rg * rg / gg)
}

/// Whether the discs' windows of two blobs overlap.
fn overlaps(a: &Blob, b: &Blob) -> bool {
    let reach = a.radius_px + b.radius_px + 1.0;
    (a.x_px as f64 - b.x_px as f64).abs() <= reach && (a.y_px as f64 - b.y_px as f64).abs() <= reach
}

/// Fits metaballs to the image (Nishita & Dobashi 2001, §3.1); see the module docs.
///
/// After each new ball, the centre densities of the balls overlapping it are re-optimised by
/// non-negative coordinate descent (each update is the exact minimiser along its coordinate, so
/// the error never rises and earlier balls that now overshoot are turned down); all balls are
/// refitted whenever the count reaches a power of two and once at the end.
pub fn fit(img: &GrayImage, params: &SatelliteParams) -> Result<FitResult> {
    fit_unless(img, params, &|| false)
}

/// [`fit`], stopped with [`Error::Cancelled`] once `cancelled` returns true (asked before every
/// new ball).
pub fn fit_unless(
    img: &GrayImage,
    params: &SatelliteParams,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<FitResult> {
    params.validate()?;
    let threshold = params.cloud_threshold as f32;
    let target: Vec<f64> = img
        .data
        .iter()
        .map(|&v| if v > threshold { v as f64 } else { 0.0 })
        .collect();
    let norm2: f64 = target.iter().map(|t| t * t).sum();
    if norm2 <= 0.0 {
        return Err(Error::invalid(
            "cloud_threshold",
            format!("no pixel is brighter than {threshold}, so the image holds no cloud"),
        ));
    }
    let mut r = Residual::new(img, target);
    let mut history = vec![1.0];
    let mut blobs: Vec<Blob> = Vec::new();
    let (rmin, rmax) = (params.min_radius_px, params.max_radius_px);
    let full_refit = |r: &mut Residual, blobs: &mut Vec<Blob>| {
        for blob in blobs.iter_mut() {
            r.refit(blob);
        }
        r.resum();
    };
    let converged = loop {
        if cancelled() {
            return Err(Error::Cancelled);
        }
        if (r.err2 / norm2).max(0.0).sqrt() < params.error_threshold {
            break true;
        }
        if blobs.len() >= params.max_balls {
            break false;
        }
        let Some((best, peak)) = r.brightest() else {
            break false;
        };
        if peak <= 0.0 {
            break false;
        }
        let (x, y) = (best % img.width, best / img.width);
        // Geometric scan of the radius, then golden-section refinement around the best.
        let steps = 16;
        let ratio = (rmax / rmin).powf(1.0 / steps as f64);
        let mut best_i = 0;
        let mut best_gain = -1.0;
        for i in 0..=steps {
            let gain = score(img, &r.res, x, y, rmin * ratio.powi(i)).1;
            if gain > best_gain {
                best_gain = gain;
                best_i = i;
            }
        }
        let (mut lo, mut hi) = (
            (rmin * ratio.powi(best_i - 1)).max(rmin).ln(),
            (rmin * ratio.powi(best_i + 1)).min(rmax).ln(),
        );
        let phi = 0.5 * (5f64.sqrt() - 1.0);
        for _ in 0..12 {
            let a = hi - phi * (hi - lo);
            let b = lo + phi * (hi - lo);
            if score(img, &r.res, x, y, a.exp()).1 > score(img, &r.res, x, y, b.exp()).1 {
                hi = b;
            } else {
                lo = a;
            }
        }
        let mut radius = (0.5 * (lo + hi)).exp();
        let (mut amplitude, mut gain) = score(img, &r.res, x, y, radius);
        if best_gain > gain {
            radius = rmin * ratio.powi(best_i);
            (amplitude, gain) = score(img, &r.res, x, y, radius);
        }
        if gain.is_nan() || gain <= 1e-12 * norm2 {
            break false;
        }
        let before = r.err2;
        let mut blob = Blob {
            x_px: x,
            y_px: y,
            radius_px: radius,
            amplitude: 0.0,
        };
        r.set_amplitude(&mut blob, amplitude);
        for other in blobs.iter_mut().filter(|b| overlaps(b, &blob)) {
            r.refit(other);
        }
        r.refit(&mut blob);
        blobs.push(blob);
        if blobs.len().is_power_of_two() {
            full_refit(&mut r, &mut blobs);
        }
        if r.err2 >= before {
            break false;
        }
        history.push((r.err2.max(0.0) / norm2).sqrt());
    };
    // A last pass over every ball can only lower the error; it refines the last entry.
    full_refit(&mut r, &mut blobs);
    let error = (r.err2.max(0.0) / norm2).sqrt();
    if let Some(last) = history.last_mut() {
        *last = last.min(error);
    }
    Ok(FitResult {
        blobs,
        error: history.last().copied().unwrap_or(error),
        error_history: history,
        converged: converged || error < params.error_threshold,
    })
}

/// World-space metaballs for the fitted blobs of non-zero amplitude: pixel (x, y) maps to
/// `((x + ½)·pixel, (height − y − ½)·pixel)` (north up), each ball resting on `cloud_base_m`, with
/// centre density `column_density_m · amplitude / (R · P(0))` so the column density of the ball
/// equals `column_density_m` times its projected image.
pub fn to_metaballs(
    img: &GrayImage,
    fit: &FitResult,
    params: &SatelliteParams,
) -> Result<Vec<Metaball>> {
    params.validate()?;
    let p0 = wyvill::column_integral_m(0.0, 1.0);
    let balls: Vec<Metaball> = fit
        .blobs
        .iter()
        .filter(|b| b.amplitude > 0.0)
        .map(|b| {
            let radius_m = b.radius_px * params.pixel_size_m;
            Metaball {
                centre_m: DVec3::new(
                    (b.x_px as f64 + 0.5) * params.pixel_size_m,
                    (img.height as f64 - b.y_px as f64 - 0.5) * params.pixel_size_m,
                    params.cloud_base_m + radius_m,
                ),
                radius_m,
                density: params.column_density_m * b.amplitude / (radius_m * p0),
            }
        })
        .collect();
    validate_balls(&balls)?;
    Ok(balls)
}

/// Decodes the PNG, fits metaballs and voxelises them at `voxel_size_m` (Nishita & Dobashi 2001, §3.1, eq 3).
pub fn voxelize(
    png_bytes: &[u8],
    params: &SatelliteParams,
    voxel_size_m: f64,
) -> Result<DensityGrid> {
    voxelize_with_fit(png_bytes, params, voxel_size_m).map(|(grid, _)| grid)
}

/// [`voxelize`], also returning the fit (final error, blobs, convergence) so callers can report it.
pub fn voxelize_with_fit(
    png_bytes: &[u8],
    params: &SatelliteParams,
    voxel_size_m: f64,
) -> Result<(DensityGrid, FitResult)> {
    voxelize_with_fit_within(png_bytes, params, voxel_size_m, super::grid::MAX_VOXELS)
}

/// [`voxelize_with_fit`], refusing a grid of more than `max_voxels` voxels (too large on `dims`)
/// once the fitted balls give its box, before it is allocated.
pub fn voxelize_with_fit_within(
    png_bytes: &[u8],
    params: &SatelliteParams,
    voxel_size_m: f64,
    max_voxels: usize,
) -> Result<(DensityGrid, FitResult)> {
    voxelize_with_fit_unless(png_bytes, params, voxel_size_m, max_voxels, &|| false)
}

/// [`voxelize_with_fit_within`], stopped with [`Error::Cancelled`] once `cancelled` returns true
/// (asked before every ball of the fit and every z-slice of the grid).
pub fn voxelize_with_fit_unless(
    png_bytes: &[u8],
    params: &SatelliteParams,
    voxel_size_m: f64,
    max_voxels: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<(DensityGrid, FitResult)> {
    let img = GrayImage::from_png_bytes(png_bytes)?;
    let fitted = fit_unless(&img, params, cancelled)?;
    let balls = to_metaballs(&img, &fitted, params)?;
    let grid = MetaballField::new(balls)?.voxelize_within_unless(
        voxel_size_m,
        voxel_size_m,
        max_voxels,
        cancelled,
    )?;
    Ok((grid, fitted))
}

/// A synthetic satellite-like image: clusters of Gaussian cloud cells of varied size and optical
/// thickness, shown as reflectance `1 − exp(−1.5 τ)` (bright, saturating cores; dim fringes).
/// Deterministic for `seed`; for tests, benchmarks and the example scene.
pub fn synthetic_cloud_field(side_px: usize, seed: u64) -> Result<GrayImage> {
    use rand::{Rng, SeedableRng};
    check_dims(side_px, side_px)?;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let s = side_px as f64;
    let clusters: Vec<(f64, f64)> = (0..8)
        .map(|_| {
            (
                rng.random_range(0.1 * s..0.9 * s),
                rng.random_range(0.1 * s..0.9 * s),
            )
        })
        .collect();
    let cells: Vec<(f64, f64, f64, f64)> = (0..(side_px / 3).max(3))
        .map(|i| {
            let (cx, cy) = clusters[i % clusters.len()];
            (
                cx + rng.random_range(-0.08 * s..0.08 * s),
                cy + rng.random_range(-0.08 * s..0.08 * s),
                rng.random_range(0.015 * s..0.06 * s),
                rng.random_range(0.3..1.0),
            )
        })
        .collect();
    let data = (0..side_px * side_px)
        .map(|i| {
            let (x, y) = ((i % side_px) as f64 + 0.5, (i / side_px) as f64 + 0.5);
            let tau: f64 = cells
                .iter()
                .map(|&(cx, cy, w, a)| {
                    a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * w * w)).exp()
                })
                .sum();
            (1.0 - (-1.5 * tau).exp()) as f32
        })
        .collect();
    GrayImage::new(side_px, side_px, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_table_matches_closed_form() {
        let p0 = wyvill::column_integral_m(0.0, 1.0);
        for i in 0..=1000 {
            let u = i as f64 / 1000.0;
            let exact = wyvill::column_integral_m(u, 1.0) / p0;
            assert!((profile(u * u) - exact).abs() < 1e-6, "u = {u}");
        }
        assert_eq!(profile(1.0), 0.0);
        assert_eq!(profile(0.0), 1.0);
    }

    #[test]
    fn tiled_maximum_tracks_the_residual() {
        let img = synthetic_cloud_field(70, 9).unwrap();
        let target: Vec<f64> = img.data.iter().map(|&v| v as f64).collect();
        let mut r = Residual::new(&img, target);
        let mut blob = Blob {
            x_px: 33,
            y_px: 40,
            radius_px: 9.5,
            amplitude: 0.0,
        };
        for step in 0..5 {
            r.set_amplitude(&mut blob, 0.3 * step as f64);
            let brute = r
                .res
                .iter()
                .enumerate()
                .filter(|(i, _)| r.cloud[*i])
                .map(|(_, v)| *v)
                .fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(r.brightest().unwrap().1, brute);
            let exact: f64 = r.res.iter().map(|v| v * v).sum();
            assert!((r.err2 - exact).abs() < 1e-9 * exact);
            blob.x_px += 7;
        }
    }
}
