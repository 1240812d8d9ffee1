//! What both transports put around every request, built in one place so that they cannot
//! differ: its id and its span, from tower-http's layers, and its observation: one log line,
//! one count and one latency sample in the metrics, by transport, route and code.
//!
//! Request ids: the client's `x-request-id` when it is 1 to 128 printable ASCII characters,
//! otherwise a new one (`<process start, hex>-<counter>`: unique across restarts with no
//! random source). tower-http's `SetRequestIdLayer` keeps whatever id a request carries, so an
//! unacceptable one is removed first and a new one made in its place. `PropagateRequestIdLayer`
//! echoes the id in the answer's headers, which for gRPC are its response metadata, an error's
//! included (tonic sends a failed call's status in the headers of a trailers-only answer). The
//! request's span, tower-http's `TraceLayer`, carries the id, so every log line of the request
//! names it and a client quoting the id of a bad answer finds it in the logs.
//!
//! The observation ([`ObserveLayer`]) is the only place a request is logged and counted; the
//! use cases take no transport name and record only what they alone know, a Match's stage
//! times. It knows its transport, reads the route from the request head by the transport's
//! table (requests off the API, probes, metrics, gRPC health and reflection, are not
//! observed), times the request on the service's clock (so a test's `ManualClock` decides the
//! latency), and reads the outcome from the answer: the [`ServiceError`] it carries (the HTTP
//! error response's extension, the gRPC status's source, both set by the one error mapping),
//! else its code (tonic's own refusals, an HTTP status axum made). An overload refusal is
//! logged at debug, everything else at info, an internal error's detail at error.
//!
//! ```text
//! request ─▶ drop an unacceptable id ─▶ SetRequestId ─▶ PropagateRequestId ─▶ Trace (span)
//!         ─▶ Observe (log line, metrics) ─▶ the transport's routes
//! ```
//!
//! A request whose future is dropped before it is answered (the client went away, or tonic's
//! call timeout cut it) is not observed: it has no answer to read a code from.

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::task::{Context, Poll};
use std::time::{SystemTime, UNIX_EPOCH};

use axum::http::request::Parts;
use axum::http::{HeaderName, HeaderValue, Request, Response};
use tonic::Code;
use tower::util::MapRequestLayer;
use tower::ServiceBuilder;
use tower_http::classify::{GrpcErrorsAsFailures, ServerErrorsAsFailures, SharedClassifier};
use tower_http::request_id::{
    MakeRequestId, PropagateRequestIdLayer, RequestId, SetRequestIdLayer,
};
use tower_http::trace::TraceLayer;
use tower_layer::{Identity, Stack};
use tracing::Span;

use crate::service::error::code_of_http_status;
use crate::service::{Service, ServiceError};

/// The header (and gRPC metadata key) of request ids.
pub const REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");
/// Longest client id kept, bytes.
const MAX_ID_LEN: usize = 128;

/// Whether a client's id is kept: 1 to [`MAX_ID_LEN`] printable ASCII characters, so that it
/// can go into a log line as it is.
pub fn acceptable(id: &HeaderValue) -> bool {
    let bytes = id.as_bytes();
    !bytes.is_empty() && bytes.len() <= MAX_ID_LEN && bytes.iter().all(u8::is_ascii_graphic)
}

/// The request without its `x-request-id` if that is not [`acceptable`]: `SetRequestIdLayer`
/// then gives it a new one.
fn without_unacceptable_id<B>(mut request: Request<B>) -> Request<B> {
    if request
        .headers()
        .get(&REQUEST_ID)
        .is_some_and(|id| !acceptable(id))
    {
        request.headers_mut().remove(&REQUEST_ID);
    }
    request
}

/// A new id: `<process start, hex>-<counter>`.
pub fn new_id() -> String {
    static START: OnceLock<u64> = OnceLock::new();
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let start = START.get_or_init(|| {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64)
    });
    format!("{start:x}-{}", COUNTER.fetch_add(1, Ordering::Relaxed))
}

/// What `SetRequestIdLayer` asks for an id when the request brings none.
#[derive(Debug, Clone, Copy, Default)]
pub struct NewRequestId;

impl MakeRequestId for NewRequestId {
    fn make_request_id<B>(&mut self, _: &Request<B>) -> Option<RequestId> {
        // Hex digits, '-' and digits: always a valid header value.
        HeaderValue::from_str(&new_id()).ok().map(RequestId::new)
    }
}

/// The request's id, once `SetRequestIdLayer` has run.
fn id_of<B>(request: &Request<B>) -> &str {
    request
        .headers()
        .get(&REQUEST_ID)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
}

/// The span of an HTTP request: its id and path.
fn http_span<B>(request: &Request<B>) -> Span {
    tracing::info_span!("http", request_id = %id_of(request), path = %request.uri().path())
}

/// The span of a gRPC call: its id and method (`/trinocular.v1.Trinocular/Match`: `Match`).
fn grpc_span<B>(request: &Request<B>) -> Span {
    let rpc = request.uri().path().rsplit('/').next().unwrap_or_default();
    tracing::info_span!("grpc", request_id = %id_of(request), rpc)
}

/// tower-http's trace layer making only the span: the observation of each request is the one
/// log line [`ObserveLayer`] writes, so its default lines (on request, on response, and on
/// failure, at ERROR for every gRPC error and 5xx) stay off.
type Trace<B, M> = TraceLayer<M, fn(&Request<B>) -> Span, (), (), (), (), ()>;

/// The layers of one transport whose request bodies are `B`, outermost first (a
/// `ServiceBuilder` applies its first layer outermost).
pub type Layers<B, M> = Stack<
    ObserveLayer,
    Stack<
        Trace<B, M>,
        Stack<
            PropagateRequestIdLayer,
            Stack<
                SetRequestIdLayer<NewRequestId>,
                Stack<MapRequestLayer<fn(Request<B>) -> Request<B>>, Identity>,
            >,
        >,
    >,
>;

fn layers<B, M>(
    trace: TraceLayer<M>,
    span: fn(&Request<B>) -> Span,
    observe: ObserveLayer,
) -> ServiceBuilder<Layers<B, M>> {
    ServiceBuilder::new()
        .map_request(without_unacceptable_id::<B> as fn(Request<B>) -> Request<B>)
        .layer(SetRequestIdLayer::new(REQUEST_ID, NewRequestId))
        .layer(PropagateRequestIdLayer::new(REQUEST_ID))
        .layer(
            trace
                .make_span_with(span)
                .on_request(())
                .on_response(())
                .on_body_chunk(())
                .on_eos(())
                .on_failure(()),
        )
        .layer(observe)
}

/// The HTTP server's layers (axum's router), observing the routes `route_of` names.
pub fn http(
    service: Arc<Service>,
    route_of: RouteOf,
) -> ServiceBuilder<Layers<axum::body::Body, SharedClassifier<ServerErrorsAsFailures>>> {
    let observe = ObserveLayer::new(Transport::Http, route_of, service);
    layers(TraceLayer::new_for_http(), http_span, observe)
}

/// The gRPC server's layers (tonic's `Server::builder().layer`), observing the calls
/// `route_of` names.
pub fn grpc(
    service: Arc<Service>,
    route_of: RouteOf,
) -> ServiceBuilder<Layers<tonic::body::Body, SharedClassifier<GrpcErrorsAsFailures>>> {
    let observe = ObserveLayer::new(Transport::Grpc, route_of, service);
    layers(TraceLayer::new_for_grpc(), grpc_span, observe)
}

/// The transport a request came by: the `transport` label of the metrics and logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transport {
    Http,
    Grpc,
}

impl Transport {
    pub fn name(self) -> &'static str {
        match self {
            Transport::Http => "http",
            Transport::Grpc => "grpc",
        }
    }
}

/// A request's route in the metrics and logs (`match`, `create_session` …), read from its
/// head by the transport's own table; `None`: not observed (probes, metrics, gRPC health and
/// reflection, unknown paths).
pub type RouteOf = fn(&Parts) -> Option<&'static str>;

/// What a Match answer put in its response's extensions for the log line: a layer cannot
/// read the encoded body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Matched {
    pub segments_3d: usize,
}

/// Observes each request of one transport: see the module doc.
#[derive(Clone)]
pub struct ObserveLayer {
    transport: Transport,
    route_of: RouteOf,
    service: Arc<Service>,
}

impl ObserveLayer {
    pub fn new(transport: Transport, route_of: RouteOf, service: Arc<Service>) -> ObserveLayer {
        ObserveLayer {
            transport,
            route_of,
            service,
        }
    }
}

impl<S> tower_layer::Layer<S> for ObserveLayer {
    type Service = Observe<S>;

    fn layer(&self, inner: S) -> Observe<S> {
        Observe {
            inner,
            layer: self.clone(),
        }
    }
}

/// The service [`ObserveLayer`] makes.
#[derive(Clone)]
pub struct Observe<S> {
    inner: S,
    layer: ObserveLayer,
}

impl<S, B, ResBody> tower_service::Service<Request<B>> for Observe<S>
where
    S: tower_service::Service<Request<B>, Response = Response<ResBody>>,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = Pin<Box<dyn Future<Output = Result<S::Response, S::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: Request<B>) -> Self::Future {
        let (parts, body) = request.into_parts();
        let Some(route) = (self.layer.route_of)(&parts) else {
            return Box::pin(self.inner.call(Request::from_parts(parts, body)));
        };
        let (transport, service) = (self.layer.transport, Arc::clone(&self.layer.service));
        let start = service.clock().monotonic();
        let answer = self.inner.call(Request::from_parts(parts, body));
        Box::pin(async move {
            let answer = answer.await;
            if let Ok(response) = &answer {
                let seconds = service.clock().since(start).as_secs_f64();
                let outcome = Outcome::of(response);
                outcome.log(transport, route, seconds);
                service
                    .metrics()
                    .record_request(transport.name(), route, outcome.code, seconds);
            }
            answer
        })
    }
}

/// How a request ended, read from its answer.
struct Outcome<'a> {
    code: Code,
    /// The service's error, when the answer carries it: an HTTP error response's extension
    /// ([`crate::http::error_response`]), a gRPC status's source ([`crate::grpc::status`]), or
    /// the extension the gRPC body budget adds to the call it refused.
    error: Option<&'a ServiceError>,
    /// An error's message when the service's error is not there (tonic's own refusals: a
    /// message that does not decode, or past the size limit).
    message: Option<&'a str>,
    matched: Option<Matched>,
}

impl<'a> Outcome<'a> {
    fn of<B>(response: &'a Response<B>) -> Outcome<'a> {
        let extensions = response.extensions();
        let matched = extensions.get::<Matched>().copied();
        let status = extensions.get::<tonic::Status>();
        let error = extensions.get::<ServiceError>().or_else(|| {
            status
                .and_then(std::error::Error::source)
                .and_then(|source| source.downcast_ref::<ServiceError>())
        });
        let (code, message) = match (error, status) {
            (Some(e), _) => (e.code(), None),
            (None, Some(status)) => (status.code(), Some(status.message())),
            // A gRPC answer has its status in its headers when it fails at once; otherwise in
            // its trailers, after the body: OK for a unary call that has its answer.
            (None, None) => match response.headers().get("grpc-status") {
                Some(code) => (Code::from_bytes(code.as_bytes()), None),
                None => (code_of_http_status(response.status()), None),
            },
        };
        Outcome {
            code,
            error,
            message,
            matched,
        }
    }

    /// The request's one log line, in its span: at debug for an overload refusal, else info.
    fn log(&self, transport: Transport, route: &'static str, seconds: f64) {
        let transport = transport.name();
        let (code, ms) = (self.code, seconds * 1e3);
        let kind = match route {
            "match" => "match",
            "calibrate" | "import_calibration" | "export_calibration" => "calibrate",
            _ => "session",
        };
        match (self.error, self.message, self.matched) {
            (Some(e), _, _) if e.is_overload() => {
                tracing::debug!(transport, route, code = ?code, error = %e, "{kind} refused");
            }
            (Some(e), _, _) => {
                if let ServiceError::Internal { detail } = e {
                    tracing::error!(detail = %detail, route, "internal error");
                }
                tracing::info!(transport, route, code = ?code, ms, error = %e, "{kind}");
            }
            (None, Some(message), _) => {
                tracing::info!(transport, route, code = ?code, ms, error = %message, "{kind}");
            }
            (None, None, Some(matched)) => {
                let segments_3d = matched.segments_3d;
                tracing::info!(transport, route, code = ?code, ms, segments_3d, "{kind}");
            }
            (None, None, None) => tracing::info!(transport, route, code = ?code, ms, "{kind}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::clock::ManualClock;
    use std::time::Duration;

    fn with_id(id: &str) -> Request<()> {
        Request::builder().header(&REQUEST_ID, id).body(()).unwrap()
    }

    #[test]
    fn a_sane_client_id_is_kept_and_others_dropped() {
        let kept = without_unacceptable_id(with_id("robot-42"));
        assert_eq!(kept.headers()[&REQUEST_ID], "robot-42");
        for bad in ["", "with spaces", &"x".repeat(MAX_ID_LEN + 1)] {
            let dropped = without_unacceptable_id(with_id(bad));
            assert!(dropped.headers().get(&REQUEST_ID).is_none(), "{bad:?}");
        }
        let longest = "x".repeat(MAX_ID_LEN);
        assert!(without_unacceptable_id(with_id(&longest))
            .headers()
            .contains_key(&REQUEST_ID));
    }

    /// A service timing requests on `clock`.
    fn service_on(clock: Arc<ManualClock>) -> Arc<Service> {
        use crate::service::{store::memory::MemoryStore, Limits};
        let ttl = Duration::from_secs(60);
        let limits = Limits {
            threads: 1,
            max_jobs: 1,
            ..Limits::default()
        };
        let store = Arc::new(MemoryStore::new(ttl));
        Arc::new(Service::new(limits, store, ttl).unwrap().with_clock(clock))
    }

    /// Test routes: `/ok`, `/missing`, `/busy`, `/status`, `/trailers` are `get_session`,
    /// anything else is not observed.
    fn test_route(parts: &Parts) -> Option<&'static str> {
        matches!(
            parts.uri.path(),
            "/ok" | "/missing" | "/busy" | "/status" | "/trailers"
        )
        .then_some("get_session")
    }

    /// Answers each test route as a transport would, taking 250 ms of `clock`'s time.
    fn answer(path: &str) -> Response<()> {
        let missing = ServiceError::NotFound {
            field: "session_id".into(),
            what: "session \"x\"".into(),
        };
        let mut response = Response::new(());
        match path {
            // HTTP's error mapping: the error in the extensions.
            "/missing" => {
                response.extensions_mut().insert(missing);
            }
            "/busy" => {
                let busy = ServiceError::Busy { max_jobs: 1 };
                response.extensions_mut().insert(busy);
            }
            // gRPC's: the error as the status's source, which tonic keeps.
            "/status" => return crate::grpc::status(&missing).into_http(),
            // A gRPC failure the service did not make: only its header.
            "/trailers" => {
                response
                    .headers_mut()
                    .insert("grpc-status", HeaderValue::from_static("14"));
            }
            _ => {}
        }
        response
    }

    #[tokio::test]
    async fn each_request_is_counted_once_by_transport_route_and_code_on_the_clock() {
        use tower::ServiceExt;
        use tower_layer::Layer;
        let clock = Arc::new(ManualClock::new(1_700_000_000_000));
        let service = service_on(Arc::clone(&clock));
        for (transport, paths) in [
            (
                Transport::Http,
                &["/ok", "/missing", "/busy", "/healthz"][..],
            ),
            (Transport::Grpc, &["/ok", "/status", "/trailers"][..]),
        ] {
            let ticking = Arc::clone(&clock);
            let inner = tower::service_fn(move |request: Request<()>| {
                ticking.advance(Duration::from_millis(250));
                std::future::ready(Ok::<_, std::convert::Infallible>(answer(
                    request.uri().path(),
                )))
            });
            let observed =
                ObserveLayer::new(transport, test_route, Arc::clone(&service)).layer(inner);
            for path in paths {
                let request = Request::builder().uri(*path).body(()).unwrap();
                observed.clone().oneshot(request).await.unwrap();
            }
        }
        let text = service.metrics_text();
        let has = |line: &str| text.lines().any(|l| l == line);
        for line in [
            r#"trinocular_requests_total{code="OK",route="get_session",transport="http"} 1"#,
            r#"trinocular_requests_total{code="NOT_FOUND",route="get_session",transport="http"} 1"#,
            r#"trinocular_requests_total{code="RESOURCE_EXHAUSTED",route="get_session",transport="http"} 1"#,
            r#"trinocular_requests_total{code="OK",route="get_session",transport="grpc"} 1"#,
            r#"trinocular_requests_total{code="NOT_FOUND",route="get_session",transport="grpc"} 1"#,
            r#"trinocular_requests_total{code="UNAVAILABLE",route="get_session",transport="grpc"} 1"#,
            "trinocular_rejections_total 1",
            // Each request took exactly 250 ms of the manual clock: three of them per
            // transport, all in the 0.5 s bucket and none in the 0.2 s one.
            r#"trinocular_request_duration_seconds_sum{route="get_session",transport="http"} 0.75"#,
            r#"trinocular_request_duration_seconds_bucket{route="get_session",transport="http",le="0.2"} 0"#,
            r#"trinocular_request_duration_seconds_bucket{route="get_session",transport="http",le="0.5"} 3"#,
            r#"trinocular_request_duration_seconds_sum{route="get_session",transport="grpc"} 0.75"#,
        ] {
            assert!(has(line), "{line} missing from\n{text}");
        }
        // /healthz went through the layer but is not a route: not counted.
        let counted = text
            .lines()
            .filter(|l| l.starts_with("trinocular_requests_total{"))
            .count();
        assert_eq!(counted, 6, "{text}");
    }

    #[test]
    fn new_ids_differ_and_are_acceptable() {
        let (a, b) = (new_id(), new_id());
        assert_ne!(a, b);
        let made = NewRequestId
            .make_request_id(&Request::new(()))
            .expect("an id");
        assert!(acceptable(made.header_value()));
    }
}
