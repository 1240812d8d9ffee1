//! Session messages ⇄ domain: poses (checked rigid), the session a `CreateSessionRequest`
//! describes, the match an `AddCaptureRequest` asks for, what a store keeps per capture, and
//! the fused map's `Map` message.
//!
//! A capture's 3D segments are stored in the rig frame with the capture's pose, not in the
//! world frame: the map is fused from them when asked, so fusion can improve without
//! migrating stored sessions.

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Matrix6, Point3, Rotation3, Translation3, UnitQuaternion,
};

use super::{match_params, pb, rig_from_calibration, InputError};
use trinocular_core::map::poses::RelativePose;
use trinocular_core::map::{MapSegment, Measured, PosePrior, Registration, RegistrationStatus};
use trinocular_core::segment::Segment3;

/// How far a pose's rotation block may be from a rotation (RᵀR − I, determinant − 1) and be
/// taken as it is, without a warning.
pub const POSE_TOLERANCE: f64 = 1e-6;
/// Longest session name, characters.
pub const MAX_NAME_CHARS: usize = 200;

/// A rigid transform from a `Pose` message: its matrix, or its quaternion and translation.
/// A matrix within [`NEAR_RIGID`] of rigid is replaced by the nearest rotation; use
/// [`pose_from_pb_noting`] to learn when that happened.
pub fn pose_from_pb(pose: Option<&pb::Pose>, field: &str) -> Result<Isometry3<f64>, InputError> {
    pose_from_pb_noting(pose, field).map(|(pose, _)| pose)
}

/// How far from orthonormal (max |RᵀR − I|, and |det − 1|) a pose's rotation block may be and
/// still be accepted, re-orthonormalised: a pose printed to three or four digits.
pub const NEAR_RIGID: f64 = 1e-3;

/// [`pose_from_pb`], and a warning when the pose was corrected to be taken.
pub fn pose_from_pb_noting(
    pose: Option<&pb::Pose>,
    field: &str,
) -> Result<(Isometry3<f64>, Option<String>), InputError> {
    let pb::Pose {
        matrix,
        quaternion,
        translation,
    } = pose.ok_or_else(|| {
        InputError::new(
            field,
            "missing: a rigid transform (a row-major 4x4 as 16 numbers, or a quaternion w x y z \
             and a translation)",
        )
    })?;
    let finite = |values: &[f64], name: &str| -> Result<(), InputError> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(i) => Err(InputError::new(
                format!("{field}.{name}[{i}]"),
                format!("{} is not a finite number", values[i]),
            )),
            None => Ok(()),
        }
    };
    if !quaternion.is_empty() || !translation.is_empty() {
        if !matrix.is_empty() {
            return Err(InputError::new(
                field,
                "give the matrix or the quaternion and translation, not both",
            ));
        }
        for (values, name, n) in [
            (quaternion, "quaternion", 4),
            (translation, "translation", 3),
        ] {
            if values.len() != n {
                return Err(InputError::new(
                    format!("{field}.{name}"),
                    format!("needs exactly {n} numbers, got {}", values.len()),
                ));
            }
            finite(values, name)?;
        }
        let q =
            nalgebra::Quaternion::new(quaternion[0], quaternion[1], quaternion[2], quaternion[3]);
        let norm = q.norm();
        if (norm - 1.0).abs() > NEAR_RIGID {
            return Err(InputError::new(
                format!("{field}.quaternion"),
                format!("must be a unit quaternion (w, x, y, z), its norm is {norm:.6}"),
            ));
        }
        let warning = ((norm - 1.0).abs() > POSE_TOLERANCE)
            .then(|| format!("{field}.quaternion: norm {norm:.6} normalised to 1"));
        let pose = Isometry3::from_parts(
            Translation3::new(translation[0], translation[1], translation[2]),
            UnitQuaternion::from_quaternion(q),
        );
        return Ok((pose, warning));
    }
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
    if orthogonality > NEAR_RIGID || (det - 1.0).abs() > NEAR_RIGID {
        return Err(InputError::new(
            field,
            format!(
                "the 3x3 block is not a rotation (|RᵀR − I| = {orthogonality:.2e}, det = {det:.6}): \
                 the pose must be rigid, without scale or reflection"
            ),
        ));
    }
    let (rotation, warning) =
        if orthogonality > POSE_TOLERANCE || (det - 1.0).abs() > POSE_TOLERANCE {
            (
                nearest_rotation(&r),
                Some(format!(
                    "{field}: the rotation block was {orthogonality:.1e} from orthonormal and was \
                 replaced by the nearest rotation"
                )),
            )
        } else {
            (r, None)
        };
    let rotation =
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation));
    let translation = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok((Isometry3::from_parts(translation, rotation), warning))
}

/// Farthest a pose a client gives a capture may put its rig from the world's origin, metres
/// along each axis: 10,000 km holds any frame on Earth (a UTM northing included). A pose
/// beyond it is no place a robot maps; taken, a pose 1e189 m away made the session's top view
/// a picture of 1e186 pixels (found by the `session_whole` fuzz target).
pub const MAX_POSE_TRANSLATION_M: f64 = 1e7;

/// [`pose_from_pb_noting`] for the pose a client gives a capture (`AddCaptureRequest.
/// rig_to_world`): also within [`MAX_POSE_TRANSLATION_M`] of the origin, the number beyond it
/// named (`FIELD.matrix[3]`, `[7]`, `[11]` or `FIELD.translation[i]`).
pub fn capture_pose_from_pb(
    pose: Option<&pb::Pose>,
    field: &str,
) -> Result<(Isometry3<f64>, Option<String>), InputError> {
    let (taken, warning) = pose_from_pb_noting(pose, field)?;
    let t = taken.translation.vector;
    if let Some(axis) = (0..3).find(|&k| t[k].abs() > MAX_POSE_TRANSLATION_M) {
        let name = match pose {
            Some(p) if p.matrix.is_empty() => format!("{field}.translation[{axis}]"),
            _ => format!("{field}.matrix[{}]", 4 * axis + 3),
        };
        return Err(InputError::new(
            name,
            format!(
                "{} m from the world's origin: a capture's pose must lie within {:.0e} m of it \
                 along each axis",
                t[axis], MAX_POSE_TRANSLATION_M
            ),
        ));
    }
    Ok((taken, warning))
}

/// The rotation nearest `m` (its polar factor, by SVD): for a matrix already close to one,
/// which the callers check first (a reflection is not close to any).
pub(crate) fn nearest_rotation(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    svd.u.expect("u asked for") * svd.v_t.expect("v_t asked for")
}

/// A `Pose` message.
pub fn pose_to_pb(pose: &Isometry3<f64>) -> pb::Pose {
    let m = pose.to_homogeneous();
    pb::Pose {
        matrix: (0..4)
            .flat_map(|r| (0..4).map(move |c| (r, c)))
            .map(|(r, c)| m[(r, c)])
            .collect(),
        ..pb::Pose::default()
    }
}

/// Checks a session id, given in a path or chosen by a client: ids are store keys and appear
/// in logs, so letters, digits and '-', 1 to 64.
pub fn check_session_id(id: &str) -> Result<(), InputError> {
    if id.is_empty() || id.len() > 64 || !id.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-')
    {
        let shown: String = id.chars().take(64).collect();
        let more = if shown.len() < id.len() { "..." } else { "" };
        return Err(InputError::new(
            "session_id",
            format!("{shown:?}{more} is not a session id (letters, digits and '-', up to 64)"),
        ));
    }
    Ok(())
}

/// Checks a `CreateSessionRequest`: the calibration and options as `Match` would, the map
/// options, the name and the session id if the client chose one.
pub fn check_create_session(request: &pb::CreateSessionRequest) -> Result<(), InputError> {
    let pb::CreateSessionRequest {
        name,
        calibration,
        options,
        map_options,
        session_id,
    } = request;
    if !session_id.is_empty() {
        check_session_id(session_id)?;
    }
    if name.chars().count() > MAX_NAME_CHARS {
        return Err(InputError::new(
            "name",
            format!("longer than {MAX_NAME_CHARS} characters"),
        ));
    }
    crate::convert::one_line("name", name)?;
    rig_from_calibration(calibration.as_ref())?;
    match_params(options.as_ref())
        .check()
        .map_err(|e| InputError::new(format!("options.{}", e.field()), e.to_string()))?;
    super::extract_params(options.as_ref().and_then(|o| o.extract.as_ref()))
        .check()
        .map_err(|e| InputError::new(format!("options.extract.{}", e.field()), e.to_string()))?;
    if let Some(pb::MapOptions {
        min_observations: Some(0),
        ..
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
        rig_to_world_covariance: Vec::new(),
        capture_id: String::new(),
    }
}

/// Largest standard deviation a pose prior may state: 30° of rotation, 10 m of translation
/// (beyond them a pose says nothing registration could start from).
pub const MAX_PRIOR_ROTATION_SIGMA_DEG: f64 = 30.0;
pub const MAX_PRIOR_TRANSLATION_SIGMA_M: f64 = 10.0;
/// Smallest variance a prior may state (radians², metres²): its inverse must stay finite.
pub const MIN_PRIOR_VARIANCE: f64 = 1e-20;

/// The prior of a capture's pose: `pose` with the 6x6 row-major `covariance` (empty for the
/// default), or an error naming `field`.
pub fn pose_prior(
    pose: Isometry3<f64>,
    covariance: &[f64],
    field: &str,
) -> Result<PosePrior, InputError> {
    if covariance.is_empty() {
        return Ok(PosePrior::with_default_covariance(pose));
    }
    if covariance.len() != 36 {
        return Err(InputError::new(
            field,
            format!(
                "needs 36 numbers (a row-major 6x6: rotation, then translation) or none for the \
                 default, got {}",
                covariance.len()
            ),
        ));
    }
    if let Some(i) = covariance.iter().position(|v| !v.is_finite()) {
        return Err(InputError::new(
            format!("{field}[{i}]"),
            format!("{} is not a finite number", covariance[i]),
        ));
    }
    let m = Matrix6::from_row_slice(covariance);
    let scale = m.abs().max();
    if (m - m.transpose()).abs().max() > 1e-9 * scale {
        return Err(InputError::new(field, "must be symmetric"));
    }
    let limits = [
        MAX_PRIOR_ROTATION_SIGMA_DEG.to_radians(),
        MAX_PRIOR_TRANSLATION_SIGMA_M,
    ];
    for i in 0..6 {
        let limit = limits[i / 3];
        if m[(i, i)] > limit * limit {
            return Err(InputError::new(
                format!("{field}[{}]", 7 * i),
                format!(
                    "a standard deviation of {:.3} is more than the {limit:.3} a prior may state \
                     ({MAX_PRIOR_ROTATION_SIGMA_DEG}° of rotation, \
                     {MAX_PRIOR_TRANSLATION_SIGMA_M} m of translation)",
                    m[(i, i)].sqrt()
                ),
            ));
        }
    }
    if let Some(i) = (0..6).find(|&i| m[(i, i)] < MIN_PRIOR_VARIANCE) {
        return Err(InputError::new(
            format!("{field}[{}]", 7 * i),
            format!(
                "a variance of {:e} is below {MIN_PRIOR_VARIANCE:e}: an exact pose has a tiny \
                 variance, not none",
                m[(i, i)]
            ),
        ));
    }
    if m.cholesky().is_none() {
        return Err(InputError::new(field, "must be positive definite"));
    }
    Ok(PosePrior {
        rig_to_world: pose,
        covariance: m,
    })
}

/// A 6x6 matrix as 36 numbers, row-major.
pub fn matrix6_to_vec(m: &Matrix6<f64>) -> Vec<f64> {
    m.transpose().as_slice().to_vec()
}

/// The `Registration` message.
pub fn registration_to_pb(r: &Registration) -> pb::Registration {
    pb::Registration {
        status: status_to_pb(r.status) as i32,
        rig_to_world: Some(pose_to_pb(&r.rig_to_world)),
        covariance: matrix6_to_vec(&r.covariance),
        inliers: r.inliers,
        rotation_change_deg: r.rotation_change_deg,
        translation_change_m: r.translation_change_m,
    }
}

pub fn status_to_pb(status: RegistrationStatus) -> pb::RegistrationStatus {
    match status {
        RegistrationStatus::Registered => pb::RegistrationStatus::Registered,
        RegistrationStatus::EmptyMap => pb::RegistrationStatus::EmptyMap,
        RegistrationStatus::TooFewInCommon => pb::RegistrationStatus::TooFewInCommon,
        RegistrationStatus::DisagreesWithPrior => pb::RegistrationStatus::DisagreesWithPrior,
    }
}

/// A `MatchResponse` without its uncertain 3D segments and their triplets, renumbered: what
/// the same match answers when `include_uncertain` is not asked for (the pipeline decides
/// every segment alike either way and only leaves them out at the end).
pub fn certain_only(response: &pb::MatchResponse) -> pb::MatchResponse {
    let mut triplets = Vec::new();
    let mut segments_3d = Vec::new();
    for s in response.segments_3d.iter().filter(|s| !s.uncertain) {
        let first = triplets.len() as u32;
        triplets.extend(
            s.triplets
                .iter()
                .filter_map(|&t| response.triplets.get(t as usize).cloned()),
        );
        segments_3d.push(pb::Segment3 {
            triplet: first,
            triplets: (first..triplets.len() as u32).collect(),
            ..s.clone()
        });
    }
    let mut stats = response.stats.clone();
    if let Some(stats) = stats.as_mut() {
        stats.segments_3d = segments_3d.len() as u32;
    }
    pb::MatchResponse {
        triplets,
        segments_3d,
        stats,
        extracted: response.extracted.clone(),
    }
}

/// What the map and registration take of a stored capture.
#[derive(Debug, Clone)]
pub struct StoredSegments {
    /// The pose the map uses, and its covariance.
    pub pose: PosePrior,
    /// The pose as given, with its covariance.
    pub prior: PosePrior,
    /// The segments the map fuses: those that met the gate, rig frame.
    pub certain: Vec<Segment3>,
    /// Every segment with its covariance, rig frame, for registration.
    pub measured: Vec<Measured>,
    /// How the capture was placed when it was added (unspecified: stored before
    /// registration).
    pub status: pb::RegistrationStatus,
}

impl StoredSegments {
    /// The segments of a `MatchResponse` or a stored capture with their covariances (1 cm
    /// across each endpoint where a segment has none).
    pub fn measured_of(segments: &[pb::Segment3]) -> Vec<Measured> {
        segments.iter().map(measured).collect()
    }
}

fn measured(s: &pb::Segment3) -> Measured {
    let point = |p: &Option<pb::Point3>| {
        let p = p.unwrap_or_default();
        Point3::new(p.x, p.y, p.z)
    };
    let (start, end) = (point(&s.start), point(&s.end));
    let covariance = if s.covariance.len() == 36 && s.covariance.iter().all(|v| v.is_finite()) {
        // The shift the three views share is shared with the other captures of the scene
        // too: registration and fusion compare segments by what they do not share.
        let shift = if s.shift_sigma_m.is_finite() {
            s.shift_sigma_m
        } else {
            0.0
        };
        Matrix6::from_row_slice(&s.covariance)
            - trinocular_core::pipeline::shared_shift_covariance(&start, &end, shift)
    } else {
        Matrix6::identity() * LEGACY_SEGMENT_SIGMA_M.powi(2)
    };
    Measured {
        start,
        end,
        covariance,
        uncertain: s.uncertain,
    }
}

/// Covariance of a stored segment that has none (stored before registration): 1 cm across
/// each endpoint.
const LEGACY_SEGMENT_SIGMA_M: f64 = 0.01;

/// What the map and registration take of a stored capture.
pub fn stored_capture_segments(capture: &pb::StoredCapture) -> Result<StoredSegments, InputError> {
    let pose = pose_from_pb(capture.rig_to_world.as_ref(), "rig_to_world")?;
    let prior = stored_prior(
        pose,
        capture.prior_rig_to_world.as_ref(),
        &capture.prior_covariance,
    )?;
    let covariance = pose_prior(pose, &capture.pose_covariance, "pose_covariance")?.covariance;
    let measured = StoredSegments::measured_of(&capture.segments);
    let certain = capture
        .segments
        .iter()
        .zip(&measured)
        .filter(|(s, _)| !s.uncertain)
        .map(|(_, m)| Segment3 {
            start: m.start,
            end: m.end,
        })
        .collect();
    Ok(StoredSegments {
        pose: PosePrior {
            rig_to_world: pose,
            covariance,
        },
        prior,
        certain,
        measured,
        status: pb::RegistrationStatus::try_from(capture.status).unwrap_or_default(),
    })
}

/// The pose a stored capture was given and its covariance: what the session's pose graph
/// starts from. `pose` is the stored pose the map uses, which is also the given one in
/// captures stored before registration (they have no other).
fn stored_prior(
    pose: Isometry3<f64>,
    prior_rig_to_world: Option<&pb::Pose>,
    prior_covariance: &[f64],
) -> Result<PosePrior, InputError> {
    let prior = match prior_rig_to_world {
        Some(p) => pose_from_pb(Some(p), "prior_rig_to_world")?,
        None => pose,
    };
    pose_prior(prior, prior_covariance, "prior_covariance")
}

/// The pose a capture was given with its covariance, and the pose-graph edges it found when
/// it was added, read from its header (`from`: its index in the session): all that placing
/// a new capture needs of a capture that is not one of its neighbours.
pub fn stored_header_of(
    header: &pb::StoredCaptureHeader,
    from: usize,
) -> Result<(PosePrior, Vec<RelativePose>), InputError> {
    let pose = pose_from_pb(header.rig_to_world.as_ref(), "rig_to_world")?;
    let prior = stored_prior(
        pose,
        header.prior_rig_to_world.as_ref(),
        &header.prior_covariance,
    )?;
    Ok((prior, edges_of(&header.edges, from)?))
}

/// The pose-graph edges a capture found when it was added, as stored.
pub fn edges_to_pb(edges: &[RelativePose]) -> Vec<pb::PoseEdge> {
    edges
        .iter()
        .map(|e| pb::PoseEdge {
            to: e.to as u64,
            pose: Some(pose_to_pb(&e.pose)),
            information: matrix6_to_vec(&e.information),
            inliers: e.inliers,
        })
        .collect()
}

/// The edges stored with capture `from`: each to an earlier capture, with a finite, symmetric
/// information matrix. An edge that is not (a damaged store) is an error naming it.
pub fn edges_of(edges: &[pb::PoseEdge], from: usize) -> Result<Vec<RelativePose>, InputError> {
    edges
        .iter()
        .enumerate()
        .map(|(k, e)| {
            let field = |name: &str| format!("edges[{k}].{name}");
            let to = usize::try_from(e.to)
                .ok()
                .filter(|&to| to < from)
                .ok_or_else(|| {
                    InputError::new(field("to"), format!("must name a capture before {from}"))
                })?;
            let pose = pose_from_pb(e.pose.as_ref(), &field("pose"))?;
            if e.information.len() != 36 || !e.information.iter().all(|v| v.is_finite()) {
                return Err(InputError::new(
                    field("information"),
                    "must be 36 finite numbers",
                ));
            }
            let information = Matrix6::from_row_slice(&e.information);
            Ok(RelativePose {
                from,
                to,
                pose,
                information: (information + information.transpose()) * 0.5,
                inliers: e.inliers,
            })
        })
        .collect()
}

/// A session's fused map, world frame.
#[derive(Debug, Clone)]
pub struct SessionMap {
    pub session_id: String,
    pub segments: Vec<MapSegment>,
    /// Rig pose of each capture, in capture order: the one the map uses.
    pub poses: Vec<Isometry3<f64>>,
    /// … and as the client gave it.
    pub prior_poses: Vec<Isometry3<f64>>,
    pub fuse_ms: f64,
    /// Where the session rig's cameras are, for the top views.
    pub rig: trinocular_core::map::export::RigMarker,
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
                covariance: matrix6_to_vec(&s.covariance),
                direction_sigma_deg: s.direction_sigma_deg,
                position_sigma_m: s.position_sigma_m,
                uncertain: s.uncertain,
            })
            .collect(),
        poses: map.poses.iter().map(pose_to_pb).collect(),
        fuse_ms: map.fuse_ms,
        prior_poses: map.prior_poses.iter().map(pose_to_pb).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    fn pose(matrix: Vec<f64>) -> Option<pb::Pose> {
        Some(pb::Pose {
            matrix,
            ..pb::Pose::default()
        })
    }

    #[test]
    fn pose_priors_are_checked_and_default_when_absent() {
        let pose = Isometry3::identity();
        let default = pose_prior(pose, &[], "c").unwrap();
        assert_eq!(default, PosePrior::with_default_covariance(pose));
        let field = |c: Vec<f64>| pose_prior(pose, &c, "c").unwrap_err();
        assert!(field(vec![0.0; 35]).message.contains("36"));
        let mut diagonal = vec![0.0; 36];
        for i in 0..6 {
            diagonal[7 * i] = 1e-4;
        }
        assert!(pose_prior(pose, &diagonal, "c").is_ok());
        let mut nan = diagonal.clone();
        nan[8] = f64::NAN;
        assert_eq!(field(nan).field, "c[8]");
        let mut skew = diagonal.clone();
        skew[1] = 1e-5;
        assert!(field(skew).message.contains("symmetric"));
        let mut wide = diagonal.clone();
        wide[21] = 200.0;
        assert_eq!(field(wide).field, "c[21]");
        assert!(field(vec![1e-4; 36]).message.contains("positive definite"));
        let mut zero = diagonal.clone();
        zero[35] = 0.0;
        assert_eq!(field(zero).field, "c[35]");
    }

    #[test]
    fn registration_and_fusion_take_the_shared_shift_out_of_a_covariance() {
        let (start, end) = (Point3::new(0.2, 0.1, 2.0), Point3::new(0.2, 0.6, 2.4));
        let own = Matrix6::from_fn(|r, c| if r == c { 4e-6 } else { 1e-7 });
        let sigma = 0.0015;
        let reported =
            own + trinocular_core::pipeline::shared_shift_covariance(&start, &end, sigma);
        let p = |p: Point3<f64>| {
            Some(pb::Point3 {
                x: p.x,
                y: p.y,
                z: p.z,
            })
        };
        let segment = pb::Segment3 {
            start: p(start),
            end: p(end),
            covariance: reported.transpose().as_slice().to_vec(),
            shift_sigma_m: sigma,
            ..Default::default()
        };
        let measured = StoredSegments::measured_of(std::slice::from_ref(&segment));
        assert!((measured[0].covariance - own).abs().max() < 1e-18);
        // A capture stored before the shift was reported (none given) keeps its covariance.
        let older = pb::Segment3 {
            shift_sigma_m: 0.0,
            ..segment
        };
        let measured = StoredSegments::measured_of(std::slice::from_ref(&older));
        assert_eq!(measured[0].covariance, reported);
    }

    #[test]
    fn certain_only_drops_uncertain_segments_and_renumbers_their_triplets() {
        let triplet = |s1| pb::Triplet {
            s1,
            ..Default::default()
        };
        let segment = |triplets: Vec<u32>, uncertain| pb::Segment3 {
            triplet: triplets[0],
            triplets,
            uncertain,
            ..Default::default()
        };
        let response = pb::MatchResponse {
            triplets: (0..4).map(triplet).collect(),
            segments_3d: vec![
                segment(vec![0], true),
                segment(vec![1, 2], false),
                segment(vec![3], false),
            ],
            stats: Some(pb::MatchStats {
                segments_3d: 3,
                ..Default::default()
            }),
            extracted: Vec::new(),
        };
        let certain = certain_only(&response);
        let firsts: Vec<u32> = certain.triplets.iter().map(|t| t.s1).collect();
        assert_eq!(firsts, [1, 2, 3]);
        let kept: Vec<Vec<u32>> = certain
            .segments_3d
            .iter()
            .map(|s| s.triplets.clone())
            .collect();
        assert_eq!(kept, [vec![0, 1], vec![2]]);
        assert_eq!(certain.segments_3d[1].triplet, 2);
        assert_eq!(certain.stats.unwrap().segments_3d, 2);
    }

    #[test]
    fn a_capture_pose_beyond_the_earth_is_refused_naming_the_number() {
        let mut matrix = vec![0.0; 16];
        for i in 0..4 {
            matrix[i * 5] = 1.0;
        }
        // A UTM position: taken.
        matrix[3] = 500_000.0;
        matrix[7] = 5_000_000.0;
        let utm = pb::Pose {
            matrix: matrix.clone(),
            ..pb::Pose::default()
        };
        assert!(capture_pose_from_pb(Some(&utm), "rig_to_world").is_ok());
        matrix[7] = -1.0187e189;
        let far = pb::Pose {
            matrix,
            ..pb::Pose::default()
        };
        let e = capture_pose_from_pb(Some(&far), "rig_to_world").unwrap_err();
        assert_eq!(e.field, "rig_to_world.matrix[7]");
        assert!(e.message.contains("within 1e7 m"), "{e}");
        let far = pb::Pose {
            quaternion: vec![1.0, 0.0, 0.0, 0.0],
            translation: vec![0.0, 0.0, 2e7],
            ..pb::Pose::default()
        };
        let e = capture_pose_from_pb(Some(&far), "p").unwrap_err();
        assert_eq!(e.field, "p.translation[2]");
        // Stored poses are read as they were stored: a refined pose is not refused.
        assert!(pose_from_pb(Some(&far), "p").is_ok());
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
        let mut projective = identity.clone();
        projective[12] = 0.5;
        assert!(field(projective).message.contains("last row"));
        let quaternion = |q: Vec<f64>, t: Vec<f64>| pb::Pose {
            quaternion: q,
            translation: t,
            ..pb::Pose::default()
        };
        let e = pose_from_pb(
            Some(&quaternion(vec![2.0, 0.0, 0.0, 0.0], vec![0.0; 3])),
            "p",
        );
        assert_eq!(e.unwrap_err().field, "p.quaternion");
        let e = pose_from_pb(
            Some(&quaternion(vec![1.0, 0.0, 0.0, 0.0], vec![0.0; 2])),
            "p",
        );
        assert_eq!(e.unwrap_err().field, "p.translation");
        let both = pb::Pose {
            matrix: identity,
            ..quaternion(vec![1.0, 0.0, 0.0, 0.0], vec![0.0; 3])
        };
        assert!(pose_from_pb(Some(&both), "p")
            .unwrap_err()
            .message
            .contains("not both"));
    }

    #[test]
    fn a_pose_comes_as_a_quaternion_or_a_near_rigid_matrix_noted() {
        let truth = Isometry3::new(
            nalgebra::Vector3::new(0.4, -1.2, 0.9),
            nalgebra::Vector3::new(0.1, -0.2, 0.7),
        );
        let q = truth.rotation.quaternion();
        let t = truth.translation.vector;
        let given = pb::Pose {
            quaternion: vec![q.w, q.i, q.j, q.k],
            translation: vec![t.x, t.y, t.z],
            ..pb::Pose::default()
        };
        let (read, warning) = pose_from_pb_noting(Some(&given), "p").unwrap();
        assert!(warning.is_none());
        assert!((read.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-12);
        // Printed to four digits: accepted as the nearest rotation, with a warning.
        let rounded: Vec<f64> = pose_to_pb(&truth)
            .matrix
            .iter()
            .map(|v| (v * 1e4).round() / 1e4)
            .collect();
        let (read, warning) = pose_from_pb_noting(pose(rounded).as_ref(), "rig_to_world").unwrap();
        assert!(warning.unwrap().starts_with("rig_to_world.matrix"));
        let r = read.rotation.to_rotation_matrix().into_inner();
        assert!((r.transpose() * r - Matrix3::identity()).abs().max() < 1e-12);
        assert!((read.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-4);
        let exact = pose_from_pb_noting(Some(&pose_to_pb(&truth)), "p").unwrap();
        assert!(exact.1.is_none(), "an exact pose brings no warning");
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

    #[test]
    fn a_session_name_is_one_line_of_text() {
        let request = |name: &str| pb::CreateSessionRequest {
            name: name.to_string(),
            ..Default::default()
        };
        for bad in ["two\nlines", "nul\0", "tab\there"] {
            let e = check_create_session(&request(bad)).unwrap_err();
            assert_eq!(e.field, "name", "{bad:?}");
            assert!(e.message.contains("control character"), "{}", e.message);
        }
        // Past the name, the next field is checked: the calibration, missing here.
        let e = check_create_session(&request("kitchen, 2nd floor <b>")).unwrap_err();
        assert!(e.field.starts_with("calibration"), "{}", e.field);
    }
}
