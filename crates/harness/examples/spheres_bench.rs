//! Ostroushko et al., table 1: an 800×600 transmittance image of a cloud with 5^K leaf spheres.
//! Run: `cargo run -p skybake-harness --features probes --example spheres_bench [K ...]` (default K = 6 8 10).

fn main() -> Result<(), skybake_physics::Error> {
    let mut ks: Vec<u32> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    if ks.is_empty() {
        ks = vec![6, 8, 10];
    }
    for k in ks {
        let b = skybake_harness::physics_bench::bench_spheres(k, 800, 600)?;
        println!(
            "K={k} leaves={}: build {:.3} s, render {:.3} s ({} tests), render LOD 1px {:.3} s ({} tests), coverage {:.2}",
            b.leaves,
            b.build.as_secs_f64(),
            b.render.as_secs_f64(),
            b.stats.spheres_tested,
            b.render_lod.as_secs_f64(),
            b.stats_lod.spheres_tested,
            b.coverage
        );
    }
    Ok(())
}
