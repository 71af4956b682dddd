//! The S3-compatible test server of the bucket tests: its endpoint comes from
//! `SKYBAKE_TEST_S3_ENDPOINT` (`.ci/run` starts one on loopback, creates the bucket [`BUCKET`]
//! and runs these tests with `--features s3`); without it those tests print why and pass without
//! checking anything. Each test
//! works under a prefix of its own. [`Proxy`] stands between a client and the server so a test
//! can cut the bucket off (connections refused) and bring it back.
#![allow(dead_code)]

use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{SystemTime, UNIX_EPOCH};

use skybake_store::{Bucket, RetryPolicy};

/// The bucket `.ci/run` creates on the test server.
pub const BUCKET: &str = "skybake-test";

/// The test server's endpoint, or `None` after printing why the calling test checks nothing.
/// A server set for a test build without the `s3` feature is a mistake, not a skip: it panics.
pub fn endpoint(test: &str) -> Option<String> {
    match std::env::var("SKYBAKE_TEST_S3_ENDPOINT") {
        Ok(e) if !e.trim().is_empty() => {
            if !skybake_store::bucket::AVAILABLE {
                panic!(
                    "SKYBAKE_TEST_S3_ENDPOINT is set but the tests were built without the S3 \
                     backend: run them with `cargo test --release --locked --features s3`"
                );
            }
            Some(e.trim().to_string())
        }
        _ => {
            eprintln!(
                "SKIPPED {test}: SKYBAKE_TEST_S3_ENDPOINT is not set (.ci/run starts an S3 server on loopback and sets it)"
            );
            None
        }
    }
}

/// A fresh `s3://` URL under the test bucket.
pub fn fresh_url(test: &str) -> String {
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!("s3://{BUCKET}/{test}-{}-{nanos}", std::process::id())
}

/// Static test credentials (the test server accepts any).
pub fn overrides(endpoint: &str) -> Vec<(&'static str, String)> {
    vec![
        ("aws_endpoint", endpoint.to_string()),
        ("aws_access_key_id", "skybake-test".into()),
        ("aws_secret_access_key", "skybake-test".into()),
        ("aws_region", "us-east-1".into()),
    ]
}

/// Opens `url` on the server at `endpoint` with `retry`.
pub fn open(url: &str, endpoint: &str, retry: RetryPolicy) -> Arc<Bucket> {
    let o = overrides(endpoint);
    let pairs: Vec<(&str, &str)> = o.iter().map(|(k, v)| (*k, v.as_str())).collect();
    Arc::new(Bucket::open(url, &pairs, retry).expect("open the test bucket"))
}

/// Quick retries, so the fault tests do not wait long.
pub fn quick_retry() -> RetryPolicy {
    RetryPolicy {
        attempts: 3,
        first_delay: std::time::Duration::from_millis(20),
        max_delay: std::time::Duration::from_millis(100),
        request_timeout: std::time::Duration::from_secs(10),
    }
}

/// Sets the AWS environment of a `skybake` process for the server at `endpoint`.
pub fn aws_env(cmd: &mut Command, endpoint: &str) {
    cmd.env("AWS_ENDPOINT_URL", endpoint)
        .env("AWS_ACCESS_KEY_ID", "skybake-test")
        .env("AWS_SECRET_ACCESS_KEY", "skybake-test")
        .env("AWS_REGION", "us-east-1")
        .env("AWS_ALLOW_HTTP", "true");
}

/// A TCP relay on loopback to the test server that can be stopped (every connection closed, new
/// ones refused) and started again on the same port.
pub struct Proxy {
    pub port: u16,
    upstream: String,
    runtime: tokio::runtime::Runtime,
    tasks: Arc<Mutex<Vec<tokio::task::JoinHandle<()>>>>,
}

impl Proxy {
    /// A running relay to `endpoint` (`http://host:port`).
    pub fn start(endpoint: &str) -> Self {
        let upstream = endpoint
            .trim_start_matches("http://")
            .trim_end_matches('/')
            .to_string();
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        let port = runtime.block_on(async {
            let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
            l.local_addr().unwrap().port()
        });
        let proxy = Self {
            port,
            upstream,
            runtime,
            tasks: Arc::default(),
        };
        proxy.resume();
        proxy
    }

    /// The endpoint through the relay.
    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// Accepts and relays connections again.
    pub fn resume(&self) {
        let (port, upstream, tasks) = (self.port, self.upstream.clone(), self.tasks.clone());
        let listener = self.runtime.block_on(async move {
            // The port was just released by `stop`; rebinding can take a moment.
            for _ in 0..100 {
                if let Ok(l) = tokio::net::TcpListener::bind(("127.0.0.1", port)).await {
                    return l;
                }
                tokio::time::sleep(std::time::Duration::from_millis(20)).await;
            }
            panic!("cannot rebind the proxy port {port}");
        });
        let inner_tasks = tasks.clone();
        let accept = self.runtime.spawn(async move {
            loop {
                let Ok((mut client, _)) = listener.accept().await else {
                    return;
                };
                let upstream = upstream.clone();
                let relay = tokio::spawn(async move {
                    if let Ok(mut server) = tokio::net::TcpStream::connect(&upstream).await {
                        let _ = tokio::io::copy_bidirectional(&mut client, &mut server).await;
                    }
                });
                inner_tasks.lock().unwrap().push(relay);
            }
        });
        tasks.lock().unwrap().push(accept);
    }

    /// Closes every connection and refuses new ones.
    pub fn stop(&self) {
        let tasks: Vec<_> = self.tasks.lock().unwrap().drain(..).collect();
        for t in &tasks {
            t.abort();
        }
        self.runtime.block_on(async {
            for t in tasks {
                let _ = t.await;
            }
        });
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop();
    }
}
