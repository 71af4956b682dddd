//! Imported grids: `.npy` files written by NumPy parse to the right values and our writer emits
//! the same bytes; raw f32 + JSON grids round-trip; malformed headers are refused, naming the
//! offending part, before any grid memory is allocated.

use glam::DVec3;
use proptest::prelude::*;
use skybake_physics::cloud::import::{
    from_npy_bytes, from_raw_f32, parse_raw_header, to_npy_bytes, to_raw_f32,
};
use skybake_physics::cloud::DensityGrid;

const F4: &[u8] = include_bytes!("../data/cloud_grid_f4.npy");
const F8: &[u8] = include_bytes!("../data/cloud_grid_f8.npy");
const FORTRAN: &[u8] = include_bytes!("../data/cloud_grid_fortran.npy");
const BIG_ENDIAN: &[u8] = include_bytes!("../data/cloud_grid_big_endian.npy");
const INT32: &[u8] = include_bytes!("../data/cloud_grid_int32.npy");
const TWO_D: &[u8] = include_bytes!("../data/cloud_grid_2d.npy");

/// The fixture formula (tools/make_cloud_npy_fixtures.py).
fn fixture_value(x: usize, y: usize, z: usize) -> f64 {
    0.5 + 0.1 * x as f64 + 0.01 * y as f64 + 0.001 * z as f64
}

/// A version-1.0 .npy file with the given header dictionary and data.
fn npy(dict: &str, data: &[u8]) -> Vec<u8> {
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&((dict.len() + 1) as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.push(b'\n');
    out.extend_from_slice(data);
    out
}

#[test]
fn numpy_written_float32_and_float64_files_parse_to_the_formula() {
    for bytes in [F4, F8] {
        let g = from_npy_bytes(bytes, 10.0, DVec3::new(1.0, 2.0, 3.0)).unwrap();
        assert_eq!(g.dims, [5, 4, 3]);
        assert_eq!(g.voxel_size_m, 10.0);
        for z in 0..3 {
            for y in 0..4 {
                for x in 0..5 {
                    assert!((g.at(x, y, z) as f64 - fixture_value(x, y, z)).abs() < 1e-7);
                }
            }
        }
    }
}

#[test]
fn npy_writer_matches_numpy_byte_for_byte() {
    let g = from_npy_bytes(F4, 1.0, DVec3::ZERO).unwrap();
    assert_eq!(to_npy_bytes(&g), F4);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn npy_round_trip_is_bit_exact_and_raw_keeps_data_exactly(
        nx in 1usize..9, ny in 1usize..9, nz in 1usize..9,
        seed in any::<u64>(), voxel in 0.1f64..500.0,
        ox in -1e4f64..1e4, oy in -1e4f64..1e4, oz in 0f64..1e4,
    ) {
        let n = nx * ny * nz;
        let data: Vec<f32> = (0..n).map(|i| ((seed.wrapping_mul(i as u64 + 1) >> 40) as f32) * 1e-6).collect();
        let g = DensityGrid::from_data([nx, ny, nz], voxel, DVec3::new(ox, oy, oz), data).unwrap();
        let back = from_npy_bytes(&to_npy_bytes(&g), voxel, g.origin_m).unwrap();
        prop_assert_eq!(&back, &g);
        let (header, raw) = to_raw_f32(&g).unwrap();
        let back = from_raw_f32(&parse_raw_header(&header).unwrap(), &raw).unwrap();
        prop_assert_eq!(&back.data, &g.data);
        prop_assert_eq!(back.dims, g.dims);
        // serde_json parses decimals to within 1 ulp (its float_roundtrip feature is off).
        prop_assert!((back.voxel_size_m - voxel).abs() <= 2.0 * f64::EPSILON * voxel);
        prop_assert!((back.origin_m - g.origin_m).abs().max_element() <= 2.0 * f64::EPSILON * 1e4);
    }
}

#[test]
fn bad_npy_files_are_refused_with_the_reason() {
    let o = DVec3::ZERO;
    let field = |bytes: &[u8]| {
        from_npy_bytes(bytes, 1.0, o)
            .unwrap_err()
            .field()
            .to_string()
    };
    // Wrong magic.
    let mut wrong = F4.to_vec();
    wrong[1] = b'X';
    assert_eq!(field(&wrong), "npy");
    assert_eq!(field(b"short"), "npy");
    // Unsupported version.
    let mut v9 = F4.to_vec();
    v9[6] = 9;
    assert_eq!(field(&v9), "npy.version");
    // Fortran order, big-endian, integer dtype, 2-D.
    assert_eq!(field(FORTRAN), "npy.fortran_order");
    assert_eq!(field(BIG_ENDIAN), "npy.descr");
    assert_eq!(field(INT32), "npy.descr");
    assert_eq!(field(TWO_D), "npy.shape");
    // Size mismatch: truncated and padded data.
    assert_eq!(field(&F4[..F4.len() - 4]), "npy.data");
    let mut long = F4.to_vec();
    long.extend_from_slice(&[0; 4]);
    assert_eq!(field(&long), "npy.data");
    // Header length pointing past the end of the file.
    let mut cut = F4.to_vec();
    cut[8] = 0xff;
    cut[9] = 0x7f;
    assert_eq!(field(&cut), "npy.header");
    // Huge dimensions: refused from the header alone (the file has no data at all).
    let huge = npy(
        "{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000, 100000), }",
        &[],
    );
    assert_eq!(field(&huge), "dims");
    let overflow = npy(
        "{'descr': '<f4', 'fortran_order': False, 'shape': (18446744073709551615, 2, 2), }",
        &[],
    );
    assert_eq!(field(&overflow), "dims");
    // Malformed dictionaries.
    for dict in [
        "{'descr': '<f4', 'fortran_order': False}",
        "{'descr': '<f4', 'fortran_order': Maybe, 'shape': (1, 1, 1), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 1), 'extra': 1}",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1, -1, 1), }",
        "['descr']",
    ] {
        assert_eq!(field(&npy(dict, &[0; 4])), "npy.header", "{dict}");
    }
    // Values the grid cannot hold.
    let neg = npy(
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 2), }",
        &[0, 0, 0, 0, 0, 0, 128, 191],
    );
    assert_eq!(field(&neg), "data");
    let nan = npy(
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 1), }",
        &f32::NAN.to_le_bytes(),
    );
    assert_eq!(field(&nan), "data");
    // Bad geometry from the caller.
    assert_eq!(
        from_npy_bytes(F4, -1.0, o).unwrap_err().field(),
        "voxel_size_m"
    );
}

#[test]
fn bad_raw_headers_and_data_are_refused() {
    let good = br#"{"dims": [2, 2, 1], "voxel_size_m": 5.0, "origin_m": [0, 0, 1000]}"#;
    let h = parse_raw_header(good).unwrap();
    assert_eq!(h.dims, [2, 2, 1]);
    assert_eq!(from_raw_f32(&h, &[0; 12]).unwrap_err().field(), "data");
    assert_eq!(from_raw_f32(&h, &[0; 16]).unwrap().dims, [2, 2, 1]);
    for bad in [
        &br#"{"dims": [2, 2], "voxel_size_m": 5.0, "origin_m": [0, 0, 0]}"#[..],
        br#"{"dims": [2, 2, 1], "voxel_size_m": 5.0}"#,
        br#"{"dims": [2, 2, 1], "voxel_size_m": 5.0, "origin_m": [0, 0, 0], "scale": 2}"#,
        br#"{"dims": [2, -2, 1], "voxel_size_m": 5.0, "origin_m": [0, 0, 0]}"#,
        b"not json",
    ] {
        assert_eq!(parse_raw_header(bad).unwrap_err().field(), "header");
    }
    let huge = br#"{"dims": [100000, 100000, 100000], "voxel_size_m": 5.0, "origin_m": [0, 0, 0]}"#;
    assert_eq!(parse_raw_header(huge).unwrap_err().field(), "dims");
    let zero = br#"{"dims": [0, 4, 4], "voxel_size_m": 5.0, "origin_m": [0, 0, 0]}"#;
    assert_eq!(parse_raw_header(zero).unwrap_err().field(), "dims");
    let h = parse_raw_header(br#"{"dims": [1, 1, 1], "voxel_size_m": 0.0, "origin_m": [0, 0, 0]}"#)
        .unwrap();
    assert_eq!(
        from_raw_f32(&h, &[0; 4]).unwrap_err().field(),
        "voxel_size_m"
    );
}
