//! A faster reader for the bulk of a JSON `MatchRequest`: its segment lists.
//!
//! pbjson's generated code reads every `double` through an untagged enum (a JSON number, or
//! a string such as `"NaN"`), which builds and drops a serde error for each number: 2.7 ms
//! for 600 segments per list, more than matching them takes. Here the segment lists are read
//! as plain JSON numbers straight into the messages; the small rest of the request
//! (calibration, options, images) still goes through pbjson.
//!
//! Only the common, plain form takes this path: known field names, plain numbers. Anything
//! else in the segment lists (strings such as `"NaN"`, unknown fields, original field names)
//! makes it give up, and the request is read by pbjson alone, which accepts every proto3 JSON
//! form and words every error. So the result is pbjson's, only sooner: a test compares them.

use std::marker::PhantomData;

use serde::de::value::MapAccessDeserializer;
use serde::de::{self, Deserializer, IgnoredAny, MapAccess, Visitor};
use serde::Deserialize;

use super::pb;

/// A `double` written as a plain JSON number (nothing else: see the module doc).
struct Plain(f64);

impl<'de> Deserialize<'de> for Plain {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Plain, D::Error> {
        struct V;
        impl Visitor<'_> for V {
            type Value = Plain;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a plain JSON number")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Plain, E> {
                Ok(Plain(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Plain, E> {
                Ok(Plain(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Plain, E> {
                Ok(Plain(v as f64))
            }
        }
        d.deserialize_f64(V)
    }
}

/// A message read from a JSON object only. serde's derived structs also take the array form
/// (their fields in order, `[1, 2, 3, 4]` for a segment), which proto3 JSON does not have:
/// pbjson refuses it, and so must the fast reader (found by `fuzz/json_body`: `"segments": []`
/// read as an empty triplet).
struct Object<T>(T);

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Object<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Object<T>, D::Error> {
        struct V<T>(PhantomData<T>);
        impl<'de, T: Deserialize<'de>> Visitor<'de> for V<T> {
            type Value = T;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<T, A::Error> {
                T::deserialize(MapAccessDeserializer::new(map))
            }
        }
        d.deserialize_map(V(PhantomData)).map(Object)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Segment {
    u1: Plain,
    v1: Plain,
    u2: Plain,
    v2: Plain,
    #[serde(default)]
    gradient: Option<Plain>,
    #[serde(default, rename = "offsetSigmaPx")]
    offset_sigma_px: Option<Plain>,
    #[serde(default, rename = "angleSigmaDeg")]
    angle_sigma_deg: Option<Plain>,
    #[serde(default, rename = "shiftSigmaPx")]
    shift_sigma_px: Option<Plain>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentList {
    #[serde(default)]
    segments: Vec<Object<Segment>>,
    #[serde(default)]
    oriented: bool,
    #[serde(default, rename = "backgroundGradient")]
    background_gradient: Option<Plain>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentTriplet {
    #[serde(default)]
    lists: Vec<Object<SegmentList>>,
}

/// The request with its segments read here and its other parts by pbjson.
struct Fast(pb::MatchRequest);

impl<'de> Deserialize<'de> for Fast {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Fast, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Fast;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a MatchRequest")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Fast, A::Error> {
                let mut request = pb::MatchRequest::default();
                while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
                    let taken = request.input.is_some();
                    match key.as_ref() {
                        "calibration" if request.calibration.is_none() => {
                            request.calibration = Some(map.next_value()?)
                        }
                        "options" if request.options.is_none() => {
                            request.options = Some(map.next_value()?)
                        }
                        "segments" if !taken => {
                            let Object(t): Object<SegmentTriplet> = map.next_value()?;
                            request.input =
                                Some(pb::match_request::Input::Segments(triplet_to_pb(t)));
                        }
                        "images" if !taken => {
                            request.input =
                                Some(pb::match_request::Input::Images(map.next_value()?))
                        }
                        _ => {
                            // Unknown, repeated or conflicting: leave it to pbjson.
                            let _: IgnoredAny = map.next_value()?;
                            return Err(de::Error::custom("not the plain form"));
                        }
                    }
                }
                Ok(Fast(request))
            }
        }
        d.deserialize_map(V)
    }
}

fn triplet_to_pb(t: SegmentTriplet) -> pb::SegmentTriplet {
    pb::SegmentTriplet {
        lists: t
            .lists
            .into_iter()
            .map(|Object(l)| pb::SegmentList {
                oriented: l.oriented,
                background_gradient: l.background_gradient.map(|g| g.0),
                segments: l
                    .segments
                    .into_iter()
                    .map(|Object(s)| pb::Segment {
                        u1: s.u1.0,
                        v1: s.v1.0,
                        u2: s.u2.0,
                        v2: s.v2.0,
                        gradient: s.gradient.map(|g| g.0),
                        offset_sigma_px: s.offset_sigma_px.map(|g| g.0),
                        angle_sigma_deg: s.angle_sigma_deg.map(|g| g.0),
                        shift_sigma_px: s.shift_sigma_px.map(|g| g.0),
                    })
                    .collect(),
            })
            .collect(),
    }
}

/// A `MatchRequest` from proto3 JSON: the fast reader when the request is in the plain form,
/// pbjson otherwise (and for every error).
pub fn match_request_from_json(text: &str) -> Result<pb::MatchRequest, super::InputError> {
    match serde_json::from_str::<Fast>(text) {
        Ok(Fast(request)) => Ok(request),
        Err(_) => super::from_json("request", text),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn both(
        text: &str,
    ) -> (
        Result<pb::MatchRequest, String>,
        Result<pb::MatchRequest, String>,
    ) {
        (
            match_request_from_json(text).map_err(|e| e.to_string()),
            super::super::from_json::<pb::MatchRequest>("request", text).map_err(|e| e.to_string()),
        )
    }

    /// One segment as a JSON object: the four coordinates (any finite number, extremes and
    /// subnormals included), each optional field present or not.
    fn segment_json() -> impl proptest::strategy::Strategy<Value = serde_json::Value> {
        use proptest::prelude::*;
        let finite = || any::<f64>().prop_filter("finite", |x| x.is_finite());
        (
            [finite(), finite(), finite(), finite()],
            proptest::option::of(0.0..1e6f64),
            proptest::option::of(1e-9..1e3f64),
            proptest::option::of(1e-9..90.0f64),
            proptest::option::of(0.0..1.0f64),
        )
            .prop_map(|([u1, v1, u2, v2], gradient, offset, angle, shift)| {
                let mut s = serde_json::json!({"u1": u1, "v1": v1, "u2": u2, "v2": v2});
                for (name, value) in [
                    ("gradient", gradient),
                    ("offsetSigmaPx", offset),
                    ("angleSigmaDeg", angle),
                    ("shiftSigmaPx", shift),
                ] {
                    if let Some(v) = value {
                        s[name] = serde_json::json!(v);
                    }
                }
                s
            })
    }

    proptest::proptest! {
        /// Whatever lists a client sends in the plain form, the fast reader takes them itself
        /// and reads exactly what pbjson reads.
        #[test]
        fn reads_arbitrary_plain_lists_exactly_as_pbjson(
            lists in proptest::collection::vec(
                (proptest::collection::vec(segment_json(), 0..12), proptest::option::of(proptest::bool::ANY)),
                0..4,
            ),
        ) {
            let lists: Vec<serde_json::Value> = lists
                .into_iter()
                .map(|(segments, oriented)| {
                    let mut list = serde_json::json!({"segments": segments});
                    if let Some(o) = oriented {
                        list["oriented"] = serde_json::json!(o);
                    }
                    list
                })
                .collect();
            let text = serde_json::json!({
                "calibration": {"cameras": [{"name": "c", "width": 10, "height": 10,
                    "projection": [1,0,0,0, 0,1,0,0, 0,0,1,0]}]},
                "segments": {"lists": lists},
            })
            .to_string();
            proptest::prop_assert!(serde_json::from_str::<Fast>(&text).is_ok(), "{}", text);
            let (fast, reference) = both(&text);
            use prost::Message;
            proptest::prop_assert_eq!(
                fast.map(|r| r.encode_to_vec()),
                reference.map(|r| r.encode_to_vec()),
                "{}",
                text
            );
        }
    }

    #[test]
    fn gives_what_pbjson_gives_in_every_form() {
        let cal = r#""calibration": {"cameras": [{"name": "c", "width": 10, "height": 10,
            "projection": [1,0,0,0, 0,1,0,0, 0,0,1,0]}]}"#;
        for (i, text) in [
            format!(
                r#"{{{cal}, "segments": {{"lists": [{{"segments": [{{"u1": 1, "v1": 2.5, "u2": -3e2, "v2": 0.1, "gradient": 7}}], "oriented": true}}, {{}}, {{"segments": []}}]}}}}"#
            ),
            format!(
                r#"{{{cal}, "options": {{"tolerancePx": 2}}, "segments": {{"lists": [{{"segments": [{{"u1": 0.30000000000000004, "v1": 1e-300, "u2": 5, "v2": 6}}]}}]}}}}"#
            ),
            // Forms only pbjson reads (strings for numbers), and null and original field
            // names, which the fast reader takes or hands to pbjson for the small parts.
            format!(
                r#"{{{cal}, "segments": {{"lists": [{{"segments": [{{"u1": "NaN", "v1": "1.5", "u2": 3, "v2": 4}}]}}]}}}}"#
            ),
            format!(
                r#"{{{cal}, "segments": {{"lists": [{{"segments": [{{"u1": 1, "v1": 2, "u2": 3, "v2": 4, "gradient": null}}]}}]}}}}"#
            ),
            format!(r#"{{{cal}, "options": {{"tolerance_px": 2}}}}"#),
            // Errors: unknown fields, both inputs, wrong types, bad JSON.
            format!(r#"{{{cal}, "segment": {{}}}}"#),
            format!(r#"{{{cal}, "segments": {{"lists": []}}, "images": {{"images": []}}}}"#),
            format!(r#"{{{cal}, "segments": {{"lists": [{{"segments": [{{"u1": true}}]}}]}}}}"#),
            format!(
                r#"{{{cal}, "segments": {{"lists": [{{"segments": [{{"u1": 1, "w": 2}}]}}]}}}}"#
            ),
            "{".to_string(),
            "[]".to_string(),
            "{}".to_string(),
            // Arrays where proto3 JSON has objects (serde's derived structs would take them).
            format!(r#"{{{cal}, "segments": []}}"#),
            format!(r#"{{{cal}, "segments": {{"lists": [[]]}}}}"#),
            format!(r#"{{{cal}, "segments": {{"lists": [{{"segments": [[1, 2, 3, 4]]}}]}}}}"#),
        ]
        .iter()
        .enumerate()
        {
            // Those in the plain form the fast reader must take itself.
            let plain = serde_json::from_str::<Fast>(text).is_ok();
            assert_eq!(plain, [0, 1, 3, 4, 11].contains(&i), "{text}");
            let (fast, reference) = both(text);
            match (&fast, &reference) {
                (Ok(a), Ok(b)) => {
                    // NaN != NaN: compare the encodings.
                    use prost::Message;
                    assert_eq!(a.encode_to_vec(), b.encode_to_vec(), "{text}");
                }
                _ => assert_eq!(fast, reference, "{text}"),
            }
        }
    }
}
