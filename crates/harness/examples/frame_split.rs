//! Where the fast frame's error is (the bench frame against the path tracer): the bench cumulus's cloud radiance I_a
//! (before background and aerial perspective) from the fast method against the path tracer,
//! split by light source and scattering order, with the bias by cloud transmittance band; or
//! the whole composited frame (`frame`). Path-traced references are cached under $REF_DIR
//! (default /tmp); the README's "where the error is" figures come from it.
//!
//! cargo run --release -p skybake-harness --features probes --example frame_split -- W H SPP MODE...
//! MODE: all | sun | env | sky | gnd, suffixed `1` for first order only (e.g. env1).
//! Knobs (env): TPOW, COARSE, ENVP, SUNP, ANG, STEP, QUALITY.
use rayon::prelude::*;
use skybake_harness::frame_bench::{bench_cumulus, bench_scene};
use skybake_render::compare::image_errors;
use skybake_render::lighting::Hemisphere;
use skybake_render::pathtracer::PathTracer;
use skybake_render::{camera, lighting_for, Method, Prepared, RenderSettings};
use std::time::Instant;

mod probe_support;
use probe_support::env_f;

fn main() -> skybake_physics::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let w: usize = a[1].parse().unwrap();
    let h: usize = a[2].parse().unwrap();
    let spp: usize = a[3].parse().unwrap();
    let grid = bench_cumulus()?;
    let mut scene = bench_scene(w, h)?;
    let engine = skybake_engine::engine::Engine::new();
    let base = lighting_for(&scene, &grid, &engine)?;
    let n_l = scene.wavelengths.len();
    let dir = std::env::var("REF_DIR").unwrap_or("/tmp".into());
    for mode in &a[4..] {
        if mode == "frame" {
            whole_frame(&scene, &grid, &base, w, h, spp, &dir)?;
            continue;
        }
        let first = mode.ends_with('1');
        let src = mode.trim_end_matches('1');
        let mut lt = base.clone();
        lt.aerial = None;
        match src {
            "all" => {}
            "sun" => {
                lt.sky = Hemisphere::Zero;
                lt.below = Hemisphere::Zero;
            }
            "env" => lt.sun_irradiance.iter_mut().for_each(|x| *x = 0.0),
            "sky" => {
                lt.sun_irradiance.iter_mut().for_each(|x| *x = 0.0);
                lt.below = Hemisphere::Zero;
            }
            "gnd" => {
                lt.sun_irradiance.iter_mut().for_each(|x| *x = 0.0);
                lt.sky = Hemisphere::Zero;
            }
            _ => panic!("mode {mode}"),
        }
        // Path-traced reference of I_a (min_orders 1 drops the background).
        let path = format!("{dir}/ref_{w}x{h}_{spp}_{mode}.bin");
        let reference: Vec<f32> = if let Ok(b) = std::fs::read(&path) {
            b.chunks(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        } else {
            let t = Instant::now();
            let s = RenderSettings::for_quality(scene.quality, Method::Reference);
            let p = Prepared::new(&scene, &grid, &lt, s, &|| false)?;
            let mut pt = PathTracer::new(p.vol(), &scene.optics, &lt, 0xABCD);
            pt.min_orders = 1;
            if first {
                pt.max_orders = 1;
            }
            let img: Vec<f32> = (0..w * h)
                .into_par_iter()
                .flat_map_iter(|i| {
                    let (x, y) = (i % w, i / w);
                    let mut rng = pt.rng(x, y, 7);
                    let mut sum = vec![0.0; n_l];
                    for _ in 0..spp {
                        use rand::Rng;
                        let (jx, jy) = (rng.random::<f64>(), rng.random::<f64>());
                        if let Some(ray) =
                            camera::primary_ray(&scene.camera, x as f64 + jx, y as f64 + jy)
                        {
                            let s = pt.sample(&ray, &mut rng);
                            for (acc, v) in sum.iter_mut().zip(&s.radiance) {
                                *acc += v;
                            }
                        }
                    }
                    sum.into_iter().map(move |v| (v / spp as f64) as f32)
                })
                .collect();
            let bytes: Vec<u8> = img.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(&path, bytes).ok();
            eprintln!("reference {mode}: {:.1} s", t.elapsed().as_secs_f64());
            img
        };
        let mut s = RenderSettings::for_quality(scene.quality, Method::Fast);
        if let Some(v) = env_f("TPOW") {
            s.photons.truncation_power = v;
        }
        if let Some(v) = env_f("COARSE") {
            s.photons.max_coarse_dim = v as usize;
        }
        if let Some(v) = env_f("ENVP") {
            s.photons.env_photons = v as usize;
        }
        if let Some(v) = env_f("SUNP") {
            s.photons.sun_photons = v as usize;
        }
        if let Some(v) = env_f("ANG") {
            s.photons.angular_order = v as usize;
        }
        if let Some(v) = env_f("STEP") {
            s.step_voxels = v;
        }
        scene.lighting.multiple_scattering = !first;
        let t = Instant::now();
        let p = Prepared::new(&scene, &grid, &lt, s, &|| false)?;
        let mut fast = vec![0f32; w * h * n_l];
        let mut trans = vec![1f32; w * h];
        fast.par_chunks_mut(n_l)
            .zip(trans.par_iter_mut())
            .enumerate()
            .for_each(|(i, (px, tr))| {
                let (x, y) = (i % w, i / w);
                let mut ia = vec![0.0; n_l];
                let mut tc = vec![0.0; n_l];
                if let Some(ray) =
                    camera::primary_ray(&scene.camera, x as f64 + 0.5, y as f64 + 0.5)
                {
                    p.march(&ray, &mut ia, &mut tc);
                    for l in 0..n_l {
                        px[l] = ia[l] as f32;
                    }
                    *tr = (tc.iter().sum::<f64>() / n_l as f64) as f32;
                }
            });
        let fast_s = t.elapsed().as_secs_f64();
        drop(p);
        scene.lighting.multiple_scattering = true;
        let mask: Vec<bool> = trans.iter().map(|&t| t < 0.99).collect();
        if let Ok(d) = std::env::var("DUMP") {
            let bytes: Vec<u8> = fast
                .iter()
                .chain(&trans)
                .flat_map(|v| v.to_le_bytes())
                .collect();
            std::fs::write(format!("{d}/fast_{w}x{h}_{mode}.bin"), bytes).ok();
        }
        let e = image_errors(&fast, &reference, &mask, w, n_l);
        // Bias by transmittance band.
        let mut bands = String::new();
        for (lo, hi) in [(0.0, 0.01), (0.01, 0.3), (0.3, 0.99)] {
            let (mut sf, mut sr, mut n) = (0.0, 0.0, 0);
            for i in 0..w * h {
                if trans[i] >= lo && trans[i] < hi {
                    for l in 0..n_l {
                        sf += fast[i * n_l + l] as f64;
                        sr += reference[i * n_l + l] as f64;
                    }
                    n += 1;
                }
            }
            bands += &format!(
                " T[{lo},{hi}) n={n} share={:.2} bias={:+.2}%;",
                sr,
                100.0 * (sf - sr) / sr.max(1e-30)
            );
        }
        println!(
            "{mode:6} blocks {:5.2}% px {:5.2}% bias {:+6.2}%  fast {:.2}s |{bands}",
            100.0 * e.nrmse_blocks,
            100.0 * e.nrmse_pixels,
            100.0 * e.mean_bias,
            fast_s
        );
    }
    Ok(())
}

/// The whole composited frame (background, aerial perspective) as `bench frame-accuracy` does.
fn whole_frame(
    scene: &skybake_render::FrameScene,
    grid: &skybake_physics::cloud::DensityGrid,
    lt: &skybake_render::Lighting,
    w: usize,
    h: usize,
    spp: usize,
    dir: &str,
) -> skybake_physics::Result<()> {
    use skybake_render::render_frame;
    let n_l = scene.wavelengths.len();
    let seed = env_f("SEED").map(|v| v as u64);
    let path = match seed {
        Some(sd) => format!("{dir}/ref_{w}x{h}_{spp}_frame_seed{sd}.bin"),
        None => format!("{dir}/ref_{w}x{h}_{spp}_frame.bin"),
    };
    let npx = w * h;
    let (reference, trans, var) = if let Ok(b) = std::fs::read(&path) {
        let v: Vec<f32> = b
            .chunks(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        (
            v[..npx * n_l].to_vec(),
            v[npx * n_l..npx * (n_l + 1)].to_vec(),
            v[npx * (n_l + 1)..].to_vec(),
        )
    } else {
        let t = Instant::now();
        let mut s = RenderSettings::for_quality(scene.quality, Method::Reference);
        s.spp = spp;
        if let Some(sd) = seed {
            s.seed = sd;
        }
        let f = render_frame(scene, grid, lt, &s, None, &|_| {}, &|| false)?;
        let bytes: Vec<u8> = f
            .radiance
            .iter()
            .chain(&f.transmittance)
            .chain(&f.variance)
            .flat_map(|v| v.to_le_bytes())
            .collect();
        std::fs::write(&path, bytes).ok();
        eprintln!("reference frame: {:.1} s", t.elapsed().as_secs_f64());
        (f.radiance, f.transmittance, f.variance)
    };
    // The reference's own noise on 8×8 cloud blocks: RMS of the block mean's standard error.
    let mask: Vec<bool> = trans.iter().map(|&t| t < 0.99).collect();
    if var.len() == npx * n_l {
        let (mut s2, mut nb, mut sum, mut n) = (0.0, 0, 0.0, 0);
        for i in 0..npx {
            if mask[i] {
                sum += (0..n_l).map(|l| reference[i * n_l + l] as f64).sum::<f64>() / n_l as f64;
                n += 1;
            }
        }
        for by in 0..h / 8 {
            for bx in 0..w / 8 {
                let idx = |k: usize| (by * 8 + k / 8) * w + bx * 8 + k % 8;
                if (0..64).all(|k| mask[idx(k)]) {
                    let v: f64 = (0..64)
                        .map(|k| {
                            // Wavelengths of a grey cloud share their paths: fully correlated.
                            ((0..n_l)
                                .map(|l| (var[idx(k) * n_l + l] as f64).sqrt())
                                .sum::<f64>()
                                / n_l as f64)
                                .powi(2)
                        })
                        .sum::<f64>()
                        / (64.0 * 64.0);
                    s2 += v;
                    nb += 1;
                }
            }
        }
        println!(
            "reference block noise {:.2}% ({nb} blocks)",
            100.0 * (s2 / nb.max(1) as f64).sqrt() / (sum / n.max(1) as f64)
        );
    }
    let s = RenderSettings::for_quality(scene.quality, Method::Fast);
    let t = Instant::now();
    let fast = render_frame(scene, grid, lt, &s, None, &|_| {}, &|| false)?;
    let e = image_errors(&fast.radiance, &reference, &mask, w, n_l);
    // With a second reference of another seed (CROSS=path), the squared block error without
    // the references' noise: the mean of (F − R1)(F − R2) over cloud blocks.
    if let Some(b) = std::env::var("CROSS")
        .ok()
        .and_then(|p| std::fs::read(p).ok())
    {
        let r2: Vec<f32> = b[..npx * n_l * 4]
            .chunks(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let px = |img: &[f32], i: usize| -> f64 {
            (0..n_l).map(|l| img[i * n_l + l] as f64).sum::<f64>() / n_l as f64
        };
        let (mut cross, mut nb, mut sum, mut n) = (0.0, 0, 0.0, 0);
        for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            sum += 0.5 * (px(&reference, i) + px(&r2, i));
            n += 1;
        }
        for by in 0..h / 8 {
            for bx in 0..w / 8 {
                let idx = |k: usize| (by * 8 + k / 8) * w + bx * 8 + k % 8;
                if (0..64).all(|k| mask[idx(k)]) {
                    let m = |img: &[f32]| (0..64).map(|k| px(img, idx(k))).sum::<f64>() / 64.0;
                    let f = m(&fast.radiance);
                    cross += (f - m(&reference)) * (f - m(&r2));
                    nb += 1;
                }
            }
        }
        let mean = sum / n.max(1) as f64;
        let mut cross_px = 0.0;
        for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            let f = px(&fast.radiance, i);
            cross_px += (f - px(&reference, i)) * (f - px(&r2, i));
        }
        println!(
            "cross-estimated pixel NRMSE {:.2}%",
            100.0 * (cross_px / n.max(1) as f64).max(0.0).sqrt() / mean
        );
        println!(
            "cross-estimated block NRMSE {:.2}% (signed square {:+.3e})",
            100.0 * (cross / nb.max(1) as f64).max(0.0).sqrt() / mean,
            cross / nb.max(1) as f64 / (mean * mean)
        );
    }
    println!(
        "frame  blocks {:5.2}% px {:5.2}% bias {:+6.2}%  fast {:.2}s",
        100.0 * e.nrmse_blocks,
        100.0 * e.nrmse_pixels,
        100.0 * e.mean_bias,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
