//! Running the service: bind, serve until SIGTERM or ctrl-c (graceful: in-flight requests finish,
//! job progress is already persisted), and the tiny HTTP client behind `skybake healthcheck`.

use super::conn::ClientConn;
use super::{app, AppState};
use axum::body::Body;
use axum::http::Request;
use hyper::body::Incoming;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto;
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use skybake_product::config::Settings;
use std::collections::HashMap;
use std::future::Future;
use std::io::{Read, Write};
use std::net::{IpAddr, SocketAddr, TcpStream};
use std::pin::Pin;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::Semaphore;
use tower::ServiceExt;

/// Serves `state` on `listener` until `shutdown` resolves, then drains open connections for at
/// most `server.shutdown_grace_s` and closes whatever is left, so a slow or stalled client cannot
/// hold the shutdown.
///
/// The accept loop is hyper's own (axum::serve exposes none of these): a request's headers must
/// arrive within `server.header_read_timeout_s` (on a kept-alive connection the wait for the next
/// request counts too, so it is also the idle timeout), and at most `server.max_connections` are
/// open, at most `server.max_connections_per_client` of one client address; further connections
/// are closed as soon as they are accepted and counted. The requests
/// hyper refuses itself (a URI over 64 KiB, a head over its buffer, a malformed head) get the
/// service's problem+json answer ([`ClientConn`]), not hyper's empty one.
pub async fn serve_on(
    listener: tokio::net::TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    serve_until(listener, state, Box::pin(shutdown)).await
}

/// [`serve_on`] with the shutdown signal boxed: the accept loop and hyper's connection types are
/// compiled once, here, instead of in every crate that starts a server (the test binaries).
async fn serve_until(
    listener: tokio::net::TcpListener,
    state: AppState,
    mut shutdown: Pin<Box<dyn Future<Output = ()> + Send>>,
) -> std::io::Result<()> {
    let server = state.settings().server.clone();
    let header_timeout = Duration::from_secs_f64(server.header_read_timeout_s);
    let grace = Duration::from_secs_f64(server.shutdown_grace_s);
    let connections = Arc::new(Semaphore::new(server.max_connections));
    let per_client = ClientConnections::new(server.max_connections_per_client);
    let metrics_state = state.clone();
    state.start_job_workers();
    let router = app(state);
    let graceful = GracefulShutdown::new();
    let mut builder = auto::Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(header_timeout);
    builder
        .http2()
        .timer(TokioTimer::new())
        .keep_alive_interval(header_timeout)
        .keep_alive_timeout(header_timeout);

    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(pair) => pair,
                Err(e) => {
                    // Out of file descriptors and similar: back off instead of spinning.
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        let metrics = metrics_state.metrics();
        let Ok(permit) = Arc::clone(&connections).try_acquire_owned() else {
            metrics.connections_refused.fetch_add(1, Ordering::Relaxed);
            drop(stream);
            continue;
        };
        let Some(client_slot) = per_client.open(peer.ip()) else {
            metrics
                .client_connections_refused
                .fetch_add(1, Ordering::Relaxed);
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let service =
            TowerToHyperService::new(router.clone().map_request(move |req: Request<Incoming>| {
                // The peer address, for the per-client rate limit.
                let mut req = req.map(Body::new);
                req.extensions_mut()
                    .insert(axum::extract::ConnectInfo(peer));
                req
            }));
        let connection = builder
            .serve_connection_with_upgrades(TokioIo::new(ClientConn::new(stream)), service)
            .into_owned();
        let connection = graceful.watch(connection);
        let open = metrics_state.clone();
        open.metrics()
            .connections_open
            .fetch_add(1, Ordering::Relaxed);
        tokio::spawn(async move {
            if let Err(e) = connection.await {
                tracing::debug!(error = %e, "connection ended with an error");
            }
            open.metrics()
                .connections_open
                .fetch_sub(1, Ordering::Relaxed);
            drop(client_slot);
            drop(permit);
        });
    }
    drop(listener);
    tracing::info!("shutting down: draining open connections");
    if tokio::time::timeout(grace, graceful.shutdown())
        .await
        .is_err()
    {
        tracing::warn!(
            grace_s = grace.as_secs_f64(),
            "connections still open after the shutdown grace period: closed"
        );
    }
    Ok(())
}

/// Open connections per client address, capped at `server.max_connections_per_client`.
#[derive(Clone)]
struct ClientConnections {
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
    max: usize,
}

/// One open connection of a client; dropping it frees its place.
struct ClientSlot {
    of: ClientConnections,
    ip: IpAddr,
}

impl ClientConnections {
    fn new(max: usize) -> Self {
        Self {
            open: Default::default(),
            max,
        }
    }

    /// A place for one more connection of `ip`, if it has fewer than the cap open.
    fn open(&self, ip: IpAddr) -> Option<ClientSlot> {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let n = open.entry(ip).or_insert(0);
        if *n >= self.max {
            return None;
        }
        *n += 1;
        Some(ClientSlot {
            of: self.clone(),
            ip,
        })
    }
}

impl Drop for ClientSlot {
    fn drop(&mut self) {
        let mut open = self.of.open.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = open.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

/// Resolves on SIGTERM or ctrl-c.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    tracing::info!("shutting down: draining in-flight requests");
}

/// `skybake serve`: builds the runtime from the settings, binds, prints `listening on ADDR` to
/// stderr, and serves until SIGTERM or ctrl-c.
pub fn run(settings: Settings) -> Result<(), String> {
    let addr = settings.bind_addr().map_err(|e| e.to_string())?;
    let grace = Duration::from_secs_f64(settings.server.shutdown_grace_s);
    let mut rt = tokio::runtime::Builder::new_multi_thread();
    rt.enable_all();
    if settings.server.worker_threads > 0 {
        rt.worker_threads(settings.server.worker_threads);
    }
    let rt = rt
        .build()
        .map_err(|e| format!("cannot start the runtime: {e}"))?;
    let result = rt.block_on(async move {
        let state = AppState::new(settings).map_err(|e| format!("cannot open the cache: {e}"))?;
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(|e| format!("cannot bind {addr}: {e}"))?;
        let local = listener.local_addr().map_err(|e| e.to_string())?;
        eprintln!("listening on {local}");
        serve_on(listener, state, shutdown_signal())
            .await
            .map_err(|e| format!("server error: {e}"))
    });
    // Connections have drained (or were closed after the grace period); a job item still computing
    // on a blocking thread is abandoned after another grace period (its job resumes from the
    // persisted progress at the next start).
    rt.shutdown_timeout(grace);
    result
}

/// `skybake healthcheck`: `GET /healthz` on `addr` (0.0.0.0 is asked as 127.0.0.1); Ok when 200.
pub fn healthcheck(addr: SocketAddr) -> Result<(), String> {
    let addr = if addr.ip().is_unspecified() {
        SocketAddr::from(([127, 0, 0, 1], addr.port()))
    } else {
        addr
    };
    let timeout = Duration::from_secs(3);
    let mut s = TcpStream::connect_timeout(&addr, timeout).map_err(|e| format!("{addr}: {e}"))?;
    s.set_read_timeout(Some(timeout))
        .map_err(|e| e.to_string())?;
    s.set_write_timeout(Some(timeout))
        .map_err(|e| e.to_string())?;
    write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .map_err(|e| e.to_string())?;
    let mut head = [0u8; 12];
    s.read_exact(&mut head).map_err(|e| e.to_string())?;
    if &head[..9] == b"HTTP/1.1 " && &head[9..12] == b"200" {
        Ok(())
    } else {
        Err(format!("unhealthy: {}", String::from_utf8_lossy(&head)))
    }
}
