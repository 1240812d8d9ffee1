//! What both transports put around every request, built in one place so that they cannot
//! differ: its id and its span, from tower-http's layers.
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
//! ```text
//! request ─▶ drop an unacceptable id ─▶ SetRequestId ─▶ PropagateRequestId ─▶ Trace (span)
//!         ─▶ the transport's routes
//! ```

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{SystemTime, UNIX_EPOCH};

use axum::http::{HeaderName, HeaderValue, Request};
use tower::util::MapRequestLayer;
use tower::ServiceBuilder;
use tower_http::classify::{GrpcErrorsAsFailures, ServerErrorsAsFailures, SharedClassifier};
use tower_http::request_id::{
    MakeRequestId, PropagateRequestIdLayer, RequestId, SetRequestIdLayer,
};
use tower_http::trace::TraceLayer;
use tower_layer::{Identity, Stack};
use tracing::Span;

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
/// log line this module writes, so its default lines (on request, on response, and on
/// failure, at ERROR for every gRPC error and 5xx) stay off.
type Trace<B, M> = TraceLayer<M, fn(&Request<B>) -> Span, (), (), (), (), ()>;

/// The layers of one transport whose request bodies are `B`, outermost first (a
/// `ServiceBuilder` applies its first layer outermost).
pub type Layers<B, M> = Stack<
    Trace<B, M>,
    Stack<
        PropagateRequestIdLayer,
        Stack<
            SetRequestIdLayer<NewRequestId>,
            Stack<MapRequestLayer<fn(Request<B>) -> Request<B>>, Identity>,
        >,
    >,
>;

fn layers<B, M>(
    trace: TraceLayer<M>,
    span: fn(&Request<B>) -> Span,
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
}

/// The HTTP server's layers (axum's router).
pub fn http() -> ServiceBuilder<Layers<axum::body::Body, SharedClassifier<ServerErrorsAsFailures>>>
{
    layers(TraceLayer::new_for_http(), http_span)
}

/// The gRPC server's layers (tonic's `Server::builder().layer`).
pub fn grpc() -> ServiceBuilder<Layers<tonic::body::Body, SharedClassifier<GrpcErrorsAsFailures>>> {
    layers(TraceLayer::new_for_grpc(), grpc_span)
}

#[cfg(test)]
mod tests {
    use super::*;

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
