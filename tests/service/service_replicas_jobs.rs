//! Bake jobs (`POST /v1/jobs`) on replicas sharing a bucket, on a real S3-compatible server
//! (`SKYBAKE_TEST_S3_ENDPOINT`; skipped with a printed reason without one): a job submitted to one
//! replica is listed, polled, fetched and cancelled through another, and a job whose replica is
//! killed is continued by another from the stored progress, with only the item in flight computed
//! again.

use crate::service_replicas::{Replica, SKY_COMPUTATIONS};
use crate::service_support;

use serde_json::Value;
use service_support::{request, s3, Scratch};
use std::net::SocketAddr;
use std::time::{Duration, Instant};

/// A job of `n` skies (fast, draft, 3 wavelengths, 129 × 64: a noticeable time each), the sun
/// 0.25° higher each.
fn sky_job(n: usize) -> String {
    format!(
        r#"{{"grids": [{{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "440,550,680",
            "elevation_count": 129, "azimuth_count": 64,
            "sweep": {{"sun_elevation_deg": {{"from": 0, "to": {}, "step": 0.25}}}}}}]}}"#,
        (n - 1) as f64 * 0.25
    )
}

async fn submit(addr: SocketAddr, body: &str) -> String {
    let r = request(addr, "POST", "/v1/jobs", Some(body.as_bytes())).await;
    assert_eq!(r.status, 202, "{}", r.text());
    r.json()["id"].as_str().unwrap().to_string()
}

async fn status(addr: SocketAddr, id: &str) -> Value {
    let r = request(addr, "GET", &format!("/v1/jobs/{id}?limit=1000"), None).await;
    assert_eq!(r.status, 200, "{}", r.text());
    r.json()
}

/// Polls `addr` for job `id` until `done(status)` holds.
async fn wait_for(addr: SocketAddr, id: &str, what: &str, done: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        let st = status(addr, id).await;
        if done(&st) {
            return st;
        }
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "job {id}: {what} never came: {st}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_submitted_to_one_replica_is_polled_fetched_and_cancelled_on_another() {
    let Some(endpoint) = s3::endpoint("a_job_submitted_to_one_replica_is_polled_on_another") else {
        return;
    };
    let dir = Scratch::new("replica-jobs");
    let url = s3::fresh_url("replica-jobs");
    let a = Replica::start(&dir.path().join("a"), &url, &endpoint, "30");
    let b = Replica::start(&dir.path().join("b"), &url, &endpoint, "30");

    // Submitted to a, followed on b until it has finished.
    let id = submit(a.addr, &sky_job(4)).await;
    let st = wait_for(b.addr, &id, "completion", |st| st["state"] == "completed").await;
    assert_eq!(
        (st["done"].as_u64(), st["failed"].as_u64()),
        (Some(4), Some(0)),
        "{st}"
    );
    let items = st["artifacts"]["items"].as_array().unwrap();
    assert!(items.iter().all(|a| a["status"] == "done"), "{st}");
    let listed = request(b.addr, "GET", "/v1/jobs", None).await.json();
    assert!(
        listed["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .any(|j| j["id"] == id.as_str()),
        "b lists a's job: {listed}"
    );
    // Its artifacts come from the bucket on b; each item was computed once in all (by a, which
    // runs it, unless b's periodic look for unstarted jobs took it first).
    let art = request(b.addr, "GET", &format!("/v1/jobs/{id}/artifacts/2"), None).await;
    assert_eq!(art.status, 200, "{}", art.text());
    let same = request(a.addr, "GET", &format!("/v1/jobs/{id}/artifacts/2"), None).await;
    assert_eq!(art.body, same.body);
    let computed = a.metric(SKY_COMPUTATIONS).await + b.metric(SKY_COMPUTATIONS).await;
    assert_eq!(computed, 4.0);

    // A long job running on a, cancelled through b: a stops it.
    let long = submit(a.addr, &sky_job(200)).await;
    wait_for(b.addr, &long, "progress", |st| {
        st["done"].as_u64() >= Some(1)
    })
    .await;
    let r = request(b.addr, "DELETE", &format!("/v1/jobs/{long}"), None).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(
        r.json()["deleted"],
        false,
        "a running job is cancelled first"
    );
    let st = wait_for(a.addr, &long, "cancellation", |st| {
        st["state"] == "cancelled"
    })
    .await;
    assert!(st["done"].as_u64() < Some(200), "{st}");
    // Finished now: b removes it, and a no longer knows it.
    let r = request(b.addr, "DELETE", &format!("/v1/jobs/{long}"), None).await;
    assert_eq!(r.json()["deleted"], true, "{}", r.text());
    let gone = request(a.addr, "GET", &format!("/v1/jobs/{long}"), None).await;
    assert_eq!(gone.status, 404, "{}", gone.text());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_whose_replica_is_killed_is_continued_by_another() {
    let Some(endpoint) = s3::endpoint("a_job_whose_replica_is_killed_is_continued") else {
        return;
    };
    let dir = Scratch::new("replica-job-kill");
    let url = s3::fresh_url("replica-job-kill");
    // Leases of 2 s: b looks for orphaned jobs every second.
    let mut a = Replica::start(&dir.path().join("a"), &url, &endpoint, "2");
    let total = 24;
    let id = submit(a.addr, &sky_job(total)).await;
    // b starts once a runs the job (holds its lease), so every item b computes is one a left.
    wait_for(a.addr, &id, "a start", |st| st["done"].as_u64() >= Some(1)).await;
    let b = Replica::start(&dir.path().join("b"), &url, &endpoint, "2");
    let st = wait_for(b.addr, &id, "progress", |st| st["done"].as_u64() >= Some(3)).await;
    assert_eq!(st["state"], "running", "{st}");
    a.child.kill().unwrap(); // SIGKILL: a neither stores nor releases anything more
    a.child.wait().unwrap();

    // What a stored before it died, read from the bucket itself.
    let bucket = s3::open(&url, &endpoint, s3::quick_retry());
    let keys: Vec<String> = st["artifacts"]["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|it| it["cache_key"].as_str().unwrap().to_string())
        .collect();
    let stored = |key: &String| {
        bucket
            .get(&skybake_store::cache::object_name(key))
            .unwrap()
            .is_some()
    };
    let stored_by_a = keys.iter().filter(|k| stored(k)).count();
    assert!(
        (3..total).contains(&stored_by_a),
        "a was killed mid-job ({stored_by_a} of {total} stored)"
    );

    let st = wait_for(b.addr, &id, "completion", |st| st["state"] == "completed").await;
    assert_eq!(
        (st["done"].as_u64(), st["failed"].as_u64()),
        (Some(total as u64), Some(0)),
        "{st}"
    );
    assert_eq!(keys.iter().filter(|k| stored(k)).count(), total);
    // b computed exactly what a had not stored: the item a was computing when killed, and the
    // rest; the items a finished after its last progress write were bucket hits.
    assert_eq!(
        b.metric(SKY_COMPUTATIONS).await as usize,
        total - stored_by_a,
        "{st}"
    );
    let art = request(b.addr, "GET", &format!("/v1/jobs/{id}/artifacts/0"), None).await;
    assert_eq!(art.status, 200, "{}", art.text());
}
