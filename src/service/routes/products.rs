//! The product routes `GET /v1/sun|sky|ground|aerial`: query → request (with the deployment's
//! defaults) → body from the response cache, the product cache or one computation.

use super::super::extract::Query;
use super::super::problem::ApiError;
use super::super::AppState;
use crate::product::params::RequestParams;
use crate::product::ProductKind;
use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};

/// `GET /v1/{product}`.
pub fn route(kind: ProductKind) -> axum::routing::MethodRouter<AppState> {
    axum::routing::get(
        move |State(state): State<AppState>, Query(params): Query<RequestParams>| {
            product(state, kind, params)
        },
    )
}

async fn product(
    state: AppState,
    kind: ProductKind,
    params: RequestParams,
) -> Result<Response, ApiError> {
    let req = state.request(kind, params)?;
    let (body, source, key) = state.body(&req).await?;
    let mut resp = body.into_response();
    let h = resp.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(req.format.content_type()),
    );
    h.insert("x-cache", HeaderValue::from_static(source.header()));
    if let Ok(v) = HeaderValue::from_str(&key) {
        h.insert("x-skybake-cache-key", v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!("\"{key}-{}\"", req.format.name())) {
        h.insert(header::ETAG, v);
    }
    Ok(resp)
}
