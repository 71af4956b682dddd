//! OpenVDB grids written by the reference OpenVDB library (`tools/vdb_fixtures.py`, OpenVDB
//! 10.0.1): the `vdb` grid source reads the same voxels, voxel size and position as the `.npy`
//! import of the same grid (NumPy's file of the dense box), alone and selected from several grids;
//! what is not a density grid, what the decoder cannot read (half floats), too large or corrupt is
//! refused, naming the parameter, without a panic.

use serde_json::{json, Value};
use skybake_physics::cloud::scene::{parse_cloud_section, CloudSection};
use skybake_physics::cloud::vdb::{grid_names, inspect};
use skybake_physics::cloud::DensityGrid;
use skybake_physics::{Error, Result};
use std::path::Path;

const DENSITY: &[u8] = include_bytes!("../data/cloud_vdb_density.vdb");
const HALF: &[u8] = include_bytes!("../data/cloud_vdb_half.vdb");
const MULTI: &[u8] = include_bytes!("../data/cloud_vdb_multi.vdb");

fn fixtures() -> Value {
    serde_json::from_str(include_str!("../data/cloud_vdb_fixtures.json")).unwrap()
}

fn files(path: &str) -> Result<Vec<u8>> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");
    std::fs::read(Path::new(dir).join(path)).map_err(|e| Error::invalid("path", e))
}

fn section(voxel_size_m: f64, source: Value) -> Result<CloudSection> {
    parse_cloud_section(
        json!({"voxel_size_m": voxel_size_m, "source": source})
            .to_string()
            .as_bytes(),
    )
}

fn vdb_grid(voxel_size_m: f64, source: Value) -> Result<DensityGrid> {
    section(voxel_size_m, source)?.voxelize(&files)
}

/// The `.npy` import of the same voxels, placed where the fixture's metadata says.
fn npy_grid() -> DensityGrid {
    let meta = &fixtures()["density_npy"];
    vdb_grid(
        25.0,
        json!({"type": "grid", "path": "cloud_vdb_density.npy",
               "file_voxel_size_m": meta["voxel_size_m"], "origin_m": meta["origin_m"]}),
    )
    .unwrap()
}

#[test]
fn openvdb_grids_read_as_the_npy_of_the_same_voxels() {
    let expected = npy_grid();
    let meta = fixtures();
    assert_eq!(
        expected.dims.to_vec(),
        serde_json::from_value::<Vec<usize>>(meta["density_npy"]["dims_xyz"].clone()).unwrap()
    );
    let sources = [
        json!({"type": "grid", "path": "cloud_vdb_density.vdb"}),
        json!({"type": "grid", "path": "cloud_vdb_multi.vdb"}),
        json!({"type": "grid", "path": "cloud_vdb_multi.vdb", "grid_name": "density"}),
        json!({"type": "grid", "path": "cloud_vdb_density.vdb", "format": "vdb",
               "grid_name": "density", "file_unit_m": 1.0}),
    ];
    for source in sources {
        let g = vdb_grid(25.0, source.clone()).unwrap();
        assert_eq!(g.dims, expected.dims, "{source}");
        assert_eq!(g.voxel_size_m, 25.0, "{source}");
        assert_eq!(g.origin_m, expected.origin_m, "{source}");
        assert!(g.data == expected.data, "{source}: voxels differ");
    }
    // The walk's measurements against OpenVDB's own (leafCount, evalActiveVoxelBoundingBox).
    let bbox: Vec<Vec<i32>> =
        serde_json::from_value(meta["density_vdb"]["active_bbox"].clone()).unwrap();
    for bytes in [DENSITY, MULTI] {
        let layout = inspect(bytes, None).unwrap();
        assert_eq!(layout.nodes[0], meta["density_vdb"]["leaf_count"], "leaves");
        assert_eq!(layout.bbox.0.to_vec(), bbox[0]);
        assert_eq!(layout.bbox.1.to_vec(), bbox[1]);
        assert!(!layout.half);
    }
    // Active voxels and their sum, as NumPy counted them.
    let g = vdb_grid(
        25.0,
        json!({"type": "grid", "path": "cloud_vdb_density.vdb"}),
    )
    .unwrap();
    let active = g.data.iter().filter(|&&v| v > 0.0).count();
    assert_eq!(active as u64, meta["density_npy"]["active_voxels"]);
    let sum: f64 = g.data.iter().map(|&v| v as f64).sum();
    assert_eq!(sum, meta["density_npy"]["sum"].as_f64().unwrap());
}

#[test]
fn file_units_and_the_section_voxel_size_apply_as_for_other_grids() {
    let base = npy_grid();
    // Metres per file unit scale the voxel and the position; the voxels stay.
    let g = vdb_grid(
        50.0,
        json!({"type": "grid", "path": "cloud_vdb_density.vdb", "file_unit_m": 2.0}),
    )
    .unwrap();
    assert_eq!((g.dims, g.voxel_size_m), (base.dims, 50.0));
    assert_eq!(g.origin_m, base.origin_m * 2.0);
    assert!(g.data == base.data);
    // Another section voxel size resamples over the same box, as `.npy` grids are.
    let fine = vdb_grid(
        12.5,
        json!({"type": "grid", "path": "cloud_vdb_density.vdb"}),
    )
    .unwrap();
    let npy_fine = section(
        12.5,
        json!({"type": "grid", "path": "cloud_vdb_density.npy", "file_voxel_size_m": 25.0,
               "origin_m": base.origin_m.to_array()}),
    )
    .unwrap()
    .voxelize(&files)
    .unwrap();
    assert_eq!(fine.dims, npy_fine.dims);
    assert!(fine.data == npy_fine.data);
}

fn refusal(source: Value) -> Error {
    match vdb_grid(25.0, source.clone()) {
        Ok(_) => panic!("{source}: read"),
        Err(e) => e,
    }
}

fn expect(e: Error, field: &str, words: &[&str]) {
    assert_eq!(e.field(), field, "{e}");
    for w in words {
        assert!(e.to_string().contains(w), "'{w}' not in: {e}");
    }
}

#[test]
fn what_is_not_a_density_grid_is_refused_naming_the_parameter() {
    let multi =
        |name: &str| json!({"type": "grid", "path": "cloud_vdb_multi.vdb", "grid_name": name});
    assert_eq!(
        grid_names(&files("cloud_vdb_multi.vdb").unwrap()).unwrap(),
        ["temperature", "vel", "density"]
    );
    expect(
        refusal(multi("vel")),
        "grid_name",
        &["'vel'", "Tree_vec3s", "float"],
    );
    expect(
        refusal(multi("fog")),
        "grid_name",
        &["no grid 'fog'", "'temperature', 'vel', 'density'"],
    );
    expect(
        refusal(json!({"type": "grid", "path": "cloud_vdb_levelset.vdb"})),
        "grid_name",
        &["level set", "fog volume"],
    );
    expect(
        refusal(json!({"type": "grid", "path": "cloud_vdb_rotated.vdb"})),
        "vdb.transform",
        &["AffineMap", "axis-aligned"],
    );
    // Two voxels 4000 apart: a 4001³ box, refused from the walk before any value is decoded.
    match refusal(json!({"type": "grid", "path": "cloud_vdb_oversize.vdb"})) {
        Error::TooLarge { field, reason, .. } => {
            assert_eq!(field, "dims");
            assert!(reason.contains("[4001, 4001, 4001]"), "{reason}");
        }
        other => panic!("not too large: {other}"),
    }
    // Fields of other formats, and the vdb-only fields elsewhere, are refused by name.
    for (field, value) in [
        ("origin_m", json!([0, 0, 0])),
        ("file_voxel_size_m", json!(25.0)),
        ("header", json!("x.json")),
    ] {
        let mut s = json!({"type": "grid", "path": "cloud_vdb_density.vdb"});
        s[field] = value;
        assert_eq!(section(25.0, s).unwrap_err().field(), field);
    }
    for (field, value) in [("grid_name", json!("density")), ("file_unit_m", json!(1.0))] {
        let mut s = json!({"type": "grid", "path": "cloud_vdb_density.npy"});
        s[field] = value;
        assert_eq!(section(25.0, s).unwrap_err().field(), field);
    }
    let e = section(
        25.0,
        json!({"type": "grid", "path": "c.vdb", "file_unit_m": 0.0}),
    )
    .unwrap_err();
    expect(e, "file_unit_m", &["[1e-6, 1e6]"]);
    // Half floats: the decoder misreads them, so they are refused by name.
    expect(
        inspect(HALF, None).unwrap_err(),
        "vdb.precision",
        &["half floats", "32-bit float"],
    );
    // A newer file layout is named, not misread.
    let mut newer = DENSITY.to_vec();
    newer[8] = 230;
    expect(inspect(&newer, None).unwrap_err(), "vdb.version", &["230"]);
}

/// A loader serving `bytes` for every path.
fn read_bytes(bytes: &[u8]) -> Result<DensityGrid> {
    section(25.0, json!({"type": "grid", "path": "x.vdb"}))?.voxelize(&|_| Ok(bytes.to_vec()))
}

#[test]
fn truncated_or_damaged_files_are_refused_without_a_panic() {
    for original in [DENSITY, MULTI] {
        // Every truncation is refused (the walk needs every byte up to the grid's end).
        for cut in (0..original.len()).step_by(97) {
            let e = read_bytes(&original[..cut]).unwrap_err();
            assert_eq!(e.field(), "vdb", "cut at {cut}: {e}");
        }
        // Damaged bytes: refused or read, never a panic, and what is read is a valid grid.
        let mut refused = 0;
        for at in (0..original.len()).step_by(151) {
            for flip in [0x01u8, 0x80, 0xff] {
                let mut bytes = original.to_vec();
                bytes[at] ^= flip;
                match read_bytes(&bytes) {
                    Ok(g) => assert!(g.data.iter().all(|v| v.is_finite() && *v >= 0.0)),
                    Err(_) => refused += 1,
                }
            }
        }
        assert!(refused > 0);
    }
}
