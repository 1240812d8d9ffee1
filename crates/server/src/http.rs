//! The HTTP transport (axum): the same messages as gRPC, as canonical proto3 JSON or as
//! protobuf (`Content-Type: application/x-protobuf`); answers in the request's format.
//!
//! - `POST /v1/match[?timeout_ms=N][&format=json|ply]`: a `MatchRequest` → a `MatchResponse`
//!   (504 DEADLINE_EXCEEDED past the timeout), or its 3D segments as PLY; or a
//!   `multipart/form-data` upload (parts `calibration`, `options`, and `segments` or `image1`
//!   `image2` `image3`), answered in JSON;
//! - `POST /v1/calibrate[?timeout_ms=N]`: a `CalibrateRequest` → a `CalibrateResponse`, or a
//!   multipart upload (parts `pattern`, `options`, `pattern_to_rig`, `image1..3`);
//! - `POST /v1/calibration/import`: an `ImportCalibrationRequest` (or a multipart upload,
//!   parts `format` and `file` or `file1..3`) → a `Calibration`; `POST
//!   /v1/calibration/export`: an `ExportCalibrationRequest` → an `ExportCalibrationResponse`;
//! - sessions: `POST /v1/sessions` (a `CreateSessionRequest`), `GET /v1/sessions`,
//!   `GET|DELETE /v1/sessions/{id}`, `POST /v1/sessions/{id}/captures[?timeout_ms=N]` (an
//!   `AddCaptureRequest`, or a multipart upload with parts `pose` and `segments` or
//!   `image1..3`), `GET /v1/sessions/{id}/map[?format=json|ply|obj|svg|png][&min_observations=N]`;
//! - the browser view (`/`, `/sessions/{id}`, `/ui/…`) and its live feed
//!   `GET /v1/sessions/{id}/events` ([`crate::ui`]);
//! - `GET /openapi.json`: this API as an OpenAPI 3 document;
//! - `GET /healthz`: the process is up; `GET /readyz`: it takes work (503 while stopping);
//! - `GET /metrics`: Prometheus text format.
//!
//! Errors are `{"error": {"code": "INVALID_ARGUMENT", "field": "...", "message": "..."}}` with
//! the HTTP status of the gRPC code.
//!
//! Query strings are read by axum's `Query` into one small struct per route whose fields are
//! optional strings, then checked here: a bad value is that error naming its parameter
//! (`timeout_ms`, `page_size`, `min_observations`, `format`), not axum's plain-text rejection.

use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{
    DefaultBodyLimit, Extension, FromRequest, FromRequestParts, MatchedPath, Multipart, Path,
    Query, State,
};
use std::time::Duration;

use axum::http::request::Parts;
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use prost::Message;
use serde::Deserialize;

use crate::http_server::timed_out_body;
use crate::metered_body::{Metered, MeteredBody};
use crate::observe;
use crate::service::auth::Caller;
use crate::service::metrics::grpc_code_name;
use crate::service::sessions::{map_to_pb, SessionMap};
use crate::service::{Service, ServiceError};
use trinocular_schema::{
    calibrate_request_from_json, from_json, pb, to_json, InputError, LEGACY_PATTERN_TO_RIG,
};

const PROTOBUF: &str = "application/x-protobuf";
const JSON: &str = "application/json";

/// The HTTP routes over `service`.
pub fn router(service: Arc<Service>) -> Router {
    let max = service.limits().max_message_bytes;
    Router::new()
        .route("/v1/match", post(match_handler))
        .route("/v1/calibrate", post(calibrate))
        .route("/v1/calibration/import", post(import_calibration))
        .route("/v1/calibration/export", post(export_calibration))
        .route("/v1/sessions", post(create_session).get(list_sessions))
        .route("/v1/sessions/{id}", get(get_session).delete(delete_session))
        .route("/v1/sessions/{id}/captures", post(add_capture))
        .route("/v1/sessions/{id}/map", get(get_map))
        .merge(crate::ui::routes())
        .route("/openapi.json", get(openapi))
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
        // A path or method not served answers in the API's error format too.
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(max))
        .layer(axum::middleware::from_fn_with_state(
            Arc::clone(&service),
            admit,
        ))
        // Outermost: every request, refused ones too, has its id and span.
        .layer(observe::http(Arc::clone(&service), route))
        .with_state(service)
}

/// A request's route in the metrics and the log (`None`: not observed: the probes, the
/// metrics, a method or path not served), from the router's pattern and the method, so
/// `/v1/sessions/{id}` is one route whatever the id.
fn route(parts: &Parts) -> Option<&'static str> {
    use axum::http::Method;
    let path = parts.extensions.get::<MatchedPath>()?.as_str();
    Some(match (&parts.method, path) {
        (&Method::POST, "/v1/match") => "match",
        (&Method::POST, "/v1/calibrate") => "calibrate",
        (&Method::POST, "/v1/calibration/import") => "import_calibration",
        (&Method::POST, "/v1/calibration/export") => "export_calibration",
        (&Method::POST, "/v1/sessions") => "create_session",
        (&Method::GET, "/v1/sessions") => "list_sessions",
        (&Method::GET, "/v1/sessions/{id}") => "get_session",
        (&Method::DELETE, "/v1/sessions/{id}") => "delete_session",
        (&Method::POST, "/v1/sessions/{id}/captures") => "add_capture",
        (&Method::GET, "/v1/sessions/{id}/map") => "get_map",
        (&Method::GET, "/v1/sessions/{id}/events") => "session_events",
        _ => return None,
    })
}

/// Largest body read (and dropped) before a refusal for lack of compute, bytes.
const DRAIN_BEFORE_REFUSING: usize = 64 << 10;

/// Authentication ([`Caller`]), then admission before a body is read: a request that
/// declares a body larger than the limit gets 413, and one that needs a compute slot when
/// none is free gets 429, at no cost of body reading or memory. Every body then takes its
/// bytes from the service's body budget as they arrive ([`MeteredBody`]) — 429 when the
/// bodies being received hold it all — and gives them back with the answer.
async fn admit(
    State(service): State<Arc<Service>>,
    mut request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let path = request.uri().path();
    if !matches!(path, "/healthz" | "/readyz" | "/metrics" | "/openapi.json")
        && !crate::ui::is_public(path)
    {
        // The key is checked before anything else, by the handlers' own extractor: an
        // unknown caller costs no admission and reads no body. The caller it finds is kept in
        // the request for the handler's extraction.
        let (mut parts, body) = request.into_parts();
        if let Err(rejection) = Caller::from_request_parts(&mut parts, &service).await {
            return rejection.into_response();
        }
        request = axum::extract::Request::from_parts(parts, body);
    }
    if request.method() != axum::http::Method::POST {
        return next.run(request).await;
    }
    let max = service.limits().max_message_bytes;
    let declared = request
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<usize>().ok());
    let refuse = |e: ServiceError| error_response(&e);
    if declared.is_some_and(|n| n > max) {
        return refuse(ServiceError::TooLarge { limit_bytes: max });
    }
    let path = request.uri().path();
    let computes = path == "/v1/match" || path == "/v1/calibrate" || path.ends_with("/captures");
    if computes && service.compute_full() {
        // A small body is read and dropped so the connection stays open for the client's
        // retry: a new connection per refusal costs both sides more than the bytes.
        if declared.is_some_and(|n| n <= DRAIN_BEFORE_REFUSING) {
            // Frame by frame, dropped as they come: nothing gathered or copied.
            let mut body = request.into_body();
            while let Some(Ok(_)) =
                std::future::poll_fn(|cx| http_body::Body::poll_frame(Pin::new(&mut body), cx))
                    .await
            {}
        }
        return refuse(ServiceError::Busy {
            max_jobs: service.limits().max_jobs,
        });
    }
    let metered = Metered::new(&service);
    let request = request.map(|body| {
        axum::body::Body::new(MeteredBody::new(body, metered.clone(), |e| {
            axum::Error::new(e.clone())
        }))
    });
    let response = next.run(request).await;
    // The handler failed to read a body the budget refused: the refusal is the answer.
    match metered.refusal() {
        Some(e) => refuse(e),
        None => response,
    }
}

async fn ready(State(service): State<Arc<Service>>) -> Response {
    if service.is_ready() {
        (StatusCode::OK, "ready\n").into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, "stopping\n").into_response()
    }
}

/// How a request's body is written, from its `Content-Type`: proto3 JSON (the default),
/// protobuf, or a `multipart/form-data` upload (for curl). An extractor, so that no handler
/// reads the header itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BodyFormat {
    Json,
    Protobuf,
    Multipart,
}

impl BodyFormat {
    fn of(headers: &HeaderMap) -> BodyFormat {
        let content_type = headers
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("");
        if content_type.starts_with(PROTOBUF) {
            BodyFormat::Protobuf
        } else if content_type.starts_with("multipart/form-data") {
            BodyFormat::Multipart
        } else {
            BodyFormat::Json
        }
    }
}

impl<S: Send + Sync> FromRequestParts<S> for BodyFormat {
    type Rejection = Infallible;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Self::Rejection> {
        Ok(BodyFormat::of(&parts.headers))
    }
}

/// Whether the answer is protobuf: when the body was, or when `Accept` asks for it (GETs have
/// no body to take the format from); proto3 JSON otherwise. An extractor, like [`BodyFormat`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct AnswerFormat {
    protobuf: bool,
}

impl AnswerFormat {
    fn of(headers: &HeaderMap) -> AnswerFormat {
        let accepts = headers
            .get(header::ACCEPT)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|v| v.starts_with(PROTOBUF));
        AnswerFormat {
            protobuf: accepts || BodyFormat::of(headers) == BodyFormat::Protobuf,
        }
    }
}

impl<S: Send + Sync> FromRequestParts<S> for AnswerFormat {
    type Rejection = Infallible;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Self::Rejection> {
        Ok(AnswerFormat::of(&parts.headers))
    }
}

/// The caller, from `Authorization: Bearer <key>` (anyone, when the service has no keys): an
/// extractor, like [`BodyFormat`], so that no handler reads the header itself. A request
/// without a valid key is rejected with the service's error mapping ([`CallerRejected`]).
/// [`admit`] extracts it first, before admission; the handler's extraction then finds it in
/// the request's extensions rather than checking the key twice.
impl FromRequestParts<Arc<Service>> for Caller {
    type Rejection = CallerRejected;

    async fn from_request_parts(
        parts: &mut Parts,
        service: &Arc<Service>,
    ) -> Result<Self, Self::Rejection> {
        if let Some(caller) = parts.extensions.get::<Caller>() {
            return Ok(caller.clone());
        }
        let authorization = parts
            .headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok());
        let caller = service.caller(authorization).map_err(CallerRejected)?;
        parts.extensions.insert(caller.clone());
        Ok(caller)
    }
}

/// The session id of the URL (`/v1/sessions/{id}...`): an extractor, like [`BodyFormat`]. A
/// segment that is not UTF-8 once percent-decoded is INVALID_ARGUMENT naming `session_id`
/// in the service's error format, where axum's `Path` answers plain text.
pub(crate) struct SessionId(pub String);

impl<S: Send + Sync> FromRequestParts<S> for SessionId {
    type Rejection = Response;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        Path::<String>::from_request_parts(parts, state)
            .await
            .map(|Path(id)| SessionId(id))
            .map_err(|e| {
                error_response(&ServiceError::Input(InputError::new(
                    "session_id",
                    e.body_text(),
                )))
            })
    }
}

/// A caller without a valid key: 401 UNAUTHENTICATED in the service's error format, with
/// `WWW-Authenticate: Bearer`.
#[derive(Debug)]
pub struct CallerRejected(pub ServiceError);

impl IntoResponse for CallerRejected {
    fn into_response(self) -> Response {
        let mut response = error_response(&self.0);
        response.headers_mut().insert(
            header::WWW_AUTHENTICATE,
            header::HeaderValue::from_static("Bearer"),
        );
        response
    }
}

/// An error response, in JSON whatever the request's format (clients read it as text). The
/// error itself rides along in the response's extensions, for the observation layer to log
/// and count ([`observe`]).
pub fn error_response(e: &ServiceError) -> Response {
    let mut body = serde_json::json!({
        "error": {"code": grpc_code_name(e.code()), "message": e.to_string()}
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
    if e.is_overload() {
        response
            .headers_mut()
            .insert(header::RETRY_AFTER, header::HeaderValue::from_static("1"));
    }
    response
}

/// The HTTP API's OpenAPI 3 document (`src/openapi.json`; a test holds it to the router's
/// routes, CI validates it).
pub const OPENAPI: &str = include_str!("openapi.json");

async fn openapi() -> Response {
    ([(header::CONTENT_TYPE, JSON)], OPENAPI).into_response()
}

async fn not_found(uri: axum::http::Uri) -> Response {
    error_response(&ServiceError::NotFound {
        field: "path".into(),
        what: format!("route {}", shown_path(uri.path())),
    })
}

/// Most characters of a request's path an error repeats: a 60,000-character path was echoed
/// whole, into the answer and every log line.
const MAX_SHOWN_PATH_CHARS: usize = 128;

/// `path` as an error shows it: at most [`MAX_SHOWN_PATH_CHARS`] characters, then "…".
pub(crate) fn shown_path(path: &str) -> String {
    let mut shown: String = path.chars().take(MAX_SHOWN_PATH_CHARS).collect();
    if shown.len() < path.len() {
        shown.push('…');
    }
    shown
}

async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> Response {
    let body = serde_json::json!({"error": {
        "code": "UNIMPLEMENTED",
        "field": "method",
        "message": format!("{method} is not served on {}", uri.path()),
    }});
    (
        StatusCode::METHOD_NOT_ALLOWED,
        [(header::CONTENT_TYPE, JSON)],
        body.to_string() + "\n",
    )
        .into_response()
}

/// Longest `timeout_ms` accepted: an hour.
const MAX_TIMEOUT_MS: u64 = 3_600_000;

/// The query string as `T`. Every field of a query struct is an optional string, and none
/// takes a parameter it does not know (a misspelt `timout_ms` would otherwise be ignored, and
/// the call run without the deadline its client asked for), so a parameter that is not the
/// call's, named as the field, and a repeated one (serde refuses a duplicate field), naming
/// the query, are what fails here: INVALID_ARGUMENT, in our error format rather than axum's.
fn query<T>(query: Result<Query<T>, QueryRejection>) -> Result<T, InputError> {
    query.map(|Query(q)| q).map_err(|e| {
        let text = e.body_text();
        // serde's words: "… unknown field `name`, expected `a` or `b`" (or "there are no
        // fields"): the name becomes the field, what is expected the message.
        let unknown = text
            .split_once("unknown field `")
            .and_then(|(_, rest)| rest.split_once('`'));
        match unknown {
            Some((name, rest)) => {
                let expected = rest.trim_start_matches([',', ' ']);
                let message = if expected.is_empty() {
                    "this call takes no such query parameter".to_string()
                } else {
                    format!("this call takes no such query parameter ({expected})")
                };
                InputError::new(name, message)
            }
            None => InputError::new("query", text),
        }
    })
}

/// The query of the calls that run compute: `?timeout_ms=N`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct TimeoutQuery {
    timeout_ms: Option<String>,
}

impl TimeoutQuery {
    /// The timeout asked for, if any: 1 ms to an hour.
    fn timeout(&self) -> Result<Option<Duration>, InputError> {
        let Some(value) = &self.timeout_ms else {
            return Ok(None);
        };
        match value.parse::<u64>() {
            Ok(ms) if (1..=MAX_TIMEOUT_MS).contains(&ms) => Ok(Some(Duration::from_millis(ms))),
            _ => Err(InputError::new(
                "timeout_ms",
                format!(
                    "must be a whole number of milliseconds from 1 to {MAX_TIMEOUT_MS}, got {value:?}"
                ),
            )),
        }
    }
}

/// Match's query: `?timeout_ms=N&format=json|ply`, both optional.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct MatchQuery {
    timeout_ms: Option<String>,
    format: Option<String>,
}

impl MatchQuery {
    fn timeout(&self) -> Result<Option<Duration>, InputError> {
        TimeoutQuery {
            timeout_ms: self.timeout_ms.clone(),
        }
        .timeout()
    }

    /// PLY asked for: the 3D segments as a file for point-cloud viewers, not the response.
    fn ply(&self) -> Result<bool, InputError> {
        match self.format.as_deref() {
            None | Some("json") => Ok(false),
            Some("ply") => Ok(true),
            Some(other) => Err(InputError::new(
                "format",
                format!("must be json or ply, got {other:?}"),
            )),
        }
    }
}

/// ListSessions' query: `?page_size=N&page_token=T`, both optional.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ListQuery {
    page_size: Option<String>,
    page_token: Option<String>,
}

impl ListQuery {
    fn request(self) -> Result<pb::ListSessionsRequest, InputError> {
        let page_size = match self.page_size {
            None => 0,
            Some(v) => v.parse::<u32>().map_err(|_| {
                InputError::new("page_size", format!("must be a whole number, got {v:?}"))
            })?,
        };
        Ok(pb::ListSessionsRequest {
            page_size,
            page_token: self.page_token.unwrap_or_default(),
        })
    }
}

/// GetMap's query: `?format=F&min_observations=N`, both optional.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct MapQuery {
    format: Option<String>,
    min_observations: Option<String>,
}

impl MapQuery {
    fn min_observations(&self) -> Result<Option<u32>, InputError> {
        let Some(v) = &self.min_observations else {
            return Ok(None);
        };
        match v.parse::<u32>() {
            Ok(n) if n >= 1 => Ok(Some(n)),
            _ => Err(InputError::new(
                "min_observations",
                format!("must be a whole number at least 1, got {v:?}"),
            )),
        }
    }

    /// The export asked for; JSON (or protobuf, by `Accept`) when none is.
    fn format(&self) -> Result<MapFormat, InputError> {
        self.format
            .as_deref()
            .map_or(Ok(MapFormat::Json), str::parse)
    }
}

/// The formats GetMap exports a map in over HTTP.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum MapFormat {
    /// The `SessionMap` message: proto3 JSON, or protobuf if the client accepts it.
    Json,
    Ply,
    Obj,
    /// A top view.
    Svg,
    /// The same top view, rasterised.
    Png,
}

impl MapFormat {
    /// Every format, by its query value.
    const ALL: [(&'static str, MapFormat); 5] = [
        ("json", MapFormat::Json),
        ("ply", MapFormat::Ply),
        ("obj", MapFormat::Obj),
        ("svg", MapFormat::Svg),
        ("png", MapFormat::Png),
    ];
}

impl std::str::FromStr for MapFormat {
    type Err = InputError;

    /// A query's `format` value, exactly as written (lower case).
    fn from_str(s: &str) -> Result<MapFormat, InputError> {
        MapFormat::ALL
            .iter()
            .find(|(name, _)| *name == s)
            .map(|&(_, format)| format)
            .ok_or_else(|| {
                InputError::new(
                    "format",
                    format!("{s:?}: expected json, ply, obj, svg or png"),
                )
            })
    }
}

async fn match_handler(
    State(service): State<Arc<Service>>,
    _: Caller,
    params: Result<Query<MatchQuery>, QueryRejection>,
    format: BodyFormat,
    request: axum::extract::Request,
) -> Response {
    let protobuf = format == BodyFormat::Protobuf;
    let multipart = format == BodyFormat::Multipart;
    let max_bytes = service.limits().max_message_bytes;
    let refuse = |e: ServiceError| error_response(&e);
    let (timeout, ply) = match query(params).and_then(|q| Ok((q.timeout()?, q.ply()?))) {
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
        match Upload::read(parts, max_bytes)
            .await
            .and_then(Upload::match_request)
        {
            Ok(request) => Box::new(move || Ok(request)),
            Err(e) => return refuse(e),
        }
    } else {
        match Bytes::from_request(request, &()).await {
            Ok(body) => Box::new(move || {
                decode_body_with(&body, protobuf, trinocular_schema::match_request_from_json)
            }),
            Err(e) => return refuse(body_error(&e, e.status(), e.body_text(), max_bytes)),
        }
    };
    let encode = move |r: &pb::MatchResponse| {
        if ply {
            trinocular_core::map::export::segments_to_ply(&trinocular_schema::segments_3d_of(r))
                .into_bytes()
        } else if protobuf {
            r.encode_to_vec()
        } else {
            (to_json(r) + "\n").into_bytes()
        }
    };
    match service.match_within(read, encode, timeout).await {
        Ok((response, body)) => {
            let content_type = match (ply, protobuf) {
                (true, _) => "application/x-ply",
                (false, true) => PROTOBUF,
                (false, false) => JSON,
            };
            let matched = observe::Matched {
                segments_3d: response.segments_3d.len(),
            };
            (
                [(header::CONTENT_TYPE, content_type)],
                Extension(matched),
                body,
            )
                .into_response()
        }
        Err(e) => error_response(&e),
    }
}

/// A body that could not be read: too slow (408), too large (413, naming the limit), or
/// malformed.
fn body_error<E: std::error::Error + 'static>(
    error: &E,
    status: StatusCode,
    text: String,
    max_bytes: usize,
) -> ServiceError {
    if let Some(timeout) = timed_out_body(error) {
        ServiceError::BodyTimeout {
            seconds: timeout.as_secs_f64(),
        }
    } else if status == StatusCode::PAYLOAD_TOO_LARGE {
        ServiceError::TooLarge {
            limit_bytes: max_bytes,
        }
    } else {
        ServiceError::Input(InputError::new("request", text))
    }
}

/// A message from a body in protobuf or proto3 JSON.
fn decode_body<T: Message + Default + serde::de::DeserializeOwned>(
    body: &[u8],
    protobuf: bool,
) -> Result<T, InputError> {
    decode_body_with(body, protobuf, |text| from_json("request", text))
}

/// [`decode_body`] with the message's own JSON reader (Match's fast reader of segment lists,
/// Calibrate's that accepts a field's former name).
fn decode_body_with<T: Message + Default>(
    body: &[u8],
    protobuf: bool,
    read_json: impl FnOnce(&str) -> Result<T, InputError>,
) -> Result<T, InputError> {
    if protobuf {
        T::decode(body).map_err(|e| trinocular_schema::protobuf_error("request", &e))
    } else {
        std::str::from_utf8(body)
            .map_err(|_| InputError::new("request", "the body is not UTF-8 JSON"))
            .and_then(read_json)
    }
}

/// A message as the answer, in the request's format.
fn encoded<T: Message + serde::Serialize>(message: &T, protobuf: bool) -> Response {
    if protobuf {
        ([(header::CONTENT_TYPE, PROTOBUF)], message.encode_to_vec()).into_response()
    } else {
        ([(header::CONTENT_TYPE, JSON)], to_json(message) + "\n").into_response()
    }
}

/// The answer to a session call: the message in the request's format, or the error.
fn answer<T: Message + serde::Serialize>(
    result: Result<T, ServiceError>,
    protobuf: bool,
) -> Response {
    match result {
        Ok(message) => encoded(&message, protobuf),
        Err(e) => error_response(&e),
    }
}

/// Reads a whole body, within the body limit.
async fn read_body(
    request: axum::extract::Request,
    max_bytes: usize,
) -> Result<Bytes, ServiceError> {
    Bytes::from_request(request, &())
        .await
        .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))
}

async fn calibrate(
    State(service): State<Arc<Service>>,
    _: Caller,
    params: Result<Query<TimeoutQuery>, QueryRejection>,
    format: BodyFormat,
    request: axum::extract::Request,
) -> Response {
    let protobuf = format == BodyFormat::Protobuf;
    let multipart = format == BodyFormat::Multipart;
    let max_bytes = service.limits().max_message_bytes;
    let result = async {
        let timeout = query(params)?.timeout()?;
        type Read = Box<dyn FnOnce() -> Result<pb::CalibrateRequest, InputError> + Send>;
        let read: Read = if multipart {
            let parts = Multipart::from_request(request, &())
                .await
                .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))?;
            let request = Upload::read(parts, max_bytes).await?.calibrate_request()?;
            Box::new(move || Ok(request))
        } else {
            let body = read_body(request, max_bytes).await?;
            Box::new(move || decode_body_with(&body, protobuf, calibrate_request_from_json))
        };
        service.calibrate(read, timeout).await
    }
    .await;
    answer(result, protobuf)
}

async fn create_session(
    State(service): State<Arc<Service>>,
    caller: Caller,
    format: BodyFormat,
    request: axum::extract::Request,
) -> Response {
    let protobuf = format == BodyFormat::Protobuf;
    let max_bytes = service.limits().max_message_bytes;
    let result = async {
        let body = read_body(request, max_bytes).await?;
        let request: pb::CreateSessionRequest = decode_body(&body, protobuf)?;
        service.create_session(&caller, request).await
    }
    .await;
    answer(result, protobuf)
}

/// `POST /v1/calibration/import`: an `ImportCalibrationRequest` (JSON or protobuf), or a
/// multipart upload as curl sends files (parts `format`, and `file` or `file1` `file2` `file3`)
/// → the `Calibration`.
async fn import_calibration(
    State(service): State<Arc<Service>>,
    _: Caller,
    format: BodyFormat,
    request: axum::extract::Request,
) -> Response {
    let protobuf = format == BodyFormat::Protobuf;
    let max_bytes = service.limits().max_message_bytes;
    let result = async {
        type Read = Box<dyn FnOnce() -> Result<pb::ImportCalibrationRequest, InputError> + Send>;
        let read: Read = if format == BodyFormat::Multipart {
            let parts = Multipart::from_request(request, &())
                .await
                .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))?;
            let request = calibration_files_upload(parts, max_bytes).await?;
            Box::new(move || Ok(request))
        } else {
            let body = read_body(request, max_bytes).await?;
            Box::new(move || decode_body(&body, protobuf))
        };
        service.import_calibration(read).await
    }
    .await;
    answer(result, protobuf)
}

/// The parts of a calibration import upload: `format`, then `file` or `file1..3` in order.
async fn calibration_files_upload(
    mut parts: Multipart,
    max_bytes: usize,
) -> Result<pb::ImportCalibrationRequest, ServiceError> {
    let bad = |field: &str, message: &str| ServiceError::Input(InputError::new(field, message));
    let mut request = pb::ImportCalibrationRequest::default();
    let mut numbered: [Option<String>; 3] = Default::default();
    while let Some(field) = parts
        .next_field()
        .await
        .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))?
    {
        let name = field.name().unwrap_or_default().to_string();
        let bytes = field
            .bytes()
            .await
            .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))?;
        let text =
            String::from_utf8(bytes.to_vec()).map_err(|_| bad(&name, "is not UTF-8 text"))?;
        match name.as_str() {
            "format" => request.format = text.trim().to_string(),
            "file" => request.files.push(text),
            "file1" | "file2" | "file3" => {
                numbered[usize::from(name.as_bytes()[4] - b'1')] = Some(text)
            }
            other => {
                return Err(bad(
                    other,
                    "unknown part (expected format, and file or file1, file2, file3)",
                ))
            }
        }
    }
    request.files.extend(numbered.into_iter().flatten());
    Ok(request)
}

/// `POST /v1/calibration/export`: an `ExportCalibrationRequest` → the files' text.
async fn export_calibration(
    State(service): State<Arc<Service>>,
    _: Caller,
    format: BodyFormat,
    request: axum::extract::Request,
) -> Response {
    let protobuf = format == BodyFormat::Protobuf;
    let max_bytes = service.limits().max_message_bytes;
    let result = async {
        let body = read_body(request, max_bytes).await?;
        service
            .export_calibration(move || decode_body(&body, protobuf))
            .await
    }
    .await;
    answer(result, protobuf)
}

async fn list_sessions(
    State(service): State<Arc<Service>>,
    caller: Caller,
    params: Result<Query<ListQuery>, QueryRejection>,
    answer_format: AnswerFormat,
) -> Response {
    let result = async {
        let request = query(params)?.request()?;
        service.list_sessions(&caller, request).await
    }
    .await;
    answer(result, answer_format.protobuf)
}

async fn get_session(
    State(service): State<Arc<Service>>,
    caller: Caller,
    SessionId(id): SessionId,
    answer_format: AnswerFormat,
) -> Response {
    answer(
        service.get_session(&caller, &id).await,
        answer_format.protobuf,
    )
}

async fn delete_session(
    State(service): State<Arc<Service>>,
    caller: Caller,
    SessionId(id): SessionId,
    answer_format: AnswerFormat,
) -> Response {
    let result = service.delete_session(&caller, &id).await;
    answer(
        result.map(|()| pb::DeleteSessionResponse {}),
        answer_format.protobuf,
    )
}

async fn add_capture(
    State(service): State<Arc<Service>>,
    caller: Caller,
    SessionId(id): SessionId,
    params: Result<Query<TimeoutQuery>, QueryRejection>,
    format: BodyFormat,
    request: axum::extract::Request,
) -> Response {
    let protobuf = format == BodyFormat::Protobuf;
    let multipart = format == BodyFormat::Multipart;
    let max_bytes = service.limits().max_message_bytes;
    let result = async {
        let timeout = query(params)?.timeout()?;
        let mut capture = if multipart {
            let parts = Multipart::from_request(request, &())
                .await
                .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))?;
            let upload = Upload::read(parts, max_bytes).await?;
            upload.capture()?
        } else {
            let body = read_body(request, max_bytes).await?;
            // Parsing a large body is CPU work: on the compute pool.
            service
                .pool()
                .run(move |_| decode_body::<pb::AddCaptureRequest>(&body, protobuf))
                .await??
        };
        if !capture.session_id.is_empty() && capture.session_id != id {
            return Err(ServiceError::Input(InputError::new(
                "session_id",
                format!(
                    "{:?} differs from the session of the URL, {id:?}",
                    capture.session_id
                ),
            )));
        }
        capture.session_id = id;
        service.add_capture(&caller, capture, timeout).await
    }
    .await;
    answer(result, protobuf)
}

async fn get_map(
    State(service): State<Arc<Service>>,
    caller: Caller,
    SessionId(id): SessionId,
    params: Result<Query<MapQuery>, QueryRejection>,
    answer_format: AnswerFormat,
) -> Response {
    let result = async {
        let params = query(params)?;
        let min_observations = params.min_observations()?;
        let format = params.format()?;
        let map = service.get_map(&caller, &id, min_observations).await?;
        // Drawing and writing a large map is CPU work too.
        service
            .pool()
            .run(move |_| map_export(&map, format, answer_format.protobuf))
            .await?
    }
    .await;
    result.unwrap_or_else(|e| error_response(&e))
}

/// A fused map in `format`.
fn map_export(
    map: &SessionMap,
    format: MapFormat,
    protobuf: bool,
) -> Result<Response, ServiceError> {
    use trinocular_core::map::export;
    let file = |content_type: &'static str, ext: &str, body: Vec<u8>| {
        let disposition = format!("inline; filename=\"map-{}.{ext}\"", map.session_id);
        let mut response = ([(header::CONTENT_TYPE, content_type)], body).into_response();
        if let Ok(v) = header::HeaderValue::from_str(&disposition) {
            response
                .headers_mut()
                .insert(header::CONTENT_DISPOSITION, v);
        }
        response
    };
    Ok(match format {
        MapFormat::Json => encoded(&map_to_pb(map), protobuf),
        MapFormat::Ply => file(
            "application/x-ply",
            "ply",
            export::to_ply(&map.segments).into_bytes(),
        ),
        MapFormat::Obj => file(
            "model/obj",
            "obj",
            export::to_obj(&map.segments).into_bytes(),
        ),
        MapFormat::Svg => file(
            "image/svg+xml",
            "svg",
            export::top_view_svg(&map.segments, &map.poses, &map.prior_poses, &map.rig)
                .into_bytes(),
        ),
        MapFormat::Png => file(
            "image/png",
            "png",
            export::top_view_png(&map.segments, &map.poses, &map.prior_poses, &map.rig).map_err(
                |e| ServiceError::Internal {
                    detail: format!("cannot encode the map's PNG: {e}"),
                },
            )?,
        ),
    })
}

/// The parts of a `multipart/form-data` upload, for curl: `calibration` and `options` (JSON,
/// for `/v1/match`), `pose` (JSON, for captures: a `Pose` or its 16 numbers) and
/// `pose_covariance` (its 36 numbers, row-major 6x6, optional) and `capture_id` (text, the
/// capture's name, optional), `pattern`,
/// `options` and `pattern_to_rig` (JSON, for `/v1/calibrate`), and either `segments` (a
/// `SegmentTriplet`, JSON) or `image1`, `image2`, `image3` (image files).
#[derive(Default)]
struct Upload {
    calibration: Option<pb::Calibration>,
    /// Read when it is known which options these are.
    options: Option<String>,
    pattern: Option<pb::CalibrationPattern>,
    pattern_to_rig: Option<pb::Pose>,
    pose: Option<pb::Pose>,
    pose_covariance: Option<Vec<f64>>,
    capture_id: Option<String>,
    segments: Option<pb::SegmentTriplet>,
    images: [Option<Vec<u8>>; 3],
}

impl Upload {
    async fn read(mut parts: Multipart, max_bytes: usize) -> Result<Upload, ServiceError> {
        let bad =
            |field: &str, message: String| ServiceError::Input(InputError::new(field, message));
        let text = |field: &str, bytes: &[u8]| -> Result<String, ServiceError> {
            String::from_utf8(bytes.to_vec()).map_err(|_| bad(field, "is not UTF-8 JSON".into()))
        };
        let mut upload = Upload::default();
        let mut seen: Vec<String> = Vec::new();
        loop {
            let field = match parts.next_field().await {
                Ok(Some(field)) => field,
                Ok(None) => break,
                Err(e) => return Err(body_error(&e, e.status(), e.body_text(), max_bytes)),
            };
            let Some(name) = field.name().map(str::to_string) else {
                return Err(bad(
                    "part",
                    "a part has no name (Content-Disposition: form-data; name=\"...\")".into(),
                ));
            };
            // One value per part: a second would silently replace the first.
            let part = if name == LEGACY_PATTERN_TO_RIG {
                "pattern_to_rig"
            } else {
                name.as_str()
            };
            if seen.iter().any(|s| s == part) {
                return Err(bad(&name, "given twice: send each part once".into()));
            }
            seen.push(part.to_string());
            let bytes = field
                .bytes()
                .await
                .map_err(|e| body_error(&e, e.status(), e.body_text(), max_bytes))?;
            match name.as_str() {
                "calibration" => {
                    upload.calibration = Some(from_json("calibration", &text(&name, &bytes)?)?)
                }
                "options" => upload.options = Some(text(&name, &bytes)?),
                "pattern" => upload.pattern = Some(from_json("pattern", &text(&name, &bytes)?)?),
                // The part's name before the schema named frames source_to_target.
                "pattern_to_rig" | LEGACY_PATTERN_TO_RIG => {
                    upload.pattern_to_rig = Some(pose_part(&name, &text(&name, &bytes)?)?)
                }
                "segments" => upload.segments = Some(from_json("segments", &text(&name, &bytes)?)?),
                "pose" => upload.pose = Some(pose_part(&name, &text(&name, &bytes)?)?),
                "pose_covariance" => {
                    upload.pose_covariance = Some(
                        serde_json::from_str::<Vec<f64>>(&text(&name, &bytes)?)
                            .map_err(|e| bad(&name, format!("invalid JSON (36 numbers): {e}")))?,
                    )
                }
                "capture_id" => {
                    upload.capture_id = Some(
                        String::from_utf8(bytes.to_vec())
                            .map_err(|_| bad(&name, "is not UTF-8 text".into()))?,
                    )
                }
                "image1" | "image2" | "image3" => {
                    let i = usize::from(name.as_bytes()[5] - b'1');
                    upload.images[i] = Some(bytes.to_vec());
                }
                other => {
                    return Err(bad(
                        other,
                        "unknown part: expected calibration, options, pose, pose_covariance, \
                         capture_id, pattern, pattern_to_rig, segments or image1..image3"
                            .into(),
                    ))
                }
            }
        }
        Ok(upload)
    }

    fn given(&self, part: &str) -> bool {
        match part {
            "calibration" => self.calibration.is_some(),
            "options" => self.options.is_some(),
            "pose" => self.pose.is_some(),
            "pose_covariance" => self.pose_covariance.is_some(),
            "capture_id" => self.capture_id.is_some(),
            "pattern" => self.pattern.is_some(),
            "pattern_to_rig" => self.pattern_to_rig.is_some(),
            "segments" => self.segments.is_some(),
            _ => false,
        }
    }

    /// An error naming the first of `parts` that was uploaded (they do not belong here).
    fn refuse(&self, parts: &[&str], why: &str) -> Result<(), ServiceError> {
        match parts.iter().find(|p| self.given(p)) {
            Some(part) => Err(ServiceError::Input(InputError::new(*part, why))),
            None => Ok(()),
        }
    }

    /// The `options` part, read as the options of the call at hand (match or calibrate).
    fn options<T: serde::de::DeserializeOwned>(&mut self) -> Result<Option<T>, ServiceError> {
        match self.options.take() {
            Some(text) => Ok(Some(from_json("options", &text)?)),
            None => Ok(None),
        }
    }

    /// The input: segments, or the three images.
    fn input(self) -> Result<Input, ServiceError> {
        let bad =
            |field: &str, message: String| ServiceError::Input(InputError::new(field, message));
        let given = self.images.iter().filter(|i| i.is_some()).count();
        match (self.segments, given) {
            (Some(s), 0) => Ok(Input::Segments(s)),
            (None, 3) => Ok(Input::Images(pb::ImageTriplet {
                images: self
                    .images
                    .into_iter()
                    .map(|bytes| pb::Image {
                        source: bytes.map(pb::image::Source::Encoded),
                    })
                    .collect(),
            })),
            (Some(_), _) => Err(bad("segments", "give segments or images, not both".into())),
            (None, n) => Err(bad(
                "images",
                format!("needs the three parts image1, image2, image3 (or segments), got {n}"),
            )),
        }
    }

    /// The upload as a `MatchRequest`.
    fn match_request(mut self) -> Result<pb::MatchRequest, ServiceError> {
        self.refuse(
            &["pose", "pose_covariance", "capture_id"],
            "a match has no pose or capture id (captures of a session do)",
        )?;
        self.refuse(
            &["pattern", "pattern_to_rig"],
            "a match has no pattern (calibrations do)",
        )?;
        let calibration = self.calibration.take();
        let options = self.options()?;
        let input = match self.input()? {
            Input::Segments(s) => pb::match_request::Input::Segments(s),
            Input::Images(i) => pb::match_request::Input::Images(i),
        };
        Ok(pb::MatchRequest {
            calibration,
            options,
            input: Some(input),
        })
    }

    /// The upload as an `AddCaptureRequest` (its session from the URL).
    fn capture(mut self) -> Result<pb::AddCaptureRequest, ServiceError> {
        self.refuse(
            &["calibration", "options"],
            "a session's captures use the calibration and options given when it was created",
        )?;
        let rig_to_world = self.pose.take();
        let rig_to_world_covariance = self.pose_covariance.take().unwrap_or_default();
        let capture_id = self.capture_id.take().unwrap_or_default();
        let input = match self.input()? {
            Input::Segments(s) => pb::add_capture_request::Input::Segments(s),
            Input::Images(i) => pb::add_capture_request::Input::Images(i),
        };
        Ok(pb::AddCaptureRequest {
            session_id: String::new(),
            rig_to_world,
            input: Some(input),
            rig_to_world_covariance,
            capture_id,
        })
    }
}

/// A pose part: a `Pose` in JSON, or its 16 numbers as a bare list (the easy thing to type).
fn pose_part(name: &str, text: &str) -> Result<pb::Pose, ServiceError> {
    if text.trim_start().starts_with('[') {
        // 16 numbers, or a nested 4x4 (four rows of four).
        let flat = serde_json::from_str::<Vec<f64>>(text)
            .or_else(|_| serde_json::from_str::<Vec<Vec<f64>>>(text).map(|rows| rows.concat()));
        flat.map(|matrix| pb::Pose {
            matrix,
            ..pb::Pose::default()
        })
        .map_err(|e| {
            ServiceError::Input(InputError::new(
                name,
                format!("invalid JSON (16 numbers, or four rows of four): {e}"),
            ))
        })
    } else {
        Ok(from_json(name, text)?)
    }
}

impl Upload {
    /// The upload as a `CalibrateRequest`: parts `pattern` (optional: the default pattern),
    /// `options`, `pattern_to_rig`, and the three images.
    fn calibrate_request(mut self) -> Result<pb::CalibrateRequest, ServiceError> {
        self.refuse(
            &[
                "calibration",
                "pose",
                "pose_covariance",
                "capture_id",
                "segments",
            ],
            "a calibration takes pattern, options, pattern_to_rig and image1..image3",
        )?;
        let options = self.options()?;
        let (pattern, pattern_to_rig) = (self.pattern.take(), self.pattern_to_rig.take());
        let images = match self.input()? {
            Input::Images(i) => i,
            Input::Segments(_) => unreachable!("segments were refused above"),
        };
        Ok(pb::CalibrateRequest {
            pattern,
            input: Some(pb::calibrate_request::Input::Images(images)),
            pattern_to_rig,
            options,
            camera_names: Vec::new(),
        })
    }
}

/// What an upload matches.
enum Input {
    Segments(pb::SegmentTriplet),
    Images(pb::ImageTriplet),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(header::HeaderName, &str)]) -> HeaderMap {
        pairs
            .iter()
            .map(|(k, v)| (k.clone(), v.parse().unwrap()))
            .collect()
    }

    #[test]
    fn the_formats_come_from_content_type_and_accept() {
        let protobuf = headers(&[(header::CONTENT_TYPE, PROTOBUF)]);
        let upload = headers(&[(header::CONTENT_TYPE, "multipart/form-data; boundary=x")]);
        let json = headers(&[(header::CONTENT_TYPE, "application/json")]);
        assert_eq!(BodyFormat::of(&protobuf), BodyFormat::Protobuf);
        assert_eq!(BodyFormat::of(&upload), BodyFormat::Multipart);
        assert_eq!(BodyFormat::of(&json), BodyFormat::Json);
        assert_eq!(BodyFormat::of(&HeaderMap::new()), BodyFormat::Json);
        assert!(AnswerFormat::of(&protobuf).protobuf, "answered as asked");
        assert!(
            !AnswerFormat::of(&upload).protobuf,
            "an upload is answered in JSON"
        );
        assert!(AnswerFormat::of(&headers(&[(header::ACCEPT, PROTOBUF)])).protobuf);
        assert!(!AnswerFormat::of(&HeaderMap::new()).protobuf);
    }

    /// A service with one key, `robot`'s.
    fn keyed_service() -> Arc<Service> {
        use crate::service::{auth::ApiKeys, store::memory::MemoryStore, Limits};
        let keys = ApiKeys::parse(Some("robot 0123456789abcdef0123"), None).unwrap();
        let store = Arc::new(MemoryStore::new(Duration::from_secs(60)));
        let limits = Limits {
            threads: 1,
            max_jobs: 1,
            ..Limits::default()
        };
        let service = Service::new(limits, store, Duration::from_secs(60)).unwrap();
        Arc::new(service.with_api_keys(keys, 10))
    }

    fn parts(authorization: Option<&str>) -> Parts {
        let mut request = axum::http::Request::builder();
        if let Some(value) = authorization {
            request = request.header(header::AUTHORIZATION, value);
        }
        request.body(()).unwrap().into_parts().0
    }

    #[tokio::test]
    async fn the_caller_comes_from_a_bearer_key_and_a_bad_key_is_refused_as_before() {
        let service = keyed_service();
        let mut given = parts(Some("Bearer 0123456789abcdef0123"));
        let caller = Caller::from_request_parts(&mut given, &service)
            .await
            .unwrap();
        assert_eq!(caller.tenant.as_deref(), Some("robot"));
        // Kept for the handler's extraction, which then reads no header.
        given.headers.clear();
        let again = Caller::from_request_parts(&mut given, &service)
            .await
            .unwrap();
        assert_eq!(again, caller);

        for (authorization, message) in [
            (
                None,
                "an API key is required: send 'authorization: Bearer <key>'",
            ),
            (
                Some("Bearer not-a-key-not-a-key"),
                "the API key is not valid",
            ),
        ] {
            let rejected = Caller::from_request_parts(&mut parts(authorization), &service)
                .await
                .unwrap_err()
                .into_response();
            assert_eq!(rejected.status(), StatusCode::UNAUTHORIZED);
            assert_eq!(rejected.headers()[header::WWW_AUTHENTICATE], "Bearer");
            assert_eq!(rejected.headers()[header::CONTENT_TYPE], JSON);
            let body = axum::body::to_bytes(rejected.into_body(), 1 << 16)
                .await
                .unwrap();
            assert_eq!(
                std::str::from_utf8(&body).unwrap(),
                format!(
                    "{{\"error\":{{\"code\":\"UNAUTHENTICATED\",\"message\":\"{message}\"}}}}\n"
                )
            );
        }
    }

    #[test]
    fn map_formats_parse_by_their_query_names() {
        for (name, format) in MapFormat::ALL {
            assert_eq!(name.parse::<MapFormat>().unwrap(), format);
        }
        let e = "dxf".parse::<MapFormat>().unwrap_err();
        assert_eq!(e.field, "format");
        assert!(
            e.message.contains("\"dxf\"") && e.message.contains("json, ply, obj, svg or png"),
            "{e}"
        );
        for (name, _) in MapFormat::ALL {
            assert!(e.message.contains(name), "{e} should list {name}");
        }
        // Exactly as written: the query values are lower case.
        assert!("PNG".parse::<MapFormat>().is_err());
        assert_eq!(MapQuery::default().format().unwrap(), MapFormat::Json);
    }

    #[test]
    fn a_bad_query_value_names_its_parameter() {
        let parsed = |uri: &str| {
            let uri: axum::http::Uri = uri.parse().unwrap();
            query(Query::<MapQuery>::try_from_uri(&uri))
        };
        let q = parsed("/v1/sessions/x/map?min_observations=3&format=svg").unwrap();
        assert_eq!(q.min_observations().unwrap(), Some(3));
        assert_eq!(q.format().unwrap(), MapFormat::Svg);
        for bad in ["0", "-1", "many", ""] {
            let e = parsed(&format!("/m?min_observations={bad}"))
                .unwrap()
                .min_observations()
                .unwrap_err();
            assert_eq!(e.field, "min_observations", "{bad:?}");
            assert!(e.message.contains(&format!("{bad:?}")), "{e}");
        }
        let e = TimeoutQuery {
            timeout_ms: Some("soon".into()),
        }
        .timeout()
        .unwrap_err();
        assert_eq!(e.field, "timeout_ms");
        // A repeated parameter is refused in our format, naming the query.
        let e = parsed("/m?format=ply&format=obj").err().unwrap();
        assert_eq!(e.field, "query");
        assert!(e.message.contains("format"), "{e}");
        // A parameter the call does not take is named, not ignored: a misspelt deadline would
        // otherwise run the call without it.
        let e = parsed("/m?format=svg&min_observation=2").err().unwrap();
        assert_eq!(e.field, "min_observation");
        assert_eq!(
            e.message,
            "this call takes no such query parameter (expected `format` or `min_observations`)"
        );
        let uri: axum::http::Uri = "/v1/match?timout_ms=5".parse().unwrap();
        let e = query(Query::<MatchQuery>::try_from_uri(&uri))
            .err()
            .unwrap();
        assert_eq!(e.field, "timout_ms");
        let uri: axum::http::Uri = "/v1/sessions?page_size=2&page_token=".parse().unwrap();
        assert!(query(Query::<ListQuery>::try_from_uri(&uri)).is_ok());
    }

    /// The routes the router serves, read from the sources that declare them (each `route`
    /// call with its path and method handlers, in this file and `ui.rs`), as (method, OpenAPI
    /// path) pairs.
    fn declared_routes() -> Vec<(String, String)> {
        let mut out = Vec::new();
        for source in [include_str!("http.rs"), include_str!("ui.rs")] {
            for (at, _) in source.match_indices(".route(") {
                let rest = source[at + 7..].trim_start();
                let Some(rest) = rest.strip_prefix('"') else {
                    continue;
                };
                let path = &rest[..rest.find('"').unwrap()];
                // The call's text up to its closing parenthesis at depth zero.
                let mut depth = 1;
                let call: String = rest
                    .chars()
                    .take_while(|&c| {
                        depth += i32::from(c == '(') - i32::from(c == ')');
                        depth > 0
                    })
                    .collect();
                let path = path.replace("{*path}", "{path}");
                for method in ["get", "post", "delete", "put", "patch"] {
                    let called = [
                        format!(" {method}("),
                        format!(".{method}("),
                        format!("({method}("),
                    ];
                    if called.iter().any(|c| call.contains(c.as_str())) {
                        out.push((method.to_string(), path.clone()));
                    }
                }
            }
        }
        out.sort();
        out.dedup();
        out
    }

    #[test]
    fn the_openapi_document_lists_every_route_and_no_other() {
        let doc: serde_json::Value = serde_json::from_str(OPENAPI).expect("JSON");
        assert!(doc["openapi"].as_str().unwrap().starts_with("3."));
        let mut documented: Vec<(String, String)> = doc["paths"]
            .as_object()
            .unwrap()
            .iter()
            .flat_map(|(path, item)| {
                item.as_object()
                    .unwrap()
                    .keys()
                    .filter(|k| ["get", "post", "delete", "put", "patch"].contains(&k.as_str()))
                    .map(move |m| (m.clone(), path.clone()))
            })
            .collect();
        documented.sort();
        let declared = declared_routes();
        assert!(
            declared.len() >= 15,
            "the scan found the routes: {declared:?}"
        );
        assert_eq!(documented, declared, "OpenAPI paths vs the router's routes");
    }

    #[tokio::test]
    async fn every_documented_route_is_served() {
        use tower::ServiceExt;
        let app = router(Service::in_memory(Default::default()));
        for (method, path) in declared_routes() {
            let uri = path
                .replace("{id}", "0123456789abcdef0123456789abcdef")
                .replace("{path}", "style.css");
            let request = axum::extract::Request::builder()
                .method(method.to_uppercase().as_str())
                .uri(&uri)
                .header(header::CONTENT_TYPE, JSON)
                .body(axum::body::Body::from("{}"))
                .unwrap();
            let response = app.clone().oneshot(request).await.unwrap();
            let status = response.status();
            // A documented route may refuse the empty request or the unknown session, but
            // never as a route that does not exist or a method it does not serve.
            assert_ne!(status, StatusCode::METHOD_NOT_ALLOWED, "{method} {uri}");
            if status == StatusCode::NOT_FOUND {
                let body = axum::body::to_bytes(response.into_body(), 1 << 20)
                    .await
                    .unwrap();
                let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
                assert_ne!(
                    body["error"]["field"], "path",
                    "{method} {uri} is not routed"
                );
            }
        }
    }
}
