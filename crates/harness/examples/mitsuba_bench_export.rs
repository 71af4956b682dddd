//! Exports skybake's bench frame (crates/harness/src/frame_bench.rs) for Mitsuba 3 (tools/cloud_mitsuba_bench.py:
//! Mitsuba's time to reach the fast method's error) and renders it with skybake's fast method and path tracer under the same light.
//!
//! The light is the bench scene's `Lighting` (earth atmosphere, sun 35° el / 140° az, ground albedo
//! 0.3) as seen at the cloud: the sun's transmitted irradiance per wavelength, and `Lighting::env`
//! (sky radiance above the horizontal, ground light below). The comparison scene is that light in
//! vacuum: no aerial perspective, no ground plane, and the camera sees `env` where the cloud does
//! not cover it (so every renderer's image is I_a + T_c·env). Writes into OUT_DIR:
//!
//!   grid.npy         float32 (128, 128, 128) density, (z, y, x), values at voxel centres
//!   env.npy          float32 (H, 2H, λ) lat-long `Lighting::env`: row i at zenith angle
//!                    (i + ½)·180°/H, column j at azimuth (j + ½)·360°/(2H) from +y towards +x
//!   meta.json        wavelengths, sun direction and irradiance, camera, grid box, optics, timings
//!   fast.npy         float32 (h, w, λ) the fast method under the comparison light
//!   reference.npy    float32 (h, w, λ) the path tracer (SPP samples per pixel), and its
//!   reference_var.npy  variance of each pixel's mean, and
//!   transmittance.npy  float32 (h, w) cloud transmittance along the pixel centres
//!
//! Run: `cargo run --release -p skybake-harness --features probes --example mitsuba_bench_export -- OUT_DIR [WIDTH HEIGHT SPP ENV_H]`
//! (defaults 160 120 1024 1024; SPP 0 skips the path tracer).

use skybake_harness::frame_bench::{bench_cumulus, bench_scene};
use skybake_render::{lighting_for, render_frame, Method, RenderSettings};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

fn write_npy(path: &Path, shape: &[usize], data: &[f32]) -> std::io::Result<()> {
    assert_eq!(shape.iter().product::<usize>(), data.len());
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let tuple = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {tuple}, }}");
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    dict.push('\n');
    let mut out = Vec::with_capacity(10 + dict.len() + 4 * data.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::File::create(path)?.write_all(&out)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(out) = args.first() else {
        return Err("usage: mitsuba_bench_export OUT_DIR [WIDTH HEIGHT SPP ENV_H]".into());
    };
    let num = |i: usize, default: usize| -> Result<usize, Box<dyn std::error::Error>> {
        match args.get(i) {
            Some(s) => Ok(s.parse().map_err(|e| format!("argument {i} ({s}): {e}"))?),
            None => Ok(default),
        }
    };
    let (width, height, spp, env_h) = (num(1, 160)?, num(2, 120)?, num(3, 1024)?, num(4, 1024)?);
    let out = Path::new(out);
    std::fs::create_dir_all(out)?;

    let grid = bench_cumulus()?;
    let scene = bench_scene(width, height)?;
    let engine = skybake_engine::engine::Engine::new();
    let lighting = lighting_for(&scene, &grid, &engine)?;
    let mut light = lighting.clone();
    light.aerial = None;
    light.background = None;
    light.ground = None;
    let n_l = light.wavelengths_nm.len();

    let [nx, ny, nz] = grid.dims;
    write_npy(&out.join("grid.npy"), &[nz, ny, nx], &grid.data)?;

    let env_w = 2 * env_h;
    let mut env = vec![0f32; env_h * env_w * n_l];
    let mut v = vec![0.0; n_l];
    for i in 0..env_h {
        let theta = (i as f64 + 0.5) / env_h as f64 * std::f64::consts::PI;
        for j in 0..env_w {
            let phi = (j as f64 + 0.5) / env_w as f64 * 2.0 * std::f64::consts::PI;
            let d = glam::DVec3::new(
                theta.sin() * phi.sin(),
                theta.sin() * phi.cos(),
                theta.cos(),
            );
            light.env(d, &mut v);
            for l in 0..n_l {
                env[(i * env_w + j) * n_l + l] = v[l] as f32;
            }
        }
    }
    write_npy(&out.join("env.npy"), &[env_h, env_w, n_l], &env)?;

    let fast_settings = RenderSettings::for_quality(scene.quality, Method::Fast);
    let t = Instant::now();
    let fast = render_frame(
        &scene,
        &grid,
        &light,
        &fast_settings,
        None,
        &|_| {},
        &|| false,
    )?;
    let fast_ms = t.elapsed().as_secs_f64() * 1e3;
    write_npy(&out.join("fast.npy"), &[height, width, n_l], &fast.radiance)?;
    write_npy(
        &out.join("transmittance.npy"),
        &[height, width],
        &fast.transmittance,
    )?;
    eprintln!("fast: {fast_ms:.0} ms");

    let mut reference_ms = None;
    let mut reference_noise = None;
    if spp > 0 {
        let mut s = RenderSettings::for_quality(scene.quality, Method::Reference);
        s.spp = spp;
        let t = Instant::now();
        let r = render_frame(&scene, &grid, &light, &s, None, &|_| {}, &|| false)?;
        reference_ms = Some(t.elapsed().as_secs_f64() * 1e3);
        reference_noise = r.meta.error_estimate.path_tracer_relative_noise;
        write_npy(
            &out.join("reference.npy"),
            &[height, width, n_l],
            &r.radiance,
        )?;
        write_npy(
            &out.join("reference_var.npy"),
            &[height, width, n_l],
            &r.variance,
        )?;
        eprintln!("reference {spp} spp: {:.0} ms", reference_ms.unwrap_or(0.0));
    }

    let cam = &scene.camera;
    let meta = serde_json::json!({
        "what": "skybake-harness bench frame under its own light at the cloud, in vacuum (crates/harness/examples/mitsuba_bench_export.rs)",
        "wavelengths_nm": light.wavelengths_nm,
        "sun_direction": [light.sun_dir.x, light.sun_dir.y, light.sun_dir.z],
        "sun_irradiance_w_m2_nm": light.sun_irradiance,
        "env": {"file": "env.npy", "rows": env_h, "cols": env_w,
                "layout": "row i: zenith angle (i+0.5)*180/rows deg; col j: azimuth (j+0.5)*360/cols deg from +y towards +x; W m-2 sr-1 nm-1"},
        "camera": {"position_m": [cam.position_m.x, cam.position_m.y, cam.position_m.z],
                   "forward": [cam.forward.x, cam.forward.y, cam.forward.z],
                   "up": [cam.up.x, cam.up.y, cam.up.z],
                   "right": [cam.right.x, cam.right.y, cam.right.z],
                   "fov_deg": 50.0, "fov_axis": "horizontal", "width": width, "height": height},
        "grid": {"file": "grid.npy", "dims_xyz": grid.dims, "voxel_size_m": grid.voxel_size_m,
                 "origin_m": [grid.origin_m.x, grid.origin_m.y, grid.origin_m.z]},
        "optics": {"extinction_per_density_m": scene.optics.extinction_per_density_m,
                   "single_scattering_albedo": scene.optics.albedo,
                   "henyey_greenstein_g": 0.85},
        "quality": "standard",
        "fast_ms": fast_ms,
        "fast_stages_ms": fast.meta.timing_ms,
        "reference_spp": spp,
        "reference_ms": reference_ms,
        "reference_relative_noise": reference_noise,
        "threads": rayon::current_num_threads(),
        "lighting_notes": lighting.notes,
    });
    std::fs::write(
        out.join("meta.json"),
        serde_json::to_string_pretty(&meta)? + "\n",
    )?;
    Ok(())
}
