//! Times the cellular automaton on the paper's 256×256×20 space (Dobashi et al. 2000, §6: 0.5 s per step).
//! Run: `cargo run -p skybake-harness --features probes --example ca_bench [nx ny nz steps]`.

fn main() -> Result<(), skybake_physics::Error> {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let [nx, ny, nz, steps] = match args.as_slice() {
        [a, b, c, d] => [*a, *b, *c, *d],
        _ => [256, 256, 20, 200],
    };
    let b = skybake_harness::physics_bench::bench_ca_step(nx, ny, nz, steps)?;
    println!(
        "ca-step {}x{}x{}: mean {:.3} ms, min {:.3} ms over {} steps, cloud cover {:.3}",
        nx,
        ny,
        nz,
        b.mean_step.as_secs_f64() * 1e3,
        b.min_step.as_secs_f64() * 1e3,
        b.steps,
        b.cloud_cover
    );
    Ok(())
}
