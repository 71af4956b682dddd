//! Plain texture OpenEXR files (the real-time bundle's transmittance, scattering and irradiance
//! textures): single part, scan lines (what texture loaders such as three.js's `EXRLoader`
//! read), ZIP-compressed, channels `R`, `G`, `B`, `A` or named ones, 16- or 32-bit float, with
//! the whole-file checksum every file skybake writes carries ([`super::checksum`]). Row 0 of
//! the file is the texture's first row (v = 0.5/height).

use std::io::{Cursor, Write};

use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock};
use exr::block::writer::ChunksWriter;
use flate2::write::ZlibEncoder;

use exr::prelude::{
    read, AnyChannel, AnyChannels, AttributeValue, Blocks, Compression, Encoding, FlatSamples,
    Image, Layer, LayerAttributes, LineOrder, ReadChannels, ReadLayers, SmallVec, Text, Vec2,
    WritableImage,
};

use super::checksum::{self, PLACEHOLDER};
use super::layout::ATTR_FILE_CHECKSUM;
use super::StoreError;

/// A texture's channels as they are written: (name, values row by row, whether 16-bit).
pub struct TextureImage<'a> {
    pub width: usize,
    pub height: usize,
    pub channels: Vec<(&'a str, Vec<f32>)>,
    pub half: bool,
}

/// Encodes a texture as a scan-line, ZIP-compressed OpenEXR file with the checksum embedded.
pub fn encode_texture_exr(t: TextureImage) -> Result<Vec<u8>, StoreError> {
    let mut channels: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for (name, values) in t.channels {
        if values.len() != t.width * t.height {
            return Err(StoreError::Exr(format!(
                "texture channel {name} has {} values for {}×{}",
                values.len(),
                t.width,
                t.height
            )));
        }
        let samples = if t.half {
            FlatSamples::F16(values.into_iter().map(half::f16::from_f32).collect())
        } else {
            FlatSamples::F32(values)
        };
        channels.push(AnyChannel::new(Text::from(name), samples));
    }
    let mut attributes = LayerAttributes {
        software_name: Some(Text::from(concat!("skybake ", env!("CARGO_PKG_VERSION")))),
        ..LayerAttributes::default()
    };
    attributes.other.insert(
        Text::from(ATTR_FILE_CHECKSUM),
        AttributeValue::Text(Text::from_slice_unchecked(&PLACEHOLDER)),
    );
    let encoding = Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new(
        Vec2(t.width, t.height),
        attributes,
        encoding,
        AnyChannels::sort(channels),
    );
    let image = Image::from_layer(layer);
    let headers = image.write().infer_meta_data();
    let blocks = zip_blocks(&image.layer_data.channel_data.list, t.width, t.height);
    let mut bytes = Vec::new();
    exr::block::write(Cursor::new(&mut bytes), headers, true, |_, writer| {
        for (index, (y, compressed)) in blocks.into_iter().enumerate() {
            let block = CompressedScanLineBlock {
                y_coordinate: y as i32,
                compressed_pixels_le: compressed,
            };
            writer.write_chunk(
                index,
                Chunk {
                    layer_index: 0,
                    compressed_block: CompressedBlock::ScanLine(block),
                },
            )?;
        }
        Ok(())
    })
    .map_err(|e| StoreError::Exr(format!("encoding failed: {e}")))?;
    checksum::embed(&mut bytes)?;
    Ok(bytes)
}

/// Scan lines per ZIP block (OpenEXR's `ZIP_COMPRESSION`).
const ZIP_LINES: usize = 16;

/// The deflate level of the ZIP blocks (the exr crate's own is 4): 6, which every ZIP reader
/// inflates unchanged. On the `skyview` texels (zlib, docs/lut.md "Size"): level 6 within 40 kB
/// of level 9 at half its CPU, 0.25 MB under level 4 for ~0.3 s more.
const ZIP_LEVEL: u32 = 6;

/// The ZIP blocks of a scan-line image (OpenEXR's `ZIP_COMPRESSION`, as the exr crate and
/// OpenEXR write them: per block of 16 lines, each line's channels in the header's order,
/// little-endian; the bytes split into the even and odd ones, a byte-delta predictor, zlib),
/// deflated at [`ZIP_LEVEL`]; a block stored raw where that is not smaller. (y, bytes) per
/// block, in increasing y; blocks are compressed on the available cores.
fn zip_blocks(
    channels: &[AnyChannel<FlatSamples>],
    width: usize,
    height: usize,
) -> Vec<(usize, Vec<u8>)> {
    let block = |y0: usize| -> (usize, Vec<u8>) {
        let y1 = (y0 + ZIP_LINES).min(height);
        let mut raw = Vec::new();
        for y in y0..y1 {
            for c in channels {
                let line = y * width..(y + 1) * width;
                match &c.sample_data {
                    FlatSamples::F16(v) => v[line].iter().for_each(|h| raw.extend(h.to_le_bytes())),
                    FlatSamples::F32(v) => v[line].iter().for_each(|f| raw.extend(f.to_le_bytes())),
                    FlatSamples::U32(v) => v[line].iter().for_each(|u| raw.extend(u.to_le_bytes())),
                }
            }
        }
        // The even bytes, then the odd ones; then each byte as the difference from the one
        // before, + 128.
        let mut split: Vec<u8> = raw
            .iter()
            .step_by(2)
            .chain(raw.iter().skip(1).step_by(2))
            .copied()
            .collect();
        for i in (1..split.len()).rev() {
            split[i] = split[i].wrapping_sub(split[i - 1]).wrapping_add(128);
        }
        let mut z = ZlibEncoder::new(
            Vec::with_capacity(raw.len()),
            flate2::Compression::new(ZIP_LEVEL),
        );
        let compressed = z
            .write_all(&split)
            .and_then(|()| z.finish())
            .unwrap_or_default();
        (
            y0,
            if !compressed.is_empty() && compressed.len() < raw.len() {
                compressed
            } else {
                raw
            },
        )
    };
    let starts: Vec<usize> = (0..height).step_by(ZIP_LINES).collect();
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, 8);
    let per = starts.len().div_ceil(threads).max(1);
    std::thread::scope(|s| {
        let handles: Vec<_> = starts
            .chunks(per)
            .map(|part| s.spawn(|| part.iter().map(|&y| block(y)).collect::<Vec<_>>()))
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_default())
            .collect()
    })
}

/// A decoded texture: width, height and its channels (name, values as f32) in name order.
pub type DecodedTexture = (usize, usize, Vec<(String, Vec<f32>)>);

/// Decodes a file written by [`encode_texture_exr`] (checksum verified): width, height and the
/// channels (name, values as f32) in name order.
pub fn decode_texture_exr(bytes: &[u8]) -> Result<DecodedTexture, StoreError> {
    checksum::verify(bytes)?;
    let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(Cursor::new(bytes))
    }))
    .map_err(|_| StoreError::Corrupt("OpenEXR decoder panicked".into()))?
    .map_err(|e| StoreError::Exr(format!("decoding failed: {e}")))?;
    let layer = decoded.layer_data;
    let channels = layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            let name = String::from_utf8_lossy(c.name.bytes()).into_owned();
            let values = match &c.sample_data {
                FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
                FlatSamples::F32(v) => v.clone(),
                FlatSamples::U32(v) => v.iter().map(|u| *u as f32).collect(),
            };
            (name, values)
        })
        .collect();
    Ok((layer.size.0, layer.size.1, channels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn textures_round_trip_in_half_and_float() {
        let values: Vec<f32> = (0..6 * 4).map(|i| i as f32 * 0.37 + 1e-3).collect();
        for half in [false, true] {
            let bytes = encode_texture_exr(TextureImage {
                width: 6,
                height: 4,
                channels: vec![
                    ("R", values.clone()),
                    ("A", values.iter().map(|v| v * 2.0).collect()),
                ],
                half,
            })
            .unwrap();
            let (w, h, ch) = decode_texture_exr(&bytes).unwrap();
            assert_eq!((w, h, ch.len()), (6, 4, 2));
            assert_eq!(ch[0].0, "A");
            for (a, b) in ch[1].1.iter().zip(&values) {
                let tol = if half { 1e-3 * b.abs() } else { 0.0 };
                assert!((a - b).abs() <= tol, "{a} vs {b}");
            }
            let mut bad = bytes.clone();
            let n = bad.len();
            bad[n - 3] ^= 1;
            assert!(decode_texture_exr(&bad).is_err());
        }
    }
}
