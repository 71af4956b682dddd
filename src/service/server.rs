//! Running the service: bind, serve until SIGTERM or ctrl-c (graceful: in-flight requests finish,
//! job progress is already persisted), and the tiny HTTP client behind `skybake healthcheck`.

use super::{app, AppState};
use crate::config::Settings;
use std::future::Future;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// Serves `state` on `listener` until `shutdown` resolves, then drains in-flight requests.
pub async fn serve_on(
    listener: tokio::net::TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    state.start_job_workers();
    axum::serve(listener, app(state))
        .with_graceful_shutdown(shutdown)
        .await
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
    // Requests have drained; a job item still computing on a blocking thread is abandoned after a
    // grace period (its job resumes from the persisted progress at the next start).
    rt.shutdown_timeout(SHUTDOWN_GRACE);
    result
}

/// How long shutdown waits for engine computations still running on blocking threads.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(10);

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
