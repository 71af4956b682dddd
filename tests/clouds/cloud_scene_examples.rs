//! The cloud section of the scene JSON: example scenes parse and voxelise, files come through
//! the injected loader, and malformed sections are refused with the offending field named.
//! `SKYBAKE_REGENERATE_EXAMPLES=1 cargo test --test cloud_scene_examples` rewrites the example
//! satellite PNG from its generator.

use glam::DVec3;
use skybake_physics::cloud::satellite::{synthetic_cloud_field, GrayImage};
use skybake_physics::cloud::scene::{
    parse_cloud_section, parse_scene_file, voxelize, CloudSource, GridParams,
};
use skybake_physics::{Error, Result};
use std::path::Path;

const SCENES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes");
/// Side and seed of the example satellite image.
const SATELLITE_SIDE: usize = 128;
const SATELLITE_SEED: u64 = 2026;

fn loader(path: &str) -> Result<Vec<u8>> {
    std::fs::read(Path::new(SCENES).join(path))
        .map_err(|e| Error::invalid("path", format!("{path}: {e}")))
}

fn section(name: &str) -> skybake_physics::cloud::scene::CloudSection {
    let text = std::fs::read(Path::new(SCENES).join(name)).unwrap();
    parse_scene_file(&text).unwrap()
}

/// Every `.json` file in `config/scenes/` is a scene that voxelises through the one scene API
/// (files it names are read relative to `config/scenes/`), and together they cover every source
/// that needs no external grid file.
#[test]
fn every_scene_file_voxelises_through_the_scene_api() {
    let mut kinds = Vec::new();
    let mut names: Vec<_> = std::fs::read_dir(SCENES)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    names.sort();
    for path in &names {
        let name = path.file_name().unwrap().to_string_lossy();
        let text = std::fs::read(path).unwrap();
        let scene: serde_json::Value = serde_json::from_slice(&text).unwrap();
        assert!(scene["name"].is_string(), "{name}: no name");
        assert!(scene["description"].is_string(), "{name}: no description");
        let section = parse_scene_file(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let grid = section
            .voxelize(&loader)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(grid.voxel_size_m, section.voxel_size_m, "{name}");
        assert_eq!(
            grid.data.len(),
            grid.dims.iter().product::<usize>(),
            "{name}"
        );
        assert!(
            grid.data.iter().all(|v| v.is_finite() && *v >= 0.0),
            "{name}: densities must be finite and >= 0"
        );
        let cloudy = grid.data.iter().filter(|v| **v > 0.01).count();
        assert!(
            grid.max_density() > 0.1 && cloudy >= 1000,
            "{name}: max {} and {cloudy} cloudy voxels",
            grid.max_density()
        );
        // Frame scenes (`*-frame.json`, tests/clouds/render_frame.rs) reuse a source for lighting.
        if !name.ends_with("-frame.json") {
            kinds.push(section.source.kind());
        }
    }
    kinds.sort();
    assert_eq!(
        kinds,
        ["automaton", "fractal", "metaballs", "satellite", "spheres"],
        "one example scene per source"
    );
}

#[test]
fn scene_files_without_a_valid_cloud_section_are_refused() {
    let field = |json: &str| {
        parse_scene_file(json.as_bytes())
            .unwrap_err()
            .field()
            .to_string()
    };
    assert_eq!(field("not json"), "scene");
    assert_eq!(field(r#"{"name": "x"}"#), "cloud");
    assert_eq!(
        field(r#"{"cloud": {"source": {"type": "metaballs"}}}"#),
        "cloud"
    );
    assert_eq!(
        field(
            r#"{"cloud": {"source": {"type": "spheres", "level": 7, "params": {"levels": 2, "size_m": [1, 1, 1], "mor_m": 5, "seed": 1}}}}"#
        ),
        "level"
    );
    assert_eq!(
        field(
            r#"{"cloud": {"source": {"type": "automaton", "frame_time_steps": -1, "params": {"dims": [8, 8, 8], "cell_size_m": 10, "seed": 1, "background": {"hum": 0, "act": 0, "ext": 0}}}}}"#
        ),
        "frame_time_steps"
    );
    assert_eq!(
        field(
            r#"{"cloud": {"source": {"type": "automaton", "frame_time_steps": 1, "params": {"dims": [8, 0, 8], "cell_size_m": 10, "seed": 1, "background": {"hum": 0, "act": 0, "ext": 0}}}}}"#
        ),
        "dims"
    );
}

/// The example PNG is the 8-bit quantisation of `synthetic_cloud_field(128, 2026)`.
/// The example satellite PNG is a cloud field of the kind the generator describes
/// (`synthetic_cloud_field`: reflectance 1 − exp(−1.5 τ) of Gaussian cells at least 1.9 px wide
/// in clusters): a 128 × 128 grey image with clear sky and bright saturating cores, partial cover,
/// and smooth (cells, not pixel noise). `SKYBAKE_REGENERATE_EXAMPLES=1` rewrites it.
#[test]
fn satellite_example_png_is_the_generated_field() {
    let path = Path::new(SCENES).join("satellite-field.png");
    if std::env::var_os("SKYBAKE_REGENERATE_EXAMPLES").is_some() {
        let field = synthetic_cloud_field(SATELLITE_SIDE, SATELLITE_SEED).unwrap();
        let quantised: Vec<u8> = field
            .data
            .iter()
            .map(|v| (v * 255.0).round() as u8)
            .collect();
        image::GrayImage::from_raw(SATELLITE_SIDE as u32, SATELLITE_SIDE as u32, quantised)
            .unwrap()
            .save(&path)
            .unwrap();
    }
    let bytes = std::fs::read(&path).unwrap();
    assert!(bytes.len() < 50_000, "{} bytes", bytes.len());
    let png = GrayImage::from_png_bytes(&bytes).unwrap();
    assert_eq!((png.width, png.height), (SATELLITE_SIDE, SATELLITE_SIDE));
    let v = &png.data;
    let (min, max) = v
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    assert!(min < 0.05, "no clear sky: darkest pixel {min}");
    assert!(max > 0.5 && max <= 1.0, "brightest pixel {max}");
    let cover = v.iter().filter(|&&x| x > 0.1).count() as f64 / v.len() as f64;
    assert!((0.1..0.9).contains(&cover), "cloud cover {cover}");
    // Smooth: neighbouring pixels differ little on average (white noise of the same histogram
    // would differ by about the standard deviation).
    let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
    let sd = (v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
    let side = SATELLITE_SIDE;
    let step: f64 = (0..side)
        .flat_map(|y| (1..side).map(move |x| (y, x)))
        .map(|(y, x)| (v[y * side + x] - v[y * side + x - 1]).abs() as f64)
        .sum::<f64>()
        / (side * (side - 1)) as f64;
    assert!(
        step < 0.2 * sd,
        "mean neighbour step {step} vs standard deviation {sd}"
    );
}

#[test]
fn example_scenes_parse_and_voxelise() {
    for (name, min_voxels) in [
        ("cumulus-metaballs.json", 50_000),
        ("cumulus-fractal.json", 50_000),
        ("satellite-field.json", 50_000),
    ] {
        let s = section(name);
        let grid = s.voxelize(&loader).unwrap();
        assert_eq!(grid.voxel_size_m, s.voxel_size_m, "{name}");
        assert!(
            grid.data.len() >= min_voxels,
            "{name}: {} voxels",
            grid.data.len()
        );
        assert!(grid.max_density() > 0.1, "{name}");
        // The box border is clear of cloud (one voxel of margin around the support).
        let [nx, ny, nz] = grid.dims;
        for y in 0..ny {
            for x in 0..nx {
                assert_eq!(grid.at(x, y, 0), 0.0, "{name}");
                assert_eq!(grid.at(x, y, nz - 1), 0.0, "{name}");
            }
        }
    }
}

#[test]
fn sources_round_trip_through_json() {
    for name in [
        "cumulus-metaballs.json",
        "cumulus-fractal.json",
        "satellite-field.json",
        "automaton-field.json",
        "sphere-cloud.json",
    ] {
        let s = section(name);
        let again = parse_cloud_section(&serde_json::to_vec(&s).unwrap()).unwrap();
        assert_eq!(again, s);
    }
    // Defaults fill omitted fields.
    let s = parse_cloud_section(br#"{"source": {"type": "satellite", "image": "a.png"}}"#).unwrap();
    assert_eq!(s.voxel_size_m, 50.0);
    let CloudSource::Satellite(p) = s.source else {
        panic!("wrong variant")
    };
    assert_eq!(
        (p.pixel_size_m, p.max_balls, p.cloud_threshold),
        (250.0, 4000, 0.25)
    );
}

#[test]
fn malformed_sections_are_refused_naming_the_field() {
    let field = |json: &str| {
        parse_cloud_section(json.as_bytes())
            .unwrap_err()
            .field()
            .to_string()
    };
    assert_eq!(field(r#"{"source": {"type": "volcano"}}"#), "cloud");
    assert_eq!(
        field(r#"{"source": {"type": "metaballs", "balls": [], "extra": 1}}"#),
        "cloud"
    );
    assert_eq!(field(r#"{"source": {"type": "metaballs"}}"#), "cloud");
    assert_eq!(
        field(r#"{"voxel": 3, "source": {"type": "metaballs", "balls": []}}"#),
        "cloud"
    );
    assert_eq!(
        field(r#"{"source": {"type": "metaballs", "balls": []}}"#),
        "balls"
    );
    assert_eq!(
        field(
            r#"{"voxel_size_m": 0, "source": {"type": "metaballs", "balls": [{"centre_m": [0,0,0], "radius_m": 1, "density": 1}]}}"#
        ),
        "voxel_size_m"
    );
    assert_eq!(
        field(
            r#"{"source": {"type": "metaballs", "balls": [{"centre_m": [0,0,0], "radius_m": 0, "density": 1}]}}"#
        ),
        "balls[0].radius_m"
    );
    assert_eq!(
        field(
            r#"{"source": {"type": "fractal", "balls": [{"centre_m": [0,0,0], "radius_m": 1, "density": 1}], "levels": 40}}"#
        ),
        "levels"
    );
    assert_eq!(
        field(r#"{"source": {"type": "satellite", "image": "a.png", "error_threshold": 2}}"#),
        "error_threshold"
    );
    assert_eq!(
        field(r#"{"source": {"type": "grid", "path": "a.npy", "density_scale": -1}}"#),
        "density_scale"
    );
}

#[test]
fn grid_sources_load_through_the_loader_and_resample() {
    let fixtures = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");
    let files = |path: &str| -> Result<Vec<u8>> {
        std::fs::read(Path::new(fixtures).join(path)).map_err(|e| Error::invalid("path", e))
    };
    let npy = CloudSource::Grid(GridParams {
        path: "cloud_grid_f4.npy".into(),
        format: None,
        header: None,
        file_voxel_size_m: Some(10.0),
        origin_m: Some([100.0, 200.0, 1000.0]),
        density_scale: 2.0,
    });
    // Same voxel size: the file as is (scaled).
    let g = voxelize(&npy, 10.0, &files).unwrap();
    assert_eq!(g.dims, [5, 4, 3]);
    assert!((g.at(4, 3, 2) as f64 - 2.0 * (0.5 + 0.4 + 0.03 + 0.002)).abs() < 1e-6);
    assert_eq!(g.origin_m, DVec3::new(100.0, 200.0, 1000.0));
    // Half the voxel size: trilinear resampling of the same box; the field is linear in x, y, z
    // so interior samples are exact.
    let fine = voxelize(&npy, 5.0, &files).unwrap();
    assert_eq!(fine.dims, [10, 8, 6]);
    let p = fine.voxel_centre(4, 3, 2);
    let l = (p - g.origin_m) / 10.0 - 0.5;
    let expected = 2.0 * (0.5 + 0.1 * l.x + 0.01 * l.y + 0.001 * l.z);
    assert!((fine.at(4, 3, 2) as f64 - expected).abs() < 1e-6);

    // Raw f32 with the header next to it (default header path: extension replaced by .json).
    let raw_files = |path: &str| -> Result<Vec<u8>> {
        match path {
            "clouds/c.raw" => Ok([0.25f32, 0.5, 0.75, 1.0]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect()),
            "clouds/c.json" => Ok(
                br#"{"dims": [2, 2, 1], "voxel_size_m": 30.0, "origin_m": [0, 0, 900]}"#.to_vec(),
            ),
            other => Err(Error::invalid("path", format!("no file {other}"))),
        }
    };
    let raw = CloudSource::Grid(GridParams {
        path: "clouds/c.raw".into(),
        format: None,
        header: None,
        file_voxel_size_m: None,
        origin_m: None,
        density_scale: 1.0,
    });
    let g = voxelize(&raw, 30.0, &raw_files).unwrap();
    assert_eq!(g.data, vec![0.25, 0.5, 0.75, 1.0]);
    // Loader errors surface unchanged.
    let missing = CloudSource::Grid(GridParams {
        path: "clouds/none.npy".into(),
        format: None,
        header: None,
        file_voxel_size_m: None,
        origin_m: None,
        density_scale: 1.0,
    });
    assert_eq!(
        voxelize(&missing, 30.0, &raw_files).unwrap_err().field(),
        "path"
    );
}
