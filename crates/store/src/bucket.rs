//! An S3-compatible bucket (`s3://bucket/prefix`) as a store of named objects, through the
//! `object_store` crate: whole-object get, put, conditional create and replace (for leases),
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

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use object_store::aws::AmazonS3Builder;
use object_store::path::Path as ObjectPath;
use object_store::{
    ClientOptions, ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload, RetryConfig,
    UpdateVersion,
};
use serde::Serialize;

use super::exr::MAX_FILE_BYTES;
use super::StoreError;

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
    store: Arc<dyn ObjectStore>,
    /// `Some` until drop, which shuts it down without waiting (a drop may happen on an async
    /// thread, where waiting is not allowed).
    runtime: Option<tokio::runtime::Runtime>,
    retry: RetryPolicy,
    counters: Counters,
}

impl std::fmt::Debug for Bucket {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bucket").field("url", &self.url).finish()
    }
}

impl Drop for Bucket {
    fn drop(&mut self) {
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
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
        // TLS through rustls with ring (reqwest is built without a bundled provider); a provider
        // installed earlier by the process is kept.
        let _ = rustls::crypto::ring::default_provider().install_default();
        let mut builder = AmazonS3Builder::from_env().with_bucket_name(&bucket);
        for (key, value) in overrides {
            let key = key.parse().map_err(|e| {
                crate::Error::invalid("cache_url", format!("bucket setting {key}: {e}"))
            })?;
            builder = builder.with_config(key, *value);
        }
        let endpoint =
            builder
                .get_config_value(&"aws_endpoint".parse().map_err(|e| {
                    crate::Error::invalid("cache_url", format!("bucket setting: {e}"))
                })?)
                .unwrap_or_default();
        let options = ClientOptions::new()
            .with_allow_http(endpoint.starts_with("http://"))
            .with_timeout(retry.request_timeout)
            .with_connect_timeout(Duration::from_secs(5));
        let store = builder
            .with_client_options(options)
            // Our own retry loop counts and bounds the retries.
            .with_retry(RetryConfig {
                max_retries: 0,
                ..RetryConfig::default()
            })
            .build()
            .map_err(|e| crate::Error::invalid("cache_url", format!("{url}: {e}")))?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("skybake-bucket")
            .enable_all()
            .build()
            .map_err(|e| StoreError::io("bucket runtime", e))?;
        Ok(Self {
            url: url.to_string(),
            prefix,
            store: Arc::new(store),
            runtime: Some(runtime),
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

    /// The object path of `name` (a `/`-separated name made by the store, never request text).
    fn path(&self, name: &str) -> ObjectPath {
        if self.prefix.is_empty() {
            ObjectPath::from(name)
        } else {
            ObjectPath::from(format!("{}/{name}", self.prefix))
        }
    }

    /// Runs `op` on the bucket's runtime, retrying failures per the policy; `Ok(Err(e))` is an
    /// answer that is not a failure (not found, precondition failed), returned at once.
    fn run<T, F, Fut>(&self, what: &str, name: &str, op: F) -> Result<Outcome<T>, StoreError>
    where
        T: Send + 'static,
        F: Fn(Arc<dyn ObjectStore>) -> Fut,
        Fut: Future<Output = object_store::Result<T>> + Send + 'static,
    {
        let Some(runtime) = &self.runtime else {
            return Err(self.unavailable(what, name, "bucket closed"));
        };
        let mut delay = self.retry.first_delay;
        let mut attempt = 1;
        loop {
            let (tx, rx) = std::sync::mpsc::sync_channel(1);
            let fut = op(self.store.clone());
            runtime.spawn(async move {
                let _ = tx.send(fut.await);
            });
            let result = rx
                .recv()
                .map_err(|_| self.unavailable(what, name, "bucket request dropped"))?;
            let error = match result {
                Ok(value) => return Ok(Ok(value)),
                Err(object_store::Error::NotFound { .. }) => return Ok(Err(Answer::NotFound)),
                Err(
                    object_store::Error::Precondition { .. }
                    | object_store::Error::AlreadyExists { .. },
                ) => return Ok(Err(Answer::Precondition)),
                Err(e) => e,
            };
            let permanent = matches!(
                error,
                object_store::Error::PermissionDenied { .. }
                    | object_store::Error::Unauthenticated { .. }
                    | object_store::Error::NotImplemented { .. }
                    | object_store::Error::NotSupported { .. }
            );
            if permanent || attempt >= self.retry.attempts {
                return Err(self.unavailable(what, name, &error.to_string()));
            }
            tracing::debug!(what, name, attempt, error = %error, "bucket request failed; retrying");
            self.counters.retries.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(delay);
            delay = (delay * 2).min(self.retry.max_delay);
            attempt += 1;
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
        let path = self.path(name);
        let outcome = self.run("get", name, |store| {
            let path = path.clone();
            async move {
                let result = store.get(&path).await?;
                let e_tag = result.meta.e_tag.clone();
                if result.meta.size > MAX_FILE_BYTES {
                    return Err(object_store::Error::Generic {
                        store: "skybake",
                        source: format!("{path} is {} bytes", result.meta.size).into(),
                    });
                }
                let bytes = result.bytes().await?;
                Ok((bytes.to_vec(), e_tag))
            }
        })?;
        match outcome {
            Ok(found) => Ok(Some(found)),
            Err(_) => Ok(None),
        }
    }

    /// Stores `bytes` as `name`, replacing any object there (an S3 put is atomic: readers see the
    /// old object or the whole new one).
    pub fn put(&self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.put_mode(name, bytes, PutMode::Overwrite).map(|_| ())
    }

    /// Creates `name` only if no object has that name (`If-None-Match: *`): `Some(entity tag)`,
    /// or `None` when one had.
    pub fn create(&self, name: &str, bytes: &[u8]) -> Result<Option<String>, StoreError> {
        self.put_mode(name, bytes, PutMode::Create)
    }

    /// Replaces `name` only if it still has entity tag `e_tag` (`If-Match`): `Some(new entity
    /// tag)`, or `None` when another writer changed or removed it meanwhile.
    pub fn replace(
        &self,
        name: &str,
        bytes: &[u8],
        e_tag: &str,
    ) -> Result<Option<String>, StoreError> {
        self.put_mode(
            name,
            bytes,
            PutMode::Update(UpdateVersion {
                e_tag: Some(e_tag.to_string()),
                version: None,
            }),
        )
    }

    fn put_mode(
        &self,
        name: &str,
        bytes: &[u8],
        mode: PutMode,
    ) -> Result<Option<String>, StoreError> {
        self.counters.puts.fetch_add(1, Ordering::Relaxed);
        let path = self.path(name);
        let payload = PutPayload::from(bytes.to_vec());
        let outcome = self.run("put", name, |store| {
            let (path, payload, mode) = (path.clone(), payload.clone(), mode.clone());
            async move {
                let options = PutOptions {
                    mode,
                    ..PutOptions::default()
                };
                let done = store.put_opts(&path, payload, options).await?;
                Ok(done.e_tag.unwrap_or_default())
            }
        })?;
        // A failed precondition, or a conditional replace of an object that is gone: `None`.
        Ok(outcome.ok())
    }

    /// Deletes `name` (an absent object is not an error).
    pub fn delete(&self, name: &str) -> Result<(), StoreError> {
        self.counters.deletes.fetch_add(1, Ordering::Relaxed);
        let path = self.path(name);
        self.run("delete", name, |store| {
            let path = path.clone();
            async move { store.delete(&path).await }
        })
        .map(|_| ())
    }

    /// The objects directly in folder `dir` (names relative to it) and its subfolders' names.
    pub fn list(&self, dir: &str) -> Result<(Vec<Listed>, Vec<String>), StoreError> {
        self.counters.lists.fetch_add(1, Ordering::Relaxed);
        let path = self.path(dir.trim_end_matches('/'));
        let outcome = self.run("list", dir, |store| {
            let path = path.clone();
            async move { store.list_with_delimiter(Some(&path)).await }
        })?;
        let Ok(listing) = outcome else {
            return Ok((Vec::new(), Vec::new()));
        };
        let objects = listing
            .objects
            .iter()
            .filter_map(|o| {
                Some(Listed {
                    name: o.location.filename()?.to_string(),
                    size_bytes: o.size,
                    modified_s: o.last_modified.timestamp(),
                })
            })
            .collect();
        let folders = listing
            .common_prefixes
            .iter()
            .filter_map(|p| Some(p.filename()?.to_string()))
            .collect();
        Ok((objects, folders))
    }
}

/// An answer that is not a failure: the object is absent, or a precondition failed.
enum Answer {
    NotFound,
    Precondition,
}

type Outcome<T> = Result<T, Answer>;

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
