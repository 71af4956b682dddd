//! The bench cumulus (the report's "cumulus" frame case: sun, sky and ground light) at a preset,
//! fast method, against the report's converged path-traced reference
//! (`report/frames-reference-cumulus.npy`, written by `skybake-harness report --only frames`),
//! with the same error measures (block NRMSE, cloud-mean bias), over several photon seeds: which
//! setting moves the frame's figures.
//!
//! cargo run --release -p skybake-harness --features probes --example cumulus_probe
//! Knobs (env): AORDER, ENV_PHOTONS, SUN_PHOTONS, SEED, SEEDS=n, QUALITY (draft, standard, high),
//! REF (another reference .npy), NOGROUND=1 / NOSKY=1 (the frame without ground / sky light, the
//! planner's hooks: its error then includes the missing light, so only the difference between
//! two settings with the same switches means anything).
use skybake_harness::frame_bench::{bench_cumulus, bench_scene};
use skybake_physics::atmosphere::quality::Quality;
use skybake_render::{lighting_for, render_frame, CloudMsMethod, Method, RenderSettings};

mod probe_support;
use probe_support::env_f;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h, n_l) = (160, 120, 3);
    let mut scene = bench_scene(w, h)?;
    scene.multiple_scattering_method = CloudMsMethod::AllOrders;
    let grid = bench_cumulus()?;
    let path = std::env::var("REF").unwrap_or_else(|_| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../report/frames-reference-cumulus.npy"
        )
        .into()
    });
    let b = std::fs::read(&path)?;
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    let vals: Vec<f32> = b[10 + hl..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let mut reference = Vec::new();
    let mut mask = Vec::new();
    for px in vals.chunks_exact(n_l + 1) {
        reference.extend_from_slice(&px[..n_l]);
        mask.push(px[n_l] < 0.99);
    }
    let lt = lighting_for(&scene, &grid, &skybake_engine::engine::Engine::new())?;
    let q = match std::env::var("QUALITY").as_deref() {
        Ok("draft") => Quality::Draft,
        Ok("high") => Quality::High,
        _ => Quality::Standard,
    };
    let mut s = RenderSettings::for_quality(q, Method::Fast);
    if let Some(v) = env_f("ENV_PHOTONS") {
        s.photons.env_photons = v as usize;
    }
    if let Some(v) = env_f("SUN_PHOTONS") {
        s.photons.sun_photons = v as usize;
    }
    if let Some(v) = env_f("SEED") {
        s.photons.seed = v as u64;
    }
    if let Some(v) = env_f("AORDER") {
        s.photons.angular_order = v as usize;
    }
    if env_f("NOGROUND").is_some() {
        s.ground_light = false;
    }
    if env_f("NOSKY").is_some() {
        s.sky_light = false;
    }
    let n = env_f("SEEDS").unwrap_or(1.0) as u64;
    let (mut sb, mut sbias) = (0.0, 0.0);
    let mut line = String::new();
    for k in 0..n {
        let mut sk = s;
        sk.photons.seed = s.photons.seed.wrapping_add(k * 7919);
        let f = render_frame(&scene, &grid, &lt, &sk, None, &|_| {}, &|| false)?;
        let e = skybake_render::compare::image_errors(&f.radiance, &reference, &mask, w, n_l);
        line += &format!(" {:.2}/{:+.2}", 100.0 * e.nrmse_blocks, 100.0 * e.mean_bias);
        sb += e.nrmse_blocks;
        sbias += e.mean_bias;
    }
    println!(
        "cumulus {q:?}: {n} seeds: block NRMSE mean {:.2}%, bias mean {:+.2}% |{line}",
        100.0 * sb / n as f64,
        100.0 * sbias / n as f64
    );
    Ok(())
}
