//! Shared engine tables kept between processes (issue 17): the [`TableStore`] the engine is
//! given, backed by the product [`Cache`]. A table is a spectral EXR like any product, so it is
//! written atomically, carries the whole-file blake3 checksum, is verified on every load (a
//! corrupt file is deleted and reported as a miss, and the engine rebuilds the table), and counts
//! in the cache's disk budget and LRU. Tables are stored uncompressed: they are read far more
//! often than written and zip would dominate the load time.

use super::cache::Cache;
use super::exr::{encode_exr_with, ExrCompression};
use crate::atmosphere::shared::TableStore;
use crate::store::SpectralImage;
use std::sync::Arc;

/// The table store of the CLI, the server and `bake`: entries of the product cache.
pub struct CacheTableStore {
    cache: Arc<Cache>,
}

impl CacheTableStore {
    pub fn new(cache: Arc<Cache>) -> Self {
        Self { cache }
    }
}

impl TableStore for CacheTableStore {
    fn load(&self, key: &str) -> Option<SpectralImage> {
        match self.cache.get_image(key) {
            Ok(image) => image,
            Err(e) => {
                tracing::warn!(key, error = %e, "shared table unreadable; rebuilding");
                None
            }
        }
    }

    fn save(&self, key: &str, table: &SpectralImage) {
        // The cache accepts only files that carry their own key.
        let mut bound = table.clone();
        let stored = bound
            .set_attribute(super::layout::ATTR_CACHE_KEY, key)
            .map_err(|e| e.to_string())
            .and_then(|()| encode_exr_with(&bound, ExrCompression::None).map_err(|e| e.to_string()))
            .and_then(|bytes| self.cache.put_bytes(key, bytes).map_err(|e| e.to_string()));
        if let Err(e) = stored {
            tracing::warn!(key, error = %e, "shared table not stored");
        }
    }
}

/// The table store in the configured cache directory (`settings.cache`, the server's cache), or
/// `None` with a warning when that directory cannot be opened (tables are then built in-process).
pub fn open_table_store(settings: &crate::config::Settings) -> Option<Arc<dyn TableStore>> {
    let config = super::CacheConfig::new(
        &settings.cache.dir,
        settings.cache.disk_budget_bytes,
        settings.cache.memory_budget_bytes,
    );
    match Cache::open(config) {
        Ok(cache) => Some(Arc::new(CacheTableStore::new(Arc::new(cache)))),
        Err(e) => {
            tracing::warn!(dir = %settings.cache.dir.display(), error = %e, "table cache unavailable; building tables in-process");
            None
        }
    }
}
