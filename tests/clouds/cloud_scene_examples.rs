//! The cloud section of the scene JSON: example scenes parse and voxelise, files come through
//! the injected loader, and malformed sections are refused with the offending field named.
//! `cargo test --release --test clouds write_the_satellite_example_png -- --ignored` rewrites the
//! example satellite PNG from its generator.

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
/// (`vdb-cloud.json`, a frame scene, is the `grid` source's, with its OpenVDB file).
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
        [
            "automaton",
            "fractal",
            "grid",
            "metaballs",
            "satellite",
            "spheres"
        ],
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

/// The generator's field quantised to 8 bits as the example PNG stores it: round-to-nearest of
/// `v × 255` (v in [0, 1]).
fn quantised_satellite_field() -> Vec<u8> {
    let field = synthetic_cloud_field(SATELLITE_SIDE, SATELLITE_SEED).unwrap();
    assert_eq!(
        (field.width, field.height),
        (SATELLITE_SIDE, SATELLITE_SIDE)
    );
    field
        .data
        .iter()
        .map(|&v| {
            assert!((0.0..=1.0).contains(&v), "generated value {v}");
            (v * 255.0).round() as u8
        })
        .collect()
}

/// The example satellite PNG in `config/scenes/` is exactly the field the generator produces,
/// `synthetic_cloud_field(128, 2026)`: the PNG, decoded as 8-bit grey, equals the generated
/// field quantised to 8 bits, pixel by pixel.
///
/// Tolerance: none where the quantisation is determined. A pixel may differ by one step only
/// when the generated value lies within 1e-6 of a rounding boundary (a half step, 1/510, from
/// a level), where the last bits of `exp` on another platform's libm (one f32 ulp is 6e-8 at
/// 1) could round it the other way; every other pixel must be equal.
#[test]
fn satellite_example_png_is_the_generated_field() {
    let path = Path::new(SCENES).join("satellite-field.png");
    let bytes = std::fs::read(&path).unwrap();
    let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).unwrap();
    assert_eq!(
        decoded.color(),
        image::ColorType::L8,
        "the example is an 8-bit grey PNG"
    );
    let png = decoded.into_luma8();
    assert_eq!(
        png.dimensions(),
        (SATELLITE_SIDE as u32, SATELLITE_SIDE as u32)
    );
    let png = png.into_raw();
    let field = synthetic_cloud_field(SATELLITE_SIDE, SATELLITE_SEED).unwrap();
    let expected = quantised_satellite_field();
    let mut ambiguous = 0;
    for (i, ((&got, &want), &v)) in png.iter().zip(&expected).zip(&field.data).enumerate() {
        let scaled = v as f64 * 255.0;
        let near_boundary = (scaled - scaled.floor() - 0.5).abs() < 1e-6 * 255.0;
        if near_boundary {
            ambiguous += 1;
            assert!(
                got.abs_diff(want) <= 1,
                "pixel ({}, {}): PNG {got}, generated {want} (value {v})",
                i % SATELLITE_SIDE,
                i / SATELLITE_SIDE
            );
        } else {
            assert_eq!(
                got,
                want,
                "pixel ({}, {}): PNG {got}, generated {want} (value {v})",
                i % SATELLITE_SIDE,
                i / SATELLITE_SIDE
            );
        }
    }
    // The slack is for a few pixels (about 0.05 % of them lie that close to a boundary), not a
    // loophole for the image.
    eprintln!("{ambiguous} pixels within 1e-6 of a rounding boundary");
    assert!(
        ambiguous * 100 <= png.len(),
        "{ambiguous} pixels at a rounding boundary"
    );
    // And through the loader the scene uses: the same field within the quantisation (half a
    // step, 1/510).
    let loaded = GrayImage::from_png_bytes(&bytes).unwrap();
    for (&l, &v) in loaded.data.iter().zip(&field.data) {
        assert!(
            (l - v).abs() <= 0.5 / 255.0 + 1e-6,
            "loaded {l}, generated {v}"
        );
    }
}

/// Rewrites the example satellite PNG from its generator (run it by name with `--ignored` after
/// changing `synthetic_cloud_field`; `satellite_example_png_is_the_generated_field` then checks
/// the committed file).
#[test]
#[ignore = "writes config/scenes/satellite-field.png"]
fn write_the_satellite_example_png() {
    let path = Path::new(SCENES).join("satellite-field.png");
    image::GrayImage::from_raw(
        SATELLITE_SIDE as u32,
        SATELLITE_SIDE as u32,
        quantised_satellite_field(),
    )
    .unwrap()
    .save(&path)
    .unwrap();
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
        grid_name: None,
        file_unit_m: None,
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
        grid_name: None,
        file_unit_m: None,
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
        grid_name: None,
        file_unit_m: None,
        density_scale: 1.0,
    });
    assert_eq!(
        voxelize(&missing, 30.0, &raw_files).unwrap_err().field(),
        "path"
    );
}
