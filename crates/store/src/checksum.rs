//! Whole-file integrity check embedded in the file itself. The encoder writes the header attribute
//! `skybakeFileBlake3` (an OpenEXR `string` of 64 hex digits) holding a placeholder, then replaces
//! the placeholder with the blake3 hash of the complete file as it was with the placeholder in place.
//! The attribute keeps its length, so every offset in the file stays valid and the file remains an
//! ordinary OpenEXR file. Any flipped byte (header, offset table or pixel data) or any truncation
//! changes the hash; the verifier recomputes it before the bytes are trusted.

use super::layout::ATTR_FILE_CHECKSUM;
use super::StoreError;

/// Length of a blake3 hash in hex digits.
pub const CHECKSUM_HEX_LEN: usize = 64;

/// The value the attribute holds while the hash is computed.
pub const PLACEHOLDER: [u8; CHECKSUM_HEX_LEN] = [b'0'; CHECKSUM_HEX_LEN];

/// Bytes preceding the attribute value in an OpenEXR header: name, NUL, type name, NUL, i32 size.
fn attribute_prefix() -> Vec<u8> {
    let mut prefix = Vec::with_capacity(ATTR_FILE_CHECKSUM.len() + 12);
    prefix.extend_from_slice(ATTR_FILE_CHECKSUM.as_bytes());
    prefix.push(0);
    prefix.extend_from_slice(b"string");
    prefix.push(0);
    prefix.extend_from_slice(&(CHECKSUM_HEX_LEN as i32).to_le_bytes());
    prefix
}

/// Offset of the checksum value: the first occurrence of the attribute prefix. The header precedes
/// all pixel data, so in a well-formed file the first occurrence is the attribute itself.
fn value_offset(bytes: &[u8]) -> Option<usize> {
    let prefix = attribute_prefix();
    let start = bytes
        .windows(prefix.len())
        .position(|window| window == prefix.as_slice())?;
    let offset = start + prefix.len();
    (offset + CHECKSUM_HEX_LEN <= bytes.len()).then_some(offset)
}

fn hash_with_placeholder(bytes: &[u8], offset: usize) -> blake3::Hash {
    let mut hasher = blake3::Hasher::new();
    hasher.update(&bytes[..offset]);
    hasher.update(&PLACEHOLDER);
    hasher.update(&bytes[offset + CHECKSUM_HEX_LEN..]);
    hasher.finalize()
}

/// Replaces the placeholder written by the encoder with the file's hash.
pub(crate) fn embed(bytes: &mut [u8]) -> Result<(), StoreError> {
    let offset = value_offset(bytes)
        .filter(|&o| bytes[o..o + CHECKSUM_HEX_LEN] == PLACEHOLDER)
        .ok_or_else(|| StoreError::Exr("checksum placeholder missing from encoded file".into()))?;
    let hash = hash_with_placeholder(bytes, offset);
    bytes[offset..offset + CHECKSUM_HEX_LEN].copy_from_slice(hash.to_hex().as_bytes());
    Ok(())
}

/// Checks the embedded whole-file hash. Errors with [`StoreError::Corrupt`] when the attribute is
/// missing or the hash does not match.
pub fn verify(bytes: &[u8]) -> Result<(), StoreError> {
    let offset = value_offset(bytes)
        .ok_or_else(|| StoreError::Corrupt(format!("no {ATTR_FILE_CHECKSUM} attribute")))?;
    let stored = &bytes[offset..offset + CHECKSUM_HEX_LEN];
    let actual = hash_with_placeholder(bytes, offset);
    if stored == actual.to_hex().as_bytes() {
        Ok(())
    } else {
        Err(StoreError::Corrupt(format!(
            "blake3 mismatch: header says {}, content hashes to {}",
            String::from_utf8_lossy(stored),
            actual.to_hex()
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_file() -> Vec<u8> {
        let mut bytes = b"header-start\0".to_vec();
        bytes.extend_from_slice(&attribute_prefix());
        bytes.extend_from_slice(&PLACEHOLDER);
        bytes.extend_from_slice(b"\0pixel data follows .......");
        bytes
    }

    #[test]
    fn embedded_checksum_verifies_and_catches_every_flip() {
        let mut bytes = sample_file();
        assert!(matches!(verify(&bytes), Err(StoreError::Corrupt(_))));
        embed(&mut bytes).unwrap();
        verify(&bytes).unwrap();
        for index in 0..bytes.len() {
            let mut damaged = bytes.clone();
            damaged[index] ^= 0x01;
            assert!(verify(&damaged).is_err(), "flip at {index} not detected");
        }
        for len in 0..bytes.len() {
            assert!(
                verify(&bytes[..len]).is_err(),
                "truncation to {len} not detected"
            );
        }
    }

    #[test]
    fn embed_needs_the_placeholder() {
        let mut bytes = b"no attribute here".to_vec();
        assert!(matches!(embed(&mut bytes), Err(StoreError::Exr(_))));
    }
}
