//! Shared fixtures: a valid rig in the schema's JSON, built from K, R, t like a user would.

use serde_json::{json, Value};

/// A non-collinear rig looking along rig +y: centres (0,0,0), (0.3,0,0), (0.15,0,0.25) m.
pub fn calibration_json() -> Value {
    let cams: Vec<Value> = [(0.0, 0.0, 0.0), (0.3, 0.0, 0.0), (0.15, 0.0, 0.25)]
        .iter()
        .enumerate()
        .map(|(i, &(x, y, z))| {
            // R maps rig (x right, y forward, z up) to camera (x right, y down, z forward).
            let r = [1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0];
            let c = [x, y, z];
            let t: Vec<f64> = (0..3)
                .map(|row| -(0..3).map(|k| r[row * 3 + k] * c[k]).sum::<f64>())
                .collect();
            json!({
                "name": format!("cam{}", i + 1),
                "width": 512, "height": 512,
                "intrinsics": [600.0, 0.0, 256.0, 0.0, 600.0, 256.0, 0.0, 0.0, 1.0],
                "rotation": r,
                "translation": t,
            })
        })
        .collect();
    json!({ "cameras": cams })
}

pub fn segment(u1: f64, v1: f64, u2: f64, v2: f64) -> Value {
    json!({"u1": u1, "v1": v1, "u2": u2, "v2": v2})
}

/// A request with one plausible segment per list.
pub fn request_json() -> Value {
    let list = json!({"oriented": true, "segments": [segment(100.0, 100.0, 100.0, 200.0)]});
    json!({
        "calibration": calibration_json(),
        "segments": {"lists": [list.clone(), list.clone(), list]},
    })
}

/// Runs a JSON request through the API, as the CLI and the service do; returns the failing
/// field, or the response.
pub fn run_json(request: &serde_json::Value) -> Result<trinocular::api::pb::MatchResponse, String> {
    use trinocular::api::{self, RunError};
    let req: api::pb::MatchRequest =
        api::from_json("request", &request.to_string()).map_err(|e| e.field)?;
    let input = api::match_request(&req, &Default::default()).map_err(|e| e.field)?;
    input.run().map_err(|e| match e {
        RunError::Input(e) => e.field,
        stopped => panic!("nothing asked to stop, yet: {stopped}"),
    })
}
