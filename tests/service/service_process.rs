//! The `skybake` binary as an operator runs it: `serve` stopped by SIGTERM (graceful) and by
//! SIGKILL (a bake job resumes after restart without recomputing finished products),
//! `healthcheck`, and the offline, resumable `bake`.

use crate::service_support;

use service_support::{metric, request, Scratch};
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_skybake");

/// Starts `skybake serve` on an ephemeral port with its cache in `dir`; returns the child and address.
fn serve(dir: &Path) -> (Child, SocketAddr) {
    let mut child = Command::new(BIN)
        .args(["serve", "--bind", "127.0.0.1:0", "--cache-dir"])
        .arg(dir)
        .env_remove("SKYBAKE_BIND")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn skybake serve");
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let addr = loop {
        let line = lines
            .next()
            .expect("server exited before listening")
            .unwrap();
        if let Some(a) = line.strip_prefix("listening on ") {
            break a.trim().parse().unwrap();
        }
    };
    // Keep draining stderr so the child never blocks on a full pipe.
    std::thread::spawn(move || for _ in lines {});
    (child, addr)
}

fn wait_exit(child: &mut Child, within: Duration) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        assert!(start.elapsed() < within, "process did not exit");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn count_cache_files(dir: &Path) -> usize {
    // Stored shared tables (precise and density) are EXR files of the cache too, named by their
    // header attribute; only products count.
    let table = |f: &Path| {
        let bytes = std::fs::read(f).unwrap_or_default();
        [&b"skybakeSharedTable"[..], &b"skybakeDensityTable"[..]]
            .iter()
            .any(|needle| bytes.windows(needle.len()).any(|w| w == *needle))
    };
    let mut n = 0;
    for shard in std::fs::read_dir(dir).unwrap().flatten() {
        if shard.file_name().len() == 2 && shard.path().is_dir() {
            n += std::fs::read_dir(shard.path())
                .unwrap()
                .flatten()
                .filter(|f| f.file_name().to_string_lossy().ends_with(".exr"))
                .filter(|f| !table(&f.path()))
                .count();
        }
    }
    n
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_drains_requests_in_flight_and_exits_cleanly() {
    let dir = Scratch::new("sigterm");
    let (mut child, addr) = serve(dir.path());
    assert_eq!(request(addr, "GET", "/healthz", None).await.status, 200);
    let path = "/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=129&azimuth_count=64&sun_elevation_deg=17&format=exr";
    let pending = tokio::spawn(async move { request(addr, "GET", path, None).await });
    tokio::time::sleep(Duration::from_millis(100)).await;
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let r = pending.await.unwrap();
    assert_eq!(r.status, 200, "request in flight completes during shutdown");
    let status = wait_exit(&mut child, Duration::from_secs(30));
    assert!(status.success(), "exit status {status:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_resumes_after_kill_9_without_recomputing_finished_products() {
    let dir = Scratch::new("resume");
    let total = 40;
    let job = format!(
        r#"{{"grids": [{{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "440,550,680",
            "elevation_count": 65, "azimuth_count": 32,
            "sweep": {{"sun_elevation_deg": {{"from": 0, "to": {}, "step": 1}}}}}}]}}"#,
        total - 1
    );
    let (mut child, addr) = serve(dir.path());
    let r = request(addr, "POST", "/v1/jobs", Some(job.as_bytes())).await;
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let status_path = format!("/v1/jobs/{id}?limit=0");
    let start = Instant::now();
    loop {
        let st = request(addr, "GET", &status_path, None).await.json();
        let done = st["done"].as_u64().unwrap();
        assert!(
            done < total,
            "job finished before it could be killed; make items slower"
        );
        if done >= 3 {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "job made no progress"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    child.kill().unwrap(); // SIGKILL: no chance to persist anything more
    child.wait().unwrap();
    let finished_before = count_cache_files(dir.path());
    assert!(finished_before >= 3 && finished_before < total as usize);

    let (mut child, addr) = serve(dir.path());
    let start = Instant::now();
    let st = loop {
        let st = request(addr, "GET", &format!("/v1/jobs/{id}?limit=1000"), None)
            .await
            .json();
        if st["state"] == "completed" {
            break st;
        }
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "job did not resume: {st}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(
        (st["done"].as_u64(), st["failed"].as_u64()),
        (Some(total), Some(0)),
        "{st}"
    );
    let items = st["artifacts"]["items"].as_array().unwrap();
    assert!(items.iter().all(|a| a["status"] == "done"));
    let metrics = request(addr, "GET", "/metrics", None).await.text();
    let recomputed = metric(&metrics, "skybake_computations_total{product=\"sky\"}").unwrap_or(0.0);
    assert_eq!(
        recomputed as usize,
        total as usize - finished_before,
        "after restart only the unfinished products are computed"
    );
    assert_eq!(count_cache_files(dir.path()), total as usize);
    child.kill().unwrap();
    child.wait().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn healthcheck_subcommand_reports_liveness() {
    let dir = Scratch::new("health");
    let (mut child, addr) = serve(dir.path());
    let ok = Command::new(BIN)
        .args(["healthcheck", "--addr", &addr.to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    child.kill().unwrap();
    child.wait().unwrap();
    let down = Command::new(BIN)
        .args(["healthcheck", "--addr", &addr.to_string()])
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert!(!down.success());
}

#[test]
fn bake_writes_artifacts_and_resumes() {
    let dir = Scratch::new("bake");
    let job = dir.path().join("job.json");
    std::fs::write(
        &job,
        r#"{"products": [{"product": "sun", "method": "fast", "wavelengths": [440, 550]}],
            "grids": [{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "550",
                       "elevation_count": 9, "azimuth_count": 4,
                       "sweep": {"sun_elevation_deg": [-3, 10, 45]}}]}"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let run = || {
        let o = Command::new(BIN)
            .arg("bake")
            .arg(&job)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stderr).contains("[4/4]"));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let first = run();
    assert_eq!(
        (first["computed"].as_u64(), first["reused"].as_u64()),
        (Some(4), Some(0))
    );
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    let files: Vec<String> = manifest["artifacts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["file"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(files.len(), 4);
    for f in &files {
        let image = skybake_store::read_exr_file(&out.join(f)).unwrap();
        assert!(image.attribute("skybakeSpec").is_some());
    }
    // Lose one product and corrupt another: a rerun recomputes exactly those two.
    std::fs::remove_file(out.join(&files[1])).unwrap();
    let mut bytes = std::fs::read(out.join(&files[3])).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0xff;
    std::fs::write(out.join(&files[3]), bytes).unwrap();
    let second = run();
    assert_eq!(
        (second["computed"].as_u64(), second["reused"].as_u64()),
        (Some(2), Some(2))
    );
    skybake_store::read_exr_file(&out.join(&files[3])).unwrap();
}

#[test]
fn invalid_configuration_is_refused_at_start_up() {
    let dir = Scratch::new("badconfig");
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, "[server]\nconcurrency_limit = 0\n").unwrap();
    let o = Command::new(BIN)
        .args(["serve", "--bind", "127.0.0.1:0", "--config"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("server.concurrency_limit"), "{err}");
    let o = Command::new(BIN)
        .args(["serve", "--bind", "127.0.0.1:0"])
        .env("SKYBAKE_REQUEST_TIMEOUT_S", "soon")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("SKYBAKE_REQUEST_TIMEOUT_S"));
    // A mistyped variable is refused with the list of known ones, not silently ignored.
    let o = Command::new(BIN)
        .args(["serve", "--bind", "127.0.0.1:0"])
        .env("SKYBAKE_CONCURENCY_LIMIT", "3")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("SKYBAKE_CONCURENCY_LIMIT"), "{err}");
    assert!(err.contains("known: SKYBAKE_BIND"), "{err}");
}
