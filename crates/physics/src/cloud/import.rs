//! Imported density grids: raw little-endian f32 with a JSON header, and NumPy `.npy` arrays.
//!
//! Everything parses from bytes (the caller reads the files). Headers are validated, and the
//! voxel count and byte length checked, before any grid memory is allocated. Both formats store
//! `[z][y][x]` with x fastest, as [`DensityGrid`] does (`cloud::grid`).

use super::grid::{checked_voxel_count, DensityGrid};
use crate::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Largest accepted JSON or `.npy` header, bytes.
pub const MAX_HEADER_BYTES: usize = 65_536;

const NPY_MAGIC: &[u8; 6] = b"\x93NUMPY";

/// Header of a raw grid: the JSON file next to the little-endian f32 data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawHeader {
    /// Voxel counts `[nx, ny, nz]`; the data holds `nx·ny·nz` f32 values, x fastest.
    pub dims: [usize; 3],
    /// Edge of a cubic voxel, metres.
    pub voxel_size_m: f64,
    /// Minimum corner of the box, metres.
    pub origin_m: [f64; 3],
}

/// Parses and validates a raw-grid JSON header.
pub fn parse_raw_header(json: &[u8]) -> Result<RawHeader> {
    if json.len() > MAX_HEADER_BYTES {
        return Err(Error::too_large(
            "header",
            format!("{} bytes", json.len()),
            format!("{MAX_HEADER_BYTES} bytes"),
        ));
    }
    let header: RawHeader = serde_json::from_slice(json)
        .map_err(|e| Error::invalid("header", format!("not a valid grid header: {e}")))?;
    checked_voxel_count(header.dims)?;
    Ok(header)
}

/// A grid from raw little-endian f32 `data` described by `header`.
pub fn from_raw_f32(header: &RawHeader, data: &[u8]) -> Result<DensityGrid> {
    let count = checked_voxel_count(header.dims)?;
    let expected = count * 4;
    if data.len() != expected {
        return Err(Error::invalid(
            "data",
            format!(
                "has {} bytes, dims {:?} of f32 need {expected}",
                data.len(),
                header.dims
            ),
        ));
    }
    let values = data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    DensityGrid::from_data(
        header.dims,
        header.voxel_size_m,
        DVec3::from_array(header.origin_m),
        values,
    )
}

/// The raw form of a grid: (JSON header, little-endian f32 data).
pub fn to_raw_f32(grid: &DensityGrid) -> Result<(Vec<u8>, Vec<u8>)> {
    let header = RawHeader {
        dims: grid.dims,
        voxel_size_m: grid.voxel_size_m,
        origin_m: grid.origin_m.to_array(),
    };
    let json = serde_json::to_vec_pretty(&header)
        .map_err(|e| Error::invalid("header", format!("cannot serialise: {e}")))?;
    let data = grid.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    Ok((json, data))
}

/// Element type of an `.npy` array.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Dtype {
    F4,
    F8,
}

/// The dimensions `[nx, ny, nz]` of the grid in `.npy` bytes, from the header alone (the
/// header and the data length are validated as [`from_npy_bytes`] does; nothing is allocated).
pub fn npy_dims(bytes: &[u8]) -> Result<[usize; 3]> {
    npy_layout(bytes).map(|(dims, _, _)| dims)
}

/// A grid from `.npy` bytes: a 3-D float32 or float64 array in C order, shape `(nz, ny, nx)`.
/// The file holds no geometry, so `voxel_size_m` and `origin_m` come from the caller.
pub fn from_npy_bytes(bytes: &[u8], voxel_size_m: f64, origin_m: DVec3) -> Result<DensityGrid> {
    let (dims, dtype, end) = npy_layout(bytes)?;
    let data = &bytes[end..];
    let values: Vec<f32> = match dtype {
        Dtype::F4 => data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        Dtype::F8 => data
            .chunks_exact(8)
            .map(|c| {
                let v = f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]);
                v as f32
            })
            .collect(),
    };
    DensityGrid::from_data(dims, voxel_size_m, origin_m, values)
}

/// Validates `.npy` bytes: dims `[nx, ny, nz]`, element type and where the data starts.
fn npy_layout(bytes: &[u8]) -> Result<([usize; 3], Dtype, usize)> {
    if bytes.len() < 10 || &bytes[..6] != NPY_MAGIC {
        return Err(Error::invalid(
            "npy",
            "not a .npy file (missing the \\x93NUMPY magic)",
        ));
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => {
            return Err(Error::out_of_range(
                "npy.version",
                format!("{major}.{minor}"),
                "1.0, 2.0 or 3.0",
            ))
        }
    };
    if header_len > MAX_HEADER_BYTES {
        return Err(Error::too_large(
            "npy.header",
            format!("{header_len} bytes"),
            format!("{MAX_HEADER_BYTES} bytes"),
        ));
    }
    let end = start + header_len;
    if end > bytes.len() {
        return Err(Error::invalid(
            "npy.header",
            "the file ends inside the header",
        ));
    }
    let text = std::str::from_utf8(&bytes[start..end])
        .map_err(|_| Error::invalid("npy.header", "the header is not text"))?;
    let header = parse_npy_dict(text)?;
    let dtype =
        match header.descr.as_str() {
            "<f4" => Dtype::F4,
            "<f8" => Dtype::F8,
            ">f4" | ">f8" => return Err(Error::out_of_range(
                "npy.descr",
                &header.descr,
                "'<f4' or '<f8' (big-endian arrays are not supported; convert with astype('<f4'))",
            )),
            other => {
                return Err(Error::out_of_range(
                    "npy.descr",
                    other,
                    "'<f4' (float32) or '<f8' (float64)",
                ))
            }
        };
    if header.fortran_order {
        return Err(Error::invalid(
            "npy.fortran_order",
            "Fortran-ordered arrays are not supported; save a C-ordered array \
             (np.ascontiguousarray) indexed [z][y][x]",
        ));
    }
    let &[nz, ny, nx] = header.shape.as_slice() else {
        return Err(Error::invalid(
            "npy.shape",
            format!(
                "must be 3-D (nz, ny, nx), found {} dimensions",
                header.shape.len()
            ),
        ));
    };
    let dims = [nx, ny, nz];
    let count = checked_voxel_count(dims)?;
    let item = match dtype {
        Dtype::F4 => 4,
        Dtype::F8 => 8,
    };
    let data = &bytes[end..];
    if data.len() != count * item {
        return Err(Error::invalid(
            "npy.data",
            format!(
                "has {} bytes, shape ({nz}, {ny}, {nx}) of {} needs {}",
                data.len(),
                header.descr,
                count * item
            ),
        ));
    }
    Ok((dims, dtype, end))
}

/// A grid as `.npy` bytes (version 1.0, `<f4`, C order, shape `(nz, ny, nx)`), readable by
/// `numpy.load`. Geometry is not stored; keep `voxel_size_m` and `origin_m` alongside.
pub fn to_npy_bytes(grid: &DensityGrid) -> Vec<u8> {
    let [nx, ny, nz] = grid.dims;
    let mut dict =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({nz}, {ny}, {nx}), }}");
    // Pad with spaces so the data starts on a 64-byte boundary; the header ends with '\n'.
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    dict.push('\n');
    let mut out = Vec::with_capacity(10 + dict.len() + grid.data.len() * 4);
    out.extend_from_slice(NPY_MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    for v in &grid.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// The three entries of an `.npy` header dictionary.
#[derive(Debug)]
struct NpyHeader {
    descr: String,
    fortran_order: bool,
    shape: Vec<usize>,
}

/// Parses the Python-literal dictionary of an `.npy` header, e.g.
/// `{'descr': '<f4', 'fortran_order': False, 'shape': (4, 3, 2), }`.
fn parse_npy_dict(text: &str) -> Result<NpyHeader> {
    let bad = |why: &str| Error::invalid("npy.header", format!("{why} in {:?}", text.trim_end()));
    let mut p = Cursor {
        s: text.as_bytes(),
        i: 0,
    };
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    p.expect(b'{').ok_or_else(|| bad("expected '{'"))?;
    loop {
        if p.eat(b'}') {
            break;
        }
        let key = p.string().ok_or_else(|| bad("expected a quoted key"))?;
        p.expect(b':').ok_or_else(|| bad("expected ':'"))?;
        match key.as_str() {
            "descr" => descr = Some(p.string().ok_or_else(|| bad("descr must be a string"))?),
            "fortran_order" => {
                fortran = Some(if p.word("True") {
                    true
                } else if p.word("False") {
                    false
                } else {
                    return Err(bad("fortran_order must be True or False"));
                })
            }
            "shape" => {
                shape = Some(
                    p.tuple()
                        .ok_or_else(|| bad("shape must be a tuple of integers"))?,
                )
            }
            other => return Err(bad(&format!("unknown key '{other}'"))),
        }
        if !p.eat(b',') {
            p.expect(b'}').ok_or_else(|| bad("expected ',' or '}'"))?;
            break;
        }
    }
    p.skip_ws();
    if p.i != p.s.len() {
        return Err(bad("trailing characters after the dictionary"));
    }
    Ok(NpyHeader {
        descr: descr.ok_or_else(|| bad("missing 'descr'"))?,
        fortran_order: fortran.ok_or_else(|| bad("missing 'fortran_order'"))?,
        shape: shape.ok_or_else(|| bad("missing 'shape'"))?,
    })
}

/// A byte cursor for the header's tiny Python-literal grammar.
struct Cursor<'a> {
    s: &'a [u8],
    i: usize,
}

impl Cursor<'_> {
    fn skip_ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
            self.i += 1;
        }
    }

    fn eat(&mut self, c: u8) -> bool {
        self.skip_ws();
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            true
        } else {
            false
        }
    }

    fn expect(&mut self, c: u8) -> Option<()> {
        self.eat(c).then_some(())
    }

    fn word(&mut self, w: &str) -> bool {
        self.skip_ws();
        if self.s[self.i..].starts_with(w.as_bytes()) {
            self.i += w.len();
            true
        } else {
            false
        }
    }

    fn string(&mut self) -> Option<String> {
        self.skip_ws();
        let quote = *self.s.get(self.i)?;
        if quote != b'\'' && quote != b'"' {
            return None;
        }
        let rest = &self.s[self.i + 1..];
        let len = rest.iter().position(|&c| c == quote)?;
        let out = std::str::from_utf8(&rest[..len]).ok()?.to_string();
        self.i += len + 2;
        Some(out)
    }

    /// `(a, b, c)` or `(a,)` or `()`; integers must fit in `usize`.
    fn tuple(&mut self) -> Option<Vec<usize>> {
        self.expect(b'(')?;
        let mut out = Vec::new();
        loop {
            if self.eat(b')') {
                return Some(out);
            }
            self.skip_ws();
            let digits = self.s[self.i..]
                .iter()
                .take_while(|c| c.is_ascii_digit())
                .count();
            if digits == 0 || digits > 20 || out.len() >= 32 {
                return None;
            }
            let n = std::str::from_utf8(&self.s[self.i..self.i + digits])
                .ok()?
                .parse()
                .ok()?;
            self.i += digits;
            out.push(n);
            if !self.eat(b',') {
                self.expect(b')')?;
                return Some(out);
            }
        }
    }
}
