//! The service's one error type, mapped once to a gRPC code; the HTTP status derives from that
//! code (the grpc-gateway table), so the two transports cannot disagree.

use axum::http::StatusCode;
use thiserror::Error;
use tonic::Code;

use super::matching::RunError;
use super::pool::PoolError;
use trinocular_core::checkpoint::Stopped;
use trinocular_schema::InputError;

#[derive(Debug, Clone, PartialEq, Error)]
pub enum ServiceError {
    /// A request field that cannot be accepted; names the field.
    #[error("{0}")]
    Input(#[from] InputError),
    /// Every compute slot is taken: retry after a moment.
    #[error("the service is busy ({max_jobs} jobs queued or running); retry later")]
    Busy { max_jobs: usize },
    /// As many live-view streams are open on this replica as it serves, or as the caller's
    /// API key may hold (`per_key`): retry after a moment, or close some.
    #[error(
        "{limit} live views are open {} already; retry later",
        if *per_key { "for this API key" } else { "on this replica" }
    )]
    TooManyStreams { limit: usize, per_key: bool },
    /// No API key, or not a valid one.
    #[error("{message}")]
    Unauthenticated { message: String },
    /// The caller's key holds as many sessions as it may.
    #[error(
        "this API key holds {limit} sessions already (auth.max_sessions_per_key): delete some"
    )]
    QuotaExceeded { limit: usize },
    /// The request bodies being received hold the whole body budget: retry after a moment.
    #[error(
        "the service is receiving {limit_bytes} bytes of requests already \
         (limits.max_bodies_mib); retry later"
    )]
    BodiesInFlight { limit_bytes: usize },
    /// The compute jobs running hold the working-memory budget: retry after a moment.
    #[error(
        "the jobs running hold the service's {} MiB of working memory \
         (limits.max_working_mib); retry later", limit_bytes >> 20
    )]
    MemoryBusy { limit_bytes: u64 },
    /// The request body did not arrive in time.
    #[error("the request body did not arrive within {seconds} s (server.body_timeout_ms)")]
    BodyTimeout { seconds: f64 },
    /// The request is larger than the configured limit.
    #[error(
        "the request is larger than the limit of {limit_bytes} bytes (limits.max_message_mib)"
    )]
    TooLarge { limit_bytes: usize },
    /// What the request names does not exist (or expired).
    #[error("{what} not found (it may have expired)")]
    NotFound { field: String, what: String },
    /// The request names, as new, something that exists already and is not what it asks
    /// for (a client-chosen session id or capture name used for another session or capture).
    #[error("{field}: {what}")]
    AlreadyExists { field: String, what: String },
    /// A dependency (the session store) cannot be reached; retry later.
    #[error("{message}")]
    Unavailable { message: String },
    /// The caller's deadline passed before the answer was ready.
    #[error("the deadline of {timeout_ms} ms passed before the answer was ready")]
    DeadlineExceeded { timeout_ms: u64 },
    /// The job stopped early because nobody waited for its answer; no client normally sees
    /// this (it has gone, or got DEADLINE_EXCEEDED already).
    #[error("stopped before {stage}: the caller went away")]
    Stopped { stage: &'static str },
    /// A bug: the detail is logged, the client gets a generic message.
    #[error("internal error")]
    Internal { detail: String },
}

impl From<PoolError> for ServiceError {
    fn from(e: PoolError) -> ServiceError {
        match e {
            PoolError::Busy { max_jobs } => ServiceError::Busy { max_jobs },
            PoolError::Panicked { message } => ServiceError::Internal { detail: message },
        }
    }
}

impl From<Stopped> for ServiceError {
    fn from(Stopped { stage }: Stopped) -> ServiceError {
        ServiceError::Stopped { stage }
    }
}

impl From<RunError> for ServiceError {
    fn from(e: RunError) -> ServiceError {
        match e {
            RunError::Input(e) => ServiceError::Input(e),
            RunError::Stopped { stage } => ServiceError::Stopped { stage },
        }
    }
}

impl ServiceError {
    pub fn code(&self) -> Code {
        match self {
            ServiceError::Input(_) => Code::InvalidArgument,
            ServiceError::Busy { .. }
            | ServiceError::BodiesInFlight { .. }
            | ServiceError::MemoryBusy { .. }
            | ServiceError::QuotaExceeded { .. }
            | ServiceError::TooManyStreams { .. } => Code::ResourceExhausted,
            ServiceError::Unauthenticated { .. } => Code::Unauthenticated,
            ServiceError::BodyTimeout { .. } => Code::DeadlineExceeded,
            // As tonic answers a message past its decoding limit.
            ServiceError::TooLarge { .. } => Code::OutOfRange,
            ServiceError::DeadlineExceeded { .. } => Code::DeadlineExceeded,
            ServiceError::NotFound { .. } => Code::NotFound,
            ServiceError::AlreadyExists { .. } => Code::AlreadyExists,
            ServiceError::Unavailable { .. } => Code::Unavailable,
            ServiceError::Stopped { .. } => Code::Cancelled,
            ServiceError::Internal { .. } => Code::Internal,
        }
    }

    /// The offending field, for input errors.
    pub fn field(&self) -> Option<&str> {
        match self {
            ServiceError::Input(e) => Some(&e.field),
            ServiceError::NotFound { field, .. } | ServiceError::AlreadyExists { field, .. } => {
                Some(field)
            }
            ServiceError::Busy { .. }
            | ServiceError::BodiesInFlight { .. }
            | ServiceError::MemoryBusy { .. }
            | ServiceError::Unauthenticated { .. }
            | ServiceError::QuotaExceeded { .. }
            | ServiceError::TooManyStreams { .. }
            | ServiceError::BodyTimeout { .. }
            | ServiceError::TooLarge { .. }
            | ServiceError::Unavailable { .. }
            | ServiceError::DeadlineExceeded { .. }
            | ServiceError::Stopped { .. }
            | ServiceError::Internal { .. } => None,
        }
    }
}

impl ServiceError {
    /// A refusal for lack of capacity now (compute slots, the body budget, working memory):
    /// answered with a hint to retry, and logged at debug, as under overload they come by the
    /// thousand a second and a log line each would cost more than the refusal (they are
    /// counted, in `trinocular_rejections_total`).
    pub fn is_overload(&self) -> bool {
        match self {
            ServiceError::Busy { .. }
            | ServiceError::BodiesInFlight { .. }
            | ServiceError::MemoryBusy { .. }
            | ServiceError::TooManyStreams { .. } => true,
            ServiceError::Input(_)
            | ServiceError::Unauthenticated { .. }
            | ServiceError::QuotaExceeded { .. }
            | ServiceError::BodyTimeout { .. }
            | ServiceError::TooLarge { .. }
            | ServiceError::NotFound { .. }
            | ServiceError::AlreadyExists { .. }
            | ServiceError::Unavailable { .. }
            | ServiceError::DeadlineExceeded { .. }
            | ServiceError::Stopped { .. }
            | ServiceError::Internal { .. } => false,
        }
    }

    /// The HTTP status: that of the gRPC code, except that HTTP has its own status for a body
    /// that is too large.
    pub fn http_status(&self) -> StatusCode {
        match self {
            ServiceError::TooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            ServiceError::BodyTimeout { .. } => StatusCode::REQUEST_TIMEOUT,
            other => http_status(other.code()),
        }
    }
}

/// The HTTP status of a gRPC code (grpc-gateway's `HTTPStatusFromCode`).
pub fn http_status(code: Code) -> StatusCode {
    match code {
        Code::Ok => StatusCode::OK,
        Code::Cancelled => StatusCode::from_u16(499).unwrap_or(StatusCode::BAD_REQUEST),
        Code::Unknown | Code::Internal | Code::DataLoss => StatusCode::INTERNAL_SERVER_ERROR,
        Code::InvalidArgument | Code::FailedPrecondition | Code::OutOfRange => {
            StatusCode::BAD_REQUEST
        }
        Code::DeadlineExceeded => StatusCode::GATEWAY_TIMEOUT,
        Code::NotFound => StatusCode::NOT_FOUND,
        Code::AlreadyExists | Code::Aborted => StatusCode::CONFLICT,
        Code::PermissionDenied => StatusCode::FORBIDDEN,
        Code::Unauthenticated => StatusCode::UNAUTHORIZED,
        Code::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
        Code::Unimplemented => StatusCode::NOT_IMPLEMENTED,
        Code::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
    }
}

/// The gRPC code of an HTTP answer the service did not make (axum's own, without a
/// [`ServiceError`]): OK for a success, else the first code whose status [`http_status`] makes
/// it (400: INVALID_ARGUMENT), UNKNOWN for a status no code has. The inverse of the one
/// mapping, not a second table.
pub fn code_of_http_status(status: StatusCode) -> Code {
    if status.is_success() {
        return Code::Ok;
    }
    (1..=16)
        .map(Code::from_i32)
        .find(|&code| http_status(code) == status)
        .unwrap_or(Code::Unknown)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_error_has_one_code_and_status() {
        let input = ServiceError::Input(InputError::new("options.tolerance_px", "bad"));
        assert_eq!(input.code(), Code::InvalidArgument);
        assert_eq!(http_status(input.code()), StatusCode::BAD_REQUEST);
        assert_eq!(input.field(), Some("options.tolerance_px"));
        let busy = ServiceError::from(PoolError::Busy { max_jobs: 3 });
        assert_eq!(http_status(busy.code()), StatusCode::TOO_MANY_REQUESTS);
        let panic = ServiceError::from(PoolError::Panicked {
            message: "secret detail".into(),
        });
        assert_eq!(http_status(panic.code()), StatusCode::INTERNAL_SERVER_ERROR);
        assert!(
            !panic.to_string().contains("secret"),
            "details stay in the log"
        );
    }

    #[test]
    fn an_http_status_maps_back_to_the_code_that_makes_it() {
        assert_eq!(code_of_http_status(StatusCode::OK), Code::Ok);
        assert_eq!(code_of_http_status(StatusCode::NO_CONTENT), Code::Ok);
        assert_eq!(
            code_of_http_status(StatusCode::BAD_REQUEST),
            Code::InvalidArgument
        );
        assert_eq!(
            code_of_http_status(StatusCode::TOO_MANY_REQUESTS),
            Code::ResourceExhausted
        );
        assert_eq!(
            code_of_http_status(StatusCode::METHOD_NOT_ALLOWED),
            Code::Unknown
        );
        for code in (1..=16).map(Code::from_i32) {
            assert_eq!(
                http_status(code_of_http_status(http_status(code))),
                http_status(code)
            );
        }
    }
}
