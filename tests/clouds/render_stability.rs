//! Stability suite for cloud frames, through `render::render_frame`, the entry
//! point of the product: stiff and extreme scenes give finite, non-negative radiance bounded by
//! energy conservation, the frame is continuous in the sun angle, and the fast method's error
//! against the path tracer falls along the quality presets.
//! (tests/clouds/render_frame.rs has the first robustness cases: empty grid, single voxel, τ 1000,
//! g 0.99 and −0.9, camera inside; this file adds the rest of the stiff and extreme cases.)

use glam::DVec3;
use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::cloud::DensityGrid;
use skybake_render::compare::image_errors;
use skybake_render::light::fibonacci;
use skybake_render::{
    lighting_for, render_frame, render_tile, Frame, FrameScene, LitInputs, LitVolume, Method,
    Prepared, RenderSettings,
};
use std::f64::consts::PI;

/// Vacuum, collimated sun of normal irradiance 1, no sky, no ground.
fn vacuum_scene(centre: DVec3, view_m: f64) -> Value {
    json!({
        "name": "stability",
        "cloud": {"voxel_size_m": 20.0, "source": {"type": "metaballs",
                  "balls": [{"centre_m": [0, 0, 1000], "radius_m": 300, "density": 1.0}]}},
        "optics": {"extinction_per_density_m": 0.02, "single_scattering_albedo": 1.0,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": {"type": "orthographic",
                   "position_m": [centre.x, centre.y - 4.0 * view_m, centre.z],
                   "look_at_m": [centre.x, centre.y, centre.z], "up": [0, 0, 1],
                   "view_width_m": view_m, "width": 16, "height": 16},
        "sun": {"collimated": {"elevation_deg": 30, "azimuth_deg": 120, "normal_irradiance_w_m2_nm": 1.0}},
        "atmosphere": null, "sky": null, "ground": null,
        "wavelengths_nm": [550], "quality": "draft"
    })
}

fn parse(v: &Value) -> FrameScene {
    FrameScene::parse(v.to_string().as_bytes()).unwrap()
}

/// A ball of density 1, radius `r` (m), centre `c`, voxels of `h` m.
fn ball(c: DVec3, r: f64, h: f64) -> DensityGrid {
    let n = (2.0 * r / h).ceil() as usize + 2;
    let origin = c - DVec3::splat(0.5 * n as f64 * h);
    DensityGrid::from_fn([n, n, n], h, origin, |p| {
        if (p - c).length() < r {
            1.0
        } else {
            0.0
        }
    })
    .unwrap()
}

fn settings(scene: &FrameScene, method: Method, quality: Quality) -> RenderSettings {
    let mut s = RenderSettings::for_quality(quality, method);
    if method == Method::Reference {
        s.spp = s.spp.min(16);
    }
    let _ = scene;
    s
}

fn render(scene: &FrameScene, grid: &DensityGrid, method: Method) -> Frame {
    let lighting = lighting_for(scene, grid, &Engine::new()).unwrap();
    let s = settings(scene, method, scene.quality);
    render_frame(scene, grid, &lighting, &s, None, &|_| {}, &|| false).unwrap()
}

fn finite_non_negative(name: &str, f: &Frame) {
    assert!(
        f.radiance.iter().all(|x| x.is_finite() && *x >= 0.0),
        "{name}: non-finite or negative radiance"
    );
    assert!(
        f.transmittance
            .iter()
            .all(|t| t.is_finite() && (0.0..=1.0 + 1e-6).contains(t)),
        "{name}: transmittance outside [0, 1]"
    );
}

/// Scattered power leaving the cloud (Σ over `n_dirs` orthographic views, Fibonacci directions, of
/// ∫L dA · 4π/n_dirs) against the power the cloud takes out of the sun's beam (∫(1 − T) dA seen
/// from the sun), each view of `px`² pixels rendered by `frame`. With albedo 1 and black
/// surroundings they are equal.
fn scattered_over_taken(
    v: &Value,
    grid: &DensityGrid,
    px: usize,
    n_dirs: usize,
    frame: &dyn Fn(&FrameScene) -> Frame,
) -> f64 {
    let c = 0.5 * (grid.origin_m + grid.max_corner_m());
    let extent = (grid.max_corner_m() - grid.origin_m).length() * 1.05;
    let pixel_area = (extent / px as f64).powi(2);
    let mut v = v.clone();
    let ortho = |dir: DVec3| {
        let cam = c + dir * 4.0 * extent;
        let up = if dir.z.abs() > 0.9 {
            [0.0, 1.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        json!({"type": "orthographic", "position_m": [cam.x, cam.y, cam.z], "look_at_m": [c.x, c.y, c.z],
               "up": up, "view_width_m": extent, "width": px, "height": px})
    };
    let mut out = 0.0;
    for i in 0..n_dirs {
        v["camera"] = ortho(fibonacci(i, n_dirs));
        let f = frame(&parse(&v));
        out += f.radiance.iter().map(|&x| f64::from(x)).sum::<f64>() * pixel_area * 4.0 * PI
            / n_dirs as f64;
    }
    v["camera"] = ortho(parse(&v).sun.direction());
    let f = frame(&parse(&v));
    let taken: f64 = f
        .transmittance
        .iter()
        .map(|&t| (1.0 - f64::from(t)) * pixel_area)
        .sum();
    out / taken
}

/// [`scattered_over_taken`] over 26 views of 16² pixels, each frame rendered on its own: the fast
/// method must not make light (≤ 1.15, its measured excess is printed).
fn power_ratio(v: &Value, grid: &DensityGrid, method: Method) -> f64 {
    let base = parse(v);
    let lighting = lighting_for(&base, grid, &Engine::new()).unwrap();
    let s = settings(&base, method, base.quality);
    scattered_over_taken(v, grid, 16, 26, &|scene| {
        render_frame(scene, grid, &lighting, &s, None, &|_| {}, &|| false).unwrap()
    })
}

#[test]
fn voxel_sizes_of_one_metre_and_one_kilometre() {
    for (h, r) in [(1.0, 12.0), (1000.0, 9000.0)] {
        let c = DVec3::new(0.0, 0.0, 2.0 * r + 1000.0);
        let mut v = vacuum_scene(c, 2.4 * r);
        // The same optical radius (τ ≈ 10) at both scales.
        v["optics"]["extinction_per_density_m"] = json!(10.0 / r);
        let grid = ball(c, r, h);
        let scene = parse(&v);
        for method in [Method::Fast, Method::Reference] {
            let f = render(&scene, &grid, method);
            finite_non_negative(&format!("voxel {h} m {method:?}"), &f);
            assert!(
                f.radiance.iter().any(|&x| x > 0.0),
                "voxel {h} m {method:?}: the lit cloud is black"
            );
        }
        let ratio = power_ratio(&v, &grid, Method::Fast);
        println!("voxel {h} m: fast method scattered power out/in = {ratio:.3}");
        assert!(
            ratio <= 1.15,
            "voxel {h} m: the fast method makes light ({ratio})"
        );
    }
}

#[test]
fn optically_thick_cloud_conserves_energy_in_the_fast_method() {
    // τ ≈ 1000 along the diameter, albedo 1.
    let c = DVec3::new(0.0, 0.0, 1000.0);
    let mut v = vacuum_scene(c, 800.0);
    v["optics"]["extinction_per_density_m"] = json!(1000.0 / 600.0);
    let grid = ball(c, 300.0, 30.0);
    let ratio = power_ratio(&v, &grid, Method::Fast);
    println!("τ 1000: fast method scattered power out/in = {ratio:.3}");
    assert!(ratio.is_finite() && ratio <= 1.15, "τ 1000: out/in {ratio}");
    // Measured 0.959 with the field seen through the face in the skins' cells too (0.968
    // without; 0.951 before the sun's single scattering was attenuated through σ_t⁺,
    // 0.63 before the march's thick steps and the photon pass's diffusion jumps; 26 views do not
    // resolve the forward lobe exactly).
    assert!(ratio > 0.9, "τ 1000: the fast method loses light ({ratio})");
}

/// A camera after a lit volume's first reads the sky light's transmittances the volume keeps
/// (per distinct extinction): its per-voxel records are bit for bit those computed without them,
/// here with three wavelengths of two extinctions and sky and sun light.
#[test]
fn a_shared_lit_volume_gives_the_same_voxel_records() {
    let c = DVec3::new(0.0, 0.0, 1000.0);
    let mut v = vacuum_scene(c, 800.0);
    v["wavelengths_nm"] = json!([450, 550, 650]);
    v["optics"]["extinction_per_density_m"] = json!({"450": 0.02, "550": 0.02, "650": 0.03});
    v["sky"] = json!({"constant_radiance_w_m2_sr_nm": 0.1});
    let base = parse(&v);
    let grid = ball(c, 300.0, 30.0);
    let lighting = lighting_for(&base, &grid, &Engine::new()).unwrap();
    let s = settings(&base, Method::Fast, base.quality);
    let inputs = LitInputs::new(&base, std::sync::Arc::new(grid.clone()), &lighting, s);
    let lit = std::sync::Arc::new(LitVolume::new(inputs, &|| false).unwrap());
    let alone = Prepared::with_lit(&base, &lighting, s, lit.clone(), false, &|| false).unwrap();
    let shared = Prepared::with_lit(&base, &lighting, s, lit.clone(), true, &|| false).unwrap();
    assert!(lit.sky_trans.get().is_some_and(|t| t.bytes() > 0));
    assert!(alone.vox.iter().any(|&x| x > 0.0));
    assert_eq!(alone.vox.len(), shared.vox.len());
    let same = alone
        .vox
        .iter()
        .zip(&shared.vox)
        .all(|(a, b)| a.to_bits() == b.to_bits());
    assert!(same, "the kept transmittances change the voxel records");
}

/// [`scattered_over_taken`] with 96 views of `px`² pixels sharing one lit volume.
fn power_ratio_shared(v: &Value, grid: &DensityGrid, px: usize) -> f64 {
    let base = parse(v);
    let lighting = lighting_for(&base, grid, &Engine::new()).unwrap();
    let s = settings(&base, Method::Fast, base.quality);
    let shared = std::sync::Arc::new(grid.clone());
    let lit = std::sync::Arc::new(
        LitVolume::new(LitInputs::new(&base, shared, &lighting, s), &|| false).unwrap(),
    );
    scattered_over_taken(v, grid, px, 96, &|scene| {
        let p = Prepared::with_lit(scene, &lighting, s, lit.clone(), true, &|| false).unwrap();
        render_tile(&p, None, &|_| {}, &|| false).unwrap()
    })
}

/// Energy in voxels of many optical depths: a conservative ball of radius 300 m in voxels of
/// 30 m, τ 1000 through the centre (51 optical depths per voxel) and τ 160 (8 per voxel), sun
/// only, vacuum, 96 views. Nothing is transmitted, so the scattered power out must equal the
/// power the ball intercepts. Measured (draft, default photon seed / seed 1), with the photon
/// field's skin tallies (docs/frames.md, "Energy"): τ 1000 1.023 / 1.012 with an isotropic
/// phase function, 0.999 / 1.004 with Henyey-Greenstein g = 0.85 (one cell mean per surface
/// voxel: 1.056 / 1.031 and 1.000 / 0.985; 0.453 and 0.694 before the march's thick steps and
/// the photon pass's diffusion jumps); τ 160 1.069 / 1.056 isotropic (1.110 / 1.094 before the
/// skin tallies), 0.910 / 0.948 with g = 0.85 (0.918 / 0.949). The photon noise of one seed is
/// about ±0.03 (over four seeds before the skin tallies, τ 1000: 1.024–1.079 and 0.976–0.998),
/// hence the bounds: the measured figures plus that noise. With the sun's single scattering
/// attenuated through σ_t⁺ (docs/frames.md, "δ-M truncation and TMS", item 6), this test reads
/// 1.026 / 1.005 (τ 1000, isotropic / g = 0.85) and 1.068 / 0.928 (τ 160); with the field
/// seen through the face towards the camera (docs/frames.md, "fast"), also in these cells (all
/// have skins) beyond the skin's depth, 0.979 / 0.996 and 1.029 / 0.921.
#[test]
fn optically_thick_voxels_conserve_energy() {
    let c = DVec3::new(0.0, 0.0, 1000.0);
    let grid = ball(c, 300.0, 30.0);
    for (tau, g, bounds) in [
        (1000.0, 0.0, 0.97..=1.06),
        (1000.0, 0.85, 0.97..=1.04),
        (160.0, 0.0, 0.97..=1.10),
        (160.0, 0.85, 0.87..=0.99),
    ] {
        let mut v = vacuum_scene(c, 800.0);
        v["optics"]["extinction_per_density_m"] = json!(tau / 600.0);
        v["optics"]["phase"] = json!({"henyey_greenstein": {"g": g}});
        let ratio = power_ratio_shared(&v, &grid, 32);
        println!("τ {tau} ball, g {g}: fast method scattered power out/in = {ratio:.4}");
        assert!(
            bounds.contains(&ratio),
            "τ {tau} ball, g {g}: out/in {ratio}"
        );
    }
}

#[test]
fn sun_at_the_horizon_and_overhead_over_a_cloud_in_the_atmosphere() {
    let c = DVec3::new(0.0, 0.0, 1500.0);
    let mut v = vacuum_scene(c, 800.0);
    v["atmosphere"] = json!("earth");
    v["sky"] = json!("atmosphere");
    v["ground"] = json!({"albedo": 0.2, "height_m": 0});
    v["wavelengths_nm"] = json!([440, 550, 680]);
    let grid = ball(c, 300.0, 30.0);
    for elevation in [-0.5, 0.0, 90.0] {
        v["sun"] = json!({"elevation_deg": elevation, "azimuth_deg": 120});
        let scene = parse(&v);
        let f = render(&scene, &grid, Method::Fast);
        finite_non_negative(&format!("sun {elevation}°"), &f);
    }
}

#[test]
fn cloud_above_the_top_of_the_atmosphere() {
    let c = DVec3::new(0.0, 0.0, 120_000.0);
    let mut v = vacuum_scene(c, 800.0);
    v["atmosphere"] = json!("earth");
    v["sky"] = json!("atmosphere");
    v["ground"] = json!({"albedo": 0.2, "height_m": 0});
    v["sun"] = json!({"elevation_deg": 20, "azimuth_deg": 120});
    let grid = ball(c, 300.0, 30.0);
    let scene = parse(&v);
    for method in [Method::Fast, Method::Reference] {
        let f = render(&scene, &grid, method);
        finite_non_negative(&format!("above TOA {method:?}"), &f);
        assert!(
            f.radiance.iter().any(|&x| x > 0.0),
            "above TOA: black cloud"
        );
    }
}

/// Mean cloud radiance over a sun sweep: no jump between neighbouring sun positions beyond what
/// the light itself does (the sun's path through the atmosphere), and no jump at all in vacuum.
#[test]
fn continuous_in_the_sun_angle() {
    let c = DVec3::new(0.0, 0.0, 1500.0);
    let grid = ball(c, 300.0, 30.0);
    let mean = |v: &Value| {
        let f = render(&parse(v), &grid, Method::Fast);
        f.radiance.iter().map(|&x| f64::from(x)).sum::<f64>() / f.radiance.len() as f64
    };
    // Vacuum: the sun's beam is the same at every elevation; steps of 2° change little.
    let mut v = vacuum_scene(c, 800.0);
    let mut last: Option<f64> = None;
    for e in (0..=10).map(|i| 2.0 + 8.0 * i as f64) {
        v["sun"]["collimated"]["elevation_deg"] = json!(e);
        let m = mean(&v);
        if let Some(prev) = last {
            let change = (m / prev - 1.0f64).abs();
            assert!(change < 0.25, "vacuum: {change:.3} change at sun {e}°");
        }
        last = Some(m);
    }
    // Earth atmosphere through sunset, steps of 0.5°: the frame follows the light smoothly.
    let mut v = vacuum_scene(c, 800.0);
    v["atmosphere"] = json!("earth");
    v["sky"] = json!("atmosphere");
    v["ground"] = json!({"albedo": 0.2, "height_m": 0});
    let means: Vec<f64> = [-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0]
        .iter()
        .map(|&e| {
            v["sun"] = json!({"elevation_deg": e, "azimuth_deg": 120});
            mean(&v)
        })
        .collect();
    println!("sunset sweep mean radiance: {means:?}");
    assert!(means.iter().all(|m| m.is_finite() && *m > 0.0));
    for w in means.windows(2) {
        assert!(w[1] >= w[0] * 0.98, "not rising with the sun: {means:?}");
        assert!(w[1] <= w[0] * 4.0, "jump through sunset: {means:?}");
    }
}

/// The fast method's error against the converged path tracer falls along the presets.
#[test]
fn fast_error_falls_along_the_presets() {
    let c = DVec3::new(0.0, 0.0, 1000.0);
    let mut v = vacuum_scene(c, 700.0);
    v["sky"] = json!({"constant_radiance_w_m2_sr_nm": 0.05});
    v["camera"]["width"] = json!(32);
    v["camera"]["height"] = json!(32);
    let grid = ball(c, 300.0, 20.0);
    let scene = parse(&v);
    let lighting = lighting_for(&scene, &grid, &Engine::new()).unwrap();
    let mut pt = RenderSettings::for_quality(Quality::High, Method::Reference);
    pt.spp = 512;
    let reference = render_frame(&scene, &grid, &lighting, &pt, None, &|_| {}, &|| false).unwrap();
    let mask: Vec<bool> = reference.transmittance.iter().map(|&t| t < 0.99).collect();
    let mut errors = Vec::new();
    for q in [Quality::Draft, Quality::Standard, Quality::High] {
        let s = RenderSettings::for_quality(q, Method::Fast);
        let f = render_frame(&scene, &grid, &lighting, &s, None, &|_| {}, &|| false).unwrap();
        let e = image_errors(&f.radiance, &reference.radiance, &mask, 32, 1);
        errors.push(e.nrmse_blocks);
    }
    let noise = reference
        .meta
        .error_estimate
        .path_tracer_relative_noise
        .unwrap_or(0.0);
    // The reference's per-pixel noise, averaged over an 8×8 block.
    let block_noise = noise / 8.0;
    println!(
        "fast block NRMSE draft/standard/high: {errors:?} (reference block noise {block_noise:.4})"
    );
    // Monotone up to twice the reference's own block noise.
    for w in errors.windows(2) {
        assert!(
            w[1] <= w[0] + 2.0 * block_noise,
            "error rises with quality: {errors:?}"
        );
    }
}
