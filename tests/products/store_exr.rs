//! Tiled spectral OpenEXR: bit-exact round trips, the Fichet et al. (JCGT 2021) channel layout, and
//! detection of damaged files.

use std::path::PathBuf;

use exr::prelude::{Compression, MetaData};
use proptest::prelude::*;
use skybake_physics::image::layout::{
    ATTR_COMPUTE_TIME_MS, ATTR_ENGINE_VERSION, ATTR_ERROR_ESTIMATE_JSON, ATTR_SPEC_JSON,
    EMISSIVE_LAYER, TRANSMITTANCE_LAYER,
};
use skybake_store::{
    decode_exr, encode_exr, encode_exr_with, read_exr_file, write_atomic, write_exr_file,
    ExrCompression, SpectralImage, StoreError,
};

/// A scratch directory removed on drop.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("skybake-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Scratch(dir)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Deterministic awkward values: signed zeros, subnormals, huge and tiny magnitudes.
fn plane(width: usize, height: usize, seed: u32) -> Vec<f32> {
    let specials = [0.0, -0.0, f32::MIN_POSITIVE / 4.0, f32::MAX, -1.0e-30, 1.0];
    (0..width * height)
        .map(|i| {
            let i = i as u32;
            if i % 7 == 0 {
                specials[(i as usize / 7 + seed as usize) % specials.len()]
            } else {
                let h = i
                    .wrapping_mul(2_654_435_761)
                    .wrapping_add(seed.wrapping_mul(40_503));
                f32::from_bits(h % 0x7f00_0000) * if h & 1 == 0 { 1.0 } else { -1.0 }
            }
        })
        .collect()
}

/// An aerial-perspective-like image: `S0` radiance and `T` transmittance, RGB and attributes.
fn sample_image(width: usize, height: usize) -> SpectralImage {
    let wavelengths_nm = [440.0, 550.5, 680.25];
    let mut image = SpectralImage::new(width, height, &wavelengths_nm).unwrap();
    let planes = |seed: u32| (0..3u32).map(|k| plane(width, height, seed + k)).collect();
    image.add_layer(EMISSIVE_LAYER, planes(1)).unwrap();
    image.add_layer(TRANSMITTANCE_LAYER, planes(10)).unwrap();
    image
        .set_rgb([
            plane(width, height, 20),
            plane(width, height, 21),
            plane(width, height, 22),
        ])
        .unwrap();
    image
        .set_attribute(ATTR_SPEC_JSON, r#"{"product":"aerial","name":"Zürich ☀"}"#)
        .unwrap();
    image.set_attribute(ATTR_ENGINE_VERSION, "0.1.0").unwrap();
    image
        .set_attribute(ATTR_ERROR_ESTIMATE_JSON, r#"{"max_rel_error":0.01}"#)
        .unwrap();
    image.set_attribute(ATTR_COMPUTE_TIME_MS, "12.5").unwrap();
    image
}

/// Equality of every stored bit (f32 `==` would equate 0.0 and -0.0).
fn assert_bit_identical(a: &SpectralImage, b: &SpectralImage) {
    let bits = |p: &[f32]| p.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!((a.width(), a.height()), (b.width(), b.height()));
    let wl_bits = |i: &SpectralImage| {
        i.wavelengths_nm()
            .iter()
            .map(|w| w.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(wl_bits(a), wl_bits(b));
    assert_eq!(a.layers().len(), b.layers().len());
    for (la, lb) in a.layers().iter().zip(b.layers()) {
        assert_eq!(la.name(), lb.name());
        for (pa, pb) in la.planes().iter().zip(lb.planes()) {
            assert_eq!(bits(pa), bits(pb), "layer {}", la.name());
        }
    }
    match (a.rgb(), b.rgb()) {
        (Some(ra), Some(rb)) => {
            for (pa, pb) in ra.iter().zip(rb) {
                assert_eq!(bits(pa), bits(pb), "rgb");
            }
        }
        (None, None) => {}
        _ => panic!("rgb presence differs"),
    }
    assert_eq!(a.attributes(), b.attributes());
}

#[test]
fn round_trip_in_memory_is_bit_exact_across_partial_tiles() {
    // 130 x 70 spans 3 x 2 tiles of 64, the last ones partial.
    let image = sample_image(130, 70);
    let bytes = encode_exr(&image).unwrap();
    let back = decode_exr(&bytes).unwrap();
    assert_bit_identical(&image, &back);
    assert_eq!(image, back);
}

#[test]
fn round_trip_through_a_file_is_bit_exact() {
    let scratch = Scratch::new("exr-file");
    let path = scratch.0.join("nested").join("sky.exr");
    let image = sample_image(65, 3);
    write_exr_file(&path, &image).unwrap();
    assert_bit_identical(&image, &read_exr_file(&path).unwrap());
    // The file holds a complete, verifiable encoding (decode checks the embedded checksum).
    assert_bit_identical(&image, &decode_exr(&std::fs::read(&path).unwrap()).unwrap());
}

#[test]
fn header_follows_the_spectral_layout_and_is_tiled() {
    let mut image = SpectralImage::new(3, 2, &[550.0, 550.5]).unwrap();
    image
        .add_layer(EMISSIVE_LAYER, vec![vec![1.0; 6], vec![2.0; 6]])
        .unwrap();
    image
        .add_layer(TRANSMITTANCE_LAYER, vec![vec![0.5; 6], vec![0.25; 6]])
        .unwrap();
    image
        .set_rgb([vec![0.1; 6], vec![0.2; 6], vec![0.3; 6]])
        .unwrap();
    let bytes = encode_exr(&image).unwrap();

    let meta = MetaData::read_from_buffered(std::io::Cursor::new(&bytes), true).unwrap();
    let header = &meta.headers[0];
    let names: Vec<String> = header
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    assert_eq!(
        names,
        [
            "B",
            "G",
            "R",
            "S0.550,000000nm",
            "S0.550,500000nm",
            "T.550,000000nm",
            "T.550,500000nm"
        ]
    );
    assert!(header
        .channels
        .list
        .iter()
        .all(|c| c.sample_type == exr::prelude::SampleType::F32));
    match header.blocks {
        exr::meta::BlockDescription::Tiles(tiles) => {
            assert_eq!(tiles.tile_size, exr::prelude::Vec2(64, 64));
            assert_eq!(tiles.level_mode, exr::meta::attribute::LevelMode::Singular);
        }
        other => panic!("not tiled: {other:?}"),
    }
    assert_eq!(header.compression, Compression::ZIP16);
    let text = |name: &str| match header
        .own_attributes
        .other
        .get(&exr::prelude::Text::from(name))
    {
        Some(exr::prelude::AttributeValue::Text(t)) => t.to_string(),
        other => panic!("{name}: {other:?}"),
    };
    assert_eq!(text("spectralLayoutVersion"), "1.0");
    assert_eq!(text("emissiveUnits"), "W.m^-2.sr^-1");
    assert_eq!(text("skybakeFileBlake3").len(), 64);
}

/// One image always encodes to the same bytes: the header attributes are written in name order
/// (the `exr` crate keeps them in a hash map) and the chunks in increasing order, also when they
/// are compressed on several threads (images of at least 2^20 samples). Each encode builds a new
/// hash map with new random keys, so before the sort eight encodes all agreeing was unlikely.
#[test]
fn the_same_image_always_encodes_to_the_same_bytes() {
    // 3 layers × 3 planes: 9 × 70 × 70 samples (one thread) and 9 × 400 × 300 (several).
    for (width, height) in [(70, 70), (400, 300)] {
        let mut image = sample_image(width, height);
        for k in 0..12 {
            image
                .set_attribute(&format!("skybakeExtra{k}"), format!("value {k}"))
                .unwrap();
        }
        let first = encode_exr(&image).unwrap();
        for _ in 0..7 {
            assert!(
                encode_exr(&image).unwrap() == first,
                "{width}x{height}: two encodes of one image differ"
            );
        }
        // And the header lists its attributes in byte order of their names (OpenEXR layout:
        // magic, version, then name NUL type NUL i32 size value ..., ended by a NUL).
        let mut names: Vec<&[u8]> = Vec::new();
        let mut at = 8;
        while first[at] != 0 {
            let name_end = at + first[at..].iter().position(|&b| b == 0).unwrap();
            let type_end =
                name_end + 1 + first[name_end + 1..].iter().position(|&b| b == 0).unwrap();
            let size = i32::from_le_bytes(first[type_end + 1..type_end + 5].try_into().unwrap());
            names.push(&first[at..name_end]);
            at = type_end + 5 + size as usize;
        }
        assert!(names.len() >= 12 + 8, "{} attributes", names.len());
        assert!(
            names.windows(2).all(|w| w[0] < w[1]),
            "attributes not in name order"
        );
    }
}

#[test]
fn transmittance_only_image_has_no_emissive_units() {
    let mut image = SpectralImage::new(2, 2, &[500.0]).unwrap();
    image
        .add_layer(TRANSMITTANCE_LAYER, vec![vec![1.0; 4]])
        .unwrap();
    let bytes = encode_exr(&image).unwrap();
    let meta = MetaData::read_from_buffered(std::io::Cursor::new(&bytes), true).unwrap();
    let key = exr::prelude::Text::from("emissiveUnits");
    assert!(!meta.headers[0].own_attributes.other.contains_key(&key));
    assert_bit_identical(&image, &decode_exr(&bytes).unwrap());
}

#[test]
fn image_without_layers_is_refused() {
    let image = SpectralImage::new(2, 2, &[500.0]).unwrap();
    let err = encode_exr(&image).unwrap_err();
    assert!(
        matches!(err, StoreError::Invalid(ref e) if e.field() == "image"),
        "{err}"
    );
}

#[test]
fn flipped_byte_in_the_middle_is_detected() {
    let bytes = encode_exr(&sample_image(70, 70)).unwrap();
    let mut damaged = bytes.clone();
    let middle = damaged.len() / 2;
    damaged[middle] ^= 0x40;
    assert!(matches!(decode_exr(&damaged), Err(StoreError::Corrupt(_))));
}

#[test]
fn truncation_is_detected() {
    let bytes = encode_exr(&sample_image(70, 70)).unwrap();
    for len in [0, 3, 100, bytes.len() / 2, bytes.len() - 1] {
        assert!(decode_exr(&bytes[..len]).is_err(), "truncated to {len}");
    }
}

#[test]
fn garbage_is_an_error_not_a_panic() {
    assert!(decode_exr(b"").is_err());
    assert!(decode_exr(b"v/1\x01 definitely not an exr").is_err());
}

fn arb_image() -> impl Strategy<Value = SpectralImage> {
    (
        1usize..=70,
        1usize..=70,
        prop::collection::btree_set(360_000_000u64..=830_000_000, 1..=3),
    )
        .prop_flat_map(|(width, height, wavelengths)| {
            let wavelengths_nm: Vec<f64> = wavelengths.iter().map(|&w| w as f64 / 1.0e6).collect();
            let n = width * height;
            let count = wavelengths_nm.len();
            let finite = any::<u32>().prop_map(|bits| {
                let v = f32::from_bits(bits);
                if v.is_finite() {
                    v
                } else {
                    f32::from_bits(bits & 0x807f_ffff)
                }
            });
            let planes = prop::collection::vec(prop::collection::vec(finite.clone(), n), count);
            let rgb = prop::option::of(prop::collection::vec(prop::collection::vec(finite, n), 3));
            (
                Just((width, height, wavelengths_nm)),
                planes.clone(),
                prop::option::of(planes),
                rgb,
                "[^\\x00]{0,40}",
            )
        })
        .prop_map(|((width, height, wavelengths_nm), s0, t, rgb, text)| {
            let mut image = SpectralImage::new(width, height, &wavelengths_nm).unwrap();
            image.add_layer(EMISSIVE_LAYER, s0).unwrap();
            if let Some(t) = t {
                image.add_layer(TRANSMITTANCE_LAYER, t).unwrap();
            }
            if let Some(mut rgb) = rgb {
                let b = rgb.pop().unwrap();
                let g = rgb.pop().unwrap();
                let r = rgb.pop().unwrap();
                image.set_rgb([r, g, b]).unwrap();
            }
            image.set_attribute(ATTR_SPEC_JSON, text).unwrap();
            image
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn any_small_image_round_trips_bit_exactly(
        image in arb_image(),
        compression in prop::sample::select(vec![
            ExrCompression::Zip,
            ExrCompression::Piz,
            ExrCompression::None,
        ]),
    ) {
        let back = decode_exr(&encode_exr_with(&image, compression).unwrap()).unwrap();
        assert_bit_identical(&image, &back);
    }

    #[test]
    fn any_single_byte_flip_is_refused(position in 0.0f64..1.0, mask in 1u8..=255) {
        let bytes = encode_exr(&sample_image(20, 9)).unwrap();
        let mut damaged = bytes.clone();
        let index = ((bytes.len() as f64 * position) as usize).min(bytes.len() - 1);
        damaged[index] ^= mask;
        prop_assert!(decode_exr(&damaged).is_err());
    }
}

/// An analytic pattern, exact in f32, that `tools/check_exr.py` recomputes with numpy and compares
/// with what the reference OpenEXR library reads from the file (keep the two in step).
fn reference_pattern_image() -> SpectralImage {
    let (width, height) = (100, 70);
    let wavelengths_nm = [400.0, 550.5, 700.25];
    let pattern = |f: &dyn Fn(usize, usize) -> f32| -> Vec<f32> {
        (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect()
    };
    let mut image = SpectralImage::new(width, height, &wavelengths_nm).unwrap();
    let s0 = (0..3)
        .map(|k| pattern(&|x, y| (x + 128 * y) as f32 * 0.25 + k as f32))
        .collect();
    let t = (0..3)
        .map(|k| pattern(&|x, _| (k + 1) as f32 * 0.125 + x as f32 / 128.0))
        .collect();
    image.add_layer(EMISSIVE_LAYER, s0).unwrap();
    image.add_layer(TRANSMITTANCE_LAYER, t).unwrap();
    image
        .set_rgb([
            pattern(&|x, _| x as f32),
            pattern(&|_, y| y as f32),
            pattern(&|x, y| (x * y) as f32),
        ])
        .unwrap();
    image
        .set_attribute(
            ATTR_SPEC_JSON,
            r#"{"product":"aerial","site":"Zürich","wavelengths_nm":[400,550.5,700.25]}"#,
        )
        .unwrap();
    image.set_attribute(ATTR_ENGINE_VERSION, "0.1.0").unwrap();
    image
        .set_attribute(ATTR_ERROR_ESTIMATE_JSON, r#"{"max_rel_error":0.01}"#)
        .unwrap();
    image.set_attribute(ATTR_COMPUTE_TIME_MS, "12.5").unwrap();
    image
}

/// Writes the reference pattern, once per compression, to `$SKYBAKE_EXR_SAMPLE_DIR` when set (for
/// `tools/check_exr.py`), otherwise to a scratch directory, and checks that each reads back bit for
/// bit.
#[test]
fn reference_pattern_file_round_trips() {
    let scratch = Scratch::new("exr-sample");
    let dir = std::env::var_os("SKYBAKE_EXR_SAMPLE_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| scratch.0.clone());
    let image = reference_pattern_image();
    for (name, compression) in [
        ("zip", ExrCompression::Zip),
        ("piz", ExrCompression::Piz),
        ("none", ExrCompression::None),
    ] {
        let path = dir.join(format!("pattern_{name}.exr"));
        if compression == ExrCompression::Zip {
            write_exr_file(&path, &image).unwrap();
        } else {
            write_atomic(&path, &encode_exr_with(&image, compression).unwrap()).unwrap();
        }
        assert_bit_identical(&image, &read_exr_file(&path).unwrap());
    }
}
