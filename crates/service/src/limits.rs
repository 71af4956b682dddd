//! Access limits applied as middleware where the router is built: optional
//! bearer-token authentication (`server.api_tokens`, off when empty; `server.auth_exempt` paths,
//! exact or a prefix ending in `*`, answered without a token; failed attempts count against the
//! client's rate limit on every route) and a per-client rate limit on `/v1/*` (`server.rate_limit_per_s`,
//! a token bucket per client address of `server.rate_limit_burst` requests; 429 + `Retry-After`).

use super::problem::ApiError;
use super::AppState;
use axum::extract::{ConnectInfo, Request, State};
use axum::http::header;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::Ordering;
use std::sync::Mutex;
use std::time::Instant;

/// Most client addresses tracked; beyond it the buckets that are full again are forgotten (a full
/// bucket is what an unknown client starts with, so forgetting it changes nothing).
const MAX_CLIENTS: usize = 100_000;

/// Token buckets per client address.
#[derive(Default)]
pub struct RateLimiter {
    buckets: Mutex<HashMap<IpAddr, (f64, Instant)>>,
}

impl RateLimiter {
    /// Takes one request from `client`'s bucket (`burst` deep, refilled at `per_s`); `Err` with the
    /// seconds until the next request is allowed.
    pub fn take(&self, client: IpAddr, per_s: f64, burst: u32, now: Instant) -> Result<(), u64> {
        let burst = f64::from(burst);
        let mut buckets = self.buckets.lock().unwrap_or_else(|e| e.into_inner());
        if buckets.len() >= MAX_CLIENTS && !buckets.contains_key(&client) {
            buckets.retain(|_, (tokens, at)| {
                *tokens + now.saturating_duration_since(*at).as_secs_f64() * per_s < burst
            });
        }
        let (tokens, at) = buckets.entry(client).or_insert((burst, now));
        *tokens = (*tokens + now.saturating_duration_since(*at).as_secs_f64() * per_s).min(burst);
        *at = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            Ok(())
        } else {
            Err(((1.0 - *tokens) / per_s).ceil().max(1.0) as u64)
        }
    }
}

/// The client address of a request (the peer the accept loop recorded; loopback when there is
/// none, as in `oneshot` tests).
fn client(req: &Request) -> IpAddr {
    req.extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map(|c| c.0.ip())
        .unwrap_or(IpAddr::V4(Ipv4Addr::LOCALHOST))
}

/// Compares in time independent of where the first difference is.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Bearer-token authentication, when `server.api_tokens` is set.
pub async fn authenticate(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let settings = state.settings();
    let tokens = settings.api_tokens();
    let path = req.uri().path();
    let exempt = settings
        .auth_exempt()
        .iter()
        .any(|e| match e.strip_suffix('*') {
            Some(prefix) => path.starts_with(prefix),
            None => path == *e,
        });
    if tokens.is_empty() || exempt {
        return next.run(req).await;
    }
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(bearer_token);
    let known = given.is_some_and(|g| {
        tokens
            .iter()
            .fold(false, |ok, t| ok | same(g.as_bytes(), t.as_bytes()))
    });
    if known {
        return next.run(req).await;
    }
    // Failed attempts take from the client's rate-limit bucket: a flood of them gets 429.
    let s = &settings.server;
    if s.rate_limit_per_s > 0.0 {
        let taken = state.rate_limiter().take(
            client(&req),
            s.rate_limit_per_s,
            s.rate_limit_burst,
            Instant::now(),
        );
        if let Err(retry_after_s) = taken {
            state.metrics().rate_limited.fetch_add(1, Ordering::Relaxed);
            return ApiError::RateLimited { retry_after_s }.into_response();
        }
    }
    state.metrics().unauthorized.fetch_add(1, Ordering::Relaxed);
    ApiError::Unauthorized.into_response()
}

/// The token of an `Authorization: Bearer <token>` value; the scheme is case-insensitive
/// (RFC 9110 §11.1).
fn bearer_token(value: &str) -> Option<&str> {
    let (scheme, token) = value.trim_start().split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then_some(token.trim())
}

/// The per-client rate limit, when `server.rate_limit_per_s` is above 0.
pub async fn rate_limit(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let s = &state.settings().server;
    if s.rate_limit_per_s <= 0.0 {
        return next.run(req).await;
    }
    let taken = state.rate_limiter().take(
        client(&req),
        s.rate_limit_per_s,
        s.rate_limit_burst,
        Instant::now(),
    );
    match taken {
        Ok(()) => next.run(req).await,
        Err(retry_after_s) => {
            state.metrics().rate_limited.fetch_add(1, Ordering::Relaxed);
            ApiError::RateLimited { retry_after_s }.into_response()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn bucket_allows_the_burst_then_the_rate() {
        let r = RateLimiter::default();
        let a = IpAddr::V4(Ipv4Addr::new(10, 0, 0, 1));
        let b = IpAddr::V4(Ipv4Addr::new(10, 0, 0, 2));
        let t0 = Instant::now();
        for _ in 0..3 {
            assert_eq!(r.take(a, 2.0, 3, t0), Ok(()));
        }
        assert_eq!(r.take(a, 2.0, 3, t0), Err(1));
        // Another client has its own bucket.
        assert_eq!(r.take(b, 2.0, 3, t0), Ok(()));
        // Half a second at 2/s refills one request.
        assert_eq!(r.take(a, 2.0, 3, t0 + Duration::from_millis(500)), Ok(()));
        assert!(r.take(a, 2.0, 3, t0 + Duration::from_millis(500)).is_err());
        assert!(same(b"token", b"token") && !same(b"token", b"tokem") && !same(b"a", b"ab"));
    }

    #[test]
    fn the_bearer_scheme_is_case_insensitive() {
        for v in ["Bearer abc", "bearer abc", "BEARER  abc ", "bEaReR abc"] {
            assert_eq!(bearer_token(v), Some("abc"), "{v}");
        }
        for v in ["Basic abc", "Bearerabc", "Bearer", "Token abc"] {
            assert_eq!(bearer_token(v), None, "{v}");
        }
    }
}
