//! Storage: the only crate that touches the disk or the network.
//!
//! - [`SpectralImage`] and [`layout`] (re-exported from the physics crate, where the tables that are
//!   stored are made): the in-memory multi-layer spectral image and the spectral OpenEXR layout.
//! - [`exr`]: tiled spectral OpenEXR encode/decode, in memory and to files.
//! - [`checksum`]: the whole-file blake3 checksum embedded in every file skybake writes.
//! - [`atomic`]: the one function that writes files (temp file, fsync, rename, fsync directory).
//! - [`files`]: whole-file reads and directory listing for the job store and bakes.
//! - [`tiles`]: the tiles of a product computed piece by piece (a resumable render).
//! - [`cache`]: the content-addressed, size-bounded disk cache with an in-memory LRU in front.
//! - [`bucket`]: an S3-compatible bucket (`s3://bucket/prefix`), the shared tier behind the cache,
//!   frame tiles and bake state when several processes or machines share one store.
//! - [`lease`]: leases in a bucket, so one process at a time computes a product.
//! - [`location`]: a folder of files in a directory or a bucket (where bakes write).
//! - [`tables`]: the engine's shared tables (precise multiple scattering) kept in that cache.
//!
//! ```no_run
//! use skybake_store::{cache_key, Cache, CacheConfig, SpectralImage};
//! let cache = Cache::open(CacheConfig::new("/var/cache/skybake", 10 << 30, 256 << 20))?;
//! let key = cache_key(r#"{"product":"sky"}"#, "0.1.0");
//! let image = SpectralImage::emissive(1, 1, &[550.0], vec![vec![1.0]])?;
//! let bytes = cache.put_image(&key, &image)?; // the EXR file, ready to serve
//! assert_eq!(cache.get(&key)?.as_deref(), Some(&bytes[..]));
//! # Ok::<(), skybake_store::StoreError>(())
//! ```

pub mod atomic;
pub mod blob;
pub mod bucket;
pub mod cache;
pub mod checksum;
mod error;
pub mod exr;
pub mod files;
pub mod lease;
pub mod location;
mod lru;
pub mod tables;
pub mod texture;
pub mod tiles;

pub use atomic::write_atomic;
pub use bucket::{Bucket, BucketStats, RetryPolicy};
pub use cache::{Cache, CacheConfig, CacheStats};
pub use error::StoreError;
pub use exr::{
    decode_exr, encode_exr, encode_exr_with, read_exr_file, write_exr_file, ExrCompression,
};
pub use location::Location;
pub use skybake_physics::image::{layout, spectral_image, SpectralImage, SpectralLayer};
pub use skybake_physics::key::cache_key;
pub use skybake_physics::{Error, Result};
pub use tiles::{FrameTiles, TileStore};
