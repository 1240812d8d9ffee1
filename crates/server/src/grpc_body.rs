//! gRPC request messages held within the same body budget as HTTP bodies.
//!
//! tonic gathers a whole message before it decodes it, and one connection carries up to 64
//! calls: without a budget, a few connections could make it buffer gigabytes of 32 MiB
//! messages. So this layer watches each request body go by and takes each frame's bytes from
//! the service's body budget ([`BodyMeter`]) before tonic gathers them: refused, the call ends
//! with RESOURCE_EXHAUSTED at once, like an HTTP upload past the budget. A body holds what it
//! has sent, not what its 5-byte length prefix announces (a prefix of 32 MiB followed by
//! nothing holds nothing), and gives it back when the call is answered, as HTTP's do: the
//! decoded message, about as large, lives until then. The refusal goes into the answer's
//! extensions as the service's error, as every other refusal's does, for the observation
//! layer to log (at debug: an overload) and count (tonic keeps only the code and message of a
//! status that fails a body).

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use http_body::Frame;
use prost::bytes::Bytes;
use tonic::body::Body;

use crate::grpc::status;
use crate::service::{BodyMeter, Service, ServiceError};

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
struct Call {
    /// The budget its bytes took.
    meter: BodyMeter,
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
        let held = Arc::new(Mutex::new(Call {
            meter: self.service.body_meter(),
            refused: None,
        }));
        let body = Body::new(BudgetedBody::new(body, Arc::clone(&held)));
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

/// A request body whose bytes are taken from the budget as they go by.
pub struct BudgetedBody {
    inner: Body,
    /// The call's meter, whose bytes are given back when it is answered.
    held: Held,
    /// Refused: the call has its error, nothing more is read.
    refused: bool,
}

impl BudgetedBody {
    fn new(inner: Body, held: Held) -> BudgetedBody {
        BudgetedBody {
            inner,
            held,
            refused: false,
        }
    }

    /// Takes `bytes` more from the budget for this call.
    fn account(&mut self, bytes: usize) -> Result<(), tonic::Status> {
        let mut call = self.held.lock().unwrap_or_else(|e| e.into_inner());
        call.meter.add(bytes).map_err(|e| {
            let refused = status(&e);
            call.refused = Some(e);
            refused
        })
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
            if let Err(status) = self.account(data.len()) {
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

    fn body(service: &Arc<Service>) -> BudgetedBody {
        let held = Arc::new(Mutex::new(Call {
            meter: service.body_meter(),
            refused: None,
        }));
        BudgetedBody::new(Body::empty(), held)
    }

    #[test]
    fn a_call_holds_the_bytes_it_sent_and_gives_them_back_with_its_answer() {
        let service = service(1 << 20, 1 << 20);
        // A prefix announcing the largest message, then nothing: it holds five bytes' worth.
        let mut idle = body(&service);
        idle.account(5).unwrap();
        // Bytes sent a few at a time are counted exactly, not a KiB per piece.
        let mut trickle = body(&service);
        for _ in 0..100_000 {
            trickle.account(3).unwrap();
        }
        assert_eq!(trickle.held.lock().unwrap().meter.received(), 300_000);
        // 300,000 bytes and one KiB of the 1 MiB budget are held: 760,000 more are not free.
        let mut other = body(&service);
        other.account(700_000).unwrap();
        let refused = other.account(60_000).unwrap_err();
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted);
        assert!(refused.message().contains("bod"), "{}", refused.message());
        assert!(matches!(
            other.held.lock().unwrap().refused,
            Some(ServiceError::BodiesInFlight { .. })
        ));
        // Answered, the trickle gives its bytes back.
        drop(trickle);
        other.account(60_000).unwrap();
        drop(idle);
    }
}
