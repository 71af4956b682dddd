//! Tiles of a product computed piece by piece (DESIGN.md "Storage": large renders compute and
//! cache tile by tile, so a crash loses at most the tiles in flight and a rerun resumes).
//!
//! Layout: `<root>/<first 2 hex of key>/<key>/tile-<index:05>.exr`, one spectral EXR per tile,
//! each written atomically ([`write_atomic`]) with its whole-file checksum and the attribute
//! [`ATTR_TILE_OF`] = `<key>/<index>` binding it to its place. A read verifies both; a tile that
//! fails is deleted and reported as absent (recomputed, never used). The finished product goes to
//! the [`super::Cache`] and its tiles are then removed ([`FrameTiles::remove_all`]); tiles of a
//! render that never finishes stay until [`TileStore::prune`] removes directories older than a
//! given age. Keys are checked like cache keys (64 lowercase hex digits), so no request text
//! becomes part of a path. Tile bytes are not counted in the cache's disk budget: at most one
//! unfinished frame per computation slot (plus abandoned ones until pruned) sits here.

use super::atomic::{is_temp_file_name, write_atomic};
use super::cache::is_valid_key;
use super::exr::header_text_attribute;
use super::{checksum, StoreError};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// Header attribute binding a tile file to `<key>/<index>`.
pub const ATTR_TILE_OF: &str = "skybakeTileOf";

/// Most tiles of one product (a 16 Mi-pixel frame in 64×64 tiles has 4096).
pub const MAX_TILES: usize = 1 << 16;

/// The tile directory root (usually `<cache dir>/tiles`).
#[derive(Debug, Clone)]
pub struct TileStore {
    root: PathBuf,
}

/// The tiles of one product (one cache key).
#[derive(Debug, Clone)]
pub struct FrameTiles {
    dir: PathBuf,
    key: String,
}

impl TileStore {
    /// Opens (creating) the tile root and deletes temporary files left by a crash.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(root).map_err(|e| StoreError::io(root, e))?;
        let store = Self {
            root: root.to_path_buf(),
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
        Ok(store)
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
        let mut removed = 0;
        for dir in self.frame_dirs()? {
            let newest = std::fs::read_dir(&dir)
                .into_iter()
                .flatten()
                .flatten()
                .filter_map(|e| e.metadata().ok()?.modified().ok())
                .max();
            let stale = newest.is_none_or(|t| now.duration_since(t).unwrap_or_default() >= age);
            if stale && std::fs::remove_dir_all(&dir).is_ok() {
                removed += 1;
            }
        }
        Ok(removed)
    }
}

impl FrameTiles {
    fn path(&self, index: usize) -> PathBuf {
        self.dir.join(format!("tile-{index:05}.exr"))
    }

    /// The value of [`ATTR_TILE_OF`] for tile `index`.
    pub fn binding(&self, index: usize) -> String {
        format!("{}/{index}", self.key)
    }

    /// The verified bytes of tile `index`, or `None` when it is absent. A file that fails its
    /// checksum or carries another binding is deleted and reported as absent.
    pub fn get(&self, index: usize) -> Result<Option<Vec<u8>>, StoreError> {
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
        let bytes = std::fs::read(&path).map_err(|e| StoreError::io(&path, e))?;
        let bound = checksum::verify(&bytes).is_ok()
            && header_text_attribute(&bytes, ATTR_TILE_OF)
                .ok()
                .flatten()
                .is_some_and(|b| b == self.binding(index));
        if bound {
            Ok(Some(bytes))
        } else {
            tracing::warn!(path = %path.display(), "tile failed verification; recomputing it");
            remove_any(&path);
            Ok(None)
        }
    }

    /// Stores tile `index` (EXR bytes carrying [`ATTR_TILE_OF`] = [`Self::binding`]) atomically.
    pub fn put(&self, index: usize, bytes: &[u8]) -> Result<(), StoreError> {
        if index >= MAX_TILES {
            return Err(
                crate::Error::out_of_range("tile", index, format!("0..{MAX_TILES}")).into(),
            );
        }
        write_atomic(&self.path(index), bytes)
    }

    /// Number of tile files present (verified or not).
    pub fn count(&self) -> usize {
        std::fs::read_dir(&self.dir)
            .into_iter()
            .flatten()
            .flatten()
            .filter(|e| {
                let n = e.file_name().to_string_lossy().into_owned();
                n.starts_with("tile-") && n.ends_with(".exr")
            })
            .count()
    }

    /// Removes every tile of this product (after the assembled product went to the cache).
    pub fn remove_all(&self) -> Result<(), StoreError> {
        match std::fs::remove_dir_all(&self.dir) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(StoreError::io(&self.dir, e)),
        }
    }
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
    use crate::store::{encode_exr, SpectralImage};

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
        assert!(store.frame("../etc").is_err());
        assert_eq!(store.prune(Duration::from_secs(3600)).unwrap(), 0);
        assert_eq!(store.prune(Duration::ZERO).unwrap(), 1);
        assert_eq!(tiles.count(), 0);
        store.remove_empty().unwrap();
        assert!(!root.exists());
    }
}
