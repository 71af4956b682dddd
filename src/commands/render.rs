//! `skybake render`: a cloud frame through the frame product (the path of `POST /v1/render`).

use std::path::Path;

use skybake_engine::engine::Engine;
use skybake_physics::Error;
use skybake_product::frame::NoTiles;
use skybake_product::{AnyRequest, ComputeEnv, Format as BodyFormat};

use crate::error::Result;
use crate::flags::Format;
use crate::io::{print_json, read_limited, write_file};

/// `skybake render`: reads the scene (the library does no I/O), renders it through the frame
/// product (the same path as `POST /v1/render`), writes the EXR or PNG and prints a summary.
pub fn run_render(
    scene: &Path,
    output: Option<&Path>,
    method: &str,
    max_rel_error: Option<&str>,
    format: Format,
    engine: &Engine,
) -> Result<()> {
    use skybake_physics::cloud::scene as cloud_scene;
    use skybake_product::frame::FrameRequest;
    use skybake_render::Method;
    let method = Method::parse(method)?;
    let ext = output
        .and_then(|o| o.extension())
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if let (Some(out), Some(ext)) = (output, ext.as_deref()) {
        if ext != "exr" && ext != "png" {
            return Err(Error::invalid(
                "output",
                format!("'{}': a frame is written as .exr or .png", out.display()),
            )
            .into());
        }
    } else if let Some(out) = output {
        return Err(Error::invalid(
            "output",
            format!("'{}': a frame is written as .exr or .png", out.display()),
        )
        .into());
    }
    let text = read_limited(scene, "scene", cloud_scene::MAX_SCENE_FILE_BYTES)?;
    // A PNG is the RGB image only: the planner may run fewer wavelengths.
    let request = FrameRequest::parse(&text, method)?
        .with_max_rel_error(max_rel_error)?
        .with_rgb_only(ext.as_deref() == Some("png"));
    let dir = scene.parent().unwrap_or(Path::new("."));
    let loader =
        |name: &str| read_limited(&dir.join(name), "path", cloud_scene::MAX_GRID_FILE_BYTES);
    // A progress bar on a terminal only: tiles done / total and the time left.
    let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
        let bar = indicatif::ProgressBar::new(request.tile_count() as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} tiles ({eta} left) {msg}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message("voxels, light, multiple scattering");
        bar
    });
    let progress = |p: skybake_product::frame::TileProgress| {
        if let Some(bar) = &bar {
            if p.done > p.reused {
                bar.set_message("");
            }
            bar.set_position(p.done as u64);
        }
    };
    let request = AnyRequest::Frame(std::sync::Arc::new(request));
    let env = ComputeEnv {
        loader: &loader,
        tiles: &NoTiles,
        progress: &progress,
        cancel: &|| false,
        reuse: None,
    };
    let image = request.compute(engine, &env)?;
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    if let Some(out) = output {
        let format = match ext.as_deref() {
            Some("png") => BodyFormat::Png,
            _ => BodyFormat::Exr,
        };
        write_file(out, &request.body(format, &image)?)?;
    }
    let mut summary = skybake_product::artifact::frame_summary(&image);
    summary["scene"] = serde_json::json!(scene.display().to_string());
    summary["output"] = serde_json::json!(output.map(|p| p.display().to_string()));
    if format == Format::Json {
        print_json(&summary)
    } else {
        println!(
            "{} {}x{} ({:?}) -> {}",
            scene.display(),
            image.width(),
            image.height(),
            method,
            output
                .map(|p| p.display().to_string())
                .unwrap_or_else(|| "-".into())
        );
        Ok(())
    }
}
