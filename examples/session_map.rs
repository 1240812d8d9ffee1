//! A panoramic session map from the shared data: every capture of a session directory
//! matched (LSD segments, or with `--images` our own extraction from the PNGs), moved to the
//! world frame by its pose and fused with `map::fuse`; writes what `shared/eval/score.py`
//! scores, plus the map as PLY and its top view (the paper's figure 7) as SVG and PNG.
//!
//!     cargo run --release --example session_map -- [--data DIR] [--images] [--out DIR]
//!         [--min-observations N] [--options JSON] [--lateral-m M] [--lateral-rel R]
//!         [--angle-deg A] [--max-gap-m G]
//!         [--yaw-noise-deg Y --xy-noise-m T [--seed S]] [--register [--graph]]
//!
//! Odometry is simulated by `--yaw-noise-deg` and `--xy-noise-m`: every capture but the first
//! (whose pose anchors the map, as a robot's start anchors its odometry) gets a heading error
//! about its rig's origin and an error across the floor drawn from N(0, Y°) and N(0, T m),
//! independently, seeded by `--seed`. `--register` places each capture in order as AddCapture
//! does (`map::session::add_capture`: registered to the map from that pose and the simulated
//! noise as its covariance, then to each earlier capture it overlaps); `--graph` then solves
//! every pose from the odometry and those edges as GetMap does (`map::session::solve_poses`),
//! and the map is fused with the poses found. The pose errors against the true poses, and
//! each edge's error with its χ², are printed.
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
use trinocular::map::images::Views;
use trinocular::map::session::{Placed, SessionParams};
use trinocular::map::{self, Capture, FuseParams, Measured, PosePrior};
use trinocular::segment::{Segment2, Segment3};

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
    /// Heading error of the simulated odometry, 1σ, degrees.
    #[arg(long, default_value_t = 0.0)]
    yaw_noise_deg: f64,
    /// Error across the floor of the simulated odometry, 1σ per axis, metres.
    #[arg(long, default_value_t = 0.0)]
    xy_noise_m: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Register each capture to the ones before it.
    #[arg(long)]
    register: bool,
    /// After placing them in order, solve all poses together from the odometry and the
    /// edges between captures, as GetMap does (`map::session::solve_poses`).
    #[arg(long)]
    graph: bool,
    /// Register the captures pair by pair on their 3D segments alone, not refined in the new
    /// capture's image segments (how AddCapture placed them before image registration).
    #[arg(long)]
    in_3d_only: bool,
    /// Gate the map as a Match answer is gated (the default match options' accuracy), by
    /// each map segment's fused covariance, poses' uncertainty included.
    #[arg(long)]
    gate: bool,
    /// Fuse every 3D segment, uncertain ones too (each by its covariance), and let the map's
    /// gate decide.
    #[arg(long)]
    fuse_uncertain: bool,
    /// Place the captures without the room's directions (`map::compass`): by their segments
    /// in common and their odometry only.
    #[arg(long)]
    no_compass: bool,
    /// Place the captures without the room's long lines as landmarks (`map::landmarks`): a
    /// capture that continues a line an earlier one saw, sharing no segment with it, is then
    /// held across that line by its odometry alone.
    #[arg(long)]
    no_landmarks: bool,
}

/// Standard normal draws from a seed (splitmix64, Box–Muller): the same noise for the same
/// seed on every machine.
struct Normal(u64);

impl Normal {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn sample(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The pose odometry would report: `truth` turned about its own origin by a heading error and
/// moved across the floor.
fn perturbed(truth: &Isometry3<f64>, yaw: f64, dx: f64, dy: f64) -> Isometry3<f64> {
    let turn = UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), yaw);
    let t = truth.translation.vector + nalgebra::Vector3::new(dx, dy, 0.0);
    Isometry3::from_parts(Translation3::from(t), turn * truth.rotation)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
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
    if args.gate {
        params.gate = Some(map::MapGate::of(
            &trinocular::matching::MatchParams::default(),
        ));
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
    let mut truths = Vec::new();
    let mut measured: Vec<Vec<Measured>> = Vec::new();
    let mut segments: Vec<Vec<Segment3>> = Vec::new();
    let mut covariances: Vec<Vec<nalgebra::Matrix6<f64>>> = Vec::new();
    let mut ids = Vec::new();
    let mut rig_marker = map::export::RigMarker::origin();
    // Each capture's image segments (extracted, or the lists given) and the rig, for
    // placing as AddCapture does.
    let mut seen: Vec<[Vec<Segment2>; 3]> = Vec::new();
    let mut rig = None;
    let mut list_noise_px = 0.3;
    for dir in &dirs {
        let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let id: u32 = name.trim_start_matches("capture_").parse()?;
        let mut request = request(dir, args.images, &options)?;
        // Registration uses every segment, each by its own covariance; the map only those
        // that meet the gate, as a plain Match answers.
        let asked_uncertain = request
            .options
            .as_ref()
            .is_some_and(|o| o.include_uncertain == Some(true));
        if args.register {
            request
                .options
                .get_or_insert_with(Default::default)
                .include_uncertain = Some(true);
        }
        let input = api::match_request(&request, &RequestLimits::default())?;
        rig_marker =
            map::export::RigMarker::of(&api::rig_from_calibration(request.calibration.as_ref())?);
        let executed = input.execute()?;
        seen.push(match (&input.source, &executed.extracted) {
            (_, Some(extracted)) => std::array::from_fn(|k| extracted[k].segments.segments.clone()),
            (api::MatchSource::Segments(lists), None) => {
                std::array::from_fn(|k| lists[k].segments.clone())
            }
            _ => Default::default(),
        });
        rig = Some(input.rig.clone());
        list_noise_px = input.params.line_noise_px;
        let out = &executed.output;
        eprintln!(
            "capture {id:02}: {} 3D segments in {:.1} ms",
            out.segments_3d.len(),
            out.stats.total_ms
        );
        let fused_here = |r: &&trinocular::pipeline::Reconstructed| {
            asked_uncertain || args.fuse_uncertain || !r.uncertain
        };
        segments.push(
            out.segments_3d
                .iter()
                .filter(fused_here)
                .map(|r| r.segment)
                .collect(),
        );
        covariances.push(
            out.segments_3d
                .iter()
                .filter(fused_here)
                .map(|r| r.relative_covariance())
                .collect(),
        );
        measured.push(
            out.segments_3d
                .iter()
                .map(|r| Measured {
                    start: r.segment.start,
                    end: r.segment.end,
                    covariance: r.relative_covariance(),
                    uncertain: r.uncertain,
                })
                .collect(),
        );
        truths.push(pose(dir)?);
        ids.push(id);
    }
    let mut noise = Normal(args.seed);
    let priors: Vec<Isometry3<f64>> = truths
        .iter()
        .enumerate()
        .map(|(i, truth)| {
            let (yaw, dx, dy) = (
                noise.sample() * args.yaw_noise_deg.to_radians(),
                noise.sample() * args.xy_noise_m,
                noise.sample() * args.xy_noise_m,
            );
            if i == 0 {
                *truth
            } else {
                perturbed(truth, yaw, dx, dy)
            }
        })
        .collect();
    // Without registration the poses are taken as exact; with it, each carries the
    // covariance registration or the graph gives it.
    let poses: Vec<PosePrior> = if args.register {
        let rig = rig.as_ref().ok_or("no capture")?;
        let views: Vec<Views> = seen
            .iter()
            .map(|lists| Views {
                cameras: rig.cameras(),
                segments: std::array::from_fn(|k| &lists[k][..]),
                list_noise_px,
            })
            .collect();
        place_in_order(
            &priors
                .iter()
                .map(|p| prior_of(*p, args.yaw_noise_deg, args.xy_noise_m))
                .collect::<Vec<_>>(),
            &measured,
            (!args.in_3d_only).then_some(&views[..]),
            &truths,
            args.graph,
            &SessionParams {
                compass: !args.no_compass,
                landmarks: !args.no_landmarks,
                ..SessionParams::default()
            },
        )
    } else {
        priors
            .iter()
            .map(|&rig_to_world| PosePrior {
                rig_to_world,
                covariance: nalgebra::Matrix6::zeros(),
            })
            .collect()
    };
    let poses_only: Vec<Isometry3<f64>> = poses.iter().map(|p| p.rig_to_world).collect();
    let errors = |poses: &[Isometry3<f64>]| {
        let later = poses.iter().zip(&truths).skip(1);
        let rotation: Vec<f64> = later
            .clone()
            .map(|(p, t)| (p.rotation * t.rotation.inverse()).angle().to_degrees())
            .collect();
        let translation: Vec<f64> = later
            .map(|(p, t)| (p.translation.vector - t.translation.vector).norm())
            .collect();
        (median(rotation), median(translation))
    };
    for (i, ((p, q), t)) in priors.iter().zip(&poses_only).zip(&truths).enumerate() {
        let r = |x: &Isometry3<f64>| (x.rotation * t.rotation.inverse()).angle().to_degrees();
        let d = |x: &Isometry3<f64>| (x.translation.vector - t.translation.vector).norm() * 1e3;
        eprintln!(
            "capture {i:02} error: prior {:.2} deg {:.1} mm, used {:.2} deg {:.1} mm",
            r(p),
            d(p),
            r(q),
            d(q)
        );
    }
    let (prior_r, prior_t) = errors(&priors);
    let (pose_r, pose_t) = errors(&poses_only);
    eprintln!(
        "pose error, median over captures after the first: prior {prior_r:.3} deg {:.1} mm, \
         used {pose_r:.3} deg {:.1} mm",
        prior_t * 1e3,
        pose_t * 1e3
    );
    let captures: Vec<Capture> = ids
        .iter()
        .zip(&poses)
        .zip(segments.iter().zip(&covariances))
        .map(|((&id, pose), (s, c))| Capture {
            id,
            rig_to_world: pose.rig_to_world,
            segments: s,
            covariances: c,
            pose_covariance: pose.covariance,
        })
        .collect();
    // The gate adds, once, the shift the rig's views share (the captures' own covariances
    // leave it out).
    if let (Some(gate), Some(rig)) = (params.gate, rig.as_ref()) {
        params.gate = Some(gate.sharing_shift(rig));
    }
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
    let doc = json!({"segments": rows, "frame": "world", "observations": observations,
                     "pose_error": {"prior_deg": prior_r, "prior_m": prior_t,
                                    "used_deg": pose_r, "used_m": pose_t}});
    std::fs::write(args.out.join("map.json"), doc.to_string())?;
    std::fs::write(args.out.join("map.ply"), map::export::to_ply(&fused))?;
    std::fs::write(
        args.out.join("top.svg"),
        map::export::top_view_svg(&fused, &poses_only, &priors, &rig_marker),
    )?;
    std::fs::write(
        args.out.join("top.png"),
        map::export::top_view_png(&fused, &poses_only, &priors, &rig_marker)?,
    )?;
    println!("{}", args.out.join("map.json").display());
    Ok(())
}

/// Each capture placed in order as AddCapture places it (`map::session::add_capture`:
/// registered to the map, then to each earlier capture it overlaps); with `graph`, the poses
/// then solved as GetMap solves them (`map::session::solve_poses`), otherwise as registered.
/// Each edge's error against the true relative pose is printed with its χ² under the edge's
/// information (6 degrees of freedom: 12.6 at 95%).
fn place_in_order(
    priors: &[PosePrior],
    measured: &[Vec<Measured>],
    views: Option<&[Views]>,
    truths: &[Isometry3<f64>],
    graph: bool,
    params: &SessionParams,
) -> Vec<PosePrior> {
    let mut placed: Vec<Placed> = Vec::new();
    let mut registered = Vec::new();
    let mut edges = Vec::new();
    for (i, segments) in measured.iter().enumerate() {
        let prior = priors[i];
        let t0 = std::time::Instant::now();
        let added = match views {
            Some(views) => map::session::add_capture_with_views(
                &placed, &edges, &prior, segments, &views[i], params,
            ),
            None => map::session::add_capture(&placed, &edges, &prior, segments, params),
        };
        let got = added.registration;
        eprintln!(
            "capture {i:02}: {:?}, {} inliers, moved {:.2} deg {:.1} mm, {} edges, {:.1} ms",
            got.status,
            got.inliers,
            got.rotation_change_deg,
            got.translation_change_m * 1e3,
            added.edges.len(),
            t0.elapsed().as_secs_f64() * 1e3
        );
        registered.push(PosePrior {
            rig_to_world: got.rig_to_world,
            covariance: got.covariance,
        });
        placed.push(Placed { prior, segments });
        edges.extend(added.edges);
    }
    for r in &edges {
        let t = truths[r.to].inverse() * truths[r.from];
        let rotation = (r.pose.rotation * t.rotation.inverse()).scaled_axis();
        let shift = r.pose.translation.vector - t.translation.vector;
        let e = nalgebra::Vector6::new(
            rotation.x, rotation.y, rotation.z, shift.x, shift.y, shift.z,
        );
        let chi2 = (e.transpose() * r.information * e)[0];
        eprintln!(
            "edge {}-{}: {} inliers, error {:.3} deg {:.1} mm, chi2 {chi2:.1}",
            r.to,
            r.from,
            r.inliers,
            rotation.norm().to_degrees(),
            shift.norm() * 1e3
        );
    }
    if graph {
        let t0 = std::time::Instant::now();
        let solved = map::session::solve_poses(&placed, &edges);
        eprintln!(
            "pose graph of {} captures and {} edges solved in {:.2} ms",
            placed.len(),
            edges.len(),
            t0.elapsed().as_secs_f64() * 1e3
        );
        for (i, (p, t)) in solved.iter().zip(truths).enumerate() {
            let c = p.covariance;
            eprintln!(
                "capture {i:02} solved: error {:.3} deg {:.1} mm; sigma yaw {:.3} deg, xy {:.1} mm",
                (p.rig_to_world.rotation * t.rotation.inverse())
                    .angle()
                    .to_degrees(),
                (p.rig_to_world.translation.vector - t.translation.vector).norm() * 1e3,
                c[(2, 2)].max(0.0).sqrt().to_degrees(),
                (c[(3, 3)] + c[(4, 4)]).max(0.0).sqrt() * 1e3
            );
        }
        solved
    } else {
        registered
    }
}

/// The prior a robot that knows its odometry's noise would give: the simulated heading and
/// floor errors (no less than 0.25° and 1 cm), tilt and height as the defaults.
fn prior_of(pose: Isometry3<f64>, yaw_sigma_deg: f64, xy_sigma_m: f64) -> PosePrior {
    PosePrior::odometry(
        pose,
        yaw_sigma_deg.max(0.25),
        map::register::DEFAULT_TILT_SIGMA_DEG,
        xy_sigma_m.max(0.01),
        map::register::DEFAULT_Z_SIGMA_M,
    )
}
