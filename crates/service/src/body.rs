//! Request bodies are read whole, with a deadline and a minimum rate, before the request takes
//! a concurrency slot, so a slow upload never holds a slot that other requests (cached reads)
//! need.
//!
//! - A declared `Content-Length` over `server.body_limit_bytes` is refused with 413 before a byte
//!   is read (so a client sending `Expect: 100-continue` gets the 413, never `100 Continue`:
//!   hyper sends that only when the body is first read).
//! - The body must arrive within `server.body_read_timeout_s`, and after its first
//!   [`BODY_RATE_GRACE_S`] seconds at an average of at least `server.body_min_rate_bytes_per_s`
//!   (the rule of ASP.NET Core Kestrel's `MinRequestBodyDataRate`); otherwise 408 problem+json
//!   and the connection is closed (RFC 9110 §15.5.9).
//!
//! The memory a request body can take is thus at most `server.body_limit_bytes`, and all bodies
//! being read at most that times the open connections (`server.max_connections`).

use super::problem::ApiError;
use super::AppState;
use axum::body::{Body, HttpBody};
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use skybake_product::config::BODY_RATE_GRACE_S;
use std::sync::atomic::Ordering;
use std::time::Duration;
use tokio::time::Instant;

/// How often a stalled body's rate is checked.
const RATE_CHECK: Duration = Duration::from_millis(250);

/// Why a body could not be read.
#[derive(Debug)]
pub enum BodyError {
    /// Over the limit (declared or as it arrived).
    TooLarge { limit: usize, declared: Option<u64> },
    /// Not complete within the timeout, seconds.
    Timeout { timeout_s: f64, received: usize },
    /// Below the minimum average rate after the grace period.
    TooSlow {
        min_rate: f64,
        received: usize,
        elapsed_s: f64,
    },
    /// The connection failed or the framing was invalid.
    Broken(String),
}

impl From<BodyError> for ApiError {
    fn from(e: BodyError) -> Self {
        match e {
            BodyError::TooLarge { limit, declared } => ApiError::Body {
                status: StatusCode::PAYLOAD_TOO_LARGE,
                detail: match declared {
                    Some(n) => format!("the body is {n} bytes (content-length), larger than server.body_limit_bytes (limit {limit} bytes)"),
                    None => format!("the body is larger than server.body_limit_bytes (limit {limit} bytes)"),
                },
            },
            BodyError::Timeout { timeout_s, received } => ApiError::SlowBody(format!(
                "the body was not complete within server.body_read_timeout_s ({timeout_s} s; {received} bytes received)"
            )),
            BodyError::TooSlow { min_rate, received, elapsed_s } => ApiError::SlowBody(format!(
                "the body arrived at {:.0} bytes/s ({received} bytes in {elapsed_s:.1} s), below server.body_min_rate_bytes_per_s ({min_rate} bytes/s after the first {BODY_RATE_GRACE_S} s)",
                received as f64 / elapsed_s.max(1e-9)
            )),
            BodyError::Broken(why) => ApiError::Body {
                status: StatusCode::BAD_REQUEST,
                detail: format!("reading the body failed: {why}"),
            },
        }
    }
}

/// The limits a body is read under.
#[derive(Debug, Clone, Copy)]
pub struct BodyLimits {
    pub max_bytes: usize,
    pub timeout: Duration,
    /// Bytes per second; 0 = no minimum.
    pub min_rate: f64,
    pub grace: Duration,
}

/// Reads `body` whole under `limits`; `declared` is its `Content-Length`, if any.
pub async fn read_limited(
    mut body: Body,
    declared: Option<u64>,
    limits: BodyLimits,
) -> Result<Vec<u8>, BodyError> {
    if let Some(n) = declared.filter(|&n| n > limits.max_bytes as u64) {
        return Err(BodyError::TooLarge {
            limit: limits.max_bytes,
            declared: Some(n),
        });
    }
    let start = Instant::now();
    let deadline = start + limits.timeout;
    let mut buf = Vec::with_capacity(declared.unwrap_or(0) as usize);
    loop {
        let wake = if limits.min_rate > 0.0 {
            deadline.min((start + limits.grace).max(Instant::now() + RATE_CHECK))
        } else {
            deadline
        };
        let next = tokio::time::timeout_at(
            wake,
            std::future::poll_fn(|cx| std::pin::Pin::new(&mut body).poll_frame(cx)),
        )
        .await;
        match next {
            Ok(None) => return Ok(buf),
            Ok(Some(Err(e))) => return Err(BodyError::Broken(e.to_string())),
            Ok(Some(Ok(frame))) => {
                if let Ok(data) = frame.into_data() {
                    if buf.len() + data.len() > limits.max_bytes {
                        return Err(BodyError::TooLarge {
                            limit: limits.max_bytes,
                            declared: None,
                        });
                    }
                    buf.extend_from_slice(&data);
                }
            }
            Err(_) => {}
        }
        let now = Instant::now();
        if now >= deadline {
            return Err(BodyError::Timeout {
                timeout_s: limits.timeout.as_secs_f64(),
                received: buf.len(),
            });
        }
        let elapsed = now - start;
        if limits.min_rate > 0.0
            && elapsed > limits.grace
            && (buf.len() as f64) < limits.min_rate * elapsed.as_secs_f64()
        {
            return Err(BodyError::TooSlow {
                min_rate: limits.min_rate,
                received: buf.len(),
                elapsed_s: elapsed.as_secs_f64(),
            });
        }
    }
}

/// The middleware: buffers the body of every request that has one (see the module
/// documentation); requests without a body pass as they are.
pub async fn buffer_body(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let (parts, body) = req.into_parts();
    if body.is_end_stream() {
        return next.run(Request::from_parts(parts, body)).await;
    }
    let s = &state.settings().server;
    let limits = BodyLimits {
        max_bytes: s.body_limit_bytes,
        timeout: Duration::from_secs_f64(s.body_read_timeout_s),
        min_rate: s.body_min_rate_bytes_per_s,
        grace: Duration::from_secs_f64(BODY_RATE_GRACE_S),
    };
    let declared = parts
        .headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    match read_limited(body, declared, limits).await {
        Ok(bytes) => {
            next.run(Request::from_parts(parts, Body::from(bytes)))
                .await
        }
        Err(e) => {
            if matches!(e, BodyError::Timeout { .. } | BodyError::TooSlow { .. }) {
                state
                    .metrics()
                    .body_timeouts
                    .fetch_add(1, Ordering::Relaxed);
            }
            let mut resp = ApiError::from(e).into_response();
            // The rest of the body is not read: the connection cannot carry another request.
            resp.headers_mut()
                .insert(header::CONNECTION, HeaderValue::from_static("close"));
            resp
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytes::Bytes;
    use std::future::Future;

    fn limits(min_rate: f64) -> BodyLimits {
        BodyLimits {
            max_bytes: 1000,
            timeout: Duration::from_millis(500),
            min_rate,
            grace: Duration::from_millis(200),
        }
    }

    /// A body of `chunks` bytes, one every `every`, then its end (or a stall when `end` is false).
    struct Trickle {
        left: usize,
        every: Duration,
        end: bool,
        sleep: std::pin::Pin<Box<tokio::time::Sleep>>,
    }

    impl HttpBody for Trickle {
        type Data = Bytes;
        type Error = std::convert::Infallible;

        fn poll_frame(
            mut self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
        ) -> std::task::Poll<Option<Result<hyper::body::Frame<Bytes>, Self::Error>>> {
            use std::task::Poll;
            if self.left == 0 {
                return if self.end {
                    Poll::Ready(None)
                } else {
                    Poll::Pending
                };
            }
            if !self.every.is_zero() {
                std::task::ready!(self.sleep.as_mut().poll(cx));
                let next = Instant::now() + self.every;
                self.sleep.as_mut().reset(next);
            }
            self.left -= 1;
            Poll::Ready(Some(Ok(hyper::body::Frame::data(Bytes::from_static(b"x")))))
        }
    }

    fn trickle(chunks: usize, every: Duration, end: bool) -> Body {
        Body::new(Trickle {
            left: chunks,
            every,
            end,
            sleep: Box::pin(tokio::time::sleep(every)),
        })
    }

    #[tokio::test]
    async fn a_trickling_body_is_refused_after_the_grace_period() {
        // A byte every 20 ms (50 B/s), 500 declared: below 1024 B/s once the 0.2 s grace is over.
        let started = Instant::now();
        let r = read_limited(
            trickle(500, Duration::from_millis(20), true),
            Some(500),
            limits(1024.0),
        )
        .await;
        assert!(matches!(r, Err(BodyError::TooSlow { .. })), "{r:?}");
        let waited = started.elapsed();
        assert!(
            waited >= Duration::from_millis(200) && waited < Duration::from_secs(3),
            "{waited:?}"
        );
        // Without a minimum rate, the total timeout (0.5 s) ends it.
        let r = read_limited(
            trickle(500, Duration::from_millis(20), true),
            Some(500),
            limits(0.0),
        )
        .await;
        assert!(
            matches!(r, Err(BodyError::Timeout { received, .. }) if received > 5 && received < 500),
            "{r:?}"
        );
    }

    #[tokio::test]
    async fn complete_and_oversized_bodies() {
        let r = read_limited(
            trickle(3, Duration::from_millis(10), true),
            None,
            limits(1024.0),
        )
        .await;
        assert_eq!(r.unwrap(), b"xxx");
        // A declared length over the limit is refused before anything is read.
        let r = read_limited(
            trickle(0, Duration::ZERO, false),
            Some(99_999_999),
            limits(0.0),
        )
        .await;
        assert!(matches!(
            r,
            Err(BodyError::TooLarge {
                declared: Some(99_999_999),
                ..
            })
        ));
        // An undeclared one as soon as it passes the limit.
        let r = read_limited(trickle(1001, Duration::ZERO, true), None, limits(0.0)).await;
        assert!(matches!(r, Err(BodyError::TooLarge { declared: None, .. })));
    }
}
