//! HTTP errors as `application/problem+json` (RFC 9457): `type`, `title`, `status`, `detail`, and a
//! `parameter` member naming the offending request parameter when there is one. Bad input is always
//! 4xx; 500 is kept for real server faults (disk I/O), 503 for overload and timeouts.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

/// An error the service answers with.
#[derive(Debug, Clone)]
pub enum ApiError {
    /// A request parameter is wrong (from the engine's validation).
    Param(crate::Error),
    /// Query parameters that no route knows.
    UnknownParameters(Vec<String>),
    /// The request body is not what the route expects.
    Body { status: StatusCode, detail: String },
    /// No such resource (job, artifact).
    NotFound(String),
    /// Too many requests in flight: shed.
    Overloaded,
    /// The request ran longer than the request timeout.
    Timeout,
    /// The service is shutting down or a worker vanished.
    Unavailable(String),
    /// A server-side fault (disk I/O, corrupted state); the detail is logged and reported.
    Internal(String),
    /// The route exists but not with this method (the allowed ones are listed).
    MethodNotAllowed(String),
    /// A bearer token is required (`server.api_tokens`) and missing or unknown.
    Unauthorized,
    /// The client exceeded `server.rate_limit_per_s`; retry after this many seconds.
    RateLimited { retry_after_s: u64 },
    /// Too many live jobs (`jobs.max_live`).
    JobsFull(String),
    /// The request body did not arrive in time or arrived too slowly (408; the connection is
    /// closed).
    SlowBody(String),
    /// The shared bucket did not answer after the retries; retry after this many seconds.
    StorageUnavailable { detail: String, retry_after_s: u64 },
}

impl From<crate::Error> for ApiError {
    fn from(e: crate::Error) -> Self {
        if e == crate::Error::Cancelled {
            ApiError::Unavailable(e.to_string())
        } else if e.is_input() {
            ApiError::Param(e)
        } else {
            ApiError::Internal(e.to_string())
        }
    }
}

impl From<skybake_product::params::PairsError> for ApiError {
    fn from(e: skybake_product::params::PairsError) -> Self {
        match e {
            skybake_product::params::PairsError::Unknown(names) => {
                ApiError::UnknownParameters(names)
            }
            skybake_product::params::PairsError::Param(e) => e.into(),
        }
    }
}

impl From<skybake_job::JobError> for ApiError {
    fn from(e: skybake_job::JobError) -> Self {
        use skybake_job::JobError;
        match e {
            JobError::Param(e) => e.into(),
            JobError::Unknown(names) => ApiError::UnknownParameters(names),
            JobError::Body(detail) => ApiError::Body {
                status: StatusCode::UNPROCESSABLE_ENTITY,
                detail,
            },
            JobError::NotFound(d) => ApiError::NotFound(d),
            JobError::Failure(d) => ApiError::Internal(d),
            JobError::Full(d) => ApiError::JobsFull(d),
            JobError::Unavailable {
                detail,
                retry_after_s,
            } => ApiError::StorageUnavailable {
                detail,
                retry_after_s,
            },
        }
    }
}

impl From<skybake_store::StoreError> for ApiError {
    fn from(e: skybake_store::StoreError) -> Self {
        match e {
            skybake_store::StoreError::Invalid(e) => e.into(),
            skybake_store::StoreError::Unavailable { retry_after_s, .. } => {
                ApiError::StorageUnavailable {
                    detail: e.to_string(),
                    retry_after_s,
                }
            }
            other => ApiError::Internal(other.to_string()),
        }
    }
}

#[derive(Serialize)]
struct Problem<'a> {
    #[serde(rename = "type")]
    kind: &'a str,
    title: &'a str,
    status: u16,
    detail: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    parameter: Option<String>,
}

impl ApiError {
    /// HTTP status of this error.
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::Param(crate::Error::OutOfRange { .. }) => StatusCode::BAD_REQUEST,
            ApiError::Param(crate::Error::TooLarge { field, .. }) if field == "query" => {
                StatusCode::URI_TOO_LONG
            }
            ApiError::Param(crate::Error::TooLarge { field, .. }) if field == "headers" => {
                StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE
            }
            ApiError::Param(crate::Error::TooLarge { .. }) => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::Param(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::UnknownParameters(_) => StatusCode::BAD_REQUEST,
            ApiError::Body { status, .. } => *status,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::Overloaded | ApiError::Timeout | ApiError::Unavailable(_) => {
                StatusCode::SERVICE_UNAVAILABLE
            }
            ApiError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
            ApiError::MethodNotAllowed(_) => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::Unauthorized => StatusCode::UNAUTHORIZED,
            ApiError::RateLimited { .. } => StatusCode::TOO_MANY_REQUESTS,
            ApiError::JobsFull(_) | ApiError::StorageUnavailable { .. } => {
                StatusCode::SERVICE_UNAVAILABLE
            }
            ApiError::SlowBody(_) => StatusCode::REQUEST_TIMEOUT,
        }
    }

    fn parts(&self) -> (&'static str, &'static str, String, Option<String>) {
        match self {
            ApiError::Param(e) => {
                let (kind, title) = match e {
                    crate::Error::OutOfRange { .. } => {
                        ("urn:skybake:problem:out-of-range", "Parameter out of range")
                    }
                    crate::Error::TooLarge { .. } => {
                        ("urn:skybake:problem:too-large", "Request exceeds a limit")
                    }
                    _ => ("urn:skybake:problem:invalid", "Invalid parameter"),
                };
                (kind, title, e.to_string(), Some(e.field().to_string()))
            }
            ApiError::UnknownParameters(names) => (
                "urn:skybake:problem:unknown-parameter",
                "Unknown parameter",
                format!(
                    "unknown query parameter(s): {}; see /openapi.json for the parameters of each route",
                    names.join(", ")
                ),
                names.first().cloned(),
            ),
            ApiError::Body { detail, .. } => (
                "urn:skybake:problem:bad-body",
                "Invalid request body",
                detail.clone(),
                Some("body".into()),
            ),
            ApiError::NotFound(d) => ("urn:skybake:problem:not-found", "Not found", d.clone(), None),
            ApiError::Overloaded => (
                "urn:skybake:problem:overloaded",
                "Server overloaded",
                "too many requests in flight; retry after the indicated delay".into(),
                None,
            ),
            ApiError::Timeout => (
                "urn:skybake:problem:timeout",
                "Request timed out",
                "the request took longer than the configured request timeout; its computation is cancelled unless another request or a job waits for it (server.finish_abandoned keeps it running): submit long computations as a job (POST /v1/jobs)".into(),
                None,
            ),
            ApiError::Unavailable(d) => (
                "urn:skybake:problem:unavailable",
                "Service unavailable",
                d.clone(),
                None,
            ),
            ApiError::Internal(d) => (
                "urn:skybake:problem:internal",
                "Internal server error",
                d.clone(),
                None,
            ),
            ApiError::MethodNotAllowed(d) => (
                "urn:skybake:problem:method-not-allowed",
                "Method not allowed",
                d.clone(),
                None,
            ),
            ApiError::Unauthorized => (
                "urn:skybake:problem:unauthorized",
                "Unauthorized",
                "this route needs an Authorization: Bearer <token> header with one of the tokens of server.api_tokens".into(),
                None,
            ),
            ApiError::RateLimited { retry_after_s } => (
                "urn:skybake:problem:rate-limited",
                "Too many requests",
                format!("this client exceeded server.rate_limit_per_s; retry after {retry_after_s} s"),
                None,
            ),
            ApiError::JobsFull(d) => (
                "urn:skybake:problem:jobs-full",
                "Too many live jobs",
                d.clone(),
                None,
            ),
            ApiError::SlowBody(d) => (
                "urn:skybake:problem:body-timeout",
                "Request body timed out",
                d.clone(),
                Some("body".into()),
            ),
            ApiError::StorageUnavailable { detail, .. } => (
                "urn:skybake:problem:storage-unavailable",
                "Storage unavailable",
                format!("{detail}; nothing was served from it: retry after the indicated delay"),
                None,
            ),
        }
    }
}

/// The problem+json body of an error (also written by [`super::conn`] for the requests hyper
/// refuses before the router runs).
pub fn problem_json(
    status: StatusCode,
    kind: &str,
    title: &str,
    detail: String,
    parameter: Option<String>,
) -> Vec<u8> {
    serde_json::to_vec(&Problem {
        kind,
        title,
        status: status.as_u16(),
        detail,
        parameter,
    })
    .unwrap_or_default()
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.parts().2)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        if status.is_server_error() {
            tracing::warn!(status = status.as_u16(), error = %self, "request failed");
        }
        let (kind, title, detail, parameter) = self.parts();
        let body = problem_json(status, kind, title, detail, parameter);
        let mut resp = (status, body).into_response();
        let h = resp.headers_mut();
        h.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/problem+json"),
        );
        if status == StatusCode::SERVICE_UNAVAILABLE {
            h.insert(header::RETRY_AFTER, HeaderValue::from_static("1"));
        }
        if let ApiError::RateLimited { retry_after_s }
        | ApiError::StorageUnavailable { retry_after_s, .. } = self
        {
            h.insert(header::RETRY_AFTER, HeaderValue::from(retry_after_s));
        }
        if status == StatusCode::REQUEST_TIMEOUT {
            // RFC 9110 §15.5.9: the server closes the connection after a 408.
            h.insert(header::CONNECTION, HeaderValue::from_static("close"));
        }
        if status == StatusCode::UNAUTHORIZED {
            h.insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"skybake\""),
            );
        }
        resp
    }
}
