//! A panoramic session map from the shared data: every capture of a session directory
//! matched (LSD segments, or with `--images` our own extraction from the PNGs), moved to the
//! world frame by its pose and fused with `map::fuse`; writes what `shared/eval/score.py`
//! scores, plus the map as PLY and its top view (the paper's figure 7) as SVG and PNG.
//!
//!     cargo run --release --example session_map -- [--data DIR] [--images] [--out DIR]
//!         [--min-observations N] [--options JSON] [--lateral-m M] [--lateral-rel R]
//!         [--angle-deg A] [--max-gap-m G]
//!
//! `--options` is a proto3-JSON `MatchOptions`, e.g. `{"maxDirectionSigmaDeg": 2}`.
//! Writes `OUT/map.json` (`{"segments": [[x1,y1,z1,x2,y2,z2],...], "frame": "world",
//! "observations": [...]}`), `OUT/map.ply`, `OUT/top.svg`, `OUT/top.png`.

use std::path::{Path, PathBuf};

use base64::Engine;
use clap::Parser;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use serde_json::{json, Value};
use trinocular::api::{self, pb, RequestLimits, RunMatch};
use trinocular::map::{self, Capture, FuseParams};
use trinocular::segment::Segment3;

#[derive(Parser)]
struct Args {
    /// Session directory holding capture_NN/{calib,pose}.json and the images or LSD lists.
    #[arg(long, default_value = "../shared/data/office")]
    data: PathBuf,
    /// Match the images (our extraction), not segments_lsd.json.
    #[arg(long)]
    images: bool,
    #[arg(long, default_value = "target/session_map")]
    out: PathBuf,
    #[arg(long)]
    min_observations: Option<u32>,
    /// Match options, proto3 JSON.
    #[arg(long)]
    options: Option<String>,
    #[arg(long)]
    lateral_m: Option<f64>,
    #[arg(long)]
    lateral_rel: Option<f64>,
    #[arg(long)]
    angle_deg: Option<f64>,
    #[arg(long)]
    max_gap_m: Option<f64>,
}

type Error = Box<dyn std::error::Error>;

fn read_json(path: &Path) -> Result<Value, Error> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(serde_json::from_str(&text)?)
}

/// The `MatchRequest` of one capture, as `tools/eval_rooms.py` builds it.
fn request(dir: &Path, images: bool, options: &Option<Value>) -> Result<pb::MatchRequest, Error> {
    let calib = read_json(&dir.join("calib.json"))?;
    let cameras: Vec<Value> = calib["cameras"]
        .as_array()
        .ok_or("calib.json: no cameras")?
        .iter()
        .map(|c| {
            let projection: Vec<Value> = c["P"]
                .as_array()
                .into_iter()
                .flatten()
                .flat_map(|row| row.as_array().cloned().unwrap_or_default())
                .collect();
            json!({"name": c["name"], "width": c["width"], "height": c["height"],
                   "projection": projection})
        })
        .collect();
    let mut req = json!({"calibration": {"cameras": cameras}});
    if images {
        let mut list = Vec::new();
        for i in 1..=3 {
            let bytes = std::fs::read(dir.join(format!("img{i}.png")))?;
            list.push(json!({"encoded": base64::engine::general_purpose::STANDARD.encode(bytes)}));
        }
        req["images"] = json!({ "images": list });
    } else {
        let lsd = read_json(&dir.join("segments_lsd.json"))?;
        let lists: Vec<Value> = lsd["images"]
            .as_array()
            .ok_or("segments_lsd.json: no images")?
            .iter()
            .map(|im| {
                let segments: Vec<Value> = im["segments"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|s| json!({"u1": s[0], "v1": s[1], "u2": s[2], "v2": s[3]}))
                    .collect();
                json!({"oriented": true, "segments": segments})
            })
            .collect();
        req["segments"] = json!({ "lists": lists });
    }
    if let Some(o) = options {
        req["options"] = o.clone();
    }
    Ok(api::from_json("MatchRequest", &req.to_string())?)
}

/// `rig_to_world` of pose.json (4x4, rows).
fn pose(dir: &Path) -> Result<Isometry3<f64>, Error> {
    let p = read_json(&dir.join("pose.json"))?;
    let at = |r: usize, c: usize| {
        p["rig_to_world"][r][c]
            .as_f64()
            .ok_or("pose.json: bad matrix")
    };
    let mut m = Matrix3::zeros();
    for r in 0..3 {
        for c in 0..3 {
            m[(r, c)] = at(r, c)?;
        }
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&m));
    let t = Translation3::new(at(0, 3)?, at(1, 3)?, at(2, 3)?);
    Ok(Isometry3::from_parts(t, rotation))
}

fn main() -> Result<(), Error> {
    let args = Args::parse();
    let options: Option<Value> = args
        .options
        .as_deref()
        .map(serde_json::from_str)
        .transpose()?;
    let mut params = FuseParams::default();
    if let Some(v) = args.min_observations {
        params.min_observations = v;
    }
    if let Some(v) = args.lateral_m {
        params.lateral_m = v;
    }
    if let Some(v) = args.lateral_rel {
        params.lateral_rel = v;
    }
    if let Some(v) = args.angle_deg {
        params.angle_deg = v;
    }
    if let Some(v) = args.max_gap_m {
        params.max_gap_m = v;
    }
    params.check()?;

    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&args.data)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("capture_"))
        })
        .collect();
    dirs.sort();
    let mut poses = Vec::new();
    let mut segments: Vec<Vec<Segment3>> = Vec::new();
    let mut ids = Vec::new();
    for dir in &dirs {
        let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let id: u32 = name.trim_start_matches("capture_").parse()?;
        let input = api::match_request(
            &request(dir, args.images, &options)?,
            &RequestLimits::default(),
        )?;
        let executed = input.execute()?;
        let out = &executed.output;
        eprintln!(
            "capture {id:02}: {} 3D segments in {:.1} ms",
            out.segments_3d.len(),
            out.stats.total_ms
        );
        segments.push(out.segments());
        poses.push(pose(dir)?);
        ids.push(id);
    }
    let captures: Vec<Capture> = ids
        .iter()
        .zip(&poses)
        .zip(&segments)
        .map(|((&id, &rig_to_world), s)| Capture {
            id,
            rig_to_world,
            segments: s,
        })
        .collect();
    let t0 = std::time::Instant::now();
    let fused = map::fuse(&captures, &params);
    let fuse_ms = t0.elapsed().as_secs_f64() * 1e3;
    let total_in: usize = segments.iter().map(Vec::len).sum();
    eprintln!(
        "fused {total_in} segments of {} captures into {} map segments in {fuse_ms:.2} ms ({params:?})",
        captures.len(),
        fused.len()
    );

    std::fs::create_dir_all(&args.out)?;
    let rows: Vec<[f64; 6]> = fused
        .iter()
        .map(|m| [m.start.x, m.start.y, m.start.z, m.end.x, m.end.y, m.end.z])
        .collect();
    let observations: Vec<u32> = fused.iter().map(|m| m.observations).collect();
    let doc = json!({"segments": rows, "frame": "world", "observations": observations});
    std::fs::write(args.out.join("map.json"), doc.to_string())?;
    std::fs::write(args.out.join("map.ply"), map::export::to_ply(&fused))?;
    std::fs::write(
        args.out.join("top.svg"),
        map::export::top_view_svg(&fused, &poses),
    )?;
    std::fs::write(
        args.out.join("top.png"),
        map::export::top_view_png(&fused, &poses)?,
    )?;
    println!("{}", args.out.join("map.json").display());
    Ok(())
}
