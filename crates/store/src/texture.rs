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
    for (name, values) in &t.channels {
        if values.len() != t.width * t.height {
            return Err(StoreError::Exr(format!(
                "texture channel {name} has {} values for {}×{}",
                values.len(),
                t.width,
                t.height
            )));
        }
    }
    let names: Vec<&str> = t.channels.iter().map(|(name, _)| *name).collect();
    let file = TextureFile::new(t.width, t.height, &names, t.half);
    let width = t.width;
    let value = |c: usize, y: usize, x: usize| t.channels[c].1[y * width + x];
    let count = file.blocks();
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, 8);
    let per = count.div_ceil(threads).max(1);
    let starts: Vec<usize> = (0..count).collect();
    let blocks = std::thread::scope(|s| {
        let handles: Vec<_> = starts
            .chunks(per)
            .map(|part| {
                let (file, value) = (&file, &value);
                s.spawn(move || {
                    part.iter()
                        .map(|&b| file.zip_block(b, value))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_default())
            .collect()
    });
    file.write(blocks)
}

/// A texture file's layout (size, channels, sample width), so that its ZIP blocks can be
/// compressed one by one as their lines become final ([`Self::zip_block`]) and the file written
/// from them ([`Self::write`]): the bytes of [`encode_texture_exr`] of the same values.
pub struct TextureFile {
    width: usize,
    height: usize,
    half: bool,
    /// The channels in the file's order (the header's, by name): their index in `names`.
    order: Vec<usize>,
    headers: exr::meta::Headers,
}

impl TextureFile {
    /// The layout of a `width` × `height` texture whose channels are `names` (in the order
    /// [`Self::zip_block`]'s values are asked by), 16-bit floats where `half`.
    pub fn new(width: usize, height: usize, names: &[&str], half: bool) -> Self {
        let mut channels: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
        for name in names {
            // The header needs the channels' names and sample types only.
            let samples = if half {
                FlatSamples::F16(Vec::new())
            } else {
                FlatSamples::F32(Vec::new())
            };
            channels.push(AnyChannel::new(Text::from(*name), samples));
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
        let sorted = AnyChannels::sort(channels);
        let order = sorted
            .list
            .iter()
            .map(|c| names.iter().position(|n| c.name.eq(n)).unwrap_or(0))
            .collect();
        let layer = Layer::new(Vec2(width, height), attributes, encoding, sorted);
        let image = Image::from_layer(layer);
        let headers = image.write().infer_meta_data();
        Self {
            width,
            height,
            half,
            order,
            headers,
        }
    }

    /// The number of ZIP blocks ([`ZIP_LINES`] lines each, the last one shorter).
    pub fn blocks(&self) -> usize {
        self.height.div_ceil(ZIP_LINES)
    }

    /// The lines of block `b`.
    pub fn block_lines(&self, b: usize) -> std::ops::Range<usize> {
        b * ZIP_LINES..((b + 1) * ZIP_LINES).min(self.height)
    }

    /// Block `b` as the file stores it (OpenEXR's `ZIP_COMPRESSION`, as the exr crate and
    /// OpenEXR write it: each line's channels in the header's order, little-endian; the bytes
    /// split into the even and odd ones, a byte-delta predictor, zlib at [`ZIP_LEVEL`]; stored
    /// raw where that is not smaller). `value(c, y, x)`: channel `c` (of `names`) at line `y`,
    /// column `x`.
    pub fn zip_block(&self, b: usize, value: impl Fn(usize, usize, usize) -> f32) -> Vec<u8> {
        let lines = self.block_lines(b);
        let size = if self.half { 2 } else { 4 };
        let mut raw = Vec::with_capacity(lines.len() * self.order.len() * self.width * size);
        for y in lines {
            for &c in &self.order {
                for x in 0..self.width {
                    let v = value(c, y, x);
                    if self.half {
                        raw.extend(half::f16::from_f32(v).to_le_bytes());
                    } else {
                        raw.extend(v.to_le_bytes());
                    }
                }
            }
        }
        zip(raw)
    }

    /// The file of the blocks (every one of [`Self::blocks`], in order), the checksum embedded.
    pub fn write(self, blocks: Vec<Vec<u8>>) -> Result<Vec<u8>, StoreError> {
        if blocks.len() != self.blocks() {
            return Err(StoreError::Exr(format!(
                "texture of {} lines given {} blocks",
                self.height,
                blocks.len()
            )));
        }
        let mut bytes = Vec::new();
        exr::block::write(Cursor::new(&mut bytes), self.headers, true, |_, writer| {
            for (index, compressed) in blocks.into_iter().enumerate() {
                let block = CompressedScanLineBlock {
                    y_coordinate: (index * ZIP_LINES) as i32,
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
}

/// Scan lines per ZIP block (OpenEXR's `ZIP_COMPRESSION`).
const ZIP_LINES: usize = 16;

/// The deflate level of the ZIP blocks (the exr crate's own is 4): 6, which every ZIP reader
/// inflates unchanged. On the `skyview` texels (zlib, docs/lut.md "Size"): level 6 within 40 kB
/// of level 9 at half its CPU, 0.25 MB under level 4 for ~0.3 s more.
const ZIP_LEVEL: u32 = 6;

/// A block's little-endian bytes as OpenEXR's `ZIP_COMPRESSION` stores them: the even bytes,
/// then the odd ones, each byte as the difference from the one before + 128, deflated (zlib) at
/// [`ZIP_LEVEL`]; the raw bytes where that is not smaller.
fn zip(raw: Vec<u8>) -> Vec<u8> {
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
    if !compressed.is_empty() && compressed.len() < raw.len() {
        compressed
    } else {
        raw
    }
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

    /// A file written from blocks compressed one by one, in any order and from values laid out
    /// otherwise (here interleaved, channels not in name order), is the file of the planes.
    #[test]
    fn blocks_compressed_apart_make_the_same_file() {
        let (width, height) = (5, 40);
        let names = ["R", "G", "B"];
        let interleaved: Vec<f32> = (0..width * height * 3)
            .map(|i| ((i * 7919) % 1000) as f32 * 1e-3 + 0.25)
            .collect();
        for half in [false, true] {
            let planes = (0..3)
                .map(|c| {
                    let plane = interleaved.iter().skip(c).step_by(3).copied().collect();
                    (names[c], plane)
                })
                .collect();
            let whole = encode_texture_exr(TextureImage {
                width,
                height,
                channels: planes,
                half,
            })
            .unwrap();
            let file = TextureFile::new(width, height, &names, half);
            assert_eq!(file.blocks(), 3);
            assert_eq!(file.block_lines(2), 32..40);
            let mut blocks = vec![Vec::new(); file.blocks()];
            for b in (0..file.blocks()).rev() {
                blocks[b] = file.zip_block(b, |c, y, x| interleaved[(y * width + x) * 3 + c]);
            }
            assert_eq!(file.write(blocks).unwrap(), whole);
            let (w, h, ch) = decode_texture_exr(&whole).unwrap();
            assert_eq!((w, h), (width, height));
            let names: Vec<&str> = ch.iter().map(|(n, _)| n.as_str()).collect();
            assert_eq!(names, ["B", "G", "R"]);
            let tol = if half { 1e-3 } else { 0.0 };
            for (x, r) in ch[2].1.iter().enumerate() {
                assert!((r - interleaved[x * 3]).abs() <= tol * r.abs(), "{r}");
            }
        }
    }
}
