//! The engine of every product path (the server, the CLI's product commands and `bake`), built on
//! the store's table store so all of them share one set of stored precise tables.

use std::sync::Arc;

use skybake_engine::engine::Engine;
use skybake_store::tables::CacheTableStore;
use skybake_store::{Bucket, Cache, CacheConfig, RetryPolicy, StoreError};

/// The engine of the server: precise tables are loaded from and saved to its product cache.
pub fn engine_with_cache(cache: Arc<Cache>) -> Engine {
    Engine::with_table_store(Arc::new(CacheTableStore::new(cache)))
}

/// The bucket of `settings.cache.url` (opened with the AWS environment variables), or `None`
/// when the cache is the directory alone.
pub fn shared_bucket(
    settings: &crate::config::Settings,
) -> Result<Option<Arc<Bucket>>, StoreError> {
    let url = settings.cache.url.trim();
    if url.is_empty() {
        return Ok(None);
    }
    Ok(Some(Arc::new(Bucket::open(
        url,
        &[],
        RetryPolicy::default(),
    )?)))
}

/// The engine of the CLI's product commands and `bake`: precise tables are loaded from and saved
/// to the configured cache directory (`settings.cache`, the server's cache), opened on first use,
/// and the configured bucket behind it; a bucket that cannot be opened leaves the directory alone
/// (tables are only a head start) with a warning.
pub fn engine_for_settings(settings: &crate::config::Settings) -> Engine {
    let config = CacheConfig::new(
        &settings.cache.dir,
        settings.cache.disk_budget_bytes,
        settings.cache.memory_budget_bytes,
    );
    let store = match shared_bucket(settings) {
        Ok(Some(bucket)) => CacheTableStore::lazy_shared(config, bucket),
        Ok(None) => CacheTableStore::lazy(config),
        Err(e) => {
            tracing::warn!(error = %e, "cache bucket unavailable; tables stay in the directory");
            CacheTableStore::lazy(config)
        }
    };
    Engine::with_table_store(Arc::new(store))
}
