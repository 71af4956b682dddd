//! Storage: the only module that touches the disk.
//!
//! - [`spectral_image`]: the in-memory multi-layer spectral image that products are stored as.
//! - [`layout`]: the spectral OpenEXR layout (channel names, attribute names).
//! - [`exr`]: tiled spectral OpenEXR encode/decode, in memory and to files.
//! - [`checksum`]: the whole-file blake3 checksum embedded in every file skybake writes.
//! - [`atomic`]: the one function that writes files (temp file, fsync, rename, fsync directory).
//! - [`files`]: whole-file reads and directory listing for the job store and bakes.
//! - [`cache`]: the content-addressed, size-bounded disk cache with an in-memory LRU in front.
//! - [`tables`]: the engine's shared tables (precise multiple scattering) kept in that cache.
//!
//! ```no_run
//! use skybake::store::{cache_key, Cache, CacheConfig, SpectralImage};
//! let cache = Cache::open(CacheConfig::new("/var/cache/skybake", 10 << 30, 256 << 20))?;
//! let key = cache_key(r#"{"product":"sky"}"#, "0.1.0");
//! let image = SpectralImage::emissive(1, 1, &[550.0], vec![vec![1.0]])?;
//! let bytes = cache.put_image(&key, &image)?; // the EXR file, ready to serve
//! assert_eq!(cache.get(&key)?.as_deref(), Some(&bytes[..]));
//! # Ok::<(), skybake::store::StoreError>(())
//! ```

pub mod atomic;
pub mod bench;
pub mod cache;
pub mod checksum;
mod error;
pub mod exr;
pub mod files;
pub mod layout;
mod lru;
pub mod spectral_image;
pub mod tables;

pub use atomic::write_atomic;
pub use bench::{bench_store, StoreBench};
pub use cache::{cache_key, Cache, CacheConfig, CacheStats};
pub use error::StoreError;
pub use exr::{
    decode_exr, encode_exr, encode_exr_with, read_exr_file, write_exr_file, ExrCompression,
};
pub use spectral_image::{SpectralImage, SpectralLayer};
