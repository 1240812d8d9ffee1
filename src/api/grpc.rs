//! The gRPC transport: `trinocular.v1.Trinocular` over tonic, calling the [`Service`].

use std::sync::Arc;

use tonic::{Request, Response, Status};

use super::pb;
use crate::service::{Service, ServiceError};

pub struct GrpcApi {
    service: Arc<Service>,
}

impl GrpcApi {
    pub fn new(service: Arc<Service>) -> GrpcApi {
        GrpcApi { service }
    }
}

/// The status of a service error: its code, and its message (`field: what is wrong` for
/// input errors).
pub fn status(e: &ServiceError) -> Status {
    Status::new(e.code(), e.to_string())
}

#[tonic::async_trait]
impl pb::trinocular_server::Trinocular for GrpcApi {
    async fn r#match(
        &self,
        request: Request<pb::MatchRequest>,
    ) -> Result<Response<pb::MatchResponse>, Status> {
        self.service
            .match_request(request.into_inner())
            .await
            .map(Response::new)
            .map_err(|e| status(&e))
    }
}
