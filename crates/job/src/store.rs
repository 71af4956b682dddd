//! Persistence of jobs (under `<cache dir>/jobs/<id>/`, or `jobs/<id>/` in a bucket that replicas
//! share): `job.json` is the body as submitted, `status.json` the progress ([`JobStatus`]), both
//! written atomically ([`skybake_store::write_atomic`], or one S3 put); reads go through
//! [`skybake_store::files`] or the bucket. In a bucket the replica running a job holds its lease
//! ([`Claim`]) and is the only writer of its progress. Finished items are in
//! the product cache, so a resumed job requests the items from the persisted `next` on again and
//! those already computed are cache hits.

use super::JobError;
use serde::{Deserialize, Serialize};
use skybake_store::lease::{Acquired, Lease};
use skybake_store::{files, write_atomic, Bucket};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// A stored job that cannot be read: (job id, why).
pub type Unreadable = (String, String);

/// Job lifecycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    Queued,
    Running,
    Completed,
    Cancelled,
}

/// One failed item.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ItemError {
    pub index: usize,
    pub parameter: Option<String>,
    pub detail: String,
}

/// Persisted progress.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobStatus {
    pub state: JobState,
    /// Items before this index are finished (done or failed).
    pub next: usize,
    pub done: usize,
    pub failed: usize,
    pub total: usize,
    pub errors: Vec<ItemError>,
    pub created: String,
    pub updated: String,
}

/// Now, as RFC 3339 UTC with milliseconds.
pub fn now() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

impl JobStatus {
    /// A queued job of `total` items, nothing done yet.
    /// Whether the job has ended (completed or cancelled): it expires, and `DELETE` removes it.
    pub fn finished(&self) -> bool {
        matches!(self.state, JobState::Completed | JobState::Cancelled)
    }

    /// Seconds since the last update (0 when the stamp cannot be read).
    pub fn age_s(&self) -> f64 {
        chrono::DateTime::parse_from_rfc3339(&self.updated)
            .map(|t| {
                (chrono::Utc::now() - t.with_timezone(&chrono::Utc)).num_milliseconds() as f64 / 1e3
            })
            .unwrap_or(0.0)
    }

    pub fn queued(total: usize) -> Self {
        let t = now();
        Self {
            state: JobState::Queued,
            next: 0,
            done: 0,
            failed: 0,
            total,
            errors: Vec::new(),
            created: t.clone(),
            updated: t,
        }
    }
}

/// A job found on disk.
#[derive(Debug, Clone)]
pub struct StoredJob {
    pub id: String,
    pub body: Vec<u8>,
    /// `None` when the job was stored but its progress never was.
    pub status: Option<JobStatus>,
    /// Bytes of `status.json` (0 when absent).
    pub status_bytes: u64,
}

/// Where jobs are kept: a local directory (one process), or a bucket folder that replicas
/// share.
#[derive(Debug, Clone)]
enum Backend {
    Dir(PathBuf),
    /// `jobs/` in the shared bucket; `holder` names this process on the job leases it takes,
    /// for `lease` at a time (renewed while it runs the job).
    Bucket {
        bucket: Arc<Bucket>,
        holder: String,
        lease: Duration,
    },
}

/// Where a job's files are: `<dir>/<id>/` on disk, or `jobs/<id>/` in a bucket (`job.json`,
/// `status.json`, and with a bucket `cancel`, written by any replica to stop the job, and
/// `lease`, held by the replica running it).
#[derive(Debug, Clone)]
pub struct JobStore {
    backend: Backend,
}

/// The right to run a job and write its progress: always granted for a directory (one process
/// owns it); with a bucket, a lease on `jobs/<id>/lease` that the holder renews while it runs
/// the job, so a replica that dies lets another continue once the lease has expired.
#[derive(Debug)]
pub enum Claim {
    Local,
    Lease(Lease),
}

impl Claim {
    /// Whether another replica took the job over (this one could not renew its lease in time):
    /// the job must stop here without writing its progress.
    pub fn lost(&self) -> bool {
        match self {
            Claim::Local => false,
            Claim::Lease(lease) => lease.lost(),
        }
    }
}

/// Whether `id` has the form of a job id (16 hex digits).
pub fn valid_id(id: &str) -> bool {
    id.len() == 16 && id.bytes().all(|b| b.is_ascii_hexdigit())
}

/// The object names of one job in a bucket.
fn object(id: &str, file: &str) -> String {
    format!("jobs/{id}/{file}")
}

fn parse_status(bytes: &[u8]) -> Result<JobStatus, String> {
    serde_json::from_slice(bytes).map_err(|e| e.to_string())
}

impl JobStore {
    /// Opens (creating) the job directory.
    pub fn open(dir: &Path) -> Result<Self, JobError> {
        files::create_dir_all(dir)?;
        Ok(Self {
            backend: Backend::Dir(dir.to_path_buf()),
        })
    }

    /// The jobs under `jobs/` in `bucket`, shared by every replica that opens it; `holder` names
    /// this process on job leases (unique per process) held for `lease` at a time.
    pub fn in_bucket(bucket: Arc<Bucket>, holder: &str, lease: Duration) -> Self {
        Self {
            backend: Backend::Bucket {
                bucket,
                holder: holder.to_string(),
                lease,
            },
        }
    }

    /// Whether other processes share these jobs (a bucket).
    pub fn shared(&self) -> bool {
        matches!(self.backend, Backend::Bucket { .. })
    }

    fn job_dir(dir: &Path, id: &str) -> PathBuf {
        dir.join(id)
    }

    /// Stores a new job's body.
    pub fn create(&self, id: &str, body: &[u8]) -> Result<(), JobError> {
        match &self.backend {
            Backend::Dir(dir) => Ok(write_atomic(
                &Self::job_dir(dir, id).join("job.json"),
                body,
            )?),
            Backend::Bucket { bucket, .. } => Ok(bucket.put(&object(id, "job.json"), body)?),
        }
    }

    /// Stores a job's progress; returns the bytes written.
    pub fn save_status(&self, id: &str, status: &JobStatus) -> Result<u64, JobError> {
        let text = serde_json::to_vec_pretty(status)
            .map_err(|e| JobError::Failure(format!("encoding job status: {e}")))?;
        match &self.backend {
            Backend::Dir(dir) => write_atomic(&Self::job_dir(dir, id).join("status.json"), &text)?,
            Backend::Bucket { bucket, .. } => bucket.put(&object(id, "status.json"), &text)?,
        }
        Ok(text.len() as u64)
    }

    /// A job's stored progress (`None` when the job is gone or its progress was never stored).
    pub fn load_status(&self, id: &str) -> Result<Option<JobStatus>, JobError> {
        let bytes = match &self.backend {
            Backend::Dir(dir) => {
                files::read_if_exists(&Self::job_dir(dir, id).join("status.json"))?
            }
            Backend::Bucket { bucket, .. } => bucket.get(&object(id, "status.json"))?,
        };
        bytes
            .map(|b| parse_status(&b))
            .transpose()
            .map_err(|e| JobError::Failure(format!("job {id}: status: {e}")))
    }

    /// Removes a job's files.
    pub fn remove(&self, id: &str) -> Result<(), JobError> {
        if !valid_id(id) {
            return Err(JobError::NotFound(format!("no job '{id}'")));
        }
        match &self.backend {
            Backend::Dir(dir) => Ok(files::remove_dir_all(&Self::job_dir(dir, id))?),
            Backend::Bucket { bucket, .. } => {
                // The body last: a job whose body is gone is gone for every replica.
                for file in ["status.json", "cancel", "lease", "job.json"] {
                    bucket.delete(&object(id, file))?;
                }
                Ok(())
            }
        }
    }

    /// Asks whichever process runs job `id` to stop it (a bucket's `cancel` object; a directory
    /// has one process, which is told directly).
    pub fn request_cancel(&self, id: &str) -> Result<(), JobError> {
        match &self.backend {
            Backend::Dir(_) => Ok(()),
            Backend::Bucket { bucket, .. } => Ok(bucket.put(&object(id, "cancel"), b"{}")?),
        }
    }

    /// Whether some process asked for job `id` to stop ([`Self::request_cancel`]).
    pub fn cancel_requested(&self, id: &str) -> Result<bool, JobError> {
        match &self.backend {
            Backend::Dir(_) => Ok(false),
            Backend::Bucket { bucket, .. } => Ok(bucket.get(&object(id, "cancel"))?.is_some()),
        }
    }

    /// The right to run job `id` ([`Claim`]), or `None` while another replica holds it.
    pub fn claim(&self, id: &str) -> Result<Option<Claim>, JobError> {
        match &self.backend {
            Backend::Dir(_) => Ok(Some(Claim::Local)),
            Backend::Bucket {
                bucket,
                holder,
                lease,
            } => Ok(
                match Lease::try_acquire(bucket, &object(id, "lease"), holder, *lease)? {
                    Acquired::Held(lease) => Some(Claim::Lease(lease)),
                    Acquired::Busy { .. } => None,
                },
            ),
        }
    }

    /// The job `id`, or `None` when there is no such job.
    pub fn load(&self, id: &str) -> Result<Option<StoredJob>, JobError> {
        if !valid_id(id) {
            return Ok(None);
        }
        let read = |file: &str| -> Result<Option<Vec<u8>>, JobError> {
            Ok(match &self.backend {
                Backend::Dir(dir) => files::read_if_exists(&Self::job_dir(dir, id).join(file))?,
                Backend::Bucket { bucket, .. } => bucket.get(&object(id, file))?,
            })
        };
        let Some(body) = read("job.json")? else {
            return Ok(None);
        };
        let (status, status_bytes) = match read("status.json")? {
            Some(bytes) => (
                Some(
                    parse_status(&bytes)
                        .map_err(|e| JobError::Failure(format!("job {id}: status: {e}")))?,
                ),
                bytes.len() as u64,
            ),
            None => (None, 0),
        };
        Ok(Some(StoredJob {
            id: id.to_string(),
            body,
            status,
            status_bytes,
        }))
    }

    /// The ids of every stored job (directories or bucket folders named like job ids).
    pub fn ids(&self) -> Result<Vec<String>, JobError> {
        let names = match &self.backend {
            Backend::Dir(dir) => files::subdirectories(dir)?
                .into_iter()
                .map(|(id, _)| id)
                .collect(),
            Backend::Bucket { bucket, .. } => bucket.list("jobs")?.1,
        };
        Ok(names.into_iter().filter(|id| valid_id(id)).collect())
    }

    /// Every stored job; a job that cannot be read is reported in the second list, as
    /// (job id, why).
    pub fn load_all(&self) -> Result<(Vec<StoredJob>, Vec<Unreadable>), JobError> {
        let mut jobs = Vec::new();
        let mut unreadable = Vec::new();
        for id in self.ids()? {
            match self.load(&id) {
                Ok(Some(job)) => jobs.push(job),
                // Removed meanwhile (or a folder left without its body).
                Ok(None) => {}
                Err(e) => unreadable.push((id, e.to_string())),
            }
        }
        Ok((jobs, unreadable))
    }
}
