//! Tiles of a product computed piece by piece (large renders compute and
//! cache tile by tile, so a crash loses at most the tiles in flight and a rerun resumes).
//!
//! Layout: `<root>/<first 2 hex of key>/<key>/tile-<index:05>.exr`, one spectral EXR per tile,
//! each written atomically ([`write_atomic`]) with its whole-file checksum and the attribute
//! [`ATTR_TILE_OF`] = `<key>/<index>` binding it to its place. A read verifies both; a tile that
//! fails is deleted and reported as absent (recomputed, never used). The finished product goes to
//! the [`super::Cache`] and its tiles are then removed ([`FrameTiles::remove_all`]); tiles of a
//! render that never finishes stay until [`TileStore::prune`] removes directories older than a
//! given age. Keys are checked like cache keys (64 lowercase hex digits), so no request text
//! becomes part of a path.
//!
//! The store counts the bytes of its tile files ([`TileStore::bytes`]; counted at open, kept up
//! to date by every put and removal), so that the service counts them in the cache's disk
//! budget, and [`TileStore::evict_oldest`] removes whole frames' tiles, least recently written
//! first, when that budget needs room (a frame's tiles are only a head start for a retry).
//!
//! A store in a bucket ([`TileStore::in_bucket`]) keeps the same files as objects
//! `<folder>/<key>/tile-<index:05>.exr`, verified the same way, so a bake shard restarted on
//! another machine resumes inside a frame. Its tiles are not in any local budget ([`Self::bytes`]
//! is 0); [`TileStore::prune`] removes abandoned ones.

use super::atomic::{is_temp_file_name, write_atomic};
use super::bucket::Bucket;
use super::cache::is_valid_key;
use super::exr::header_text_attribute;
use super::{checksum, StoreError};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

/// Header attribute binding a tile file to `<key>/<index>`.
pub const ATTR_TILE_OF: &str = "skybakeTileOf";

/// Most tiles of one product (a 16 Mi-pixel frame in 64×64 tiles has 4096).
pub const MAX_TILES: usize = 1 << 16;

/// The tile directory root (usually `<cache dir>/tiles`).
#[derive(Debug, Clone)]
pub struct TileStore {
    root: PathBuf,
    /// Bytes of the tile files under `root`.
    bytes: Arc<AtomicU64>,
    /// The bucket and folder holding the tiles instead of `root`.
    bucket: Option<(Arc<Bucket>, String)>,
}

/// The tiles of one product (one cache key).
#[derive(Debug, Clone)]
pub struct FrameTiles {
    dir: PathBuf,
    key: String,
    /// The store's byte count.
    bytes: Arc<AtomicU64>,
    /// The bucket and this product's folder in it, instead of `dir`.
    bucket: Option<(Arc<Bucket>, String)>,
}

/// Bytes of the files directly in `dir` (0 when it does not exist).
fn dir_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| e.metadata().ok())
        .filter(|m| m.is_file())
        .map(|m| m.len())
        .sum()
}

/// Subtracts without wrapping below zero (a file changed behind the store's back).
fn sub_bytes(counter: &AtomicU64, n: u64) {
    let _ = counter.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |b| {
        Some(b.saturating_sub(n))
    });
}

impl TileStore {
    /// Opens (creating) the tile root and deletes temporary files left by a crash.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(root).map_err(|e| StoreError::io(root, e))?;
        let store = Self {
            root: root.to_path_buf(),
            bytes: Arc::default(),
            bucket: None,
        };
        for dir in store.frame_dirs()? {
            for entry in std::fs::read_dir(&dir)
                .map_err(|e| StoreError::io(&dir, e))?
                .flatten()
            {
                if is_temp_file_name(&entry.file_name().to_string_lossy()) {
                    // Best effort: a leftover that cannot be deleted is only wasted space.
                    let _ = std::fs::remove_file(entry.path());
                }
            }
        }
        store.recount()?;
        Ok(store)
    }

    /// A store of tiles in `bucket` under `folder` (e.g. `tiles`).
    pub fn in_bucket(bucket: Arc<Bucket>, folder: &str) -> Self {
        Self {
            root: PathBuf::new(),
            bytes: Arc::default(),
            bucket: Some((bucket, folder.trim_matches('/').to_string())),
        }
    }

    /// Bytes of the tile files in the store.
    pub fn bytes(&self) -> u64 {
        self.bytes.load(Ordering::Relaxed)
    }

    /// Counts the tile files' bytes again from the disk.
    fn recount(&self) -> Result<(), StoreError> {
        let total = self.frame_dirs()?.iter().map(|d| dir_bytes(d)).sum();
        self.bytes.store(total, Ordering::Relaxed);
        Ok(())
    }

    /// Removes the tiles of whole frames, least recently written first and never those of
    /// `keep` (the render in progress), until the store holds at most `target_bytes`; returns
    /// how many frames' tiles were removed.
    pub fn evict_oldest(&self, keep: Option<&str>, target_bytes: u64) -> Result<usize, StoreError> {
        if self.bytes() <= target_bytes || self.bucket.is_some() {
            return Ok(0);
        }
        let mut frames: Vec<(SystemTime, PathBuf)> = self
            .frame_dirs()?
            .into_iter()
            .filter(|d| keep.is_none_or(|k| d.file_name().is_none_or(|n| n != k)))
            .map(|d| (newest_modification(&d), d))
            .collect();
        frames.sort();
        let mut removed = 0;
        for (_, dir) in frames {
            if self.bytes() <= target_bytes {
                break;
            }
            let n = dir_bytes(&dir);
            if std::fs::remove_dir_all(&dir).is_ok() {
                sub_bytes(&self.bytes, n);
                removed += 1;
            }
        }
        Ok(removed)
    }

    /// The tiles stored under `key` (64 lowercase hex digits).
    pub fn frame(&self, key: &str) -> Result<FrameTiles, StoreError> {
        if !is_valid_key(key) {
            return Err(crate::Error::invalid(
                "cache_key",
                "must be 64 lowercase hexadecimal digits (a blake3 hash)",
            )
            .into());
        }
        Ok(FrameTiles {
            dir: self.root.join(&key[..2]).join(key),
            key: key.to_string(),
            bytes: self.bytes.clone(),
            bucket: self
                .bucket
                .as_ref()
                .map(|(b, folder)| (b.clone(), format!("{folder}/{key}"))),
        })
    }

    fn frame_dirs(&self) -> Result<Vec<PathBuf>, StoreError> {
        let mut dirs = Vec::new();
        let shards = std::fs::read_dir(&self.root).map_err(|e| StoreError::io(&self.root, e))?;
        for shard in shards.flatten() {
            let name = shard.file_name().to_string_lossy().into_owned();
            if name.len() != 2 || !shard.file_type().is_ok_and(|t| t.is_dir()) {
                continue;
            }
            for frame in std::fs::read_dir(shard.path())
                .into_iter()
                .flatten()
                .flatten()
            {
                let key = frame.file_name().to_string_lossy().into_owned();
                if is_valid_key(&key) && frame.file_type().is_ok_and(|t| t.is_dir()) {
                    dirs.push(frame.path());
                }
            }
        }
        Ok(dirs)
    }

    /// Removes the shard directories left empty by finished products, and the root when nothing
    /// else is in it (a bake whose frames are all finished leaves no `tiles/` behind).
    pub fn remove_empty(&self) -> Result<(), StoreError> {
        if self.bucket.is_some() {
            // A bucket has no folders to leave behind.
            return Ok(());
        }
        let shards = std::fs::read_dir(&self.root).map_err(|e| StoreError::io(&self.root, e))?;
        for shard in shards.flatten() {
            if shard.file_type().is_ok_and(|t| t.is_dir()) {
                // Fails (and is meant to) when the shard still holds a product's tiles.
                let _ = std::fs::remove_dir(shard.path());
            }
        }
        let _ = std::fs::remove_dir(&self.root);
        Ok(())
    }

    /// Removes the tiles of products whose newest tile is older than `age` (renders abandoned for
    /// good); returns how many products were removed.
    pub fn prune(&self, age: Duration) -> Result<usize, StoreError> {
        let now = SystemTime::now();
        if let Some((bucket, folder)) = &self.bucket {
            let now_s = now
                .duration_since(SystemTime::UNIX_EPOCH)
                .unwrap_or_default()
                .as_secs() as i64;
            let mut removed = 0;
            for key in bucket.list(folder)?.1 {
                if !is_valid_key(&key) {
                    continue;
                }
                let frame = self.frame(&key)?;
                let (tiles, _) = bucket.list(&format!("{folder}/{key}"))?;
                let newest = tiles.iter().map(|t| t.modified_s).max().unwrap_or(0);
                if now_s - newest >= age.as_secs() as i64 {
                    frame.remove_all()?;
                    removed += 1;
                }
            }
            return Ok(removed);
        }
        let mut removed = 0;
        for dir in self.frame_dirs()? {
            let newest = newest_modification(&dir);
            let stale = now.duration_since(newest).unwrap_or_default() >= age;
            if stale && std::fs::remove_dir_all(&dir).is_ok() {
                removed += 1;
            }
        }
        self.recount()?;
        Ok(removed)
    }
}

/// The newest modification time of the files in `dir` (the epoch when it has none).
fn newest_modification(dir: &Path) -> SystemTime {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| e.metadata().ok()?.modified().ok())
        .max()
        .unwrap_or(SystemTime::UNIX_EPOCH)
}

impl FrameTiles {
    fn path(&self, index: usize) -> PathBuf {
        self.dir.join(tile_name(index))
    }

    /// The value of [`ATTR_TILE_OF`] for tile `index`.
    pub fn binding(&self, index: usize) -> String {
        format!("{}/{index}", self.key)
    }

    /// The verified bytes of tile `index`, or `None` when it is absent. A file that fails its
    /// checksum or carries another binding is deleted and reported as absent.
    pub fn get(&self, index: usize) -> Result<Option<Vec<u8>>, StoreError> {
        if let Some((bucket, folder)) = &self.bucket {
            let name = format!("{folder}/{}", tile_name(index));
            let Some(bytes) = bucket.get(&name)? else {
                return Ok(None);
            };
            if self.verified(index, &bytes) {
                return Ok(Some(bytes));
            }
            tracing::warn!(name, "tile failed verification; recomputing it");
            bucket.delete(&name)?;
            return Ok(None);
        }
        let path = self.path(index);
        let meta = match std::fs::symlink_metadata(&path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(StoreError::io(&path, e)),
        };
        if !meta.is_file() {
            remove_any(&path);
            return Ok(None);
        }
        let size = meta.len();
        let bytes = std::fs::read(&path).map_err(|e| StoreError::io(&path, e))?;
        if self.verified(index, &bytes) {
            Ok(Some(bytes))
        } else {
            tracing::warn!(path = %path.display(), "tile failed verification; recomputing it");
            remove_any(&path);
            sub_bytes(&self.bytes, size);
            Ok(None)
        }
    }

    /// Whether `bytes` pass their checksum and are bound to tile `index` of this product.
    fn verified(&self, index: usize, bytes: &[u8]) -> bool {
        checksum::verify(bytes).is_ok()
            && header_text_attribute(bytes, ATTR_TILE_OF)
                .ok()
                .flatten()
                .is_some_and(|b| b == self.binding(index))
    }

    /// Stores tile `index` (EXR bytes carrying [`ATTR_TILE_OF`] = [`Self::binding`]) atomically.
    pub fn put(&self, index: usize, bytes: &[u8]) -> Result<(), StoreError> {
        if index >= MAX_TILES {
            return Err(
                crate::Error::out_of_range("tile", index, format!("0..{MAX_TILES}")).into(),
            );
        }
        if let Some((bucket, folder)) = &self.bucket {
            return bucket.put(&format!("{folder}/{}", tile_name(index)), bytes);
        }
        let path = self.path(index);
        let before = std::fs::symlink_metadata(&path)
            .ok()
            .filter(|m| m.is_file())
            .map_or(0, |m| m.len());
        write_atomic(&path, bytes)?;
        sub_bytes(&self.bytes, before);
        self.bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        Ok(())
    }

    /// Number of tile files present (verified or not; 0 when a bucket cannot be listed).
    pub fn count(&self) -> usize {
        if let Some((bucket, folder)) = &self.bucket {
            return bucket.list(folder).map_or(0, |(tiles, _)| {
                tiles.iter().filter(|t| is_tile_name(&t.name)).count()
            });
        }
        std::fs::read_dir(&self.dir)
            .into_iter()
            .flatten()
            .flatten()
            .filter(|e| is_tile_name(&e.file_name().to_string_lossy()))
            .count()
    }

    /// Removes every tile of this product (after the assembled product went to the cache).
    pub fn remove_all(&self) -> Result<(), StoreError> {
        if let Some((bucket, folder)) = &self.bucket {
            for tile in bucket.list(folder)?.0 {
                bucket.delete(&format!("{folder}/{}", tile.name))?;
            }
            return Ok(());
        }
        let n = dir_bytes(&self.dir);
        match std::fs::remove_dir_all(&self.dir) {
            Ok(()) => {
                sub_bytes(&self.bytes, n);
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(StoreError::io(&self.dir, e)),
        }
    }
}

fn tile_name(index: usize) -> String {
    format!("tile-{index:05}.exr")
}

fn is_tile_name(name: &str) -> bool {
    name.starts_with("tile-") && name.ends_with(".exr")
}

fn remove_any(path: &Path) {
    // Best effort: whatever cannot be removed is reported as absent and overwritten later.
    if std::fs::remove_file(path).is_err() {
        let _ = std::fs::remove_dir_all(path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{encode_exr, SpectralImage};

    fn tile_bytes(binding: &str, value: f32) -> Vec<u8> {
        let mut img = SpectralImage::emissive(2, 2, &[550.0], vec![vec![value; 4]]).unwrap();
        img.set_attribute(ATTR_TILE_OF, binding).unwrap();
        encode_exr(&img).unwrap()
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "skybake-tiles-{name}-{}-{:?}",
            std::process::id(),
            SystemTime::now()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn tiles_round_trip_and_bad_ones_are_dropped() {
        let root = scratch("roundtrip");
        let store = TileStore::open(&root).unwrap();
        let key = "ab".repeat(32);
        let tiles = store.frame(&key).unwrap();
        assert_eq!(tiles.get(0).unwrap(), None);
        let good = tile_bytes(&tiles.binding(0), 1.0);
        tiles.put(0, &good).unwrap();
        assert_eq!(tiles.get(0).unwrap().as_deref(), Some(&good[..]));
        // A valid tile stored at the wrong index is not used.
        tiles.put(1, &good).unwrap();
        assert_eq!(tiles.get(1).unwrap(), None);
        // A flipped byte is detected, the file deleted.
        let mut bad = tile_bytes(&tiles.binding(2), 2.0);
        let n = bad.len();
        bad[n - 3] ^= 0x40;
        tiles.put(2, &bad).unwrap();
        assert_eq!(tiles.get(2).unwrap(), None);
        assert_eq!(tiles.count(), 1);
        // Two tiles written (index 1 was good bytes), two removed: the count is the one left.
        assert_eq!(store.bytes(), good.len() as u64);
        assert_eq!(TileStore::open(&root).unwrap().bytes(), good.len() as u64);
        assert!(store.frame("../etc").is_err());
        assert_eq!(store.prune(Duration::from_secs(3600)).unwrap(), 0);
        assert_eq!(store.prune(Duration::ZERO).unwrap(), 1);
        assert_eq!(tiles.count(), 0);
        store.remove_empty().unwrap();
        assert!(!root.exists());
    }

    #[test]
    fn the_oldest_frames_are_evicted_first_and_the_kept_one_never() {
        let root = scratch("evict");
        let store = TileStore::open(&root).unwrap();
        let keys: Vec<String> = ["aa", "bb", "cc"].iter().map(|k| k.repeat(32)).collect();
        let mut sizes = Vec::new();
        for key in &keys {
            let tiles = store.frame(key).unwrap();
            let bytes = tile_bytes(&tiles.binding(0), 1.0);
            tiles.put(0, &bytes).unwrap();
            sizes.push(bytes.len() as u64);
            // Distinct modification times.
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(store.bytes(), sizes.iter().sum::<u64>());
        // Room for one frame, keeping the oldest: the middle one goes, then the newest.
        let removed = store.evict_oldest(Some(&keys[0]), sizes[0]).unwrap();
        assert_eq!(removed, 2);
        assert_eq!(store.bytes(), sizes[0]);
        assert_eq!(store.frame(&keys[0]).unwrap().count(), 1);
        assert_eq!(store.frame(&keys[1]).unwrap().count(), 0);
        // Nothing to keep: the last one goes too.
        assert_eq!(store.evict_oldest(None, 0).unwrap(), 1);
        assert_eq!(store.bytes(), 0);
        let _ = std::fs::remove_dir_all(&root);
    }
}
