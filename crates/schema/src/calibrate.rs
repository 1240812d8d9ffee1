//! `CalibrateRequest` ⇄ domain: the pattern, the images or the caller's correspondences, the
//! estimation options and the rig frame, checked and named by field. Running the calibration
//! on a checked request is the server's (`trinocular_server::service::calibration`).

use nalgebra::{Isometry3, Point2, Point3, Vector3};

use crate::session::pose_from_pb;
use crate::{extract_params, from_json, pb, InputError};
use trinocular_core::calibrate::estimate::EstimateOptions;
use trinocular_core::calibrate::{CalibrationPattern, GridBoard};
use trinocular_core::extract::decode::DecodeLimits;
use trinocular_core::extract::GreyImage;

/// Where the 3D–2D correspondences come from.
#[derive(Debug, Clone)]
pub enum CalibrateSource {
    Images([GreyImage; 3]),
    Correspondences {
        points_3d: Vec<Point3<f64>>,
        points_2d: [Vec<Point2<f64>>; 3],
        sizes: [(u32, u32); 3],
    },
}

/// The name `CalibrateRequest.pattern_to_rig` had before the schema named every frame
/// transform source_to_target (like `rig_to_world`); requests that use it are still read.
pub const LEGACY_PATTERN_TO_RIG: &str = "rig_from_pattern";

/// Parses a `CalibrateRequest` from proto3 JSON, reading the pose under its former name
/// (`rigFromPattern` or `rig_from_pattern`) as `patternToRig`.
pub fn calibrate_request_from_json(text: &str) -> Result<pb::CalibrateRequest, InputError> {
    if !(text.contains("rigFromPattern") || text.contains(LEGACY_PATTERN_TO_RIG)) {
        return from_json("request", text);
    }
    let mut value: serde_json::Value = from_json("request", text)?;
    if let Some(fields) = value.as_object_mut() {
        for legacy in ["rigFromPattern", LEGACY_PATTERN_TO_RIG] {
            if let Some(pose) = fields.remove(legacy) {
                if fields.contains_key("patternToRig") || fields.contains_key("pattern_to_rig") {
                    return Err(InputError::new(
                        "pattern_to_rig",
                        format!("given twice, also as {legacy} (its former name): give one"),
                    ));
                }
                fields.insert("patternToRig".to_string(), pose);
            }
        }
    }
    crate::located::from_json_value("request", value)
}

/// A checked `CalibrateRequest`.
#[derive(Debug, Clone)]
pub struct CalibrateInput {
    pub pattern: CalibrationPattern,
    pub source: CalibrateSource,
    pub options: EstimateOptions,
    pub extract: trinocular_core::extract::Params,
    pub pattern_to_rig: Option<Isometry3<f64>>,
    pub names: [String; 3],
}

fn point3(p: &Option<pb::Point3>) -> Point3<f64> {
    let p = p.unwrap_or_default();
    Point3::new(p.x, p.y, p.z)
}

fn vector3(p: &Option<pb::Point3>) -> Vector3<f64> {
    point3(p).coords
}

/// The pattern of a request: its boards, or the default two-board pattern when none is given.
pub fn pattern_from_pb(
    pattern: Option<&pb::CalibrationPattern>,
) -> Result<CalibrationPattern, InputError> {
    let boards = pattern.map(|p| p.boards.as_slice()).unwrap_or_default();
    if boards.is_empty() {
        return Ok(CalibrationPattern::default());
    }
    let pattern = CalibrationPattern {
        boards: boards
            .iter()
            .map(|b| {
                let pb::GridBoard {
                    origin,
                    u_axis,
                    v_axis,
                    rows,
                    cols,
                    square,
                    pitch,
                    missing,
                } = b;
                GridBoard {
                    origin: point3(origin),
                    u_axis: vector3(u_axis),
                    v_axis: vector3(v_axis),
                    rows: *rows,
                    cols: *cols,
                    square: *square,
                    pitch: *pitch,
                    missing: missing.iter().map(|c| (c.row, c.col)).collect(),
                }
            })
            .collect(),
    };
    pattern
        .check()
        .map_err(|e| InputError::new(format!("pattern.{}", e.field), e.message))?;
    Ok(pattern)
}

/// Converts and checks a `CalibrateRequest`; images are decoded within `limits`.
pub fn calibrate_request(
    request: &pb::CalibrateRequest,
    limits: &DecodeLimits,
) -> Result<CalibrateInput, InputError> {
    let pb::CalibrateRequest {
        pattern,
        input,
        pattern_to_rig,
        options,
        camera_names,
    } = request;
    let pattern = pattern_from_pb(pattern.as_ref())?;
    let names: [String; 3] = match camera_names.len() {
        0 => std::array::from_fn(|i| format!("cam{}", i + 1)),
        3 => {
            let max = crate::convert::MAX_CAMERA_NAME_CHARS;
            if let Some(i) = (0..3).find(|&i| camera_names[i].chars().count() > max) {
                return Err(InputError::new(
                    format!("camera_names[{i}]"),
                    format!("longer than {max} characters"),
                ));
            }
            std::array::from_fn(|i| camera_names[i].clone())
        }
        n => {
            return Err(InputError::new(
                "camera_names",
                format!("give none or three names, got {n}"),
            ))
        }
    };
    let pattern_to_rig = match pattern_to_rig {
        Some(pose) => Some(pose_from_pb(Some(pose), "pattern_to_rig")?),
        None => None,
    };
    let distortion = options.as_ref().and_then(|o| o.distortion).unwrap_or(false);
    let extract = extract_params(options.as_ref().and_then(|o| o.extract.as_ref()));
    extract
        .check()
        .map_err(|e| InputError::new(format!("options.extract.{}", e.field()), e.to_string()))?;
    let source = match input {
        Some(pb::calibrate_request::Input::Images(triplet)) => {
            CalibrateSource::Images(crate::images(triplet, limits)?)
        }
        Some(pb::calibrate_request::Input::Correspondences(c)) => correspondences(c)?,
        None => {
            return Err(InputError::new(
                "input",
                "missing: give images or correspondences",
            ))
        }
    };
    Ok(CalibrateInput {
        pattern,
        source,
        options: EstimateOptions {
            distortion,
            ..EstimateOptions::default()
        },
        extract,
        pattern_to_rig,
        names,
    })
}

/// Largest image coordinate of a correspondence, pixels: far beyond any image, far below where
/// the estimate's products of coordinates lose their meaning.
const MAX_CORRESPONDENCE_PX: f64 = 1e6;
/// Largest reference point coordinate, metres.
const MAX_CORRESPONDENCE_M: f64 = 1e6;

fn correspondences(c: &pb::Correspondences) -> Result<CalibrateSource, InputError> {
    let pb::Correspondences {
        points_3d,
        points_2d,
    } = c;
    if points_2d.len() != 3 {
        return Err(InputError::new(
            "correspondences.points_2d",
            format!(
                "needs exactly 3 lists, one per camera, got {}",
                points_2d.len()
            ),
        ));
    }
    for (i, list) in points_2d.iter().enumerate() {
        if list.points.len() != points_3d.len() {
            return Err(InputError::new(
                format!("correspondences.points_2d[{i}].points"),
                format!(
                    "{} points, but points_3d has {}: one image point per reference point",
                    list.points.len(),
                    points_3d.len()
                ),
            ));
        }
        if list.width == 0 || list.height == 0 {
            return Err(InputError::new(
                format!("correspondences.points_2d[{i}].width"),
                "the camera's image size is needed (width and height, pixels)",
            ));
        }
        for (j, p) in list.points.iter().enumerate() {
            if !(p.u.is_finite() && p.v.is_finite())
                || p.u.abs().max(p.v.abs()) > MAX_CORRESPONDENCE_PX
            {
                return Err(InputError::new(
                    format!("correspondences.points_2d[{i}].points[{j}]"),
                    format!(
                        "({}, {}): coordinates must be finite pixels within \
                         ±{MAX_CORRESPONDENCE_PX}",
                        p.u, p.v
                    ),
                ));
            }
        }
    }
    for (j, p) in points_3d.iter().enumerate() {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
            || p.x.abs().max(p.y.abs()).max(p.z.abs()) > MAX_CORRESPONDENCE_M
        {
            return Err(InputError::new(
                format!("correspondences.points_3d[{j}]"),
                format!(
                    "({}, {}, {}): coordinates must be finite metres within \
                     ±{MAX_CORRESPONDENCE_M}",
                    p.x, p.y, p.z
                ),
            ));
        }
    }
    Ok(CalibrateSource::Correspondences {
        points_3d: points_3d
            .iter()
            .map(|p| Point3::new(p.x, p.y, p.z))
            .collect(),
        points_2d: std::array::from_fn(|i| {
            points_2d[i]
                .points
                .iter()
                .map(|p| Point2::new(p.u, p.v))
                .collect()
        }),
        sizes: std::array::from_fn(|i| (points_2d[i].width, points_2d[i].height)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const POSE: &str = r#"{"matrix": [1,0,0,0.1, 0,1,0,0, 0,0,1,0, 0,0,0,1]}"#;

    #[test]
    fn the_pose_is_read_under_its_name_and_its_former_one() {
        let new = calibrate_request_from_json(&format!(r#"{{"patternToRig": {POSE}}}"#)).unwrap();
        let pose = new.pattern_to_rig.clone().expect("the pose");
        assert_eq!(pose.matrix[3], 0.1);
        for legacy in ["rigFromPattern", "rig_from_pattern"] {
            let old = calibrate_request_from_json(&format!(r#"{{"{legacy}": {POSE}}}"#)).unwrap();
            assert_eq!(old, new, "{legacy}");
        }
        let both = format!(r#"{{"patternToRig": {POSE}, "rigFromPattern": {POSE}}}"#);
        assert_eq!(
            calibrate_request_from_json(&both).unwrap_err().field,
            "pattern_to_rig"
        );
        // Without the former name the text is read as it is.
        assert_eq!(
            calibrate_request_from_json("{}").unwrap(),
            pb::CalibrateRequest::default()
        );
    }
}
