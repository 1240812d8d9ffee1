//! Golden outputs, compared bit for bit (timings aside) with `tests/golden/`: a Match response
//! from the CLI on a rendered image triplet, and the fused map of a session built over gRPC.
//! They guard behaviour across refactors and performance work: any change that moves a number
//! of either must be deliberate — rerun with `REGENERATE=1` and review the diff.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;
use trinocular::api::{self, pb};
use trinocular::synth::{render_triplet, standard_capture, Defects, RenderParams};

use crate::common::{runtime, scratch_dir};
use crate::sessions::{connect, map_of, panorama, start};

fn golden_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name)
}

/// Drops the timings (every field whose name ends in `Ms`): they are the only part of an
/// answer that may differ between two runs.
fn without_timings(value: &mut Value) {
    match value {
        Value::Object(fields) => {
            fields.retain(|k, _| !k.ends_with("Ms"));
            fields.values_mut().for_each(without_timings);
        }
        Value::Array(items) => items.iter_mut().for_each(without_timings),
        _ => {}
    }
}

/// Compares `actual` (pretty JSON, numbers written to round trip exactly) with the golden
/// file, or rewrites the file when `REGENERATE=1`.
fn check_exact(name: &str, mut actual: Value) {
    without_timings(&mut actual);
    let text = serde_json::to_string_pretty(&actual).unwrap() + "\n";
    let path = golden_path(name);
    if std::env::var("REGENERATE").as_deref() == Ok("1") {
        std::fs::write(&path, &text).unwrap();
        println!("rewrote {}", path.display());
        return;
    }
    let expected = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (run with REGENERATE=1 to create)", path.display()));
    if let Some((line, (a, e))) = text
        .lines()
        .zip(expected.lines())
        .enumerate()
        .find(|(_, (a, e))| a != e)
    {
        panic!(
            "{name} differs from its golden file at line {}: {a:?}, golden {e:?}\n\
             (if the change is intended, rerun with REGENERATE=1 and review the diff)",
            line + 1
        );
    }
    assert_eq!(
        text.lines().count(),
        expected.lines().count(),
        "{name}: the golden file has another number of lines"
    );
}

#[test]
fn a_match_response_is_the_golden_one() {
    let dir = scratch_dir("golden-match");
    let (scene, rig, _) = standard_capture(2, Defects::clean(), false);
    let images = render_triplet(&scene, &rig, &RenderParams::default(), 2);
    let mut args = vec!["match".to_string(), "--calibration".to_string()];
    let calib = dir.join("calib.json");
    std::fs::write(&calib, api::to_json(&api::calibration_to_pb(&rig))).unwrap();
    args.push(calib.to_str().unwrap().to_string());
    args.push("--images".to_string());
    for (i, img) in images.iter().enumerate() {
        let p = dir.join(format!("img{}.png", i + 1));
        std::fs::write(&p, trinocular::overlay::grey_png(img).unwrap()).unwrap();
        args.push(p.to_str().unwrap().to_string());
    }
    // Everything, the uncertain segments too: the golden file then holds the gate's decision
    // and the covariance of every 3D segment.
    let options = dir.join("options.json");
    std::fs::write(&options, r#"{"includeUncertain": true}"#).unwrap();
    args.extend([
        "--options".to_string(),
        options.to_str().unwrap().to_string(),
    ]);
    let out = Command::new(env!("CARGO_BIN_EXE_trinocular"))
        .args(&args)
        .output()
        .expect("the binary runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let response: Value = serde_json::from_slice(&out.stdout).unwrap();
    let segments = response["segments3d"].as_array().map_or(0, Vec::len);
    assert!(segments > 50, "{segments} 3D segments");
    check_exact("match_response.json", response);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_fused_session_map_is_the_golden_one() {
    // Twelve captures 30 degrees apart, poses as given: each registers to its neighbours, the
    // pose graph closes the loop, the map is fused by covariance and gated.
    let (calibration, captures) = panorama(12);
    let map = runtime().block_on(async {
        let running = start().await;
        let mut client = connect(running.grpc_addr).await;
        map_of(&mut client, &calibration, &captures).await
    });
    assert!(
        map.segments.len() > 100,
        "{} map segments",
        map.segments.len()
    );
    // The session's id is new each time; the map is not.
    let map = pb::Map {
        session_id: String::new(),
        ..map
    };
    check_exact("session_map.json", serde_json::to_value(&map).unwrap());
}
