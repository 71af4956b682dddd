//! Shared helpers of the service tests: a scratch directory, settings for fast tests, an in-process
//! server on an ephemeral port, and a minimal HTTP/1.1 client (one request per connection).
#![allow(dead_code)]

pub mod json_mutation;
pub mod s3;

use skybake_product::config::Settings;
use skybake_service::{server, AppState};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Cheap product parameters: fast multiple scattering, draft quality, three wavelengths, small table.
pub const FAST: &str =
    "method=fast&quality=draft&wavelengths=440,550,680&elevation_count=9&azimuth_count=8";

/// A fresh scratch directory under the system temp dir (removed on drop).
pub struct Scratch(pub PathBuf);

impl Scratch {
    pub fn new(name: &str) -> Self {
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let dir =
            std::env::temp_dir().join(format!("skybake-{name}-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Default settings with the cache in `dir`.
pub fn settings(dir: &Path) -> Settings {
    let mut s = Settings::defaults();
    s.cache.dir = dir.to_path_buf();
    s.server.bind = "127.0.0.1:0".into();
    s
}

/// A server running on its own task.
pub struct TestServer {
    pub addr: std::net::SocketAddr,
    pub state: AppState,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<std::io::Result<()>>,
}

impl TestServer {
    pub async fn start(settings: Settings) -> Self {
        let state = AppState::new(settings).expect("state");
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel();
        let task = tokio::spawn(server::serve_on(listener, state.clone(), async move {
            let _ = rx.await;
        }));
        Self {
            addr,
            state,
            stop: Some(tx),
            task,
        }
    }

    pub async fn get(&self, path: &str) -> Response {
        request(self.addr, "GET", path, None).await
    }

    pub async fn post(&self, path: &str, body: &str) -> Response {
        request(self.addr, "POST", path, Some(body.as_bytes())).await
    }

    pub async fn delete(&self, path: &str) -> Response {
        request(self.addr, "DELETE", path, None).await
    }

    /// Graceful shutdown; waits for the server task.
    pub async fn stop(mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        let _ = (&mut self.task).await;
    }
}

/// A parsed HTTP response.
#[derive(Debug)]
pub struct Response {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| {
            panic!(
                "status {}: body is not JSON ({e}): {}",
                self.status,
                String::from_utf8_lossy(&self.body)
            )
        })
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

/// One request on a fresh connection (`Connection: close`), read to the end.
pub async fn request(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    body: Option<&[u8]>,
) -> Response {
    let mut s = TcpStream::connect(addr).await.expect("connect");
    let body = body.unwrap_or(b"");
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    // A server may answer (413) before reading the whole body: write errors are not fatal.
    if s.write_all(head.as_bytes()).await.is_ok() {
        let _ = s.write_all(body).await;
    }
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).await.expect("read");
    parse_response(&raw)
}

/// Runs the `skybake` binary with `args` and checks that it succeeded (its stderr otherwise).
pub fn skybake_ok<I, S>(args: I) -> std::process::Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skybake"))
        .args(args)
        .output()
        .expect("run skybake");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// One request through the router in process (no socket), the whole response read.
pub async fn send(state: &AppState, req: axum::http::Request<axum::body::Body>) -> Response {
    use tower::ServiceExt;
    let resp = skybake_service::app(state.clone())
        .oneshot(req)
        .await
        .expect("router");
    let status = resp.status().as_u16();
    let headers = resp
        .headers()
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_str().unwrap_or("").to_string()))
        .collect();
    let body = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .expect("body")
        .to_vec();
    Response {
        status,
        headers,
        body,
    }
}

/// [`send`] of `method` `uri` with a JSON `body`.
pub async fn call(state: &AppState, method: &str, uri: &str, body: impl Into<Vec<u8>>) -> Response {
    let req = axum::http::Request::builder()
        .method(method)
        .uri(uri)
        .header("content-type", "application/json")
        .body(axum::body::Body::from(body.into()))
        .expect("request");
    send(state, req).await
}

/// Parses a full HTTP/1.1 response (content-length or chunked body).
pub fn parse_response(raw: &[u8]) -> Response {
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("end of head");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.split("\r\n");
    let status: u16 = lines
        .next()
        .and_then(|l| l.split(' ').nth(1))
        .and_then(|s| s.parse().ok())
        .expect("status line");
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect();
    let rest = &raw[split + 4..];
    let chunked = headers.iter().any(|(k, v)| {
        k.eq_ignore_ascii_case("transfer-encoding") && v.eq_ignore_ascii_case("chunked")
    });
    let body = if chunked {
        let mut out = Vec::new();
        let mut i = 0;
        loop {
            let eol = i + rest[i..].windows(2).position(|w| w == b"\r\n").unwrap();
            let size =
                usize::from_str_radix(String::from_utf8_lossy(&rest[i..eol]).trim(), 16).unwrap();
            if size == 0 {
                break;
            }
            out.extend_from_slice(&rest[eol + 2..eol + 2 + size]);
            i = eol + 2 + size + 2;
        }
        out
    } else {
        rest.to_vec()
    };
    Response {
        status,
        headers,
        body,
    }
}

/// The value of a Prometheus series line `name` (exact, with labels) in a metrics text.
pub fn metric(text: &str, series: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(series).and_then(|r| r.strip_prefix(' ')))
        .and_then(|v| v.trim().parse().ok())
}

/// The `validation-frame` example scene made cheap: `w` × `h` pixels, draft quality, 100 m voxels
/// (a grid of about 20³).
pub fn tiny_frame_scene(w: usize, h: usize) -> serde_json::Value {
    let text = skybake_product::frame::EXAMPLE_SCENES
        .iter()
        .find(|(n, _)| *n == "validation-frame")
        .unwrap()
        .1;
    let mut scene: serde_json::Value = serde_json::from_str(text).unwrap();
    scene["camera"]["width"] = serde_json::json!(w);
    scene["camera"]["height"] = serde_json::json!(h);
    scene["quality"] = serde_json::json!("draft");
    scene["cloud"]["voxel_size_m"] = serde_json::json!(100.0);
    scene
}

/// One engine for the tests of a binary that only compute with it: its table cache keeps the
/// precise tables, which every product and frame under the same atmosphere, wavelengths and
/// quality shares, so they are built once per binary rather than once per test. A test that reads
/// an engine's counters, or checks that tables are built or loaded, makes its own.
pub fn shared_engine() -> &'static skybake_engine::engine::Engine {
    static ENGINE: std::sync::OnceLock<skybake_engine::engine::Engine> = std::sync::OnceLock::new();
    ENGINE.get_or_init(skybake_engine::engine::Engine::new)
}

/// Bakes a one-item `job` into `out` (offline, default parameters) and returns the EXR it wrote.
pub fn bake_single_exr(job: &serde_json::Value, out: &Path) -> Vec<u8> {
    let summary = skybake_job::bake::bake(
        job.to_string().as_bytes(),
        out,
        &skybake_product::params::Defaults::default(),
        10,
        shared_engine(),
        |_, _, _| {},
    )
    .unwrap();
    assert_eq!(summary.computed, 1);
    let name = std::fs::read_dir(out)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().into_string().unwrap())
        .find(|n| n.ends_with(".exr"))
        .unwrap();
    std::fs::read(out.join(name)).unwrap()
}
