//! Where a Mitsuba validation case's error is (the fast method against the committed Mitsuba 3
//! image), by part and by scattering order: the fast frame's cloud radiance (I_a, no
//! background) split into its sun single-scattering term (TMS, the per-voxel sources zeroed) and
//! the field J*, the exact single scattering (no truncation), the path tracer's orders 1..=N,
//! with the bias per band of the optical depth along the pixel's ray
//! (tests/data/cloud_mitsuba_tau*.npy) and of the scattering angle.
//!
//! cargo run --release -p skybake-harness --features probes --example back_probe -- CASE [SPP [MAXORD]]
//! CASE: a validation case (`sun_back20`, …); SPP: path-tracer samples per pixel for its orders
//! (0: none); MAXORD: path-tracer orders 1..=N to render (default 1). Path-traced images are
//! cached under $REF_DIR (default /tmp). Knobs (env): PEAK (peak spread), TPOW (truncation
//! power); CLASSES=spp: a path tracer that classes each scattering as within the truncated peak
//! or not and splits the sun's light by the number of smooth scatterings (0, 1, ≥ 2), against
//! the fast method's parts; BRUTE=1: the exact single scattering by brute force (the sun's path
//! marched from every sample) against the march's, and with the per-voxel sun path replaced by
//! brute-force integrals at the voxel centres.
use rayon::prelude::*;
use skybake_render::pathtracer::PathTracer;
use skybake_render::{camera, lighting_for, FrameScene, Method, Prepared, RenderSettings};
use std::time::Instant;

mod probe_support;
use probe_support::{env_f, npy, share, DATA};

static THETA: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();

/// Block NRMSE, bias, and the bias by τ band (share of the reference, bias).
fn report(name: &str, test: &[f32], reference: &[f32], mask: &[bool], tau: &[f32]) {
    let theta = THETA.get().unwrap();
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
    for (lo, hi) in [
        (0.0, 12.0),
        (12.0, 16.0),
        (16.0, 20.0),
        (20.0, 25.0),
        (25.0, 180.0),
    ] {
        let (mut sf, mut sr) = (0.0, 0.0);
        for i in 0..mask.len() {
            if mask[i] && theta[i] >= lo && theta[i] < hi {
                sf += test[i] as f64;
                sr += reference[i] as f64;
            }
        }
        bands += &format!(" Θ[{lo},{hi}) {:+6.1}%", 100.0 * (sf / sr.max(1e-30) - 1.0));
    }
    println!(
        "{name:28} blocks {:5.1}% bias {:+6.1}% |{bands}",
        100.0 * e.nrmse_blocks,
        100.0 * e.mean_bias
    );
}

fn h_px(scene: &FrameScene) -> usize {
    scene.camera.height
}

fn march_all(p: &Prepared, scene: &FrameScene) -> Vec<f32> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let mut ia = [0.0];
            let mut tc = [0.0];
            if let Some(ray) = camera::primary_ray(&scene.camera, x as f64 + 0.5, y as f64 + 0.5) {
                p.march(&ray, &mut ia, &mut tc);
            }
            ia[0] as f32
        })
        .collect()
}

fn main() -> skybake_physics::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let case = a.get(1).cloned().unwrap_or("sun_back20".into());
    let spp: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(0);
    let max_ord: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
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
    // Scattering angle of each pixel's central ray, degrees.
    let (w, h) = (scene.camera.width, scene.camera.height);
    let theta: Vec<f64> = (0..w * h)
        .map(|i| {
            camera::primary_ray(&scene.camera, (i % w) as f64 + 0.5, (i / w) as f64 + 0.5)
                .map_or(180.0, |r| {
                    r.dir.dot(lt.sun_dir).clamp(-1.0, 1.0).acos().to_degrees()
                })
        })
        .collect();
    let mut counts = String::new();
    for (lo, hi) in [
        (0.0, 12.0),
        (12.0, 16.0),
        (16.0, 20.0),
        (20.0, 25.0),
        (25.0, 180.0),
    ] {
        let (mut n, mut sr) = (0, 0.0);
        for i in 0..w * h {
            if mask[i] && theta[i] >= lo && theta[i] < hi {
                n += 1;
                sr += reference[i] as f64;
            }
        }
        counts += &format!(" Θ[{lo},{hi}) n={n} share={:.2};", sr / norm);
    }
    println!("{case}:{counts}");
    THETA.set(theta).ok();
    let mut s = RenderSettings::for_quality(scene.quality, Method::Fast);
    if let Some(v) = env_f("PEAK") {
        s.photons.peak_spread = v;
    }
    if let Some(v) = env_f("TPOW") {
        s.photons.truncation_power = v;
    }
    if let Some(v) = env_f("STEP") {
        s.step_voxels = v;
    }
    let t = Instant::now();
    let mut p = Prepared::new(&scene, &grid, &lt, s, &|| false)?;
    let total = march_all(&p, &scene);
    let fast_s = t.elapsed().as_secs_f64();
    report("fast total", &total, &reference, &mask, &tau);
    // The sun's single scattering term alone (TMS): the per-voxel sources zeroed.
    for v in p.vox.chunks_mut(p.stride) {
        v[2..].iter_mut().for_each(|x| *x = 0.0);
    }
    let ss_tms = march_all(&p, &scene);
    let rest: Vec<f32> = total.iter().zip(&ss_tms).map(|(a, b)| a - b).collect();
    // Exact single scattering: no multiple scattering, no truncation.
    let mut scene1 = scene.clone();
    scene1.lighting.multiple_scattering = false;
    let p1 = Prepared::new(&scene1, &grid, &lt, s, &|| false)?;
    let ss_exact = march_all(&p1, &scene1);
    println!(
        "shares of Mitsuba's cloud sum: fast total {:.3}, TMS single scattering {:.3}, field J* {:.3}, exact single scattering {:.3}  (fast {fast_s:.1} s)",
        share(&total, &mask, norm),
        share(&ss_tms, &mask, norm),
        share(&rest, &mask, norm),
        share(&ss_exact, &mask, norm)
    );
    report("TMS SS vs Mitsuba", &ss_tms, &reference, &mask, &tau);
    if env_f("BRUTE").is_some() {
        // Exact single scattering by brute force: quarter-voxel steps along the view ray, the
        // sun's density integral marched from every sample (no per-voxel table).
        let vol = p1.vol();
        let k = scene.optics.extinction_per_density_m[0];
        let h = vol.grid.voxel_size_m * 0.25;
        let sd = lt.sun_dir;
        let e = lt.sun_irradiance[0] * scene.optics.albedo[0];
        let ph = scene.optics.phase[0];
        let t = Instant::now();
        let brute: Vec<f32> = (0..w * h_px(&scene))
            .into_par_iter()
            .map(|i| {
                if !mask[i] {
                    return 0.0;
                }
                let Some(ray) =
                    camera::primary_ray(&scene.camera, (i % w) as f64 + 0.5, (i / w) as f64 + 0.5)
                else {
                    return 0.0;
                };
                let Some((t0, t1)) = vol.interval(ray.origin_m, ray.dir) else {
                    return 0.0;
                };
                let pf = ph.eval(sd.dot(ray.dir));
                let (mut tv, mut sum, mut tt) = (0.0f64, 0.0f64, t0);
                while tt < t1 {
                    let dt = h.min(t1 - tt);
                    let pm = ray.origin_m + ray.dir * (tt + 0.5 * dt);
                    let rho = vol.rho(pm);
                    if rho > 0.0 {
                        let ds = vol.density_integral(pm, sd, h);
                        let a = k * rho * dt;
                        sum += e * pf * (-k * ds).exp() * (-tv).exp() * (-(-a).exp_m1());
                        tv += a;
                    }
                    tt += dt;
                }
                sum as f32
            })
            .collect();
        eprintln!(
            "brute-force single scattering: {:.1} s",
            t.elapsed().as_secs_f64()
        );
        report("fast exact SS vs brute SS", &ss_exact, &brute, &mask, &tau);
        println!("brute SS share {:.3}", share(&brute, &mask, norm));
        // The same march with the per-voxel sun path replaced by brute-force integrals at the
        // voxel centres: separates the cumulative scheme from the interpolation between centres.
        let mut pb = Prepared::new(&scene1, &grid, &lt, s, &|| false)?;
        let [nx, ny, _] = grid.dims;
        let stride = pb.stride;
        let (mut dmax, mut dsum, mut dn) = (0.0f64, 0.0, 0);
        for (i, v) in pb.vox.chunks_mut(stride).enumerate() {
            let c = grid.voxel_centre(i % nx, (i / nx) % ny, i / (nx * ny));
            let d = vol.density_integral(c, sd, h);
            if v[0] > 0.0 && d > 1.0 {
                let r = (v[1] as f64).powi(2) / d - 1.0;
                dmax = dmax.max(r.abs());
                dsum += r;
                dn += 1;
            }
            v[1] = d.sqrt() as f32;
        }
        println!(
            "cumulative D / brute D − 1 at occupied voxel centres: mean {:+.2}%, max |.| {:.1}%",
            100.0 * dsum / dn as f64,
            100.0 * dmax
        );
        let ss_b = march_all(&pb, &scene1);
        report("SS, brute D at centres", &ss_b, &brute, &mask, &tau);
    }
    if let Some(cspp) = env_f("CLASSES") {
        classes(
            &scene,
            &lt,
            &p1,
            &ss_tms,
            &rest,
            &reference,
            &mask,
            &tau,
            cspp as usize,
        );
    }
    if spp == 0 {
        return Ok(());
    }
    let dir = std::env::var("REF_DIR").unwrap_or("/tmp".into());
    let mut prev: Vec<f32> = vec![0.0; w * h];
    for n in 1..=max_ord {
        let path = format!("{dir}/back_probe_{case}_{spp}_o{n}.bin");
        let img: Vec<f32> = if let Ok(b) = std::fs::read(&path) {
            b.chunks(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        } else {
            let t = Instant::now();
            let rs = RenderSettings::for_quality(scene.quality, Method::Reference);
            let pr = Prepared::new(&scene, &grid, &lt, rs, &|| false)?;
            let mut pt = PathTracer::new(pr.vol(), &scene.optics, &lt, 0xABCD);
            pt.min_orders = 1;
            pt.max_orders = n;
            let img: Vec<f32> = (0..w * h)
                .into_par_iter()
                .map(|i| {
                    let (x, y) = (i % w, i / w);
                    let mut rng = pt.rng(x, y, 7);
                    let mut sum = 0.0;
                    for _ in 0..spp {
                        use rand::Rng;
                        let (jx, jy) = (rng.random::<f64>(), rng.random::<f64>());
                        if let Some(ray) =
                            camera::primary_ray(&scene.camera, x as f64 + jx, y as f64 + jy)
                        {
                            sum += pt.sample(&ray, &mut rng).radiance[0];
                        }
                    }
                    (sum / spp as f64) as f32
                })
                .collect();
            let bytes: Vec<u8> = img.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(&path, bytes).ok();
            eprintln!(
                "path tracer orders ≤ {n}: {:.1} s",
                t.elapsed().as_secs_f64()
            );
            img
        };
        let this: Vec<f32> = img.iter().zip(&prev).map(|(a, b)| a - b).collect();
        println!(
            "path tracer order {n}: share {:.3} (orders ≤ {n}: {:.3})",
            share(&this, &mask, norm),
            share(&img, &mask, norm)
        );
        if n == 1 {
            report("exact SS vs PT order 1", &ss_exact, &img, &mask, &tau);
            let hi: Vec<f32> = reference.iter().zip(&img).map(|(a, b)| a - b).collect();
            let fast_hi: Vec<f32> = total.iter().zip(&ss_exact).map(|(a, b)| a - b).collect();
            report("fast − exactSS vs Mit − PT1", &fast_hi, &hi, &mask, &tau);
            let tms_hi: Vec<f32> = ss_tms.iter().zip(&ss_exact).map(|(a, b)| a - b).collect();
            println!(
                "orders ≥ 2: Mitsuba − PT1 {:.3}; fast: TMS peak part (TMS SS − exact SS) {:.3} + field {:.3}",
                share(&hi, &mask, norm),
                share(&tms_hi, &mask, norm),
                share(&rest, &mask, norm)
            );
        }
        prev = img;
    }
    Ok(())
}

/// The path tracer with each scattering classed as a peak scattering (probability r⁺(μ)/p(μ),
/// r⁺ = max(p − (1 − f)·HG(g*), 0), the δ-M truncated peak's positive part) or a smooth one; the
/// sun's light by the number n of smooth scatterings on its path: 0 (the truncated peak only),
/// 1 (what TMS's single scattering with the scaled beam stands for), ≥ 2 (the scaled field J*).
#[allow(clippy::too_many_arguments)]
fn classes(
    scene: &FrameScene,
    lt: &skybake_render::Lighting,
    p1: &Prepared,
    ss_tms: &[f32],
    field: &[f32],
    reference: &[f32],
    mask: &[bool],
    tau: &[f32],
    spp: usize,
) {
    use glam::DVec3;
    use rand::{Rng, SeedableRng};
    use skybake_physics::phase::Phase;
    let vol = p1.vol();
    let phase = scene.optics.phase[0];
    let k = scene.optics.extinction_per_density_m[0];
    let albedo = scene.optics.albedo[0];
    let e_sun = lt.sun_irradiance[0];
    let g = phase.mean_cosine();
    let f = g.powf(skybake_render::TRUNCATION_POWER);
    let smooth = Phase::HenyeyGreenstein {
        g: (g - f) / (1.0 - f),
    };
    let rplus = |mu: f64| (phase.eval(mu) - (1.0 - f) * smooth.eval(mu)).max(0.0);
    // The path tracer's own delta and ratio tracking.
    let tracer = PathTracer::new(vol, &scene.optics, lt, 0);
    let free = |o: DVec3, d: DVec3, rng: &mut rand_pcg::Pcg64| tracer.free_path(o, d, k, rng);
    let trans = |o: DVec3, d: DVec3, rng: &mut rand_pcg::Pcg64| tracer.transmittance(o, d, k, rng);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let t = Instant::now();
    let img: Vec<[f64; 3]> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let mut acc = [0.0; 3];
            if !mask[i] {
                return acc;
            }
            let (x, y) = (i % w, i / w);
            let mut rng = rand_pcg::Pcg64::seed_from_u64(
                0x5EED ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            for _ in 0..spp {
                let (jx, jy) = (rng.random::<f64>(), rng.random::<f64>());
                let Some(ray) = camera::primary_ray(&scene.camera, x as f64 + jx, y as f64 + jy)
                else {
                    continue;
                };
                let (mut pos, mut dir) = (ray.origin_m, ray.dir);
                let mut thr = 1.0;
                let mut n = 0usize;
                for _depth in 0..5000 {
                    let Some(t) = free(pos, dir, &mut rng) else {
                        break;
                    };
                    pos += dir * t;
                    thr *= albedo;
                    // The light comes from the sun and travels along −dir after this event.
                    let mu = lt.sun_dir.dot(dir);
                    let tr = trans(pos, lt.sun_dir, &mut rng);
                    let (pk, all) = (rplus(mu), phase.eval(mu));
                    acc[n.min(2)] += thr * e_sun * pk * tr;
                    acc[(n + 1).min(2)] += thr * e_sun * (all - pk) * tr;
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
        .collect();
    eprintln!("classed path tracer: {:.1} s", t.elapsed().as_secs_f64());
    let norm = share(reference, mask, 1.0);
    let part = |c: usize| -> Vec<f32> { img.iter().map(|a| a[c] as f32).collect() };
    let (c0, c1, c2) = (part(0), part(1), part(2));
    let total: Vec<f32> = img.iter().map(|a| (a[0] + a[1] + a[2]) as f32).collect();
    println!(
        "classed PT (peak-only n=0 / n=1 / n≥2 / total) shares of Mitsuba: {:.3} / {:.3} / {:.3} / {:.3}",
        share(&c0, mask, norm),
        share(&c1, mask, norm),
        share(&c2, mask, norm),
        share(&total, mask, norm)
    );
    report("classed PT total vs Mitsuba", &total, reference, mask, tau);
    let theta = THETA.get().unwrap();
    let split = |frac_peak: bool| -> Vec<f32> {
        ss_tms
            .iter()
            .zip(theta)
            .map(|(v, th)| {
                let mu = th.to_radians().cos();
                let r = rplus(mu) / phase.eval(mu);
                (*v as f64 * if frac_peak { r } else { 1.0 - r }) as f32
            })
            .collect()
    };
    let (fa, fb) = (split(true), split(false));
    report("fast TMS·r⁺/p vs PT n=0", &fa, &c0, mask, tau);
    report("fast TMS·s/p vs PT n=1", &fb, &c1, mask, tau);
    report(
        "fast TMS SS vs PT n≤1",
        ss_tms,
        &c0.iter().zip(&c1).map(|(a, b)| a + b).collect::<Vec<_>>(),
        mask,
        tau,
    );
    report("fast J* vs PT n≥2", field, &c2, mask, tau);
}
