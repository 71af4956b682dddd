//! Service metrics in the Prometheus text exposition format (version 0.0.4): request counts and
//! latency histograms per route, computations per product, single-flight joins, load shedding and
//! timeouts. Cache, job and engine gauges are read from their owners when `/metrics` is rendered.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Duration;

/// Upper bounds of the latency histogram buckets, seconds.
pub const LATENCY_BUCKETS_S: [f64; 14] = [
    0.0005, 0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0, 60.0,
];

#[derive(Default, Clone)]
struct Histogram {
    buckets: [u64; LATENCY_BUCKETS_S.len()],
    count: u64,
    sum_s: f64,
}

/// Counters owned by the service.
#[derive(Default)]
pub struct Metrics {
    /// (route, method, status) → count.
    requests: Mutex<BTreeMap<(String, String, u16), u64>>,
    /// route → latency histogram.
    latency: Mutex<BTreeMap<String, Histogram>>,
    /// product → engine computations started.
    computations: Mutex<BTreeMap<&'static str, u64>>,
    pub single_flight_joins: AtomicU64,
    /// Polls while another replica held the lease on a product being computed.
    pub lease_waits: AtomicU64,
    pub load_shed: AtomicU64,
    pub timeouts: AtomicU64,
    pub response_cache_hits: AtomicU64,
    pub compute_in_flight: AtomicU64,
    /// Client connections open now.
    pub connections_open: AtomicU64,
    /// Connections closed at accept because `server.max_connections` were open.
    pub connections_refused: AtomicU64,
    /// Frame tiles rendered (tiles taken from an earlier, interrupted run are not counted).
    pub frame_tiles_computed: AtomicU64,
    /// Frame renders stopped because no request waited for them any more.
    pub frames_abandoned: AtomicU64,
    /// Computations cancelled because every client waiting for them had gone.
    pub cancelled: AtomicU64,
    /// New computations shed because `server.max_queued_computations` were waiting.
    pub queue_shed: AtomicU64,
    /// Requests refused with 429 by the per-client rate limit.
    pub rate_limited: AtomicU64,
    /// Requests refused with 401 (missing or unknown bearer token).
    pub unauthorized: AtomicU64,
    /// Connections closed at accept because their client address had
    /// `server.max_connections_per_client` open.
    pub client_connections_refused: AtomicU64,
    /// Requests answered 408 because their body arrived too slowly
    /// (`server.body_read_timeout_s`, `server.body_min_rate_bytes_per_s`).
    pub body_timeouts: AtomicU64,
}

impl Metrics {
    /// Records one finished request.
    pub fn observe(&self, route: &str, method: &str, status: u16, elapsed: Duration) {
        if let Ok(mut m) = self.requests.lock() {
            *m.entry((route.to_string(), method.to_string(), status))
                .or_default() += 1;
        }
        let s = elapsed.as_secs_f64();
        if let Ok(mut m) = self.latency.lock() {
            let h = m.entry(route.to_string()).or_default();
            for (b, &le) in h.buckets.iter_mut().zip(&LATENCY_BUCKETS_S) {
                if s <= le {
                    *b += 1;
                }
            }
            h.count += 1;
            h.sum_s += s;
        }
    }

    /// Counts one engine computation of `product`.
    pub fn computed(&self, product: &'static str) {
        if let Ok(mut m) = self.computations.lock() {
            *m.entry(product).or_default() += 1;
        }
    }

    /// Engine computations of `product` so far.
    pub fn computations(&self, product: &str) -> u64 {
        self.computations
            .lock()
            .map(|m| m.get(product).copied().unwrap_or(0))
            .unwrap_or(0)
    }

    /// Requests counted for `route` with `status`.
    pub fn requests(&self, route: &str, status: u16) -> u64 {
        self.requests
            .lock()
            .map(|m| {
                m.iter()
                    .filter(|((r, _, s), _)| r == route && *s == status)
                    .map(|(_, n)| n)
                    .sum()
            })
            .unwrap_or(0)
    }

    /// Writes the service's own series.
    pub fn render(&self, out: &mut String) {
        out.push_str("# HELP skybake_http_requests_total HTTP requests by route, method and status.\n# TYPE skybake_http_requests_total counter\n");
        if let Ok(m) = self.requests.lock() {
            for ((route, method, status), n) in m.iter() {
                let _ = writeln!(
                    out,
                    "skybake_http_requests_total{{route=\"{}\",method=\"{}\",status=\"{status}\"}} {n}",
                    escape(route),
                    escape(method)
                );
            }
        }
        out.push_str("# HELP skybake_http_request_duration_seconds Request latency by route.\n# TYPE skybake_http_request_duration_seconds histogram\n");
        if let Ok(m) = self.latency.lock() {
            for (route, h) in m.iter() {
                let r = escape(route);
                for (le, n) in LATENCY_BUCKETS_S.iter().zip(&h.buckets) {
                    let _ = writeln!(
                        out,
                        "skybake_http_request_duration_seconds_bucket{{route=\"{r}\",le=\"{le}\"}} {n}"
                    );
                }
                let _ = writeln!(
                    out,
                    "skybake_http_request_duration_seconds_bucket{{route=\"{r}\",le=\"+Inf\"}} {}",
                    h.count
                );
                let _ = writeln!(
                    out,
                    "skybake_http_request_duration_seconds_sum{{route=\"{r}\"}} {}",
                    h.sum_s
                );
                let _ = writeln!(
                    out,
                    "skybake_http_request_duration_seconds_count{{route=\"{r}\"}} {}",
                    h.count
                );
            }
        }
        out.push_str("# HELP skybake_computations_total Engine computations by product (cache misses that ran).\n# TYPE skybake_computations_total counter\n");
        if let Ok(m) = self.computations.lock() {
            for (p, n) in m.iter() {
                let _ = writeln!(out, "skybake_computations_total{{product=\"{p}\"}} {n}");
            }
        }
        counter(
            out,
            "skybake_single_flight_joins_total",
            "Requests that waited for an identical computation already in flight.",
            self.single_flight_joins.load(Ordering::Relaxed),
        );
        counter(
            out,
            "skybake_load_shed_total",
            "Requests refused with 503 because the concurrency limit was reached.",
            self.load_shed.load(Ordering::Relaxed),
        );
        counter(
            out,
            "skybake_request_timeouts_total",
            "Requests that exceeded the request timeout.",
            self.timeouts.load(Ordering::Relaxed),
        );
        counter(
            out,
            "skybake_response_cache_hits_total",
            "Responses served from the rendered-response memory cache.",
            self.response_cache_hits.load(Ordering::Relaxed),
        );
        gauge(
            out,
            "skybake_computations_in_flight",
            "Engine computations running now.",
            self.compute_in_flight.load(Ordering::Relaxed),
        );
        gauge(
            out,
            "skybake_connections_open",
            "Client connections open now.",
            self.connections_open.load(Ordering::Relaxed),
        );
        counter(
            out,
            "skybake_connections_refused_total",
            "Connections closed at accept because the connection cap was reached.",
            self.connections_refused.load(Ordering::Relaxed),
        );
        counter(
            out,
            "skybake_frame_tiles_computed_total",
            "Frame tiles rendered (tiles resumed from an interrupted render not counted).",
            self.frame_tiles_computed.load(Ordering::Relaxed),
        );
        counter(
            out,
            "skybake_frames_abandoned_total",
            "Frame renders stopped at a tile because no request waited for them.",
            self.frames_abandoned.load(Ordering::Relaxed),
        );
        for (name, help, v) in [
            (
                "skybake_computations_cancelled_total",
                "Computations cancelled because every client waiting for them had gone.",
                &self.cancelled,
            ),
            (
                "skybake_computations_queue_shed_total",
                "New computations shed with 503 because the compute queue was full.",
                &self.queue_shed,
            ),
            (
                "skybake_rate_limited_total",
                "Requests refused with 429 by the per-client rate limit.",
                &self.rate_limited,
            ),
            (
                "skybake_unauthorized_total",
                "Requests refused with 401 (missing or unknown bearer token).",
                &self.unauthorized,
            ),
            (
                "skybake_client_connections_refused_total",
                "Connections closed at accept because their client address had the per-client connection cap open.",
                &self.client_connections_refused,
            ),
            (
                "skybake_body_timeouts_total",
                "Requests answered 408 because their body arrived too slowly.",
                &self.body_timeouts,
            ),
        ] {
            counter(out, name, help, v.load(Ordering::Relaxed));
        }
    }
}

/// Writes one counter with its HELP and TYPE lines.
pub fn counter(out: &mut String, name: &str, help: &str, value: u64) {
    let _ = writeln!(
        out,
        "# HELP {name} {help}\n# TYPE {name} counter\n{name} {value}"
    );
}

/// Writes one gauge with its HELP and TYPE lines.
pub fn gauge(out: &mut String, name: &str, help: &str, value: u64) {
    let _ = writeln!(
        out,
        "# HELP {name} {help}\n# TYPE {name} gauge\n{name} {value}"
    );
}

/// Escapes a label value (backslash, quote, newline).
fn escape(s: &str) -> String {
    s.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative() {
        let m = Metrics::default();
        m.observe("/v1/sky", "GET", 200, Duration::from_micros(300));
        m.observe("/v1/sky", "GET", 200, Duration::from_millis(30));
        let mut out = String::new();
        m.render(&mut out);
        assert!(out.contains(
            "skybake_http_request_duration_seconds_bucket{route=\"/v1/sky\",le=\"0.0005\"} 1"
        ));
        assert!(out.contains(
            "skybake_http_request_duration_seconds_bucket{route=\"/v1/sky\",le=\"0.05\"} 2"
        ));
        assert!(out.contains(
            "skybake_http_requests_total{route=\"/v1/sky\",method=\"GET\",status=\"200\"} 2"
        ));
        assert_eq!(m.requests("/v1/sky", 200), 2);
    }
}
