//! The bucket's client over S3: `object_store`'s Amazon S3 store on a small runtime of its own,
//! one request per call (the retries are [`Bucket`](super::Bucket)'s).

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use object_store::aws::AmazonS3Builder;
use object_store::path::Path as ObjectPath;
use object_store::{
    ClientOptions, ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload, RetryConfig,
    UpdateVersion,
};

use super::{Answer, Failure, Listed, Listing, Outcome, Versioned, Write};
use crate::StoreError;

pub(super) struct Client {
    store: Arc<dyn ObjectStore>,
    /// `Some` until drop, which shuts it down without waiting (a drop may happen on an async
    /// thread, where waiting is not allowed).
    runtime: Option<tokio::runtime::Runtime>,
}

impl Drop for Client {
    fn drop(&mut self) {
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
    }
}

impl Client {
    /// Bucket `bucket` with the AWS environment variables, then `overrides`; `url` is for
    /// messages.
    pub(super) fn open(
        url: &str,
        bucket: &str,
        overrides: &[(&str, &str)],
        request_timeout: Duration,
    ) -> Result<Self, StoreError> {
        // TLS through rustls with ring (reqwest is built without a bundled provider); a provider
        // installed earlier by the process is kept.
        let _ = rustls::crypto::ring::default_provider().install_default();
        let mut builder = AmazonS3Builder::from_env().with_bucket_name(bucket);
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
            .with_timeout(request_timeout)
            .with_connect_timeout(Duration::from_secs(5));
        let store = builder
            .with_client_options(options)
            // The bucket's own retry loop counts and bounds the retries.
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
            store: Arc::new(store),
            runtime: Some(runtime),
        })
    }

    /// Runs `fut` on the bucket's runtime and waits for it on this thread (a blocking thread,
    /// possibly of another runtime, where `block_on` is not allowed).
    fn wait<T, Fut>(&self, fut: Fut) -> Result<Outcome<T>, Failure>
    where
        T: Send + 'static,
        Fut: Future<Output = object_store::Result<T>> + Send + 'static,
    {
        let Some(runtime) = &self.runtime else {
            return Err(Failure {
                reason: "bucket closed".into(),
                permanent: true,
            });
        };
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        runtime.spawn(async move {
            let _ = tx.send(fut.await);
        });
        let result = rx.recv().map_err(|_| Failure {
            reason: "bucket request dropped".into(),
            permanent: false,
        })?;
        match result {
            Ok(value) => Ok(Ok(value)),
            Err(object_store::Error::NotFound { .. }) => Ok(Err(Answer::NotFound)),
            Err(
                object_store::Error::Precondition { .. }
                | object_store::Error::AlreadyExists { .. },
            ) => Ok(Err(Answer::Precondition)),
            Err(error) => Err(Failure {
                permanent: matches!(
                    error,
                    object_store::Error::PermissionDenied { .. }
                        | object_store::Error::Unauthenticated { .. }
                        | object_store::Error::NotImplemented { .. }
                        | object_store::Error::NotSupported { .. }
                ),
                reason: error.to_string(),
            }),
        }
    }

    /// The object `key` and its entity tag; an object above `max_bytes` is a permanent failure.
    pub(super) fn get(&self, key: &str, max_bytes: u64) -> Result<Outcome<Versioned>, Failure> {
        let (store, path) = (self.store.clone(), ObjectPath::from(key));
        let outcome = self.wait(async move {
            let result = store.get(&path).await?;
            if result.meta.size > max_bytes {
                return Ok(Err(result.meta.size));
            }
            let e_tag = result.meta.e_tag.clone();
            let bytes = result.bytes().await?;
            Ok(Ok((bytes.to_vec(), e_tag)))
        })?;
        match outcome {
            Ok(Ok(found)) => Ok(Ok(found)),
            Ok(Err(size)) => Err(Failure {
                reason: format!("{key} is {size} bytes, above the {max_bytes}-byte limit"),
                permanent: true,
            }),
            Err(answer) => Ok(Err(answer)),
        }
    }

    /// Puts `bytes` as `key` per `mode`: the new entity tag.
    pub(super) fn put(
        &self,
        key: &str,
        bytes: &[u8],
        mode: &Write,
    ) -> Result<Outcome<String>, Failure> {
        let (store, path) = (self.store.clone(), ObjectPath::from(key));
        let payload = PutPayload::from(bytes.to_vec());
        let mode = match mode {
            Write::Overwrite => PutMode::Overwrite,
            Write::Create => PutMode::Create,
            Write::Replace(e_tag) => PutMode::Update(UpdateVersion {
                e_tag: Some(e_tag.clone()),
                version: None,
            }),
        };
        self.wait(async move {
            let options = PutOptions {
                mode,
                ..PutOptions::default()
            };
            let done = store.put_opts(&path, payload, options).await?;
            Ok(done.e_tag.unwrap_or_default())
        })
    }

    /// Deletes `key`.
    pub(super) fn delete(&self, key: &str) -> Result<Outcome<()>, Failure> {
        let (store, path) = (self.store.clone(), ObjectPath::from(key));
        self.wait(async move { store.delete(&path).await })
    }

    /// The objects directly under folder `key` and its subfolders' names.
    pub(super) fn list(&self, key: &str) -> Result<Outcome<Listing>, Failure> {
        let (store, path) = (self.store.clone(), ObjectPath::from(key));
        self.wait(async move {
            let listing = store.list_with_delimiter(Some(&path)).await?;
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
        })
    }
}
