//! The HTTP transport (axum): the same messages as gRPC, as canonical proto3 JSON or as
//! protobuf (`Content-Type: application/x-protobuf`); answers in the request's format.
//!
//! - `POST /v1/match[?timeout_ms=N]`: a `MatchRequest` → a `MatchResponse` (504
//!   DEADLINE_EXCEEDED past the timeout); or a `multipart/form-data` upload (parts
//!   `calibration`, `options`, and `segments` or `image1` `image2` `image3`), answered in JSON;
//! - `GET /healthz`: the process is up; `GET /readyz`: it takes work (503 while stopping);
//! - `GET /metrics`: Prometheus text format.
//!
//! Errors are `{"error": {"code": "INVALID_ARGUMENT", "field": "...", "message": "..."}}` with
//! the HTTP status of the gRPC code.

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, FromRequest, Multipart, State};
use std::time::Duration;

use axum::http::{header, HeaderMap, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use prost::Message;

use super::{from_json, pb, to_json, InputError};
use crate::service::{request_id, Service, ServiceError};

const PROTOBUF: &str = "application/x-protobuf";
const JSON: &str = "application/json";

/// The HTTP routes over `service`.
pub fn router(service: Arc<Service>) -> Router {
    let max = service.limits().max_message_bytes;
    Router::new()
        .route("/v1/match", post(match_handler))
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/readyz", get(ready))
        .route(
            "/metrics",
            get(|State(service): State<Arc<Service>>| async move {
                (
                    [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
                    service.metrics_text(),
                )
            }),
        )
        .layer(DefaultBodyLimit::max(max))
        .layer(axum::middleware::from_fn(with_request_id))
        .with_state(service)
}

/// Gives every request an id (the client's `x-request-id`, or a new one), runs it inside a
/// span carrying it, and echoes it in the response.
async fn with_request_id(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    use tracing::Instrument;
    let id = request_id::request_id(
        request
            .headers()
            .get(request_id::HEADER)
            .and_then(|v| v.to_str().ok()),
    );
    let span = tracing::info_span!("http", request_id = %id, path = %request.uri().path());
    let mut response = next.run(request).instrument(span).await;
    if let Ok(value) = header::HeaderValue::from_str(&id) {
        response.headers_mut().insert(request_id::HEADER, value);
    }
    response
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
        "error": {"code": code_name(e.code()), "message": e.to_string()}
    });
    if let Some(field) = e.field() {
        body["error"]["field"] = serde_json::Value::String(field.to_string());
    }
    let mut response = (
        e.http_status(),
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

/// The gRPC name of a code: `InvalidArgument` → `INVALID_ARGUMENT`.
fn code_name(code: tonic::Code) -> String {
    let mut out = String::new();
    for (i, c) in format!("{code:?}").chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
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
    request: axum::extract::Request,
) -> Response {
    let protobuf = is_protobuf(request.headers());
    let multipart = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("multipart/form-data"));
    let start = std::time::Instant::now();
    let max_bytes = service.limits().max_message_bytes;
    let refuse = |e: ServiceError| {
        service.record_refused("http", &e, start.elapsed().as_secs_f64());
        error_response(&e)
    };
    let timeout = match timeout_of(&uri) {
        Ok(t) => t,
        Err(e) => return refuse(ServiceError::Input(e)),
    };
    // The body is parsed on the compute pool with the rest of the work; a multipart upload is
    // read part by part here (that is I/O), its small JSON parts parsed as they come.
    type Read = Box<dyn FnOnce() -> Result<pb::MatchRequest, InputError> + Send>;
    let read: Read = if multipart {
        let parts = match Multipart::from_request(request, &()).await {
            Ok(parts) => parts,
            Err(e) => {
                return refuse(ServiceError::Input(InputError::new(
                    "request",
                    e.body_text(),
                )))
            }
        };
        match request_from_multipart(parts, max_bytes).await {
            Ok(request) => Box::new(move || Ok(request)),
            Err(e) => return refuse(e),
        }
    } else {
        match Bytes::from_request(request, &()).await {
            Ok(body) => Box::new(move || decode_body(&body, protobuf)),
            Err(e) => return refuse(body_error(e.status(), e.body_text(), max_bytes)),
        }
    };
    let encode = move |r: &pb::MatchResponse| {
        if protobuf {
            r.encode_to_vec()
        } else {
            (to_json(r) + "\n").into_bytes()
        }
    };
    match service.match_within(read, encode, timeout, "http").await {
        Ok((_, body)) => {
            let content_type = if protobuf { PROTOBUF } else { JSON };
            ([(header::CONTENT_TYPE, content_type)], body).into_response()
        }
        Err(e) => error_response(&e),
    }
}

/// A body that could not be read: too large (413, naming the limit), or malformed.
fn body_error(status: StatusCode, text: String, max_bytes: usize) -> ServiceError {
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        ServiceError::TooLarge {
            limit_bytes: max_bytes,
        }
    } else {
        ServiceError::Input(InputError::new("request", text))
    }
}

fn decode_body(body: &[u8], protobuf: bool) -> Result<pb::MatchRequest, InputError> {
    if protobuf {
        pb::MatchRequest::decode(body)
            .map_err(|e| InputError::new("request", format!("invalid protobuf: {e}")))
    } else {
        std::str::from_utf8(body)
            .map_err(|_| InputError::new("request", "the body is not UTF-8 JSON"))
            .and_then(|text| from_json("request", text))
    }
}

/// A `MatchRequest` from a `multipart/form-data` upload, for curl: parts `calibration` (JSON),
/// `options` (JSON, optional), and either `segments` (a `SegmentTriplet`, JSON) or `image1`,
/// `image2`, `image3` (image files).
async fn request_from_multipart(
    mut parts: Multipart,
    max_bytes: usize,
) -> Result<pb::MatchRequest, ServiceError> {
    let bad = |field: &str, message: String| ServiceError::Input(InputError::new(field, message));
    let text = |field: &str, bytes: &[u8]| -> Result<String, ServiceError> {
        String::from_utf8(bytes.to_vec()).map_err(|_| bad(field, "is not UTF-8 JSON".into()))
    };
    let (mut calibration, mut options, mut segments) = (None, None, None);
    let mut images: [Option<Vec<u8>>; 3] = Default::default();
    loop {
        let field = match parts.next_field().await {
            Ok(Some(field)) => field,
            Ok(None) => break,
            Err(e) => return Err(body_error(e.status(), e.body_text(), max_bytes)),
        };
        let name = field.name().unwrap_or_default().to_string();
        let bytes = field
            .bytes()
            .await
            .map_err(|e| body_error(e.status(), e.body_text(), max_bytes))?;
        match name.as_str() {
            "calibration" => calibration = Some(from_json("calibration", &text(&name, &bytes)?)?),
            "options" => options = Some(from_json("options", &text(&name, &bytes)?)?),
            "segments" => segments = Some(from_json("segments", &text(&name, &bytes)?)?),
            "image1" | "image2" | "image3" => {
                let i = usize::from(name.as_bytes()[5] - b'1');
                images[i] = Some(bytes.to_vec());
            }
            other => {
                return Err(bad(
                    other,
                    "unknown part: expected calibration, options, segments or image1..image3"
                        .into(),
                ))
            }
        }
    }
    let given = images.iter().filter(|i| i.is_some()).count();
    let input = match (segments, given) {
        (Some(s), 0) => pb::match_request::Input::Segments(s),
        (None, 3) => pb::match_request::Input::Images(pb::ImageTriplet {
            images: images
                .into_iter()
                .map(|bytes| pb::Image {
                    source: bytes.map(pb::image::Source::Encoded),
                })
                .collect(),
        }),
        (Some(_), _) => return Err(bad("segments", "give segments or images, not both".into())),
        (None, n) => {
            return Err(bad(
                "images",
                format!("needs the three parts image1, image2, image3 (or segments), got {n}"),
            ))
        }
    };
    Ok(pb::MatchRequest {
        calibration,
        options,
        input: Some(input),
    })
}
