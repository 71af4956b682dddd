//! Output forms of the atmosphere products: JSON documents (serde structs) and PNG previews.
//! Encoding only; writing files is the caller's (CLI) or the store's business.

use crate::engine::{AerialProduct, DomeProduct, ErrorEstimate, Probe, ProductMeta};
use crate::spec::CommonSpec;
use crate::{Error, Result};
use serde::Serialize;
use skybake_physics::atmosphere::sky::DomeTable;
use skybake_physics::spectrum::colour::{srgb_encode, XyzWeights};

/// JSON form of a sky or ground product.
#[derive(Debug, Serialize)]
pub struct DomeJson<'a> {
    pub product: &'static str,
    pub wavelengths_nm: &'a [f64],
    pub sun_elevation_deg: f64,
    pub observer_altitude_m: f64,
    /// Rows of the table: view elevation, degrees (view zenith = 90° − elevation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub elevation_deg: Option<&'a [f64]>,
    /// Columns: view azimuth relative to the sun, degrees (symmetric: 0–180° covers the sky).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub azimuth_deg: Option<&'a [f64]>,
    /// `[row][col][λ]`, W m⁻² sr⁻¹ nm⁻¹ (left out when probes are requested).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radiance_w_m2_sr_nm: Option<Vec<Vec<&'a [f32]>>>,
    #[serde(skip_serializing_if = "<[Probe]>::is_empty")]
    pub probes: &'a [Probe],
    pub error_estimate: &'a ErrorEstimate,
    pub timing_ms: f64,
    pub meta: &'a ProductMeta,
    pub spec: &'a CommonSpec,
}

impl<'a> DomeJson<'a> {
    pub fn new(product: &'static str, p: &'a DomeProduct, spec: &'a CommonSpec) -> Self {
        let t = &p.table;
        let n_l = t.wavelengths_nm.len();
        let with_table = p.probes.is_empty();
        let rows = with_table.then(|| {
            t.radiance
                .chunks(t.azimuth_deg.len() * n_l)
                .map(|row| row.chunks(n_l).collect())
                .collect()
        });
        Self {
            product,
            wavelengths_nm: &t.wavelengths_nm,
            sun_elevation_deg: spec.sun.sun_elevation_deg,
            observer_altitude_m: spec.observer_altitude_m,
            elevation_deg: with_table.then_some(&t.elevation_deg[..]),
            azimuth_deg: with_table.then_some(&t.azimuth_deg[..]),
            radiance_w_m2_sr_nm: rows,
            probes: &p.probes,
            error_estimate: &p.meta.error_estimate,
            timing_ms: p.meta.timing_ms,
            meta: &p.meta,
            spec,
        }
    }
}

/// JSON form of an aerial-perspective product.
#[derive(Debug, Serialize)]
pub struct AerialJson<'a> {
    pub product: &'static str,
    pub wavelengths_nm: &'a [f64],
    pub elevation_deg: &'a [f64],
    pub azimuth_deg: &'a [f64],
    pub distance_m: &'a [f64],
    /// `[elevation][azimuth][distance][λ]`.
    pub transmittance: Vec<Vec<Vec<&'a [f32]>>>,
    /// `[elevation][azimuth][distance][λ]`, W m⁻² sr⁻¹ nm⁻¹.
    pub inscatter_w_m2_sr_nm: Vec<Vec<Vec<&'a [f32]>>>,
    pub error_estimate: &'a ErrorEstimate,
    pub timing_ms: f64,
    pub meta: &'a ProductMeta,
    pub spec: &'a CommonSpec,
}

/// Views a flat `[row][azimuth][distance][λ]` array as nested slices for JSON.
pub fn nest4(v: &[f32], n_az: usize, n_d: usize, n_l: usize) -> Vec<Vec<Vec<&[f32]>>> {
    v.chunks(n_az * n_d * n_l)
        .map(|row| {
            row.chunks(n_d * n_l)
                .map(|dir| dir.chunks(n_l).collect())
                .collect()
        })
        .collect()
}

impl<'a> AerialJson<'a> {
    pub fn new(p: &'a AerialProduct, spec: &'a CommonSpec) -> Self {
        let (n_az, n_d, n_l) = (
            p.azimuth_deg.len(),
            p.distance_m.len(),
            p.wavelengths_nm.len(),
        );
        Self {
            product: "aerial",
            wavelengths_nm: &p.wavelengths_nm,
            elevation_deg: &p.elevation_deg,
            azimuth_deg: &p.azimuth_deg,
            distance_m: &p.distance_m,
            transmittance: nest4(&p.transmittance, n_az, n_d, n_l),
            inscatter_w_m2_sr_nm: nest4(&p.inscatter, n_az, n_d, n_l),
            error_estimate: &p.meta.error_estimate,
            timing_ms: p.meta.timing_ms,
            meta: &p.meta,
            spec,
        }
    }
}

/// Linear sRGB planes (R, G, B) of a spectral table whose pixels hold `n_l` samples each.
pub fn rgb_planes(wavelengths_nm: &[f64], spectral: &[f32]) -> [Vec<f32>; 3] {
    let n_l = wavelengths_nm.len();
    let w = XyzWeights::new(wavelengths_nm);
    let mut planes = [Vec::new(), Vec::new(), Vec::new()];
    let mut buf = vec![0.0; n_l];
    for px in spectral.chunks(n_l) {
        for (b, v) in buf.iter_mut().zip(px) {
            *b = *v as f64;
        }
        let rgb = w.linear_srgb(&buf);
        for c in 0..3 {
            planes[c].push(rgb[c] as f32);
        }
    }
    planes
}

/// Image projection of a PNG preview.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Projection {
    /// Equidistant fisheye of the table's hemisphere, zenith (or nadir) at the centre, the sun
    /// towards the top of the image.
    Fisheye,
    /// Latitude-longitude: azimuth −180…180° across, elevation top to bottom.
    LatLong,
}

/// Renders a PNG preview of a dome table: spectral → XYZ → linear sRGB, exposed so that the
/// median luminance maps to 0.18 (a photographic middle grey; the sun's aureole may clip),
/// then sRGB-encoded to 8 bits.
pub fn dome_png(t: &DomeTable, projection: Projection, size: usize) -> Result<Vec<u8>> {
    if !(16..=4096).contains(&size) {
        return Err(Error::out_of_range("size", size, "16 to 4096 pixels"));
    }
    let n_l = t.wavelengths_nm.len();
    let w = XyzWeights::new(&t.wavelengths_nm);
    let (width, height) = match projection {
        Projection::Fisheye => (size, size),
        Projection::LatLong => (size * 2, size),
    };
    let lower = t.elevation_deg.iter().all(|&e| e <= 0.0);
    let (e_lo, e_hi) = (
        t.elevation_deg[0],
        t.elevation_deg[t.elevation_deg.len() - 1],
    );
    let sample = |elev: f64, az: f64, buf: &mut [f64]| {
        let az = az.abs() % 360.0;
        let az = if az > 180.0 { 360.0 - az } else { az };
        let (r, fr) = axis_pos(&t.elevation_deg, elev);
        let (c, fc) = axis_pos(&t.azimuth_deg, az);
        let n_az = t.azimuth_deg.len();
        let r1 = (r + 1).min(t.elevation_deg.len() - 1);
        let c1 = (c + 1).min(n_az - 1);
        for (i, b) in buf.iter_mut().enumerate() {
            let v = |rr: usize, cc: usize| t.radiance[(rr * n_az + cc) * n_l + i] as f64;
            *b = (v(r, c) * (1.0 - fc) + v(r, c1) * fc) * (1.0 - fr)
                + (v(r1, c) * (1.0 - fc) + v(r1, c1) * fc) * fr;
        }
    };
    let mut rgb = vec![[0.0f64; 3]; width * height];
    let mut lum = Vec::with_capacity(width * height);
    let mut buf = vec![0.0; n_l];
    for y in 0..height {
        for x in 0..width {
            let (elev, az) = match projection {
                Projection::Fisheye => {
                    let dx = (x as f64 + 0.5) / width as f64 * 2.0 - 1.0;
                    let dy = (y as f64 + 0.5) / height as f64 * 2.0 - 1.0;
                    let rad = (dx * dx + dy * dy).sqrt();
                    if rad > 1.0 {
                        continue;
                    }
                    let off = 90.0 * rad;
                    let elev = if lower { -90.0 + off } else { 90.0 - off };
                    (elev, dx.atan2(-dy).to_degrees())
                }
                Projection::LatLong => {
                    let az = ((x as f64 + 0.5) / width as f64 * 360.0) - 180.0;
                    let elev = e_hi - (y as f64 + 0.5) / height as f64 * (e_hi - e_lo);
                    (elev, az)
                }
            };
            sample(elev, az, &mut buf);
            let xyz = w.xyz(&buf);
            lum.push(xyz[1]);
            rgb[y * width + x] = skybake_physics::spectrum::xyz_to_linear_srgb(xyz);
        }
    }
    // Expose on the lit part of the view (space around a planet seen from orbit is black).
    let exposure = middle_grey_exposure(lum);
    exposed_srgb_png(width, height, exposure, |i| rgb[i])
}

/// The exposure that maps the median of the positive luminances to 0.18 (photographic middle
/// grey); 1 when nothing is lit.
fn middle_grey_exposure(mut lum: Vec<f64>) -> f64 {
    lum.retain(|&y| y > 0.0);
    lum.sort_by(f64::total_cmp);
    let mid = lum.get(lum.len() / 2).copied().unwrap_or(1.0);
    if mid > 0.0 {
        0.18 / mid
    } else {
        1.0
    }
}

/// 8-bit sRGB PNG of `width` × `height` linear sRGB pixels (`pixel(i)`, row-major) times `exposure`.
fn exposed_srgb_png(
    width: usize,
    height: usize,
    exposure: f64,
    pixel: impl Fn(usize) -> [f64; 3],
) -> Result<Vec<u8>> {
    let mut img = image::RgbImage::new(width as u32, height as u32);
    for (i, px) in img.pixels_mut().enumerate() {
        *px = image::Rgb(pixel(i).map(|v| (srgb_encode(v * exposure) * 255.0).round() as u8));
    }
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| Error::invalid("format", format!("PNG encoding failed: {e}")))?;
    Ok(bytes)
}

/// (lower index, fraction) of `x` on an ascending axis, clamped.
fn axis_pos(axis: &[f64], x: f64) -> (usize, f64) {
    let n = axis.len();
    if n == 1 || x <= axis[0] {
        return (0, 0.0);
    }
    if x >= axis[n - 1] {
        return (n - 1, 0.0);
    }
    let i = axis.partition_point(|&v| v <= x) - 1;
    (i, (x - axis[i]) / (axis[i + 1] - axis[i]))
}

/// PNG of a rendered frame from its linear sRGB planes (the frame's `R`, `G`, `B`): exposed so
/// that the median luminance of the lit pixels maps to 0.18 (photographic middle grey; bright
/// cloud tops may clip), then sRGB-encoded to 8 bits. Pixels are row-major, top row first.
pub fn frame_png(width: usize, height: usize, rgb: &[Vec<f32>; 3]) -> Result<Vec<u8>> {
    let n = width * height;
    if n == 0 || rgb.iter().any(|p| p.len() != n) {
        return Err(Error::invalid(
            "frame",
            "RGB planes do not match the image size",
        ));
    }
    let pixel = |i: usize| [rgb[0][i], rgb[1][i], rgb[2][i]].map(f64::from);
    let lum = (0..n)
        .map(|i| {
            let [r, g, b] = pixel(i);
            0.2126 * r + 0.7152 * g + 0.0722 * b
        })
        .collect();
    exposed_srgb_png(width, height, middle_grey_exposure(lum), pixel)
}
