//! The gRPC transport: `trinocular.v1.Trinocular` over tonic, calling the [`Service`].

use std::sync::Arc;

use std::time::Duration;

use tonic::metadata::MetadataValue;
use tonic::{Request, Response, Status};
use tracing::Instrument;

use super::pb;
use crate::service::{request_id, Service, ServiceError};

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

#[tonic::async_trait]
impl pb::trinocular_server::Trinocular for GrpcApi {
    async fn r#match(
        &self,
        request: Request<pb::MatchRequest>,
    ) -> Result<Response<pb::MatchResponse>, Status> {
        let timeout = request
            .metadata()
            .get("grpc-timeout")
            .and_then(|v| v.to_str().ok())
            .and_then(grpc_timeout)
            .map(with_margin);
        let id = request_id::request_id(
            request
                .metadata()
                .get(request_id::HEADER)
                .and_then(|v| v.to_str().ok()),
        );
        let request = request.into_inner();
        let answer = self
            .service
            .match_within(move || Ok(request), |_| (), timeout, "grpc")
            .instrument(tracing::info_span!("grpc", request_id = %id))
            .await;
        let value = MetadataValue::try_from(id.as_str()).ok();
        match answer {
            Ok((r, ())) => {
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
