//! Measures what coarser cells of the all-order multiple-scattering field cost and save
//! (`plan::MS_GRID_ERROR`): the validation cloud at 25 m voxels, 160×120 px, standard quality,
//! from the distance given in metres (default 4000; beyond 10 km fov 12°), rendered with the
//! field at most 32, 16, 8 and 4 cells per axis; prints the frame time, the multiple-scattering
//! stages' time and the per-pixel RMS change and bias of the mean against 32 cells.
//!
//! `cargo run --release -p skybake-harness --features probes --example ms_grid_probe -- 30000`

use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_render::{lighting_for, render_tile, FrameScene, Method, Prepared, RenderSettings};
use std::time::Instant;

fn main() {
    let dist: f64 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(4000.0);
    let mut v: Value =
        serde_json::from_str(include_str!("../../../config/scenes/validation-frame.json")).unwrap();
    v["camera"]["position_m"] = json!([0, -dist, 1200]);
    if dist > 10000.0 {
        v["camera"]["fov_deg"] = json!(12);
    }
    v["camera"]["width"] = json!(160);
    v["camera"]["height"] = json!(120);
    let scene = FrameScene::parse(&serde_json::to_vec(&v).unwrap()).unwrap();
    let grid = scene
        .cloud
        .voxelize(&|_| Err(skybake_physics::Error::invalid("p", "x")))
        .unwrap();
    eprintln!("grid {:?} voxel {}", grid.dims, grid.voxel_size_m);
    let lighting = lighting_for(&scene, &grid, &Engine::new()).unwrap();
    let mut base: Option<Vec<f32>> = None;
    for dim in [32usize, 16, 8, 4] {
        let mut s = RenderSettings::for_quality(scene.quality, Method::Fast);
        s.photons.max_coarse_dim = dim;
        let mut best = f64::INFINITY;
        let mut img = Vec::new();
        let mut ms = 0.0;
        for _ in 0..2 {
            let t = Instant::now();
            let p = Prepared::new(&scene, &grid, &lighting, s, &|| false).unwrap();
            let f = render_tile(&p, None, &|_| {}, &|| false).unwrap();
            let el = t.elapsed().as_secs_f64() * 1e3;
            if el < best {
                best = el;
                ms = p
                    .timing_ms
                    .iter()
                    .filter(|(n, _)| n.contains("multiple") || n.contains("ms_"))
                    .map(|(_, m)| m)
                    .sum();
            }
            img = f.radiance;
        }
        let b = base.get_or_insert_with(|| img.clone());
        let n = b.len() as f64;
        let mean = b.iter().map(|&x| x as f64).sum::<f64>() / n;
        let rms = (img
            .iter()
            .zip(b.iter())
            .map(|(a, c)| ((a - c) as f64).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
            / mean;
        let bias = (img.iter().map(|&x| x as f64).sum::<f64>() / n) / mean - 1.0;
        println!(
            "dim {dim}: total {best:.0} ms, ms stages {ms:.0} ms, rms {:.2} %, bias {:+.2} %",
            rms * 100.0,
            bias * 100.0
        );
    }
}
