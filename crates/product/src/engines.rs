//! The engine of every product path (the server, the CLI's product commands and `bake`), built on
//! the store's table store so all of them share one set of stored precise tables.

use std::sync::Arc;

use skybake_engine::engine::Engine;
use skybake_store::tables::CacheTableStore;
use skybake_store::{Cache, CacheConfig};

/// The engine of the server: precise tables are loaded from and saved to its product cache.
pub fn engine_with_cache(cache: Arc<Cache>) -> Engine {
    Engine::with_table_store(Arc::new(CacheTableStore::new(cache)))
}

/// The engine of the CLI's product commands and `bake`: precise tables are loaded from and saved
/// to the configured cache directory (`settings.cache`, the server's cache), opened on first use.
pub fn engine_for_settings(settings: &crate::config::Settings) -> Engine {
    Engine::with_table_store(Arc::new(CacheTableStore::lazy(CacheConfig::new(
        &settings.cache.dir,
        settings.cache.disk_budget_bytes,
        settings.cache.memory_budget_bytes,
    ))))
}
