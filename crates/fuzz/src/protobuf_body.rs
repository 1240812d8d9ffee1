//! Protobuf bodies (HTTP `application/x-protobuf`, and gRPC's messages): the same bytes decoded
//! as each request message, then converted and checked as the service does. A calibration is
//! run when its images are small (at most 256 x 256) or it gives correspondences.

use crate::debug;
use prost::Message;
use trinocular::api::calibrate::{calibrate_request, CalibrateSource};
use trinocular::api::session::{capture_match_request, capture_pose_from_pb, check_create_session};
use trinocular::api::{self, pb, RunCalibration};

/// Largest image side a calibration is run on.
const CALIBRATE_MAX_SIDE: u32 = 256;

pub fn run(data: &[u8]) {
    let limits = crate::request_limits();
    if let Ok(request) = pb::MatchRequest::decode(data) {
        let checked = api::match_request(&request, &limits);
        debug(|| format!("MatchRequest: {:?}", checked.map(|_| ())));
    }
    if let Ok(request) = pb::CalibrateRequest::decode(data) {
        if let Ok(input) = calibrate_request(&request, &limits.decode) {
            let small = match &input.source {
                CalibrateSource::Images(images) => images
                    .iter()
                    .all(|i| i.width() <= CALIBRATE_MAX_SIDE && i.height() <= CALIBRATE_MAX_SIDE),
                CalibrateSource::Correspondences { .. } => true,
            };
            if small {
                let calibrated = input.run();
                debug(|| format!("CalibrateRequest: run {:?}", calibrated.map(|_| ())));
            }
        } else {
            debug(|| "CalibrateRequest: refused".into());
        }
    }
    if let Ok(request) = pb::AddCaptureRequest::decode(data) {
        // As the service does with a session's stored calibration and options.
        if capture_pose_from_pb(request.rig_to_world.as_ref(), "rig_to_world").is_ok() {
            let calibration = crate::calibration(64, 48);
            let checked = api::match_request(
                &capture_match_request(calibration, None, request.input),
                &limits,
            );
            debug(|| format!("AddCaptureRequest: {:?}", checked.map(|_| ())));
        }
    }
    if let Ok(request) = pb::CreateSessionRequest::decode(data) {
        let checked = check_create_session(&request);
        debug(|| format!("CreateSessionRequest: {checked:?}"));
    }
}
