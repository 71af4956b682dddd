//! The job table, the queue and the workers. A worker takes the next queued job and asks its
//! [`Producer`] for each item's artifact in turn (the service's producer is its product cache:
//! cached items are hits, the rest are computed once and stored), persisting progress as it goes.

use super::spec::{ItemRequest, JobSpec};
use super::store::{now, ItemError, JobState, JobStatus, JobStore};
use super::JobError;
use crate::product::params::Defaults;
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

/// Whatever turns a product request into a stored artifact.
pub trait Producer: Clone + Send + Sync + 'static {
    /// Makes sure the artifact of `req` (a product or a frame) exists (cached or computed now).
    fn produce(&self, req: ItemRequest) -> impl Future<Output = Result<(), JobError>> + Send;
    /// The job table the workers take jobs from.
    fn jobs(&self) -> &Jobs;
}

/// A job in memory.
pub struct Job {
    pub id: String,
    pub spec: JobSpec,
    status: Mutex<JobStatus>,
    cancel: AtomicBool,
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
        };
        let mut found = Vec::new();
        for s in stored {
            let spec = match JobSpec::parse_body(&s.body, crate::config::MAX_JOB_PRODUCTS_LIMIT) {
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
        if let Err(e) = self.store.save_status(&job.id, status) {
            tracing::warn!(job = %job.id, error = %e, "cannot persist job status");
        }
    }

    /// Parses and validates a job body (every item), stores and queues it; returns the job.
    pub fn submit(&self, body: &[u8], max_products: usize) -> Result<Arc<Job>, JobError> {
        let spec = JobSpec::parse_body(body, max_products)?;
        spec.validate(&self.defaults)?;
        let id = format!("{:016x}", rand::random::<u64>());
        self.store.create(&id, body)?;
        let job = Arc::new(Job {
            id: id.clone(),
            status: Mutex::new(JobStatus::queued(spec.len())),
            spec,
            cancel: AtomicBool::new(false),
        });
        self.store.save_status(&id, &job.status())?;
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
