//! Colour conversion against colour-science (tests/data/colour_reference.json, made by
//! tools/colour_reference.py with colour-science 0.4.7).

use serde_json::Value;
use skybake_physics::spectrum::colour::{spectrum_to_xyz, xyz_to_linear_srgb};
use skybake_physics::spectrum::data::cie1931_cmfs;

fn load() -> Value {
    let path = format!(
        "{}/tests/data/colour_reference.json",
        env!("CARGO_MANIFEST_DIR")
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[test]
fn embedded_cmfs_equal_colour_science_tables() {
    let data = load();
    let nm = floats(&data["cmf_wavelengths_nm"]);
    let cmfs = cie1931_cmfs();
    for (c, key) in ["cmf_x_bar", "cmf_y_bar", "cmf_z_bar"].iter().enumerate() {
        for (l, v) in nm.iter().zip(floats(&data[*key])) {
            assert!(
                (cmfs[c].eval(*l) - v).abs() <= 1e-9 + 1e-6 * v.abs(),
                "{key} at {l}"
            );
        }
    }
}

#[test]
fn xyz_and_linear_srgb_match_colour_science() {
    let data = load();
    for case in data["cases"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let nm = floats(&case["wavelengths_nm"]);
        let values = floats(&case["values"]);
        let xyz = spectrum_to_xyz(&nm, &values);
        let reference = floats(&case["XYZ"]);
        let scale = reference.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for c in 0..3 {
            // Same integration rule; 1e-6 of the largest component covers float summation order.
            assert!(
                (xyz[c] - reference[c]).abs() <= 1e-6 * scale,
                "{name} XYZ[{c}]: {} vs {}",
                xyz[c],
                reference[c]
            );
        }
        let rgb = xyz_to_linear_srgb(xyz);
        let reference = floats(&case["linear_srgb"]);
        for c in 0..3 {
            // colour-science derives the sRGB matrix from the primaries (more digits than the
            // 4-decimal IEC matrix): agreement to 2e-4 of the largest component.
            assert!(
                (rgb[c] - reference[c]).abs() <= 2e-4 * scale,
                "{name} RGB[{c}]: {} vs {}",
                rgb[c],
                reference[c]
            );
        }
    }
}
