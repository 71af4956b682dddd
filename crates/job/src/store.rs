//! Persistence of jobs (under `<cache dir>/jobs/<id>/`): `job.json` is the body as submitted,
//! `status.json` the progress ([`JobStatus`]), both written atomically through
//! [`skybake_store::write_atomic`]; reads go through [`skybake_store::files`]. Finished items are in
//! the product cache, so a resumed job requests the items from the persisted `next` on again and
//! those already computed are cache hits.

use super::JobError;
use serde::{Deserialize, Serialize};
use skybake_store::{files, write_atomic};
use std::path::{Path, PathBuf};

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

/// The job directory.
#[derive(Debug, Clone)]
pub struct JobStore {
    dir: PathBuf,
}

/// Whether `id` has the form of a job id (16 hex digits).
pub fn valid_id(id: &str) -> bool {
    id.len() == 16 && id.bytes().all(|b| b.is_ascii_hexdigit())
}

impl JobStore {
    /// Opens (creating) the job directory.
    pub fn open(dir: &Path) -> Result<Self, JobError> {
        files::create_dir_all(dir)?;
        Ok(Self {
            dir: dir.to_path_buf(),
        })
    }

    fn job_dir(&self, id: &str) -> PathBuf {
        self.dir.join(id)
    }

    /// Stores a new job's body.
    pub fn create(&self, id: &str, body: &[u8]) -> Result<(), JobError> {
        Ok(write_atomic(&self.job_dir(id).join("job.json"), body)?)
    }

    /// Stores a job's progress; returns the bytes written.
    pub fn save_status(&self, id: &str, status: &JobStatus) -> Result<u64, JobError> {
        let text = serde_json::to_vec_pretty(status)
            .map_err(|e| JobError::Failure(format!("encoding job status: {e}")))?;
        write_atomic(&self.job_dir(id).join("status.json"), &text)?;
        Ok(text.len() as u64)
    }

    /// Removes a job's files.
    pub fn remove(&self, id: &str) -> Result<(), JobError> {
        if !valid_id(id) {
            return Err(JobError::NotFound(format!("no job '{id}'")));
        }
        Ok(files::remove_dir_all(&self.job_dir(id))?)
    }

    /// Every stored job; a job that cannot be read is reported in the second list, as
    /// (job id, why).
    pub fn load_all(&self) -> Result<(Vec<StoredJob>, Vec<Unreadable>), JobError> {
        let mut jobs = Vec::new();
        let mut unreadable = Vec::new();
        for (id, dir) in files::subdirectories(&self.dir)? {
            if !valid_id(&id) {
                continue;
            }
            let load = || -> Result<StoredJob, String> {
                let body = files::read(&dir.join("job.json")).map_err(|e| e.to_string())?;
                let (status, status_bytes) = match files::read_if_exists(&dir.join("status.json"))
                    .map_err(|e| e.to_string())?
                {
                    Some(bytes) => (
                        Some(serde_json::from_slice(&bytes).map_err(|e| e.to_string())?),
                        bytes.len() as u64,
                    ),
                    None => (None, 0),
                };
                Ok(StoredJob {
                    id: id.clone(),
                    body,
                    status,
                    status_bytes,
                })
            };
            match load() {
                Ok(job) => jobs.push(job),
                Err(e) => unreadable.push((id, e)),
            }
        }
        Ok((jobs, unreadable))
    }
}
