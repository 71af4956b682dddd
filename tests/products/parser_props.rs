//! Property tests of the parsers a request reaches: frame scenes, atmospheres, jobs and grid files
//! (.npy, raw f32 with its JSON header), on random bytes and on the examples with members
//! replaced, removed or emptied. None may panic, and every refusal is an input error naming a
//! field (a 4xx in the service, exit 2 in the CLI), never an internal one.

use proptest::prelude::*;
use rand::seq::IndexedRandom;
use rand::{Rng, SeedableRng};
use serde_json::{json, Value};
use skybake_physics::cloud::import;
use skybake_physics::Error;

/// A refusal must be bad input naming something, never a server fault or a cancellation.
fn input_error(e: &Error, what: &str) {
    assert!(e.is_input(), "{what}: not an input error: {e:?}");
    assert!(!e.field().is_empty(), "{what}: names no field: {e}");
}

fn random_json(rng: &mut impl Rng, depth: u32) -> Value {
    match rng.random_range(0..if depth == 0 { 6 } else { 8 }) {
        0 => Value::Null,
        1 => json!(rng.random_bool(0.5)),
        2 => json!([0.0, -1.0, 1e308, -1e-300, 0.5, 1e6, 12345.678]
            .choose(rng)
            .unwrap()),
        3 => json!(
            ["", "x", "earth", "fast", "metaballs", "automaton", "\u{0}"]
                .choose(rng)
                .unwrap()
        ),
        4 => json!(rng.random_range(-5i64..1 << 40)),
        5 => json!(u64::MAX),
        6 => Value::Object(
            (0..rng.random_range(0..3))
                .map(|i| (format!("k{i}"), random_json(rng, depth - 1)))
                .collect(),
        ),
        _ => Value::Array(
            (0..rng.random_range(0..4))
                .map(|_| random_json(rng, depth - 1))
                .collect(),
        ),
    }
}

/// `v` with one to four members (at any depth) replaced, removed or emptied, driven by `seed`.
fn mutated(v: &Value, seed: u64) -> Value {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut v = v.clone();
    crate::service_support::json_mutation::mutate(&mut rng, &mut v, 1..=4, 0.75, |rng| {
        random_json(rng, 2)
    });
    v
}

fn example_scenes() -> Vec<Value> {
    skybake_product::frame::EXAMPLE_SCENES
        .iter()
        .map(|(_, t)| serde_json::from_str(t).unwrap())
        .collect()
}

fn atmospheres() -> Vec<Value> {
    [
        include_str!("../../config/atmospheres/earth.json"),
        include_str!("../../config/atmospheres/earth-hazy.json"),
        include_str!("../../config/atmospheres/mars.json"),
        include_str!("../../config/atmospheres/rayleigh-only.json"),
    ]
    .iter()
    .map(|t| serde_json::from_str(t).unwrap())
    .collect()
}

fn example_jobs() -> Vec<Value> {
    let scene = serde_json::from_str::<Value>(
        skybake_product::frame::EXAMPLE_SCENES
            .iter()
            .find(|(n, _)| *n == "validation-frame")
            .unwrap()
            .1,
    )
    .unwrap();
    vec![
        json!({"products": [{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "550", "sun_elevation_deg": 30}]}),
        json!({"grids": [{"product": "sun", "wavelengths": "440,550", "sweep": {"sun_elevation_deg": {"from": 0, "to": 90, "step": 30}}}]}),
        json!({"products": [{"product": "frame", "method": "fast", "scene": scene}]}),
        json!({"frames": [[{"scene": scene}]], "products": [{"product": "aerial", "max_distance_m": 1000}]}),
    ]
}

/// A small valid grid as .npy bytes.
fn npy_example() -> Vec<u8> {
    let grid = skybake_physics::cloud::DensityGrid::from_data(
        [3, 2, 2],
        10.0,
        glam::DVec3::ZERO,
        (0..12).map(|i| i as f32 * 0.1).collect(),
    )
    .unwrap();
    import::to_npy_bytes(&grid)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn scenes_parse_or_name_a_field(which in 0usize..8, seed in any::<u64>(), raw in proptest::collection::vec(any::<u8>(), 0..80)) {
        let scenes = example_scenes();
        let bytes = if which == 7 {
            raw
        } else {
            mutated(&scenes[which % scenes.len()], seed).to_string().into_bytes()
        };
        for method in [skybake_render::Method::Fast, skybake_render::Method::Reference] {
            if let Err(e) = skybake_product::frame::FrameRequest::parse(&bytes, method) {
                input_error(&e, &String::from_utf8_lossy(&bytes));
            }
        }
    }

    #[test]
    fn atmospheres_parse_or_name_a_field(which in 0usize..5, seed in any::<u64>(), raw in "\\PC{0,60}") {
        let presets = atmospheres();
        let text = if which == 4 { raw } else { mutated(&presets[which], seed).to_string() };
        match skybake_physics::atmosphere::presets::parse_json("atmosphere", &text) {
            Ok(params) => {
                // What parses resolves into a medium or is refused as input.
                let wl = skybake_physics::spectrum::Wavelengths::new(vec![440.0, 550.0]).unwrap();
                if let Err(e) = skybake_physics::atmosphere::Medium::new(&params, &wl, Some(0.3)) {
                    input_error(&e, &text);
                }
            }
            Err(e) => input_error(&e, &text),
        }
    }

    #[test]
    fn jobs_parse_or_name_what_is_wrong(which in 0usize..5, seed in any::<u64>(), raw in proptest::collection::vec(any::<u8>(), 0..80)) {
        let jobs = example_jobs();
        let bytes = if which == 4 { raw } else { mutated(&jobs[which], seed).to_string().into_bytes() };
        match skybake_job::spec::JobSpec::parse_body(&bytes, 10_000) {
            Ok(_) => {}
            Err(skybake_job::JobError::Param(e)) => input_error(&e, &String::from_utf8_lossy(&bytes)),
            Err(skybake_job::JobError::Body(d)) if !d.is_empty() => {}
            Err(skybake_job::JobError::Unknown(names)) if !names.is_empty() => {}
            Err(e) => panic!("{}: {e:?}", String::from_utf8_lossy(&bytes)),
        }
    }

    #[test]
    fn grid_files_parse_or_name_a_field(flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6), cut in any::<usize>(), raw in proptest::collection::vec(any::<u8>(), 0..200), header in "\\PC{0,80}") {
        // .npy: a valid file with bytes changed and possibly cut short, and random bytes.
        let mut npy = npy_example();
        for (at, b) in &flips {
            let i = at % npy.len();
            npy[i] = *b;
        }
        if cut % 3 == 0 {
            npy.truncate(cut % (npy.len() + 1));
        }
        for bytes in [&npy, &raw] {
            if let Err(e) = import::npy_dims(bytes) {
                input_error(&e, "npy dims");
            }
            if let Err(e) = import::from_npy_bytes(bytes, 10.0, glam::DVec3::ZERO) {
                input_error(&e, "npy");
            }
        }
        // Raw f32: a random header, and a valid one with random data.
        for text in [header.clone(), r#"{"dims": [2, 2, 1], "voxel_size_m": 5.0, "origin_m": [0, 0, 0]}"#.to_string()] {
            match import::parse_raw_header(text.as_bytes()) {
                Ok(h) => {
                    if let Err(e) = import::from_raw_f32(&h, &raw) {
                        input_error(&e, "raw data");
                    }
                }
                Err(e) => input_error(&e, &text),
            }
        }
    }
}
