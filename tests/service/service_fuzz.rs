//! Property test: random query strings and JSON bodies thrown at the router (tower `oneshot`, no
//! network) never produce a 5xx or a panic, and every error is problem+json naming something.
//! Requests that happen to be valid are kept cheap (fast method, draft, one wavelength, tiny
//! tables) so about 2 000 cases run in seconds.

use crate::service_support;

use axum::body::Body;
use axum::http::Request;
use proptest::prelude::*;
use service_support::{settings, Scratch};
use skybake_service::{app, AppState};
use std::sync::OnceLock;
use tower::ServiceExt;

struct Fixture {
    rt: tokio::runtime::Runtime,
    state: AppState,
    _dir: Scratch,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let dir = Scratch::new("fuzz");
        let mut s = settings(dir.path());
        // No job workers run here, so valid jobs stay queued: the live-job limit (503, not the
        // body's fault) must not be what a long run of valid bodies meets.
        s.jobs.max_live = 100_000;
        let state = AppState::new(s).unwrap();
        Fixture {
            rt: tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .unwrap(),
            state,
            _dir: dir,
        }
    })
}

/// Sends one request; returns (status, content type, body).
fn send(method: &str, uri: &str, body: Vec<u8>) -> (u16, String, Vec<u8>) {
    let f = fixture();
    f.rt.block_on(async {
        let req = Request::builder()
            .method(method)
            .uri(uri)
            .header("content-type", "application/json")
            .body(Body::from(body))
            .unwrap();
        let resp = app(f.state.clone()).oneshot(req).await.unwrap();
        let status = resp.status().as_u16();
        let ct = resp
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        let bytes = axum::body::to_bytes(resp.into_body(), 1 << 26)
            .await
            .unwrap();
        (status, ct, bytes.to_vec())
    })
}

fn check(status: u16, ct: &str, body: &[u8], what: &str) {
    assert!(
        status < 500,
        "{what} → {status}: {}",
        String::from_utf8_lossy(body)
    );
    if status >= 400 {
        assert_eq!(ct, "application/problem+json", "{what}");
        let v: serde_json::Value = serde_json::from_slice(body).unwrap();
        assert_eq!(v["status"].as_u64(), Some(status as u64), "{what}");
        assert!(!v["detail"].as_str().unwrap_or("").is_empty(), "{what}");
    }
}

/// Parameter names a fuzzed request may set (the cost-controlling ones are fixed below).
const NAMES: [&str; 10] = [
    "sun_elevation_deg",
    "latitude_deg",
    "longitude_deg",
    "time",
    "observer_altitude_m",
    "probe",
    "max_distance_m",
    "format",
    "colour",
    "",
];

fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        (-200.0f64..200.0).prop_map(|v| format!("{v}")),
        (-1e9f64..1e9).prop_map(|v| format!("{v:e}")),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("-0".to_string()),
        Just("earth".to_string()),
        Just("rayleigh-only".to_string()),
        Just("{\"name\":1}".to_string()),
        Just("2026-06-21T12:00:00Z".to_string()),
        Just("120:0,180:45".to_string()),
        Just("30:0,".to_string()),
        Just("json".to_string()),
        Just("exr".to_string()),
        Just("png".to_string()),
        "[ -~]{0,12}",
        "\\PC{0,8}",
    ]
}

/// A (name, value) pair; parameters that select the shared engine tables (atmosphere, albedo) take
/// few distinct values so valid requests reuse tables instead of building new ones each case.
fn pair() -> impl Strategy<Value = (&'static str, String)> {
    prop_oneof![
        4 => (proptest::sample::select(NAMES.to_vec()), value()),
        1 => proptest::sample::select(vec!["0", "0.3", "1.5", "-1", "x", ""])
            .prop_map(|v| ("ground_albedo", v.to_string())),
        1 => proptest::sample::select(vec!["earth", "venus", "{", "{\"rayleigh\":null}", "[]", ""])
            .prop_map(|v| ("atmosphere", v.to_string())),
    ]
}

/// Settings that keep a valid request cheap.
const CHEAP: &str =
    "method=fast&quality=draft&wavelengths=550&elevation_count=3&azimuth_count=2&distance_count=2";

fn query() -> impl Strategy<Value = String> {
    prop_oneof![
        // Structured: known names with odd values, then the cheap settings.
        proptest::collection::vec(pair(), 0..5).prop_map(|pairs| {
            let mut q: String = form_urlencoded::Serializer::new(String::new())
                .extend_pairs(pairs)
                .finish();
            q.push('&');
            q.push_str(CHEAP);
            q
        }),
        // Raw garbage (still with the cheap settings, so a valid-by-chance query stays cheap).
        "[ -~]{0,60}".prop_map(|s| format!("{}&{CHEAP}", s.replace(['#', ' '], ""))),
    ]
}

fn json_value() -> impl Strategy<Value = serde_json::Value> {
    let leaf = prop_oneof![
        Just(serde_json::Value::Null),
        any::<bool>().prop_map(serde_json::Value::from),
        (-1e6f64..1e6).prop_map(serde_json::Value::from),
        "[a-z_]{0,10}".prop_map(serde_json::Value::from),
        proptest::sample::select(vec![
            "sun", "sky", "ground", "aerial", "fast", "draft", "550"
        ])
        .prop_map(serde_json::Value::from),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            proptest::collection::vec(inner.clone(), 0..4).prop_map(serde_json::Value::Array),
            proptest::collection::btree_map(
                proptest::sample::select(vec![
                    "product",
                    "products",
                    "grids",
                    "sweep",
                    "from",
                    "to",
                    "step",
                    "sun_elevation_deg",
                    "observer_altitude_m",
                    "atmosphere",
                    "x",
                ])
                .prop_map(String::from),
                inner,
                0..4
            )
            .prop_map(|m| serde_json::Value::Object(m.into_iter().collect())),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn random_queries_never_5xx(
        route in proptest::sample::select(vec!["/v1/sun", "/v1/sky", "/v1/ground", "/v1/aerial", "/v1/jobs/00000000000000ff", "/v1/jobs/zz/artifacts/-1", "/healthz"]),
        q in query(),
    ) {
        let uri = format!("{route}?{q}");
        if let Ok(uri) = uri.parse::<axum::http::Uri>() {
            let (status, ct, body) = send("GET", &uri.to_string(), Vec::new());
            check(status, &ct, &body, &uri.to_string());
        }
    }

    #[test]
    fn random_bodies_never_5xx(
        route in proptest::sample::select(vec!["/v1/plan", "/v1/jobs"]),
        body in prop_oneof![
            json_value().prop_map(|v| {
                // Keep valid jobs and plans cheap: fix method, quality and wavelengths when absent.
                let mut v = v;
                if let serde_json::Value::Object(m) = &mut v {
                    m.entry("method").or_insert("fast".into());
                    m.entry("wavelengths").or_insert("550".into());
                }
                v.to_string().into_bytes()
            }),
            proptest::collection::vec(any::<u8>(), 0..64),
        ],
    ) {
        let (status, ct, resp) = send("POST", route, body.clone());
        check(status, &ct, &resp, &String::from_utf8_lossy(&body));
    }
}

/// The HTTP surface fuzzed in-process (the router through tower's `oneshot`, no sockets):
/// generated methods, paths (every route, mangled), queries (the parameter table's names with odd
/// values), headers and bodies (scenes and jobs mutated from the examples, random JSON, raw bytes).
/// `SKYBAKE_FUZZ_REQUESTS` requests (default 3 000; `.ci/run` runs 100 000): none may answer 5xx
/// or panic, every error is problem+json, and the process's resident memory stays bounded.
#[test]
fn http_surface_fuzz() {
    use rand::SeedableRng;
    let n: usize = std::env::var("SKYBAKE_FUZZ_REQUESTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3000);
    let seed: u64 = std::env::var("SKYBAKE_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(30);
    let dir = Scratch::new("fuzz-surface");
    let mut s = settings(dir.path());
    s.jobs.max_live = 1_000_000;
    // A frame a mutation makes larger than a tiny one is refused for cost rather than rendered,
    // so the run stays quick; the refusal is part of what is fuzzed.
    s.server.max_frame_cost = 2_000_000_000;
    let state = AppState::new(s).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let router = app(state.clone());
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let scenes: Vec<serde_json::Value> = skybake_product::frame::EXAMPLE_SCENES
        .iter()
        .filter_map(|(_, t)| serde_json::from_str(t).ok())
        .chain([service_support::tiny_frame_scene(4, 3)])
        .collect();
    let start = std::time::Instant::now();
    let (mut statuses, mut failures) = (std::collections::BTreeMap::new(), Vec::new());
    let mut rss_at_tenth = 0;
    for i in 0..n {
        if i == n / 10 {
            rss_at_tenth = rss_kb();
        }
        let (method, uri, headers, body) = fuzz::request(&mut rng, &scenes);
        let Ok(parsed) = uri.parse::<axum::http::Uri>() else {
            continue;
        };
        let mut req = Request::builder().method(method.as_str()).uri(parsed);
        for (k, v) in &headers {
            req = req.header(k.as_str(), v.as_bytes());
        }
        let Ok(req) = req.body(Body::from(body.clone())) else {
            continue;
        };
        let app = router.clone();
        let outcome = rt.block_on(async move {
            tokio::spawn(async move {
                let resp = app.oneshot(req).await.unwrap();
                let status = resp.status().as_u16();
                let (ct, encoding) = {
                    let header = |name: &str| {
                        resp.headers()
                            .get(name)
                            .and_then(|v| v.to_str().ok())
                            .unwrap_or("")
                            .to_string()
                    };
                    (header("content-type"), header("content-encoding"))
                };
                let bytes = axum::body::to_bytes(resp.into_body(), 1 << 28)
                    .await
                    .map(|b| b.to_vec())
                    .unwrap_or_default();
                // Compressed when the client asked for gzip (the only coding the generator asks for).
                let bytes = if encoding == "gzip" {
                    use std::io::Read;
                    let mut plain = Vec::new();
                    match flate2::read::GzDecoder::new(&bytes[..]).read_to_end(&mut plain) {
                        Ok(_) => plain,
                        Err(e) => format!("undecodable gzip body: {e}").into_bytes(),
                    }
                } else {
                    bytes
                };
                (status, ct, bytes)
            })
            .await
        });
        let what = || {
            format!(
                "{method} {uri} {headers:?} {}",
                String::from_utf8_lossy(&body[..body.len().min(400)])
            )
        };
        match outcome {
            Err(e) => failures.push(format!("panic ({e}): {}", what())),
            Ok((status, ct, resp)) => {
                *statuses.entry(status).or_insert(0usize) += 1;
                // A HEAD answer has no body to check.
                let problem = status < 400
                    || (method == "HEAD" && ct == "application/problem+json")
                    || (ct == "application/problem+json"
                        && serde_json::from_slice::<serde_json::Value>(&resp)
                            .is_ok_and(|v| v["status"].as_u64() == Some(status as u64)));
                if status >= 500 || !problem {
                    failures.push(format!(
                        "{status} {ct}: {} ← {}",
                        String::from_utf8_lossy(&resp[..resp.len().min(300)]),
                        what()
                    ));
                }
            }
        }
        if failures.len() >= 20 {
            break;
        }
    }
    let rss = rss_kb();
    eprintln!(
        "http_surface_fuzz: {n} requests (seed {seed}) in {:.1} s; statuses {statuses:?}; RSS {} MB at a tenth, {} MB at the end; frames computed {}",
        start.elapsed().as_secs_f64(),
        rss_at_tenth / 1024,
        rss / 1024,
        state.metrics().computations("frame"),
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // Bounded memory: the caches have budgets (256 MiB products, the response cache); what
    // grows past the first tenth of the run beyond them is a leak.
    assert!(
        rss < rss_at_tenth + 768 * 1024,
        "resident memory grew from {rss_at_tenth} kB to {rss} kB"
    );
}

/// The resident set of this process, kB (Linux; 0 elsewhere).
fn rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .unwrap_or(0)
}

/// The request generator of [`http_surface_fuzz`].
mod fuzz {
    use rand::seq::IndexedRandom;
    use rand::Rng;
    use serde_json::{json, Value};

    const ROUTES: &[&str] = &[
        "/v1/sun",
        "/v1/sky",
        "/v1/ground",
        "/v1/aerial",
        "/v1/plan",
        "/v1/render",
        "/v1/scenes",
        "/v1/scenes/cumulus-frame",
        "/v1/scenes/../../etc/passwd",
        "/v1/jobs",
        "/v1/jobs/00000000000000ff",
        "/v1/jobs/00000000000000ff/artifacts/0",
        "/v1/atmospheres",
        "/",
        "/assets/viewer.js",
        "/assets/..%2f..%2fCargo.toml",
        "/healthz",
        "/metrics",
        "/openapi.json",
        "/v2/sun",
        "//v1//sun",
    ];
    const METHODS: &[&str] = &[
        "GET", "GET", "GET", "POST", "POST", "DELETE", "PUT", "HEAD", "OPTIONS", "PATCH",
    ];
    /// Settings that keep a valid product request cheap (appended to most queries).
    const CHEAP: &str =
        "method=fast&quality=draft&wavelengths=550&elevation_count=3&azimuth_count=2&distance_count=2";

    fn odd_number(rng: &mut impl Rng) -> String {
        match rng.random_range(0..10) {
            0 => "NaN".into(),
            1 => "-inf".into(),
            2 => "1e308".into(),
            3 => "-0".into(),
            4 => format!("{}", rng.random_range(-1e6..1e6)),
            5 => format!("{}", rng.random_range(-1i64 << 40..1i64 << 40)),
            // Few distinct in-range values: valid requests repeat and hit the cache.
            _ => ["0", "10", "45", "90", "1000", "0.3"]
                .choose(rng)
                .unwrap()
                .to_string(),
        }
    }

    fn garbage(rng: &mut impl Rng, max: usize) -> String {
        let len = rng.random_range(0..=max);
        (0..len)
            .map(|_| match rng.random_range(0..8) {
                0 => char::from_u32(rng.random_range(0x80..0x2fff)).unwrap_or('x'),
                1 => ['%', '&', '=', '?', '/', '\\', '"', '{', '}', ';', ',', '\0']
                    [rng.random_range(0..12)],
                _ => rng.random_range(b' '..=b'~') as char,
            })
            .collect()
    }

    fn query(rng: &mut impl Rng) -> String {
        let names: Vec<&str> = skybake_product::params::PARAMETERS
            .iter()
            .map(|p| p.name)
            .collect();
        let mut pairs: Vec<(String, String)> = Vec::new();
        for _ in 0..rng.random_range(0..5) {
            let name = match rng.random_range(0..10) {
                0 => garbage(rng, 8),
                1 => "offset".into(),
                2 => "limit".into(),
                _ => names.choose(rng).unwrap().to_string(),
            };
            let value = match rng.random_range(0..6) {
                0 => garbage(rng, 16),
                1 => [
                    "earth",
                    "venus",
                    "fast",
                    "precise",
                    "none",
                    "draft",
                    "reference",
                    "exr",
                    "png",
                    "png_latlong",
                    "json",
                    "550",
                    "440,550,680",
                    "120:0,180:45",
                    "2026-06-21T12:00:00Z",
                    "{",
                    "[]",
                ]
                .choose(rng)
                .unwrap()
                .to_string(),
                _ => odd_number(rng),
            };
            pairs.push((name, value));
        }
        let mut q: String = form_urlencoded::Serializer::new(String::new())
            .extend_pairs(pairs)
            .finish();
        match rng.random_range(0..10) {
            0 => q = garbage(rng, 40).replace(['#', ' '], ""),
            1 => {}
            _ => {
                q.push('&');
                q.push_str(CHEAP);
            }
        }
        q
    }

    fn path(rng: &mut impl Rng) -> String {
        let mut p = ROUTES.choose(rng).unwrap().to_string();
        match rng.random_range(0..10) {
            0 => p.push_str(&format!(
                "/{}",
                garbage(rng, 12).replace(['#', '?', ' '], "")
            )),
            1 => {
                p = p.replace(
                    "00000000000000ff",
                    &garbage(rng, 20).replace(['#', '?', ' ', '/'], ""),
                )
            }
            2 => p = p.replace("/0", &format!("/{}", odd_number(rng))),
            3 => p.push_str(&"a".repeat(rng.random_range(1..5000))),
            _ => {}
        }
        p
    }

    fn random_json(rng: &mut impl Rng, depth: u32) -> Value {
        match rng.random_range(0..if depth == 0 { 5 } else { 8 }) {
            0 => Value::Null,
            1 => json!(rng.random_bool(0.5)),
            2 => json!(odd_number(rng)
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .unwrap_or(1e300)),
            3 => json!(garbage(rng, 10)),
            4 => json!(rng.random_range(-3i64..1 << 20)),
            5 | 6 => Value::Object(
                (0..rng.random_range(0..4))
                    .map(|_| {
                        (
                            [
                                "product", "scene", "method", "items", "products", "grids", "x",
                                "type", "source",
                            ]
                            .choose(rng)
                            .unwrap()
                            .to_string(),
                            random_json(rng, depth - 1),
                        )
                    })
                    .collect(),
            ),
            _ => Value::Array(
                (0..rng.random_range(0..4))
                    .map(|_| random_json(rng, depth - 1))
                    .collect(),
            ),
        }
    }

    /// `v` with one to three of its members (at any depth) replaced, removed or emptied.
    fn mutate(rng: &mut impl Rng, v: &mut Value) {
        crate::service_support::json_mutation::mutate(rng, v, 1..=3, 0.7, |rng| {
            random_json(rng, 2)
        });
    }

    fn job(rng: &mut impl Rng, scenes: &[Value]) -> Value {
        let kind = *["sun", "sky", "ground", "aerial"].choose(rng).unwrap();
        let product = json!({"product": kind, "method": "fast", "quality": "draft", "wavelengths": "550", "sun_elevation_deg": odd_number(rng)});
        match rng.random_range(0..4) {
            0 => json!({"products": [product]}),
            1 => json!({"products": [{"product": "frame", "scene": scenes.choose(rng).unwrap()}]}),
            2 => {
                json!({"grids": [{"product": "sky", "method": "fast", "quality": "draft", "wavelengths": "550", "sweep": {"sun_elevation_deg": {"from": 0, "to": odd_number(rng), "step": odd_number(rng)}}}]})
            }
            _ => json!({"frames": [[{"scene": scenes.choose(rng).unwrap()}]], "products": []}),
        }
    }

    /// One generated request: method, path and query, headers, body.
    pub fn request(
        rng: &mut impl Rng,
        scenes: &[Value],
    ) -> (String, String, Vec<(String, String)>, Vec<u8>) {
        let method = METHODS.choose(rng).unwrap().to_string();
        let p = path(rng);
        let uri = if rng.random_bool(0.8) {
            format!("{p}?{}", query(rng))
        } else {
            p.clone()
        };
        let mut headers = vec![("content-type".to_string(), "application/json".to_string())];
        for _ in 0..rng.random_range(0..3) {
            let (k, v) = match rng.random_range(0..9) {
                0 => (
                    "accept",
                    [
                        "image/png",
                        "image/x-exr",
                        "application/json",
                        "*/*",
                        "text/html;q=0.1",
                        garbage(rng, 20).as_str(),
                    ]
                    .choose(rng)
                    .unwrap()
                    .to_string(),
                ),
                1 => (
                    "if-none-match",
                    ["*", "\"x\"", "W/\"y\"", ""]
                        .choose(rng)
                        .unwrap()
                        .to_string(),
                ),
                2 => ("authorization", format!("Bearer {}", garbage(rng, 10))),
                3 => (
                    "content-type",
                    [
                        "text/plain",
                        "application/json; charset=utf-8",
                        "multipart/form-data",
                        "",
                    ]
                    .choose(rng)
                    .unwrap()
                    .to_string(),
                ),
                4 => ("range", "bytes=0-10".into()),
                5 => ("expect", "100-continue".into()),
                6 => ("x-forwarded-for", garbage(rng, 15)),
                7 => ("accept-encoding", "gzip".into()),
                _ => (
                    ["x-fuzz", "cookie", "origin"]
                        .choose(rng)
                        .unwrap()
                        .to_owned(),
                    garbage(rng, 30),
                ),
            };
            headers.push((
                k.to_string(),
                v.chars()
                    .filter(|c| c.is_ascii() && !c.is_ascii_control())
                    .collect(),
            ));
        }
        let body = if method == "POST" || rng.random_bool(0.05) {
            let value = match rng.random_range(0..10) {
                0 => return (method, uri, headers, garbage(rng, 64).into_bytes()),
                1 => random_json(rng, 3),
                2..=4 => {
                    let mut scene = scenes.choose(rng).unwrap().clone();
                    if rng.random_bool(0.9) {
                        mutate(rng, &mut scene);
                    }
                    if p.starts_with("/v1/plan") {
                        json!({"product": "frame", "scene": scene})
                    } else {
                        scene
                    }
                }
                5 | 6 => {
                    let mut j = job(rng, scenes);
                    if rng.random_bool(0.8) {
                        mutate(rng, &mut j);
                    }
                    j
                }
                _ => {
                    let kind = *["sun", "sky", "ground", "aerial", "frame", "x"]
                        .choose(rng)
                        .unwrap();
                    let mut v = json!({"product": kind, "method": "fast", "quality": "draft", "wavelengths": "550"});
                    mutate(rng, &mut v);
                    v
                }
            };
            value.to_string().into_bytes()
        } else {
            Vec::new()
        };
        (method, uri, headers, body)
    }
}
