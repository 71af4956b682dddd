//! Products → spectral images (the stored form of every product): one emissive channel per wavelength
//! (`S0.<λ>nm`), linear sRGB for viewers, and the table axes as a header attribute. The request,
//! response, plan, error estimate and timing attributes are added by [`crate::artifact`],
//! the one place that makes artifacts. Encoding only; `store` writes.

use crate::Result;
use skybake_engine::engine::{AerialProduct, DomeProduct, SunProduct};
use skybake_engine::output::rgb_planes;
use skybake_store::{layout, SpectralImage};

/// The sun product as a 1×1 spectral image: layer `T` holds the transmittance (the irradiances
/// are in the JSON envelope).
pub fn sun_image(p: &SunProduct) -> Result<SpectralImage> {
    let t: Vec<Vec<f32>> = p.transmittance.iter().map(|&t| vec![t as f32]).collect();
    let mut img = SpectralImage::new(1, 1, &p.wavelengths_nm)?;
    img.add_layer(layout::TRANSMITTANCE_LAYER, t)?;
    Ok(img)
}

/// A sky or ground table as a spectral image: rows are view elevations from the highest (top
/// row) down, columns azimuths 0…180° from the sun; attribute `skybakeAxes` lists both.
pub fn dome_image(p: &DomeProduct) -> Result<SpectralImage> {
    let t = &p.table;
    let (w, h, n_l) = (
        t.azimuth_deg.len(),
        t.elevation_deg.len(),
        t.wavelengths_nm.len(),
    );
    let mut planes = vec![vec![0f32; w * h]; n_l];
    let mut flipped = vec![0f32; w * h * n_l];
    for row in 0..h {
        let src_row = h - 1 - row;
        for col in 0..w {
            for (i, plane) in planes.iter_mut().enumerate() {
                let v = t.radiance[(src_row * w + col) * n_l + i];
                plane[row * w + col] = v;
                flipped[(row * w + col) * n_l + i] = v;
            }
        }
    }
    let mut img = SpectralImage::emissive(w, h, &t.wavelengths_nm, planes)?;
    img.set_rgb(rgb_planes(&t.wavelengths_nm, &flipped))?;
    let mut rows = t.elevation_deg.clone();
    rows.reverse();
    let axes = serde_json::json!({ "rows_view_elevation_deg": rows, "columns_view_azimuth_deg": t.azimuth_deg });
    img.set_attribute("skybakeAxes", axes.to_string())?;
    Ok(img)
}

/// An aerial-perspective table as a spectral image: one row per direction (elevation-major,
/// then azimuth), one column per distance; layer `S0` holds in-scattered radiance and layer
/// `T` transmittance.
pub fn aerial_image(p: &AerialProduct) -> Result<SpectralImage> {
    let (n_d, n_l) = (p.distance_m.len(), p.wavelengths_nm.len());
    let h = p.elevation_deg.len() * p.azimuth_deg.len();
    let to_planes = |v: &[f32]| -> Vec<Vec<f32>> {
        (0..n_l)
            .map(|i| (0..h * n_d).map(|px| v[px * n_l + i]).collect())
            .collect()
    };
    let mut img = SpectralImage::emissive(n_d, h, &p.wavelengths_nm, to_planes(&p.inscatter))?;
    img.add_layer(layout::TRANSMITTANCE_LAYER, to_planes(&p.transmittance))?;
    img.set_rgb(rgb_planes(&p.wavelengths_nm, &p.inscatter))?;
    let axes = serde_json::json!({
        "rows": "elevation-major, then azimuth",
        "view_elevation_deg": p.elevation_deg,
        "view_azimuth_deg": p.azimuth_deg,
        "columns_distance_m": p.distance_m,
    });
    img.set_attribute("skybakeAxes", axes.to_string())?;
    Ok(img)
}
/// A rendered cloud frame as a spectral image (width × height of the camera): layer `S0` holds
/// the spectral radiance of each pixel, layer `T` the cloud's transmittance along the pixel's ray
/// (mean over wavelengths, repeated per wavelength), plus linear sRGB. Its attributes are added
/// by [`crate::artifact::frame_artifact`].
pub fn frame_image(frame: &skybake_render::Frame) -> Result<SpectralImage> {
    let (w, h, n_l) = (
        frame.tile.width,
        frame.tile.height,
        frame.wavelengths_nm.len(),
    );
    let mut planes = vec![vec![0f32; w * h]; n_l];
    for (p, spectrum) in frame.radiance.chunks(n_l).enumerate() {
        for (plane, v) in planes.iter_mut().zip(spectrum) {
            plane[p] = *v;
        }
    }
    let mut img = SpectralImage::emissive(w, h, &frame.wavelengths_nm, planes)?;
    img.add_layer(
        layout::TRANSMITTANCE_LAYER,
        vec![frame.transmittance.clone(); n_l],
    )?;
    img.set_rgb(rgb_planes(&frame.wavelengths_nm, &frame.radiance))?;
    Ok(img)
}
