//! The fast method's figures against Mitsuba 3 in every validation case, over several photon
//! seeds: block NRMSE (8×8 blocks, Mitsuba's own block noise removed in quadrature for the cases
//! `fast_cloud_matches_mitsuba_every_side` treats so, raw for the others, as the tests do) and
//! cloud-mean bias, per seed, then the mean and the worst over the seeds.
//!
//! cargo run --release -p skybake-harness --example seed_probe -- [CASE…]
//! Knobs (env): SEEDS (comma-separated photon seeds; default 24301 (0x5EED, the tests'),1,2,3,4,5),
//! PHOTONS_X (multiplies both photon budgets), MAP (set: also print per 8×8 block the spread
//! between the seeds and the seeds' mean frame's error, in % of Mitsuba's cloud mean and of its block).
use skybake_render::{lighting_for, FrameScene, Method, RenderSettings};

mod probe_support;
use probe_support::{env_f, npy, DATA};

const ALL: [&str; 12] = [
    "sun",
    "sky",
    "sun_thin",
    "sun_g05",
    "sun_albedo09",
    "sunsky",
    "sun_back35",
    "sun_back20",
    "sun_back35_thin",
    "sunsky_back35",
    "below_sun",
    "below_sky",
];

/// Block NRMSE, bias (tests/data/README.md's statistics, whole 160×120 frame).
fn stats(test: &[f32], reference: &[f32], mask: &[bool]) -> (f64, f64, f64) {
    let (w, h) = (160usize, 120usize);
    let (mut st, mut sr, mut n) = (0.0, 0.0, 0usize);
    for i in 0..mask.len() {
        if mask[i] {
            st += test[i] as f64;
            sr += reference[i] as f64;
            n += 1;
        }
    }
    let mean_r = sr / n as f64;
    let (mut be2, mut nb) = (0.0, 0usize);
    for by in 0..h / 8 {
        for bx in 0..w / 8 {
            let idx: Vec<usize> = (0..64)
                .map(|k| (by * 8 + k / 8) * w + bx * 8 + k % 8)
                .collect();
            if idx.iter().all(|&i| mask[i]) {
                let a: f64 = idx.iter().map(|&i| test[i] as f64).sum::<f64>() / 64.0;
                let b: f64 = idx.iter().map(|&i| reference[i] as f64).sum::<f64>() / 64.0;
                be2 += (a - b).powi(2);
                nb += 1;
            }
        }
    }
    ((be2 / nb as f64).sqrt() / mean_r, st / sr - 1.0, mean_r)
}

/// The 8×8 block means of a 160×120 frame over the blocks inside the mask, in order.
fn block_means(img: &[f32], mask: &[bool]) -> Vec<f64> {
    let mut out = Vec::new();
    for by in 0..15 {
        for bx in 0..20 {
            let idx: Vec<usize> = (0..64)
                .map(|k| (by * 8 + k / 8) * 160 + bx * 8 + k % 8)
                .collect();
            if idx.iter().all(|&i| mask[i]) {
                out.push(idx.iter().map(|&i| img[i] as f64).sum::<f64>() / 64.0);
            }
        }
    }
    out
}

/// RMS over the cloud blocks of the reference's block standard error, relative to its mean.
fn block_noise(stderr: &[f32], mask: &[bool], mean_r: f64) -> f64 {
    let (mut v, mut nb) = (0.0, 0usize);
    for by in 0..15 {
        for bx in 0..20 {
            let idx: Vec<usize> = (0..64)
                .map(|k| (by * 8 + k / 8) * 160 + bx * 8 + k % 8)
                .collect();
            if idx.iter().all(|&i| mask[i]) {
                v += idx.iter().map(|&i| (stderr[i] as f64).powi(2)).sum::<f64>() / 64.0 / 64.0;
                nb += 1;
            }
        }
    }
    (v / nb as f64).sqrt() / mean_r
}

fn main() -> skybake_physics::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let cases: Vec<String> = if args.is_empty() {
        ALL.iter().map(|s| s.to_string()).collect()
    } else {
        args
    };
    let seeds: Vec<u64> = std::env::var("SEEDS")
        .unwrap_or("24301,1,2,3,4,5".into())
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let x = env_f("PHOTONS_X").unwrap_or(1.0);
    for case in &cases {
        let bytes = std::fs::read(format!("{DATA}/validation-cloud-{case}.json")).unwrap();
        let scene = FrameScene::parse(&bytes)?;
        let grid = scene.cloud.voxelize(&|p: &str| {
            std::fs::read(format!("{DATA}/{p}"))
                .map_err(|e| skybake_physics::Error::invalid("path", e))
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
        let reference = npy(&format!("cloud_mitsuba_{case}.npy"));
        // The cases whose block NRMSE the tests take without Mitsuba's block noise.
        let clean = matches!(
            case.as_str(),
            "sun_back35"
                | "sun_back20"
                | "sun_back35_thin"
                | "sunsky_back35"
                | "below_sun"
                | "below_sky"
        );
        let lt = lighting_for(&scene, &grid, &skybake_engine::engine::Engine::new())?;
        let mut s = RenderSettings::for_quality(scene.quality, Method::Fast);
        s.photons.sun_photons = (s.photons.sun_photons as f64 * x) as usize;
        s.photons.env_photons = (s.photons.env_photons as f64 * x) as usize;
        if let Some(c) = env_f("COARSE") {
            s.photons.max_coarse_dim = c as usize;
        }
        let (mut sb, mut sbias, mut wb, mut wbias) = (0.0, 0.0, 0.0f64, 0.0f64);
        let mut line = String::new();
        // Per seed, the frame's 8×8 block means over the blocks inside the mask.
        let mut blocks_per_seed: Vec<Vec<f64>> = Vec::new();
        let mut mean_ref = 0.0;
        for &seed in &seeds {
            let mut sk = s;
            sk.photons.seed = seed;
            let f =
                skybake_render::render_frame(&scene, &grid, &lt, &sk, None, &|_| {}, &|| false)?;
            let (b, bias, mean_r) = stats(&f.radiance, &reference, &mask);
            blocks_per_seed.push(block_means(&f.radiance, &mask));
            mean_ref = mean_r;
            let noise = block_noise(
                &npy(&format!("cloud_mitsuba_{case}_stderr.npy")),
                &mask,
                mean_r,
            );
            let b_clean = (b * b - noise * noise).max(0.0).sqrt();
            let raw = b;
            let b = if clean { b_clean } else { b };
            line += &format!(" {:.2}/{:+.2}", 100.0 * b, 100.0 * bias);
            if !clean {
                line += &format!("({:.2})", 100.0 * b_clean);
            } else {
                line += &format!("({:.2}r)", 100.0 * raw);
            }
            sb += b;
            sbias += bias;
            wb = wb.max(b);
            if bias.abs() > wbias.abs() {
                wbias = bias;
            }
        }
        let n = seeds.len() as f64;
        // The photon noise apart: the RMS over the blocks of the block means' standard deviation
        // between the seeds, relative to Mitsuba's cloud mean; and the seeds' mean frame's block
        // NRMSE against Mitsuba (raw), what the method leaves with the noise averaged out.
        let nb = blocks_per_seed[0].len();
        let (mut var, mut mean_blocks) = (0.0, vec![0.0; nb]);
        for b in 0..nb {
            let m = blocks_per_seed.iter().map(|v| v[b]).sum::<f64>() / n;
            mean_blocks[b] = m;
            var += blocks_per_seed
                .iter()
                .map(|v| (v[b] - m).powi(2))
                .sum::<f64>()
                / (n - 1.0).max(1.0);
        }
        let ref_blocks = block_means(&reference, &mask);
        let sys = (mean_blocks
            .iter()
            .zip(&ref_blocks)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / nb as f64)
            .sqrt()
            / mean_ref;
        if std::env::var("MAP").is_ok() {
            // Per block of the 20×15 grid: seed std / mean-frame error, % of Mitsuba's mean.
            let mut k = 0;
            let (mut sd_map, mut err_map, mut rel_map) =
                (String::new(), String::new(), String::new());
            for by in 0..15 {
                for bx in 0..20 {
                    let inside = (0..64).all(|q| mask[(by * 8 + q / 8) * 160 + bx * 8 + q % 8]);
                    if inside {
                        let m = mean_blocks[k];
                        let sd = (blocks_per_seed
                            .iter()
                            .map(|v| (v[k] - m).powi(2))
                            .sum::<f64>()
                            / (n - 1.0))
                            .sqrt();
                        sd_map += &format!("{:5.1}", 100.0 * sd / mean_ref);
                        err_map += &format!("{:+6.1}", 100.0 * (m - ref_blocks[k]) / mean_ref);
                        rel_map += &format!("{:+6.1}", 100.0 * (m / ref_blocks[k] - 1.0));
                        k += 1;
                    } else {
                        sd_map += "    .";
                        err_map += "     .";
                        rel_map += "     .";
                    }
                }
                sd_map += "\n";
                err_map += "\n";
                rel_map += "\n";
            }
            println!("{case} seed std per block (% of mean):\n{sd_map}");
            println!("{case} mean-frame error per block (% of mean):\n{err_map}");
            println!("{case} mean-frame error per block (% of Mitsuba's block):\n{rel_map}");
        }
        println!(
            "{case:16} seed noise {:.2} % | mean frame block NRMSE {:.2} % (raw)",
            100.0 * (var / nb as f64).sqrt() / mean_ref,
            100.0 * sys
        );
        println!(
            "{case:16} block mean {:.2} worst {:.2} | bias mean {:+.2} worst {:+.2} |{line}",
            100.0 * sb / n,
            100.0 * wb,
            100.0 * sbias / n,
            100.0 * wbias
        );
    }
    Ok(())
}
