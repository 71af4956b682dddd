//! `GET /v1/lut` (the texture bundle's manifest with links) and `GET /v1/lut/files/{key}` (its
//! textures): computed once and cached, ETag/304, compression of the manifest, problems naming
//! the parameter.

use crate::service_support;

use service_support::{settings, Scratch, TestServer};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

async fn request_with(
    addr: std::net::SocketAddr,
    path: &str,
    headers: &str,
) -> service_support::Response {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{headers}Content-Length: 0\r\n\r\n"
    );
    s.write_all(head.as_bytes()).await.unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).await.unwrap();
    service_support::parse_response(&raw)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bundle_is_served_as_a_manifest_with_links_to_cached_textures() {
    let dir = Scratch::new("lut");
    let mut s = settings(dir.path());
    // A cold bundle (its precise table included) takes tens of seconds on a loaded machine.
    s.server.request_timeout_s = 900.0;
    let srv = TestServer::start(s).await;

    // Refusals name the parameter, before anything is computed.
    for (query, name, status) in [
        ("sun_elevation_deg=10", "sun_elevation_deg", 422),
        ("quality=draft&ground_albedo=2", "ground_albedo", 400),
        ("quality=draft&layout=bruneton", "layout", 400),
    ] {
        let r = srv.get(&format!("/v1/lut?{query}")).await;
        assert_eq!(r.status, status, "{}", r.text());
        assert_eq!(r.header("content-type"), Some("application/problem+json"));
        assert_eq!(r.json()["parameter"], name, "{}", r.text());
    }
    // `layout` is the bundle's alone: a product refuses it by name.
    let r = srv.get("/v1/sky?layout=skyview").await;
    assert!(r.status == 400 || r.status == 422, "{}", r.text());
    assert_eq!(r.json()["parameter"], "layout", "{}", r.text());
    let r = srv.get("/v1/lut?quality=draft&colour=1").await;
    assert_eq!(r.status, 400, "{}", r.text());
    assert!(r.text().contains("colour"), "{}", r.text());
    let r = srv.get("/v1/lut/files/00000000000000ff").await;
    assert_eq!(r.status, 404);
    assert_eq!(r.header("content-type"), Some("application/problem+json"));

    let path = "/v1/lut?quality=draft";
    let first = srv.get(path).await;
    assert_eq!(first.status, 200, "{}", first.text());
    assert_eq!(first.header("content-type"), Some("application/json"));
    assert_eq!(first.header("x-cache"), Some("miss"));
    let etag = first.header("etag").unwrap().to_string();
    let manifest = first.json();
    assert_eq!(manifest["request"]["form"], "rgb");
    assert_eq!(manifest["request"]["quality"], "draft");
    let links = manifest["links"].as_object().unwrap().clone();
    for name in ["transmittance.exr", "scattering.exr", "irradiance.exr"] {
        assert!(links.contains_key(name), "{links:?}");
    }
    assert_eq!(srv.state.metrics().computations("lut"), 1);

    // Again: from the cache, the same bytes; with the ETag: 304 and no body.
    let again = srv.get(path).await;
    assert_eq!(again.header("x-cache"), Some("hit"));
    assert_eq!(again.body, first.body);
    let r = request_with(srv.addr, path, &format!("If-None-Match: {etag}\r\n")).await;
    assert_eq!(r.status, 304);
    assert!(r.body.is_empty());
    // The manifest is compressed for a client that accepts gzip.
    let gz = request_with(srv.addr, path, "Accept-Encoding: gzip\r\n").await;
    assert_eq!(gz.header("content-encoding"), Some("gzip"));
    let mut plain = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&gz.body[..]), &mut plain)
        .unwrap();
    assert_eq!(plain, first.body);
    assert_eq!(srv.state.metrics().computations("lut"), 1);

    // Each link is an immutable EXR texture, 304 with its ETag.
    for (name, url) in &links {
        let url = url.as_str().unwrap();
        let t = srv.get(url).await;
        assert_eq!(t.status, 200, "{name}: {}", t.text());
        assert_eq!(t.header("content-type"), Some("image/x-exr"));
        assert_eq!(t.body[..4], EXR_MAGIC);
        assert!(t.header("cache-control").unwrap().contains("immutable"));
        let tag = t.header("etag").unwrap().to_string();
        let r = request_with(srv.addr, url, &format!("If-None-Match: {tag}\r\n")).await;
        assert_eq!(r.status, 304, "{name}");
    }
    srv.stop().await;
}

/// The second layout over HTTP (`layout=skyview`): its own manifest, files and cache entry.
/// One cold sky-view build (about 30 s of CPU): ignored by the README's command, run by `.ci/run`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore]
async fn the_skyview_layout_is_served_with_its_own_files() {
    let dir = Scratch::new("lut-skyview");
    let mut s = settings(dir.path());
    s.server.request_timeout_s = 900.0;
    let srv = TestServer::start(s).await;

    let path = "/v1/lut?quality=draft&layout=skyview";
    let first = srv.get(path).await;
    assert_eq!(first.status, 200, "{}", first.text());
    assert_eq!(first.header("x-cache"), Some("miss"));
    let manifest = first.json();
    assert_eq!(manifest["format"], "skyview", "{manifest}");
    assert_eq!(manifest["request"]["layout"], "skyview");
    let links = manifest["links"].as_object().unwrap().clone();
    for name in [
        "transmittance.exr",
        "skyview_rayleigh.exr",
        "skyview_mie.exr",
        "skyview_scale.exr",
        "skyview_irradiance.exr",
    ] {
        assert!(links.contains_key(name), "{links:?}");
    }
    assert!(!links.contains_key("scattering.exr"), "{links:?}");
    for (name, url) in &links {
        let t = srv.get(url.as_str().unwrap()).await;
        assert_eq!(t.status, 200, "{name}: {}", t.text());
        assert_eq!(t.body[..4], EXR_MAGIC, "{name}");
    }
    let again = srv.get(path).await;
    assert_eq!(again.header("x-cache"), Some("hit"));
    assert_eq!(again.body, first.body);
    // Bruneton's layout is another bundle with its own key.
    let bruneton = srv.get("/v1/lut?quality=draft").await;
    assert_eq!(bruneton.status, 200, "{}", bruneton.text());
    assert_ne!(bruneton.header("etag"), first.header("etag"));
    assert_eq!(srv.state.metrics().computations("lut"), 2);
    srv.stop().await;
}
