//! Orders 2 and 3 by the reference pattern of Nishita et al. 1996, §3.4, measured against the
//! path tracer restricted to the same orders (`min_orders` 2, `max_orders` 3: the independent,
//! unbiased estimate of exactly what the pattern approximates), on a 20³ cloud of non-uniform
//! density in vacuum lit by a collimated sun, HG g = 0.85, at optical diameters 3 and 20. The
//! pattern's image of orders 2 + 3 is the fast frame with the pattern minus the fast frame with
//! multiple scattering switched off (the same exact single scattering), both through
//! `render::render_frame`. Also measured: the share of all orders that orders ≤ 3 carry at the
//! centre of the τ = 20 cloud (a fisheye camera at the centre, path tracer all orders vs ≤ 3).

use glam::DVec3;
use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_physics::cloud::DensityGrid;
use skybake_render::compare::{image_errors, ImageErrors};
use skybake_render::{lighting_for, render_frame, Frame, FrameScene, Method, RenderSettings};

const H: f64 = 20.0;
const N: usize = 20;
const CENTRE: DVec3 = DVec3::new(0.0, 0.0, 1200.0);
/// Radius of the cloud's support, m.
const R: f64 = 9.0 * H;

/// A smooth blob (1 − r²/R²) modulated by ±30 % waves, so that the local densities differ from the
/// pattern's average density; its optical diameter through the centre is k·4R/3 (the waves are
/// zero along the axes through the centre).
fn blob() -> DensityGrid {
    let side = N as f64 * H;
    DensityGrid::from_fn([N; 3], H, CENTRE - DVec3::splat(0.5 * side), |p| {
        let q = p - CENTRE;
        let f = 1.0 - q.length_squared() / (R * R);
        if f <= 0.0 {
            return 0.0;
        }
        let w = (q.x / 47.0).sin() * (q.y / 61.0).sin() * (q.z / 53.0).sin();
        (f * (1.0 + 0.3 * w)) as f32
    })
    .unwrap()
}

/// Extinction per unit density for an optical diameter `tau` through the blob's centre.
fn k_for(tau: f64) -> f64 {
    tau / (4.0 * R / 3.0)
}

fn scene(tau: f64, sun_elev: f64, sun_az: f64, camera: Value, pattern: bool) -> FrameScene {
    let v = json!({
        "cloud": {"voxel_size_m": H, "source": {"type": "metaballs",
                  "balls": [{"centre_m": [0, 0, 1200], "radius_m": 180, "density": 1.0}]}},
        "optics": {"extinction_per_density_m": k_for(tau), "single_scattering_albedo": 1.0,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": camera,
        "sun": {"collimated": {"elevation_deg": sun_elev, "azimuth_deg": sun_az,
                               "normal_irradiance_w_m2_nm": 1.0}},
        "atmosphere": null, "sky": null, "ground": null,
        "wavelengths_nm": [550], "quality": "standard",
        "multiple_scattering_method": if pattern { "reference_pattern" } else { "all_orders" }
    });
    FrameScene::parse(v.to_string().as_bytes()).unwrap()
}

fn side_camera(px: usize) -> Value {
    json!({"type": "pinhole", "position_m": [0, -1500, 1200], "look_at_m": [0, 0, 1200],
           "up": [0, 0, 1], "fov_deg": 16, "width": px, "height": px})
}

fn render(scene: &FrameScene, grid: &DensityGrid, s: &RenderSettings) -> Frame {
    let lighting = lighting_for(scene, grid, &Engine::new()).unwrap();
    render_frame(scene, grid, &lighting, s, None, &|_| {}, &|| false).unwrap()
}

/// The pattern's orders 2 + 3 and the path tracer's, with the pattern's figures from the stages.
fn orders_2_3(tau: f64, sun_elev: f64, sun_az: f64, px: usize, spp: usize) -> ImageErrors {
    let grid = blob();
    let with = scene(tau, sun_elev, sun_az, side_camera(px), true);
    let fast = RenderSettings::for_quality(with.quality, Method::Fast);
    let f_pattern = render(&with, &grid, &fast);
    let mut without = with.clone();
    without.lighting.multiple_scattering = false;
    let f_single = render(&without, &grid, &fast);
    let pattern: Vec<f32> = f_pattern
        .radiance
        .iter()
        .zip(&f_single.radiance)
        .map(|(a, b)| a - b)
        .collect();
    let mut pt = RenderSettings::for_quality(with.quality, Method::Reference);
    pt.spp = spp;
    pt.min_orders = 2;
    pt.max_orders = 3;
    let t = std::time::Instant::now();
    let f_pt = render(&with, &grid, &pt);
    let pt_s = t.elapsed().as_secs_f64();
    let mask: Vec<bool> = f_pt.transmittance.iter().map(|&t| t < 0.99).collect();
    let e = image_errors(&pattern, &f_pt.radiance, &mask, px, 1);
    let noise = f_pt
        .meta
        .error_estimate
        .path_tracer_relative_noise
        .unwrap_or(0.0);
    let ms_stage = f_pattern
        .meta
        .stages
        .ran
        .iter()
        .find(|s| s.contains("reference pattern"))
        .cloned()
        .unwrap_or_default();
    let share = |name: &str| {
        let total: f64 = f_pattern.meta.timing_ms.iter().map(|t| t.1).sum();
        f_pattern
            .meta
            .timing_ms
            .iter()
            .find(|t| t.0 == name)
            .map_or(0.0, |t| t.1 / total)
    };
    // The path tracer's own noise in an 8×8 block mean (its per-pixel noise / 8), removed in
    // quadrature for the pattern's own block error.
    let block_noise = noise / 8.0;
    println!(
        "tau {tau}, sun {sun_elev}/{sun_az}: orders 2+3 block NRMSE {:.3} ({:.3} without the path tracer's block noise {block_noise:.3}), pixel NRMSE {:.3}, bias {:+.3} ({} cloud px; path tracer noise {:.4}); pattern stage {:.0} % of the frame time; path tracer {pt_s:.1} s\n  {ms_stage}",
        e.nrmse_blocks,
        (e.nrmse_blocks.powi(2) - block_noise.powi(2)).max(0.0).sqrt(),
        e.nrmse_pixels,
        e.mean_bias,
        e.cloud_pixels,
        noise,
        100.0 * share("reference_pattern"),
    );
    assert!(
        ms_stage.contains("Nishita et al. 1996, §3.4"),
        "{:?}",
        f_pattern.meta.stages
    );
    assert!(f_pattern
        .meta
        .timing_ms
        .iter()
        .any(|t| t.0 == "reference_pattern"));
    e
}

/// Optical diameter 3 (the pattern's domain: thin clouds), sun from the side (scattering angle
/// about 90°) and from behind the cloud (about 18°). Measured (64², 256 spp): side block NRMSE
/// 0.196 (0.165 without the path tracer's block noise of 0.106), bias +10.9 %; back 0.074,
/// +2.7 %. The bounds guard these figures.
#[test]
fn pattern_orders_2_3_match_the_path_tracer_thin_cloud() {
    let side = orders_2_3(3.0, 30.0, 90.0, 64, 256);
    assert!(side.cloud_pixels > 2000);
    assert!(side.nrmse_blocks < 0.24, "{side:?}");
    assert!(side.mean_bias.abs() < 0.14, "{side:?}");
    let back = orders_2_3(3.0, 15.0, 10.0, 64, 256);
    assert!(back.nrmse_blocks < 0.10, "{back:?}");
    assert!(back.mean_bias.abs() < 0.05, "{back:?}");
}

/// Optical diameter 20 (0.65 per voxel at the average density), sun from the side: measured
/// (64², 128 spp) block NRMSE 0.235 (0.199 without the path tracer's block noise of 0.126),
/// bias +9.3 %. Orders 2 and 3 are right, but here they are a small part of the light (below).
#[test]
fn pattern_orders_2_3_match_the_path_tracer_thick_cloud() {
    let e = orders_2_3(20.0, 30.0, 90.0, 64, 128);
    assert!(e.cloud_pixels > 2000);
    assert!(e.nrmse_blocks < 0.28, "{e:?}");
    assert!(e.mean_bias.abs() < 0.13, "{e:?}");
}

/// At the centre of the τ = 20 cloud (g 0.85, albedo 1; the centre is 10 optical depths from the
/// surface) orders ≤ 3 carry a small share of the radiance: fisheye camera (360°, equidistant) at the centre, the solid-angle weighted mean
/// (weight sin θ/θ per pixel) of the path tracer with orders ≤ 3 over all orders.
#[test]
fn low_orders_are_a_small_share_at_the_thick_cloud_centre() {
    let grid = blob();
    let px = 24;
    let cam = json!({"type": "fisheye", "position_m": [0, 0, 1200], "look_at_m": [0, 1, 1200],
                     "up": [0, 0, 1], "fov_deg": 360, "width": px, "height": px});
    let sc = scene(20.0, 30.0, 90.0, cam, false);
    let mut s = RenderSettings::for_quality(sc.quality, Method::Reference);
    s.spp = 64;
    let all = render(&sc, &grid, &s);
    s.max_orders = 3;
    let low = render(&sc, &grid, &s);
    s.max_orders = 1;
    let first = render(&sc, &grid, &s);
    let rad_per_px = std::f64::consts::PI / (0.5 * px as f64);
    let mean = |f: &Frame| {
        let (mut sum, mut wsum) = (0.0, 0.0);
        for y in 0..px {
            for x in 0..px {
                let (dx, dy) = (
                    x as f64 + 0.5 - 0.5 * px as f64,
                    0.5 * px as f64 - y as f64 - 0.5,
                );
                let theta = (dx * dx + dy * dy).sqrt() * rad_per_px;
                if theta > std::f64::consts::PI {
                    continue;
                }
                let w = theta.sin() / theta;
                sum += w * f.radiance[y * px + x] as f64;
                wsum += w;
            }
        }
        sum / wsum
    };
    let (a, l, o1) = (mean(&all), mean(&low), mean(&first));
    println!(
        "tau 20 centre: mean radiance all orders {a:.4e}, orders <= 3 {l:.4e} ({:.1} %), order 1 {o1:.4e} ({:.1} %)",
        100.0 * l / a,
        100.0 * o1 / a
    );
    // Measured 0.5 % (orders ≤ 3) and 0.06 % (order 1); the required bound is < 10 %.
    assert!(a > 0.0 && l > 0.0);
    assert!(l / a < 0.02, "{l} / {a}");
}
