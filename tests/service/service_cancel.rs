//! Abandoned computations are cancelled, the compute queue is bounded, a
//! request's estimated cost is capped, and an atmosphere outside the validated range says so.

use crate::service_support;

use service_support::{metric, settings, Scratch, TestServer};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

/// Sends a GET and returns the open connection without reading the answer (drop it to hang up).
async fn send_and_hold(addr: std::net::SocketAddr, path: &str) -> TcpStream {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let head = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    s.write_all(head.as_bytes()).await.unwrap();
    s
}

/// Polls `/metrics` until `series` reaches `at_least` (or 120 s pass); returns its last value.
async fn wait_for_metric(srv: &TestServer, series: &str, at_least: f64) -> f64 {
    let mut v = 0.0;
    for _ in 0..1200 {
        v = metric(&srv.get("/metrics").await.text(), series).unwrap_or(0.0);
        if v >= at_least {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    v
}

fn cache_key(srv: &TestServer, path: &str) -> String {
    let query = &path[path.find('?').unwrap() + 1..];
    let pairs = skybake_service::extract::query_pairs(Some(query)).unwrap();
    let p = skybake_product::params::RequestParams::from_pairs(pairs).unwrap();
    srv.state
        .request(skybake_product::ProductKind::Sky, p)
        .unwrap()
        .cache_key()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abandoned_computations_are_cancelled_and_the_queue_is_bounded() {
    let dir = Scratch::new("cancel");
    let mut s = settings(dir.path());
    s.server.compute_threads = 1;
    s.server.max_queued_computations = 1;
    let srv = TestServer::start(s).await;
    // Cold precise tables at standard quality: seconds of work each, several orders of scattering.
    let a = "/v1/sky?ground_albedo=0.11&wavelengths=440,550,680&elevation_count=9&azimuth_count=8";
    let b = "/v1/sky?ground_albedo=0.12&wavelengths=440,550,680&elevation_count=9&azimuth_count=8";
    let c = "/v1/sky?ground_albedo=0.13&wavelengths=440,550,680&elevation_count=9&azimuth_count=8";
    let conn_a = send_and_hold(srv.addr, a).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let conn_b = send_and_hold(srv.addr, b).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    // A computes, B waits for the one compute slot: a third computation is shed, not queued.
    let shed = srv.get(c).await;
    assert_eq!(shed.status, 503, "{}", shed.text());
    assert_eq!(shed.header("retry-after"), Some("1"));
    assert_eq!(shed.json()["type"], "urn:skybake:problem:overloaded");
    // Both clients hang up: B leaves the queue without computing, A stops between two stages.
    drop(conn_a);
    drop(conn_b);
    let cancelled = wait_for_metric(&srv, "skybake_computations_cancelled_total", 2.0).await;
    assert_eq!(cancelled, 2.0);
    let m = srv.get("/metrics").await.text();
    assert_eq!(
        metric(&m, "skybake_computations_queue_shed_total"),
        Some(1.0)
    );
    assert_eq!(metric(&m, "skybake_computations_in_flight"), Some(0.0));
    assert_eq!(
        srv.state.metrics().computations("sky"),
        1,
        "the queued computation never started"
    );
    assert!(!srv.state.cache().contains(&cache_key(&srv, a)));
    // Nothing is left holding the slot: a fresh request is computed and answered.
    let fresh = srv.get(c).await;
    assert_eq!(fresh.status, 200, "{}", fresh.text());
    // And A asked again is computed whole (the cancelled table was not kept half-built).
    let again = srv.get(a).await;
    assert_eq!(again.status, 200, "{}", again.text());
    assert!(again.json()["meta"]["error_estimate"]["scattering_orders"]
        .as_u64()
        .is_some_and(|n| n >= 2));
    srv.stop().await;
}

/// The earth preset with its aerosol optical depth (0.1 at 550 nm) replaced by `tau`.
fn earth_with_aerosol(tau: f64) -> String {
    let earth = include_str!("../../config/atmospheres/earth.json");
    let thick = earth.replace("\"value\": 0.1,", &format!("\"value\": {tau:.1},"));
    assert_ne!(thick, earth);
    let compact: String = thick.split_whitespace().collect::<Vec<_>>().join("");
    form_urlencoded::byte_serialize(compact.as_bytes()).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_above_the_cost_budget_is_refused_naming_it() {
    let dir = Scratch::new("cost");
    let srv = TestServer::start(settings(dir.path())).await;
    // The case that motivated the cost cap: aerosol optical depth 100 took 90 s of CPU for one sun product.
    let r = srv
        .get(&format!("/v1/sun?atmosphere={}", earth_with_aerosol(100.0)))
        .await;
    assert_eq!(r.status, 413, "{}", r.text());
    let p = r.json();
    assert_eq!(p["parameter"], "request_cost");
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("server.max_request_cost"), "{detail}");
    assert!(detail.contains("limit 100000000"), "{detail}");
    assert_eq!(srv.state.metrics().computations("sun"), 0);
    // The default request is well within the budget.
    let ok = srv
        .get("/v1/sun?method=fast&quality=draft&wavelengths=550")
        .await;
    assert_eq!(ok.status, 200, "{}", ok.text());
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_atmosphere_outside_the_validated_range_is_not_validated() {
    let dir = Scratch::new("validated");
    let srv = TestServer::start(settings(dir.path())).await;
    let cheap = "method=fast&quality=draft&wavelengths=550&sun_elevation_deg=45";
    let thin = srv.get(&format!("/v1/sun?{cheap}")).await.json();
    assert_eq!(thin["error_estimate"]["validated"], true, "{thin}");
    let thick = srv
        .get(&format!(
            "/v1/sun?{cheap}&atmosphere={}",
            earth_with_aerosol(5.0)
        ))
        .await
        .json();
    assert_eq!(thick["error_estimate"]["validated"], false, "{thick}");
    let caveat = thick["error_estimate"]["caveat"].as_str().unwrap();
    assert!(caveat.contains("optical depth"), "{caveat}");
    srv.stop().await;
}
