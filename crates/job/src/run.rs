//! The job table, the queue and the workers. A worker takes the next queued job and asks its
//! [`Producer`] for each item's artifact in turn (the service's producer is its product cache:
//! cached items are hits, the rest are computed once and stored), persisting progress as it goes.
//!
//! With a shared store ([`JobStore::in_bucket`]) every replica sees every job: a job is loaded
//! from the bucket when a replica is asked about it, [`Jobs::sync`] (run periodically) brings the
//! table in line and queues the unfinished jobs, and a worker runs a job only while it holds the
//! job's lease ([`Claim`]), starting from the progress stored last. A replica that dies stops
//! renewing its lease; once it has expired another replica's worker takes the job over. Items
//! finished after the last progress write are product-cache hits, so only the item in flight is
//! computed again.

use super::spec::JobSpec;
use super::store::{now, valid_id, Claim, ItemError, JobState, JobStatus, JobStore, StoredJob};
use super::JobError;
use skybake_product::params::Defaults;
use skybake_product::AnyRequest;
use std::collections::{HashMap, HashSet, VecDeque};
use std::future::Future;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Most errors kept per job (later ones are counted only).
pub const MAX_KEPT_ERRORS: usize = 1000;
/// Most time between progress writes.
const PERSIST_EVERY: Duration = Duration::from_millis(250);

/// The limits a submission is checked against.
#[derive(Debug, Clone, Copy)]
pub struct SubmitLimits {
    /// Most products in the job.
    pub max_products: usize,
    /// Most jobs queued or running.
    pub max_live: usize,
    /// Most bytes of job files on disk.
    pub disk_bytes: u64,
    /// Largest estimated cost of the whole job ([`JobSpec::validate_and_cost`]).
    pub max_cost: u64,
    /// Largest estimated peak memory of one frame item ([`JobSpec::check_frame_memory`]).
    pub max_item_memory_bytes: u64,
}

/// Whatever turns a product request into a stored artifact.
pub trait Producer: Clone + Send + Sync + 'static {
    /// Makes sure the artifact of `req` (a product or a frame) exists (cached or computed now).
    fn produce(&self, req: AnyRequest) -> impl Future<Output = Result<(), JobError>> + Send;
    /// The job table the workers take jobs from.
    fn jobs(&self) -> &Jobs;
}

/// A job in memory.
pub struct Job {
    pub id: String,
    pub spec: JobSpec,
    status: Mutex<JobStatus>,
    cancel: AtomicBool,
    /// Bytes of its files on disk (body + last status written), for the disk budget.
    body_bytes: u64,
    status_bytes: AtomicU64,
    /// Held while the job's files are written or removed; `true` once removed, so a late progress
    /// write does not bring the directory back.
    files: Mutex<bool>,
    /// A worker of this process runs it now (its status here is the freshest).
    here: AtomicBool,
}

/// One item of a job as listed in its status.
#[derive(Debug, Clone, PartialEq)]
pub struct ItemView {
    pub index: usize,
    pub product: &'static str,
    pub cache_key: Option<String>,
    /// "done", "failed" or "pending".
    pub status: &'static str,
}

impl Job {
    pub fn status(&self) -> JobStatus {
        self.status
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Replaces the status with one read from the store, unless a worker of this process runs
    /// the job (its status is then the freshest, and the one being written).
    fn refresh(&self, status: JobStatus) {
        let mut s = self.status.lock().unwrap_or_else(|e| e.into_inner());
        if !self.here() {
            *s = status;
        }
    }

    fn here(&self) -> bool {
        self.here.load(Ordering::Relaxed)
    }

    /// A job read from the store, or `None` (logged) when its body or status no longer parse.
    fn from_stored(s: StoredJob) -> Option<Self> {
        let spec =
            match JobSpec::parse_body(&s.body, skybake_product::config::MAX_JOB_PRODUCTS_LIMIT) {
                Ok(spec) => spec,
                Err(e) => {
                    tracing::warn!(job = %s.id, error = %e, "persisted job not loaded");
                    return None;
                }
            };
        let status = s.status.unwrap_or_else(|| JobStatus::queued(spec.len()));
        if status.total != spec.len() {
            tracing::warn!(job = %s.id, "persisted status does not match the job");
            return None;
        }
        Some(Job {
            id: s.id,
            spec,
            status: Mutex::new(status),
            cancel: AtomicBool::new(false),
            body_bytes: s.body.len() as u64,
            status_bytes: AtomicU64::new(s.status_bytes),
            files: Mutex::new(false),
            here: AtomicBool::new(false),
        })
    }

    fn update(&self, f: impl FnOnce(&mut JobStatus)) -> JobStatus {
        let mut s = self.status.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut s);
        s.updated = now();
        s.clone()
    }

    /// Items `offset..offset + limit` with their cache keys and states (validates and hashes each
    /// item: call off the async executor for long pages).
    pub fn items(&self, offset: usize, limit: usize, defaults: &Defaults) -> Vec<ItemView> {
        let st = self.status();
        let failed: HashSet<usize> = st.errors.iter().map(|e| e.index).collect();
        let end = offset.saturating_add(limit).min(st.total);
        (offset.min(end)..end)
            .map(|i| {
                let (product, key) = match self.spec.request(i, defaults) {
                    Ok(r) => (r.name(), Some(r.cache_key())),
                    Err(_) => (self.spec.item_name(i).unwrap_or(""), None),
                };
                let status = if failed.contains(&i) || (key.is_none() && i < st.next) {
                    "failed"
                } else if i < st.next {
                    "done"
                } else {
                    "pending"
                };
                ItemView {
                    index: i,
                    product,
                    cache_key: key,
                    status,
                }
            })
            .collect()
    }
}

/// The job table and queue, persisted in a [`JobStore`].
pub struct Jobs {
    store: JobStore,
    defaults: Defaults,
    table: Mutex<HashMap<String, Arc<Job>>>,
    queue: Mutex<VecDeque<String>>,
    wake: tokio::sync::Notify,
    running: AtomicU64,
    /// Held from the live-job and disk checks of a submission to its insertion in the table, so
    /// concurrent submissions never exceed `jobs.max_live`.
    admission: Mutex<()>,
}

impl Jobs {
    /// Loads the jobs stored under `dir`; unfinished ones are queued again. `defaults` are the
    /// deployment's parameter defaults, applied to every item.
    pub fn open(dir: &Path, defaults: Defaults) -> Result<Self, JobError> {
        Self::with_store(JobStore::open(dir)?, defaults)
    }

    /// Loads the jobs of `store` (a directory, or a bucket shared with other replicas);
    /// unfinished ones are queued.
    pub fn with_store(store: JobStore, defaults: Defaults) -> Result<Self, JobError> {
        let jobs = Self {
            store,
            defaults,
            table: Mutex::new(HashMap::new()),
            queue: Mutex::new(VecDeque::new()),
            wake: tokio::sync::Notify::new(),
            running: AtomicU64::new(0),
            admission: Mutex::new(()),
        };
        if jobs.store.shared() {
            // A bucket that does not answer now does not keep the service down: the next sync
            // loads the jobs.
            if let Err(e) = jobs.sync() {
                tracing::warn!(error = %e, "cannot read the shared jobs yet");
            }
            return Ok(jobs);
        }
        let (stored, unreadable) = jobs.store.load_all()?;
        for (id, why) in unreadable {
            tracing::warn!(job = %id, error = %why, "persisted job not loaded");
        }
        let mut found: Vec<Job> = stored.into_iter().filter_map(Job::from_stored).collect();
        found.sort_by(|a, b| a.status().created.cmp(&b.status().created));
        for job in found {
            if matches!(job.status().state, JobState::Queued | JobState::Running) {
                job.update(|s| s.state = JobState::Queued);
                jobs.lock_queue().push_back(job.id.clone());
            }
            jobs.lock_table().insert(job.id.clone(), Arc::new(job));
        }
        Ok(jobs)
    }

    /// Whether the jobs are shared with other replicas (kept in a bucket).
    pub fn shared(&self) -> bool {
        self.store.shared()
    }

    /// With a shared store (blocking: bucket requests): brings the table in line with the
    /// bucket — jobs submitted to other replicas are loaded, removed ones forgotten, the progress
    /// of those not running here read again — and queues every unfinished job this process does
    /// not run (a worker runs it only if it can take the job's lease, so a job another replica is
    /// running is skipped, and one whose replica died is taken over once its lease has expired).
    /// Returns how many jobs were queued. Does nothing with a directory.
    pub fn sync(&self) -> Result<usize, JobError> {
        if !self.store.shared() {
            return Ok(0);
        }
        let ids: HashSet<String> = self.store.ids()?.into_iter().collect();
        let known: Vec<Arc<Job>> = self.lock_table().values().cloned().collect();
        for job in known {
            // Listed before a submission here stored it, or removed by another replica.
            if !ids.contains(&job.id) && !job.here() && self.store.load(&job.id)?.is_none() {
                self.forget(&job.id);
            }
        }
        let mut queued = 0;
        let mut sorted: Vec<String> = ids.into_iter().collect();
        sorted.sort();
        let mut loaded = Vec::new();
        for id in sorted {
            let job = match self.get(&id) {
                Some(job) if job.here() || job.status().finished() => continue,
                Some(job) => match self.store.load_status(&id)? {
                    Some(st) => {
                        job.refresh(st);
                        job
                    }
                    None => job,
                },
                None => match self.store.load(&id)?.and_then(Job::from_stored) {
                    Some(job) => Arc::new(job),
                    None => continue,
                },
            };
            loaded.push(job);
        }
        loaded.sort_by(|a, b| (a.status().created, &a.id).cmp(&(b.status().created, &b.id)));
        for job in loaded {
            let job = self
                .lock_table()
                .entry(job.id.clone())
                .or_insert(job)
                .clone();
            if !job.status().finished() && !job.here() {
                let mut q = self.lock_queue();
                if !q.contains(&job.id) {
                    q.push_back(job.id.clone());
                    queued += 1;
                }
            }
        }
        for _ in 0..queued {
            self.wake.notify_one();
        }
        Ok(queued)
    }

    /// Drops job `id` from the table and the queue (its files are gone).
    fn forget(&self, id: &str) {
        self.lock_table().remove(id);
        self.lock_queue().retain(|x| x != id);
    }

    fn lock_table(&self) -> std::sync::MutexGuard<'_, HashMap<String, Arc<Job>>> {
        self.table.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn lock_queue(&self) -> std::sync::MutexGuard<'_, VecDeque<String>> {
        self.queue.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The parameter defaults applied to every item.
    pub fn defaults(&self) -> &Defaults {
        &self.defaults
    }

    pub fn get(&self, id: &str) -> Option<Arc<Job>> {
        self.lock_table().get(id).cloned()
    }

    /// The job `id`, or [`JobError::NotFound`]. With a shared store (blocking: bucket requests)
    /// its progress is read from the bucket unless this process runs it, and a job submitted to
    /// another replica is loaded.
    pub fn find(&self, id: &str) -> Result<Arc<Job>, JobError> {
        let not_found = || JobError::NotFound(format!("no job '{id}'"));
        if !self.store.shared() {
            return self.get(id).ok_or_else(not_found);
        }
        if !valid_id(id) {
            return Err(not_found());
        }
        if let Some(job) = self.get(id) {
            if job.here() {
                return Ok(job);
            }
            if let Some(st) = self.store.load_status(id)? {
                job.refresh(st);
                return Ok(job);
            }
        }
        // Not known here, or its progress is gone (removed by another replica).
        match self.store.load(id)?.and_then(Job::from_stored) {
            Some(job) => {
                let job = Arc::new(job);
                let mut table = self.lock_table();
                let entry = table.entry(id.to_string()).or_insert_with(|| job.clone());
                if !entry.here() {
                    *entry = job.clone();
                }
                Ok(entry.clone())
            }
            None => {
                self.forget(id);
                Err(not_found())
            }
        }
    }

    /// Jobs waiting for a worker.
    pub fn queue_depth(&self) -> u64 {
        self.lock_queue().len() as u64
    }

    /// Jobs running now.
    pub fn running(&self) -> u64 {
        self.running.load(Ordering::Relaxed)
    }

    fn persist(&self, job: &Job, status: &JobStatus) {
        let removed = job.files.lock().unwrap_or_else(|e| e.into_inner());
        if *removed {
            return;
        }
        match self.store.save_status(&job.id, status) {
            Ok(n) => job.status_bytes.store(n, Ordering::Relaxed),
            Err(e) => tracing::warn!(job = %job.id, error = %e, "cannot persist job status"),
        }
    }

    /// Every job, oldest first.
    pub fn list(&self) -> Vec<Arc<Job>> {
        let mut all: Vec<Arc<Job>> = self.lock_table().values().cloned().collect();
        all.sort_by(|a, b| (a.status().created, &a.id).cmp(&(b.status().created, &b.id)));
        all
    }

    /// Jobs queued or running.
    pub fn live(&self) -> usize {
        self.lock_table()
            .values()
            .filter(|j| !j.status().finished())
            .count()
    }

    /// Bytes of all job files on disk (counted in the cache's disk budget; none when the jobs are
    /// in a bucket).
    pub fn disk_bytes(&self) -> u64 {
        if self.store.shared() {
            return 0;
        }
        self.lock_table()
            .values()
            .map(|j| j.body_bytes + j.status_bytes.load(Ordering::Relaxed))
            .sum()
    }

    /// Refuses a submission when `jobs.max_live` jobs are live or its body would not fit the
    /// disk budget.
    fn check_room(&self, body: &[u8], limits: &SubmitLimits) -> Result<(), JobError> {
        let live = self.live();
        if live >= limits.max_live {
            return Err(JobError::Full(format!(
                "{live} jobs are queued or running, the most jobs.max_live allows (limit {}); retry when one has finished",
                limits.max_live
            )));
        }
        let on_disk = self.disk_bytes();
        if on_disk + body.len() as u64 > limits.disk_bytes {
            return Err(JobError::Full(format!(
                "job files take {on_disk} bytes; this body ({} bytes) would exceed cache.disk_budget_bytes (limit {}); delete finished jobs (DELETE /v1/jobs/{{id}})",
                body.len(),
                limits.disk_bytes
            )));
        }
        Ok(())
    }

    /// Parses and validates a job body (every item), stores and queues it; returns the job.
    /// Refused ([`JobError::Full`]) when `limits.max_live` jobs are queued or running, or when the
    /// job files would exceed `limits.disk_bytes`.
    pub fn submit(&self, body: &[u8], limits: SubmitLimits) -> Result<Arc<Job>, JobError> {
        // With a bucket, the live jobs of every replica count (as of this listing).
        self.sync()?;
        // A quick refusal before the (possibly long) validation; checked again under the
        // admission lock below.
        self.check_room(body, &limits)?;
        let spec = JobSpec::parse_body(body, limits.max_products)?;
        if spec.has_bundles() {
            return Err(crate::Error::invalid(
                "bundles",
                "texture bundles are baked offline (skybake bake JOB.json --out DIR); the server serves one bundle per request (GET /v1/lut)",
            )
            .into());
        }
        if spec.has_cloud_lights() {
            return Err(crate::Error::invalid(
                "cloud_lights",
                "pre-lit cloud volumes are baked offline (skybake bake JOB.json --out DIR) or written by skybake cloud-light",
            )
            .into());
        }
        // A frame may name only the example scenes' files, as in a render.
        let cost = spec.validate_and_cost_loading(
            &self.defaults,
            Some(&skybake_product::frame::example_file),
        )?;
        spec.check_frame_memory(&self.defaults, limits.max_item_memory_bytes)?;
        if cost > limits.max_cost {
            return Err(crate::Error::too_large(
                "job_cost",
                format!(
                    "the job's estimated cost is {cost} units (products: each distinct table's cells × expected orders plus every output's cells, × wavelengths; frames: pixels × voxels × samples per pixel), over server.max_job_cost; split the job or lower its quality, sizes or wavelengths"
                ),
                limits.max_cost,
            )
            .into());
        }
        // Admission is atomic: the checks and the insertion under one lock.
        let _admission = self.admission.lock().unwrap_or_else(|e| e.into_inner());
        self.check_room(body, &limits)?;
        let id = format!("{:016x}", rand::random::<u64>());
        self.store.create(&id, body)?;
        let job = Arc::new(Job {
            id: id.clone(),
            status: Mutex::new(JobStatus::queued(spec.len())),
            spec,
            cancel: AtomicBool::new(false),
            body_bytes: body.len() as u64,
            status_bytes: AtomicU64::new(0),
            files: Mutex::new(false),
            here: AtomicBool::new(false),
        });
        let n = self.store.save_status(&id, &job.status())?;
        job.status_bytes.store(n, Ordering::Relaxed);
        self.lock_table().insert(id.clone(), job.clone());
        self.lock_queue().push_back(id);
        self.wake.notify_one();
        Ok(job)
    }

    /// Stops a queued or running job after its current item. With a shared store the request is
    /// stored for whichever replica runs the job (it stops within [`PERSIST_EVERY`] of its current
    /// item), and a job nobody runs is marked cancelled at once.
    pub fn cancel(&self, id: &str) -> Result<Arc<Job>, JobError> {
        let job = self.find(id)?;
        if job.status().finished() {
            return Ok(job);
        }
        job.cancel.store(true, Ordering::Relaxed);
        self.store.request_cancel(id)?;
        let was_queued = {
            let mut q = self.lock_queue();
            let before = q.len();
            q.retain(|x| x != id);
            q.len() != before
        };
        if self.store.shared() {
            if job.here() {
                return Ok(job);
            }
            // Nobody runs it (or its runner died): take its lease and end it here.
            if let Some(claim) = self.store.claim(id)? {
                if let Some(st) = self.store.load_status(id)? {
                    job.refresh(st);
                }
                if !job.status().finished() {
                    let st = job.update(|s| s.state = JobState::Cancelled);
                    self.store.save_status(&job.id, &st)?;
                }
                drop(claim);
            }
            return Ok(job);
        }
        if was_queued {
            let st = job.update(|s| s.state = JobState::Cancelled);
            self.store.save_status(&job.id, &st)?;
        }
        Ok(job)
    }

    /// `DELETE`: a finished job is removed with its files (`Ok((job, true))`); a queued or
    /// running one is cancelled (`Ok((job, false))`, delete it again once it has stopped).
    pub fn delete(&self, id: &str) -> Result<(Arc<Job>, bool), JobError> {
        let job = self.find(id)?;
        if !job.status().finished() {
            return Ok((self.cancel(id)?, false));
        }
        self.remove(&job)?;
        Ok((job, true))
    }

    /// Removes a job's files, then forgets it.
    fn remove(&self, job: &Job) -> Result<(), JobError> {
        {
            let mut removed = job.files.lock().unwrap_or_else(|e| e.into_inner());
            self.store.remove(&job.id)?;
            *removed = true;
        }
        self.lock_table().remove(&job.id);
        Ok(())
    }

    /// Removes finished jobs last updated more than `max_age_s` ago, with their files; returns
    /// how many.
    pub fn expire(&self, max_age_s: f64) -> usize {
        let old: Vec<Arc<Job>> = self
            .lock_table()
            .values()
            .filter(|j| {
                let st = j.status();
                st.finished() && st.age_s() > max_age_s
            })
            .cloned()
            .collect();
        let mut removed = 0;
        for job in old {
            match self.remove(&job) {
                Ok(()) => removed += 1,
                Err(e) => tracing::warn!(job = %job.id, error = %e, "cannot remove expired job"),
            }
        }
        removed
    }

    async fn next_job(&self) -> Arc<Job> {
        loop {
            let notified = self.wake.notified();
            let id = self.lock_queue().pop_front();
            if let Some(job) = id.and_then(|id| self.get(&id)) {
                return job;
            }
            notified.await;
        }
    }
}

/// Starts `workers` job workers on the current tokio runtime.
pub fn start_workers<P: Producer>(producer: &P, workers: usize) {
    for _ in 0..workers {
        let producer = producer.clone();
        tokio::spawn(async move {
            loop {
                let jobs = producer.jobs();
                let job = jobs.next_job().await;
                jobs.running.fetch_add(1, Ordering::Relaxed);
                run_job(&producer, &job).await;
                producer.jobs().running.fetch_sub(1, Ordering::Relaxed);
            }
        });
    }
}

/// Runs `f` on the job table on a blocking thread (bucket requests), off the async executor.
async fn off_executor<P: Producer, T: Send + 'static>(
    producer: &P,
    f: impl FnOnce(&Jobs) -> T + Send + 'static,
) -> Result<T, JobError> {
    let p = producer.clone();
    tokio::task::spawn_blocking(move || f(p.jobs()))
        .await
        .map_err(|e| JobError::Failure(format!("job store task failed: {e}")))
}

/// Takes the right to run `job` and reads the progress stored last: `None` when another process
/// runs it, or it has finished or gone meanwhile.
fn start(jobs: &Jobs, job: &Job) -> Result<Option<Claim>, JobError> {
    let Some(claim) = jobs.store.claim(&job.id)? else {
        return Ok(None);
    };
    let stored = if jobs.store.shared() {
        match jobs.store.load_status(&job.id)? {
            Some(st) => Some(st),
            // Removed by another replica.
            None if jobs.store.load(&job.id)?.is_none() => {
                jobs.forget(&job.id);
                return Ok(None);
            }
            None => None,
        }
    } else {
        None
    };
    {
        // Under the status lock, so a concurrent refresh from the store either comes before
        // (and is replaced here) or sees the job run here and leaves its status alone.
        let mut s = job.status.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(st) = stored {
            *s = st;
            if s.finished() {
                return Ok(None);
            }
        }
        job.here.store(true, Ordering::Relaxed);
    }
    if jobs.store.shared() && jobs.store.cancel_requested(&job.id)? {
        job.cancel.store(true, Ordering::Relaxed);
    }
    Ok(Some(claim))
}

/// Writes `status` unless the claim was lost, and picks up a cancellation stored by another
/// replica; false when the claim was lost (the job must stop without writing anything more).
fn checkpoint(jobs: &Jobs, job: &Job, claim: &Claim, status: &JobStatus) -> bool {
    if claim.lost() {
        return false;
    }
    jobs.persist(job, status);
    match jobs.store.cancel_requested(&job.id) {
        Ok(true) => job.cancel.store(true, Ordering::Relaxed),
        Ok(false) => {}
        Err(e) => tracing::warn!(job = %job.id, error = %e, "cannot read the job's cancellation"),
    }
    true
}

/// Runs `job` from its persisted `next` item on, if this process can claim it ([`Claim`]).
pub async fn run_job<P: Producer>(producer: &P, job: &Arc<Job>) {
    let jobs = producer.jobs();
    let j = job.clone();
    let claim = match off_executor(producer, move |jobs| start(jobs, &j)).await {
        Ok(Ok(Some(claim))) => claim,
        Ok(Ok(None)) => return,
        Ok(Err(e)) | Err(e) => {
            // Retried at the next sync (a bucket) or restart (a directory).
            tracing::warn!(job = %job.id, error = %e, "cannot start the job");
            return;
        }
    };
    let claim = Arc::new(claim);
    let shared = jobs.store.shared();
    let checkpoint_async = |status: JobStatus| {
        let (j, c) = (job.clone(), claim.clone());
        async move {
            if shared {
                off_executor(producer, move |jobs| checkpoint(jobs, &j, &c, &status))
                    .await
                    .unwrap_or(false)
            } else {
                checkpoint(producer.jobs(), &j, &c, &status)
            }
        }
    };
    let start = job.update(|s| s.state = JobState::Running);
    let mut kept = checkpoint_async(start.clone()).await;
    let mut last = Instant::now();
    let mut i = start.next;
    while kept && i < job.spec.len() {
        if job.cancel.load(Ordering::Relaxed) || claim.lost() {
            break;
        }
        let result = match job.spec.request(i, &jobs.defaults) {
            Ok(req) => producer.produce(req).await,
            Err(e) => Err(e),
        };
        let st = job.update(|s| {
            match &result {
                Ok(()) => s.done += 1,
                Err(e) => {
                    s.failed += 1;
                    if s.errors.len() < MAX_KEPT_ERRORS {
                        s.errors.push(ItemError {
                            index: i,
                            parameter: e.parameter(),
                            detail: e.to_string(),
                        });
                    }
                }
            }
            s.next = i + 1;
        });
        if last.elapsed() >= PERSIST_EVERY {
            last = Instant::now();
            kept = checkpoint_async(st).await;
        }
        i += 1;
    }
    if kept && !claim.lost() {
        let end = job.update(|s| {
            s.state = if job.cancel.load(Ordering::Relaxed) && s.next < s.total {
                JobState::Cancelled
            } else {
                JobState::Completed
            };
        });
        checkpoint_async(end).await;
    } else {
        tracing::warn!(job = %job.id, "job taken over by another replica; stopped here");
    }
    job.here.store(false, Ordering::Relaxed);
    // Releasing a lease deletes it in the bucket: off the executor.
    let _ = off_executor(producer, move |_| drop(claim)).await;
}
