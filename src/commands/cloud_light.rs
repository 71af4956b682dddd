//! `skybake cloud-light`: the pre-lit cloud volume of a frame scene (the fast method's per-voxel
//! light as OpenEXR 3-D textures + `manifest.json`, docs/cloud-light.md) written to a directory;
//! prints what was written.

use std::path::Path;
use std::time::Instant;

use serde_json::json;
use skybake_engine::engine::Engine;
use skybake_physics::cloud::scene as cloud_scene;
use skybake_product::cloud_light::CloudLightRequest;

use crate::error::Result;
use crate::flags::Format;
use crate::io::{print_json, read_limited, write_file};

/// Reads the scene (files it names relative to its directory), lights its cloud by the fast
/// method and writes the export's files into `dir`.
pub fn cloud_light(scene: &Path, dir: &Path, format: Format, engine: &Engine) -> Result<()> {
    let text = read_limited(scene, "scene", cloud_scene::MAX_SCENE_FILE_BYTES)?;
    let req = CloudLightRequest::parse(&text)?;
    let base = scene.parent().unwrap_or(Path::new("."));
    let loader =
        |name: &str| read_limited(&base.join(name), "path", cloud_scene::MAX_GRID_FILE_BYTES);
    let start = Instant::now();
    let out = req.compute(engine, &loader, &|| false)?;
    let compute_ms = start.elapsed().as_secs_f64() * 1e3;
    let encode = Instant::now();
    let files = out.light.files()?;
    let encode_ms = encode.elapsed().as_secs_f64() * 1e3;
    skybake_store::files::create_dir_all(dir)?;
    let mut listed = Vec::new();
    for (name, bytes) in &files {
        write_file(&dir.join(name), bytes)?;
        listed.push(json!({"file": name, "bytes": bytes.len()}));
    }
    let total: usize = files.iter().map(|(_, b)| b.len()).sum();
    let timing: serde_json::Map<String, serde_json::Value> = out
        .timing_ms
        .iter()
        .map(|(n, ms)| (n.clone(), json!(ms)))
        .collect();
    let summary = json!({
        "directory": dir.display().to_string(),
        "dims": out.light.dims,
        "voxel_size_m": out.light.voxel_size_m,
        "wavelengths_nm": out.light.wavelengths_nm,
        "files": listed,
        "total_bytes": total,
        "compute_ms": compute_ms,
        "encode_ms": encode_ms,
        "stage_ms": timing,
        "total_ms": start.elapsed().as_secs_f64() * 1e3,
    });
    match format {
        Format::Json => print_json(&summary),
        Format::Text => {
            println!(
                "{}: {} files, {:.1} MB, {:?} voxels, {:.0} ms",
                dir.display(),
                files.len(),
                total as f64 / 1e6,
                out.light.dims,
                start.elapsed().as_secs_f64() * 1e3
            );
            Ok(())
        }
    }
}
