//! Frames and frame plans are charged to the frame cost cap and the memory cap before anything is
//! voxelised, run under the compute slots, and stop within a step of the automaton when their
//! client hangs up or their request times out.

use crate::service_support;

use service_support::{metric, settings, tiny_frame_scene, Scratch, TestServer};
use std::time::{Duration, Instant};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

/// The cumulus-frame example with its cloud replaced by the automaton-field example at
/// `steps`, `w` × `h` pixels (the abandoned automaton frame the service once ran for minutes).
fn automaton_scene(steps: f64, w: usize, h: usize) -> serde_json::Value {
    let example = |name: &str| -> serde_json::Value {
        let text = skybake_product::frame::EXAMPLE_SCENES
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap()
            .1;
        serde_json::from_str(text).unwrap()
    };
    let mut scene = example("cumulus-frame");
    scene["cloud"] = example("automaton-field")["cloud"].clone();
    scene["cloud"]["source"]["frame_time_steps"] = serde_json::json!(steps);
    scene["camera"]["width"] = serde_json::json!(w);
    scene["camera"]["height"] = serde_json::json!(h);
    scene
}

/// The same automaton made small (64 × 32 × 10 cells): cheap per step, so only its step count
/// makes it long.
fn small_automaton_scene(steps: f64) -> serde_json::Value {
    let mut scene = automaton_scene(steps, 32, 24);
    let p = &mut scene["cloud"]["source"]["params"];
    p["dims"] = serde_json::json!([64, 32, 10]);
    p["random_ellipsoids"]["count"] = serde_json::json!(4);
    p["random_ellipsoids"]["centre_height_range_cells"] = serde_json::json!([4.0, 6.0]);
    p["random_ellipsoids"]["semi_axes_min_cells"] = serde_json::json!([4.0, 4.0, 2.0]);
    p["random_ellipsoids"]["semi_axes_max_cells"] = serde_json::json!([8.0, 8.0, 3.0]);
    p["ellipsoids"] = serde_json::json!([]);
    p["obstacle"] = serde_json::Value::Null;
    p["wind"] = serde_json::json!([
        {"height_cells": 0.0, "velocity_cells_per_step": 0.0},
        {"height_cells": 10.0, "velocity_cells_per_step": 1.0}
    ]);
    scene
}

/// Sends a POST and returns the open connection without reading the answer (drop it to hang up).
async fn post_and_hold(addr: std::net::SocketAddr, path: &str, body: &str) -> TcpStream {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "POST {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(body.as_bytes()).await.unwrap();
    s
}

async fn metric_now(srv: &TestServer, series: &str) -> f64 {
    metric(&srv.get("/metrics").await.text(), series).unwrap_or(0.0)
}

/// Polls until `series` satisfies `ok` (or `limit` passes); returns the time it took, or None.
async fn until(
    srv: &TestServer,
    series: &str,
    ok: impl Fn(f64) -> bool,
    limit: Duration,
) -> Option<Duration> {
    let start = Instant::now();
    while start.elapsed() < limit {
        if ok(metric_now(srv, series).await) {
            return Some(start.elapsed());
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    None
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_and_plans_over_the_cost_or_memory_cap_are_refused_naming_it() {
    let dir = Scratch::new("frame-cost");
    let srv = TestServer::start(settings(dir.path())).await;
    // The documented maximum of the automaton's steps: about 6 minutes of one core.
    let scene = automaton_scene(1e6, 160, 120).to_string();
    let plan_body = format!(r#"{{"product": "frame", "scene": {scene}}}"#);
    for (path, body) in [
        ("/v1/render?format=json", scene.as_str()),
        ("/v1/plan", plan_body.as_str()),
    ] {
        let r = srv.post(path, body).await;
        assert_eq!(r.status, 413, "{path}: {}", r.text());
        let p = r.json();
        assert_eq!(p["parameter"], "request_cost", "{path}: {p}");
        let detail = p["detail"].as_str().unwrap();
        assert!(detail.contains("server.max_frame_cost"), "{detail}");
        assert!(detail.contains("limit 2000000000000"), "{detail}");
        assert!(detail.contains("automaton cell-steps"), "{detail}");
    }
    // A 4096² fast frame of a tiny cloud is cheap in steps but not in memory.
    let big = tiny_frame_scene(4096, 4096).to_string();
    let r = srv.post("/v1/render?format=exr", &big).await;
    assert_eq!(r.status, 413, "{}", r.text());
    let p = r.json();
    assert_eq!(p["parameter"], "request_memory", "{p}");
    assert!(
        p["detail"]
            .as_str()
            .unwrap()
            .contains("server.max_request_memory_bytes"),
        "{p}"
    );
    // As a job item, the same frame is refused at submission, naming the item and the cap.
    let r = srv
        .post(
            "/v1/jobs",
            &format!(r#"{{"frames": [{{"scene": {big}}}]}}"#),
        )
        .await;
    assert_eq!(r.status, 413, "{}", r.text());
    let p = r.json();
    let parameter = p["parameter"].as_str().unwrap_or_default();
    assert!(parameter.starts_with("frames[0]"), "{p}");
    assert!(parameter.ends_with("request_memory"), "{p}");
    // The same automaton at few steps is within both caps.
    let r = srv
        .post(
            "/v1/plan",
            &format!(
                r#"{{"product": "frame", "scene": {}}}"#,
                small_automaton_scene(20.0)
            ),
        )
        .await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(srv.state.metrics().computations("frame"), 0);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cloud_whose_size_only_voxelising_tells_is_held_to_the_cap_once_voxelised() {
    let dir = Scratch::new("frame-cost-late");
    let mut s = settings(dir.path());
    s.server.max_frame_cost = 10_000_000;
    let srv = TestServer::start(s).await;
    let fractal: serde_json::Value = serde_json::from_str(
        skybake_product::frame::EXAMPLE_SCENES
            .iter()
            .find(|(n, _)| *n == "cumulus-fractal")
            .unwrap()
            .1,
    )
    .unwrap();
    let mut scene = tiny_frame_scene(64, 48);
    scene["cloud"]["source"] = fractal["cloud"]["source"].clone();
    // 3072 pixels × a grown cloud of thousands of voxels: over 1e7, known only once grown.
    let r = srv.post("/v1/render?format=json", &scene.to_string()).await;
    assert_eq!(r.status, 413, "{}", r.text());
    let p = r.json();
    assert_eq!(p["parameter"], "request_cost", "{p}");
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("pixels 3072"), "{detail}");
    assert!(!detail.contains("voxels 0 "), "{detail}");
    // The same size of image over a cloud whose size its parameters give is refused before.
    let metaballs = tiny_frame_scene(64, 48);
    let before = srv.state.metrics().computations("frame");
    let r = srv
        .post("/v1/render?format=json", &metaballs.to_string())
        .await;
    assert_eq!(r.status, 413, "{}", r.text());
    assert_eq!(srv.state.metrics().computations("frame"), before);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_abandoned_or_timed_out_automaton_render_or_plan_stops_within_a_step() {
    let dir = Scratch::new("frame-cancel");
    let mut s = settings(dir.path());
    // The caps are what refuses such a request by default; lifted here to see it stop.
    s.server.max_frame_cost = u64::MAX;
    s.server.compute_threads = 1;
    let srv = TestServer::start(s).await;
    let scene = small_automaton_scene(1e6).to_string();
    let plan_body = format!(r#"{{"product": "frame", "scene": {scene}}}"#);
    let in_flight = "skybake_computations_in_flight";
    let cancelled = "skybake_computations_cancelled_total";
    for (round, (path, body)) in [
        ("/v1/render?format=json", scene.as_str()),
        ("/v1/plan", plan_body.as_str()),
    ]
    .into_iter()
    .enumerate()
    {
        let conn = post_and_hold(srv.addr, path, body).await;
        assert!(
            until(&srv, in_flight, |v| v == 1.0, Duration::from_secs(30))
                .await
                .is_some(),
            "{path}: never started"
        );
        // Well into the steps (the simulation is set up in milliseconds at this size).
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert_eq!(metric_now(&srv, in_flight).await, 1.0, "{path}");
        drop(conn);
        // Before: the steps ran on for minutes after the client had gone.
        let took = until(&srv, in_flight, |v| v == 0.0, Duration::from_secs(20)).await;
        eprintln!("{path}: hang-up to nothing in flight {took:?}");
        assert!(
            took.is_some(),
            "{path}: still computing 20 s after the hang-up"
        );
        assert_eq!(metric_now(&srv, cancelled).await, (round + 1) as f64);
    }
    srv.stop().await;
    // A request that times out is cancelled the same way.
    let dir = Scratch::new("frame-timeout");
    let mut s = settings(dir.path());
    s.server.max_frame_cost = u64::MAX;
    s.server.request_timeout_s = 1.0;
    let srv = TestServer::start(s).await;
    let r = srv.post("/v1/plan", &plan_body).await;
    assert_eq!(r.status, 503, "{}", r.text());
    let took = until(&srv, in_flight, |v| v == 0.0, Duration::from_secs(20)).await;
    eprintln!("plan timed out: answer to nothing in flight {took:?}");
    assert!(took.is_some(), "still computing 20 s after the timeout");
    assert_eq!(metric_now(&srv, cancelled).await, 1.0);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_plans_take_the_compute_slots_and_the_queue() {
    let dir = Scratch::new("plan-slots");
    let mut s = settings(dir.path());
    s.server.max_frame_cost = u64::MAX;
    s.server.compute_threads = 1;
    s.server.max_queued_computations = 1;
    let srv = TestServer::start(s).await;
    let long = format!(
        r#"{{"product": "frame", "scene": {}}}"#,
        small_automaton_scene(1e6)
    );
    // One plan computes, a second waits for the one slot: a third is shed, not started.
    let a = post_and_hold(srv.addr, "/v1/plan", &long).await;
    until(
        &srv,
        "skybake_computations_in_flight",
        |v| v == 1.0,
        Duration::from_secs(30),
    )
    .await
    .expect("the first plan started");
    let b = post_and_hold(srv.addr, "/v1/plan", &long).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let shed = srv.post("/v1/plan", &long).await;
    assert_eq!(shed.status, 503, "{}", shed.text());
    assert_eq!(shed.json()["type"], "urn:skybake:problem:overloaded");
    assert_eq!(
        metric_now(&srv, "skybake_computations_in_flight").await,
        1.0,
        "the queued plan holds no slot"
    );
    drop(a);
    drop(b);
    until(
        &srv,
        "skybake_computations_cancelled_total",
        |v| v == 2.0,
        Duration::from_secs(20),
    )
    .await
    .expect("both plans cancelled");
    // The slot is free again.
    let r = srv
        .post(
            "/v1/plan",
            &format!(
                r#"{{"product": "frame", "scene": {}}}"#,
                small_automaton_scene(5.0)
            ),
        )
        .await;
    assert_eq!(r.status, 200, "{}", r.text());
    srv.stop().await;
}
