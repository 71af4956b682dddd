//! Satellite-image cloud modelling (Nishita & Dobashi 2001, §3.1): greedy metaball fitting lowers the image
//! error at every step and reaches the threshold; the 3-D cloud reproduces the fitted image as
//! column density; PNG input is validated.

use glam::DVec3;
use skybake_physics::cloud::metaballs::MetaballField;
use skybake_physics::cloud::satellite::{
    approximated_image, fit, synthetic_cloud_field, to_metaballs, GrayImage, SatelliteParams,
};

fn png_bytes(width: u32, height: u32, pixels: Vec<u16>) -> Vec<u8> {
    let img =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(width, height, pixels).unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

#[test]
fn fitting_error_decreases_every_step_and_ends_below_threshold() {
    let img = synthetic_cloud_field(64, 3).unwrap();
    let mut params = SatelliteParams::new("synthetic");
    params.error_threshold = 0.08;
    let result = fit(&img, &params).unwrap();
    assert!(
        result.converged,
        "stopped at error {} with {} balls",
        result.error,
        result.blobs.len()
    );
    assert!(result.error < 0.08);
    assert_eq!(result.error_history.len(), result.blobs.len() + 1);
    assert_eq!(result.error_history[0], 1.0);
    assert_eq!(*result.error_history.last().unwrap(), result.error);
    for w in result.error_history.windows(2) {
        assert!(w[1] < w[0], "error rose from {} to {}", w[0], w[1]);
    }
    // The reported error is the error of the approximated image against the masked image.
    let model = approximated_image(img.width, img.height, &result.blobs).unwrap();
    let (mut num, mut den) = (0.0, 0.0);
    for (&v, m) in img.data.iter().zip(&model) {
        let t = if v > params.cloud_threshold as f32 {
            v as f64
        } else {
            0.0
        };
        num += (t - m).powi(2);
        den += t * t;
    }
    assert!(((num / den).sqrt() - result.error).abs() < 1e-9);
}

#[test]
fn cloud_column_density_reproduces_the_fitted_image() {
    let img = synthetic_cloud_field(32, 5).unwrap();
    let mut params = SatelliteParams::new("synthetic");
    params.pixel_size_m = 100.0;
    params.max_balls = 40;
    let result = fit(&img, &params).unwrap();
    let balls = to_metaballs(&img, &result, &params).unwrap();
    // Flat base: every ball rests on the base plane.
    for b in &balls {
        assert!((b.centre_m.z - b.radius_m - params.cloud_base_m).abs() < 1e-9);
    }
    let model = approximated_image(img.width, img.height, &result.blobs).unwrap();
    let field = MetaballField::new(balls).unwrap();
    let top = field.bounds_m().1.z;
    for (y, x) in [(5usize, 7usize), (16, 16), (20, 9), (28, 30), (11, 24)] {
        let cx = (x as f64 + 0.5) * params.pixel_size_m;
        let cy = (img.height as f64 - y as f64 - 0.5) * params.pixel_size_m;
        // Midpoint rule in z over the cloud's vertical extent.
        let n = 4000;
        let dz = (top - params.cloud_base_m) / n as f64;
        let column: f64 = (0..n)
            .map(|k| {
                field.density(DVec3::new(
                    cx,
                    cy,
                    params.cloud_base_m + (k as f64 + 0.5) * dz,
                ))
            })
            .sum::<f64>()
            * dz;
        let expected = params.column_density_m * model[y * img.width + x];
        assert!(
            (column - expected).abs() < 1e-3 * params.column_density_m,
            "pixel ({x}, {y}): column {column} vs {expected}"
        );
    }
}

#[test]
fn png_round_trip_keeps_grey_levels() {
    let (w, h) = (7u32, 5u32);
    let pixels: Vec<u16> = (0..w * h).map(|i| (i * 1871 % 65536) as u16).collect();
    let img = GrayImage::from_png_bytes(&png_bytes(w, h, pixels.clone())).unwrap();
    assert_eq!((img.width, img.height), (7, 5));
    for (v, p) in img.data.iter().zip(&pixels) {
        assert!((*v as f64 - *p as f64 / 65535.0).abs() < 1e-6);
    }
}

#[test]
fn bad_images_and_parameters_are_refused() {
    assert_eq!(
        GrayImage::from_png_bytes(b"not a png").unwrap_err().field(),
        "image"
    );
    // Valid PNG but too wide: refused from the header.
    let wide = png_bytes(8192, 1, vec![0; 8192]);
    let err = GrayImage::from_png_bytes(&wide).unwrap_err();
    assert_eq!(err.field(), "image");
    assert!(err.to_string().contains("8192"), "{err}");
    // Truncated PNG.
    let ok = png_bytes(16, 16, vec![30000; 256]);
    assert_eq!(
        GrayImage::from_png_bytes(&ok[..ok.len() / 2])
            .unwrap_err()
            .field(),
        "image"
    );
    assert_eq!(
        GrayImage::new(2, 2, vec![0.0, 0.5, 1.5, 0.0])
            .unwrap_err()
            .field(),
        "image"
    );
    // A cloudless image.
    let blank = GrayImage::new(8, 8, vec![0.1; 64]).unwrap();
    let params = SatelliteParams::new("blank");
    assert_eq!(fit(&blank, &params).unwrap_err().field(), "cloud_threshold");
    let mut bad = SatelliteParams::new("x");
    bad.min_radius_px = 30.0;
    assert_eq!(fit(&blank, &bad).unwrap_err().field(), "min_radius_px");
    let mut bad = SatelliteParams::new("x");
    bad.pixel_size_m = f64::INFINITY;
    assert_eq!(fit(&blank, &bad).unwrap_err().field(), "pixel_size_m");
}
