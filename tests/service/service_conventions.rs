//! Service conventions: jobs bounded (listing, deletion with files, expiry, live-job
//! limit, disk budget), HTTP conventions (304, compression, Cache-Control, problem+json for
//! 405/413/414, the atmosphere list), optional bearer tokens and a per-client rate limit, and the
//! error names of inline atmospheres and sweeps.

use crate::service_support;

use service_support::{metric, settings, Scratch, TestServer, FAST};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// One request with extra header lines, read to the end.
async fn request_with(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &str,
) -> service_support::Response {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{headers}Content-Length: 0\r\n\r\n"
    );
    s.write_all(head.as_bytes()).await.unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).await.unwrap();
    service_support::parse_response(&raw)
}

fn assert_problem(r: &service_support::Response, status: u16, needle: &str) {
    assert_eq!(r.status, status, "{}", r.text());
    assert_eq!(
        r.header("content-type"),
        Some("application/problem+json"),
        "{status}"
    );
    let detail = r.json()["detail"].as_str().unwrap_or("").to_string();
    assert!(
        detail.contains(needle),
        "{status}: '{detail}' should contain '{needle}'"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_conventions_etag_compression_cache_control_and_problems() {
    let dir = Scratch::new("conventions");
    let mut s = settings(dir.path());
    s.server.body_limit_bytes = 4096;
    let srv = TestServer::start(s).await;
    let path = format!("/v1/sky?{FAST}");
    let first = srv.get(&path).await;
    assert_eq!(first.status, 200, "{}", first.text());
    let etag = first.header("etag").unwrap().to_string();
    assert_eq!(first.header("cache-control"), Some("public, max-age=86400"));
    // If-None-Match with the ETag: 304, no body.
    let again = request_with(
        srv.addr,
        "GET",
        &path,
        &format!("If-None-Match: {etag}\r\n"),
    )
    .await;
    assert_eq!(again.status, 304);
    assert!(again.body.is_empty());
    assert_eq!(again.header("etag"), Some(etag.as_str()));
    let other = request_with(srv.addr, "GET", &path, "If-None-Match: \"nope\"\r\n").await;
    assert_eq!(other.status, 200);
    // JSON is compressed for a client that accepts gzip, and decompresses to the same bytes.
    let gz = request_with(srv.addr, "GET", &path, "Accept-Encoding: gzip\r\n").await;
    assert_eq!(gz.status, 200);
    assert_eq!(gz.header("content-encoding"), Some("gzip"));
    let mut plain = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&gz.body[..]), &mut plain)
        .unwrap();
    assert_eq!(plain, first.body);
    assert!(gz.body.len() < first.body.len() / 2);
    let br = request_with(srv.addr, "GET", &path, "Accept-Encoding: br\r\n").await;
    assert_eq!(br.header("content-encoding"), Some("br"));
    // 405 with the allowed methods, as problem+json.
    let r = request_with(srv.addr, "PUT", "/v1/sky", "").await;
    assert_problem(&r, 405, "allowed: GET");
    assert_eq!(r.header("allow"), Some("GET"));
    let r = request_with(srv.addr, "PATCH", "/v1/jobs/00000000000000ff", "").await;
    assert_problem(&r, 405, "GET, DELETE");
    // 413 for a body over the limit, stating it.
    let big = format!("{{\"products\": [], \"pad\": \"{}\"}}", "x".repeat(5000));
    let r = srv.post("/v1/jobs", &big).await;
    assert_problem(&r, 413, "limit 4096 bytes");
    // 414 for a query over the service's limit, stating it.
    let long = format!("/v1/sky?probe={}", "1".repeat(40 * 1024));
    let r = srv.get(&long).await;
    assert_problem(&r, 414, "limit 32768");
    // The atmosphere presets.
    let a = srv.get("/v1/atmospheres").await;
    assert_eq!(a.status, 200);
    let names: Vec<String> = a.json()["atmospheres"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["name"].as_str().unwrap().to_string())
        .collect();
    assert!(names.contains(&"earth".to_string()) && names.contains(&"mars".to_string()));
    assert!(a.json()["atmospheres"][0]["parameters"]["planet_radius_m"].is_number());
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_are_listed_deleted_with_their_files_expired_and_limited() {
    let dir = Scratch::new("jobs-bounded");
    let mut s = settings(dir.path());
    s.jobs.max_live = 1;
    s.jobs.expire_after_s = 3600.0;
    let srv = TestServer::start(s).await;
    let body = r#"{"products": [{"product": "sun", "method": "fast", "quality": "draft", "wavelengths": "550"}]}"#;
    let r = srv.post("/v1/jobs", body).await;
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    // While it is live a second job is refused, naming the limit.
    let second = srv.post("/v1/jobs", body).await;
    if second.status != 202 {
        assert_problem(&second, 503, "jobs.max_live");
    }
    let mut state = serde_json::Value::Null;
    for _ in 0..3600 {
        state = srv.get(&format!("/v1/jobs/{id}")).await.json();
        if state["state"] == "completed" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(state["state"], "completed", "{state}");
    let list = srv.get("/v1/jobs").await.json();
    assert!(list["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .any(|j| j["id"] == id.as_str()));
    assert_eq!(list["max_live"], 1);
    // DELETE of a finished job removes it and its files.
    let job_dir = dir.path().join("jobs").join(&id);
    assert!(job_dir.join("job.json").is_file());
    let d = srv.delete(&format!("/v1/jobs/{id}")).await;
    assert_eq!(d.status, 200, "{}", d.text());
    assert_eq!(d.json()["deleted"], true);
    assert!(!job_dir.exists());
    assert_eq!(srv.get(&format!("/v1/jobs/{id}")).await.status, 404);
    srv.stop().await;

    // Finished jobs expire after jobs.expire_after_s, files and all.
    let dir = Scratch::new("jobs-expire");
    let mut s = settings(dir.path());
    s.jobs.expire_after_s = 0.2;
    let srv = TestServer::start(s).await;
    let id = srv.post("/v1/jobs", body).await.json()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let job_dir = dir.path().join("jobs").join(&id);
    let mut gone = false;
    for _ in 0..3600 {
        if srv.get(&format!("/v1/jobs/{id}")).await.status == 404 {
            gone = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(gone, "the finished job should have expired");
    assert!(!job_dir.exists());
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_files_count_in_the_disk_budget() {
    let dir = Scratch::new("jobs-budget");
    let mut s = settings(dir.path());
    s.cache.disk_budget_bytes = 1 << 20;
    s.server.body_limit_bytes = 1 << 20;
    s.jobs.max_live = 100;
    let srv = TestServer::start(s).await;
    // The motivating case: job bodies of ~980 kB against a 1 MiB budget. Padding goes in a product's
    // probe list (valid directions, the most compact way to make a large valid body).
    let probes: Vec<String> = (0..4000)
        .map(|i| format!("{}:{}", i % 80, i % 170))
        .collect();
    let item = format!(
        "{{\"product\": \"sky\", \"method\": \"fast\", \"quality\": \"draft\", \"wavelengths\": \"550\", \"probe\": \"{}\"}}",
        probes.join(",")
    );
    let body = format!("{{\"products\": [{}]}}", vec![item; 7].join(","));
    assert!(body.len() > 150_000, "{}", body.len());
    let mut accepted = 0;
    let mut refused = None;
    for _ in 0..30 {
        let r = srv.post("/v1/jobs", &body).await;
        match r.status {
            202 => accepted += 1,
            _ => {
                refused = Some(r);
                break;
            }
        }
    }
    let refused = refused.expect("jobs beyond the disk budget are refused");
    assert_problem(&refused, 503, "cache.disk_budget_bytes");
    assert!(accepted >= 1);
    let on_disk: u64 = walk_bytes(&dir.path().join("jobs"));
    assert!(on_disk <= 1 << 20, "{on_disk} bytes of jobs on disk");
    srv.stop().await;
}

fn walk_bytes(dir: &std::path::Path) -> u64 {
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let t = e.file_type().unwrap();
        if t.is_dir() {
            n += walk_bytes(&e.path());
        } else {
            n += e.metadata().unwrap().len();
        }
    }
    n
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_tokens_and_the_rate_limit() {
    let dir = Scratch::new("auth");
    let mut s = settings(dir.path());
    s.server.api_tokens = "0123456789abcdef-one, fedcba9876543210-two".into();
    s.server.rate_limit_per_s = 0.5;
    s.server.rate_limit_burst = 3;
    let srv = TestServer::start(s).await;
    // Without a token: 401 with WWW-Authenticate; health and metrics stay open.
    let r = srv.get("/v1/atmospheres").await;
    assert_problem(&r, 401, "Authorization: Bearer");
    assert!(r.header("www-authenticate").unwrap().starts_with("Bearer"));
    let wrong = request_with(
        srv.addr,
        "GET",
        "/v1/atmospheres",
        "Authorization: Bearer 0123456789abcdef-onf\r\n",
    )
    .await;
    assert_eq!(wrong.status, 401);
    assert_eq!(srv.get("/healthz").await.status, 200);
    assert_eq!(srv.get("/metrics").await.status, 200);
    // With a token: the rest of the burst of 3 passes (the two failed attempts took from the
    // same bucket), the next is 429 with Retry-After.
    let auth = "Authorization: Bearer fedcba9876543210-two\r\n";
    for _ in 0..1 {
        let r = request_with(srv.addr, "GET", "/v1/atmospheres", auth).await;
        assert_eq!(r.status, 200, "{}", r.text());
    }
    let r = request_with(srv.addr, "GET", "/v1/atmospheres", auth).await;
    assert_problem(&r, 429, "server.rate_limit_per_s");
    assert_eq!(r.header("retry-after"), Some("2"));
    let m = srv.get("/metrics").await.text();
    assert_eq!(metric(&m, "skybake_rate_limited_total"), Some(1.0));
    assert_eq!(metric(&m, "skybake_unauthorized_total"), Some(2.0));
    srv.stop().await;

    // Off by default: no token needed.
    let dir = Scratch::new("noauth");
    let srv = TestServer::start(settings(dir.path())).await;
    assert_eq!(srv.get("/v1/atmospheres").await.status, 200);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn inline_atmosphere_and_sweep_errors_name_their_parameter() {
    let dir = Scratch::new("naming");
    let srv = TestServer::start(settings(dir.path())).await;
    let earth = include_str!("../../config/atmospheres/earth.json");
    let bad = earth.replace("\"ground_albedo\": 0.1", "\"ground_albedo\": 7");
    assert_ne!(bad, earth);
    let q: String = form_urlencoded::byte_serialize(bad.as_bytes()).collect();
    let r = srv.get(&format!("/v1/sun?atmosphere={q}")).await;
    assert_eq!(r.status, 400, "{}", r.text());
    assert_eq!(r.json()["parameter"], "atmosphere.ground_albedo");
    let sweep = r#"{"grids": [{"product": "sun", "method": "fast", "wavelengths": "550",
        "sweep": {"observer_altitude_m": [0, -50000]}}]}"#;
    let r = srv.post("/v1/jobs", sweep).await;
    assert_eq!(r.status, 400, "{}", r.text());
    assert_eq!(r.json()["parameter"], "grids[0].observer_altitude_m");
    srv.stop().await;
}
