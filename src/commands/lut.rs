//! `skybake lut`: the real-time texture bundle of an atmosphere (Bruneton 2017's layout, see
//! docs/lut.md) written to a directory; prints what was written.

use std::path::Path;
use std::time::Instant;

use serde_json::json;
use skybake_engine::engine::Engine;
use skybake_product::lut::LutRequest;
use skybake_product::params::RequestParams;

use crate::error::Result;
use crate::io::{print_json, request_params, write_file};

/// Computes the bundle (the precise table comes from the table cache like every product's) and
/// writes its files into `dir`.
pub fn lut(flags: &RequestParams, dir: &Path, engine: &Engine) -> Result<()> {
    let req = LutRequest::from_params(&request_params(flags.clone())?)?;
    let start = Instant::now();
    let bundle = req.compute(engine)?;
    let compute_ms = start.elapsed().as_secs_f64() * 1e3;
    let files = req.files(&bundle)?;
    skybake_store::files::create_dir_all(dir)?;
    let mut listed = Vec::new();
    for (name, bytes) in &files {
        write_file(&dir.join(name), bytes)?;
        listed.push(json!({"file": name, "bytes": bytes.len()}));
    }
    print_json(&json!({
        "directory": dir.display().to_string(),
        "files": listed,
        "total_bytes": files.iter().map(|(_, b)| b.len()).sum::<usize>(),
        "compute_ms": compute_ms,
        "table_ms": {
            "precise_table": bundle.timing_ms[0],
            "transmittance": bundle.timing_ms[1],
            "scattering": bundle.timing_ms[2],
            "irradiance": bundle.timing_ms[3],
        },
        "total_ms": start.elapsed().as_secs_f64() * 1e3,
    }))
}
