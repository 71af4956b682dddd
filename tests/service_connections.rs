//! Connection handling of the accept loop: a client that never finishes its headers is cut off
//! after `server.header_read_timeout_s`, an idle kept-alive connection likewise, at most
//! `server.max_connections` connections are open, and a shutdown ends within
//! `server.shutdown_grace_s` whatever the clients do.

mod service_support;

use service_support::{metric, settings, Scratch, TestServer};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Reads until the peer closes (or 10 s pass); returns what was read and how long it took.
async fn read_until_closed(stream: &mut TcpStream) -> (Vec<u8>, Duration) {
    let start = Instant::now();
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match tokio::time::timeout(Duration::from_secs(10), stream.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) | Err(_) => break,
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
        }
    }
    (out, start.elapsed())
}

#[tokio::test]
async fn half_sent_headers_and_idle_connections_are_closed_after_the_header_timeout() {
    let dir = Scratch::new("header-timeout");
    let mut s = settings(dir.path());
    s.server.header_read_timeout_s = 0.5;
    let srv = TestServer::start(s).await;

    // Half a request line and no more.
    let mut slow = TcpStream::connect(srv.addr).await.unwrap();
    slow.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    let (_, waited) = read_until_closed(&mut slow).await;
    assert!(
        waited < Duration::from_secs(5),
        "a client that never ends its headers is held {waited:?}"
    );

    // A kept-alive connection that goes quiet after one request.
    let mut idle = TcpStream::connect(srv.addr).await.unwrap();
    idle.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    let (answer, waited) = read_until_closed(&mut idle).await;
    assert!(answer.starts_with(b"HTTP/1.1 200"), "{answer:?}");
    assert!(
        waited < Duration::from_secs(5),
        "idle connection held {waited:?}"
    );
    srv.stop().await;
}

#[tokio::test]
async fn connections_over_the_cap_are_closed_and_counted() {
    let dir = Scratch::new("connection-cap");
    let mut s = settings(dir.path());
    s.server.max_connections = 2;
    s.server.header_read_timeout_s = 30.0;
    let srv = TestServer::start(s).await;
    // Two connections that hold their slots with unfinished headers.
    let mut held = Vec::new();
    for _ in 0..2 {
        let mut c = TcpStream::connect(srv.addr).await.unwrap();
        c.write_all(b"GET /healthz HTTP/1.1\r\n").await.unwrap();
        held.push(c);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut third = TcpStream::connect(srv.addr).await.unwrap();
    let _ = third
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .await;
    let (answer, waited) = read_until_closed(&mut third).await;
    assert!(answer.is_empty(), "served over the cap: {answer:?}");
    assert!(waited < Duration::from_secs(5));
    drop(held);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let r = srv.get("/healthz").await;
    assert_eq!(r.status, 200, "a slot frees when a connection closes");
    let m = srv.get("/metrics").await;
    assert!(metric(&m.text(), "skybake_connections_refused_total").unwrap_or(0.0) >= 1.0);
    srv.stop().await;
}

#[tokio::test]
async fn shutdown_ends_within_its_grace_period_despite_a_stalled_client() {
    let dir = Scratch::new("shutdown-grace");
    let mut s = settings(dir.path());
    s.server.header_read_timeout_s = 600.0;
    s.server.shutdown_grace_s = 0.5;
    let srv = TestServer::start(s).await;
    let mut stalled = TcpStream::connect(srv.addr).await.unwrap();
    stalled
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let start = Instant::now();
    tokio::time::timeout(Duration::from_secs(10), srv.stop())
        .await
        .expect("shutdown hangs on a stalled client");
    assert!(
        start.elapsed() < Duration::from_secs(5),
        "{:?}",
        start.elapsed()
    );
    drop(stalled);
}
