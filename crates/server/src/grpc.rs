//! The gRPC transport: `trinocular.v1.Trinocular` over tonic, calling the [`Service`].

use std::sync::Arc;

use std::time::Duration;

use tonic::codegen::http::request::Parts;
use tonic::{Request, Response, Status};

use crate::service::auth::Caller;
use crate::service::sessions::map_to_pb;
use crate::service::{Service, ServiceError};
use trinocular_schema::{pb, InputError};

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
/// The error itself is the status's source, which tonic keeps in the answer's extensions for
/// the observation layer to log and count ([`crate::observe`]).
pub fn status(e: &ServiceError) -> Status {
    let mut status = match e {
        ServiceError::Input(input) => input.to_status(),
        _ => Status::new(e.code(), e.to_string()),
    };
    status.set_source(Arc::new(e.clone()));
    status
}

/// The route of a call in the metrics and the log: the method of `trinocular.v1.Trinocular`,
/// in snake case as the HTTP routes are named (`None`: health, reflection, an unknown method).
pub fn route(parts: &Parts) -> Option<&'static str> {
    let method = parts
        .uri
        .path()
        .strip_prefix("/trinocular.v1.Trinocular/")?;
    Some(match method {
        "Match" => "match",
        "Calibrate" => "calibrate",
        "ImportCalibration" => "import_calibration",
        "ExportCalibration" => "export_calibration",
        "CreateSession" => "create_session",
        "AddCapture" => "add_capture",
        "GetMap" => "get_map",
        "GetSession" => "get_session",
        "ListSessions" => "list_sessions",
        "DeleteSession" => "delete_session",
        _ => return None,
    })
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

/// The call's deadline, from `grpc-timeout`, less the margin; none when the header is
/// absent. A header that does not parse is INVALID_ARGUMENT naming it: taken as absent, a
/// client's deadline would be dropped without a word and its call run to the server's own.
fn deadline_of<T>(request: &Request<T>) -> Result<Option<Duration>, Status> {
    let Some(value) = request.metadata().get("grpc-timeout") else {
        return Ok(None);
    };
    value
        .to_str()
        .ok()
        .and_then(grpc_timeout)
        .map(|t| Some(with_margin(t)))
        .ok_or_else(|| {
            status(&ServiceError::Input(InputError::new(
                "grpc-timeout",
                "must be 1 to 8 digits and a unit (H, M, S, m, u or n)",
            )))
        })
}

/// The answer to a call: the use case's answer, or the status of its error.
fn respond<T>(answer: Result<T, ServiceError>) -> Result<Response<T>, Status> {
    answer.map(Response::new).map_err(|e| status(&e))
}

impl GrpcApi {
    /// The caller, from the `authorization` metadata (UNAUTHENTICATED without a valid key
    /// when keys are configured).
    fn caller<T>(&self, request: &Request<T>) -> Result<Caller, Status> {
        self.service
            .caller(
                request
                    .metadata()
                    .get("authorization")
                    .and_then(|v| v.to_str().ok()),
            )
            .map_err(|e| status(&e))
    }
}

#[tonic::async_trait]
impl pb::trinocular_server::Trinocular for GrpcApi {
    async fn r#match(
        &self,
        request: Request<pb::MatchRequest>,
    ) -> Result<Response<pb::MatchResponse>, Status> {
        self.caller(&request)?;
        let timeout = deadline_of(&request)?;
        let request = request.into_inner();
        let (answer, ()) = self
            .service
            .match_within(move || Ok(request), |_| (), timeout)
            .await
            .map_err(|e| status(&e))?;
        let segments_3d = answer.segments_3d.len();
        let mut response = Response::new(answer);
        response
            .extensions_mut()
            .insert(crate::observe::Matched { segments_3d });
        Ok(response)
    }

    async fn create_session(
        &self,
        request: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let caller = self.caller(&request)?;
        let answer = self
            .service
            .create_session(&caller, request.into_inner())
            .await;
        respond(answer)
    }

    async fn add_capture(
        &self,
        request: Request<pb::AddCaptureRequest>,
    ) -> Result<Response<pb::AddCaptureResponse>, Status> {
        let caller = self.caller(&request)?;
        let timeout = deadline_of(&request)?;
        let answer = self
            .service
            .add_capture(&caller, request.into_inner(), timeout)
            .await;
        respond(answer)
    }

    async fn get_map(
        &self,
        request: Request<pb::GetMapRequest>,
    ) -> Result<Response<pb::Map>, Status> {
        let caller = self.caller(&request)?;
        let pb::GetMapRequest {
            session_id,
            min_observations,
        } = request.into_inner();
        let answer = self
            .service
            .get_map(&caller, &session_id, min_observations)
            .await;
        respond(answer.map(|m| map_to_pb(&m)))
    }

    async fn get_session(
        &self,
        request: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let caller = self.caller(&request)?;
        let pb::GetSessionRequest { session_id } = request.into_inner();
        let answer = self.service.get_session(&caller, &session_id).await;
        respond(answer)
    }

    async fn list_sessions(
        &self,
        request: Request<pb::ListSessionsRequest>,
    ) -> Result<Response<pb::ListSessionsResponse>, Status> {
        let caller = self.caller(&request)?;
        let answer = self
            .service
            .list_sessions(&caller, request.into_inner())
            .await;
        respond(answer)
    }

    async fn calibrate(
        &self,
        request: Request<pb::CalibrateRequest>,
    ) -> Result<Response<pb::CalibrateResponse>, Status> {
        self.caller(&request)?;
        let timeout = deadline_of(&request)?;
        let request = request.into_inner();
        let answer = self.service.calibrate(move || Ok(request), timeout).await;
        respond(answer)
    }

    async fn import_calibration(
        &self,
        request: Request<pb::ImportCalibrationRequest>,
    ) -> Result<Response<pb::Calibration>, Status> {
        self.caller(&request)?;
        let request = request.into_inner();
        let answer = self.service.import_calibration(move || Ok(request)).await;
        respond(answer)
    }

    async fn export_calibration(
        &self,
        request: Request<pb::ExportCalibrationRequest>,
    ) -> Result<Response<pb::ExportCalibrationResponse>, Status> {
        self.caller(&request)?;
        let request = request.into_inner();
        let answer = self.service.export_calibration(move || Ok(request)).await;
        respond(answer)
    }

    async fn delete_session(
        &self,
        request: Request<pb::DeleteSessionRequest>,
    ) -> Result<Response<pb::DeleteSessionResponse>, Status> {
        let caller = self.caller(&request)?;
        let pb::DeleteSessionRequest { session_id } = request.into_inner();
        let answer = self.service.delete_session(&caller, &session_id).await;
        respond(answer.map(|()| pb::DeleteSessionResponse {}))
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

    #[test]
    fn a_call_deadline_that_does_not_parse_is_named_not_dropped() {
        let with = |value: Option<&'static str>| {
            let mut request = Request::new(());
            if let Some(v) = value {
                request
                    .metadata_mut()
                    .insert("grpc-timeout", v.parse().unwrap());
            }
            deadline_of(&request)
        };
        assert_eq!(with(None).unwrap(), None);
        assert_eq!(
            with(Some("100m")).unwrap(),
            Some(with_margin(Duration::from_millis(100)))
        );
        for bad in ["soon", "12", "123456789S"] {
            let e = with(Some(bad)).unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument, "{bad:?}");
            assert!(e.message().contains("grpc-timeout"), "{bad:?}: {e:?}");
        }
    }
}
