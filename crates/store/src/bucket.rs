//! An S3-compatible bucket (`s3://bucket/prefix`) as a store of named objects, through the
//! `object_store` crate (`bucket/s3.rs`): whole-object get, put, conditional create and replace (for leases),
//! delete and one-level listing, all blocking (call them from blocking threads, as every store
//! method). The bucket runs its requests on a small runtime of its own, so callers need none.
//!
//! - Configuration: the usual AWS environment variables (`AWS_ACCESS_KEY_ID`,
//!   `AWS_SECRET_ACCESS_KEY`, `AWS_SESSION_TOKEN`, `AWS_REGION`/`AWS_DEFAULT_REGION`,
//!   `AWS_ENDPOINT_URL` for an S3-compatible server, `AWS_ALLOW_HTTP`), read by
//!   `AmazonS3Builder::from_env`; an `http://` endpoint allows plain HTTP.
//! - Failures: a request that fails for a reason other than "not found" or a failed precondition
//!   is retried with exponential backoff ([`RetryPolicy`]); when the retries are spent the error is
//!   [`StoreError::Unavailable`] (the service answers 503 + Retry-After), never a partial object.
//! - Sizes: an object larger than [`MAX_FILE_BYTES`] is refused like a file of that size.
//! - Build: the client is the `s3` cargo feature (on in the container image, the deploy files and
//!   CI's bucket tests; off in the default build, which then keeps the local directory's smaller
//!   dependency tree). Without it, opening an `s3://` URL is an error that says how to build one
//!   with it ([`AVAILABLE`]).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use serde::Serialize;

use super::exr::MAX_FILE_BYTES;
use super::StoreError;

#[cfg(not(feature = "s3"))]
mod absent;
#[cfg(feature = "s3")]
mod s3;

#[cfg(not(feature = "s3"))]
use absent::Client;
#[cfg(feature = "s3")]
use s3::Client;

/// Whether this build can open buckets (the `s3` cargo feature).
pub const AVAILABLE: bool = cfg!(feature = "s3");

/// How failed requests are retried: `attempts` tries in all, waiting `first_delay`, then twice
/// that, … up to `max_delay` between them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RetryPolicy {
    pub attempts: u32,
    pub first_delay: Duration,
    pub max_delay: Duration,
    /// Longest one request may take (connect, send, receive).
    pub request_timeout: Duration,
}

impl Default for RetryPolicy {
    /// 5 tries over about 1.5 s of waiting (0.1, 0.2, 0.4, 0.8 s): rides out a restarting server or
    /// a throttled burst without keeping a request waiting long.
    fn default() -> Self {
        Self {
            attempts: 5,
            first_delay: Duration::from_millis(100),
            max_delay: Duration::from_secs(2),
            request_timeout: Duration::from_secs(30),
        }
    }
}

/// Request counters since the bucket was opened (for `/metrics` and the tests).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct BucketStats {
    pub gets: u64,
    pub puts: u64,
    pub deletes: u64,
    pub lists: u64,
    /// Requests repeated after a failure.
    pub retries: u64,
    /// Operations that failed after every retry (each surfaced as [`StoreError::Unavailable`]).
    pub failures: u64,
}

#[derive(Default)]
struct Counters {
    gets: AtomicU64,
    puts: AtomicU64,
    deletes: AtomicU64,
    lists: AtomicU64,
    retries: AtomicU64,
    failures: AtomicU64,
}

/// An opened bucket and prefix. See the module documentation.
pub struct Bucket {
    url: String,
    prefix: String,
    client: Client,
    retry: RetryPolicy,
    counters: Counters,
}

impl std::fmt::Debug for Bucket {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bucket").field("url", &self.url).finish()
    }
}

/// An object's bytes and its entity tag, if the server gives one ([`Bucket::get_versioned`]).
pub type Versioned = (Vec<u8>, Option<String>);

/// An object found by [`Bucket::list`]: its name relative to the listed folder, and its size.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Listed {
    pub name: String,
    pub size_bytes: u64,
    /// Seconds since the Unix epoch.
    pub modified_s: i64,
}

/// A folder's objects and its subfolders' names ([`Bucket::list`]).
pub type Listing = (Vec<Listed>, Vec<String>);

/// True when `url` names a bucket (`s3://…`) rather than a directory.
pub fn is_bucket_url(url: &str) -> bool {
    url.starts_with("s3://")
}

/// Splits `s3://bucket/prefix` into the bucket name and the prefix (no leading or trailing `/`).
fn parse_url(url: &str) -> Result<(String, String), StoreError> {
    let bad = |why: &str| -> StoreError {
        crate::Error::invalid(
            "cache_url",
            format!("{url}: {why} (expected s3://bucket/prefix)"),
        )
        .into()
    };
    let rest = url
        .strip_prefix("s3://")
        .ok_or_else(|| bad("not an s3:// URL"))?;
    let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
    let valid_bucket = (3..=63).contains(&bucket.len())
        && bucket
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-' || b == b'.');
    if !valid_bucket {
        return Err(bad(
            "bucket names are 3 to 63 lowercase letters, digits, '-' or '.'",
        ));
    }
    let prefix = prefix.trim_matches('/');
    if prefix
        .split('/')
        .any(|p| p == "." || p == ".." || (p.is_empty() && !prefix.is_empty()))
    {
        return Err(bad("the prefix has an empty, '.' or '..' segment"));
    }
    Ok((bucket.to_string(), prefix.to_string()))
}

impl Bucket {
    /// Opens `s3://bucket/prefix` with the AWS environment variables, then `overrides`
    /// (`object_store` AWS configuration keys such as `aws_endpoint`, `aws_access_key_id`;
    /// tests pass their server here instead of changing the environment).
    pub fn open(
        url: &str,
        overrides: &[(&str, &str)],
        retry: RetryPolicy,
    ) -> Result<Self, StoreError> {
        let (bucket, prefix) = parse_url(url)?;
        let client = Client::open(url, &bucket, overrides, retry.request_timeout)?;
        Ok(Self {
            url: url.to_string(),
            prefix,
            client,
            retry,
            counters: Counters::default(),
        })
    }

    /// The URL it was opened with.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The request counters.
    pub fn stats(&self) -> BucketStats {
        let c = &self.counters;
        BucketStats {
            gets: c.gets.load(Ordering::Relaxed),
            puts: c.puts.load(Ordering::Relaxed),
            deletes: c.deletes.load(Ordering::Relaxed),
            lists: c.lists.load(Ordering::Relaxed),
            retries: c.retries.load(Ordering::Relaxed),
            failures: c.failures.load(Ordering::Relaxed),
        }
    }

    /// The object key of `name` (a `/`-separated name made by the store, never request text).
    fn key(&self, name: &str) -> String {
        if self.prefix.is_empty() {
            name.to_string()
        } else {
            format!("{}/{name}", self.prefix)
        }
    }

    /// Runs one request `attempt` after another per the retry policy until it gives an answer;
    /// `Ok(Err(e))` is an answer that is not a failure (not found, precondition failed).
    fn run<T>(
        &self,
        what: &str,
        name: &str,
        attempt: impl Fn() -> Result<Outcome<T>, Failure>,
    ) -> Result<Outcome<T>, StoreError> {
        let mut delay = self.retry.first_delay;
        let mut tries = 1;
        loop {
            let failure = match attempt() {
                Ok(answer) => return Ok(answer),
                Err(failure) => failure,
            };
            if failure.permanent || tries >= self.retry.attempts {
                return Err(self.unavailable(what, name, &failure.reason));
            }
            tracing::debug!(what, name, tries, error = %failure.reason, "bucket request failed; retrying");
            self.counters.retries.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(delay);
            delay = (delay * 2).min(self.retry.max_delay);
            tries += 1;
        }
    }

    fn unavailable(&self, what: &str, name: &str, why: &str) -> StoreError {
        self.counters.failures.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(bucket = %self.url, what, name, error = why, "bucket unavailable");
        StoreError::Unavailable {
            what: format!("{what} {name} in {}", self.url),
            reason: why.to_string(),
            retry_after_s: self.retry_after_s(),
        }
    }

    /// Seconds a client should wait before retrying after a failure: the policy's whole backoff.
    pub fn retry_after_s(&self) -> u64 {
        let mut total = Duration::ZERO;
        let mut delay = self.retry.first_delay;
        for _ in 1..self.retry.attempts {
            total += delay;
            delay = (delay * 2).min(self.retry.max_delay);
        }
        total.as_secs().max(1)
    }

    /// The object `name`, or `None` when there is none.
    pub fn get(&self, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        Ok(self.get_versioned(name)?.map(|(bytes, _)| bytes))
    }

    /// The object `name` and its entity tag (for [`Self::replace`]), or `None`.
    pub fn get_versioned(&self, name: &str) -> Result<Option<Versioned>, StoreError> {
        self.counters.gets.fetch_add(1, Ordering::Relaxed);
        let key = self.key(name);
        Ok(self
            .run("get", name, || self.client.get(&key, MAX_FILE_BYTES))?
            .ok())
    }

    /// Stores `bytes` as `name`, replacing any object there (an S3 put is atomic: readers see the
    /// old object or the whole new one).
    pub fn put(&self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.write(name, bytes, &Write::Overwrite).map(|_| ())
    }

    /// Creates `name` only if no object has that name (`If-None-Match: *`): `Some(entity tag)`,
    /// or `None` when one had.
    pub fn create(&self, name: &str, bytes: &[u8]) -> Result<Option<String>, StoreError> {
        self.write(name, bytes, &Write::Create)
    }

    /// Replaces `name` only if it still has entity tag `e_tag` (`If-Match`): `Some(new entity
    /// tag)`, or `None` when another writer changed or removed it meanwhile.
    pub fn replace(
        &self,
        name: &str,
        bytes: &[u8],
        e_tag: &str,
    ) -> Result<Option<String>, StoreError> {
        self.write(name, bytes, &Write::Replace(e_tag.to_string()))
    }

    fn write(&self, name: &str, bytes: &[u8], mode: &Write) -> Result<Option<String>, StoreError> {
        self.counters.puts.fetch_add(1, Ordering::Relaxed);
        let key = self.key(name);
        // A failed precondition, or a conditional replace of an object that is gone: `None`.
        Ok(self
            .run("put", name, || self.client.put(&key, bytes, mode))?
            .ok())
    }

    /// Deletes `name` (an absent object is not an error).
    pub fn delete(&self, name: &str) -> Result<(), StoreError> {
        self.counters.deletes.fetch_add(1, Ordering::Relaxed);
        let key = self.key(name);
        self.run("delete", name, || self.client.delete(&key))
            .map(|_| ())
    }

    /// The objects directly in folder `dir` (names relative to it) and its subfolders' names.
    pub fn list(&self, dir: &str) -> Result<Listing, StoreError> {
        self.counters.lists.fetch_add(1, Ordering::Relaxed);
        let key = self.key(dir.trim_end_matches('/'));
        Ok(self
            .run("list", dir, || self.client.list(&key))?
            .unwrap_or_default())
    }
}

/// How a put treats an object already under its name.
// Read and made only by a client, which a build without `s3` does not have.
#[cfg_attr(not(feature = "s3"), allow(dead_code))]
enum Write {
    /// Replace it.
    Overwrite,
    /// Only create: fail the precondition when there is one.
    Create,
    /// Only replace the version with this entity tag.
    Replace(String),
}

/// An answer that is not a failure: the object is absent, or a precondition failed.
#[cfg_attr(not(feature = "s3"), allow(dead_code))]
enum Answer {
    NotFound,
    Precondition,
}

type Outcome<T> = Result<T, Answer>;

/// A request that failed: `permanent` ones (denied, unsupported, too large) are not retried.
struct Failure {
    reason: String,
    permanent: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_name_a_bucket_and_a_clean_prefix() {
        assert_eq!(
            parse_url("s3://sky-cache/prod/v1/").unwrap(),
            ("sky-cache".into(), "prod/v1".into())
        );
        assert_eq!(
            parse_url("s3://sky-cache").unwrap(),
            ("sky-cache".into(), String::new())
        );
        for bad in [
            "sky-cache/x",
            "s3://",
            "s3://Upper/x",
            "s3://ab/x",
            "s3://b_c_d/x",
            "s3://bucket/a/../b",
            "s3://bucket/a//b",
        ] {
            assert!(parse_url(bad).is_err(), "{bad}");
        }
        assert!(is_bucket_url("s3://a"));
        assert!(!is_bucket_url("/var/cache"));
    }
}
