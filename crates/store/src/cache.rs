//! Content-addressed product cache: files `<dir>/<first 2 hex>/<key>.exr`, where the key is the
//! blake3 hash of the canonical spec and the engine version ([`cache_key`]). Only 64-digit lowercase
//! hex keys are accepted, so no request string ever becomes part of a path.
//!
//! Two entry kinds ([`EntryKind`]) share the index, the budgets, the memory tier and the bucket:
//! product images (spectral OpenEXR, `<key>.exr`; [`Cache::get`], [`Cache::put_image`],
//! [`Cache::put_bytes`]) and blobs (any bytes, e.g. a texture bundle's manifest and textures,
//! `<key>.blob` in [`super::blob`]'s layout; [`Cache::get_blob`], [`Cache::put_blob`]). Every
//! guarantee below holds for both.
//!
//! - Integrity: every file carries its whole-file blake3 checksum (see [`super::checksum`]); a read
//!   verifies it, and a file that fails is counted, deleted and reported as a miss, never served.
//! - Binding: every file carries the key it was stored under (header attribute
//!   [`ATTR_CACHE_KEY`]); a read checks it, so a valid file copied or renamed under another key is
//!   counted in [`CacheStats::key_mismatches`], deleted and reported as a miss, never served.
//! - Robustness: something other than a regular file at an entry's path (a directory, a symlink) is
//!   removed and treated as a miss; an entry larger than the whole disk budget is returned to the
//!   caller but not stored ([`CacheStats::not_stored`]).
//! - Size: the files on disk keep to a byte budget, evicting the least recently used. Access order
//!   lives in memory and is rebuilt from file modification times when the cache is opened (a disk
//!   hit refreshes the file's mtime), so a restarted service reuses and ages the same files.
//! - Memory: verified file bytes are also kept in an in-memory LRU with its own byte budget, so a hot
//!   entry is served without touching the disk.
//! - Shared tier: a cache opened with [`Cache::open_shared`] keeps every entry in a bucket too
//!   (`<prefix>/cache/<first 2 hex>/<key>.exr`), where other processes and machines find it; the
//!   directory and memory tiers stay in front of it. A bucket object is verified like a file
//!   (checksum, then key binding): one that fails is counted, deleted and reported as a miss. A
//!   bucket that stays unreachable after the retries is [`StoreError::Unavailable`].
//! - Concurrency: all methods take `&self`; the index sits behind a mutex that is never held while
//!   reading or writing file contents. Methods block on disk I/O: call them from
//!   `tokio::task::spawn_blocking`. One process owns a cache directory.

use std::collections::HashMap;
use std::fs;
use std::io::ErrorKind;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::SystemTime;

use serde::Serialize;

use super::atomic::{is_temp_file_name, write_atomic};
use super::blob::{encode_blob, verify_blob, BlobRejection};
use super::bucket::Bucket;
use super::exr::{
    decode_exr, encode_exr_with, header_text_attribute, read_bounded, ExrCompression,
};
use super::layout::ATTR_CACHE_KEY;
use super::lru::LruIndex;
use super::{checksum, SpectralImage, StoreError};

/// Length of a cache key in hex digits (a blake3 hash).
pub const KEY_LEN: usize = 64;
/// What a cache entry holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum EntryKind {
    /// A product image: spectral OpenEXR with its checksum and key attributes.
    Image,
    /// Any bytes in the blob layout ([`super::blob`]): key and checksum in a text header.
    Blob,
}

impl EntryKind {
    const ALL: [EntryKind; 2] = [EntryKind::Image, EntryKind::Blob];

    /// File name extension of entries of this kind.
    fn extension(self) -> &'static str {
        match self {
            EntryKind::Image => "exr",
            EntryKind::Blob => "blob",
        }
    }
}

/// A file on disk in the index: its kind and the generation of its last write, so a slow reader
/// that finds a corrupt file does not delete a newer one written meanwhile.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Indexed {
    generation: u64,
    kind: EntryKind,
}

/// True when `key` is 64 lowercase hexadecimal digits.
pub fn is_valid_key(key: &str) -> bool {
    key.len() == KEY_LEN && key.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

fn check_key(key: &str) -> Result<(), StoreError> {
    if is_valid_key(key) {
        Ok(())
    } else {
        Err(crate::Error::invalid(
            "cache_key",
            format!("must be {KEY_LEN} lowercase hexadecimal digits (a blake3 hash)"),
        )
        .into())
    }
}

/// An entry larger than the memory budget divided by this is kept on disk only (it would evict
/// most of the memory tier for itself).
pub const MEMORY_ENTRY_FRACTION: u64 = 8;

/// Where and how big the cache is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CacheConfig {
    /// Root directory; created if missing.
    pub dir: PathBuf,
    /// Most bytes of cache files on disk.
    pub disk_budget_bytes: u64,
    /// Most bytes of file contents held in memory (0 disables the memory tier).
    pub memory_budget_bytes: u64,
    /// Compression of files written by [`Cache::put_image`].
    pub compression: ExrCompression,
}

impl CacheConfig {
    /// A configuration with the given directory and budgets, and ZIP compression.
    pub fn new(dir: impl Into<PathBuf>, disk_budget_bytes: u64, memory_budget_bytes: u64) -> Self {
        Self {
            dir: dir.into(),
            disk_budget_bytes,
            memory_budget_bytes,
            compression: ExrCompression::Zip,
        }
    }
}

/// Counters and sizes, for `/metrics` and logs. Counters count since [`Cache::open`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct CacheStats {
    /// Lookups answered (memory or disk).
    pub hits: u64,
    /// Lookups answered from memory.
    pub memory_hits: u64,
    /// Lookups answered from disk (after verification).
    pub disk_hits: u64,
    /// Lookups answered from the bucket (after verification; the entry is then kept on disk).
    pub bucket_hits: u64,
    /// Lookups not answered (absent, vanished or corrupt).
    pub misses: u64,
    /// Entries stored on disk (computed ones, and copies of bucket hits).
    pub puts: u64,
    /// Files deleted to keep to the disk budget.
    pub evictions: u64,
    /// Entries dropped from memory to keep to the memory budget.
    pub memory_evictions: u64,
    /// Files that failed verification (each deleted and reported as a miss).
    pub corrupt_detected: u64,
    /// Valid files found under a key other than the one they carry (each deleted, a miss).
    pub key_mismatches: u64,
    /// Entries returned but not stored: larger than the disk budget, or their path could not be
    /// cleared of something that is not a regular file.
    pub not_stored: u64,
    /// Cache files on disk.
    pub entries_on_disk: u64,
    /// Bytes of cache files on disk.
    pub bytes_on_disk: u64,
    /// Entries held in memory.
    pub entries_in_memory: u64,
    /// Bytes held in memory.
    pub bytes_in_memory: u64,
}

/// Shared mutable state, behind the cache's mutex.
struct State {
    /// Files on disk.
    disk: LruIndex<Indexed>,
    /// What [`Cache::get`] / [`Cache::get_blob`] return (image file bytes, blob payloads).
    memory: LruIndex<Arc<[u8]>>,
    /// Keys with writes in flight (count per key); never evicted or deleted while present.
    writing: HashMap<String, usize>,
    next_generation: u64,
    stats: CacheStats,
    /// Last access stamp written as a file mtime: strictly increasing, so the access order
    /// survives a restart even when the file system's own clock ticks coarsely.
    last_stamp: SystemTime,
    /// Bytes of the budget taken by other files under the cache directory (persisted jobs).
    reserved_bytes: u64,
}

impl State {
    /// A strictly increasing wall-clock stamp (at least 1 µs after the previous one).
    fn next_stamp(&mut self) -> SystemTime {
        let now = SystemTime::now();
        let min = self.last_stamp + std::time::Duration::from_micros(1);
        self.last_stamp = if now > min { now } else { min };
        self.last_stamp
    }
}

/// The content-addressed, size-bounded, verified product cache. See the module documentation.
pub struct Cache {
    config: CacheConfig,
    state: Mutex<State>,
    /// The shared tier behind the directory ([`Cache::open_shared`]).
    bucket: Option<Arc<Bucket>>,
}

impl std::fmt::Debug for Cache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cache")
            .field("config", &self.config)
            .field("stats", &self.stats())
            .finish()
    }
}

impl Cache {
    /// Opens (creating if needed) the cache at `config.dir`, indexes the files already there by
    /// modification time, deletes temporary files left by a crash, and evicts down to the budget.
    pub fn open(config: CacheConfig) -> Result<Self, StoreError> {
        fs::create_dir_all(&config.dir).map_err(|e| StoreError::io(&config.dir, e))?;
        let mut found: Vec<(SystemTime, String, u64, EntryKind)> = Vec::new();
        for shard in read_dir(&config.dir)? {
            let shard_name = shard.file_name().to_string_lossy().into_owned();
            let is_shard =
                shard_name.len() == 2 && shard_name.bytes().all(|b| b.is_ascii_hexdigit());
            if !is_shard || !shard.path().is_dir() {
                continue;
            }
            for file in read_dir(&shard.path())? {
                let name = file.file_name().to_string_lossy().into_owned();
                if is_temp_file_name(&name) {
                    // Best effort: a leftover that cannot be deleted is only wasted space.
                    let _ = fs::remove_file(file.path());
                    continue;
                }
                let Some((key, kind)) = EntryKind::ALL.iter().find_map(|&kind| {
                    Some((name.strip_suffix(&format!(".{}", kind.extension()))?, kind))
                }) else {
                    continue;
                };
                if !is_valid_key(key) || key[..2] != shard_name {
                    continue;
                }
                let meta = file
                    .metadata()
                    .map_err(|e| StoreError::io(file.path(), e))?;
                if !meta.is_file() {
                    continue;
                }
                let mtime = meta.modified().unwrap_or(SystemTime::UNIX_EPOCH);
                found.push((mtime, key.to_string(), meta.len(), kind));
            }
        }
        found.sort();

        let mut state = State {
            disk: LruIndex::new(),
            memory: LruIndex::new(),
            writing: HashMap::new(),
            next_generation: 0,
            stats: CacheStats::default(),
            last_stamp: SystemTime::UNIX_EPOCH,
            reserved_bytes: 0,
        };
        for (mtime, key, size_bytes, kind) in found {
            state.last_stamp = state.last_stamp.max(mtime);
            state.next_generation += 1;
            let generation = state.next_generation;
            state
                .disk
                .insert(&key, size_bytes, Indexed { generation, kind });
        }
        let cache = Self {
            config,
            state: Mutex::new(state),
            bucket: None,
        };
        {
            let mut state = cache.lock();
            cache.evict_disk(&mut state);
            cache.refresh_sizes(&mut state);
        }
        Ok(cache)
    }

    /// [`Cache::open`] with `bucket` as the shared tier behind the directory: a miss on disk looks
    /// in the bucket, and every entry stored goes to the bucket too.
    pub fn open_shared(config: CacheConfig, bucket: Arc<Bucket>) -> Result<Self, StoreError> {
        let mut cache = Self::open(config)?;
        cache.bucket = Some(bucket);
        Ok(cache)
    }

    /// The shared tier, if any.
    pub fn bucket(&self) -> Option<&Arc<Bucket>> {
        self.bucket.as_ref()
    }

    /// The configuration this cache was opened with.
    pub fn config(&self) -> &CacheConfig {
        &self.config
    }

    /// The file path of `key` (`<dir>/<first 2 hex>/<key>.exr`); refuses keys that are not 64
    /// lowercase hex digits.
    pub fn path_for(&self, key: &str) -> Result<PathBuf, StoreError> {
        self.path_of(key, EntryKind::Image)
    }

    /// The file path of `key` as an entry of `kind`.
    pub fn path_of(&self, key: &str, kind: EntryKind) -> Result<PathBuf, StoreError> {
        check_key(key)?;
        Ok(self
            .config
            .dir
            .join(&key[..2])
            .join(format!("{key}.{}", kind.extension())))
    }

    /// The verified EXR file bytes stored under `key`, or `None` on a miss. A file that fails its
    /// checksum is deleted, counted in [`CacheStats::corrupt_detected`] and reported as a miss.
    /// Errors only for an invalid key or an unexpected I/O failure (e.g. permissions).
    pub fn get(&self, key: &str) -> Result<Option<Arc<[u8]>>, StoreError> {
        self.get_kind(key, EntryKind::Image)
    }

    /// The verified payload of the blob stored under `key`, or `None` on a miss (also when `key`
    /// holds an image); otherwise as [`Self::get`].
    pub fn get_blob(&self, key: &str) -> Result<Option<Arc<[u8]>>, StoreError> {
        self.get_kind(key, EntryKind::Blob)
    }

    /// [`Self::get`] / [`Self::get_blob`].
    fn get_kind(&self, key: &str, kind: EntryKind) -> Result<Option<Arc<[u8]>>, StoreError> {
        let path = self.path_of(key, kind)?;
        let generation = {
            let mut state = self.lock();
            match state.disk.peek(key).copied() {
                Some(e) if e.kind != kind => {
                    state.stats.misses += 1;
                    return Ok(None);
                }
                _ => {}
            }
            if let Some(bytes) = state.memory.get(key).cloned() {
                state.disk.get(key);
                state.stats.hits += 1;
                state.stats.memory_hits += 1;
                return Ok(Some(bytes));
            }
            match state.disk.get(key).copied() {
                Some(e) => e.generation,
                None => {
                    drop(state);
                    return self.get_from_bucket(key, kind);
                }
            }
        };

        if !self.clear_non_file(&path) {
            // Something that is not a regular file sits at the path and could not be removed.
            self.forget_missing(key, generation);
            return Ok(None);
        }
        let bytes = match read_bounded(&path) {
            Ok(bytes) => bytes,
            Err(StoreError::Io { source, .. }) if source.kind() == ErrorKind::NotFound => {
                self.forget_missing(key, generation);
                return Ok(None);
            }
            Err(StoreError::Invalid(_)) => {
                self.discard_corrupt(key, &path, generation);
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        let bytes: Arc<[u8]> = match verify(kind, key, bytes) {
            Ok(served) => served,
            Err(Rejected::Corrupt(why)) => {
                tracing::warn!(key, error = %why, "corrupt cache file removed");
                self.discard_corrupt(key, &path, generation);
                return Ok(None);
            }
            Err(Rejected::ForeignKey(carried)) => {
                tracing::warn!(key, carried = ?carried, "cache file under a foreign key removed");
                self.lock().stats.key_mismatches += 1;
                self.discard(key, &path, generation);
                return Ok(None);
            }
        };
        let stamp = {
            let mut state = self.lock();
            state.stats.hits += 1;
            state.stats.disk_hits += 1;
            if state.disk.peek(key).map(|e| e.generation) == Some(generation) {
                self.remember_in_memory(&mut state, key, &bytes);
            }
            self.refresh_sizes(&mut state);
            state.next_stamp()
        };
        // Best effort: the mtime only carries the access order across restarts.
        let _ = fs::File::open(&path).and_then(|f| f.set_modified(stamp));
        Ok(Some(bytes))
    }

    /// The entry for `key` from the bucket (a miss without one), verified like a file; a hit is
    /// kept on disk and in memory.
    fn get_from_bucket(&self, key: &str, kind: EntryKind) -> Result<Option<Arc<[u8]>>, StoreError> {
        let Some(bucket) = &self.bucket else {
            self.lock().stats.misses += 1;
            return Ok(None);
        };
        let name = object_name_of(key, kind);
        let Some(file) = bucket.get(&name)? else {
            self.lock().stats.misses += 1;
            return Ok(None);
        };
        let file: Arc<[u8]> = file.into();
        let served = match verify(kind, key, file.to_vec()) {
            Ok(served) => served,
            Err(rejected) => {
                let corrupt = matches!(rejected, Rejected::Corrupt(_));
                let why = match rejected {
                    Rejected::Corrupt(why) => why,
                    Rejected::ForeignKey(carried) => format!("carries key {carried:?}"),
                };
                tracing::warn!(key, error = %why, "bucket object failed verification; removed");
                {
                    let mut state = self.lock();
                    state.stats.misses += 1;
                    if corrupt {
                        state.stats.corrupt_detected += 1;
                    } else {
                        state.stats.key_mismatches += 1;
                    }
                }
                bucket.delete(&name)?;
                return Ok(None);
            }
        };
        self.store_local(key, kind, &file, &served)?;
        let mut state = self.lock();
        state.stats.hits += 1;
        state.stats.bucket_hits += 1;
        Ok(Some(served))
    }

    /// The decoded image stored under `key`, or `None` on a miss; an entry that fails to decode is
    /// treated like a corrupt file.
    pub fn get_image(&self, key: &str) -> Result<Option<SpectralImage>, StoreError> {
        let Some(bytes) = self.get(key)? else {
            return Ok(None);
        };
        match decode_exr(&bytes) {
            Ok(image) => Ok(Some(image)),
            Err(e) => {
                tracing::warn!(key, error = %e, "undecodable cache entry removed");
                if let Some(bucket) = &self.bucket {
                    bucket.delete(&object_name(key))?;
                }
                let path = self.path_for(key)?;
                let generation = self.lock().disk.peek(key).map(|e| e.generation);
                if let Some(generation) = generation {
                    self.discard_corrupt(key, &path, generation);
                } else {
                    let mut state = self.lock();
                    state.memory.remove(key);
                    state.stats.corrupt_detected += 1;
                    self.refresh_sizes(&mut state);
                }
                Ok(None)
            }
        }
    }

    /// Encodes `image` (with the configured compression) and stores it under `key`; returns the file
    /// bytes (ready to serve). The file carries `key` in its [`ATTR_CACHE_KEY`] attribute: an image
    /// that already carries one must carry this key; one without gets it added.
    pub fn put_image(&self, key: &str, image: &SpectralImage) -> Result<Arc<[u8]>, StoreError> {
        check_key(key)?;
        let bytes: Arc<[u8]> = match image.attribute(ATTR_CACHE_KEY) {
            Some(carried) if carried == key => encode_exr_with(image, self.config.compression)?,
            Some(carried) => return Err(foreign_key(key, carried)),
            None => {
                let mut bound = image.clone();
                bound.set_attribute(ATTR_CACHE_KEY, key)?;
                encode_exr_with(&bound, self.config.compression)?
            }
        }
        .into();
        self.store(key, EntryKind::Image, &bytes, &bytes)?;
        Ok(bytes)
    }

    /// Stores EXR file bytes produced by [`super::encode_exr`] under `key` after decoding them in
    /// full, so only valid files enter the cache; they must carry `key` in [`ATTR_CACHE_KEY`].
    pub fn put_bytes(&self, key: &str, bytes: Vec<u8>) -> Result<Arc<[u8]>, StoreError> {
        check_key(key)?;
        let image = decode_exr(&bytes)?;
        match image.attribute(ATTR_CACHE_KEY) {
            Some(carried) if carried == key => {}
            carried => return Err(foreign_key(key, carried.unwrap_or("no key"))),
        }
        let bytes: Arc<[u8]> = bytes.into();
        self.store(key, EntryKind::Image, &bytes, &bytes)?;
        Ok(bytes)
    }

    /// Stores `payload` under `key` as a blob ([`super::blob`]: the file carries the key and a
    /// checksum); returns the payload (ready to serve).
    pub fn put_blob(&self, key: &str, payload: Vec<u8>) -> Result<Arc<[u8]>, StoreError> {
        check_key(key)?;
        let file: Arc<[u8]> = encode_blob(key, &payload).into();
        let payload: Arc<[u8]> = payload.into();
        self.store(key, EntryKind::Blob, &file, &payload)?;
        Ok(payload)
    }

    /// Deletes the entry for `key` (of either kind); returns whether there was one.
    pub fn remove(&self, key: &str) -> Result<bool, StoreError> {
        check_key(key)?;
        if let Some(bucket) = &self.bucket {
            for kind in EntryKind::ALL {
                bucket.delete(&object_name_of(key, kind))?;
            }
        }
        let mut state = self.lock();
        state.memory.remove(key);
        let mut found = state.disk.remove(key).is_some();
        self.refresh_sizes(&mut state);
        drop(state);
        for kind in EntryKind::ALL {
            let path = self.path_of(key, kind)?;
            match fs::remove_file(&path) {
                Ok(()) => found = true,
                Err(e) if e.kind() == ErrorKind::NotFound => {}
                Err(e) => return Err(StoreError::io(&path, e)),
            }
        }
        Ok(found)
    }

    /// True when the index lists `key` (without reading or verifying the file).
    pub fn contains(&self, key: &str) -> bool {
        is_valid_key(key) && self.lock().disk.peek(key).is_some()
    }

    /// A snapshot of the counters and sizes.
    pub fn stats(&self) -> CacheStats {
        self.lock().stats
    }

    /// Counts `bytes` of other files under the cache directory (persisted jobs) in the disk
    /// budget, evicting products to make room for them.
    pub fn set_reserved_bytes(&self, bytes: u64) {
        let mut state = self.lock();
        state.reserved_bytes = bytes;
        self.evict_disk(&mut state);
        self.refresh_sizes(&mut state);
    }

    /// Stores the entry file `file` of `kind` for `key` on disk ([`Self::store_local`]) and in
    /// the bucket, if any; `served` is what a read returns (kept in memory).
    fn store(
        &self,
        key: &str,
        kind: EntryKind,
        file: &Arc<[u8]>,
        served: &Arc<[u8]>,
    ) -> Result<(), StoreError> {
        self.store_local(key, kind, file, served)?;
        if let Some(bucket) = &self.bucket {
            bucket.put(&object_name_of(key, kind), file)?;
        }
        Ok(())
    }

    /// Writes `bytes` for `key` atomically, then indexes it and evicts to the budgets.
    /// An entry larger than the whole disk budget, or whose path cannot be cleared of a non-file,
    /// is not stored (and counted in [`CacheStats::not_stored`]); the caller still serves it.
    fn store_local(
        &self,
        key: &str,
        kind: EntryKind,
        bytes: &Arc<[u8]>,
        served: &Arc<[u8]>,
    ) -> Result<(), StoreError> {
        let path = self.path_of(key, kind)?;
        let room = self
            .config
            .disk_budget_bytes
            .saturating_sub(self.lock().reserved_bytes);
        if bytes.len() as u64 > room || !self.clear_non_file(&path) {
            tracing::warn!(key, bytes = bytes.len(), "product served but not stored");
            self.lock().stats.not_stored += 1;
            return Ok(());
        }
        *self.lock().writing.entry(key.to_string()).or_insert(0) += 1;
        let written = write_atomic(&path, bytes);
        let mut state = self.lock();
        if let Some(count) = state.writing.get_mut(key) {
            *count -= 1;
            if *count == 0 {
                state.writing.remove(key);
            }
        }
        written?;
        let stamp = state.next_stamp();
        let _ = fs::File::open(&path).and_then(|f| f.set_modified(stamp));
        state.next_generation += 1;
        let generation = state.next_generation;
        state
            .disk
            .insert(key, bytes.len() as u64, Indexed { generation, kind });
        state.stats.puts += 1;
        self.remember_in_memory(&mut state, key, served);
        self.evict_disk(&mut state);
        self.refresh_sizes(&mut state);
        Ok(())
    }

    /// Removes whatever sits at an entry's path when it is not a regular file (a directory or a
    /// symlink; the path is built from a validated key inside the cache directory). True when the
    /// path now holds a regular file or nothing.
    fn clear_non_file(&self, path: &Path) -> bool {
        let meta = match fs::symlink_metadata(path) {
            Ok(meta) => meta,
            Err(e) => return e.kind() == ErrorKind::NotFound,
        };
        if meta.is_file() {
            return true;
        }
        let removed = if meta.is_dir() {
            fs::remove_dir_all(path)
        } else {
            fs::remove_file(path)
        };
        match removed {
            Ok(()) => {
                tracing::warn!(path = %path.display(), "removed a non-file at a cache path");
                true
            }
            Err(e) => {
                tracing::warn!(path = %path.display(), error = %e, "cannot clear a cache path");
                false
            }
        }
    }

    /// Counts a miss for an entry whose file is gone and drops it from the index (unless a newer
    /// write replaced it meanwhile).
    fn forget_missing(&self, key: &str, generation: u64) {
        let mut state = self.lock();
        if state.disk.peek(key).map(|e| e.generation) == Some(generation) {
            state.disk.remove(key);
        }
        state.stats.misses += 1;
        self.refresh_sizes(&mut state);
    }

    /// Counts a corrupt file and deletes it, unless a newer write replaced it meanwhile.
    fn discard_corrupt(&self, key: &str, path: &Path, generation: u64) {
        self.lock().stats.corrupt_detected += 1;
        self.discard(key, path, generation);
    }

    /// Counts a miss and deletes the file, unless a newer write replaced it meanwhile.
    fn discard(&self, key: &str, path: &Path, generation: u64) {
        let mut state = self.lock();
        state.stats.misses += 1;
        state.memory.remove(key);
        if state.disk.peek(key).map(|e| e.generation) == Some(generation)
            && !state.writing.contains_key(key)
        {
            state.disk.remove(key);
            if let Err(e) = fs::remove_file(path) {
                if e.kind() != ErrorKind::NotFound {
                    tracing::warn!(path = %path.display(), error = %e, "cannot delete cache file");
                }
            }
        }
        self.refresh_sizes(&mut state);
    }

    fn remember_in_memory(&self, state: &mut State, key: &str, bytes: &Arc<[u8]>) {
        let size_bytes = bytes.len() as u64;
        // One entry may take at most 1/MEMORY_ENTRY_FRACTION of the memory tier, so a large
        // product is served from disk instead of flushing every other entry out of memory.
        if size_bytes > self.config.memory_budget_bytes / MEMORY_ENTRY_FRACTION {
            state.memory.remove(key);
            return;
        }
        state.memory.insert(key, size_bytes, Arc::clone(bytes));
        while state.memory.total_bytes() > self.config.memory_budget_bytes {
            if state.memory.pop_oldest_unpinned(|_| false).is_none() {
                break;
            }
            state.stats.memory_evictions += 1;
        }
    }

    /// Deletes least recently used files until the disk budget holds; keys being written are kept.
    fn evict_disk(&self, state: &mut State) {
        while state.disk.total_bytes() + state.reserved_bytes > self.config.disk_budget_bytes {
            let writing = &state.writing;
            let Some((key, _, indexed)) =
                state.disk.pop_oldest_unpinned(|k| writing.contains_key(k))
            else {
                break;
            };
            state.memory.remove(&key);
            state.stats.evictions += 1;
            if let Ok(path) = self.path_of(&key, indexed.kind) {
                if let Err(e) = fs::remove_file(&path) {
                    if e.kind() != ErrorKind::NotFound {
                        tracing::warn!(path = %path.display(), error = %e, "cannot evict cache file");
                    }
                }
            }
        }
    }

    fn refresh_sizes(&self, state: &mut State) {
        state.stats.entries_on_disk = state.disk.len() as u64;
        state.stats.bytes_on_disk = state.disk.total_bytes();
        state.stats.entries_in_memory = state.memory.len() as u64;
        state.stats.bytes_in_memory = state.memory.total_bytes();
    }

    /// Locks the state; a panic elsewhere while holding the lock leaves the index usable (every
    /// update keeps it consistent), so poisoning is ignored.
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// The bucket object of image `key` (a validated key).
pub fn object_name(key: &str) -> String {
    object_name_of(key, EntryKind::Image)
}

/// The bucket object of `key` as an entry of `kind`.
pub fn object_name_of(key: &str, kind: EntryKind) -> String {
    format!("cache/{}/{key}.{}", &key[..2], kind.extension())
}

/// Why an entry's bytes were refused.
enum Rejected {
    /// Damaged (checksum, header): counted in [`CacheStats::corrupt_detected`].
    Corrupt(String),
    /// Intact but carrying another key: counted in [`CacheStats::key_mismatches`].
    ForeignKey(Option<String>),
}

/// Checks entry file `bytes` of `kind` stored under `key` (checksum, then the key it carries);
/// returns what a read serves: the file of an image, the payload of a blob.
fn verify(kind: EntryKind, key: &str, bytes: Vec<u8>) -> Result<Arc<[u8]>, Rejected> {
    match kind {
        EntryKind::Image => {
            checksum::verify(&bytes).map_err(|e| Rejected::Corrupt(e.to_string()))?;
            match header_text_attribute(&bytes, ATTR_CACHE_KEY) {
                Ok(Some(carried)) if carried == key => Ok(bytes.into()),
                Ok(carried) => Err(Rejected::ForeignKey(carried)),
                Err(e) => Err(Rejected::Corrupt(e.to_string())),
            }
        }
        EntryKind::Blob => match verify_blob(&bytes, key) {
            Ok(payload) => Ok(payload.into()),
            Err(BlobRejection::Corrupt(e)) => Err(Rejected::Corrupt(e.to_string())),
            Err(BlobRejection::ForeignKey(carried)) => Err(Rejected::ForeignKey(Some(carried))),
        },
    }
}

fn foreign_key(key: &str, carried: &str) -> StoreError {
    crate::Error::invalid(
        "cache_key",
        format!("the image carries cache key {carried}, not {key}"),
    )
    .into()
}

fn read_dir(dir: &Path) -> Result<Vec<fs::DirEntry>, StoreError> {
    fs::read_dir(dir)
        .and_then(|entries| entries.collect::<Result<Vec<_>, _>>())
        .map_err(|e| StoreError::io(dir, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache_key;

    #[test]
    fn keys_are_blake3_hex_and_unambiguous() {
        let key = cache_key(r#"{"product":"sun"}"#, "0.1.0");
        assert!(is_valid_key(&key));
        assert_eq!(key, cache_key(r#"{"product":"sun"}"#, "0.1.0"));
        assert_ne!(key, cache_key(r#"{"product":"sun"}"#, "0.1.1"));
        assert_ne!(cache_key("ab", "c"), cache_key("a", "bc"));
    }

    #[test]
    fn only_lowercase_hex_keys_are_valid() {
        assert!(is_valid_key(&"0123456789abcdef".repeat(4)));
        for bad in [
            String::new(),
            "../".repeat(21) + "a",
            "A".repeat(64),
            "g".repeat(64),
            "a".repeat(63),
            "a".repeat(65),
            format!("{}/", "a".repeat(63)),
        ] {
            assert!(!is_valid_key(&bad), "{bad}");
        }
    }
}
