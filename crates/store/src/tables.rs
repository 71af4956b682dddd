//! Shared engine tables kept between processes (a later process loads a table instead of building it): the [`TableStore`] the engine is
//! given, backed by the product [`Cache`]. A table is a spectral EXR like any product, so it is
//! written atomically, carries the whole-file blake3 checksum and its own key
//! (`skybakeCacheKey`), is verified on every load (a corrupt file is deleted and reported as a
//! miss, and the engine rebuilds the table), and counts in the cache's disk budget and LRU.
//! Tables are stored uncompressed: they are read far more often than written and zip would
//! dominate the load time.

use super::bucket::Bucket;
use super::cache::{Cache, CacheConfig};
use super::exr::{encode_exr_with, ExrCompression};
use skybake_physics::atmosphere::shared::{TableLoad, TableStore};
use skybake_physics::image::SpectralImage;
use std::sync::{Arc, OnceLock};

/// The table store of the CLI, the server and `bake`: entries of the product cache.
pub struct CacheTableStore {
    /// The cache, once opened (`None` inside: it could not be opened; tables are built instead).
    cache: OnceLock<Option<Arc<Cache>>>,
    /// Where to open it on first use ([`Self::lazy`]).
    config: Option<CacheConfig>,
    /// The shared tier of the cache opened on first use.
    bucket: Option<Arc<Bucket>>,
}

impl CacheTableStore {
    /// A store in an open cache (the server's: one disk budget for products and tables).
    pub fn new(cache: Arc<Cache>) -> Self {
        Self {
            cache: OnceLock::from(Some(cache)),
            config: None,
            bucket: None,
        }
    }

    /// A store that opens the cache at `config` when a table is first loaded or saved, so a
    /// process that needs no stored table (fast method, `plan`) neither creates nor scans it.
    pub fn lazy(config: CacheConfig) -> Self {
        Self {
            cache: OnceLock::new(),
            config: Some(config),
            bucket: None,
        }
    }

    /// [`Self::lazy`] with `bucket` as the cache's shared tier ([`Cache::open_shared`]).
    pub fn lazy_shared(config: CacheConfig, bucket: Arc<Bucket>) -> Self {
        Self {
            bucket: Some(bucket),
            ..Self::lazy(config)
        }
    }

    fn cache(&self) -> Option<&Arc<Cache>> {
        self.cache
            .get_or_init(|| {
                let config = self.config.clone()?;
                let dir = config.dir.clone();
                let opened = match &self.bucket {
                    Some(bucket) => Cache::open_shared(config, bucket.clone()),
                    None => Cache::open(config),
                };
                match opened {
                    Ok(cache) => Some(Arc::new(cache)),
                    Err(e) => {
                        tracing::warn!(dir = %dir.display(), error = %e, "table cache unavailable; building tables in-process");
                        None
                    }
                }
            })
            .as_ref()
    }
}

impl TableStore for CacheTableStore {
    fn load(&self, key: &str) -> TableLoad {
        let Some(cache) = self.cache() else {
            return TableLoad::Absent;
        };
        // Listed in the cache's index but not returned: the file failed verification and was
        // removed (or, rarely, was evicted in between).
        let listed = cache.contains(key);
        match cache.get_image(key) {
            Ok(Some(image)) => TableLoad::Found(image),
            Ok(None) if listed => TableLoad::Rejected,
            Ok(None) => TableLoad::Absent,
            Err(e) => {
                tracing::warn!(key, error = %e, "shared table unreadable; rebuilding");
                TableLoad::Absent
            }
        }
    }

    fn save(&self, key: &str, table: &SpectralImage) {
        let Some(cache) = self.cache() else {
            return;
        };
        // The cache accepts only files that carry their own key.
        let mut bound = table.clone();
        let stored = bound
            .set_attribute(super::layout::ATTR_CACHE_KEY, key)
            .map_err(|e| e.to_string())
            .and_then(|()| encode_exr_with(&bound, ExrCompression::None).map_err(|e| e.to_string()))
            .and_then(|bytes| cache.put_bytes(key, bytes).map_err(|e| e.to_string()));
        if let Err(e) = stored {
            tracing::warn!(key, error = %e, "shared table not stored");
        }
    }
}
