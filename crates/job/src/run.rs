//! The job table, the queue and the workers. A worker takes the next queued job and asks its
//! [`Producer`] for each item's artifact in turn (the service's producer is its product cache:
//! cached items are hits, the rest are computed once and stored), persisting progress as it goes.

use super::spec::JobSpec;
use super::store::{now, ItemError, JobState, JobStatus, JobStore};
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
        let store = JobStore::open(dir)?;
        let (stored, unreadable) = store.load_all()?;
        for (id, why) in unreadable {
            tracing::warn!(job = %id, error = %why, "persisted job not loaded");
        }
        let jobs = Self {
            store,
            defaults,
            table: Mutex::new(HashMap::new()),
            queue: Mutex::new(VecDeque::new()),
            wake: tokio::sync::Notify::new(),
            running: AtomicU64::new(0),
            admission: Mutex::new(()),
        };
        let mut found = Vec::new();
        for s in stored {
            let spec =
                match JobSpec::parse_body(&s.body, skybake_product::config::MAX_JOB_PRODUCTS_LIMIT)
                {
                    Ok(spec) => spec,
                    Err(e) => {
                        tracing::warn!(job = %s.id, error = %e, "persisted job not loaded");
                        continue;
                    }
                };
            let status = s.status.unwrap_or_else(|| JobStatus::queued(spec.len()));
            if status.total != spec.len() {
                tracing::warn!(job = %s.id, "persisted status does not match the job");
                continue;
            }
            found.push(Job {
                id: s.id,
                spec,
                status: Mutex::new(status),
                cancel: AtomicBool::new(false),
                body_bytes: s.body.len() as u64,
                status_bytes: AtomicU64::new(s.status_bytes),
                files: Mutex::new(false),
            });
        }
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

    /// The job `id`, or [`JobError::NotFound`].
    pub fn find(&self, id: &str) -> Result<Arc<Job>, JobError> {
        self.get(id)
            .ok_or_else(|| JobError::NotFound(format!("no job '{id}'")))
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

    /// Bytes of all job files on disk (counted in the cache's disk budget).
    pub fn disk_bytes(&self) -> u64 {
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
        // A quick refusal before the (possibly long) validation; checked again under the
        // admission lock below.
        self.check_room(body, &limits)?;
        let spec = JobSpec::parse_body(body, limits.max_products)?;
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
        });
        let n = self.store.save_status(&id, &job.status())?;
        job.status_bytes.store(n, Ordering::Relaxed);
        self.lock_table().insert(id.clone(), job.clone());
        self.lock_queue().push_back(id);
        self.wake.notify_one();
        Ok(job)
    }

    /// Stops a queued or running job after its current item.
    pub fn cancel(&self, id: &str) -> Result<Arc<Job>, JobError> {
        let job = self.find(id)?;
        job.cancel.store(true, Ordering::Relaxed);
        let was_queued = {
            let mut q = self.lock_queue();
            let before = q.len();
            q.retain(|x| x != id);
            q.len() != before
        };
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

/// Runs `job` from its persisted `next` item on.
pub async fn run_job<P: Producer>(producer: &P, job: &Job) {
    let jobs = producer.jobs();
    let start = job.update(|s| s.state = JobState::Running);
    jobs.persist(job, &start);
    let mut last = Instant::now();
    for i in start.next..job.spec.len() {
        if job.cancel.load(Ordering::Relaxed) {
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
            jobs.persist(job, &st);
        }
    }
    let end = job.update(|s| {
        s.state = if job.cancel.load(Ordering::Relaxed) && s.next < s.total {
            JobState::Cancelled
        } else {
            JobState::Completed
        };
    });
    jobs.persist(job, &end);
}
