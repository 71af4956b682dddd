//! Where a Mitsuba validation case's error is, by light source, part and order, for the cases the
//! sun's single scattering does not explain (sky light, side-lit thin and absorbing clouds): the
//! fast frame (the whole composited radiance, as the tests compare it) against the committed
//! Mitsuba 3 image, its block-ratio map, and its parts: the transmitted background, the sky's
//! first order through the 16 sky elements (TMS: scaled paths, the view cap), the sun's single
//! scattering, and the multiple-scattering field J* (with the sun's once-scattered change where
//! the march adds it). Against a path tracer that classes each scattering as within the truncated
//! peak or not (as `back_probe`'s, with next-event estimates towards the sky by sampling the phase
//! function, and towards the sun), split by the number n of smooth scatterings (n ≤ 1: what the
//! first-order terms stand for, n ≥ 2: the field).
//!
//! cargo run --release -p skybake-harness --features probes --example sky_probe -- CASE [CLASSED_SPP]
//! Knobs (env): ENV_PHOTONS, SUN_PHOTONS, COARSE (the field's cells per axis), SEED, SEEDS=n (the
//! frame's error over n photon seeds, then stop), AORDER (the field's angular order), TPOW
//! (truncation power), EXACT=spp (the fast exact first order, no multiple scattering, against the
//! path tracer's order 1), MAP=1 (print the 8×8 block ratio map fast / Mitsuba), PTCACHE=FILE
//! (the classed path tracer's image read from FILE where it holds one of this size, else
//! written there: for comparing the fast frame's variants against one path-traced image).
use rayon::prelude::*;
use skybake_render::pathtracer::PathTracer;
use skybake_render::{camera, lighting_for, FrameScene, Method, Prepared, RenderSettings};
use std::time::Instant;

mod probe_support;
use probe_support::{env_f, npy, share, DATA};

/// Block NRMSE and bias of `test` against `reference`, and the bias by band of the optical depth
/// along the pixel's ray and by image row third (top / middle / bottom).
fn report(name: &str, test: &[f32], reference: &[f32], mask: &[bool], tau: &[f32]) {
    let e = skybake_render::compare::image_errors(test, reference, mask, 160, 1);
    let mut bands = String::new();
    for (lo, hi) in [(1.0, 2.0), (2.0, 4.0), (4.0, 8.0), (8.0, 100.0)] {
        let (mut sf, mut sr) = (0.0, 0.0);
        for i in 0..mask.len() {
            if mask[i] && tau[i] >= lo && tau[i] < hi {
                sf += test[i] as f64;
                sr += reference[i] as f64;
            }
        }
        bands += &format!(" τ[{lo},{hi}) {:+6.1}%", 100.0 * (sf / sr.max(1e-30) - 1.0));
    }
    bands += " |";
    for (lo, hi) in [(0, 40), (40, 80), (80, 120)] {
        let (mut sf, mut sr) = (0.0, 0.0);
        for i in 0..mask.len() {
            let y = i / 160;
            if mask[i] && y >= lo && y < hi {
                sf += test[i] as f64;
                sr += reference[i] as f64;
            }
        }
        bands += &format!(
            " rows[{lo},{hi}) {:+6.1}%",
            100.0 * (sf / sr.max(1e-30) - 1.0)
        );
    }
    println!(
        "{name:30} blocks {:5.1}% bias {:+6.1}% |{bands}",
        100.0 * e.nrmse_blocks,
        100.0 * e.mean_bias
    );
}

/// The 8×8 block map of test / reference − 1 (percent) over blocks with every pixel in the mask.
fn block_map(test: &[f32], reference: &[f32], mask: &[bool]) {
    for by in 0..15 {
        let mut line = String::new();
        for bx in 0..20 {
            let idx: Vec<usize> = (0..64)
                .map(|k| (by * 8 + k / 8) * 160 + bx * 8 + k % 8)
                .collect();
            if idx.iter().all(|&i| mask[i]) {
                let a: f64 = idx.iter().map(|&i| test[i] as f64).sum();
                let b: f64 = idx.iter().map(|&i| reference[i] as f64).sum();
                line += &format!("{:+4.0}", 100.0 * (a / b - 1.0));
            } else {
                line += "   .";
            }
        }
        println!("  {line}");
    }
}

fn march_ia(p: &Prepared, scene: &FrameScene) -> Vec<f32> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let mut ia = [0.0];
            let mut tc = [0.0];
            if let Some(ray) =
                camera::primary_ray(&scene.camera, (i % w) as f64 + 0.5, (i / w) as f64 + 0.5)
            {
                p.march(&ray, &mut ia, &mut tc);
            }
            ia[0] as f32
        })
        .collect()
}

fn main() -> skybake_physics::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let case = a.get(1).cloned().unwrap_or("sky".into());
    let cspp: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(0);
    let bytes = std::fs::read(format!("{DATA}/validation-cloud-{case}.json")).unwrap();
    let scene = FrameScene::parse(&bytes)?;
    let grid = scene.cloud.voxelize(&|p: &str| {
        std::fs::read(format!("{DATA}/{p}")).map_err(|e| skybake_physics::Error::invalid("path", e))
    })?;
    let below = case.starts_with("below");
    let mask: Vec<bool> = npy(if below {
        "cloud_mitsuba_mask_below.npy"
    } else {
        "cloud_mitsuba_mask.npy"
    })
    .iter()
    .map(|&m| m > 0.0)
    .collect();
    let tau = npy(if below {
        "cloud_mitsuba_tau_below.npy"
    } else {
        "cloud_mitsuba_tau.npy"
    });
    let reference = npy(&format!("cloud_mitsuba_{case}.npy"));
    let norm: f64 = share(&reference, &mask, 1.0);
    let lt = lighting_for(&scene, &grid, &skybake_engine::engine::Engine::new())?;
    let mut s = RenderSettings::for_quality(scene.quality, Method::Fast);
    if let Some(v) = env_f("ENV_PHOTONS") {
        s.photons.env_photons = v as usize;
    }
    if let Some(v) = env_f("SUN_PHOTONS") {
        s.photons.sun_photons = v as usize;
    }
    if let Some(v) = env_f("COARSE") {
        s.photons.max_coarse_dim = v as usize;
    }
    if let Some(v) = env_f("SEED") {
        s.photons.seed = v as u64;
    }
    if let Some(v) = env_f("AORDER") {
        s.photons.angular_order = v as usize;
    }
    if let Some(v) = env_f("TPOW") {
        s.photons.truncation_power = v;
    }
    if let Some(n) = env_f("SEEDS") {
        // The fast frame's error over `n` photon seeds (its photon noise varies the figures).
        let (mut sb, mut sbias, mut sb2) = (0.0, 0.0, 0.0);
        let mut line = String::new();
        for k in 0..n as u64 {
            let mut sk = s;
            sk.photons.seed = s.photons.seed.wrapping_add(k * 7919);
            let f =
                skybake_render::render_frame(&scene, &grid, &lt, &sk, None, &|_| {}, &|| false)?;
            let e = skybake_render::compare::image_errors(&f.radiance, &reference, &mask, 160, 1);
            line += &format!(" {:.1}/{:+.1}", 100.0 * e.nrmse_blocks, 100.0 * e.mean_bias);
            sb += e.nrmse_blocks;
            sb2 += e.nrmse_blocks * e.nrmse_blocks;
            sbias += e.mean_bias;
        }
        println!(
            "{case}: {n} seeds: block NRMSE mean {:.2}% (rms {:.2}%), bias mean {:+.2}% |{line}",
            100.0 * sb / n,
            100.0 * (sb2 / n).sqrt(),
            100.0 * sbias / n
        );
        return Ok(());
    }
    let t = Instant::now();
    let frame = skybake_render::render_frame(&scene, &grid, &lt, &s, None, &|_| {}, &|| false)?;
    let fast_s = t.elapsed().as_secs_f64();
    let total = frame.radiance.clone();
    report("fast frame vs Mitsuba", &total, &reference, &mask, &tau);
    if env_f("MAP").is_some() {
        block_map(&total, &reference, &mask);
    }
    let mut p = Prepared::new(&scene, &grid, &lt, s, &|| false)?;
    let ia = march_ia(&p, &scene);
    // The field's part: the per-voxel sources less ω*·J* and the sun's once-scattered change
    // where the march adds it (voxels not seen through a face; the sky's first order and the
    // view cap remain), then the sun's single scattering (sources zeroed).
    if let Some(field) = p.lit.ms.as_ref() {
        let [nx, ny, nz] = grid.dims;
        let stride = p.stride;
        let albedo = p.lit.ms_albedo[0];
        let cam = scene.camera.position_m;
        let once = field.once_towards(&|c: glam::DVec3| (c - cam).normalize());
        let mut vox = p.vox.clone();
        for (i, v) in vox.chunks_mut(stride).enumerate() {
            if v[0] <= 0.0 && v[2] == 0.0 {
                continue;
            }
            let ijk = [i % nx, (i / nx) % ny, i / (nx * ny)];
            let c = grid.voxel_centre(ijk[0], ijk[1], ijk[2]);
            let d = (c - cam).normalize();
            let mut j = [0.0];
            field.inscatter(c, d, &mut j);
            // As the march's `field_source`: a voxel whose neighbour towards the viewer is empty
            // is seen through that face, and takes no once-scattered change.
            let dims = [nx, ny, nz];
            let face = grid.at(ijk[0], ijk[1], ijk[2]) > 0.0
                && (0..3).any(|a| {
                    let mut q = ijk;
                    if d[a] < 0.0 {
                        q[a] += 1;
                        q[a] >= dims[a] || grid.at(q[0], q[1], q[2]) <= 0.0
                    } else if d[a] > 0.0 {
                        q[a] == 0 || {
                            q[a] -= 1;
                            grid.at(q[0], q[1], q[2]) <= 0.0
                        }
                    } else {
                        false
                    }
                });
            if !face {
                field.once_add(&once, c, &mut j);
            }
            v[2] -= (albedo * j[0]) as f32;
        }
        std::mem::swap(&mut p.vox, &mut vox);
    }
    let no_field = march_ia(&p, &scene);
    for v in p.vox.chunks_mut(p.stride) {
        v[2] = 0.0;
    }
    let sun_ss = march_ia(&p, &scene);
    let bg: Vec<f32> = total.iter().zip(&ia).map(|(a, b)| a - b).collect();
    let field: Vec<f32> = ia.iter().zip(&no_field).map(|(a, b)| a - b).collect();
    let sky1: Vec<f32> = no_field.iter().zip(&sun_ss).map(|(a, b)| a - b).collect();
    println!(
        "shares of Mitsuba's cloud sum: fast {:.3} = background {:.3} + sky first order {:.3} + sun single scattering and view cap {:.3} + field J* {:.3} (fast {fast_s:.1} s)",
        share(&total, &mask, norm),
        share(&bg, &mask, norm),
        share(&sky1, &mask, norm),
        share(&sun_ss, &mask, norm),
        share(&field, &mask, norm)
    );
    if let Some(espp) = env_f("EXACT") {
        // The first order without truncation: the fast method (sky elements along the true
        // extinction, no field) against the path tracer's order 1.
        let mut scene1 = scene.clone();
        scene1.lighting.multiple_scattering = false;
        let f1 = skybake_render::render_frame(&scene1, &grid, &lt, &s, None, &|_| {}, &|| false)?;
        let rs = RenderSettings::for_quality(scene.quality, Method::Reference);
        let pr = Prepared::new(&scene, &grid, &lt, rs, &|| false)?;
        let mut pt = PathTracer::new(pr.vol(), &scene.optics, &lt, 0xABCD);
        pt.min_orders = 0;
        pt.max_orders = 1;
        let (w, _) = (scene.camera.width, scene.camera.height);
        let espp = espp as usize;
        let t = Instant::now();
        let img: Vec<f32> = (0..w * scene.camera.height)
            .into_par_iter()
            .map(|i| {
                if !mask[i] {
                    return 0.0;
                }
                let (x, y) = (i % w, i / w);
                let mut rng = pt.rng(x, y, 7);
                let mut sum = 0.0;
                for _ in 0..espp {
                    use rand::Rng;
                    let (jx, jy) = (rng.random::<f64>(), rng.random::<f64>());
                    if let Some(ray) =
                        camera::primary_ray(&scene.camera, x as f64 + jx, y as f64 + jy)
                    {
                        sum += pt.sample(&ray, &mut rng).radiance[0];
                    }
                }
                (sum / espp as f64) as f32
            })
            .collect();
        eprintln!("path tracer orders 0–1: {:.1} s", t.elapsed().as_secs_f64());
        report("fast exact order ≤1 vs PT", &f1.radiance, &img, &mask, &tau);
        if env_f("MAP").is_some() {
            block_map(&f1.radiance, &img, &mask);
        }
    }
    if cspp > 0 {
        classes(
            &scene, &lt, &p, &bg, &sky1, &sun_ss, &field, &reference, &mask, &tau, cspp,
        );
    }
    Ok(())
}

/// The path tracer with each scattering classed as a peak scattering (probability r⁺(μ)/p(μ),
/// r⁺ = max(p − (1 − f)·HG(g*), 0)) or a smooth one, next-event estimates towards the sun and
/// towards the sky (a direction drawn from the phase function, the sky's radiance there times the
/// transmittance); the light split by the number n of smooth scatterings on its path.
#[allow(clippy::too_many_arguments)]
fn classes(
    scene: &FrameScene,
    lt: &skybake_render::Lighting,
    p: &Prepared,
    bg: &[f32],
    sky1: &[f32],
    sun_ss: &[f32],
    field: &[f32],
    reference: &[f32],
    mask: &[bool],
    tau: &[f32],
    spp: usize,
) {
    use glam::DVec3;
    use rand::{Rng, SeedableRng};
    use skybake_physics::phase::Phase;
    let vol = p.vol();
    let phase = scene.optics.phase[0];
    let k = scene.optics.extinction_per_density_m[0];
    let albedo = scene.optics.albedo[0];
    let e_sun = lt.sun_irradiance[0];
    let g = phase.mean_cosine();
    let f = g.powf(p.settings.photons.truncation_power);
    let smooth = Phase::HenyeyGreenstein {
        g: (g - f) / (1.0 - f),
    };
    let rplus = |mu: f64| (phase.eval(mu) - (1.0 - f) * smooth.eval(mu)).max(0.0);
    // The path tracer's own delta and ratio tracking.
    let tracer = PathTracer::new(vol, &scene.optics, lt, 0);
    let free = |o: DVec3, d: DVec3, rng: &mut rand_pcg::Pcg64| tracer.free_path(o, d, k, rng);
    let trans = |o: DVec3, d: DVec3, rng: &mut rand_pcg::Pcg64| tracer.transmittance(o, d, k, rng);
    let sky_on = (!lt.sky.is_zero() || !lt.below.is_zero()) && scene.lighting.sky_light;
    let sun_on = e_sun > 0.0;
    let (w, h) = (scene.camera.width, scene.camera.height);
    let t = Instant::now();
    // Per pixel: [sky n=0, sky n=1, sky n≥2, sun n=0, sun n=1, sun n≥2].
    let cache = std::env::var("PTCACHE").unwrap_or_default();
    let cached: Option<Vec<[f64; 6]>> = std::fs::read(&cache).ok().map(|b| {
        b.chunks_exact(8)
            .map(|c| f64::from_le_bytes(std::array::from_fn(|k| c[k])))
            .collect::<Vec<f64>>()
            .chunks_exact(6)
            .map(|c| std::array::from_fn(|j| c[j]))
            .collect()
    });
    let img: Vec<[f64; 6]> = if let Some(c) = cached.filter(|c| c.len() == w * h) {
        c
    } else {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let mut acc = [0.0; 6];
                if !mask[i] {
                    return acc;
                }
                let (x, y) = (i % w, i / w);
                let mut rng = rand_pcg::Pcg64::seed_from_u64(
                    0x5EED ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                let mut lsky = [0.0];
                for _ in 0..spp {
                    let (jx, jy) = (rng.random::<f64>(), rng.random::<f64>());
                    let Some(ray) =
                        camera::primary_ray(&scene.camera, x as f64 + jx, y as f64 + jy)
                    else {
                        continue;
                    };
                    let (mut pos, mut dir) = (ray.origin_m, ray.dir);
                    let mut thr = 1.0;
                    let mut n = 0usize;
                    for _depth in 0..20000 {
                        let Some(t) = free(pos, dir, &mut rng) else {
                            break;
                        };
                        pos += dir * t;
                        thr *= albedo;
                        if sun_on {
                            let mu = lt.sun_dir.dot(dir);
                            let tr = trans(pos, lt.sun_dir, &mut rng);
                            let (pk, all) = (rplus(mu), phase.eval(mu));
                            acc[3 + n.min(2)] += thr * e_sun * pk * tr;
                            acc[3 + (n + 1).min(2)] += thr * e_sun * (all - pk) * tr;
                        }
                        if sky_on {
                            // The light arrives from −w... travelling along `dir` after scattering:
                            // a direction w towards the sky drawn from p(w·dir).
                            let mut more = || rng.random::<f64>();
                            let (u1, u2) = (more(), more());
                            let wd = phase.sample(dir, u1, u2, &mut more).0;
                            lt.env(wd, &mut lsky);
                            if lsky[0] > 0.0 {
                                let mu = wd.dot(dir);
                                let tr = trans(pos, wd, &mut rng);
                                let rp = rplus(mu) / phase.eval(mu);
                                acc[n.min(2)] += thr * lsky[0] * tr * rp;
                                acc[(n + 1).min(2)] += thr * lsky[0] * tr * (1.0 - rp);
                            }
                        }
                        let mut more = || rng.random::<f64>();
                        let (u1, u2) = (more(), more());
                        let nd = phase.sample(dir, u1, u2, &mut more).0;
                        let m = nd.dot(dir);
                        if rng.random::<f64>() * phase.eval(m) >= rplus(m) {
                            n += 1;
                        }
                        dir = nd;
                        if thr < 1e-3 {
                            break;
                        }
                    }
                }
                acc.map(|v| v / spp as f64)
            })
            .collect()
    };
    if !cache.is_empty() {
        let b: Vec<u8> = img
            .iter()
            .flat_map(|a| a.iter().flat_map(|v| v.to_le_bytes()))
            .collect();
        let _ = std::fs::write(&cache, b);
    }
    eprintln!("classed path tracer: {:.1} s", t.elapsed().as_secs_f64());
    let norm = share(reference, mask, 1.0);
    let part = |c: &[usize]| -> Vec<f32> {
        img.iter()
            .map(|a| c.iter().map(|&j| a[j]).sum::<f64>() as f32)
            .collect()
    };
    let total: Vec<f32> = img
        .iter()
        .zip(bg)
        .map(|(a, b)| (a.iter().sum::<f64>() + *b as f64) as f32)
        .collect();
    println!(
        "classed PT shares of Mitsuba: sky n=0/1/≥2 {:.3}/{:.3}/{:.3}, sun n=0/1/≥2 {:.3}/{:.3}/{:.3}",
        share(&part(&[0]), mask, norm),
        share(&part(&[1]), mask, norm),
        share(&part(&[2]), mask, norm),
        share(&part(&[3]), mask, norm),
        share(&part(&[4]), mask, norm),
        share(&part(&[5]), mask, norm),
    );
    report(
        "classed PT + fast bg vs Mitsuba",
        &total,
        reference,
        mask,
        tau,
    );
    // The fast first orders: the sky elements, the view cap and the sun's single scattering.
    let first: Vec<f32> = sky1.iter().zip(sun_ss).map(|(a, b)| a + b).collect();
    report(
        "fast 1st orders vs PT n≤1",
        &first,
        &part(&[0, 1, 3, 4]),
        mask,
        tau,
    );
    if sky_on && sun_on {
        report(
            "fast sun SS+cap vs PT sun n≤1",
            sun_ss,
            &part(&[3, 4]),
            mask,
            tau,
        );
    }
    report(
        "fast J* vs PT n≥2 (sky+sun)",
        field,
        &part(&[2, 5]),
        mask,
        tau,
    );
    if env_f("MAP").is_some() {
        println!("field J* / PT n≥2 block map:");
        block_map(field, &part(&[2, 5]), mask);
        println!("first orders / PT n≤1 block map:");
        block_map(&first, &part(&[0, 1, 3, 4]), mask);
    }
}
