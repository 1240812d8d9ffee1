//! The gRPC transport: `trinocular.v1.Trinocular` over tonic, calling the [`Service`].

use std::sync::Arc;

use std::time::Duration;

use tonic::metadata::MetadataValue;
use tonic::{Request, Response, Status};
use tonic_types::{ErrorDetails, StatusExt};
use tracing::Instrument;

use crate::request_id;
use crate::service::auth::Caller;
use crate::service::sessions::map_to_pb;
use crate::service::{Service, ServiceError};
use trinocular_schema::pb;

pub struct GrpcApi {
    service: Arc<Service>,
}

impl GrpcApi {
    pub fn new(service: Arc<Service>) -> GrpcApi {
        GrpcApi { service }
    }
}

/// The status of a service error: its code, and its message (`field: what is wrong` for
/// input errors). An input error also carries the field as a `google.rpc.BadRequest` field
/// violation, the gRPC richer error model's standard detail, so a client reads which field
/// is at fault without parsing the message, as an HTTP client reads the JSON error's `field`.
pub fn status(e: &ServiceError) -> Status {
    match e {
        ServiceError::Input(input) => Status::with_error_details(
            e.code(),
            e.to_string(),
            ErrorDetails::with_bad_request_violation(input.field.clone(), input.message.clone()),
        ),
        _ => Status::new(e.code(), e.to_string()),
    }
}

/// The `grpc-timeout` header's duration (`<digits><unit>`, unit one of H M S m u n).
pub fn grpc_timeout(value: &str) -> Option<Duration> {
    let (digits, unit) = value.split_at(value.len().checked_sub(1)?);
    let n: u64 = digits.parse().ok().filter(|_| digits.len() <= 8)?;
    Some(match unit {
        "H" => Duration::from_secs(n.saturating_mul(3600)),
        "M" => Duration::from_secs(n.saturating_mul(60)),
        "S" => Duration::from_secs(n),
        "m" => Duration::from_millis(n),
        "u" => Duration::from_micros(n),
        "n" => Duration::from_nanos(n),
        _ => return None,
    })
}

/// The server's timer starts when the handler runs, after the request's upload; the client's
/// started before it, and a client past its deadline reports the call itself (tonic: as
/// CANCELLED). Answering DEADLINE_EXCEEDED this much before the deadline lets that answer
/// reach the client first: a tenth of the timeout plus 2 ms.
fn with_margin(timeout: Duration) -> Duration {
    timeout.saturating_sub(timeout / 10 + Duration::from_millis(2))
}

/// The request's id (the client's `x-request-id`, or a new one).
fn id_of<T>(request: &Request<T>) -> String {
    request_id::request_id(
        request
            .metadata()
            .get(request_id::HEADER)
            .and_then(|v| v.to_str().ok()),
    )
}

/// The call's deadline, from `grpc-timeout`, less the margin.
fn deadline_of<T>(request: &Request<T>) -> Option<Duration> {
    request
        .metadata()
        .get("grpc-timeout")
        .and_then(|v| v.to_str().ok())
        .and_then(grpc_timeout)
        .map(with_margin)
}

/// The answer, with the request id echoed in its metadata either way.
fn respond<T>(id: &str, answer: Result<T, ServiceError>) -> Result<Response<T>, Status> {
    let value = MetadataValue::try_from(id).ok();
    match answer {
        Ok(r) => {
            let mut response = Response::new(r);
            if let Some(v) = value {
                response.metadata_mut().insert(request_id::HEADER, v);
            }
            Ok(response)
        }
        Err(e) => {
            let mut s = status(&e);
            if let Some(v) = value {
                s.metadata_mut().insert(request_id::HEADER, v);
            }
            Err(s)
        }
    }
}

impl GrpcApi {
    /// The caller, from the `authorization` metadata (UNAUTHENTICATED without a valid key
    /// when keys are configured).
    fn caller<T>(&self, request: &Request<T>) -> Result<Caller, ServiceError> {
        self.service.caller(
            request
                .metadata()
                .get("authorization")
                .and_then(|v| v.to_str().ok()),
        )
    }
}

/// Answers the call with the error of a caller that is not let in.
macro_rules! caller_or_refuse {
    ($api:expr, $request:expr, $id:expr) => {
        match $api.caller(&$request) {
            Ok(caller) => caller,
            Err(e) => return respond(&$id, Err(e)),
        }
    };
}

fn span(id: &str, rpc: &'static str) -> tracing::Span {
    tracing::info_span!("grpc", request_id = %id, rpc)
}

#[tonic::async_trait]
impl pb::trinocular_server::Trinocular for GrpcApi {
    async fn r#match(
        &self,
        request: Request<pb::MatchRequest>,
    ) -> Result<Response<pb::MatchResponse>, Status> {
        let (id, timeout) = (id_of(&request), deadline_of(&request));
        caller_or_refuse!(self, request, id);
        let request = request.into_inner();
        let answer = self
            .service
            .match_within(move || Ok(request), |_| (), timeout, "grpc")
            .instrument(span(&id, "Match"))
            .await;
        respond(&id, answer.map(|(r, ())| r))
    }

    async fn create_session(
        &self,
        request: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let id = id_of(&request);
        let caller = caller_or_refuse!(self, request, id);
        let answer = self
            .service
            .create_session(&caller, request.into_inner(), "grpc")
            .instrument(span(&id, "CreateSession"))
            .await;
        respond(&id, answer)
    }

    async fn add_capture(
        &self,
        request: Request<pb::AddCaptureRequest>,
    ) -> Result<Response<pb::AddCaptureResponse>, Status> {
        let (id, timeout) = (id_of(&request), deadline_of(&request));
        let caller = caller_or_refuse!(self, request, id);
        let answer = self
            .service
            .add_capture(&caller, request.into_inner(), timeout, "grpc")
            .instrument(span(&id, "AddCapture"))
            .await;
        respond(&id, answer)
    }

    async fn get_map(
        &self,
        request: Request<pb::GetMapRequest>,
    ) -> Result<Response<pb::Map>, Status> {
        let id = id_of(&request);
        let caller = caller_or_refuse!(self, request, id);
        let pb::GetMapRequest {
            session_id,
            min_observations,
        } = request.into_inner();
        let answer = self
            .service
            .get_map(&caller, &session_id, min_observations, "grpc")
            .instrument(span(&id, "GetMap"))
            .await;
        respond(&id, answer.map(|m| map_to_pb(&m)))
    }

    async fn get_session(
        &self,
        request: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let id = id_of(&request);
        let caller = caller_or_refuse!(self, request, id);
        let pb::GetSessionRequest { session_id } = request.into_inner();
        let answer = self
            .service
            .get_session(&caller, &session_id, "grpc")
            .instrument(span(&id, "GetSession"))
            .await;
        respond(&id, answer)
    }

    async fn list_sessions(
        &self,
        request: Request<pb::ListSessionsRequest>,
    ) -> Result<Response<pb::ListSessionsResponse>, Status> {
        let id = id_of(&request);
        let caller = caller_or_refuse!(self, request, id);
        let answer = self
            .service
            .list_sessions(&caller, request.into_inner(), "grpc")
            .instrument(span(&id, "ListSessions"))
            .await;
        respond(&id, answer)
    }

    async fn calibrate(
        &self,
        request: Request<pb::CalibrateRequest>,
    ) -> Result<Response<pb::CalibrateResponse>, Status> {
        let (id, timeout) = (id_of(&request), deadline_of(&request));
        caller_or_refuse!(self, request, id);
        let request = request.into_inner();
        let answer = self
            .service
            .calibrate(move || Ok(request), timeout, "grpc")
            .instrument(span(&id, "Calibrate"))
            .await;
        respond(&id, answer)
    }

    async fn delete_session(
        &self,
        request: Request<pb::DeleteSessionRequest>,
    ) -> Result<Response<pb::DeleteSessionResponse>, Status> {
        let id = id_of(&request);
        let caller = caller_or_refuse!(self, request, id);
        let pb::DeleteSessionRequest { session_id } = request.into_inner();
        let answer = self
            .service
            .delete_session(&caller, &session_id, "grpc")
            .instrument(span(&id, "DeleteSession"))
            .await;
        respond(&id, answer.map(|()| pb::DeleteSessionResponse {}))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grpc_timeouts_parse() {
        assert_eq!(grpc_timeout("250m"), Some(Duration::from_millis(250)));
        assert_eq!(grpc_timeout("3S"), Some(Duration::from_secs(3)));
        assert_eq!(grpc_timeout("1H"), Some(Duration::from_secs(3600)));
        assert_eq!(grpc_timeout("100u"), Some(Duration::from_micros(100)));
        for bad in ["", "m", "12", "12x", "-1m", "123456789S"] {
            assert_eq!(grpc_timeout(bad), None, "{bad:?}");
        }
    }
}
