//! The HTTP service (README.md "Service"): an axum router over the engine and the product cache.
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

pub mod body;
pub mod conn;
pub mod extract;
pub mod limits;
pub mod metrics;
pub mod openapi;
pub mod problem;
pub mod server;
pub mod viewer;

mod responses;
mod routes;

use bytes::Bytes;
use metrics::Metrics;
use problem::ApiError;
use responses::ResponseCache;
use skybake_engine::engine::Engine;
use skybake_product::config::Settings;
use skybake_product::frame::{NoTiles, TileProgress};
use skybake_product::{AnyRequest, ComputeEnv, Format, ProductKind, ProductRequest};
use skybake_store::lease::{Acquired, Lease};
use skybake_store::TileStore;
use skybake_store::{Cache, CacheConfig};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::Semaphore;

pub use routes::app;
pub use skybake_physics::{Error, Result};

/// The published result of a computation.
type FlightResult = Option<Result<Arc<[u8]>, ApiError>>;

/// A computation in flight: its result once published, who waits for it, and its cancel token.
struct Flight {
    id: u64,
    rx: tokio::sync::watch::Receiver<FlightResult>,
    /// Requests and job items awaiting the result now.
    waiters: usize,
    cancel: Arc<CancelToken>,
}

/// Set when every waiter of a computation has gone: the computation leaves the
/// compute queue at once, or stops at the engine's next stage boundary.
#[derive(Default)]
struct CancelToken {
    cancelled: std::sync::atomic::AtomicBool,
    notify: tokio::sync::Notify,
}

impl CancelToken {
    fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
        self.notify.notify_waiters();
    }

    fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }
}

/// One waiter of a flight; dropping it (the request finished, timed out, or its client hung up)
/// leaves the flight, and the last one to leave cancels the computation unless
/// `server.finish_abandoned` keeps it running for the cache.
struct Waiter {
    state: AppState,
    key: String,
    id: u64,
}

impl Drop for Waiter {
    fn drop(&mut self) {
        let inner = &self.state.inner;
        let mut flights = inner.flights.lock().unwrap_or_else(|e| e.into_inner());
        let Some(f) = flights.get_mut(&self.key).filter(|f| f.id == self.id) else {
            return;
        };
        f.waiters = f.waiters.saturating_sub(1);
        if f.waiters == 0 && !inner.settings.server.finish_abandoned {
            // Out of the map first, so a new request for the key starts a fresh computation
            // instead of joining one being cancelled.
            if let Some(f) = flights.remove(&self.key) {
                if f.rx.borrow().is_none() {
                    f.cancel.cancel();
                }
            }
        }
    }
}

/// How often a replica waiting for another's product looks for it in the bucket.
const LEASE_POLL: Duration = Duration::from_millis(100);

/// The outcome of [`AppState::lease`].
enum Leased {
    /// Another replica stored the product meanwhile.
    Stored(Arc<[u8]>),
    /// This replica computes it.
    Held(Lease),
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
    metrics: Metrics,
    compute: Semaphore,
    flights: Mutex<HashMap<String, Flight>>,
    tiles: TileStore,
    /// Flights started and not yet holding a compute slot (bounded by
    /// `server.max_queued_computations`).
    queued: std::sync::atomic::AtomicUsize,
    next_flight: std::sync::atomic::AtomicU64,
    rate: limits::RateLimiter,
    responses: Mutex<ResponseCache>,
    jobs: skybake_job::run::Jobs,
    /// This process's name on the leases it holds in a bucket.
    holder: String,
    /// What consecutive frames share (a camera path's lit cloud, a sun sweep's grid).
    reuse: skybake_product::frame::FrameReuse,
}

impl AppState {
    /// Opens the cache at `settings.cache.dir` and loads persisted jobs (call
    /// [`AppState::start_job_workers`] inside a runtime to run them).
    pub fn new(settings: Settings) -> Result<Self, ApiError> {
        let config = CacheConfig::new(
            &settings.cache.dir,
            settings.cache.disk_budget_bytes,
            settings.cache.memory_budget_bytes,
        );
        // With a bucket (`cache.url`), products and frame tiles are shared with other replicas.
        let bucket = skybake_product::engines::shared_bucket(&settings)?;
        let reuse = skybake_product::frame::FrameReuse::new(
            usize::try_from(settings.cache.frame_reuse_bytes).unwrap_or(usize::MAX),
        );
        let cache = Arc::new(match &bucket {
            Some(bucket) => Cache::open_shared(config, bucket.clone())?,
            None => Cache::open(config)?,
        });
        let holder = holder_name();
        // With a bucket, jobs are shared too: any replica answers for any job, and a job whose
        // replica died is taken over by another (its lease expires after `cache.lease_s`).
        let job_store = match &bucket {
            Some(bucket) => skybake_job::store::JobStore::in_bucket(
                bucket.clone(),
                &holder,
                Duration::from_secs_f64(settings.cache.lease_s),
            ),
            None => skybake_job::store::JobStore::open(&settings.cache.dir.join("jobs"))?,
        };
        let jobs = skybake_job::run::Jobs::with_store(
            job_store,
            skybake_product::params::Defaults::from_settings(&settings),
        )?;
        let tiles = match bucket {
            Some(bucket) => TileStore::in_bucket(bucket, "tiles"),
            None => TileStore::open(&settings.cache.dir.join("tiles"))?,
        };
        // Tiles of renders nobody resumed within a week are abandoned.
        if let Err(e) = tiles.prune(std::time::Duration::from_secs(7 * 24 * 3600)) {
            tracing::warn!(error = %e, "cannot prune old render tiles");
        }
        let state = Self {
            inner: Arc::new(Inner {
                compute: Semaphore::new(settings.compute_threads()),
                responses: Mutex::new(ResponseCache::new(settings.cache.response_budget_bytes)),
                settings,
                // Precise tables persist in the same cache (one disk budget) across restarts.
                engine: skybake_product::engines::engine_with_cache(cache.clone()),
                cache,
                metrics: Metrics::default(),
                flights: Mutex::new(HashMap::new()),
                tiles,
                queued: Default::default(),
                next_flight: Default::default(),
                rate: Default::default(),
                jobs,
                holder,
                reuse,
            }),
        };
        state.housekeeping();
        Ok(state)
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

    pub fn jobs(&self) -> &skybake_job::run::Jobs {
        &self.inner.jobs
    }

    pub fn rate_limiter(&self) -> &limits::RateLimiter {
        &self.inner.rate
    }

    /// Starts the job workers (`settings.jobs.workers` tasks) on the current runtime, and the
    /// housekeeping task that expires finished jobs (`jobs.expire_after_s`) and keeps the job
    /// files counted in the cache's disk budget.
    pub fn start_job_workers(&self) {
        skybake_job::run::start_workers(self, self.settings().jobs.workers);
        if self.jobs().shared() {
            // Jobs submitted to other replicas, and those whose replica died, are picked up
            // every half lease.
            let state = self.clone();
            let every =
                Duration::from_secs_f64((self.settings().cache.lease_s / 2.0).clamp(0.05, 30.0));
            tokio::spawn(async move {
                loop {
                    tokio::time::sleep(every).await;
                    let s = state.clone();
                    let _ = Self::blocking(move || {
                        if let Err(e) = s.jobs().sync() {
                            tracing::warn!(error = %e, "cannot read the shared jobs");
                        }
                        Ok(())
                    })
                    .await;
                }
            });
        }
        let state = self.clone();
        let expire_after_s = self.settings().jobs.expire_after_s;
        let every = Duration::from_secs_f64((expire_after_s / 4.0).clamp(0.05, 30.0));
        tokio::spawn(async move {
            loop {
                let s = state.clone();
                let _ = Self::blocking(move || {
                    s.housekeeping();
                    Ok(())
                })
                .await;
                tokio::time::sleep(every).await;
            }
        });
    }

    /// Expires finished jobs and counts the job files and render tiles in the cache's disk budget.
    pub fn housekeeping(&self) {
        let jobs = self.jobs();
        let removed = jobs.expire(self.settings().jobs.expire_after_s);
        if removed > 0 {
            tracing::info!(removed, "expired finished jobs");
        }
        self.account_disk(None);
    }

    /// Counts the job files and the render tiles in the cache's disk budget
    /// (`cache.disk_budget_bytes`). When everything does not fit, the tiles of frames other than
    /// `rendering` go first, least recently written first (they are only a head start for a
    /// retry), then products, least recently used first.
    pub fn account_disk(&self, rendering: Option<&str>) {
        let budget = self.settings().cache.disk_budget_bytes;
        let jobs = self.jobs().disk_bytes();
        let tiles = &self.inner.tiles;
        let products = self.inner.cache.stats().bytes_on_disk;
        let over = (jobs + tiles.bytes() + products).saturating_sub(budget);
        if over > 0 {
            match tiles.evict_oldest(rendering, tiles.bytes().saturating_sub(over)) {
                Ok(0) => {}
                Ok(n) => {
                    tracing::info!(
                        frames = n,
                        "render tiles evicted to keep to the disk budget"
                    )
                }
                Err(e) => tracing::warn!(error = %e, "cannot evict render tiles"),
            }
        }
        self.inner
            .cache
            .set_reserved_bytes(jobs.saturating_add(tiles.bytes()));
    }

    /// Runs blocking work on the blocking pool; a panic there becomes a 500, never a crash.
    pub async fn blocking<T: Send + 'static>(
        f: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        tokio::task::spawn_blocking(f)
            .await
            .map_err(|e| ApiError::Internal(format!("worker failed: {e}")))?
    }

    /// The artifact (verified EXR bytes) of `work`: from the cache, or computed once for all
    /// identical requests in flight. A frame is computed tile by tile into the tile store and,
    /// like any computation, stops when every request waiting for it has gone (at its next tile;
    /// a retry resumes from the stored tiles).
    pub async fn artifact(
        &self,
        work: &AnyRequest,
        key: &str,
    ) -> Result<(Arc<[u8]>, Source), ApiError> {
        let work = work.clone();
        let lookup = {
            let (s, k) = (self.clone(), key.to_string());
            Self::blocking(move || Ok(s.inner.cache.get(&k)?)).await?
        };
        if let Some(bytes) = lookup {
            return Ok((bytes, Source::Cache));
        }
        // Join the computation in flight for this key, or start one. The computation runs on a
        // task of its own that publishes its result and leaves the map, so a waiter that times out
        // or disconnects does not cause a second one; when the last waiter has gone the
        // computation is cancelled (see [`Waiter`]).
        let (mut rx, waiter, leader) = {
            let mut flights = self.inner.flights.lock().unwrap_or_else(|e| e.into_inner());
            match flights.get_mut(key) {
                Some(f) => {
                    f.waiters += 1;
                    (f.rx.clone(), self.waiter(key, f.id), false)
                }
                None => {
                    let queued = self.inner.queued.load(Ordering::Relaxed);
                    if queued >= self.inner.settings.server.max_queued_computations {
                        self.inner.metrics.load_shed.fetch_add(1, Ordering::Relaxed);
                        self.inner
                            .metrics
                            .queue_shed
                            .fetch_add(1, Ordering::Relaxed);
                        return Err(ApiError::Overloaded);
                    }
                    self.inner.queued.fetch_add(1, Ordering::Relaxed);
                    let id = self.inner.next_flight.fetch_add(1, Ordering::Relaxed);
                    let (tx, rx) = tokio::sync::watch::channel(None);
                    let cancel = Arc::new(CancelToken::default());
                    flights.insert(
                        key.to_string(),
                        Flight {
                            id,
                            rx: rx.clone(),
                            waiters: 1,
                            cancel: cancel.clone(),
                        },
                    );
                    let (state, k) = (self.clone(), key.to_string());
                    tokio::spawn(async move {
                        let result = state.compute(work, k.clone(), cancel).await;
                        // Publish, then leave the map (the product is already in the cache).
                        let _ = tx.send(Some(result));
                        let mut flights = state
                            .inner
                            .flights
                            .lock()
                            .unwrap_or_else(|e| e.into_inner());
                        if flights.get(&k).is_some_and(|f| f.id == id) {
                            flights.remove(&k);
                        }
                    });
                    (rx, self.waiter(key, id), true)
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
        drop(waiter);
        result.map(|b| (b, Source::Computed))
    }

    fn waiter(&self, key: &str, id: u64) -> Waiter {
        Waiter {
            state: self.clone(),
            key: key.to_string(),
            id,
        }
    }

    /// Computes `req` (behind the compute semaphore, on a blocking thread) and stores it; a
    /// cancelled computation leaves the queue at once or stops at the engine's next stage.
    async fn compute(
        &self,
        work: AnyRequest,
        key: String,
        cancel: Arc<CancelToken>,
    ) -> Result<Arc<[u8]>, ApiError> {
        let _permit = self.compute_slot(&cancel).await?;
        let s = self.clone();
        Self::blocking(move || {
            // Another flight may have finished between our cache miss and starting this one.
            // (`contains` first, so the common case does not count a second miss.)
            if s.inner.cache.contains(&key) {
                if let Some(bytes) = s.inner.cache.get(&key)? {
                    return Ok(bytes);
                }
            }
            // With a bucket, one replica at a time computes a product (it holds the lease until
            // the product is stored); the others wait for the product.
            let _lease = match s.inner.cache.bucket() {
                Some(bucket) => match s.lease(bucket, &key, &cancel)? {
                    Leased::Stored(bytes) => return Ok(bytes),
                    Leased::Held(lease) => Some(lease),
                },
                None => None,
            };
            let m = &s.inner.metrics;
            m.computed(work.name());
            m.compute_in_flight.fetch_add(1, Ordering::Relaxed);
            let image = s.compute_image(&work, &key, &cancel);
            m.compute_in_flight.fetch_sub(1, Ordering::Relaxed);
            let bytes = s.inner.cache.put_image(&key, &image?)?;
            if let AnyRequest::Frame(_) = work {
                // The assembled frame is in the cache: its tiles are no longer needed.
                if let Err(e) = s.inner.tiles.frame(&key).and_then(|t| t.remove_all()) {
                    tracing::warn!(key = %key, error = %e, "cannot remove a finished frame's tiles");
                }
                s.account_disk(None);
            }
            Ok(bytes)
        })
        .await
    }

    /// The lease on computing `key` across replicas (blocking), or the product once the replica
    /// holding the lease has stored it. Polls every [`LEASE_POLL`] while another replica holds
    /// the lease; a lease whose holder died expires (`cache.lease_s`) and is taken over.
    fn lease(
        &self,
        bucket: &Arc<skybake_store::Bucket>,
        key: &str,
        cancel: &CancelToken,
    ) -> Result<Leased, ApiError> {
        let duration = Duration::from_secs_f64(self.inner.settings.cache.lease_s);
        let name = format!("leases/{key}");
        loop {
            match Lease::try_acquire(bucket, &name, &self.inner.holder, duration)? {
                Acquired::Held(lease) => {
                    // The previous holder may have stored the product just before letting go.
                    return Ok(match self.inner.cache.get(key)? {
                        Some(bytes) => Leased::Stored(bytes),
                        None => Leased::Held(lease),
                    });
                }
                Acquired::Busy { .. } => {
                    self.inner
                        .metrics
                        .lease_waits
                        .fetch_add(1, Ordering::Relaxed);
                    if cancel.is_cancelled() {
                        return Err(crate::Error::Cancelled.into());
                    }
                    std::thread::sleep(LEASE_POLL);
                    if let Some(bytes) = self.inner.cache.get(key)? {
                        return Ok(Leased::Stored(bytes));
                    }
                }
            }
        }
    }

    /// Computes `work`'s artifact (blocking): a frame tile by tile into the tile store. Stops at
    /// the engine's next stage, tile or row when the flight is cancelled (no request waits any
    /// more).
    fn compute_image(
        &self,
        work: &AnyRequest,
        key: &str,
        flight: &CancelToken,
    ) -> Result<skybake_physics::image::SpectralImage, ApiError> {
        let m = &self.inner.metrics;
        let tiles = match work {
            AnyRequest::Frame(_) => Some(self.inner.tiles.frame(key)?),
            AnyRequest::Atmosphere(_) => None,
        };
        let abandoned = AtomicBool::new(false);
        let cancel = || {
            let gone = flight.is_cancelled();
            if gone {
                abandoned.store(true, Ordering::Relaxed);
            }
            gone
        };
        let progress = |p: TileProgress| {
            // Called once with the tiles found, then once per tile computed.
            if p.done > p.reused {
                m.frame_tiles_computed.fetch_add(1, Ordering::Relaxed);
                // The new tile counts in the disk budget.
                self.account_disk(Some(key));
            }
        };
        let env = ComputeEnv {
            loader: &skybake_product::frame::example_file,
            tiles: match &tiles {
                Some(t) => t,
                None => &NoTiles,
            },
            progress: &progress,
            cancel: &cancel,
            reuse: Some(&self.inner.reuse),
        };
        match (work.compute(&self.inner.engine, &env), work, &tiles) {
            (Ok(image), _, _) => Ok(image),
            (Err(_), AnyRequest::Frame(req), Some(tiles)) if abandoned.load(Ordering::Relaxed) => {
                m.frames_abandoned.fetch_add(1, Ordering::Relaxed);
                m.cancelled.fetch_add(1, Ordering::Relaxed);
                Err(ApiError::Unavailable(format!(
                    "the render stopped because no client was waiting for it; {} of {} tiles are stored and a retry resumes from them",
                    tiles.count(),
                    req.tile_count()
                )))
            }
            (Err(e), _, _) => {
                if matches!(e, crate::Error::Cancelled) {
                    m.cancelled.fetch_add(1, Ordering::Relaxed);
                }
                Err(e.into())
            }
        }
    }

    /// The response body of `req` in its format, and where it came from.
    pub async fn body(&self, req: &ProductRequest) -> Result<(Bytes, Source, String), ApiError> {
        self.respond(&AnyRequest::Atmosphere(Box::new(req.clone())), req.format)
            .await
    }

    /// The one response path of every product: the body of `work` in `format` from the
    /// rendered-response cache, the product cache, or one computation shared by identical requests
    /// (an atmosphere product over `server.max_request_cost` is refused before it starts); with
    /// where it came from and its cache key.
    pub async fn respond(
        &self,
        work: &AnyRequest,
        format: Format,
    ) -> Result<(Bytes, Source, String), ApiError> {
        let key = work.cache_key();
        if let Some(b) = self.response_get(&key, format) {
            self.inner
                .metrics
                .response_cache_hits
                .fetch_add(1, Ordering::Relaxed);
            return Ok((b, Source::Response, key));
        }
        if !self.inner.cache.contains(&key) {
            match work {
                AnyRequest::Atmosphere(req) => self.check_cost(req)?,
                AnyRequest::Frame(req) => self.check_frame_cost(&req.admission_cost())?,
            }
        }
        let (artifact, source) = self.artifact(work, &key).await?;
        let body = match Self::render_body(work, format, artifact).await {
            Ok(body) => body,
            Err(ApiError::Internal(why)) => {
                // A stored artifact that passed its checksum but does not render is a server
                // fault, never the request's: drop it and compute the product again (a second
                // failure is a 500).
                tracing::warn!(key = %key, error = %why, "malformed cached artifact; recomputing");
                self.inner.cache.remove(&key)?;
                let (artifact, _) = self.artifact(work, &key).await?;
                Self::render_body(work, format, artifact).await?
            }
            Err(e) => return Err(e),
        };
        if let Ok(mut r) = self.inner.responses.lock() {
            r.put(&key, format, body.clone());
        }
        Ok((body, source, key))
    }

    /// The body of `work` in `format`, rendered from `artifact` (EXR bytes, served as they are).
    async fn render_body(
        work: &AnyRequest,
        format: Format,
        artifact: Arc<[u8]>,
    ) -> Result<Bytes, ApiError> {
        if format == Format::Exr {
            return Ok(Bytes::copy_from_slice(&artifact));
        }
        let work = work.clone();
        Self::blocking(move || {
            let image = skybake_store::decode_exr(&artifact)
                .map_err(|e| ApiError::Internal(format!("cached artifact: {e}")))?;
            Ok(Bytes::from(work.body(format, &image)?))
        })
        .await
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

    /// Refuses (413) a request whose estimated cost ([`skybake_product::cost`]) exceeds
    /// `server.max_request_cost`; jobs are not subject to it (they queue instead of holding a
    /// request open).
    pub fn check_cost(&self, req: &ProductRequest) -> Result<(), ApiError> {
        let budget = self.inner.settings.server.max_request_cost;
        let c = skybake_product::cost::estimate(req)?;
        if c.units > budget {
            return Err(crate::Error::too_large(
                "request_cost",
                format!(
                    "estimated cost {} cell-wavelength-orders ((table cells {} × expected orders {} + output cells {}) × wavelengths {}) exceeds the budget server.max_request_cost; lower quality, wavelengths or table size, or submit it as a job (POST /v1/jobs)",
                    c.units, c.table_cells, c.expected_orders, c.output_cells, c.wavelengths
                ),
                budget,
            )
            .into());
        }
        Ok(())
    }

    /// Refuses (413) a frame request or frame plan whose estimated cost
    /// ([`skybake_product::frame::FrameCost`]) exceeds `server.max_frame_cost` (naming
    /// `request_cost`) or whose estimated peak memory exceeds `server.max_request_memory_bytes`
    /// (naming `request_memory`), before anything is voxelised.
    pub fn check_frame_cost(&self, c: &skybake_product::frame::FrameCost) -> Result<(), ApiError> {
        Ok(c.check(self.frame_caps())?)
    }

    /// The caps of a frame request (`server.max_frame_cost`, `server.max_request_memory_bytes`).
    pub fn frame_caps(&self) -> skybake_product::frame::FrameCaps {
        let server = &self.inner.settings.server;
        skybake_product::frame::FrameCaps {
            max_cost: server.max_frame_cost,
            max_memory_bytes: server.max_request_memory_bytes,
        }
    }

    /// Runs blocking `work` as a computation that is not a product (a frame's plan): it waits
    /// for one of the same compute slots as products, counts in the same bounded queue (503 when
    /// full) and in `computations_in_flight`, and is cancelled — `work`'s check returns true —
    /// as soon as the caller stops waiting (the client hung up or the request timed out).
    pub async fn run_computation<T: Send + 'static>(
        &self,
        work: impl FnOnce(&(dyn Fn() -> bool + Sync)) -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        let inner = &self.inner;
        if inner.queued.load(Ordering::Relaxed) >= inner.settings.server.max_queued_computations {
            inner.metrics.load_shed.fetch_add(1, Ordering::Relaxed);
            inner.metrics.queue_shed.fetch_add(1, Ordering::Relaxed);
            return Err(ApiError::Overloaded);
        }
        inner.queued.fetch_add(1, Ordering::Relaxed);
        let cancel = Arc::new(CancelToken::default());
        /// Cancels the computation when the caller's future is dropped before it ends.
        struct CancelOnDrop(Arc<CancelToken>);
        impl Drop for CancelOnDrop {
            fn drop(&mut self) {
                self.0.cancel();
            }
        }
        let _guard = CancelOnDrop(cancel.clone());
        let state = self.clone();
        // A task of its own holds the slot until the blocking work has returned, even when the
        // caller has gone (the work stops at its next check).
        let task = tokio::spawn(async move {
            let _permit = state.compute_slot(&cancel).await?;
            let s = state.clone();
            Self::blocking(move || {
                let m = &s.inner.metrics;
                m.compute_in_flight.fetch_add(1, Ordering::Relaxed);
                let result = work(&|| cancel.is_cancelled());
                m.compute_in_flight.fetch_sub(1, Ordering::Relaxed);
                if matches!(&result, Err(ApiError::Unavailable(_))) && cancel.is_cancelled() {
                    m.cancelled.fetch_add(1, Ordering::Relaxed);
                }
                result
            })
            .await
        });
        task.await
            .map_err(|e| ApiError::Internal(format!("computation task failed: {e}")))?
    }

    /// Bundle parameters with the configured default quality (not the default wavelengths:
    /// without `wavelengths` a bundle is the RGB form).
    pub fn lut_params(
        &self,
        mut p: skybake_product::params::RequestParams,
    ) -> skybake_product::params::RequestParams {
        if p.quality.is_none() {
            p.quality = self.jobs().defaults().apply(Default::default()).quality;
        }
        p
    }

    /// The manifest of the texture bundle `req` (with a `links` entry per texture): from the
    /// cache, or computed (in a compute slot, as products are) and stored with its textures as
    /// blobs, the manifest last, so a cached manifest means cached textures (a texture evicted
    /// since is recomputed by [`Self::lut_file`]).
    pub async fn lut(
        &self,
        req: skybake_product::lut::LutRequest,
    ) -> Result<(Arc<[u8]>, Source), ApiError> {
        let key = req.cache_key();
        let lookup = {
            let (s, k) = (self.clone(), key.clone());
            Self::blocking(move || Ok(s.inner.cache.get_blob(&k)?)).await?
        };
        if let Some(bytes) = lookup {
            let s = self.clone();
            let (bytes, complete) = Self::blocking(move || {
                let complete = s.lut_textures_cached(&bytes)?;
                Ok((bytes, complete))
            })
            .await?;
            if complete {
                return Ok((bytes, Source::Cache));
            }
        }
        let s = self.clone();
        let bytes = self
            .run_computation(move |cancelled| {
                if let Some(bytes) = s.inner.cache.get_blob(&key)? {
                    if s.lut_textures_cached(&bytes)? {
                        return Ok(bytes);
                    }
                }
                s.inner.metrics.computed("lut");
                let (files, _) = req.compute_files_unless(&s.inner.engine, cancelled)?;
                let mut links = serde_json::Map::new();
                let mut manifest = None;
                for (name, bytes) in files {
                    if name == skybake_product::lut::MANIFEST_FILE {
                        manifest = Some(bytes);
                        continue;
                    }
                    let file_key = req.file_key(name);
                    s.inner.cache.put_blob(&file_key, bytes)?;
                    links.insert(name.into(), format!("/v1/lut/files/{file_key}").into());
                }
                let manifest =
                    manifest.ok_or_else(|| ApiError::Internal("bundle without manifest".into()))?;
                let mut manifest: serde_json::Value = serde_json::from_slice(&manifest)
                    .map_err(|e| ApiError::Internal(format!("bundle manifest: {e}")))?;
                manifest["links"] = links.into();
                let text = serde_json::to_vec_pretty(&manifest)
                    .map_err(|e| ApiError::Internal(format!("bundle manifest: {e}")))?;
                let bytes = s.inner.cache.put_blob(&key, text)?;
                s.account_disk(None);
                Ok(bytes)
            })
            .await?;
        Ok((bytes, Source::Computed))
    }

    /// Whether every texture a cached bundle manifest links to is still in the cache (on disk,
    /// or fetched from the bucket); false when one was evicted, so the bundle is recomputed.
    fn lut_textures_cached(&self, manifest: &[u8]) -> Result<bool, ApiError> {
        let manifest: serde_json::Value = serde_json::from_slice(manifest)
            .map_err(|e| ApiError::Internal(format!("cached bundle manifest: {e}")))?;
        let Some(links) = manifest["links"].as_object() else {
            return Ok(false);
        };
        for link in links.values() {
            let Some(key) = link.as_str().and_then(|l| l.strip_prefix("/v1/lut/files/")) else {
                return Ok(false);
            };
            let cache = &self.inner.cache;
            if !cache.contains(key) && cache.get_blob(key)?.is_none() {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// The validated request of `product` from raw parameters, with the configured defaults.
    pub fn request(
        &self,
        product: ProductKind,
        p: skybake_product::params::RequestParams,
    ) -> Result<ProductRequest, ApiError> {
        Ok(ProductRequest::from_params(
            product,
            &self.jobs().defaults().apply(p),
        )?)
    }
}

impl AppState {
    /// Waits in the queue for a compute slot, leaving the queue either way: cancelled (counted)
    /// when `cancel` fires first, 503 when the service is shutting down.
    async fn compute_slot(
        &self,
        cancel: &CancelToken,
    ) -> Result<tokio::sync::SemaphorePermit<'_>, ApiError> {
        let inner = &self.inner;
        let permit = {
            let notified = cancel.notify.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if cancel.is_cancelled() {
                None
            } else {
                tokio::select! {
                    p = inner.compute.acquire() => Some(p),
                    () = notified => None,
                }
            }
        };
        inner.queued.fetch_sub(1, Ordering::Relaxed);
        let Some(permit) = permit else {
            inner.metrics.cancelled.fetch_add(1, Ordering::Relaxed);
            return Err(crate::Error::Cancelled.into());
        };
        permit.map_err(|_| ApiError::Unavailable("shutting down".into()))
    }
}

/// Jobs produce their items through the service's cache: cached items are hits, the others are
/// computed once (joining identical requests in flight) and stored.
impl skybake_job::run::Producer for AppState {
    async fn produce(&self, work: AnyRequest) -> Result<(), skybake_job::JobError> {
        // A frame item is held to the per-request memory cap once voxelised, as a render is (its
        // cost is the job's, admitted at submission).
        let work = match work {
            AnyRequest::Frame(r) => {
                let caps = skybake_product::frame::FrameCaps {
                    max_cost: u64::MAX,
                    max_memory_bytes: self.frame_caps().max_memory_bytes,
                };
                AnyRequest::Frame(Arc::new(Arc::unwrap_or_clone(r).with_caps(Some(caps))))
            }
            other => other,
        };
        self.artifact(&work, &work.cache_key())
            .await
            .map(|_| ())
            .map_err(|e| match e {
                ApiError::Param(e) => skybake_job::JobError::Param(e),
                other => skybake_job::JobError::Failure(other.to_string()),
            })
    }

    fn jobs(&self) -> &skybake_job::run::Jobs {
        &self.inner.jobs
    }
}

/// A name for this process on the leases it holds: the host (`HOSTNAME`, a pod's name under
/// Kubernetes), the process id and the start time, so a restarted replica is a new holder.
fn holder_name() -> String {
    let host = std::env::var("HOSTNAME").unwrap_or_else(|_| "replica".into());
    let started = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default()
        .as_nanos();
    format!("{host}-{}-{started:x}", std::process::id())
}
