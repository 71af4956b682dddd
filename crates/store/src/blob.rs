//! The cache's second entry kind: a file of arbitrary bytes (a JSON manifest, a texture of a
//! bundle) with the same guarantees as the product images (see [`super::cache`]): it carries the
//! key it was stored under and a blake3 checksum of that key and its payload, both checked on
//! every read. Layout: three text lines, then the payload verbatim:
//!
//! ```text
//! skybake-blob 1
//! key <64 hex digits>
//! blake3 <64 hex digits: hash of the key's 64 digits followed by the payload>
//! <payload>
//! ```

use super::StoreError;

const MAGIC: &[u8] = b"skybake-blob 1\n";
const KEY_PREFIX: &[u8] = b"key ";
const HASH_PREFIX: &[u8] = b"blake3 ";
/// Length of the header: magic, key line, checksum line.
const HEADER_LEN: usize = MAGIC.len() + KEY_PREFIX.len() + 65 + HASH_PREFIX.len() + 65;

fn hash(key: &str, payload: &[u8]) -> blake3::Hash {
    let mut hasher = blake3::Hasher::new();
    hasher.update(key.as_bytes());
    hasher.update(payload);
    hasher.finalize()
}

/// The file bytes of `payload` stored under `key` (a validated 64-digit key).
pub fn encode_blob(key: &str, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(KEY_PREFIX);
    out.extend_from_slice(key.as_bytes());
    out.push(b'\n');
    out.extend_from_slice(HASH_PREFIX);
    out.extend_from_slice(hash(key, payload).to_hex().as_bytes());
    out.push(b'\n');
    out.extend_from_slice(payload);
    out
}

/// Why a blob file was refused.
#[derive(Debug)]
pub enum BlobRejection {
    /// Damaged: no header, or the checksum does not match.
    Corrupt(StoreError),
    /// Intact, but stored under another key (the key it carries).
    ForeignKey(String),
}

/// The payload of blob file `bytes` after checking its checksum and that it carries `key`.
pub fn verify_blob<'a>(bytes: &'a [u8], key: &str) -> Result<&'a [u8], BlobRejection> {
    let corrupt = |why: &str| BlobRejection::Corrupt(StoreError::Corrupt(format!("blob: {why}")));
    if bytes.len() < HEADER_LEN || !bytes.starts_with(MAGIC) {
        return Err(corrupt("no header"));
    }
    let key_line = &bytes[MAGIC.len()..MAGIC.len() + KEY_PREFIX.len() + 65];
    let hash_start = MAGIC.len() + KEY_PREFIX.len() + 65;
    let hash_line = &bytes[hash_start..HEADER_LEN];
    if !key_line.starts_with(KEY_PREFIX)
        || key_line[key_line.len() - 1] != b'\n'
        || !hash_line.starts_with(HASH_PREFIX)
        || hash_line[hash_line.len() - 1] != b'\n'
    {
        return Err(corrupt("malformed header"));
    }
    let carried = std::str::from_utf8(&key_line[KEY_PREFIX.len()..KEY_PREFIX.len() + 64])
        .map_err(|_| corrupt("key is not text"))?;
    let stored = &hash_line[HASH_PREFIX.len()..HASH_PREFIX.len() + 64];
    let payload = &bytes[HEADER_LEN..];
    if hash(carried, payload).to_hex().as_bytes() != stored {
        return Err(corrupt("blake3 mismatch"));
    }
    if carried != key {
        return Err(BlobRejection::ForeignKey(carried.to_string()));
    }
    Ok(payload)
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: &str = "0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";
    const OTHER: &str = "f123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";

    #[test]
    fn blobs_round_trip_and_refuse_damage_and_foreign_keys() {
        let payload = b"{\"format\": \"x\"}\n\x00\xff binary too";
        let file = encode_blob(KEY, payload);
        assert_eq!(verify_blob(&file, KEY).unwrap(), payload);
        assert!(matches!(
            verify_blob(&file, OTHER),
            Err(BlobRejection::ForeignKey(k)) if k == KEY
        ));
        for i in [0, 20, HEADER_LEN - 2, HEADER_LEN, file.len() - 1] {
            let mut bad = file.clone();
            bad[i] ^= 0x01;
            assert!(
                matches!(verify_blob(&bad, KEY), Err(BlobRejection::Corrupt(_))),
                "flipped byte {i}"
            );
        }
        assert!(matches!(
            verify_blob(&file[..file.len() - 1], KEY),
            Err(BlobRejection::Corrupt(_))
        ));
        assert!(matches!(
            verify_blob(&file[..10], KEY),
            Err(BlobRejection::Corrupt(_))
        ));
        // The empty payload is a valid blob.
        assert_eq!(verify_blob(&encode_blob(KEY, b""), KEY).unwrap(), b"");
    }
}
