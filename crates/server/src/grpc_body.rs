//! gRPC request messages held within the same body budget as HTTP bodies.
//!
//! tonic gathers a whole message before it decodes it, and one connection carries up to 64
//! calls: without a budget, a few connections could make it buffer gigabytes of 32 MiB
//! messages. HTTP reserves a body's bytes from [`Service::reserve_body`] before it reads it;
//! gRPC has no Content-Length, but every message starts with a 5-byte prefix giving its length.
//! So this layer watches each request body go by and, at each prefix, reserves that many bytes
//! before tonic reads the message: refused, the call ends with RESOURCE_EXHAUSTED at once,
//! like an HTTP upload past the budget. The bytes are returned when the call is answered, as
//! HTTP's are: the decoded message, about as large, lives until then. The refusal goes into
//! the answer's extensions as the service's error, as every other refusal's does, for the
//! observation layer to log (at debug: an overload) and count (tonic keeps only the code and
//! message of a status that fails a body).

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use http_body::Frame;
use prost::bytes::Bytes;
use tonic::body::Body;

use crate::grpc::status;
use crate::service::{BodyReservation, Service, ServiceError};

/// Bytes of a gRPC message prefix: a compression flag, then the length (big-endian u32).
const PREFIX_BYTES: usize = 5;

/// Wraps every gRPC call's request body in a [`BudgetedBody`].
#[derive(Clone)]
pub struct BodyBudgetLayer {
    service: Arc<Service>,
}

impl BodyBudgetLayer {
    pub fn new(service: Arc<Service>) -> BodyBudgetLayer {
        BodyBudgetLayer { service }
    }
}

impl<S> tower_layer::Layer<S> for BodyBudgetLayer {
    type Service = BodyBudget<S>;

    fn layer(&self, inner: S) -> BodyBudget<S> {
        BodyBudget {
            inner,
            service: Arc::clone(&self.service),
        }
    }
}

/// The service [`BodyBudgetLayer`] makes.
#[derive(Clone)]
pub struct BodyBudget<S> {
    inner: S,
    service: Arc<Service>,
}

/// What one call's body did, shared by the body as it reads and the call until it is answered.
#[derive(Default)]
struct Call {
    /// The reservations of its messages.
    reservations: Vec<BodyReservation>,
    /// Why the budget refused it.
    refused: Option<ServiceError>,
}

type Held = Arc<Mutex<Call>>;

impl<S, ResBody> tower_service::Service<tonic::codegen::http::Request<Body>> for BodyBudget<S>
where
    S: tower_service::Service<
        tonic::codegen::http::Request<Body>,
        Response = tonic::codegen::http::Response<ResBody>,
    >,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = Pin<Box<dyn Future<Output = Result<S::Response, S::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: tonic::codegen::http::Request<Body>) -> Self::Future {
        let (parts, body) = request.into_parts();
        let held = Held::default();
        let body = Body::new(BudgetedBody::new(
            body,
            Arc::clone(&self.service),
            Arc::clone(&held),
        ));
        let answer = self
            .inner
            .call(tonic::codegen::http::Request::from_parts(parts, body));
        Box::pin(async move {
            let mut answer = answer.await;
            let refused = held
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .refused
                .take();
            if let (Ok(response), Some(e)) = (&mut answer, refused) {
                response.extensions_mut().insert(e);
            }
            drop(held);
            answer
        })
    }
}

/// A request body that reserves each message's bytes as its prefix goes by.
pub struct BudgetedBody {
    inner: Body,
    service: Arc<Service>,
    prefix: [u8; PREFIX_BYTES],
    prefix_seen: usize,
    /// Bytes of the current message still to come after its prefix.
    message_left: u64,
    /// What this call's messages reserved, returned when it is answered.
    held: Held,
    /// Refused: the call has its error, nothing more is read.
    refused: bool,
}

impl BudgetedBody {
    fn new(inner: Body, service: Arc<Service>, held: Held) -> BudgetedBody {
        BudgetedBody {
            inner,
            service,
            prefix: [0; PREFIX_BYTES],
            prefix_seen: 0,
            message_left: 0,
            held,
            refused: false,
        }
    }

    /// Follows `data` through the message framing, reserving each message as its prefix ends.
    fn account(&mut self, mut data: &[u8]) -> Result<(), tonic::Status> {
        while !data.is_empty() {
            if self.message_left > 0 {
                let n = (self.message_left.min(data.len() as u64)) as usize;
                self.message_left -= n as u64;
                data = &data[n..];
                continue;
            }
            let n = (PREFIX_BYTES - self.prefix_seen).min(data.len());
            self.prefix[self.prefix_seen..self.prefix_seen + n].copy_from_slice(&data[..n]);
            self.prefix_seen += n;
            data = &data[n..];
            if self.prefix_seen < PREFIX_BYTES {
                continue;
            }
            self.prefix_seen = 0;
            let length = u32::from_be_bytes([
                self.prefix[1],
                self.prefix[2],
                self.prefix[3],
                self.prefix[4],
            ]);
            self.message_left = u64::from(length);
            // A message over the limit is refused by tonic from the same prefix, unread.
            let max = self.service.limits().max_message_bytes;
            let length = length as usize;
            if length == 0 || length > max {
                continue;
            }
            match self.service.reserve_body(length) {
                Ok(reservation) => self
                    .held
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .reservations
                    .push(reservation),
                Err(e) => {
                    let refused = status(&e);
                    self.held.lock().unwrap_or_else(|e| e.into_inner()).refused = Some(e);
                    return Err(refused);
                }
            }
        }
        Ok(())
    }
}

impl http_body::Body for BudgetedBody {
    type Data = Bytes;
    type Error = tonic::Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, tonic::Status>>> {
        if self.refused {
            return Poll::Ready(None);
        }
        let frame = match Pin::new(&mut self.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => frame,
            other => return other,
        };
        if let Some(data) = frame.data_ref() {
            if let Err(status) = self.account(data) {
                self.refused = true;
                return Poll::Ready(Some(Err(status)));
            }
        }
        Poll::Ready(Some(Ok(frame)))
    }

    fn is_end_stream(&self) -> bool {
        self.refused || self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::{store, Limits};

    fn service(budget: usize, max_message: usize) -> Arc<Service> {
        let limits = Limits {
            threads: 1,
            max_jobs: 1,
            max_message_bytes: max_message,
            max_body_bytes_in_flight: budget,
            ..Limits::default()
        };
        let store: Arc<dyn store::SessionStore> = Arc::new(store::memory::MemoryStore::new(
            std::time::Duration::from_secs(60),
        ));
        Arc::new(Service::new(limits, store, std::time::Duration::from_secs(60)).unwrap())
    }

    fn prefixed(length: u32) -> Vec<u8> {
        let mut bytes = vec![0u8];
        bytes.extend_from_slice(&length.to_be_bytes());
        bytes
    }

    #[test]
    fn each_message_is_reserved_at_its_prefix_even_split_across_frames() {
        let service = service(1 << 20, 1 << 20);
        let mut body = BudgetedBody::new(Body::empty(), Arc::clone(&service), Held::default());
        let mut stream = prefixed(300_000);
        stream.extend(vec![7u8; 300_000]);
        stream.extend(prefixed(200_000));
        stream.extend(vec![7u8; 10]);
        // Fed in awkward pieces: a prefix cut in two, a message cut anywhere.
        for piece in stream.chunks(3) {
            body.account(piece).unwrap();
        }
        assert_eq!(body.held.lock().unwrap().reservations.len(), 2);
        assert_eq!(body.message_left, 200_000 - 10);
        // 300,000 + 200,000 bytes of the 1 MiB budget are held: 600,000 more are not free.
        let mut other = BudgetedBody::new(Body::empty(), Arc::clone(&service), Held::default());
        let refused = other.account(&prefixed(600_000)).unwrap_err();
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted);
        assert!(refused.message().contains("bod"), "{}", refused.message());
        assert!(matches!(
            other.held.lock().unwrap().refused,
            Some(ServiceError::BodiesInFlight { .. })
        ));
        // Dropped with its answer, the first call gives its bytes back.
        drop(body);
        let mut again = BudgetedBody::new(Body::empty(), service, Held::default());
        again.account(&prefixed(600_000)).unwrap();
        assert_eq!(again.held.lock().unwrap().reservations.len(), 1);
    }

    #[test]
    fn a_message_over_the_limit_is_left_to_tonic_to_refuse() {
        let service = service(1 << 20, 1000);
        let mut body = BudgetedBody::new(Body::empty(), service, Held::default());
        body.account(&prefixed(u32::MAX)).unwrap();
        assert!(body.held.lock().unwrap().reservations.is_empty());
    }
}
