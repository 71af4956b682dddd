//! `skybake clouds`: a scene's cloud voxelised and written as a `.npy` density grid.

use std::path::Path;

use skybake_physics::Error;

use crate::error::Result;
use crate::flags::Format;
use crate::io::{print_json, read_limited, write_file};

/// `skybake clouds`: reads the scene (the library does no I/O), voxelises its cloud section with
/// files resolved relative to the scene's directory, writes the grid as `.npy` and prints a
/// summary.
pub fn run_clouds(scene: &Path, voxels: Option<&Path>, format: Format) -> Result<()> {
    use skybake_physics::cloud::{import, scene as cloud_scene};
    use std::time::Instant;
    if let Some(out) = voxels {
        if out
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
            != Some("npy")
        {
            return Err(Error::invalid(
                "voxels",
                format!("'{}': the density grid is written as .npy", out.display()),
            )
            .into());
        }
    }
    let start = Instant::now();
    let text = read_limited(scene, "scene", cloud_scene::MAX_SCENE_FILE_BYTES)?;
    let section = cloud_scene::parse_scene_file(&text)?;
    let dir = scene.parent().unwrap_or(Path::new("."));
    let loader =
        |name: &str| read_limited(&dir.join(name), "path", cloud_scene::MAX_GRID_FILE_BYTES);
    let parsed = Instant::now();
    let (grid, report) = section.voxelize_with_report(&loader)?;
    let voxelized = Instant::now();
    let npy_bytes = match voxels {
        Some(out) => {
            let bytes = import::to_npy_bytes(&grid);
            write_file(out, &bytes)?;
            Some(bytes.len())
        }
        None => None,
    };
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    let summary = serde_json::json!({
        "scene": scene.display().to_string(),
        "source": section.source.kind(),
        "dims": grid.dims,
        "voxel_size_m": grid.voxel_size_m,
        "origin_m": grid.origin_m.to_array(),
        "max_density": grid.max_density(),
        "nonzero_voxels": grid.data.iter().filter(|v| **v > 0.0).count(),
        "voxels": voxels.map(|p| p.display().to_string()),
        "npy_bytes": npy_bytes,
        "report": report,
        "timing_ms": {
            "read_parse": ms(start, parsed),
            "voxelize": ms(parsed, voxelized),
            "write": ms(voxelized, Instant::now()),
        },
    });
    match format {
        Format::Json => print_json(&summary),
        Format::Text => {
            println!(
                "{} ({}): {:?} voxels of {} m from {:?} m, max density {}, {} non-zero, voxelised in {:.1} ms",
                scene.display(),
                summary["source"].as_str().unwrap_or(""),
                grid.dims,
                grid.voxel_size_m,
                grid.origin_m.to_array(),
                summary["max_density"],
                summary["nonzero_voxels"],
                ms(parsed, voxelized),
            );
            if let Some(error) = summary["report"]["fit_error"].as_f64() {
                println!(
                    "satellite fit: final relative error {error:.4}, {} balls, converged {}",
                    summary["report"]["fit_balls"], summary["report"]["fit_converged"]
                );
            }
            Ok(())
        }
    }
}
