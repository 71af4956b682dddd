//! The request extractors, the one place where query strings and JSON bodies are read: a
//! [`Query`] of any [`FromQuery`] type (product parameters from the parameter table, a page, an
//! artifact format, or nothing at all) and a [`JsonObject`] body. Unknown or repeated names and
//! malformed bodies become problem+json errors here, before a handler runs.

use super::problem::ApiError;
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::request::Parts;
use axum::http::StatusCode;
use serde_json::{Map, Value};
use skybake_product::params::RequestParams;

/// Most bytes of a query string: below hyper's own URI limit (65534 bytes, answered with a bare
/// 414 before the router runs), so that the service's problem+json 414 stating this limit is what
/// a long query meets.
pub const MAX_QUERY_BYTES: usize = 32 * 1024;

/// A type built from a route's decoded query pairs.
pub trait FromQuery: Sized {
    fn from_pairs(pairs: Vec<(String, String)>) -> Result<Self, ApiError>;
}

/// The query string of a request, parsed into `T`.
pub struct Query<T>(pub T);

/// Decodes a query string (at most [`MAX_QUERY_BYTES`]) into pairs.
pub fn query_pairs(query: Option<&str>) -> Result<Vec<(String, String)>, ApiError> {
    let q = query.unwrap_or("");
    if q.len() > MAX_QUERY_BYTES {
        return Err(crate::Error::too_large(
            "query",
            format!("{} bytes", q.len()),
            MAX_QUERY_BYTES,
        )
        .into());
    }
    Ok(form_urlencoded::parse(q.as_bytes()).into_owned().collect())
}

impl<S: Send + Sync, T: FromQuery> FromRequestParts<S> for Query<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        T::from_pairs(query_pairs(parts.uri.query())?).map(Query)
    }
}

/// Path parameters (axum's `Path`), a segment that does not decode (not UTF-8 once
/// percent-decoded) or parse being a 404 problem+json instead of axum's plain-text 400.
pub struct PathParams<T>(pub T);

impl<S: Send + Sync, T: serde::de::DeserializeOwned + Send> FromRequestParts<S> for PathParams<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        axum::extract::Path::<T>::from_request_parts(parts, state)
            .await
            .map(|axum::extract::Path(t)| PathParams(t))
            .map_err(|e| ApiError::NotFound(format!("no such resource: {e}")))
    }
}

/// Product parameters: names from the parameter table, each at most once.
impl FromQuery for RequestParams {
    fn from_pairs(pairs: Vec<(String, String)>) -> Result<Self, ApiError> {
        Ok(RequestParams::from_pairs(pairs)?)
    }
}

/// Refuses every query parameter (routes that take none).
pub struct NoParams;

impl FromQuery for NoParams {
    fn from_pairs(pairs: Vec<(String, String)>) -> Result<Self, ApiError> {
        if pairs.is_empty() {
            Ok(NoParams)
        } else {
            Err(ApiError::UnknownParameters(
                pairs.into_iter().map(|(k, _)| k).collect(),
            ))
        }
    }
}

/// Most artifacts listed per status page.
pub const MAX_PAGE: usize = 1000;

/// `offset` and `limit` of a listing (default 0 and 100, limit at most [`MAX_PAGE`]).
pub struct Page {
    pub offset: usize,
    pub limit: usize,
}

impl FromQuery for Page {
    fn from_pairs(pairs: Vec<(String, String)>) -> Result<Self, ApiError> {
        let mut page = Page {
            offset: 0,
            limit: 100,
        };
        let mut unknown = Vec::new();
        for (k, v) in pairs {
            match k.as_str() {
                "offset" => {
                    page.offset =
                        skybake_product::params::parse_usize("offset", &v, 0, usize::MAX / 2)?
                }
                "limit" => {
                    page.limit = skybake_product::params::parse_usize("limit", &v, 0, MAX_PAGE)?
                }
                _ => unknown.push(k),
            }
        }
        if unknown.is_empty() {
            Ok(page)
        } else {
            Err(ApiError::UnknownParameters(unknown))
        }
    }
}

/// `format` only (job artifacts).
pub struct FormatOnly(pub Option<String>);

impl FromQuery for FormatOnly {
    fn from_pairs(pairs: Vec<(String, String)>) -> Result<Self, ApiError> {
        let mut format = None;
        let mut unknown = Vec::new();
        for (k, v) in pairs {
            match k.as_str() {
                "format" if format.is_none() => format = Some(v),
                "format" => {
                    return Err(crate::Error::invalid("format", "given more than once").into())
                }
                _ => unknown.push(k),
            }
        }
        if unknown.is_empty() {
            Ok(FormatOnly(format))
        } else {
            Err(ApiError::UnknownParameters(unknown))
        }
    }
}

/// The configured body limit in bytes, put in each request's extensions by the router so that a
/// 413 can state it.
#[derive(Debug, Clone, Copy)]
pub struct BodyLimit(pub usize);

/// A JSON object body (and its raw bytes, which jobs persist as submitted).
pub struct JsonObject {
    pub object: Map<String, Value>,
    pub bytes: bytes::Bytes,
}

impl<S: Send + Sync> FromRequest<S> for JsonObject {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, ApiError> {
        let limit = req
            .extensions()
            .get::<BodyLimit>()
            .map(|l| l.0.to_string())
            .unwrap_or_else(|| "server.body_limit_bytes".into());
        let bytes = bytes::Bytes::from_request(req, state)
            .await
            .map_err(|e| ApiError::Body {
                status: e.status(),
                detail: if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                    format!("the body is larger than server.body_limit_bytes (limit {limit} bytes)")
                } else {
                    e.body_text()
                },
            })?;
        match serde_json::from_slice::<Value>(&bytes) {
            Ok(Value::Object(object)) => Ok(Self { object, bytes }),
            Ok(_) => Err(ApiError::Body {
                status: StatusCode::UNPROCESSABLE_ENTITY,
                detail: "the body must be a JSON object".into(),
            }),
            Err(e) => Err(ApiError::Body {
                status: StatusCode::BAD_REQUEST,
                detail: format!("the body is not valid JSON: {e}"),
            }),
        }
    }
}
