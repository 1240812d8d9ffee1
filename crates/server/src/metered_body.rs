//! A request body whose bytes are taken from the service's body budget as they arrive
//! ([`BodyMeter`]), for both transports: the HTTP admission middleware wraps every POST's
//! body in one, the gRPC layer ([`crate::grpc_body`]) every call's. A body holds what it has
//! sent, counted to the byte, not what it announces (a `Content-Length`, a chunked body, a
//! gRPC message's length prefix): a client that announces 32 MiB and stalls holds nothing
//! while it waits for the body timeout. What the body took is given back when the call that
//! owns its [`Metered`] is answered — the decoded message, about as large, lives until then.

use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use http_body::Frame;
use prost::bytes::Bytes;

use crate::service::{BodyMeter, Service, ServiceError};

/// What one call's body took from the budget, and why the budget refused it: shared by the
/// body as it is read and by the call until it is answered.
#[derive(Clone)]
pub struct Metered(Arc<Mutex<Call>>);

struct Call {
    meter: BodyMeter,
    refused: Option<ServiceError>,
}

impl Metered {
    /// A new call's share of `service`'s body budget: nothing yet.
    pub fn new(service: &Service) -> Metered {
        Metered(Arc::new(Mutex::new(Call {
            meter: service.body_meter(),
            refused: None,
        })))
    }

    /// The refusal of the budget, if it refused this call's body (taken once).
    pub fn refusal(&self) -> Option<ServiceError> {
        self.lock().refused.take()
    }

    /// Bytes of the body counted so far.
    #[cfg(test)]
    fn received(&self) -> u64 {
        self.lock().meter.received()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Call> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// `inner`, its data frames' bytes taken from the budget before they are passed on; refused,
/// it yields the refusal as its transport's error (`error`) and then ends.
pub struct MeteredBody<B, E> {
    inner: B,
    call: Metered,
    error: fn(&ServiceError) -> E,
    refused: bool,
}

impl<B, E> MeteredBody<B, E> {
    pub fn new(inner: B, call: Metered, error: fn(&ServiceError) -> E) -> MeteredBody<B, E> {
        MeteredBody {
            inner,
            call,
            error,
            refused: false,
        }
    }

    /// Takes `bytes` more from the budget for this call.
    fn account(&mut self, bytes: usize) -> Result<(), E> {
        let mut call = self.call.lock();
        call.meter.add(bytes).map_err(|e| {
            let error = (self.error)(&e);
            call.refused = Some(e);
            error
        })
    }
}

impl<B, E> http_body::Body for MeteredBody<B, E>
where
    B: http_body::Body<Data = Bytes, Error = E> + Unpin,
{
    type Data = Bytes;
    type Error = E;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, E>>> {
        if self.refused {
            return Poll::Ready(None);
        }
        let frame = match Pin::new(&mut self.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => frame,
            other => return other,
        };
        if let Some(data) = frame.data_ref() {
            if let Err(error) = self.account(data.len()) {
                self.refused = true;
                return Poll::Ready(Some(Err(error)));
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
    use crate::service::Limits;

    fn service(budget: usize) -> Arc<Service> {
        Service::in_memory(Limits {
            threads: 1,
            max_jobs: 1,
            max_message_bytes: budget,
            max_body_bytes_in_flight: budget,
            ..Limits::default()
        })
    }

    type Body = MeteredBody<axum::body::Body, axum::Error>;

    fn body(service: &Service) -> Body {
        MeteredBody::new(axum::body::Body::empty(), Metered::new(service), |e| {
            axum::Error::new(e.clone())
        })
    }

    #[test]
    fn a_call_holds_the_bytes_it_sent_and_gives_them_back_with_its_answer() {
        let service = service(1 << 20);
        // A gRPC prefix announcing the largest message, then nothing: five bytes' worth.
        let mut idle = body(&service);
        idle.account(5).unwrap();
        // Bytes sent a few at a time are counted exactly, not a KiB per piece.
        let mut trickle = body(&service);
        for _ in 0..100_000 {
            trickle.account(3).unwrap();
        }
        assert_eq!(trickle.call.received(), 300_000);
        // 300,000 bytes and one KiB of the 1 MiB budget are held: 760,000 more are not free.
        let mut other = body(&service);
        other.account(700_000).unwrap();
        let refused = other.account(60_000).unwrap_err();
        assert!(refused.to_string().contains("bod"), "{refused}");
        assert!(matches!(
            other.call.refusal(),
            Some(ServiceError::BodiesInFlight { .. })
        ));
        // Answered, the trickle gives its bytes back.
        drop(trickle);
        other.account(60_000).unwrap();
        drop(idle);
    }
}
