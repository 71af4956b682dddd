//! The fly-around's camera part alone (`bench frame-sequence`'s cameras, the cloud lit once):
//! per chosen frame the process CPU of the camera's source and pixels, and the frame against a
//! saved one (the same frames of another build): cloud-mean difference and the RMS and worst of
//! the per-pixel relative differences over the pixels with cloud light.
//!
//! cargo run --release -p skybake-harness --example march_probe
//! Knobs (env): FRAMES (comma-separated camera indices of 60; default 0,8,15,23,30,38,45,53),
//! REPS (renders per frame, the CPU's median; default 1), SAVE (file prefix: write each frame's
//! radiance), REF (file prefix: compare each frame with the one saved there), CG_WAIT (see below).
use glam::DVec3;
use skybake_engine::engine::Engine;
use skybake_harness::frame_bench::{bench_cumulus, bench_scene, fly_around_camera};
use skybake_harness::process::process_cpu_ms;
use skybake_render::{
    lighting_for, render_tile, LitInputs, LitVolume, Method, Prepared, RenderSettings,
};

fn main() -> skybake_physics::Result<()> {
    let frames: Vec<usize> = std::env::var("FRAMES")
        .unwrap_or_else(|_| "0,8,15,23,30,38,45,53".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let save = std::env::var("SAVE").ok();
    let reference = std::env::var("REF").ok();
    let grid = std::sync::Arc::new(bench_cumulus()?);
    let base = bench_scene(640, 480)?;
    let settings = RenderSettings::for_quality(base.quality, Method::Fast);
    let engine = Engine::new();
    let lighting = lighting_for(&base, &grid, &engine)?;
    let target = DVec3::new(0.0, 0.0, 1500.0);
    let start = base.camera.position_m - target;
    let inputs = LitInputs::new(&base, grid.clone(), &lighting, settings);
    let lit = std::sync::Arc::new(LitVolume::new(inputs, &|| false)?);
    // The lit volume's first reuse keeps what later cameras share: not counted.
    Prepared::with_lit(&base, &lighting, settings, lit.clone(), true, &|| false)?;
    // CG_WAIT (seconds): say so on stderr and wait, for `callgrind_control -i on` (a run under
    // `valgrind --tool=callgrind --instr-atstart=no` then counts the cameras' part alone).
    if let Some(w) = std::env::var("CG_WAIT")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    {
        eprintln!("READY");
        std::thread::sleep(std::time::Duration::from_secs(w));
    }
    let mut total = 0.0;
    let (mut all_d, mut all_r) = (0.0, 0.0);
    for &k in &frames {
        let scene = fly_around_camera(&base, target, start, k, 60);
        let mut cpu = Vec::new();
        let mut frame = None;
        for _ in 0..reps {
            let c0 = process_cpu_ms().unwrap_or(0.0);
            let prepared =
                Prepared::with_lit(&scene, &lighting, settings, lit.clone(), true, &|| false)?;
            let f = render_tile(&prepared, None, &|_| {}, &|| false)?;
            cpu.push(process_cpu_ms().unwrap_or(0.0) - c0);
            frame = Some(f);
        }
        cpu.sort_by(f64::total_cmp);
        let med = cpu[cpu.len() / 2];
        total += med;
        let Some(f) = frame else { continue };
        let pix = f
            .meta
            .timing_ms
            .iter()
            .find(|(n, _)| n == "pixels")
            .map_or(0.0, |x| x.1);
        let mut line = format!("frame {k:2}: cpu {med:7.1} ms (pixels wall {pix:6.1} ms)");
        let bytes: Vec<u8> = f.radiance.iter().flat_map(|v| v.to_le_bytes()).collect();
        let tr: Vec<u8> = f
            .transmittance
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        if let Some(pre) = &save {
            std::fs::write(format!("{pre}_{k}.rad"), &bytes).expect("write");
            std::fs::write(format!("{pre}_{k}.tr"), &tr).expect("write");
        }
        if let Some(pre) = &reference {
            let r: Vec<f32> = std::fs::read(format!("{pre}_{k}.rad"))
                .expect("read")
                .chunks(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            let rt: Vec<f32> = std::fs::read(format!("{pre}_{k}.tr"))
                .expect("read")
                .chunks(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            let n_l = f.wavelengths_nm.len();
            // Pixels with cloud in the reference: its transmittance below 0.99.
            let (mut sd, mut sr, mut s2, mut n, mut worst) = (0.0, 0.0, 0.0, 0usize, 0.0f64);
            let mut dtr = 0.0f64;
            for (i, &t) in rt.iter().enumerate() {
                dtr = dtr.max((f.transmittance[i] - t).abs() as f64);
                if t > 0.99 {
                    continue;
                }
                let a: f64 = f.radiance[i * n_l..(i + 1) * n_l]
                    .iter()
                    .map(|&v| v as f64)
                    .sum();
                let b: f64 = r[i * n_l..(i + 1) * n_l].iter().map(|&v| v as f64).sum();
                sd += a - b;
                sr += b;
                if b > 0.0 {
                    let e = (a - b) / b;
                    s2 += e * e;
                    worst = worst.max(e.abs());
                }
                n += 1;
            }
            all_d += sd;
            all_r += sr;
            line += &format!(
                "  cloud mean {:+.3} %, pixels rms {:.3} % worst {:.2} % (n {n}), transmittance max |Δ| {dtr:.2e}",
                100.0 * sd / sr,
                100.0 * (s2 / n.max(1) as f64).sqrt(),
                100.0 * worst
            );
        }
        println!("{line}");
    }
    println!("total cpu {total:.1} ms over {} frames", frames.len());
    if reference.is_some() {
        println!("cloud mean over frames {:+.3} %", 100.0 * all_d / all_r);
    }
    Ok(())
}
