//! Bad input gets a clear error naming the field — through the library's API and through
//! the CLI (exit code 2, the field on stderr) — never a panic.

use std::process::Command;

use serde_json::{json, Value};
use trinocular::api::{self, pb};

use crate::common::{calibration_json, request_json, run_json as run, segment};

fn field_of(request: &Value) -> String {
    match run(request) {
        Err(field) => field,
        Ok(_) => panic!("request was accepted: {request}"),
    }
}

#[test]
fn valid_request_is_accepted() {
    let resp = run(&request_json()).expect("valid");
    let stats = resp.stats.expect("stats");
    assert_eq!(stats.segments_in, vec![1, 1, 1]);
}

#[test]
fn camera_count_must_be_three() {
    let mut r = request_json();
    r["calibration"]["cameras"].as_array_mut().unwrap().pop();
    assert_eq!(field_of(&r), "calibration.cameras");
    r["calibration"] = json!({"cameras": []});
    assert_eq!(field_of(&r), "calibration.cameras");
    r.as_object_mut().unwrap().remove("calibration");
    assert_eq!(field_of(&r), "calibration");
}

#[test]
fn list_count_must_be_three() {
    let mut r = request_json();
    r["segments"]["lists"].as_array_mut().unwrap().pop();
    assert_eq!(field_of(&r), "segments.lists");
    r.as_object_mut().unwrap().remove("segments");
    assert_eq!(field_of(&r), "input");
}

#[test]
fn non_finite_numbers_are_named() {
    // proto3 JSON spells non-finite doubles as strings.
    let mut r = request_json();
    r["calibration"]["cameras"][2]["intrinsics"][0] = json!("NaN");
    assert_eq!(field_of(&r), "calibration.cameras[2].intrinsics");
    let mut r = request_json();
    r["calibration"]["cameras"][1]["translation"][1] = json!("Infinity");
    assert_eq!(field_of(&r), "calibration.cameras[1].translation");
    let mut r = request_json();
    r["segments"]["lists"][1]["segments"][0]["v2"] = json!("NaN");
    assert_eq!(field_of(&r), "segments.lists[1].segments[0].v2");
    let mut r = request_json();
    r["options"] = json!({"tolerancePx": "NaN"});
    assert_eq!(field_of(&r), "options.tolerance_px");
    let mut r = request_json();
    r["options"] = json!({"minGradient": -1});
    assert_eq!(field_of(&r), "options.min_gradient");
    let mut r = request_json();
    r["options"] = json!({"depthBlindGradientRatioMax": 0.5});
    assert_eq!(field_of(&r), "options.depth_blind_gradient_ratio_max");
    let mut r = request_json();
    r["options"] = json!({"vertexReachPx": 9});
    assert_eq!(field_of(&r), "options.vertex_reach_px");
    let mut r = request_json();
    r["options"] = json!({"minGradientToBackground": "-Infinity"});
    assert_eq!(field_of(&r), "options.min_gradient_to_background");
    let mut r = request_json();
    r["segments"]["lists"][2]["backgroundGradient"] = json!("NaN");
    assert_eq!(field_of(&r), "segments.lists[2].background_gradient");
    let mut r = request_json();
    r["segments"]["lists"][2]["backgroundGradient"] = json!(-0.5);
    assert_eq!(field_of(&r), "segments.lists[2].background_gradient");
    let mut r = request_json();
    r["segments"]["lists"][0]["segments"][0]["gradient"] = json!("-Infinity");
    assert_eq!(field_of(&r), "segments.lists[0].segments[0].gradient");
}

#[test]
fn segment_noise_and_the_accuracy_gate_are_checked_by_name() {
    let with_noise = |r: &mut Value, sigma: Value, angle: Value| {
        let s = &mut r["segments"]["lists"][1]["segments"][0];
        s["offsetSigmaPx"] = sigma;
        s["angleSigmaDeg"] = angle;
    };
    let mut r = request_json();
    with_noise(&mut r, json!("NaN"), json!(0.1));
    assert_eq!(
        field_of(&r),
        "segments.lists[1].segments[0].offset_sigma_px"
    );
    let mut r = request_json();
    with_noise(&mut r, json!(0.05), json!(-0.1));
    assert_eq!(
        field_of(&r),
        "segments.lists[1].segments[0].angle_sigma_deg"
    );
    let mut r = request_json();
    r["segments"]["lists"][1]["segments"][0]["offsetSigmaPx"] = json!(0.05);
    assert_eq!(
        field_of(&r),
        "segments.lists[1].segments[0].angle_sigma_deg"
    );
    let mut r = request_json();
    with_noise(&mut r, json!(0.05), json!(0.1));
    assert!(run(&r).is_ok(), "both given and valid: accepted");
    // A shift goes with the two, within 0 to 1 px.
    for (shift, with_sigmas, field) in [
        (json!(0.05), false, "offset_sigma_px"),
        (json!("NaN"), true, "shift_sigma_px"),
        (json!(-0.01), true, "shift_sigma_px"),
        (json!(1.5), true, "shift_sigma_px"),
    ] {
        let mut r = request_json();
        if with_sigmas {
            with_noise(&mut r, json!(0.05), json!(0.1));
        }
        r["segments"]["lists"][1]["segments"][0]["shiftSigmaPx"] = shift.clone();
        assert_eq!(
            field_of(&r),
            format!("segments.lists[1].segments[0].{field}"),
            "{shift}"
        );
    }
    let mut r = request_json();
    with_noise(&mut r, json!(0.05), json!(0.1));
    r["segments"]["lists"][1]["segments"][0]["shiftSigmaPx"] = json!(0.0);
    assert!(run(&r).is_ok(), "a shift of 0 with both sigmas: accepted");
    for (option, value, field) in [
        ("gateConfidence", json!(1.0), "options.gate_confidence"),
        ("gateDirectionDeg", json!(0.0), "options.gate_direction_deg"),
        ("gatePositionM", json!("NaN"), "options.gate_position_m"),
        ("gatePositionRel", json!(-0.01), "options.gate_position_rel"),
    ] {
        let mut r = request_json();
        r["options"] = json!({ option: value });
        assert_eq!(field_of(&r), field, "{option}");
    }
}

#[test]
fn every_bad_option_is_reported_at_once() {
    // One round trip tells the client everything to fix: the error names the first field at
    // fault and its message lists each problem.
    let mut r = request_json();
    r["options"] = json!({"tolerancePx": "NaN", "minGradient": -1, "gateConfidence": 1.0});
    let request: pb::MatchRequest = api::from_json("request", &r.to_string()).unwrap();
    let err = api::match_request(&request, &Default::default()).unwrap_err();
    assert_eq!(err.field, "options.tolerance_px");
    for field in ["tolerance_px", "min_gradient", "gate_confidence"] {
        assert!(err.message.contains(field), "{field}: {}", err.message);
    }
    let mut r = request_json();
    r["options"] = json!({"extract": {"gradientLow": -1, "maxDeviationPx": 0}});
    let request: pb::MatchRequest = api::from_json("request", &r.to_string()).unwrap();
    let err = api::match_request(&request, &Default::default()).unwrap_err();
    assert_eq!(err.field, "options.extract.gradient_low");
    assert!(err.message.contains("max_deviation_px"), "{}", err.message);
}

#[test]
fn projection_problems_are_named() {
    let mut r = request_json();
    let p = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    r["calibration"]["cameras"][0] = json!({"width": 512, "height": 512, "projection": p});
    assert_eq!(field_of(&r), "calibration.cameras[0].projection");
    r["calibration"]["cameras"][0]["projection"] = json!([1.0, 2.0, 3.0]);
    assert_eq!(field_of(&r), "calibration.cameras[0].projection");
    // Both models at once.
    let mut r = request_json();
    r["calibration"]["cameras"][0]["projection"] = json!(p);
    assert_eq!(field_of(&r), "calibration.cameras[0].projection");
}

#[test]
fn rank_deficient_or_negative_intrinsics_are_named() {
    let mut r = request_json();
    r["calibration"]["cameras"][1]["intrinsics"] =
        json!([0.0, 0.0, 256.0, 0.0, 600.0, 256.0, 0.0, 0.0, 1.0]);
    assert_eq!(field_of(&r), "calibration.cameras[1].intrinsics");
    r["calibration"]["cameras"][1]["intrinsics"] =
        json!([600.0, 0.0, 256.0, 0.0, 600.0, 256.0, 0.0, 0.0, 0.0]);
    assert_eq!(field_of(&r), "calibration.cameras[1].intrinsics");
    let mut r = request_json();
    r["calibration"]["cameras"][1]["rotation"] = json!([1, 0, 0, 0, 1, 0, 0, 0, 1.5]);
    assert_eq!(field_of(&r), "calibration.cameras[1].rotation");
    let mut r = request_json();
    r["calibration"]["cameras"][1]["width"] = json!(0);
    assert_eq!(field_of(&r), "calibration.cameras[1].width");
}

#[test]
fn coincident_centres_are_named() {
    let mut r = request_json();
    r["calibration"]["cameras"][2] = calibration_json()["cameras"][0].clone();
    assert_eq!(field_of(&r), "calibration.cameras[2]");
}

#[test]
fn depth_range_is_checked() {
    let mut r = request_json();
    r["options"] = json!({"depthMinM": 2.0, "depthMaxM": 1.0});
    assert_eq!(field_of(&r), "options.depth_max_m");
    r["options"] = json!({"depthMinM": 0.0});
    assert_eq!(field_of(&r), "options.depth_min_m");
    r["options"] = json!({"depthMinM": -1.0, "depthMaxM": 3.0});
    assert_eq!(field_of(&r), "options.depth_min_m");
}

#[test]
fn wildly_out_of_image_segments_are_named() {
    let mut r = request_json();
    r["segments"]["lists"][2]["segments"] = json!([
        segment(10.0, 10.0, 50.0, 10.0),
        segment(10.0, 10.0, 5000.0, 10.0)
    ]);
    assert_eq!(field_of(&r), "segments.lists[2].segments[1].u2");
}

#[test]
fn zero_length_segments_are_dropped_and_counted() {
    let mut r = request_json();
    r["segments"]["lists"][1]["segments"] = json!([
        segment(10.0, 10.0, 10.0, 10.0),
        segment(10.0, 10.0, 60.0, 10.0)
    ]);
    let stats = run(&r).expect("accepted").stats.unwrap();
    assert_eq!(stats.zero_length_dropped, vec![0, 1, 0]);
    assert_eq!(stats.segments_in, vec![1, 2, 1]);
}

#[test]
fn empty_lists_give_an_empty_result() {
    let mut r = request_json();
    for l in 0..3 {
        r["segments"]["lists"][l]["segments"] = json!([]);
    }
    let resp = run(&r).expect("accepted");
    assert!(resp.triplets.is_empty() && resp.segments_3d.is_empty());
}

#[test]
fn malformed_json_is_an_error_not_a_panic() {
    let err = api::from_json::<pb::MatchRequest>("request", "{\"calibration\": [1,").unwrap_err();
    assert_eq!(err.field, "calibration");
    let err = api::from_json::<pb::MatchRequest>("request", "{\"calibration\": [1,").unwrap_err();
    assert!(err.message.contains("line 1 column 17"), "{}", err.message);
    let err = api::from_json::<pb::MatchRequest>("request", "{\"calibration\": 5}").unwrap_err();
    assert!(err.message.contains("invalid JSON"), "{}", err.message);
}

fn cli(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_trinocular"))
        .args(args)
        .output()
        .expect("run the CLI")
}

#[test]
fn cli_reports_the_field_and_exits_non_zero() {
    let dir = std::env::temp_dir().join(format!("trinocular-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut r = request_json();
    r["options"] = json!({"depthMinM": 3.0, "depthMaxM": 1.0});
    let path = dir.join("bad.json");
    std::fs::write(&path, r.to_string()).unwrap();
    let out = cli(&["match", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("options.depth_max_m"), "{stderr}");
    assert!(out.stdout.is_empty());

    // The two-file form gives the same answer as the request form.
    let good = request_json();
    let (cal, seg, req) = (
        dir.join("cal.json"),
        dir.join("seg.json"),
        dir.join("req.json"),
    );
    std::fs::write(&cal, good["calibration"].to_string()).unwrap();
    std::fs::write(&seg, good["segments"].to_string()).unwrap();
    std::fs::write(&req, good.to_string()).unwrap();
    let a = cli(&["match", req.to_str().unwrap()]);
    let b = cli(&[
        "match",
        "--calibration",
        cal.to_str().unwrap(),
        "--segments",
        seg.to_str().unwrap(),
    ]);
    assert!(a.status.success() && b.status.success());
    let strip = |o: &std::process::Output| {
        let mut v: Value = serde_json::from_slice(&o.stdout).unwrap();
        v["stats"] = Value::Null; // timings differ run to run
        v
    };
    assert_eq!(strip(&a), strip(&b));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_camera_may_give_both_models_if_they_agree() {
    let calibration: pb::Calibration =
        api::from_json("calibration", &calibration_json().to_string()).unwrap();
    let rig = api::rig_from_calibration(Some(&calibration)).unwrap();
    let both = pb::Calibration {
        cameras: rig
            .cameras()
            .iter()
            .map(|c| api::camera_to_pb(c, true))
            .collect(),
    };
    assert!(!both.cameras[0].projection.is_empty() && !both.cameras[0].intrinsics.is_empty());
    let again = api::rig_from_calibration(Some(&both)).expect("consistent models are accepted");
    assert_eq!(again.camera(2).projection(), rig.camera(2).projection());

    let mut scaled = both.clone();
    for v in &mut scaled.cameras[1].projection {
        *v *= 3.5; // any positive scale
    }
    assert!(api::rig_from_calibration(Some(&scaled)).is_ok());

    let mut off = both.clone();
    off.cameras[1].projection[3] += 1.0;
    let e = api::rig_from_calibration(Some(&off)).unwrap_err();
    assert_eq!(e.field, "calibration.cameras[1].projection");
    assert!(e.message.contains("disagrees"), "{e}");
}
