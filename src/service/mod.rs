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
use crate::render::FrameRequest;
use crate::store::TileStore;
use crate::store::{Cache, CacheConfig};
use bytes::Bytes;
use metrics::Metrics;
use problem::ApiError;
use responses::ResponseCache;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::Semaphore;

pub use routes::app;

/// A computation in flight: its result, once published, and how many requests wait for it (a
/// frame render stops at its next tile when none is left).
#[derive(Clone)]
struct Flight {
    rx: tokio::sync::watch::Receiver<Option<Result<Arc<[u8]>, ApiError>>>,
    waiters: Arc<AtomicUsize>,
}

/// What a flight computes: a product of the parameter table or a cloud frame.
#[derive(Clone)]
pub(crate) enum Work {
    Product(Box<ProductRequest>),
    Frame(Arc<FrameRequest>),
}

impl Work {
    fn name(&self) -> &'static str {
        match self {
            Work::Product(r) => r.kind().name(),
            Work::Frame(_) => "frame",
        }
    }
}

/// One request waiting for a flight; leaving (a hung-up client, a timeout) decrements the count.
struct Waiter(Arc<AtomicUsize>);

impl Waiter {
    fn join(count: &Arc<AtomicUsize>) -> Self {
        count.fetch_add(1, Ordering::SeqCst);
        Self(count.clone())
    }
}

impl Drop for Waiter {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

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
    tiles: TileStore,
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
        let tiles = TileStore::open(&settings.cache.dir.join("tiles"))?;
        // Tiles of renders nobody resumed within a week are abandoned.
        if let Err(e) = tiles.prune(std::time::Duration::from_secs(7 * 24 * 3600)) {
            tracing::warn!(error = %e, "cannot prune old render tiles");
        }
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
                tiles,
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
        self.artifact_of(Work::Product(Box::new(req.clone())), key)
            .await
    }

    /// [`Self::artifact`] of any work. A frame render is computed tile by tile into the tile
    /// store and stops at its next tile when every request waiting for it has gone (client hung
    /// up or timed out, and no job waits for it); a retry resumes from the stored tiles. Other
    /// products always finish into the cache.
    pub(crate) async fn artifact_of(
        &self,
        work: Work,
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
        // or disconnects neither cancels it (a frame: unless it was the last) nor causes a second one.
        let (flight, _waiter, leader) = {
            let mut flights = self.inner.flights.lock().unwrap_or_else(|e| e.into_inner());
            match flights.get(key) {
                Some(f) => {
                    let waiter = Waiter::join(&f.waiters);
                    (f.clone(), waiter, false)
                }
                None => {
                    let (tx, rx) = tokio::sync::watch::channel(None);
                    let flight = Flight {
                        rx,
                        waiters: Arc::new(AtomicUsize::new(0)),
                    };
                    let waiter = Waiter::join(&flight.waiters);
                    flights.insert(key.to_string(), flight.clone());
                    let (state, key, waiters) =
                        (self.clone(), key.to_string(), flight.waiters.clone());
                    tokio::spawn(async move {
                        let result = state.compute(work, key.clone(), waiters).await;
                        // Publish, then leave the map (the product is already in the cache).
                        let _ = tx.send(Some(result));
                        let mut flights = state
                            .inner
                            .flights
                            .lock()
                            .unwrap_or_else(|e| e.into_inner());
                        flights.remove(&key);
                    });
                    (flight, waiter, true)
                }
            }
        };
        if !leader {
            self.inner
                .metrics
                .single_flight_joins
                .fetch_add(1, Ordering::Relaxed);
        }
        let mut rx = flight.rx;
        let result = rx
            .wait_for(Option::is_some)
            .await
            .map_err(|_| ApiError::Internal("computation task ended without a result".into()))?
            .clone()
            .unwrap_or_else(|| Err(ApiError::Internal("no result".into())));
        result.map(|b| (b, Source::Computed))
    }

    /// Computes `work` (behind the compute semaphore, on a blocking thread) and stores it.
    async fn compute(
        &self,
        work: Work,
        key: String,
        waiters: Arc<AtomicUsize>,
    ) -> Result<Arc<[u8]>, ApiError> {
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
            m.computed(work.name());
            m.compute_in_flight.fetch_add(1, Ordering::Relaxed);
            let image = match &work {
                Work::Product(req) => req.compute(&s.inner.engine).map_err(ApiError::from),
                Work::Frame(req) => s.render_frame(req, &key, &waiters),
            };
            m.compute_in_flight.fetch_sub(1, Ordering::Relaxed);
            let bytes = s.inner.cache.put_image(&key, &image?)?;
            if let Work::Frame(_) = work {
                // The assembled frame is in the cache: its tiles are no longer needed.
                if let Err(e) = s.inner.tiles.frame(&key).and_then(|t| t.remove_all()) {
                    tracing::warn!(key = %key, error = %e, "cannot remove a finished frame's tiles");
                }
            }
            Ok(bytes)
        })
        .await
    }

    /// Renders a frame tile by tile into the tile store (blocking). Stops at the next tile when
    /// no request waits any more.
    fn render_frame(
        &self,
        req: &FrameRequest,
        key: &str,
        waiters: &AtomicUsize,
    ) -> Result<crate::store::SpectralImage, ApiError> {
        let tiles = self.inner.tiles.frame(key)?;
        let abandoned = AtomicBool::new(false);
        let cancel = || {
            let gone = waiters.load(Ordering::SeqCst) == 0;
            if gone {
                abandoned.store(true, Ordering::Relaxed);
            }
            gone
        };
        let m = &self.inner.metrics;
        let progress = |p: crate::render::product::TileProgress| {
            // Called once with the tiles found, then once per tile computed.
            if p.done > p.reused {
                m.frame_tiles_computed.fetch_add(1, Ordering::Relaxed);
            }
        };
        let result = req.compute_tiled(
            &self.inner.engine,
            &crate::render::product::example_file,
            &tiles,
            &progress,
            &cancel,
        );
        match result {
            Err(_) if abandoned.load(Ordering::Relaxed) => {
                m.frames_abandoned.fetch_add(1, Ordering::Relaxed);
                Err(ApiError::Unavailable(format!(
                    "the render stopped because no client was waiting for it; {} of {} tiles are stored and a retry resumes from them",
                    tiles.count(),
                    req.tile_count()
                )))
            }
            other => Ok(other?),
        }
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
    async fn produce(
        &self,
        req: crate::job::spec::ItemRequest,
    ) -> Result<(), crate::job::JobError> {
        let key = req.cache_key();
        let work = match req {
            crate::job::spec::ItemRequest::Product(r) => Work::Product(r),
            crate::job::spec::ItemRequest::Frame(r) => Work::Frame(Arc::from(r)),
        };
        self.artifact_of(work, &key)
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
