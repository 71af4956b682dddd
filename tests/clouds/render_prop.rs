//! Stability of cloud frames as properties (invariants that hold for
//! any input are `proptest` properties). Random small clouds (2–8 voxels a side of random
//! density, voxels of 1 m to 1 km, optical thickness 0.1 to 1000 across, single-scattering
//! albedo 0.9 to 1, Henyey-Greenstein g from −0.9 to 0.99, sun elevation −0.5° to 90°, camera
//! outside or inside the cloud) lit by a collimated sun in vacuum with black surroundings (no sky,
//! no ground), rendered through `render::render_frame`, the entry point the product runs.
//!
//! Asserted for every cloud: finite, non-negative radiance and a transmittance in [0, 1] from the
//! fast method and the path tracer; scattered power out ≤ power taken out of the sun's beam
//! × 1.15 (the fast method must not make light; albedo ≤ 1 and nothing else to reflect it);
//! continuity in the sun angle (a 0.05° turn of the sun changes the mean radiance by < 5 %); and,
//! on moderate clouds, the fast method's error against a converged path tracer does not grow from
//! the draft to the high preset beyond the reference's own noise.
//!
//! The cases are few and the frames tiny (8×8 to 16×16 pixels) so that the file runs in seconds;
//! the RNG seed is fixed so a failure reproduces (proptest also shrinks it to a small case).
//! tests/clouds/render_stability.rs has the hand-picked extremes (τ 1000 ball, 1 m and 1 km voxels,
//! sun at −0.5°, 0°, 90° in the atmosphere, a cloud above the top of the atmosphere).

use glam::DVec3;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};
use rand::{Rng, SeedableRng};
use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_physics::atmosphere::quality::Quality;
use skybake_physics::cloud::DensityGrid;
use skybake_render::compare::image_errors;
use skybake_render::light::fibonacci;
use skybake_render::{
    lighting_for, render_frame, Frame, FrameScene, Lighting, Method, RenderSettings,
};
use std::f64::consts::PI;

/// A random small cloud and its light.
#[derive(Debug, Clone)]
struct Cloud {
    dims: [usize; 3],
    voxel_m: f64,
    /// Optical thickness across the grid's largest dimension at its mean density.
    tau: f64,
    albedo: f64,
    g: f64,
    sun_elevation_deg: f64,
    sun_azimuth_deg: f64,
    camera_inside: bool,
    /// Seed of the voxel densities.
    seed: u64,
}

fn clouds(
    tau_log10: std::ops::Range<f64>,
    g: std::ops::Range<f64>,
) -> impl Strategy<Value = Cloud> {
    (
        prop::array::uniform3(2usize..=8),
        0.0f64..3.0,
        tau_log10,
        0.9f64..=1.0,
        g,
        -0.5f64..=90.0,
        0.0f64..360.0,
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(|(dims, v, t, albedo, g, e, a, inside, seed)| Cloud {
            dims,
            voxel_m: 10f64.powf(v),
            tau: 10f64.powf(t),
            albedo,
            g,
            sun_elevation_deg: e,
            sun_azimuth_deg: a,
            camera_inside: inside,
            seed,
        })
}

impl Cloud {
    /// Density 0 to 1 per voxel (a quarter of them empty), the box's centre 2 km up.
    fn grid(&self) -> DensityGrid {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(self.seed);
        let n = self.dims[0] * self.dims[1] * self.dims[2];
        let values: Vec<f32> = (0..n)
            .map(|_| {
                let u: f32 = rng.random();
                if u < 0.25 {
                    0.0
                } else {
                    (u - 0.25) / 0.75
                }
            })
            .collect();
        let side = DVec3::new(
            self.dims[0] as f64,
            self.dims[1] as f64,
            self.dims[2] as f64,
        ) * self.voxel_m;
        let origin = DVec3::new(0.0, 0.0, 2000.0) - 0.5 * side;
        let d = self.dims;
        DensityGrid::from_fn(d, self.voxel_m, origin, |p| {
            let q = (p - origin) / self.voxel_m;
            let (x, y, z) = (q.x as usize, q.y as usize, q.z as usize);
            values[(z.min(d[2] - 1) * d[1] + y.min(d[1] - 1)) * d[0] + x.min(d[0] - 1)]
        })
        .unwrap()
    }

    fn centre(&self) -> DVec3 {
        DVec3::new(0.0, 0.0, 2000.0)
    }

    /// Diagonal of the box, m.
    fn extent_m(&self) -> f64 {
        DVec3::new(
            self.dims[0] as f64,
            self.dims[1] as f64,
            self.dims[2] as f64,
        )
        .length()
            * self.voxel_m
    }

    /// The scene: vacuum, collimated sun of normal irradiance 1, no sky, no ground, 550 nm.
    fn scene(&self, grid: &DensityGrid, camera: Value) -> Value {
        let mean = grid.data.iter().map(|&v| f64::from(v)).sum::<f64>() / grid.data.len() as f64;
        let across = *self.dims.iter().max().unwrap() as f64 * self.voxel_m;
        let k = self.tau / (mean.max(1e-3) * across);
        json!({
            "name": "prop",
            "cloud": {"voxel_size_m": self.voxel_m, "source": {"type": "metaballs",
                      "balls": [{"centre_m": [0, 0, 2000], "radius_m": self.voxel_m, "density": 1.0}]}},
            "optics": {"extinction_per_density_m": k, "single_scattering_albedo": self.albedo,
                       "phase": {"henyey_greenstein": {"g": self.g}}},
            "camera": camera,
            "sun": {"collimated": {"elevation_deg": self.sun_elevation_deg,
                                   "azimuth_deg": self.sun_azimuth_deg,
                                   "normal_irradiance_w_m2_nm": 1.0}},
            "atmosphere": null, "sky": null, "ground": null,
            "wavelengths_nm": [550], "quality": "draft"
        })
    }

    /// An orthographic camera looking at the centre from direction `dir`, seeing the whole box.
    fn ortho(&self, dir: DVec3, px: usize) -> Value {
        let c = self.centre();
        let extent = self.extent_m() * 1.05;
        let cam = c + dir * 4.0 * extent;
        let up = if dir.z.abs() > 0.9 {
            [0.0, 1.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        json!({"type": "orthographic", "position_m": [cam.x, cam.y, cam.z],
               "look_at_m": [c.x, c.y, c.z], "up": up, "view_width_m": extent,
               "width": px, "height": px})
    }

    /// The property's camera: outside (orthographic, from the side) or at the cloud's centre
    /// (pinhole, 90°).
    fn camera(&self, px: usize) -> Value {
        if self.camera_inside {
            let c = self.centre();
            json!({"type": "pinhole", "position_m": [c.x, c.y, c.z],
                   "look_at_m": [c.x + 1.0, c.y + 0.3, c.z + 0.2], "up": [0, 0, 1],
                   "fov_deg": 90, "width": px, "height": px})
        } else {
            self.ortho(DVec3::new(0.3, -1.0, 0.2).normalize(), px)
        }
    }
}

fn parse(v: &Value) -> FrameScene {
    FrameScene::parse(v.to_string().as_bytes()).unwrap()
}

fn lighting(v: &Value, grid: &DensityGrid) -> Lighting {
    lighting_for(&parse(v), grid, &Engine::new()).unwrap()
}

fn render(v: &Value, grid: &DensityGrid, lt: &Lighting, s: &RenderSettings) -> Frame {
    render_frame(&parse(v), grid, lt, s, None, &|_| {}, &|| false).unwrap()
}

/// The fast method's draft settings with a small photon pass (black surroundings: no
/// environment photons carry light).
fn fast_small() -> RenderSettings {
    let mut s = RenderSettings::for_quality(Quality::Draft, Method::Fast);
    s.photons.sun_photons = 1 << 13;
    s.photons.env_photons = 0;
    s
}

fn finite_non_negative(f: &Frame) -> Result<(), TestCaseError> {
    prop_assert!(
        f.radiance.iter().all(|x| x.is_finite() && *x >= 0.0),
        "non-finite or negative radiance"
    );
    prop_assert!(
        f.transmittance
            .iter()
            .all(|t| t.is_finite() && (0.0..=1.0 + 1e-6).contains(t)),
        "transmittance outside [0, 1]"
    );
    Ok(())
}

/// Scattered power leaving the cloud, Σ over 26 orthographic views of ∫L dA · 4π/26, against the
/// power the cloud takes out of the sun's beam, ∫(1 − T) dA seen from the sun (as
/// tests/clouds/render_stability.rs). The 26 directions are turned so that none lies within 20° of the
/// sun beam's forward direction: a strongly forward-peaked phase function (g → 0.99) puts its
/// light in a cone a few degrees wide that one quadrature direction would over-count by orders of
/// magnitude; left out, the sum is a lower estimate of the power out, which is what an upper
/// bound needs.
fn power_ratio(c: &Cloud, grid: &DensityGrid, s: &RenderSettings) -> f64 {
    let px = 8;
    let extent = c.extent_m() * 1.05;
    let pixel_area = (extent / px as f64).powi(2);
    let mut v = c.scene(grid, c.ortho(DVec3::Y, px));
    let lt = lighting(&v, grid);
    let sun = parse(&v).sun.direction();
    let forward = -sun;
    let n_dirs = 26;
    let mut out = 0.0;
    for i in 0..n_dirs {
        let dir = fibonacci(i, n_dirs);
        if dir.dot(forward) > 20f64.to_radians().cos() {
            continue;
        }
        v["camera"] = c.ortho(dir, px);
        let f = render(&v, grid, &lt, s);
        out += f.radiance.iter().map(|&x| f64::from(x)).sum::<f64>() * pixel_area * 4.0 * PI
            / n_dirs as f64;
    }
    v["camera"] = c.ortho(sun, px);
    let f = render(&v, grid, &lt, s);
    let taken: f64 = f
        .transmittance
        .iter()
        .map(|&t| (1.0 - f64::from(t)) * pixel_area)
        .sum();
    if taken <= 0.0 {
        0.0
    } else {
        out / taken
    }
}

fn config(cases: u32) -> Config {
    Config {
        cases,
        failure_persistence: None,
        rng_seed: RngSeed::Fixed(0x05EE_DF15),
        ..Config::default()
    }
}

proptest! {
    #![proptest_config(config(8))]

    /// Finite, non-negative frames from both methods, camera outside or inside, and no light
    /// made by the fast method.
    #[test]
    fn frames_are_finite_non_negative_and_make_no_light(c in clouds(-1.0..3.0, -0.9..0.99)) {
        let grid = c.grid();
        let v = c.scene(&grid, c.camera(8));
        let lt = lighting(&v, &grid);
        let fast = render(&v, &grid, &lt, &fast_small());
        finite_non_negative(&fast)?;
        let mut pt = RenderSettings::for_quality(Quality::Draft, Method::Reference);
        pt.spp = 2;
        let traced = render(&v, &grid, &lt, &pt);
        finite_non_negative(&traced)?;
        let ratio = power_ratio(&c, &grid, &fast_small());
        prop_assert!(ratio.is_finite() && ratio <= 1.15, "fast method power out/in {ratio}");
    }

    /// The mean radiance is continuous in the sun angle: turning the sun by 0.05° (elevation and
    /// azimuth) changes it by less than 5 % plus three times the photon pass's own noise (the
    /// largest change under two other random streams; a turn may change the streams' mapping to
    /// paths, e.g. where the photon disc's basis flips at the horizon).
    #[test]
    fn continuous_in_the_sun_angle(c in clouds(-1.0..3.0, -0.9..0.99)) {
        let grid = c.grid();
        let mean = |c: &Cloud, seed: u64| {
            let v = c.scene(&grid, c.camera(8));
            let lt = lighting(&v, &grid);
            let mut s = RenderSettings::for_quality(Quality::Draft, Method::Fast);
            s.photons.env_photons = 0;
            s.photons.seed = seed;
            let f = render(&v, &grid, &lt, &s);
            f.radiance.iter().map(|&x| f64::from(x)).sum::<f64>() / f.radiance.len() as f64
        };
        let seed = RenderSettings::for_quality(Quality::Draft, Method::Fast).photons.seed;
        let a = mean(&c, seed);
        let noise = [1u64, 2].iter().map(|k| (mean(&c, seed ^ (k << 40)) - a).abs()).fold(0.0, f64::max);
        let mut turned = c.clone();
        turned.sun_elevation_deg = (c.sun_elevation_deg + 0.05).min(90.0);
        turned.sun_azimuth_deg += 0.05;
        let b = mean(&turned, seed);
        prop_assert!(a.is_finite() && b.is_finite());
        prop_assert!(
            (a - b).abs() <= 0.05 * a.max(b) + 3.0 * noise + 1e-12,
            "mean radiance {a:.4e} -> {b:.4e} for a 0.05° turn of the sun (photon noise {noise:.2e})"
        );
    }
}

proptest! {
    #![proptest_config(config(3))]

    /// On moderate clouds (optical thickness 0.3 to 10, g 0 to 0.9, camera outside) the fast
    /// method's per-pixel error against the path tracer at 1024 samples per pixel does not grow
    /// from `draft` to `high` beyond twice the reference's own pixel noise (+1 %).
    #[test]
    fn fast_error_does_not_grow_along_the_presets(
        c in clouds(-0.5..1.0, 0.0..0.9).prop_map(|c| Cloud { camera_inside: false, ..c })
    ) {
        let px = 16;
        let grid = c.grid();
        let v = c.scene(&grid, c.camera(px));
        let lt = lighting(&v, &grid);
        let mut pt = RenderSettings::for_quality(Quality::High, Method::Reference);
        pt.spp = 1024;
        pt.seed = 0xC0FFEE;
        let reference = render(&v, &grid, &lt, &pt);
        let mask: Vec<bool> = reference.transmittance.iter().map(|&t| t < 0.99).collect();
        prop_assume!(mask.iter().filter(|&&m| m).count() >= 16);
        let noise = reference.meta.error_estimate.path_tracer_relative_noise.unwrap_or(0.0);
        let error = |q: Quality| {
            let mut s = RenderSettings::for_quality(q, Method::Fast);
            s.photons.env_photons = 0;
            let f = render(&v, &grid, &lt, &s);
            image_errors(&f.radiance, &reference.radiance, &mask, px, 1).nrmse_pixels
        };
        let (draft, high) = (error(Quality::Draft), error(Quality::High));
        prop_assert!(
            high <= draft + 2.0 * noise + 0.01,
            "pixel NRMSE draft {draft:.4}, high {high:.4} (reference noise {noise:.4})"
        );
    }
}
