//! The HTTP transport (axum): the same messages as gRPC, as canonical proto3 JSON or as
//! protobuf (`Content-Type: application/x-protobuf`); answers in the request's format.
//!
//! - `POST /v1/match[?timeout_ms=N]`: a `MatchRequest` → a `MatchResponse` (504
//!   DEADLINE_EXCEEDED past the timeout);
//! - `GET /healthz`: the process is up; `GET /readyz`: it takes work (503 while stopping).
//!
//! Errors are `{"error": {"code": "INVALID_ARGUMENT", "field": "...", "message": "..."}}` with
//! the HTTP status of the gRPC code.

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, State};
use std::time::Duration;

use axum::http::{header, HeaderMap, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use prost::Message;

use super::{from_json, pb, to_json, InputError};
use crate::service::{http_status, Service, ServiceError};

const PROTOBUF: &str = "application/x-protobuf";
const JSON: &str = "application/json";

/// The HTTP routes over `service`.
pub fn router(service: Arc<Service>) -> Router {
    let max = service.limits().max_message_bytes;
    Router::new()
        .route("/v1/match", post(match_handler))
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/readyz", get(ready))
        .layer(DefaultBodyLimit::max(max))
        .with_state(service)
}

async fn ready(State(service): State<Arc<Service>>) -> Response {
    if service.is_ready() {
        (StatusCode::OK, "ready\n").into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, "stopping\n").into_response()
    }
}

fn is_protobuf(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with(PROTOBUF))
}

/// An error response, in JSON whatever the request's format (clients read it as text).
pub fn error_response(e: &ServiceError) -> Response {
    let mut body = serde_json::json!({
        "error": {"code": format!("{:?}", e.code()).to_uppercase_snake(), "message": e.to_string()}
    });
    if let Some(field) = e.field() {
        body["error"]["field"] = serde_json::Value::String(field.to_string());
    }
    let mut response = (
        http_status(e.code()),
        [(header::CONTENT_TYPE, JSON)],
        body.to_string() + "\n",
    )
        .into_response();
    if matches!(e, ServiceError::Busy { .. }) {
        response
            .headers_mut()
            .insert(header::RETRY_AFTER, header::HeaderValue::from_static("1"));
    }
    response
}

trait UpperSnake {
    fn to_uppercase_snake(&self) -> String;
}

impl UpperSnake for String {
    /// `InvalidArgument` → `INVALID_ARGUMENT` (the gRPC code names).
    fn to_uppercase_snake(&self) -> String {
        let mut out = String::with_capacity(self.len() + 4);
        for (i, c) in self.chars().enumerate() {
            if c.is_uppercase() && i > 0 {
                out.push('_');
            }
            out.push(c.to_ascii_uppercase());
        }
        out
    }
}

/// Longest `timeout_ms` accepted: an hour.
const MAX_TIMEOUT_MS: u64 = 3_600_000;

/// The `timeout_ms` query parameter, if any.
fn timeout_of(uri: &Uri) -> Result<Option<Duration>, InputError> {
    let Some(query) = uri.query() else {
        return Ok(None);
    };
    for pair in query.split('&') {
        if let Some(value) = pair.strip_prefix("timeout_ms=") {
            return match value.parse::<u64>() {
                Ok(ms) if (1..=MAX_TIMEOUT_MS).contains(&ms) => Ok(Some(Duration::from_millis(ms))),
                _ => Err(InputError::new(
                    "timeout_ms",
                    format!("must be a whole number of milliseconds from 1 to {MAX_TIMEOUT_MS}, got {value:?}"),
                )),
            };
        }
    }
    Ok(None)
}

async fn match_handler(
    State(service): State<Arc<Service>>,
    uri: Uri,
    headers: HeaderMap,
    body: Bytes,
) -> Response {
    let protobuf = is_protobuf(&headers);
    let timeout = match timeout_of(&uri) {
        Ok(t) => t,
        Err(e) => return error_response(&ServiceError::Input(e)),
    };
    let request: Result<pb::MatchRequest, InputError> = if protobuf {
        pb::MatchRequest::decode(body)
            .map_err(|e| InputError::new("request", format!("invalid protobuf: {e}")))
    } else {
        std::str::from_utf8(&body)
            .map_err(|_| InputError::new("request", "the body is not UTF-8 JSON"))
            .and_then(|text| from_json("request", text))
    };
    let response = match request {
        Ok(request) => service.match_within(request, timeout).await,
        Err(e) => Err(ServiceError::Input(e)),
    };
    match response {
        Ok(r) if protobuf => {
            ([(header::CONTENT_TYPE, PROTOBUF)], r.encode_to_vec()).into_response()
        }
        Ok(r) => ([(header::CONTENT_TYPE, JSON)], to_json(&r) + "\n").into_response(),
        Err(e) => error_response(&e),
    }
}
