//! Session messages ⇄ domain: poses (checked rigid), the session a `CreateSessionRequest`
//! describes, the match an `AddCaptureRequest` asks for, what a store keeps per capture, and
//! the fused map's `Map` message.
//!
//! A capture's 3D segments are stored in the rig frame with the capture's pose, not in the
//! world frame: the map is fused from them when asked, so fusion can improve without
//! migrating stored sessions.

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion};

use super::{match_params, pb, rig_from_calibration, InputError};
use trinocular_core::map::MapSegment;
use trinocular_core::segment::Segment3;

/// How far a pose's rotation block may be from a rotation (RᵀR − I, determinant − 1).
pub const POSE_TOLERANCE: f64 = 1e-6;
/// Longest session name, characters.
pub const MAX_NAME_CHARS: usize = 200;

/// The rigid transform of a `Pose` (16 doubles, row-major 4x4), or an error naming `field`.
pub fn pose_from_pb(pose: Option<&pb::Pose>, field: &str) -> Result<Isometry3<f64>, InputError> {
    let pb::Pose { matrix } = pose.ok_or_else(|| {
        InputError::new(
            field,
            "missing: a row-major 4x4 rigid transform, 16 numbers",
        )
    })?;
    let field = format!("{field}.matrix");
    if matrix.len() != 16 {
        return Err(InputError::new(
            field,
            format!(
                "needs exactly 16 numbers (row-major 4x4), got {}",
                matrix.len()
            ),
        ));
    }
    if let Some(i) = matrix.iter().position(|v| !v.is_finite()) {
        return Err(InputError::new(
            format!("{field}[{i}]"),
            format!("{} is not a finite number", matrix[i]),
        ));
    }
    let m = Matrix4::from_row_slice(matrix);
    if m.row(3)
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(a, b)| *a != b)
    {
        return Err(InputError::new(
            field,
            format!(
                "the last row must be 0 0 0 1, got {} {} {} {}",
                m[(3, 0)],
                m[(3, 1)],
                m[(3, 2)],
                m[(3, 3)]
            ),
        ));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let orthogonality = (r.transpose() * r - Matrix3::identity()).abs().max();
    let det = r.determinant();
    if orthogonality > POSE_TOLERANCE || (det - 1.0).abs() > POSE_TOLERANCE {
        return Err(InputError::new(
            field,
            format!(
                "the 3x3 block is not a rotation (|RᵀR − I| = {orthogonality:.2e}, det = {det:.6}): \
                 the pose must be rigid, without scale or reflection"
            ),
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Isometry3::from_parts(translation, rotation))
}

/// A `Pose` message.
pub fn pose_to_pb(pose: &Isometry3<f64>) -> pb::Pose {
    let m = pose.to_homogeneous();
    pb::Pose {
        matrix: (0..4)
            .flat_map(|r| (0..4).map(move |c| (r, c)))
            .map(|(r, c)| m[(r, c)])
            .collect(),
    }
}

/// Checks a `CreateSessionRequest`: the calibration and options as `Match` would, the map
/// options and the name.
pub fn check_create_session(request: &pb::CreateSessionRequest) -> Result<(), InputError> {
    let pb::CreateSessionRequest {
        name,
        calibration,
        options,
        map_options,
    } = request;
    if name.chars().count() > MAX_NAME_CHARS {
        return Err(InputError::new(
            "name",
            format!("longer than {MAX_NAME_CHARS} characters"),
        ));
    }
    rig_from_calibration(calibration.as_ref())?;
    match_params(options.as_ref())
        .check()
        .map_err(|e| InputError::new(format!("options.{}", e.field()), e.to_string()))?;
    super::extract_params(options.as_ref().and_then(|o| o.extract.as_ref()))
        .check()
        .map_err(|e| InputError::new(format!("options.extract.{}", e.field()), e.to_string()))?;
    if let Some(pb::MapOptions {
        min_observations: Some(0),
    }) = map_options
    {
        return Err(InputError::new(
            "map_options.min_observations",
            "must be at least 1",
        ));
    }
    Ok(())
}

/// The `MatchRequest` one capture of a session makes: the session's calibration and options,
/// the capture's input.
pub fn capture_match_request(
    calibration: pb::Calibration,
    options: Option<pb::MatchOptions>,
    input: Option<pb::add_capture_request::Input>,
) -> pb::MatchRequest {
    pb::MatchRequest {
        calibration: Some(calibration),
        options,
        input: input.map(|input| match input {
            pb::add_capture_request::Input::Segments(s) => pb::match_request::Input::Segments(s),
            pb::add_capture_request::Input::Images(i) => pb::match_request::Input::Images(i),
        }),
    }
}

/// An `AddCaptureRequest` (session id left empty) for segment lists seen from `rig_to_world`.
pub fn segment_capture(
    rig_to_world: &Isometry3<f64>,
    lists: &[trinocular_core::segment::SegmentList; 3],
) -> pb::AddCaptureRequest {
    pb::AddCaptureRequest {
        session_id: String::new(),
        rig_to_world: Some(pose_to_pb(rig_to_world)),
        input: Some(pb::add_capture_request::Input::Segments(
            pb::SegmentTriplet {
                lists: lists.iter().map(super::segment_list_to_pb).collect(),
            },
        )),
    }
}

/// The rig-frame 3D segments of a stored capture, and its pose.
pub fn stored_capture_segments(
    capture: &pb::StoredCapture,
) -> Result<(Isometry3<f64>, Vec<Segment3>), InputError> {
    let pose = pose_from_pb(capture.rig_to_world.as_ref(), "rig_to_world")?;
    let point = |p: &Option<pb::Point3>| {
        let p = p.unwrap_or_default();
        Point3::new(p.x, p.y, p.z)
    };
    let segments = capture
        .segments
        .iter()
        .map(|s| Segment3 {
            start: point(&s.start),
            end: point(&s.end),
        })
        .collect();
    Ok((pose, segments))
}

/// A session's fused map, world frame.
#[derive(Debug, Clone)]
pub struct SessionMap {
    pub session_id: String,
    pub segments: Vec<MapSegment>,
    /// Rig pose of each capture, in capture order.
    pub poses: Vec<Isometry3<f64>>,
    pub fuse_ms: f64,
}

/// The `Map` message of a fused map.
pub fn map_to_pb(map: &SessionMap) -> pb::Map {
    let point = |p: &nalgebra::Point3<f64>| pb::Point3 {
        x: p.x,
        y: p.y,
        z: p.z,
    };
    pb::Map {
        session_id: map.session_id.clone(),
        segments: map
            .segments
            .iter()
            .map(|s| pb::MapSegment {
                start: Some(point(&s.start)),
                end: Some(point(&s.end)),
                observations: s.observations,
                captures: s.captures.clone(),
            })
            .collect(),
        poses: map.poses.iter().map(pose_to_pb).collect(),
        fuse_ms: map.fuse_ms,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    fn pose(matrix: Vec<f64>) -> Option<pb::Pose> {
        Some(pb::Pose { matrix })
    }

    #[test]
    fn bad_poses_name_the_field_and_the_problem() {
        let field = |m: Vec<f64>| pose_from_pb(pose(m).as_ref(), "rig_to_world").unwrap_err();
        let mut identity = vec![0.0; 16];
        for i in 0..4 {
            identity[i * 5] = 1.0;
        }
        assert!(pose_from_pb(pose(identity.clone()).as_ref(), "p").is_ok());
        let e = pose_from_pb(None, "rig_to_world").unwrap_err();
        assert_eq!(e.field, "rig_to_world");
        let e = field(vec![1.0; 12]);
        assert_eq!(e.field, "rig_to_world.matrix");
        assert!(e.message.contains("16"), "{e}");
        let mut nan = identity.clone();
        nan[7] = f64::NAN;
        assert_eq!(field(nan).field, "rig_to_world.matrix[7]");
        let mut scaled = identity.clone();
        scaled[0] = 2.0;
        assert!(field(scaled).message.contains("not a rotation"));
        let mut mirrored = identity.clone();
        mirrored[0] = -1.0;
        assert!(field(mirrored).message.contains("det = -1"));
        let mut projective = identity;
        projective[12] = 0.5;
        assert!(field(projective).message.contains("last row"));
    }

    proptest! {
        #[test]
        fn poses_round_trip(
            axis in prop::array::uniform3(-1.0f64..1.0),
            angle in -3.1f64..3.1,
            t in prop::array::uniform3(-50.0f64..50.0),
        ) {
            let axis = Vector3::from(axis);
            prop_assume!(axis.norm() > 1e-3);
            let iso = Isometry3::new(Vector3::from(t), axis.normalize() * angle);
            let back = pose_from_pb(Some(&pose_to_pb(&iso)), "p").unwrap();
            prop_assert!((back.to_homogeneous() - iso.to_homogeneous()).abs().max() < 1e-12);
        }
    }
}
