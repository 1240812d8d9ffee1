//! The public schema: generated protobuf types (prost + tonic + pbjson) and the one place
//! where they are converted to and from the core's plain domain types.
//!
//! Every conversion checks what the core cannot: counts and lengths of repeated fields, and
//! maps core errors to an [`InputError`] that names the offending field by its path in the
//! request (`calibration.cameras[2].projection`, `segments.lists[1].segments[17].u1`).

pub mod calibrate;
mod convert;
mod fast_json;
pub mod grpc;
pub mod http;
pub mod session;

pub use convert::{
    calibration_to_pb, camera_to_pb, extract_params, images, match_params, match_request,
    match_response, rig_from_calibration, segment_list_to_pb, segment_lists, Executed, MatchInput,
    MatchSource, RequestLimits, RunError, MAX_SEGMENTS_PER_LIST,
};
pub use fast_json::match_request_from_json;

/// The schema as an encoded `FileDescriptorSet`, for gRPC server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/trinocular_descriptor.bin"));

#[allow(clippy::all, missing_docs)]
pub mod pb {
    tonic::include_proto!("trinocular.v1");
    include!(concat!(env!("OUT_DIR"), "/trinocular.v1.serde.rs"));
}

/// A request field that cannot be accepted: HTTP 400 / gRPC INVALID_ARGUMENT.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct InputError {
    /// Path of the field in the request, e.g. `calibration.cameras[2].projection`.
    pub field: String,
    pub message: String,
}

impl InputError {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> InputError {
        InputError {
            field: field.into(),
            message: message.into(),
        }
    }
}

/// Parses a message from proto3 JSON, naming the message in the error.
pub fn from_json<T: serde::de::DeserializeOwned>(what: &str, text: &str) -> Result<T, InputError> {
    serde_json::from_str(text).map_err(|e| InputError::new(what, format!("invalid JSON: {e}")))
}

/// Serialises a message as pretty proto3 JSON (the CLI's and the HTTP API's one format).
pub fn to_json<T: serde::Serialize>(message: &T) -> String {
    // Generated messages hold only strings, numbers, lists and maps: serialisation cannot fail.
    serde_json::to_string_pretty(message).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
}
