//! Validation: the path tracer (and the fast method's figures) against independent codes:
//! (a) DISORT for a laterally huge homogeneous slab (tests/data/cloud_slab_disort.json, made by
//! tools/cloud_slab_disort.py with pydisort 1.8.13, 128 streams), (b) Mitsuba 3 `volpath` for a
//! 3-D cloud grid lit by a sun and a constant sky in vacuum (tests/data/cloud_mitsuba_*.npy and
//! validation-cloud-*.json, made by tools/cloud_mitsuba.py with Mitsuba 3.9.1). Every render goes
//! through `render::render_frame`.

use glam::DVec3;
use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_physics::cloud::DensityGrid;
use skybake_render::{
    lighting_for, render_frame, render_tile, FrameScene, LitInputs, LitVolume, Method, Prepared,
    RenderSettings, Tile,
};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");

/// Reads a 1.0/2.0 `.npy` of little-endian float32 or uint8 as f32.
fn npy(name: &str) -> Vec<f32> {
    let b = std::fs::read(format!("{DATA}/{name}")).unwrap();
    assert_eq!(&b[..6], b"\x93NUMPY");
    let (hl, start) = if b[6] == 1 {
        (u16::from_le_bytes([b[8], b[9]]) as usize, 10)
    } else {
        (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
    };
    let header = String::from_utf8_lossy(&b[start..start + hl]).to_string();
    let data = &b[start + hl..];
    if header.contains("<f4") {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else if header.contains("u1") {
        data.iter().map(|&v| v as f32).collect()
    } else {
        panic!("{name}: unsupported dtype in {header}")
    }
}

/// tests/data/README.md's statistics over a region: cloud blocks are 8×8 blocks aligned at pixel
/// (0, 0) whose pixels are all in the mask; block NRMSE and pixel NRMSE relative to the
/// reference's cloud mean; bias = test mean / reference mean − 1.
fn stats(
    test: &[f32],
    reference: &[f32],
    mask: &[bool],
    width: usize,
    height: usize,
) -> (f64, f64, f64) {
    let (mut st, mut sr, mut se2, mut n) = (0.0, 0.0, 0.0, 0usize);
    for i in 0..mask.len() {
        if mask[i] {
            let (a, b) = (test[i] as f64, reference[i] as f64);
            st += a;
            sr += b;
            se2 += (a - b).powi(2);
            n += 1;
        }
    }
    let mean_r = sr / n as f64;
    let (mut be2, mut nb) = (0.0, 0usize);
    for by in 0..height / 8 {
        for bx in 0..width / 8 {
            let idx: Vec<usize> = (0..64)
                .map(|k| (by * 8 + k / 8) * width + bx * 8 + k % 8)
                .collect();
            if idx.iter().all(|&i| mask[i]) {
                let a: f64 = idx.iter().map(|&i| test[i] as f64).sum::<f64>() / 64.0;
                let b: f64 = idx.iter().map(|&i| reference[i] as f64).sum::<f64>() / 64.0;
                be2 += (a - b).powi(2);
                nb += 1;
            }
        }
    }
    assert!(nb > 0, "no cloud blocks");
    (
        (be2 / nb as f64).sqrt() / mean_r,
        (se2 / n as f64).sqrt() / mean_r,
        st / sr - 1.0,
    )
}

fn settings(scene: &FrameScene, method: Method, spp: usize) -> RenderSettings {
    let mut s = RenderSettings::for_quality(scene.quality, method);
    s.spp = spp;
    s
}

/// A committed validation case: its scene (`validation-cloud-CASE.json`), the scene's voxels and
/// Mitsuba 3's image of it (`cloud_mitsuba_CASE.npy`).
fn validation_case(case: &str) -> (FrameScene, DensityGrid, Vec<f32>) {
    let bytes = std::fs::read(format!("{DATA}/validation-cloud-{case}.json")).unwrap();
    let scene = FrameScene::parse(&bytes).unwrap();
    let grid = scene
        .cloud
        .voxelize(&|p: &str| {
            std::fs::read(format!("{DATA}/{p}"))
                .map_err(|e| skybake_physics::Error::invalid("path", e))
        })
        .unwrap();
    let reference = npy(&format!("cloud_mitsuba_{case}.npy"));
    (scene, grid, reference)
}

/// The fast method's frame of a scene, lit as a request's frame is.
fn fast_frame(scene: &FrameScene, grid: &DensityGrid) -> skybake_render::Frame {
    let lighting = lighting_for(scene, grid, &Engine::new()).unwrap();
    render_frame(
        scene,
        grid,
        &lighting,
        &settings(scene, Method::Fast, 1),
        None,
        &|_| {},
        &|| false,
    )
    .unwrap()
}

/// The DISORT table, its view zeniths and relative azimuths, and the case of `tau`, `albedo`, `mu0`.
fn disort_case(tau: f64, albedo: f64, mu0: f64) -> (Value, Vec<f64>, Vec<f64>) {
    let data: Value =
        serde_json::from_slice(&std::fs::read(format!("{DATA}/cloud_slab_disort.json")).unwrap())
            .unwrap();
    let axis = |k: &str| -> Vec<f64> {
        data[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    let (views, azs) = (axis("view_zenith_deg"), axis("relative_azimuth_deg"));
    let case = data["cases"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| {
            c["optical_thickness"] == json!(tau)
                && c["single_scattering_albedo"] == json!(albedo)
                && c["mu0"] == json!(mu0)
        })
        .unwrap_or_else(|| panic!("no DISORT case {tau} {albedo} {mu0}"))
        .clone();
    (case, views, azs)
}

/// The slab's grid: 4 km wide, 100 m thick in 4 voxels (40 thicknesses, so light lost at the
/// sides is negligible at the centre).
const SLAB_VOXEL_M: f64 = 25.0;
const SLAB_THICKNESS_M: f64 = 100.0;

fn slab_grid() -> DensityGrid {
    let (h, nxy, nz) = (SLAB_VOXEL_M, 160usize, 4usize);
    let origin = DVec3::new(-0.5 * nxy as f64 * h, -0.5 * nxy as f64 * h, 1000.0);
    DensityGrid::from_fn([nxy, nxy, nz], h, origin, |_| 1.0).unwrap()
}

/// A scene looking at the slab's top from view zenith `vz_deg` and azimuth `raz` from the sun's
/// (tests/data/cloud_slab_disort.json's conventions), orthographic, `width_m` across, from
/// `distance_m` away, `px`² pixels.
#[allow(clippy::too_many_arguments)]
fn slab_scene(
    tau: f64,
    albedo: f64,
    mu0: f64,
    vz_deg: f64,
    raz: f64,
    width_m: f64,
    distance_m: f64,
    px: usize,
) -> FrameScene {
    let a_sun: f64 = 100.0;
    let vz = vz_deg.to_radians();
    let a = (a_sun + 180.0 + raz).to_radians();
    let prop = DVec3::new(vz.sin() * a.sin(), vz.sin() * a.cos(), vz.cos());
    let target = DVec3::new(0.0, 0.0, 1000.0 + SLAB_THICKNESS_M);
    let cam = target + prop * distance_m;
    let up = if vz_deg == 0.0 {
        [0.0, 1.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    let v = json!({
        "cloud": {"voxel_size_m": SLAB_VOXEL_M, "source": {"type": "metaballs", "balls": [{"centre_m": [0, 0, 1000], "radius_m": 100, "density": 1}]}},
        "optics": {"extinction_per_density_m": tau / SLAB_THICKNESS_M, "single_scattering_albedo": albedo,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": {"type": "orthographic", "position_m": [cam.x, cam.y, cam.z], "look_at_m": [target.x, target.y, target.z],
                   "up": up, "view_width_m": width_m, "width": px, "height": px},
        "sun": {"collimated": {"elevation_deg": 90.0 - mu0.acos().to_degrees(), "azimuth_deg": a_sun, "normal_irradiance_w_m2_nm": 1.0}},
        "atmosphere": null, "sky": null, "ground": null, "wavelengths_nm": [550], "quality": "standard"
    });
    FrameScene::parse(v.to_string().as_bytes()).unwrap()
}

fn mean_radiance(f: &skybake_render::Frame) -> f64 {
    f.radiance.iter().map(|&x| x as f64).sum::<f64>() / f.radiance.len() as f64
}

/// (a) DISORT slab: reflected radiance at the top for a subset of the cases (view zenith 0 and
/// 60°, towards and away from the sun), path tracer within 2 % plus three of its own standard
/// errors (1–2.6 % at these sample counts: forward-peaked sun paths are heavy-tailed), on a 40 m
/// patch at the centre.
#[test]
fn slab_reflection_matches_disort() {
    let grid = slab_grid();
    let mut worst_pt = Vec::new();
    for (tau, albedo, mu0) in [(1.0f64, 1.0f64, 0.5f64), (8.0, 1.0, 0.5), (32.0, 0.99, 1.0)] {
        let (case, views, azs) = disort_case(tau, albedo, mu0);
        for (vi, ai) in [(0usize, 0usize), (2, 0), (2, 2)] {
            let expected = case["reflected_radiance_per_sr"][vi][ai].as_f64().unwrap();
            let scene = slab_scene(tau, albedo, mu0, views[vi], azs[ai], 40.0, 300.0, 4);
            let lighting = lighting_for(&scene, &grid, &Engine::new()).unwrap();
            let spp = if tau < 2.0 { 16384 } else { 4096 };
            let pt = render_frame(
                &scene,
                &grid,
                &lighting,
                &settings(&scene, Method::Reference, spp),
                None,
                &|_| {},
                &|| false,
            )
            .unwrap();
            // Noise of the 16-pixel mean (the metadata's figure is per pixel).
            let sigma = pt
                .meta
                .error_estimate
                .path_tracer_relative_noise
                .unwrap_or(0.0)
                / 4.0;
            let rp = mean_radiance(&pt) / expected - 1.0;
            println!(
                "tau {tau} albedo {albedo} mu0 {mu0} vz {} raz {}: DISORT {expected:.5} path tracer {:+.2} % (noise {:.2} %)",
                views[vi],
                azs[ai],
                rp * 100.0,
                sigma * 100.0,
            );
            // 2 %, widened by three standard errors where forward-peaked sun paths leave the
            // estimate noisier than that (optically thin cases seen off the sun's side).
            worst_pt.push((rp, sigma));
        }
    }
    for (rp, sigma) in worst_pt {
        assert!(
            rp.abs() < 0.02 + 3.0 * sigma,
            "path tracer {rp} (noise {sigma})"
        );
    }
}

/// (a) DISORT slab, the fast method at every listed view angle (zenith 0–75°, azimuth 0/90/180°
/// from the sun's side), sun at 60° from the zenith, τ 1, 8 and 32 (albedo 1): the mean
/// radiance over a patch 1.6 km·cos(view zenith) across at the slab's centre (tens of coarse
/// cells of the multiple-scattering field, so the comparison measures the method rather than
/// one cell's photon noise; ≥ 1 km from the edges, 10 thicknesses), the camera 5 km away so no
/// orthographic ray starts inside the slab. The bounds are the measured worst deviation per τ
/// (docs/frames.md) plus a margin for the photon noise; the target, 5 %, does not hold.
#[test]
fn fast_slab_every_angle_against_disort() {
    let grid = std::sync::Arc::new(slab_grid());
    // Measured worst views (P3 field, thick march steps, the field's skin tallies in thick
    // cells, the sun's path continued to the grid's faces, a sun-only frame's whole photon
    // budget on the sun, the sun's single scattering through σ_t⁺ and spread over the view's
    // path, the smooth part's kink held, the field seen through the face towards the camera):
    // with the peak's turned light gathered along the turned direction (`march/turned.rs`):
    // τ 1 −12.1 % (75°, towards the sun; nadir −10.5 %), τ 8 +7.9 % (75°, away; towards
    // −6.6 %; +9.9 % / −7.0 % before the outward light's depth profile in thin surface voxels,
    // `multiple/face.rs`), τ 32 +9.7 % (75°, away; towards −6.9 %; before the gathering −15.9 %, −10.0 %
    // (75° towards), +9.7 % (towards −9.0 %); its cells have skins: seen through the
    // face beyond the skin's depth, +14.8 % when they were left as they were). Before the field
    // was seen through the face: τ 1 −15.6 % (75°, towards the sun; nadir −11.3 %), τ 8
    // +18.5 % (75°, away from the sun; towards it −5.3 %), τ 32 +14.8 % (75°, away; nadir
    // +1.6 %; the photon seeds spread it by ±2 points). Before the kink was held: −15.8 %,
    // +18.4 %, +14.7 % (60° away from the sun τ 1 −9.8 → −0.4 %, τ 8 +4.3 → +7.4 %). Before the σ_t⁺ attenuation: −19.3 %, +17.8 %, +14.3 %. With the P2 field, no thick steps and no skins: −24.9 %,
    // +22.8 %, −51.9 %. The target, 5 % at every angle, is not met; what is left at τ 1 and 8:
    // the TMS single scattering looking towards the sun and the field
    // (`slab_split_by_smooth_scatterings_against_disort`).
    for (tau, albedo, bound) in [
        (1.0f64, 1.0f64, 0.16f64),
        (8.0, 1.0, 0.095),
        (32.0, 1.0, 0.12),
    ] {
        let mu0 = 0.5;
        let (case, views, azs) = disort_case(tau, albedo, mu0);
        let mut worst: f64 = 0.0;
        let mut line = format!("fast vs DISORT, tau {tau} albedo {albedo} mu0 {mu0}:");
        // One slab and one sun per case: the views share its lit volume (the frame each view
        // renders alone, `tests/products/frame_sequence.rs`).
        let mut lit: Option<std::sync::Arc<LitVolume>> = None;
        for (vi, &vz) in views.iter().enumerate() {
            for (ai, &raz) in azs.iter().enumerate() {
                if vz == 0.0 && ai > 0 {
                    // At nadir the azimuth is immaterial.
                    continue;
                }
                let expected = case["reflected_radiance_per_sr"][vi][ai].as_f64().unwrap();
                let width = 1600.0 * vz.to_radians().cos();
                let scene = slab_scene(tau, albedo, mu0, vz, raz, width, 5000.0, 16);
                let lighting = lighting_for(&scene, &grid, &Engine::new()).unwrap();
                let s = settings(&scene, Method::Fast, 1);
                let shared = lit.is_some();
                let lit = lit
                    .get_or_insert_with(|| {
                        let inputs = LitInputs::new(&scene, grid.clone(), &lighting, s);
                        std::sync::Arc::new(LitVolume::new(inputs, &|| false).unwrap())
                    })
                    .clone();
                let prepared =
                    Prepared::with_lit(&scene, &lighting, s, lit, shared, &|| false).unwrap();
                let fast = render_tile(&prepared, None, &|_| {}, &|| false).unwrap();
                let r = mean_radiance(&fast) / expected - 1.0;
                line += &format!(" [{vz:.0}° {raz:.0}°] {:+.1} %", r * 100.0);
                worst = worst.max(r.abs());
            }
        }
        println!("{line}; worst {:.1} %", worst * 100.0);
        assert!(worst < bound, "tau {tau}: worst {worst}");
    }
}

/// (b) Mitsuba 3: the validation cloud lit by the sky alone and by the sun alone, on a 64×48 tile
/// at the image centre (the whole 160×120 frame at this noise level takes minutes): path tracer
/// within 3 % block NRMSE and 2 % cloud-mean bias (for the sun, whose Mitsuba image itself has
/// 2.7 % block noise, the NRMSE bound is 3 % added in quadrature to that); the fast method's
/// whole-frame figures are printed.
#[test]
fn cloud_matches_mitsuba() {
    let mask_full: Vec<bool> = npy("cloud_mitsuba_mask.npy")
        .iter()
        .map(|&m| m > 0.0)
        .collect();
    // Fast method (whole frame, δ-M/TMS field, P3, 20° view cap, the field interpolated over the
    // cells that hold cloud, the sun's single scattering through σ_t⁺ and spread over the sun's
    // and the view's paths, the sun's path interpolated in √D): measured block NRMSE and bias, sun
    // 4.2 % and −0.4 % with the environment's photons traced from the sun in this sunlit-only frame
    // (4.8 % and −1.5 % with the first orders through σ_t*, 4.0 % and +0.3 % with the cells
    // weighted by their densities as well), sky 4.9 % and −1.4 % (5.3 % and +0.7 % density-weighted
    // with the view cap's edge along the view ray; 7.9 % and −0.2 % before the environment photons'
    // launch, docs/frames.md); bounds are those plus a margin for the photon noise.
    for (case, nrmse_bound, fast_block_bound, fast_bias_bound) in [
        // The fast method: 4.5 % / −0.4 % with the sky's first order through σ_t⁺ (4.9 % / −1.4 %
        // before). 4.03 % / −0.96 % with the roulette at 60 and the forced once collision (the
        // roulette's draws shift the photons' streams; over 16 photon seeds 4.17 / −0.32 % mean,
        // 4.94 / −1.01 % worst); engine17 (the spread beam's longer paths too) 4.0 % / −1.0 %.
        ("sky", 0.03, 0.055, 0.015),
        // The fast method: 3.76 % / −0.64 % with the roulette at 60 and the forced once collision
        // (4.69 % / −0.63 % before; over 16 photon seeds 5.13 / −0.89 % mean, 6.90 / −2.11 %
        // worst); 3.78 % / −0.61 % with the collision forced under 2 optical depths, not 4;
        // engine17 (the spread beam's longer paths too) 3.8 % / −0.7 %.
        (
            "sun",
            (0.03f64.powi(2) + 0.027f64.powi(2)).sqrt(),
            0.055,
            0.015,
        ),
    ] {
        let (scene, grid, reference) = validation_case(case);
        assert_eq!(reference.len(), 160 * 120);
        let tile = if case == "sun" {
            Tile {
                x0: 64,
                y0: 40,
                width: 32,
                height: 32,
            }
        } else {
            Tile {
                x0: 48,
                y0: 32,
                width: 64,
                height: 48,
            }
        };
        let spp = if case == "sun" { 512 } else { 96 };
        let crop = |img: &[f32]| -> Vec<f32> {
            (0..tile.height)
                .flat_map(|y| (0..tile.width).map(move |x| (y, x)))
                .map(|(y, x)| img[(tile.y0 + y) * 160 + tile.x0 + x])
                .collect()
        };
        let ref_tile = crop(&reference);
        let mask: Vec<bool> = (0..tile.height)
            .flat_map(|y| (0..tile.width).map(move |x| (y, x)))
            .map(|(y, x)| mask_full[(tile.y0 + y) * 160 + tile.x0 + x])
            .collect();
        let lighting = lighting_for(&scene, &grid, &Engine::new()).unwrap();
        let pt = render_frame(
            &scene,
            &grid,
            &lighting,
            &settings(&scene, Method::Reference, spp),
            Some(tile),
            &|_| {},
            &|| false,
        )
        .unwrap();
        let t = std::time::Instant::now();
        let fast = render_frame(
            &scene,
            &grid,
            &lighting,
            &settings(&scene, Method::Fast, 1),
            None,
            &|_| {},
            &|| false,
        )
        .unwrap();
        let fast_ms = t.elapsed().as_secs_f64() * 1e3;
        let (bn, pn, bias) = stats(&pt.radiance, &ref_tile, &mask, tile.width, tile.height);
        println!(
            "{case}: path tracer vs Mitsuba (tile): block NRMSE {:.2} %, pixel NRMSE {:.2} %, bias {:+.2} %, own noise {:.2} %",
            bn * 100.0,
            pn * 100.0,
            bias * 100.0,
            pt.meta.error_estimate.path_tracer_relative_noise.unwrap_or(0.0) * 100.0
        );
        let (fb, fp, fbias) = stats(&fast.radiance, &reference, &mask_full, 160, 120);
        println!(
            "{case}: fast vs Mitsuba (whole frame, {fast_ms:.0} ms): block NRMSE {:.1} %, pixel NRMSE {:.1} %, bias {:+.1} %",
            fb * 100.0,
            fp * 100.0,
            fbias * 100.0
        );
        assert!(
            bn < nrmse_bound && bias.abs() < 0.02,
            "{case}: path tracer block NRMSE {bn}, bias {bias}"
        );
        assert!(
            fb < fast_block_bound && fbias.abs() < fast_bias_bound,
            "{case}: fast method vs Mitsuba: block NRMSE {fb}, bias {fbias}"
        );
    }
}

/// (b) continued, fast method only (whole 160×120 frames, about a second each): the Mitsuba cases
/// thin cloud, g = 0.5, albedo 0.9 and sun + sky, with bounds = measured block NRMSE and bias plus
/// a margin. Measured with the field interpolated over the cells that hold cloud and the sun's
/// single scattering through σ_t⁺: thin 3.3 % / +0.1 %, g 0.5 3.9 % / −0.3 %, albedo 0.9 3.8 % /
/// +0.5 %, sun + sky 5.1 % / −2.1 %. With the field alone: thin 3.7 % /
/// −1.2 %, g 0.5 4.1 % / −0.6 % (over 4 photon seeds 5.2 % / +0.0 % raw), albedo 0.9 4.4 % / −1.3 %,
/// sun + sky 5.6 % / −1.6 %. With the cells weighted by their densities (before): thin 3.7 % /
/// −0.9 %, g 0.5 4.1 % / +2.2 % (+2.9 % over 4 seeds, +2.6 % with 16× the photons: the density
/// weights raised the thin edges' field), albedo 0.9 4.3 % / +0.3 %, sun + sky 5.4 % / −0.1 %; the
/// g 0.85 cases read lower now because their first orders are 4–10 % low, which the edges'
/// excess offset (docs/frames.md). The sunlit-only frames trace the environment's photons from
/// the sun.
#[test]
fn fast_cloud_matches_mitsuba_cases() {
    let mask: Vec<bool> = npy("cloud_mitsuba_mask.npy")
        .iter()
        .map(|&m| m > 0.0)
        .collect();
    for (case, block_bound, bias_bound) in [
        // 3.38 % / −1.49 % with the roulette at 60 and the forced once collision (2.89 % / −0.81 %
        // before); over 16 photon seeds 3.07 / −0.93 % mean, 3.44 / −1.49 % worst (before 3.60 /
        // −1.08 % and 4.01 / −1.74 %: a 1.5 % bound was held by the seed); the bias bound the
        // issue's 2 %. Engine17 (forced under 2 optical depths, the spread beam's longer paths):
        // 3.39 % / −1.51 %.
        ("sun_thin", 0.045, 0.02),
        // 4.00 % / +0.34 % with the roulette at 60 and the forced once collision (3.86 % / −0.36 %
        // before); over 16 photon seeds 5.15 / −0.26 % mean, 6.15 / −1.39 % worst (before 5.59 /
        // −0.65 %, 6.62 / −1.72 %). 4.00 % / +0.32 % forced under 2 optical depths, not 4;
        // engine17 (the spread beam's longer paths too) 4.02 % / +0.26 %. With the cells at most
        // ¼ of the transport mean free path (one voxel per cell here) 3.50 % / −0.55 %; over 16
        // photon seeds 4.08 / −0.69 % mean, 4.69 / −1.64 % worst (before 5.18 / −0.31 %, 6.16 /
        // −1.46 %): bound 5 → 4.5 %. With 3× the photons where the cells are made finer
        // (`multiple::REFINED_PHOTONS`) 2.90 % / −1.45 % (16 seeds not measured).
        ("sun_g05", 0.045, 0.015),
        // 4.32 % / −0.52 % with the once-scattered sunlight seen through the halfway kernel (4.14 %
        // / +0.85 % through p*_l; over 4 photon seeds 4.75 % / +0.07 %, 4.87 % / +1.53 %).
        // 4.19 % / −0.57 % with the roulette at 60 and the forced once collision; over 16 photon
        // seeds 5.09 / −0.06 % mean, 6.23 / −1.06 % worst. 4.19 % / −0.54 % forced under 2
        // optical depths, not 4; engine17 (the spread beam's longer paths too) 4.30 % / −0.72 %.
        // Cells within 0.1 ℓ_tr (30 m) and 3× the photons: 3.34 % / −0.64 %; over 16 photon seeds
        // 3.76 / −0.25 % mean, 4.41 / −0.91 % worst (engine18 5.42 / −0.28 %, 6.61 / −1.25 %).
        ("sun_albedo09", 0.05, 0.015),
        // 4.7 % / −1.2 % with the sky's first order through σ_t⁺ (5.1 % / −2.1 % before;
        // over 4 photon seeds 4.5 % / −0.9 %, raw). 3.84 % / −0.84 % with the roulette at 60 and
        // the forced once collision; over 16 photon seeds 4.78 / −0.52 % mean, 6.10 / −2.08 %
        // worst. 3.83 % / −0.83 % forced under 2 optical depths, not 4; engine17 (the spread
        // beam's longer paths too) 3.84 % / −0.84 %.
        ("sunsky", 0.055, 0.02),
    ] {
        let (scene, grid, reference) = validation_case(case);
        let fast = fast_frame(&scene, &grid);
        let (fb, fp, fbias) = stats(&fast.radiance, &reference, &mask, 160, 120);
        println!(
            "{case}: fast vs Mitsuba: block NRMSE {:.2} %, pixel NRMSE {:.1} %, bias {:+.2} %",
            fb * 100.0,
            fp * 100.0,
            fbias * 100.0
        );
        assert!(
            fb < block_bound && fbias.abs() < bias_bound,
            "{case}: fast method vs Mitsuba: block NRMSE {fb}, bias {fbias}"
        );
    }
}

/// (b) continued, every lighting geometry (fast method, whole 160×120 frames): the sun behind the
/// cloud 35° above the view axis (thick and thin), 22° from it (the cloud's upper edges seen 5–20°
/// from the sun), sun and sky back-lit, and the camera below the cloud looking up at its base
/// (sun, sky). Mitsuba's own block noise (its committed stderr images) is removed in quadrature
/// from the block NRMSE; the bounds are the measured figures (docs/frames.md) plus a margin for
/// the photon noise.
#[test]
fn fast_cloud_matches_mitsuba_every_side() {
    let cases: &[(&str, &str, f64, f64)] = &[
        // Measured (block NRMSE without Mitsuba's noise / bias), the field interpolated over the
        // cells that hold cloud and the sun's single scattering through σ_t⁺: 4.6 % / −0.3 %; the
        // field alone 5.3 % / −2.4 % (4.9 % / −1.1 % with the cells weighted by their
        // densities, whose thin edges' excess offset the first orders' deficit; 6.1 % / +1.0 %
        // before the peak's last scattering was seen through the true extinction).
        // 3.87 % / +0.32 % with the peak's turned light gathered (`march/turned.rs`); 3.46 % /
        // −0.62 % with the spread beam's longer paths taken out (`peak`; over 8 photon seeds −0.59 %).
        // 2.78 % / +0.06 % with the roulette at 60 and the forced once collision instead (3.42 % /
        // +0.22 % before); 2.81 % / +0.06 % forced under 2 optical depths, not 4. Both: 2.98 % /
        // −0.78 % (engine17).
        ("sun_back35", "cloud_mitsuba_mask.npy", 0.05, 0.015),
        // 4.5 % / +0.6 % (the field alone 4.3 % / +0.2 %; 4.5 % / +1.2 % density-weighted; 36.2 % / +25.8 % before: TMS counted the light scattered only within
        // the truncated peak once per peak scattering; docs/frames.md). The target
        // (5 %, 2 %) with a margin for the photon field.
        // 4.16 % / +1.27 % with the peak's turned light gathered; 3.51 % / +0.83 % with the
        // sun's once-scattered light through the true medium; 3.54 % / +1.32 % seen through the
        // halfway kernel (over 4 photon seeds +1.16 %, raw); 3.00 % / +0.02 % with the spread
        // beam's longer paths taken out (`peak`; over 8 photon seeds 2.70 % / −0.40 %, worst −0.94 %).
        // 3.52 % / +1.27 % with the roulette at 60 and the forced once collision instead; 3.51 % /
        // +1.30 % forced under 2 optical depths. Both: 3.00 % / +0.00 % (engine17).
        ("sun_back20", "cloud_mitsuba_mask.npy", 0.055, 0.02),
        // 2.3 % / +0.4 % (the field alone 2.8 % / −1.1 %; 2.8 % / −1.0 % density-weighted; 3.6 % / −2.1 % before the peak's part).
        // 1.11 % / +0.20 % with the peak's turned light gathered. 0.82 % / +0.10 % with
        // the roulette at 60 and the forced once collision. Both: 0.81 % / +0.08 % (engine17).
        ("sun_back35_thin", "cloud_mitsuba_mask.npy", 0.025, 0.015),
        // 4.6 % / −1.9 % (the field alone 5.4 % / −1.8 %; 5.1 % / −0.4 % density-weighted; 5.8 % / +1.8 % before the P3 field and
        // the environment photons' launch).
        // 4.3 % / −1.1 % with the sky's first order through σ_t⁺ (4.6 % / −1.9 % before); 4.21 % /
        // −0.98 % with the peak's turned light gathered. 3.59 % / −0.69 % with the roulette at 60
        // and the forced once collision; 3.58 % / −0.67 % forced under 2 optical depths. With the
        // spread beam's longer paths too: 3.66 % / −0.85 % (engine17).
        ("sunsky_back35", "cloud_mitsuba_mask.npy", 0.05, 0.02),
        // 5.8 % / +1.1 % (5.9 % / +1.1 % before the smooth part's kink was held, `peak`; over 4
        // photon seeds 7.7 % / +1.8 % raw, one seed +2.1 %; the field alone 7.9 % / −1.4 %, over 4 photon seeds 9.4 % / −0.7 % raw; density-weighted 6.2 % / +0.1 %,
        // 7.9 % / +0.8 % raw over 4 seeds: the field's excess in the base's far half is gone and
        // the first orders' deficit on the side away from the sun is no longer offset).
        // 5.18 % / +1.12 % with the peak's turned light gathered; 4.70 % / +1.67 % with the
        // sun's once-scattered light through the true medium (`multiple/once.rs`); 3.90 % / +0.30 %
        // seen through the halfway kernel (over 4 photon seeds 6.07 % / +1.21 % raw, seeds up to
        // +1.7 %; +2.19 % through p*_l); 3.96 % / +0.04 % with the spread beam's longer paths
        // taken out (over 8 photon seeds +1.22 %, worst +2.13 %). 4.36 % / +1.38 % with the
        // roulette at 60 and the forced once collision instead (over 16 photon seeds 5.61 / +1.62 %
        // mean, 6.66 / +2.35 % worst); 4.44 % / +1.43 % forced under 2 optical depths, not 4.
        // Both: 4.48 % / +1.15 % (engine17). Cells within 0.1 ℓ_tr (30 m) and 3× the photons:
        // 4.26 % / +1.22 %; over 16 photon seeds 4.00 / +0.93 % mean, 4.66 / +2.17 % worst
        // (engine18 5.64 / +0.97 %, 6.50 / +1.80 %).
        ("below_sun", "cloud_mitsuba_mask_below.npy", 0.05, 0.02),
        // 4.3 % / −1.4 % (sun-free: the first orders' change does not reach it; 3.8 % / +0.1 % density-weighted; 7.6 % / +0.1 % before the environment
        // photons' launch and the P3 field). The target (5 %, 2 %).
        // 4.0 % / −0.0 % with the sky's first order through σ_t⁺ (4.3 % / −1.4 % before).
        // 4.20 % / −0.38 % with the roulette at 60 and the forced once collision (engine17 alike).
        ("below_sky", "cloud_mitsuba_mask_below.npy", 0.05, 0.015),
    ];
    let mut failures = Vec::new();
    for &(case, mask_file, block_bound, bias_bound) in cases {
        let mask: Vec<bool> = npy(mask_file).iter().map(|&m| m > 0.0).collect();
        let (scene, grid, reference) = validation_case(case);
        let stderr = npy(&format!("cloud_mitsuba_{case}_stderr.npy"));
        let fast = fast_frame(&scene, &grid);
        let (fb, fp, fbias) = stats(&fast.radiance, &reference, &mask, 160, 120);
        let noise = block_noise(&stderr, &reference, &mask, 160, 120);
        let fb_clean = (fb * fb - noise * noise).max(0.0).sqrt();
        println!(
            "{case}: fast vs Mitsuba: block NRMSE {:.2} % ({:.2} % without Mitsuba's block noise {:.1} %), pixel NRMSE {:.1} %, bias {:+.2} %",
            fb * 100.0,
            fb_clean * 100.0,
            noise * 100.0,
            fp * 100.0,
            fbias * 100.0
        );
        if !(fb_clean < block_bound && fbias.abs() < bias_bound) {
            failures.push(format!("{case}: block NRMSE {fb_clean}, bias {fbias}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// RMS over the cloud blocks of the reference's block standard error (pixels independent),
/// relative to the reference's cloud mean.
fn block_noise(
    stderr: &[f32],
    reference: &[f32],
    mask: &[bool],
    width: usize,
    height: usize,
) -> f64 {
    let (mut sr, mut n) = (0.0, 0usize);
    for i in 0..mask.len() {
        if mask[i] {
            sr += reference[i] as f64;
            n += 1;
        }
    }
    let (mut v, mut nb) = (0.0, 0usize);
    for by in 0..height / 8 {
        for bx in 0..width / 8 {
            let idx: Vec<usize> = (0..64)
                .map(|k| (by * 8 + k / 8) * width + bx * 8 + k % 8)
                .collect();
            if idx.iter().all(|&i| mask[i]) {
                v += idx.iter().map(|&i| (stderr[i] as f64).powi(2)).sum::<f64>() / 64.0 / 64.0;
                nb += 1;
            }
        }
    }
    (v / nb as f64).sqrt() / (sr / n as f64)
}

/// (a) DISORT slab, split by class (a diagnosis of `fast_slab_every_angle_against_disort`): a
/// path tracer that classes each scattering as within the δ-M truncated peak (probability
/// r⁺(μ)/p(μ), r⁺ = max(p − (1 − f)·HG(g*), 0), as in `crates/harness/examples/back_probe.rs`) or
/// smooth splits the reflected radiance by the number n of smooth scatterings on its path: n ≤ 1
/// is what the fast method's TMS single scattering (with the peak's spread and last scattering)
/// stands for, n ≥ 2 what its field J* stands for. The classes must add up to DISORT (within 3 %
/// plus three standard errors of the path tracer); the fast method's two parts are printed
/// against them (docs/frames.md, "DISORT slab at every listed angle"), τ 1 and 8, view zenith 0,
/// 60 and 75°.
#[test]
fn slab_split_by_smooth_scatterings_against_disort() {
    use rand::{Rng, SeedableRng};
    use skybake_physics::phase::Phase;
    use skybake_render::pathtracer::PathTracer;
    let grid = slab_grid();
    let spp = 128usize;
    let mut checks = Vec::new();
    for tau in [1.0f64, 8.0] {
        let (case, views, azs) = disort_case(tau, 1.0, 0.5);
        for (vi, ai) in [(0usize, 0usize), (2, 0), (2, 2), (3, 0), (3, 1), (3, 2)] {
            let expected = case["reflected_radiance_per_sr"][vi][ai].as_f64().unwrap();
            let (vz, raz) = (views[vi], azs[ai]);
            let scene = slab_scene(
                tau,
                1.0,
                0.5,
                vz,
                raz,
                1600.0 * vz.to_radians().cos(),
                5000.0,
                16,
            );
            let lt = lighting_for(&scene, &grid, &Engine::new()).unwrap();
            let (w, h) = (scene.camera.width, scene.camera.height);
            // The fast method's parts: the whole march, then with the per-voxel sources (the
            // field J* and the sky light) zeroed, the TMS single scattering alone.
            let mut fast = Prepared::new(
                &scene,
                &grid,
                &lt,
                settings(&scene, Method::Fast, 1),
                &|| false,
            )
            .unwrap();
            let march_mean = |p: &Prepared| -> f64 {
                let mut sum = 0.0;
                for i in 0..w * h {
                    let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                    let ray = skybake_render::camera::primary_ray(&scene.camera, x, y).unwrap();
                    let (mut ia, mut tc) = ([0.0], [0.0]);
                    p.march(&ray, &mut ia, &mut tc);
                    sum += ia[0];
                }
                sum / (w * h) as f64
            };
            let fast_total = march_mean(&fast);
            let stride = fast.stride;
            for v in fast.vox.chunks_mut(stride) {
                v[2..].iter_mut().for_each(|x| *x = 0.0);
            }
            let fast_ss = march_mean(&fast);
            // The classed path tracer (next-event estimation towards the sun at every vertex).
            let reference = Prepared::new(
                &scene,
                &grid,
                &lt,
                settings(&scene, Method::Reference, 1),
                &|| false,
            )
            .unwrap();
            let phase = scene.optics.phase[0];
            let k = scene.optics.extinction_per_density_m[0];
            let g = phase.mean_cosine();
            let f = g.powf(skybake_render::TRUNCATION_POWER);
            let smooth = Phase::HenyeyGreenstein {
                g: (g - f) / (1.0 - f),
            };
            let rplus = |mu: f64| (phase.eval(mu) - (1.0 - f) * smooth.eval(mu)).max(0.0);
            let tracer = PathTracer::new(reference.vol(), &scene.optics, &lt, 0);
            // Classes n = 0, 1, 2, 3, 4–5, ≥ 6.
            let class = |n: usize| n.min(4) + usize::from(n >= 6);
            let (mut acc, mut sum2) = ([0.0f64; 6], 0.0f64);
            for i in 0..w * h {
                let mut rng = rand_pcg::Pcg64::seed_from_u64(
                    0x5EED ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                for _ in 0..spp {
                    let (x, y) = (
                        (i % w) as f64 + rng.random::<f64>(),
                        (i / w) as f64 + rng.random::<f64>(),
                    );
                    let ray = skybake_render::camera::primary_ray(&scene.camera, x, y).unwrap();
                    let (mut pos, mut dir) = (ray.origin_m, ray.dir);
                    let (mut n, mut path) = (0usize, 0.0f64);
                    while let Some(t) = tracer.free_path(pos, dir, k, &mut rng) {
                        pos += dir * t;
                        let mu = lt.sun_dir.dot(dir);
                        let tr = tracer.transmittance(pos, lt.sun_dir, k, &mut rng);
                        let (pk, all) = (rplus(mu), phase.eval(mu));
                        let e = lt.sun_irradiance[0] * tr;
                        acc[class(n)] += e * pk;
                        acc[class(n + 1)] += e * (all - pk);
                        path += e * all;
                        let mut more = || rng.random::<f64>();
                        let (u1, u2) = (more(), more());
                        let nd = phase.sample(dir, u1, u2, &mut more).0;
                        let m = nd.dot(dir);
                        if rng.random::<f64>() * phase.eval(m) >= rplus(m) {
                            n += 1;
                        }
                        dir = nd;
                    }
                    sum2 += path * path;
                }
            }
            let count = (spp * w * h) as f64;
            let c = acc.map(|v| v / count);
            let total: f64 = c.iter().sum();
            let sigma = ((sum2 / count - total * total).max(0.0) / count).sqrt() / total;
            let (lo, hi) = (c[0] + c[1], c[2..].iter().sum::<f64>());
            println!(
                "tau {tau} [{vz:.0}° {raz:.0}°] DISORT {expected:.5}, classed path tracer {:+.1} % (noise {:.1} %): n ≤ 1 {lo:.5} (n = 0 {:.5}), n ≥ 2 {hi:.5} (n = 2 / 3 / 4–5 / ≥ 6: {:.5} / {:.5} / {:.5} / {:.5}); fast {:+.1} %: TMS single scattering {fast_ss:.5} ({:+.1} %), field {:.5} ({:+.1} %)",
                (total / expected - 1.0) * 100.0,
                sigma * 100.0,
                c[0],
                c[2],
                c[3],
                c[4],
                c[5],
                (fast_total / expected - 1.0) * 100.0,
                (fast_ss / lo - 1.0) * 100.0,
                fast_total - fast_ss,
                ((fast_total - fast_ss) / hi - 1.0) * 100.0,
            );
            checks.push((tau, vz, raz, total / expected - 1.0, sigma));
        }
    }
    for (tau, vz, raz, r, sigma) in checks {
        assert!(
            r.abs() < 0.03 + 3.0 * sigma,
            "tau {tau} [{vz} {raz}]: classed path tracer {r} (noise {sigma})"
        );
    }
}
