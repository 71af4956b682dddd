//! What the probe examples share: the committed validation data, their knobs and one sum.
#![allow(dead_code)] // each probe uses part of it

/// The committed reference data (`tests/data`).
pub const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data");

/// A committed `.npy` array (little-endian f4, or one byte per value) as f32, flattened.
pub fn npy(name: &str) -> Vec<f32> {
    let path = format!("{DATA}/{name}");
    let b = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let (hl, start) = if b[6] == 1 {
        (u16::from_le_bytes([b[8], b[9]]) as usize, 10)
    } else {
        (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
    };
    let header = String::from_utf8_lossy(&b[start..start + hl]).to_string();
    let data = &b[start + hl..];
    if header.contains("<f4") {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else {
        data.iter().map(|&v| v as f32).collect()
    }
}

/// A numeric knob from the environment.
pub fn env_f(name: &str) -> Option<f64> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

/// Sum of `img` over the mask, relative to `norm`.
pub fn share(img: &[f32], mask: &[bool], norm: f64) -> f64 {
    img.iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|(v, _)| *v as f64)
        .sum::<f64>()
        / norm
}
