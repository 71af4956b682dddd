//! `skybake clouds`: the built binary voxelises a scene file, writes a `.npy` that reads back as
//! the library's own grid, resolves the files a scene names relative to the scene, and refuses
//! bad input with exit code 2 and the offending field named.

use glam::DVec3;
use skybake_physics::cloud::satellite::{self, GrayImage};
use skybake_physics::cloud::scene::{parse_scene_file, CloudSource, MAX_GRID_FILE_BYTES};
use skybake_physics::cloud::{import, DensityGrid};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const SCENES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes");

/// A fresh scratch directory for one test.
pub(crate) fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("skybake-cli-clouds-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The `skybake` binary run with `args` in `cwd`.
pub(crate) fn skybake(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap()
}

fn no_files(path: &str) -> skybake_physics::Result<Vec<u8>> {
    Err(skybake_physics::Error::invalid(
        "path",
        format!("no file {path}"),
    ))
}

/// Stderr of a run that must fail with exit code 2 and an `error: ...` line.
fn refused(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(2), "stderr: {stderr}");
    assert!(stderr.starts_with("error: "), "stderr: {stderr}");
    assert!(out.stdout.is_empty());
    stderr
}

#[test]
fn metaballs_example_writes_a_npy_that_round_trips() {
    let dir = scratch("metaballs");
    let scene = Path::new(SCENES).join("cumulus-metaballs.json");
    let npy = dir.join("cumulus.npy");
    let out = skybake(
        &[
            "clouds",
            scene.to_str().unwrap(),
            "--voxels",
            npy.to_str().unwrap(),
            "--format",
            "json",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();

    // The library's grid for the same scene is what the file must hold.
    let expected = parse_scene_file(&std::fs::read(&scene).unwrap())
        .unwrap()
        .voxelize(&no_files)
        .unwrap();
    let bytes = std::fs::read(&npy).unwrap();
    assert_eq!(summary["npy_bytes"], bytes.len());
    let origin = summary["origin_m"].as_array().unwrap();
    let origin = DVec3::new(
        origin[0].as_f64().unwrap(),
        origin[1].as_f64().unwrap(),
        origin[2].as_f64().unwrap(),
    );
    let voxel_size_m = summary["voxel_size_m"].as_f64().unwrap();
    let read = import::from_npy_bytes(&bytes, voxel_size_m, origin).unwrap();
    assert_eq!(read, expected);

    assert_eq!(summary["source"], "metaballs");
    assert_eq!(summary["dims"], serde_json::json!(expected.dims));
    assert_eq!(voxel_size_m, 25.0);
    assert_eq!(
        summary["nonzero_voxels"],
        expected.data.iter().filter(|v| **v > 0.0).count()
    );
    assert_eq!(
        summary["max_density"].as_f64().unwrap(),
        expected.max_density() as f64
    );
    assert!(summary["timing_ms"]["voxelize"].as_f64().unwrap() >= 0.0);
    // Writing the same grid again through the library gives the same bytes.
    assert_eq!(import::to_npy_bytes(&expected), bytes);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The satellite example reads its PNG next to the scene and reports the fit's final error, the
/// same as the library's fit of that image.
#[test]
fn satellite_example_reports_the_final_fit_error() {
    let dir = scratch("satellite");
    let scene = Path::new(SCENES).join("satellite-field.json");
    let out = skybake(&["clouds", scene.to_str().unwrap()], &dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let section = parse_scene_file(&std::fs::read(&scene).unwrap()).unwrap();
    let CloudSource::Satellite(params) = &section.source else {
        panic!("satellite-field.json is not a satellite scene")
    };
    let png = std::fs::read(Path::new(SCENES).join(&params.image)).unwrap();
    let fit = satellite::fit(&GrayImage::from_png_bytes(&png).unwrap(), params).unwrap();
    assert_eq!(summary["source"], "satellite");
    // serde_json's default float parsing may differ from the printed value in the last bit.
    let printed = summary["report"]["fit_error"].as_f64().unwrap();
    assert!(
        (printed - fit.error).abs() <= 1e-14,
        "{printed} vs {}",
        fit.error
    );
    assert_eq!(summary["report"]["fit_converged"], fit.converged);
    assert_eq!(summary["report"]["fit_balls"], fit.blobs.len());
    assert!(fit.error < 1.0);
    assert!(summary["voxels"].is_null() && summary["npy_bytes"].is_null());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A grid scene names its data file relative to itself; the CLI runs from another directory.
#[test]
fn files_a_scene_names_are_read_relative_to_the_scene() {
    let dir = scratch("relative");
    std::fs::create_dir_all(dir.join("scenes/data")).unwrap();
    let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.125).collect();
    let grid = DensityGrid::from_data([4, 3, 2], 10.0, DVec3::new(0.0, 0.0, 1000.0), data).unwrap();
    std::fs::write(dir.join("scenes/data/g.npy"), import::to_npy_bytes(&grid)).unwrap();
    std::fs::write(
        dir.join("scenes/grid.json"),
        r#"{"name": "g", "description": "a tiny imported grid",
            "cloud": {"voxel_size_m": 10, "source": {"type": "grid", "path": "data/g.npy",
                      "origin_m": [0, 0, 1000]}}}"#,
    )
    .unwrap();
    let out = skybake(&["clouds", "scenes/grid.json", "--voxels", "out.npy"], &dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let back = import::from_npy_bytes(
        &std::fs::read(dir.join("out.npy")).unwrap(),
        10.0,
        grid.origin_m,
    )
    .unwrap();
    assert_eq!(back, grid);
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["nonzero_voxels"], 23);
    assert_eq!(summary["origin_m"], serde_json::json!([0.0, 0.0, 1000.0]));

    // A data file larger than the limit is refused from its size, before it is read (sparse file).
    let big = std::fs::File::create(dir.join("scenes/data/g.npy")).unwrap();
    big.set_len(MAX_GRID_FILE_BYTES as u64 + 1).unwrap();
    drop(big);
    let stderr = refused(&skybake(&["clouds", "scenes/grid.json"], &dir));
    assert!(stderr.contains("path"), "{stderr}");
    assert!(
        stderr.contains(&MAX_GRID_FILE_BYTES.to_string()),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_scenes_exit_with_code_2_naming_the_field() {
    let dir = scratch("bad");
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path.to_str().unwrap().to_string()
    };
    let negative_radius = write(
        "radius.json",
        r#"{"cloud": {"source": {"type": "metaballs",
            "balls": [{"centre_m": [0, 0, 1000], "radius_m": -5, "density": 1}]}}}"#,
    );
    let stderr = refused(&skybake(&["clouds", &negative_radius], &dir));
    assert!(stderr.contains("balls[0].radius_m"), "{stderr}");

    let level = write(
        "level.json",
        r#"{"cloud": {"source": {"type": "spheres", "level": 9,
            "params": {"levels": 3, "size_m": [100, 100, 100], "mor_m": 20, "seed": 1}}}}"#,
    );
    let stderr = refused(&skybake(&["clouds", &level], &dir));
    assert!(stderr.contains("level"), "{stderr}");

    let no_cloud = write("none.json", r#"{"name": "empty"}"#);
    let stderr = refused(&skybake(&["clouds", &no_cloud], &dir));
    assert!(stderr.contains("cloud"), "{stderr}");

    let missing = dir.join("missing.json");
    let stderr = refused(&skybake(&["clouds", missing.to_str().unwrap()], &dir));
    assert!(stderr.contains("scene"), "{stderr}");

    let scene = Path::new(SCENES).join("cumulus-metaballs.json");
    let stderr = refused(&skybake(
        &["clouds", scene.to_str().unwrap(), "--voxels", "out.raw"],
        &dir,
    ));
    assert!(stderr.contains("voxels"), "{stderr}");
    assert!(!dir.join("out.raw").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
