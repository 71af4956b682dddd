//! The multiple-scattering table's per-ray lookup (`PreciseMultipleScattering::add_from_slice_many`,
//! the `skyview` bundle's lookup) timed on its own, one thread: a fixed set of points (random
//! radius and view zenith, seed fixed) and suns per point (zenith cosine and view–sun cosine), in
//! twilight (sun −20…0°) and mixed (sun −20…+30°, the day cells filled where a sun needs them).
//! Prints the CPU time per lookup (the thread's own, `/proc/thread-self/schedstat`, so other
//! processes' load counts only through the shared core) as the minimum and median of the rounds,
//! and a checksum of the results' bits, so two binaries' values can be compared.
//!
//! `cargo run --release -p skybake-harness --features probes --example twilight_lookup_bench -- [ROUNDS]`

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use skybake_engine::engine::Engine;
use skybake_physics::atmosphere::multiple_precise::JSlice;
use skybake_product::lut::LutRequest;
use skybake_product::params::RequestParams;

/// This thread's CPU time in ns.
fn thread_cpu_ns() -> u64 {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").expect("schedstat");
    s.split_whitespace()
        .next()
        .and_then(|v| v.parse().ok())
        .expect("schedstat's first field")
}

struct Point {
    r: f64,
    mu: f64,
    mu_s: Vec<f64>,
    nu: Vec<f64>,
}

fn workload(bottom_m: f64, lo_deg: f64, hi_deg: f64, seed: u64) -> Vec<Point> {
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..3000)
        .map(|_| {
            let h: f64 = rng.random_range(0.0..1.0f64);
            let r = bottom_m + 100_000.0 * h * h;
            let mu = rng.random_range(-1.0..1.0f64);
            let n = 96;
            let (mut mu_s, mut nu) = (Vec::with_capacity(n), Vec::with_capacity(n));
            for _ in 0..n {
                let e = rng.random_range(lo_deg..hi_deg).to_radians();
                let m_s = e.sin();
                let sin = ((1.0 - mu * mu) * (1.0 - m_s * m_s)).max(0.0).sqrt();
                mu_s.push(m_s);
                nu.push((mu * m_s + sin * rng.random_range(-1.0..1.0f64)).clamp(-1.0, 1.0));
            }
            Point { r, mu, mu_s, nu }
        })
        .collect()
}

fn main() {
    let rounds: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(7);
    let engine = Engine::new();
    let request = LutRequest::from_params(&RequestParams::default()).expect("request");
    let shared = engine.shared(&request.spec).expect("shared tables");
    let precise = shared.precise();
    let n_l = shared.medium.len();
    let bottom = shared.medium.bottom_radius_m;
    let day_mu_s = precise.day_mu_s();
    for (name, lo, hi) in [("twilight", -20.0, 0.0), ("mixed", -20.0, 30.0)] {
        let points = workload(bottom, lo, hi, 27);
        let lookups: usize = points.iter().map(|p| p.mu_s.len()).sum();
        let mut slices: Vec<JSlice> = points
            .iter()
            .map(|p| {
                let mut s = JSlice::default();
                precise.slice_corners(p.r, p.mu, &mut s);
                if p.mu_s.iter().any(|&m| m > day_mu_s) {
                    precise.fill_day(&mut s);
                }
                s
            })
            .collect();
        let mut out = vec![0.0f64; 96 * n_l];
        let mut times = Vec::new();
        let mut sum = 0u64;
        for _ in 0..rounds {
            sum = 0;
            let t0 = thread_cpu_ns();
            for (p, s) in points.iter().zip(&mut slices) {
                out.iter_mut().for_each(|o| *o = 0.0);
                precise.add_from_slice_many(s, &p.mu_s, &p.nu, &mut out);
                for o in &out {
                    sum = sum.wrapping_mul(31).wrapping_add(o.to_bits());
                }
            }
            times.push((thread_cpu_ns() - t0) as f64 / lookups as f64);
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{name}: {lookups} lookups a round; ns per lookup min {:.1} median {:.1}; checksum {sum:016x}",
            times[0],
            times[times.len() / 2]
        );
    }
}
