//! Hostile clients over real connections: 500 uploads trickling their bodies hold no slot that
//! cached reads need and are answered 408; one client address is held to
//! `server.max_connections_per_client` while others are served; `Expect: 100-continue` with an
//! oversized length is a 413 without `100 Continue`; failed authentication is rate-limited.
//! (Latency under this load is measured by `tools/slow_clients.py`, not asserted here.)

use crate::service_support;

use service_support::{metric, request, settings, Scratch, TestServer};
use std::net::SocketAddr;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};

/// A cheap sun product, cached once asked.
const SUN: &str = "/v1/sun?method=fast&quality=draft&wavelengths=550";

/// A connection from the loopback address `from` (127.0.0.x: another client address).
async fn connect_from(from: [u8; 4], to: SocketAddr) -> TcpStream {
    let socket = TcpSocket::new_v4().unwrap();
    socket
        .bind(SocketAddr::from((from, 0)))
        .expect("bind a loopback source address");
    socket.connect(to).await.expect("connect")
}

/// Sends a whole request on `s` and reads the answer until the server closes (10 s at most).
async fn ask(mut s: TcpStream, request: &str) -> Vec<u8> {
    let _ = s.write_all(request.as_bytes()).await;
    read_all(&mut s).await
}

async fn read_all(s: &mut TcpStream) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) | Err(_) => return out,
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
        }
    }
}

fn status(raw: &[u8]) -> u16 {
    std::str::from_utf8(raw.get(9..12).unwrap_or_default())
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0)
}

fn get(path: &str) -> String {
    format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn five_hundred_slow_bodies_hold_no_slot_and_get_408() {
    let dir = Scratch::new("slow-bodies");
    let mut s = settings(dir.path());
    // Far fewer slots than slow clients: if a slow body held one, cached reads would be shed.
    s.server.concurrency_limit = 16;
    s.server.max_connections = 2000;
    s.server.max_connections_per_client = 1000;
    s.server.body_read_timeout_s = 2.0;
    let srv = TestServer::start(s).await;
    assert_eq!(
        srv.get(SUN).await.status,
        200,
        "the cached read is computed"
    );

    // 500 uploads that declare 500 bytes and send one.
    let mut slow = Vec::new();
    for _ in 0..500 {
        let mut c = TcpStream::connect(srv.addr).await.unwrap();
        c.write_all(b"POST /v1/plan HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 500\r\n\r\n{")
            .await
            .unwrap();
        slow.push(c);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let addr = srv.addr;
    // Cached reads meanwhile, from the same client address, 16 at a time.
    for _ in 0..3 {
        let answers = futures_join(
            (0..16)
                .map(|_| async move { request(addr, "GET", SUN, None).await.status })
                .collect(),
        )
        .await;
        assert!(
            answers.iter().all(|&s| s == 200),
            "cached reads: {answers:?}"
        );
    }
    // Each slow upload is answered 408 problem+json (and closed) after the body timeout.
    let answers = futures_join(
        slow.into_iter()
            .map(|mut c| async move { read_all(&mut c).await })
            .collect(),
    )
    .await;
    let timed_out = answers.iter().filter(|a| status(a) == 408).count();
    assert_eq!(timed_out, 500, "{}", String::from_utf8_lossy(&answers[0]));
    let text = String::from_utf8_lossy(&answers[0]).to_ascii_lowercase();
    assert!(
        text.contains("content-type: application/problem+json"),
        "{text}"
    );
    assert!(text.contains("server.body_read_timeout_s"), "{text}");
    let m = srv.get("/metrics").await.text();
    assert_eq!(metric(&m, "skybake_body_timeouts_total"), Some(500.0));
    assert_eq!(metric(&m, "skybake_load_shed_total"), Some(0.0));
    srv.stop().await;
}

/// Runs the futures concurrently and returns their outputs in order.
async fn futures_join<T: Send + 'static>(
    futures: Vec<impl std::future::Future<Output = T> + Send + 'static>,
) -> Vec<T> {
    let handles: Vec<_> = futures.into_iter().map(tokio::spawn).collect();
    let mut out = Vec::new();
    for h in handles {
        out.push(h.await.unwrap());
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_client_address_is_held_to_its_connection_cap() {
    let dir = Scratch::new("per-client-cap");
    let mut s = settings(dir.path());
    s.server.max_connections_per_client = 4;
    s.server.header_read_timeout_s = 30.0;
    let srv = TestServer::start(s).await;
    let mut held = Vec::new();
    for _ in 0..4 {
        let mut c = connect_from([127, 0, 0, 1], srv.addr).await;
        c.write_all(b"GET /healthz HTTP/1.1\r\n").await.unwrap();
        held.push(c);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let fifth = connect_from([127, 0, 0, 1], srv.addr).await;
    assert!(
        ask(fifth, &get("/healthz")).await.is_empty(),
        "a fifth connection of the same address is closed unanswered"
    );
    let other = connect_from([127, 0, 0, 2], srv.addr).await;
    assert_eq!(status(&ask(other, &get("/healthz")).await), 200);
    drop(held);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let again = connect_from([127, 0, 0, 1], srv.addr).await;
    assert_eq!(status(&ask(again, &get("/healthz")).await), 200, "freed");
    let m = srv.get("/metrics").await.text();
    assert_eq!(
        metric(&m, "skybake_client_connections_refused_total"),
        Some(1.0)
    );
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn expect_continue_with_an_oversized_length_gets_413_not_100() {
    let dir = Scratch::new("expect-continue");
    let srv = TestServer::start(settings(dir.path())).await;
    for path in ["/v1/plan", "/v1/render", "/v1/jobs"] {
        let c = TcpStream::connect(srv.addr).await.unwrap();
        let raw = ask(
            c,
            &format!("POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nExpect: 100-continue\r\nContent-Length: 99999999\r\n\r\n"),
        )
        .await;
        let text = String::from_utf8_lossy(&raw);
        assert!(text.starts_with("HTTP/1.1 413"), "{path}: {text}");
        assert!(!text.contains("100 Continue"), "{path}: {text}");
        assert!(
            text.contains("1048576"),
            "{path}: the limit is stated: {text}"
        );
    }
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_is_case_insensitive_and_failed_attempts_are_rate_limited() {
    let dir = Scratch::new("auth-flood");
    let mut s = settings(dir.path());
    s.server.api_tokens = "0123456789abcdef0123".into();
    s.server.rate_limit_per_s = 1.0;
    s.server.rate_limit_burst = 5;
    let srv = TestServer::start(s).await;
    let with = |auth: &str| {
        format!("GET /v1/atmospheres HTTP/1.1\r\nHost: x\r\nAuthorization: {auth}\r\nConnection: close\r\n\r\n")
    };
    let lower = TcpStream::connect(srv.addr).await.unwrap();
    assert_eq!(
        status(&ask(lower, &with("bearer 0123456789abcdef0123")).await),
        200
    );
    let mut statuses = Vec::new();
    for _ in 0..12 {
        let c = TcpStream::connect(srv.addr).await.unwrap();
        statuses.push(status(
            &ask(c, &with("Bearer wrong-token-wrong-token")).await,
        ));
    }
    // The burst (5, one already taken by the good request) as 401s, then 429s.
    assert!(statuses[..4].iter().all(|&s| s == 401), "{statuses:?}");
    assert!(statuses[7..].iter().all(|&s| s == 429), "{statuses:?}");
    srv.stop().await;
}
