//! `skybake cloud-light`: the built binary writes the pre-lit cloud volume of a scene file, the
//! same files byte for byte as the library computes for the scene, decodable by the reference
//! reader; bad input is refused with exit code 2 naming the field.

use crate::cli_clouds::{scratch, skybake};
use serde_json::{json, Value};
use skybake_engine::engine::Engine;
use skybake_product::cloud_light::{CloudLight, CloudLightRequest};

/// A small vacuum scene: one metaball, sun and a constant sky, two wavelengths, draft.
fn scene() -> Value {
    json!({
        "name": "ball",
        "cloud": {"voxel_size_m": 100.0, "source": {"type": "metaballs",
            "balls": [{"centre_m": [0, 0, 1500], "radius_m": 500, "density": 1.0}]}},
        "optics": {"extinction_per_density_m": 0.02, "single_scattering_albedo": 0.99,
                   "phase": {"henyey_greenstein": {"g": 0.85}}},
        "camera": {"type": "pinhole", "position_m": [0, -4000, 1500], "look_at_m": [0, 0, 1500],
                   "up": [0, 0, 1], "fov_deg": 30, "width": 16, "height": 16},
        "sun": {"collimated": {"elevation_deg": 30, "azimuth_deg": 200, "normal_irradiance_w_m2_nm": 1.0}},
        "atmosphere": null, "sky": {"constant_radiance_w_m2_sr_nm": 0.05}, "ground": null,
        "wavelengths_nm": [450, 650], "quality": "draft"
    })
}

#[test]
fn cloud_light_writes_the_library_s_files_and_refuses_bad_scenes() {
    let dir = scratch("cloud-light-ok");
    let path = dir.join("scene.json");
    std::fs::write(&path, scene().to_string()).unwrap();
    let out = skybake(
        &[
            "cloud-light",
            "scene.json",
            "-o",
            "light",
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
    let summary: Value = serde_json::from_slice(&out.stdout).unwrap();
    let listed = summary["files"].as_array().unwrap();
    assert!(listed.len() >= 7, "{summary}");
    let req = CloudLightRequest::parse(scene().to_string().as_bytes()).unwrap();
    let lib = req
        .compute(&Engine::new(), &|_| unreachable!("no files"), &|| false)
        .unwrap();
    let files = lib.light.files().unwrap();
    assert_eq!(listed.len(), files.len());
    let mut total = 0;
    for (name, bytes) in &files {
        let written = std::fs::read(dir.join("light").join(name)).unwrap();
        assert!(written == *bytes, "{name} differs from the library's");
        total += bytes.len();
    }
    assert_eq!(summary["total_bytes"].as_u64(), Some(total as u64));
    let decoded = CloudLight::from_files(&|name: &str| {
        std::fs::read(dir.join("light").join(name))
            .map_err(|e| skybake_physics::Error::invalid(name, e.to_string()))
    })
    .unwrap();
    assert_eq!(decoded, lib.light);
    assert_eq!(decoded.wavelengths_nm, vec![450.0, 650.0]);

    // Refused, exit 2, naming the field.
    let mut bad = scene();
    bad["multiple_scattering_method"] = json!("reference_pattern");
    std::fs::write(dir.join("pattern.json"), bad.to_string()).unwrap();
    let out = skybake(&["cloud-light", "pattern.json", "-o", "x"], &dir);
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("multiple_scattering_method"), "{stderr}");
    let mut bad = scene();
    bad["optics"]["phase"] = json!({"henyey_greenstein": {"g": 1.5}});
    std::fs::write(dir.join("g.json"), bad.to_string()).unwrap();
    let out = skybake(&["cloud-light", "g.json", "-o", "x"], &dir);
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("optics.phase.g"), "{stderr}");
    assert!(
        !dir.join("x").exists(),
        "nothing written for a refused scene"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
