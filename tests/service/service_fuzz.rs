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
