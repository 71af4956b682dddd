//! The HTTP service (DESIGN.md "Interfaces"): an axum router over the engine and the product cache.
//!
//! - [`problem`]: RFC 9457 problem+json errors.
//! - [`extract`]: the query and JSON-body extractors (the only place requests are parsed).
//! - [`routes`]: the router, one module per concern (products, plan, jobs, operations).
//! - [`metrics`]: Prometheus text.
//! - [`openapi`]: the route table and the OpenAPI document generated from it.
//! - [`server`]: binding, graceful shutdown, the `healthcheck` client.
//!
//! A product request is answered from, in order: the rendered-response memory cache, the product
//! cache (memory LRU, then verified EXR files on disk), or one engine computation shared by all
//! identical requests in flight (single flight), run on a blocking thread behind a semaphore sized
//! to the cores.

pub mod extract;
pub mod metrics;
pub mod openapi;
pub mod problem;
pub mod server;
pub mod viewer;

mod responses;
mod routes;

use crate::config::Settings;
use crate::engine::Engine;
use crate::product::{Format, ProductKind, ProductRequest};
use crate::store::{Cache, CacheConfig};
use bytes::Bytes;
use metrics::Metrics;
use problem::ApiError;
use responses::ResponseCache;
use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use tokio::sync::Semaphore;

pub use routes::app;

/// A computation in flight: its result, once published.
type Flight = tokio::sync::watch::Receiver<Option<Result<Arc<[u8]>, ApiError>>>;

/// Where a response's artifact came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// The rendered-response memory cache.
    Response,
    /// The product cache (memory or disk).
    Cache,
    /// Computed for this request (or joined an identical computation in flight).
    Computed,
}

impl Source {
    pub fn header(self) -> &'static str {
        match self {
            Source::Response | Source::Cache => "hit",
            Source::Computed => "miss",
        }
    }
}

/// Shared state of the service: settings, engine, cache, metrics, jobs.
#[derive(Clone)]
pub struct AppState {
    inner: Arc<Inner>,
}

struct Inner {
    settings: Settings,
    engine: Engine,
    cache: Arc<Cache>,
    metrics: Metrics,
    compute: Semaphore,
    flights: Mutex<HashMap<String, Flight>>,
    responses: Mutex<ResponseCache>,
    jobs: crate::job::run::Jobs,
}

impl AppState {
    /// Opens the cache at `settings.cache.dir` and loads persisted jobs (call
    /// [`AppState::start_job_workers`] inside a runtime to run them).
    pub fn new(settings: Settings) -> Result<Self, ApiError> {
        let cache = Arc::new(Cache::open(CacheConfig::new(
            &settings.cache.dir,
            settings.cache.disk_budget_bytes,
            settings.cache.memory_budget_bytes,
        ))?);
        let jobs = crate::job::run::Jobs::open(
            &settings.cache.dir.join("jobs"),
            crate::product::params::Defaults::from_settings(&settings),
        )?;
        Ok(Self {
            inner: Arc::new(Inner {
                compute: Semaphore::new(settings.compute_threads()),
                responses: Mutex::new(ResponseCache::new(settings.cache.response_budget_bytes)),
                settings,
                // Precise tables persist in the same cache (one disk budget) across restarts.
                engine: crate::store::tables::engine_with_cache(cache.clone()),
                cache,
                metrics: Metrics::default(),
                flights: Mutex::new(HashMap::new()),
                jobs,
            }),
        })
    }

    pub fn settings(&self) -> &Settings {
        &self.inner.settings
    }

    pub fn engine(&self) -> &Engine {
        &self.inner.engine
    }

    pub fn cache(&self) -> &Cache {
        &self.inner.cache
    }

    pub fn metrics(&self) -> &Metrics {
        &self.inner.metrics
    }

    pub fn jobs(&self) -> &crate::job::run::Jobs {
        &self.inner.jobs
    }

    /// Starts the job workers (`settings.jobs.workers` tasks) on the current runtime.
    pub fn start_job_workers(&self) {
        crate::job::run::start_workers(self, self.settings().jobs.workers);
    }

    /// Runs blocking work on the blocking pool; a panic there becomes a 500, never a crash.
    pub async fn blocking<T: Send + 'static>(
        f: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        tokio::task::spawn_blocking(f)
            .await
            .map_err(|e| ApiError::Internal(format!("worker failed: {e}")))?
    }

    /// The artifact (verified EXR bytes) of `req`: from the cache, or computed once for all identical
    /// requests in flight.
    pub async fn artifact(
        &self,
        req: &ProductRequest,
        key: &str,
    ) -> Result<(Arc<[u8]>, Source), ApiError> {
        let lookup = {
            let (s, k) = (self.clone(), key.to_string());
            Self::blocking(move || Ok(s.inner.cache.get(&k)?)).await?
        };
        if let Some(bytes) = lookup {
            return Ok((bytes, Source::Cache));
        }
        // Join the computation in flight for this key, or start one. The computation runs on a
        // task of its own that publishes its result and leaves the map, so a waiter that times out
        // or disconnects neither cancels it nor causes a second one.
        let (mut rx, leader) = {
            let mut flights = self.inner.flights.lock().unwrap_or_else(|e| e.into_inner());
            match flights.get(key) {
                Some(rx) => (rx.clone(), false),
                None => {
                    let (tx, rx) = tokio::sync::watch::channel(None);
                    flights.insert(key.to_string(), rx.clone());
                    let (state, req, key) = (self.clone(), req.clone(), key.to_string());
                    tokio::spawn(async move {
                        let result = state.compute(req, key.clone()).await;
                        // Publish, then leave the map (the product is already in the cache).
                        let _ = tx.send(Some(result));
                        let mut flights = state
                            .inner
                            .flights
                            .lock()
                            .unwrap_or_else(|e| e.into_inner());
                        flights.remove(&key);
                    });
                    (rx, true)
                }
            }
        };
        if !leader {
            self.inner
                .metrics
                .single_flight_joins
                .fetch_add(1, Ordering::Relaxed);
        }
        let result = rx
            .wait_for(Option::is_some)
            .await
            .map_err(|_| ApiError::Internal("computation task ended without a result".into()))?
            .clone()
            .unwrap_or_else(|| Err(ApiError::Internal("no result".into())));
        result.map(|b| (b, Source::Computed))
    }

    /// Computes `req` (behind the compute semaphore, on a blocking thread) and stores it.
    async fn compute(&self, req: ProductRequest, key: String) -> Result<Arc<[u8]>, ApiError> {
        let _permit = self
            .inner
            .compute
            .acquire()
            .await
            .map_err(|_| ApiError::Unavailable("shutting down".into()))?;
        let s = self.clone();
        Self::blocking(move || {
            // Another flight may have finished between our cache miss and starting this one.
            // (`contains` first, so the common case does not count a second miss.)
            if s.inner.cache.contains(&key) {
                if let Some(bytes) = s.inner.cache.get(&key)? {
                    return Ok(bytes);
                }
            }
            let m = &s.inner.metrics;
            m.computed(req.kind().name());
            m.compute_in_flight.fetch_add(1, Ordering::Relaxed);
            let image = req.compute(&s.inner.engine);
            m.compute_in_flight.fetch_sub(1, Ordering::Relaxed);
            Ok(s.inner.cache.put_image(&key, &image?)?)
        })
        .await
    }

    /// The response body of `req` in its format, and where it came from.
    pub async fn body(&self, req: &ProductRequest) -> Result<(Bytes, Source, String), ApiError> {
        let key = req.cache_key();
        if let Some(b) = self.response_get(&key, req.format) {
            self.inner
                .metrics
                .response_cache_hits
                .fetch_add(1, Ordering::Relaxed);
            return Ok((b, Source::Response, key));
        }
        let (artifact, source) = self.artifact(req, &key).await?;
        let body = match Self::render_body(req, artifact).await {
            Ok(body) => body,
            Err(ApiError::Internal(why)) => {
                // A stored artifact that passed its checksum but does not render is a server
                // fault, never the request's: drop it and compute the product again (a second
                // failure is a 500).
                tracing::warn!(key = %key, error = %why, "malformed cached artifact; recomputing");
                self.inner.cache.remove(&key)?;
                let (artifact, _) = self.artifact(req, &key).await?;
                Self::render_body(req, artifact).await?
            }
            Err(e) => return Err(e),
        };
        if let Ok(mut r) = self.inner.responses.lock() {
            r.put(&key, req.format, body.clone());
        }
        Ok((body, source, key))
    }

    /// The body of `req` in its format, rendered from `artifact` (EXR bytes).
    async fn render_body(req: &ProductRequest, artifact: Arc<[u8]>) -> Result<Bytes, ApiError> {
        match req.format {
            Format::Exr => Ok(Bytes::copy_from_slice(&artifact)),
            format => {
                let product = req.kind();
                Self::blocking(move || {
                    let image = crate::store::decode_exr(&artifact)
                        .map_err(|e| ApiError::Internal(format!("cached artifact: {e}")))?;
                    Ok(Bytes::from(crate::product::render(
                        product, format, &image,
                    )?))
                })
                .await
            }
        }
    }

    fn response_get(&self, key: &str, format: Format) -> Option<Bytes> {
        self.inner.responses.lock().ok()?.get(key, format)
    }

    /// Drops everything the rendered-response cache holds (tests; after a cache directory change).
    pub fn clear_responses(&self) {
        if let Ok(mut r) = self.inner.responses.lock() {
            r.clear();
        }
    }

    /// The validated request of `product` from raw parameters, with the configured defaults.
    pub fn request(
        &self,
        product: ProductKind,
        p: crate::product::params::RequestParams,
    ) -> Result<ProductRequest, ApiError> {
        Ok(ProductRequest::from_params(
            product,
            &self.jobs().defaults().apply(p),
        )?)
    }
}

/// Jobs produce their items through the service's cache: cached items are hits, the others are
/// computed once (joining identical requests in flight) and stored.
impl crate::job::run::Producer for AppState {
    async fn produce(&self, req: ProductRequest) -> Result<(), crate::job::JobError> {
        let key = req.cache_key();
        self.artifact(&req, &key)
            .await
            .map(|_| ())
            .map_err(|e| match e {
                ApiError::Param(e) => crate::job::JobError::Param(e),
                other => crate::job::JobError::Failure(other.to_string()),
            })
    }

    fn jobs(&self) -> &crate::job::run::Jobs {
        &self.inner.jobs
    }
}
