//! `skybake lut`: the real-time texture bundle of an atmosphere (Bruneton 2017's layout, or
//! with `--layout skyview` skybake's sky-view layout; docs/lut.md) written to a directory;
//! prints what was written.

use std::path::Path;
use std::time::Instant;

use serde_json::json;
use skybake_engine::engine::Engine;
use skybake_product::lut::{Layout, LutRequest};
use skybake_product::params::RequestParams;

use crate::error::Result;
use crate::io::{print_json, request_params, write_file};

/// Computes the bundle (the precise table comes from the table cache like every product's) and
/// writes its files into `dir`.
/// `layout` is `bruneton2017` or `skyview` (refused otherwise, naming `layout`).
pub fn lut(flags: &RequestParams, layout: &str, dir: &Path, engine: &Engine) -> Result<()> {
    let layout = Layout::parse(layout)?;
    let req = LutRequest::from_params(&request_params(flags.clone())?)?.with_layout(layout);
    let start = Instant::now();
    let (files, timing_ms) = req.compute_files_unless(engine, &|| false)?;
    let compute_ms = start.elapsed().as_secs_f64() * 1e3;
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
            "precise_table": timing_ms[0],
            "transmittance": timing_ms[1],
            "scattering": timing_ms[2],
            "irradiance": timing_ms[3],
        },
        "total_ms": start.elapsed().as_secs_f64() * 1e3,
    }))
}
