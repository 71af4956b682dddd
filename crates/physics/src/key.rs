//! Content keys: what the cache, the stored tables and the frame tiles are addressed by.

/// The cache key of a product: blake3 (hex) of a domain tag, the length of the canonical spec JSON,
/// the spec JSON and the engine version. The length prefix keeps `(spec, version)` pairs that
/// concatenate to the same bytes apart.
pub fn cache_key(canonical_spec_json: &str, engine_version: &str) -> String {
    let mut hasher = blake3::Hasher::new();
    hasher.update(b"skybake cache key v1\0");
    hasher.update(&(canonical_spec_json.len() as u64).to_le_bytes());
    hasher.update(canonical_spec_json.as_bytes());
    hasher.update(engine_version.as_bytes());
    hasher.finalize().to_hex().to_string()
}
