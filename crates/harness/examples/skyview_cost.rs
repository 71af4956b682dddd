//! The `skyview` bundle's build cost and how far its texels are from a reference bundle's: builds
//! the bundle as `skybake lut --layout skyview` does (`earth`, RGB, `standard`), prints the
//! multiple-scattering table's point × sun lookups (`skybake_lut::build::LOOKUPS`, sky view and
//! irradiance), the interpolated suns refined (`REFINED`) and the build's wall time, and, given
//! the directory of another build of the same bundle (e.g. one written by another binary), the
//! relative differences of the rayleigh, mie and irradiance texels (their scale applied, after
//! the half floats' rounding): the largest, where, and percentiles, over texels above 10⁻⁶ of
//! their slice's peak, over all and by the sun node's elevation above the observer's horizon
//! (below −12°, −12…−6°, −6…5°, from 5°); and the refined suns by the sun's elevation at the
//! ray's origin (`REFINED_BY`).
//!
//! `cargo run --release -p skybake-harness --features probes --example skyview_cost -- [REF_DIR]`

use std::path::Path;
use std::sync::atomic::Ordering;

use serde_json::Value;
use skybake_engine::engine::Engine;
use skybake_lut::load::{skyview_from_files, DecodedFile};
use skybake_lut::manifest::MANIFEST_FILE;
use skybake_lut::skyview::{sun_node_deg, N_ALT, N_AZ, N_SUN, N_VIEW, SLICE_PEAK};
use skybake_lut::SkyViewBundle;
use skybake_product::lut::{Layout, LutRequest};
use skybake_product::params::RequestParams;

fn read_bundle(dir: &Path) -> SkyViewBundle {
    let text = std::fs::read_to_string(dir.join(MANIFEST_FILE)).expect("manifest");
    let manifest: Value = serde_json::from_str(&text).expect("manifest JSON");
    let mut read = |file: &str| -> skybake_lut::Result<DecodedFile> {
        let bytes = std::fs::read(dir.join(file))
            .map_err(|e| skybake_lut::Error::invalid("bundle", format!("{file}: {e}")))?;
        skybake_store::texture::decode_texture_exr(&bytes)
            .map_err(|e| skybake_lut::Error::invalid("bundle", format!("{file}: {e}")))
    };
    skyview_from_files(&manifest, &mut read).expect("bundle")
}

/// Prints the largest relative difference (and where), and its 99th and 99.9th percentiles.
fn report(name: &str, diffs: &mut [(f64, String)]) {
    diffs.sort_by(|a, b| b.0.total_cmp(&a.0));
    let n = diffs.len();
    let at = |q: f64| diffs[((1.0 - q) * n as f64) as usize].0;
    let moved = diffs.iter().filter(|d| d.0 > 0.0).count();
    println!(
        "{name}: {n} texels, {moved} moved; max {:.3e} ({}), 99th pct {:.2e}, 99.9th {:.2e}",
        diffs[0].0,
        diffs[0].1,
        at(0.99),
        at(0.999)
    );
}

fn main() {
    let engine = Engine::new();
    let request = LutRequest::from_params(&RequestParams::default())
        .expect("request")
        .with_layout(Layout::SkyView);
    let before = skybake_lut::build::LOOKUPS.load(Ordering::Relaxed);
    let t = std::time::Instant::now();
    let b = request.compute_skyview(&engine).expect("bundle");
    let wall = t.elapsed().as_secs_f64();
    let lookups = skybake_lut::build::LOOKUPS.load(Ordering::Relaxed) - before;
    let refined = skybake_lut::build::REFINED.load(Ordering::Relaxed);
    println!(
        "lookups {lookups}; interpolated suns refined {refined}; build {wall:.2} s wall; stages ms {:?}",
        b.timing_ms
    );
    let by: Vec<u64> = skybake_lut::build::REFINED_BY
        .iter()
        .map(|c| c.load(Ordering::Relaxed))
        .collect();
    println!(
        "refined by sun (<-12, -12..-6, -6..0, 0..5, 5..20, >20): sun axis {:?}, columns {:?}",
        &by[..6],
        &by[6..]
    );
    let Some(dir) = std::env::args().nth(1) else {
        return;
    };
    let r = read_bundle(Path::new(&dir));
    let n_c = b.wavelengths_nm.len();
    for (part, name) in [(0usize, "rayleigh"), (1, "mie")] {
        let (tb, tr) = if part == 0 {
            (&b.rayleigh, &r.rayleigh)
        } else {
            (&b.mie, &r.mie)
        };
        let mut diffs = Vec::new();
        let mut bands: Vec<Vec<(f64, String)>> = vec![Vec::new(); 4];
        for k in 0..N_ALT {
            for j in 0..N_SUN {
                let z = k * N_SUN + j;
                for c in 0..n_c {
                    let s = z * 2 * n_c + part * n_c + c;
                    let (sb, sr) = (b.scale.data[s] as f64, r.scale.data[s] as f64);
                    for i in 0..N_VIEW {
                        for a in 0..N_AZ {
                            let o = ((z * N_VIEW + i) * N_AZ + a) * n_c + c;
                            let (x, y) = (tb.data[o] as f64 * sb, tr.data[o] as f64 * sr);
                            if y.abs() <= 1e-6 * sr * SLICE_PEAK {
                                continue;
                            }
                            let d = (x / y - 1.0).abs();
                            let at = format!("alt {k} sun {j} view {i} col {a} ch {c}");
                            let e = sun_node_deg(j);
                            let band = [-12.0, -6.0, 5.0].iter().filter(|&&x| e >= x).count();
                            bands[band].push((d, at.clone()));
                            diffs.push((d, at));
                        }
                    }
                }
            }
        }
        report(name, &mut diffs);
        for (n, band) in bands.iter_mut().enumerate() {
            let label = ["< -12", "-12..-6", "-6..5", ">= 5"][n];
            report(&format!("  {name} sun {label}"), band);
        }
    }
    let mut diffs: Vec<(f64, String)> = b
        .irradiance
        .data
        .iter()
        .zip(&r.irradiance.data)
        .enumerate()
        .filter(|(_, (_, &y))| y > 0.0)
        .map(|(n, (&x, &y))| {
            let (d, sun) = ((x as f64 / y as f64 - 1.0).abs(), n / n_c % N_SUN);
            (
                d,
                format!("alt {} sun {sun} ch {}", n / n_c / N_SUN, n % n_c),
            )
        })
        .collect();
    report("irradiance", &mut diffs);
}
