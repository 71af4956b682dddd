//! Replicas of `skybake serve` sharing a bucket (`--cache-url`), on a real S3-compatible server
//! (`SKYBAKE_TEST_S3_ENDPOINT`; skipped with a printed reason without one): identical cold
//! requests on three replicas compute once, a replica killed while holding the lease is replaced
//! by another once the lease expires, and a bucket that stops answering is 503 + Retry-After,
//! never a product.

use crate::service_support;

use service_support::{metric, request, s3, Scratch};
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_skybake");

/// A sky that takes a noticeable time to compute (so requests overlap it).
const SLOW_SKY: &str = "/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=129&azimuth_count=64&format=exr";

/// A `skybake serve` replica with its own cache directory, sharing the bucket `url`.
pub(crate) struct Replica {
    pub(crate) child: Child,
    pub(crate) addr: SocketAddr,
}

impl Replica {
    pub(crate) fn start(dir: &std::path::Path, url: &str, endpoint: &str, lease_s: &str) -> Self {
        let mut cmd = Command::new(BIN);
        cmd.args([
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--cache-url",
            url,
            "--cache-dir",
        ])
        .arg(dir)
        .env_remove("SKYBAKE_BIND")
        .env("SKYBAKE_LEASE_S", lease_s)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
        s3::aws_env(&mut cmd, endpoint);
        let mut child = cmd.spawn().expect("spawn skybake serve");
        let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
        let addr = loop {
            let line = lines
                .next()
                .expect("server exited before listening")
                .unwrap();
            if let Some(a) = line.strip_prefix("listening on ") {
                break a.trim().parse().unwrap();
            }
        };
        std::thread::spawn(move || for _ in lines {});
        Self { child, addr }
    }

    pub(crate) async fn metric(&self, series: &str) -> f64 {
        let text = request(self.addr, "GET", "/metrics", None).await.text();
        metric(&text, series).unwrap_or(0.0)
    }
}

impl Drop for Replica {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub(crate) const SKY_COMPUTATIONS: &str = "skybake_computations_total{product=\"sky\"}";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_replicas_compute_sixty_identical_cold_requests_once() {
    let Some(endpoint) = s3::endpoint("three_replicas_compute_identical_cold_requests_once") else {
        return;
    };
    let dir = Scratch::new("replicas");
    let url = s3::fresh_url("replicas");
    let replicas: Vec<Replica> = (0..3)
        .map(|i| Replica::start(&dir.path().join(format!("r{i}")), &url, &endpoint, "30"))
        .collect();
    let path = format!("{SLOW_SKY}&sun_elevation_deg=23");
    let mut requests = Vec::new();
    for _ in 0..20 {
        for r in &replicas {
            let (addr, path) = (r.addr, path.clone());
            requests.push(tokio::spawn(async move {
                request(addr, "GET", &path, None).await
            }));
        }
    }
    let mut bodies = std::collections::HashSet::new();
    for r in requests {
        let r = r.await.unwrap();
        assert_eq!(r.status, 200, "{}", r.text());
        bodies.insert(r.body);
    }
    assert_eq!(bodies.len(), 1, "every replica serves the same artifact");
    let mut computed = 0.0;
    let mut from_bucket = 0.0;
    for r in &replicas {
        computed += r.metric(SKY_COMPUTATIONS).await;
        from_bucket += r.metric("skybake_cache_bucket_hits_total").await;
    }
    assert_eq!(computed, 1.0, "60 requests on 3 replicas: one computation");
    assert!(
        from_bucket >= 2.0,
        "the two other replicas read it from the bucket"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replica_killed_while_holding_the_lease_is_replaced_after_expiry() {
    let Some(endpoint) = s3::endpoint("a_replica_killed_while_holding_the_lease") else {
        return;
    };
    let dir = Scratch::new("lease-kill");
    let url = s3::fresh_url("lease-kill");
    let mut a = Replica::start(&dir.path().join("a"), &url, &endpoint, "2");
    let b = Replica::start(&dir.path().join("b"), &url, &endpoint, "2");
    // A much larger sky, so `a` is still computing when it is killed.
    let path = "/v1/sky?method=fast&quality=standard&wavelengths=440,550,680&elevation_count=513&azimuth_count=256&sun_elevation_deg=31&format=exr";
    let (addr, p) = (a.addr, path.to_string());
    let lost = tokio::spawn(async move {
        let _ = tokio::time::timeout(Duration::from_secs(60), request(addr, "GET", &p, None)).await;
    });
    let start = Instant::now();
    while a.metric("skybake_computations_in_flight").await < 1.0 {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "a never started computing"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    a.child.kill().unwrap();
    a.child.wait().unwrap();
    lost.abort();
    // b finds a's lease, waits for it to expire (nobody renews it), takes over and computes.
    let r = request(b.addr, "GET", path, None).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(b.metric(SKY_COMPUTATIONS).await, 1.0);
    assert!(b.metric("skybake_lease_waits_total").await >= 1.0);
}

/// (A plain test: the proxy runs its own runtime, which cannot be started inside a test's.)
#[test]
fn a_bucket_outage_is_503_with_retry_after_and_never_a_product() {
    let Some(endpoint) = s3::endpoint("a_bucket_outage_is_503_with_retry_after") else {
        return;
    };
    let client = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let dir = Scratch::new("outage");
    let proxy = s3::Proxy::start(&endpoint);
    let r = Replica::start(
        dir.path(),
        &s3::fresh_url("outage"),
        &proxy.endpoint(),
        "30",
    );
    let path = "/v1/sky?method=fast&quality=draft&wavelengths=550&elevation_count=9&azimuth_count=8&format=exr";
    proxy.stop();
    let down = client.block_on(request(r.addr, "GET", path, None));
    assert_eq!(down.status, 503, "{}", down.text());
    let retry_after: u64 = down.header("retry-after").unwrap().parse().unwrap();
    assert!(retry_after >= 1);
    assert!(
        down.text().contains("storage-unavailable"),
        "{}",
        down.text()
    );
    assert!(client.block_on(r.metric("skybake_bucket_failures_total")) >= 1.0);
    proxy.resume();
    let up = client.block_on(request(r.addr, "GET", path, None));
    assert_eq!(up.status, 200, "{}", up.text());
}
