//! Leases in a bucket: at most one holder computes a given product at a time across processes and
//! machines. A lease is a small JSON object (`{"holder", "expires_unix_ms"}`) created with a
//! conditional write (`If-None-Match: *`); its holder renews it before it expires (a conditional
//! replace, `If-Match` on the entity tag it wrote) and deletes it when done. A lease whose expiry
//! has passed (its holder crashed or was cut off) is taken over by a conditional replace, so
//! exactly one contender wins it. Expiry compares the holders' wall clocks: they must agree to
//! well within the lease's duration (NTP does).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use serde::{Deserialize, Serialize};

use super::bucket::Bucket;
use super::StoreError;

#[derive(Serialize, Deserialize)]
struct LeaseBody {
    holder: String,
    expires_unix_ms: u64,
}

fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap_or_default()
        .as_millis() as u64
}

/// The outcome of [`Lease::try_acquire`].
#[derive(Debug)]
pub enum Acquired {
    /// This process holds the lease now; it renews it until dropped, then deletes it.
    Held(Lease),
    /// Another holder has it, for at most this much longer unless renewed.
    Busy {
        holder: String,
        expires_in: Duration,
    },
}

/// A lease this process holds; renewed by a background thread every third of its duration and
/// deleted when dropped.
#[derive(Debug)]
pub struct Lease {
    shared: Arc<Shared>,
    renewer: Option<std::thread::JoinHandle<()>>,
}

#[derive(Debug)]
struct Shared {
    bucket: Arc<Bucket>,
    name: String,
    holder: String,
    duration: Duration,
    e_tag: Mutex<String>,
    stop: AtomicBool,
    lost: AtomicBool,
}

impl Shared {
    fn body(&self) -> Vec<u8> {
        let body = LeaseBody {
            holder: self.holder.clone(),
            expires_unix_ms: now_ms() + self.duration.as_millis() as u64,
        };
        serde_json::to_vec(&body).unwrap_or_default()
    }

    /// Extends the lease; false when it was taken over or removed meanwhile.
    fn renew(&self) -> Result<bool, StoreError> {
        let e_tag = self.e_tag.lock().unwrap_or_else(|e| e.into_inner()).clone();
        match self.bucket.replace(&self.name, &self.body(), &e_tag)? {
            Some(new_tag) => {
                *self.e_tag.lock().unwrap_or_else(|e| e.into_inner()) = new_tag;
                Ok(true)
            }
            None => Ok(false),
        }
    }
}

impl Lease {
    /// Tries to take the lease `name` for `holder` (a name unique to this process) for `duration`:
    /// creates it, or takes it over when its holder let it expire.
    pub fn try_acquire(
        bucket: &Arc<Bucket>,
        name: &str,
        holder: &str,
        duration: Duration,
    ) -> Result<Acquired, StoreError> {
        let shared = Shared {
            bucket: bucket.clone(),
            name: name.to_string(),
            holder: holder.to_string(),
            duration,
            e_tag: Mutex::new(String::new()),
            stop: AtomicBool::new(false),
            lost: AtomicBool::new(false),
        };
        // Two rounds: the lease may be deleted between a failed create and the read.
        for _ in 0..2 {
            if let Some(e_tag) = bucket.create(name, &shared.body())? {
                *shared.e_tag.lock().unwrap_or_else(|e| e.into_inner()) = e_tag;
                return Ok(Acquired::Held(Self::start(shared)));
            }
            let Some((bytes, e_tag)) = bucket.get_versioned(name)? else {
                continue;
            };
            let current: Option<LeaseBody> = serde_json::from_slice(&bytes).ok();
            let now = now_ms();
            match current {
                Some(body) if body.expires_unix_ms > now => {
                    return Ok(Acquired::Busy {
                        holder: body.holder,
                        expires_in: Duration::from_millis(body.expires_unix_ms - now),
                    })
                }
                // Expired, or unreadable (a torn lease cannot be: puts are atomic): take it over
                // if nobody else did first.
                expired => {
                    let Some(e_tag) = e_tag else {
                        return Err(StoreError::Unavailable {
                            what: format!("lease {name}"),
                            reason: "the bucket returns no entity tags".into(),
                            retry_after_s: 1,
                        });
                    };
                    if let Some(new_tag) = bucket.replace(name, &shared.body(), &e_tag)? {
                        tracing::info!(
                            name,
                            previous = expired.map(|b| b.holder).unwrap_or_default(),
                            "took over an expired lease"
                        );
                        *shared.e_tag.lock().unwrap_or_else(|e| e.into_inner()) = new_tag;
                        return Ok(Acquired::Held(Self::start(shared)));
                    }
                }
            }
        }
        Ok(Acquired::Busy {
            holder: String::new(),
            expires_in: duration,
        })
    }

    fn start(shared: Shared) -> Self {
        let shared = Arc::new(shared);
        let renewing = shared.clone();
        let renewer = std::thread::Builder::new()
            .name("skybake-lease".into())
            .spawn(move || {
                let period = renewing.duration / 3;
                let step = Duration::from_millis(20).min(period);
                let mut waited = Duration::ZERO;
                while !renewing.stop.load(Ordering::Relaxed) {
                    std::thread::sleep(step);
                    waited += step;
                    if waited < period {
                        continue;
                    }
                    waited = Duration::ZERO;
                    match renewing.renew() {
                        Ok(true) => {}
                        Ok(false) => {
                            tracing::warn!(name = renewing.name, "lease lost to another holder");
                            renewing.lost.store(true, Ordering::Relaxed);
                            return;
                        }
                        // Retried at the next period; the lease may expire meanwhile.
                        Err(e) => {
                            tracing::warn!(name = renewing.name, error = %e, "lease not renewed")
                        }
                    }
                }
            })
            .ok();
        Self { shared, renewer }
    }

    /// Whether another holder took the lease over (this one failed to renew it in time).
    pub fn lost(&self) -> bool {
        self.shared.lost.load(Ordering::Relaxed)
    }
}

impl Drop for Lease {
    /// Stops renewing and deletes the lease if it is still this holder's.
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(renewer) = self.renewer.take() {
            let _ = renewer.join();
        }
        if self.lost() {
            return;
        }
        let s = &self.shared;
        let ours = s.e_tag.lock().unwrap_or_else(|e| e.into_inner()).clone();
        // Best effort: a lease left behind expires.
        if let Ok(Some((_, Some(e_tag)))) = s.bucket.get_versioned(&s.name) {
            if e_tag == ours {
                let _ = s.bucket.delete(&s.name);
            }
        }
    }
}
