//! The public schema: generated protobuf types (prost + tonic + pbjson) and the one place
//! where they are converted to and from the core's plain domain types.
//!
//! Every conversion checks what the core cannot: counts and lengths of repeated fields, and
//! maps core errors to an [`InputError`] that names the offending field by its path in the
//! request (`calibration.cameras[2].projection`, `segments.lists[1].segments[17].u1`).
//!
//! ```text
//! trinocular-server (use cases, transports) ─▶ trinocular-schema ─▶ trinocular-core (vision)
//! ```
//!
//! Only conversions live here: running a checked request (the pipeline, the compute pool,
//! the stores) is the server's. So a client or a robot that speaks the schema compiles no
//! runtime, transport or store.

pub mod calibrate;
pub mod calibration_files;
pub mod codec;
pub(crate) mod convert;
mod fast_json;
mod located;
pub mod session;

pub use calibrate::{calibrate_request_from_json, LEGACY_PATTERN_TO_RIG};
pub use convert::{
    calibration_to_pb, camera_to_pb, extract_params, images, match_error, match_params,
    match_request, match_response, request_size, rig_from_calibration, segment_list_to_pb,
    segment_lists, segments_3d_of, triplet_pixels, MatchInput, MatchSource, RequestLimits,
    MAX_SEGMENTS_PER_LIST,
};
pub use fast_json::match_request_from_json;
pub use located::protobuf_error;

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

/// Longest field path and message an [`InputError`] carries, bytes: what a request puts in
/// them (a name, an id, a parser's quote of its input) reaches the answer and the log, and a
/// hostile request must not make either megabytes long.
pub const MAX_ERROR_FIELD_BYTES: usize = 200;
pub const MAX_ERROR_MESSAGE_BYTES: usize = 1000;

impl InputError {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> InputError {
        InputError {
            field: truncated(field.into(), MAX_ERROR_FIELD_BYTES),
            message: truncated(message.into(), MAX_ERROR_MESSAGE_BYTES),
        }
    }
}

impl InputError {
    /// The gRPC status of this error, as every input error is answered: INVALID_ARGUMENT with
    /// `field: message`, and the field as a `google.rpc.BadRequest` field violation (the richer
    /// error model's standard detail), so a client reads which field is at fault without
    /// parsing the message. Made here, where the codec's decoding errors are made too.
    pub fn to_status(&self) -> tonic::Status {
        use tonic_types::{ErrorDetails, StatusExt};
        tonic::Status::with_error_details(
            tonic::Code::InvalidArgument,
            self.to_string(),
            ErrorDetails::with_bad_request_violation(self.field.clone(), self.message.clone()),
        )
    }
}

/// `text` cut to at most `max` bytes at a character boundary, marked with "…" when cut.
pub fn truncated(mut text: String, max: usize) -> String {
    if text.len() > max {
        let mut end = max.saturating_sub('…'.len_utf8());
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        text.truncate(end);
        text.push('…');
    }
    text
}

/// Parses a message from proto3 JSON; the error names the field where parsing stopped, under
/// `what` (the message's own name, or `request` for a whole request, whose fields are named
/// from its root).
pub fn from_json<T: serde::de::DeserializeOwned>(what: &str, text: &str) -> Result<T, InputError> {
    serde_json::from_str(text).map_err(|e| located::json_error::<T>(what, text, &e))
}

/// Serialises a message as pretty proto3 JSON (the CLI's and the HTTP API's one format).
pub fn to_json<T: serde::Serialize>(message: &T) -> String {
    // Generated messages hold only strings, numbers, lists and maps: serialisation cannot fail.
    serde_json::to_string_pretty(message).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_carries_a_bounded_field_and_message() {
        let e = InputError::new("é".repeat(10_000), "x".repeat(12_000_000));
        assert!(e.field.len() <= MAX_ERROR_FIELD_BYTES && e.field.ends_with('…'));
        assert!(e.message.len() <= MAX_ERROR_MESSAGE_BYTES && e.message.ends_with('…'));
        let short = InputError::new("rows", "must be 2 to 64");
        assert_eq!(short.to_string(), "rows: must be 2 to 64");
    }
}
