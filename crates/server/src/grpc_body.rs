//! gRPC request messages held within the same body budget as HTTP bodies.
//!
//! tonic gathers a whole message before it decodes it, and one connection carries up to 64
//! calls: without a budget, a few connections could make it buffer gigabytes of 32 MiB
//! messages. So this layer watches each request body go by and takes each frame's bytes from
//! the service's body budget ([`MeteredBody`]) before tonic gathers them: refused, the call ends
//! with RESOURCE_EXHAUSTED at once, like an HTTP upload past the budget. A body holds what it
//! has sent, not what its 5-byte length prefix announces (a prefix of 32 MiB followed by
//! nothing holds nothing), and gives it back when the call is answered, as HTTP's do: the
//! decoded message, about as large, lives until then. The refusal goes into the answer's
//! extensions as the service's error, as every other refusal's does, for the observation
//! layer to log (at debug: an overload) and count (tonic keeps only the code and message of a
//! status that fails a body).

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use tonic::body::Body;

use crate::grpc::status;
use crate::metered_body::{Metered, MeteredBody};
use crate::service::Service;

/// Wraps every gRPC call's request body in a [`MeteredBody`].
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
        let metered = Metered::new(&self.service);
        let body = Body::new(MeteredBody::new(body, metered.clone(), status));
        let answer = self
            .inner
            .call(tonic::codegen::http::Request::from_parts(parts, body));
        Box::pin(async move {
            let mut answer = answer.await;
            if let (Ok(response), Some(e)) = (&mut answer, metered.refusal()) {
                response.extensions_mut().insert(e);
            }
            drop(metered);
            answer
        })
    }
}
