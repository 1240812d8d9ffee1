//! Which field a request that does not parse breaks.
//!
//! A client that sends `{"calibration": 5}` should be told `calibration` is wrong, as it is
//! told `calibration.cameras` when there are two cameras, not `request` and a column number.
//! JSON is parsed first at full speed; only a body that fails is read again, with its path
//! tracked (`serde_path_to_error`), so a good request pays nothing for the error's precision.
//! Protobuf's decoder (prost) names the messages and fields it was inside in its error's text
//! and keeps them nowhere else: the path is read back from that text, and when the text does
//! not have the expected form the error names `request`, as before.
//!
//! Fields are named as every other input error names them: the schema's field names
//! (`options.max_direction_sigma_deg`, whichever of proto3 JSON's two spellings the client
//! used), `[i]` for an element of a list.

use std::fmt::Display;

use serde::de::DeserializeOwned;
use serde_path_to_error::{Path, Segment};

use crate::InputError;

/// The error of `text`, which did not parse as JSON of a `T` (`error`, serde_json's): the
/// field is `what` followed by the path where parsing stopped (`what` itself when the
/// request is the whole body, named `request`, and the path is not empty).
pub fn json_error<T: DeserializeOwned>(
    what: &str,
    text: &str,
    error: &serde_json::Error,
) -> InputError {
    let mut reader = serde_json::Deserializer::from_str(text);
    let mut path = match serde_path_to_error::deserialize::<_, T>(&mut reader) {
        Err(e) => field_path(e.path()),
        Ok(_) => String::new(),
    };
    // A key given twice (or a second member of a oneof: `segments` and `images`) fails in
    // its parent, before the path reaches it: the key is the field to name.
    let message = error.to_string();
    if let Some(key) = message
        .strip_prefix("duplicate field `")
        .and_then(|rest| rest.split_once('`'))
        .map(|(key, _)| snake_case(key))
    {
        if !path.ends_with(&key) {
            if !path.is_empty() {
                path.push('.');
            }
            path.push_str(&key);
        }
    }
    InputError::new(within(what, &path), format!("invalid JSON: {message}"))
}

/// `value` as a `T`, the error naming the field where it does not fit, under `what`.
pub fn from_json_value<T: DeserializeOwned>(
    what: &str,
    value: serde_json::Value,
) -> Result<T, InputError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        InputError::new(
            within(what, &field_path(e.path())),
            format!("invalid JSON: {}", e.inner()),
        )
    })
}

/// The error of a protobuf message under `what` that did not decode, `error` being prost's
/// (`failed to decode Protobuf message: Calibration.cameras: MatchRequest.calibration: invalid
/// wire type…`, the innermost field first).
pub fn protobuf_error(what: &str, error: &impl Display) -> InputError {
    let text = error.to_string();
    InputError::new(
        within(what, &protobuf_path(&text)),
        format!("invalid protobuf: {text}"),
    )
}

/// `path` under `what`: the request's fields are named from its root, so `request` is left
/// out; an empty path is `what` itself.
fn within(what: &str, path: &str) -> String {
    match (what, path.is_empty()) {
        (_, true) => what.to_string(),
        ("request", false) => path.to_string(),
        (_, false) => format!("{what}.{path}"),
    }
}

/// `calibration.cameras[1].width` from serde_path_to_error's path, keys in snake case.
fn field_path(path: &Path) -> String {
    let mut out = String::new();
    for segment in path.iter() {
        match segment {
            Segment::Seq { index } => out.push_str(&format!("[{index}]")),
            Segment::Map { key } => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(&snake_case(key));
            }
            Segment::Enum { .. } | Segment::Unknown => {}
        }
    }
    out
}

/// proto3 JSON's lowerCamelCase name as the schema's field name.
fn snake_case(key: &str) -> String {
    let mut out = String::with_capacity(key.len() + 4);
    for c in key.chars() {
        if c.is_ascii_uppercase() {
            out.push('_');
            out.push(c.to_ascii_lowercase());
        } else {
            out.push(c);
        }
    }
    out
}

/// The fields in prost's error text, outermost first (`calibration.cameras`); empty when the
/// text names none or is not of prost's form.
fn protobuf_path(text: &str) -> String {
    let Some(rest) = text.strip_prefix("failed to decode Protobuf message: ") else {
        return String::new();
    };
    let mut fields: Vec<&str> = Vec::new();
    for part in rest.split(": ") {
        let Some((message, field)) = part.split_once('.') else {
            break;
        };
        let identifier = |s: &str| {
            !s.is_empty()
                && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                && !s.starts_with(|c: char| c.is_ascii_digit())
        };
        if !(identifier(message) && identifier(field)) {
            break;
        }
        fields.push(field);
    }
    fields.reverse();
    fields.join(".")
}

#[cfg(test)]
mod tests {
    use prost::Message;

    use super::*;
    use crate::{from_json, pb};

    fn field_of_json(text: &str) -> String {
        from_json::<pb::MatchRequest>("request", text)
            .unwrap_err()
            .field
    }

    #[test]
    fn a_json_error_names_the_field_it_is_in() {
        assert_eq!(field_of_json(r#"{"calibration": 5}"#), "calibration");
        assert_eq!(
            field_of_json(r#"{"calibration": {"cameras": 5}}"#),
            "calibration.cameras"
        );
        assert_eq!(
            field_of_json(r#"{"calibration": {"cameras": [{}, {"width": "wide"}]}}"#),
            "calibration.cameras[1].width"
        );
        // A key given twice, or two members of one oneof, name the second.
        assert_eq!(
            field_of_json(r#"{"segments": {"lists": []}, "images": {"images": []}}"#),
            "images"
        );
        assert_eq!(
            field_of_json(r#"{"calibration": {"cameras": [{"name": "a", "name": "b"}]}}"#),
            "calibration.cameras[0].name"
        );
        // Either spelling of a field is named by the schema's name.
        for key in ["maxDirectionSigmaDeg", "max_direction_sigma_deg"] {
            assert_eq!(
                field_of_json(&format!(r#"{{"options": {{"{key}": true}}}}"#)),
                "options.max_direction_sigma_deg"
            );
        }
        assert_eq!(field_of_json(r#"{"bogus": 1}"#), "bogus");
        // Nothing to point at: the request.
        assert_eq!(field_of_json("{"), "request");
        assert_eq!(field_of_json("[]"), "request");
    }

    #[test]
    fn a_json_error_keeps_serde_jsons_reason_and_position() {
        let e = from_json::<pb::MatchRequest>("request", r#"{"calibration": 5}"#).unwrap_err();
        assert!(
            e.message
                .starts_with("invalid JSON: invalid type: integer `5`")
                && e.message.contains("line 1 column 17"),
            "{}",
            e.message
        );
    }

    #[test]
    fn a_part_of_a_request_is_named_under_its_own_name() {
        let e = from_json::<pb::Calibration>("calibration", r#"{"cameras": 5}"#).unwrap_err();
        assert_eq!(e.field, "calibration.cameras");
        let value = serde_json::json!({"cameras": [{"width": []}]});
        let e = from_json_value::<pb::Calibration>("calibration", value).unwrap_err();
        assert_eq!(e.field, "calibration.cameras[0].width");
    }

    #[test]
    fn a_protobuf_error_names_the_fields_prost_was_in() {
        // Field 1 of MatchRequest (calibration) sent as a varint.
        let e = pb::MatchRequest::decode(&[0x08u8, 0x05][..]).unwrap_err();
        assert_eq!(protobuf_error("request", &e).field, "calibration");
        // Field 1 of Calibration (cameras) sent as a varint, inside a calibration.
        let e = pb::MatchRequest::decode(&[0x0au8, 0x02, 0x08, 0x05][..]).unwrap_err();
        let error = protobuf_error("request", &e);
        assert_eq!(error.field, "calibration.cameras");
        assert!(
            error.message.starts_with("invalid protobuf: "),
            "{}",
            error.message
        );
        // A calibration cut short: the calibration.
        let e = pb::MatchRequest::decode(&[0x0au8, 0x05][..]).unwrap_err();
        assert_eq!(protobuf_error("request", &e).field, "calibration");
        // A tag of field 0 is no field: the request.
        let e = pb::MatchRequest::decode(&[0x00u8][..]).unwrap_err();
        assert_eq!(protobuf_error("request", &e).field, "request");
    }

    #[test]
    fn a_text_not_of_prosts_form_names_no_field() {
        for text in [
            "",
            "failed to decode Protobuf message: ",
            "failed to decode Protobuf message: buffer underflow",
            "failed to decode Protobuf message: 1a.b: x",
            "something else: MatchRequest.calibration: x",
        ] {
            assert_eq!(protobuf_path(text), "", "{text}");
        }
    }
}
