//! `CalibrateRequest` ⇄ domain, and the calibration of a rig in one call: detect the pattern
//! in the three images (or take the caller's correspondences), estimate each camera, express
//! them in the rig frame if asked, and answer with both camera models and the error report.

use std::collections::HashMap;
use std::time::Instant;

use nalgebra::{Isometry3, Point2, Point3, Vector3};
use rayon::prelude::*;

use crate::session::pose_from_pb;
use crate::{camera_to_pb, extract_params, pb, InputError, RunError};
use trinocular_core::calibrate::detect::{detect_until, DetectError};
use trinocular_core::calibrate::estimate::{estimate_camera, CameraFit, EstimateOptions};
use trinocular_core::calibrate::{CalibrationPattern, GridBoard};
use trinocular_core::checkpoint::{Checkpoint, Stopped};
use trinocular_core::extract::decode::DecodeLimits;
use trinocular_core::extract::GreyImage;
use trinocular_core::geometry::{Camera, Rig, RigError};

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

/// A checked `CalibrateRequest`.
#[derive(Debug, Clone)]
pub struct CalibrateInput {
    pub pattern: CalibrationPattern,
    pub source: CalibrateSource,
    pub options: EstimateOptions,
    pub extract: trinocular_core::extract::Params,
    pub rig_from_pattern: Option<Isometry3<f64>>,
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
        rig_from_pattern,
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
    let rig_from_pattern = match rig_from_pattern {
        Some(pose) => Some(pose_from_pb(Some(pose), "rig_from_pattern")?),
        None => None,
    };
    let distortion = options.as_ref().and_then(|o| o.distortion).unwrap_or(false);
    let extract = extract_params(options.as_ref().and_then(|o| o.extract.as_ref()));
    extract
        .check()
        .map_err(|e| InputError::new(format!("options.extract.{}", e.field), e.to_string()))?;
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
        rig_from_pattern,
        names,
    })
}

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

/// One camera's correspondences, and how many boards its image showed.
struct Observed {
    points_3d: Vec<Point3<f64>>,
    points_2d: Vec<Point2<f64>>,
    size: (u32, u32),
    boards_found: u32,
}

impl CalibrateInput {
    /// Calibrates the rig: see the module doc. Errors name the image or list at fault.
    pub fn run(&self) -> Result<pb::CalibrateResponse, InputError> {
        self.run_until(Checkpoint::NEVER).map_err(|e| match e {
            RunError::Input(e) => e,
            RunError::Stopped { stage } => InputError::new("input", format!("stopped in {stage}")),
        })
    }

    /// [`CalibrateInput::run`], asking `checkpoint` as it detects the pattern and before it
    /// estimates the cameras.
    pub fn run_until(&self, checkpoint: Checkpoint) -> Result<pb::CalibrateResponse, RunError> {
        let start = Instant::now();
        let observed: Vec<Observed> = match &self.source {
            CalibrateSource::Images(images) => {
                let reference: HashMap<_, _> =
                    self.pattern.reference_points().into_iter().collect();
                images
                    .par_iter()
                    .enumerate()
                    .map(|(i, image)| {
                        let found = detect_until(image, &self.pattern, checkpoint).map_err(
                            |e| match e {
                                DetectError::Stopped(Stopped { stage }) => {
                                    RunError::Stopped { stage }
                                }
                                e => InputError::new(format!("images.images[{i}]"), e.to_string())
                                    .into(),
                            },
                        )?;
                        let (points_3d, points_2d) = found
                            .points
                            .iter()
                            .filter_map(|(id, p)| reference.get(id).map(|q| (*q, *p)))
                            .unzip();
                        Ok(Observed {
                            points_3d,
                            points_2d,
                            size: (image.width(), image.height()),
                            boards_found: found.boards_found as u32,
                        })
                    })
                    // Collected whole, then in order: the error names the first image at
                    // fault, not whichever thread failed first.
                    .collect::<Vec<Result<_, RunError>>>()
                    .into_iter()
                    .collect::<Result<_, RunError>>()?
            }
            CalibrateSource::Correspondences {
                points_3d,
                points_2d,
                sizes,
            } => (0..3)
                .map(|i| Observed {
                    points_3d: points_3d.clone(),
                    points_2d: points_2d[i].clone(),
                    size: sizes[i],
                    boards_found: 0,
                })
                .collect(),
        };
        let field = |i: usize| match &self.source {
            CalibrateSource::Images(_) => format!("images.images[{i}]"),
            CalibrateSource::Correspondences { .. } => format!("correspondences.points_2d[{i}]"),
        };
        checkpoint
            .before("estimate")
            .map_err(|Stopped { stage }| RunError::Stopped { stage })?;
        let fits: Vec<CameraFit> = observed
            .par_iter()
            .enumerate()
            .map(|(i, o)| {
                estimate_camera(
                    &self.names[i],
                    o.size.0,
                    o.size.1,
                    &o.points_3d,
                    &o.points_2d,
                    &self.options,
                )
                .map_err(|e| InputError::new(field(i), e.to_string()))
            })
            .collect::<Vec<_>>()
            .into_iter()
            .collect::<Result<_, _>>()?;
        let cameras: Vec<Camera> = fits
            .iter()
            .map(|fit| self.in_rig_frame(&fit.camera))
            .collect::<Result<_, _>>()?;
        let [a, b, c]: [Camera; 3] = cameras
            .try_into()
            .map_err(|_| InputError::new("input", "three cameras expected"))?;
        let rig = Rig::new([a, b, c]).map_err(|e| match e {
            RigError::CoincidentCentres { second, .. } => {
                InputError::new(field(second), e.to_string())
            }
        })?;
        Ok(pb::CalibrateResponse {
            calibration: Some(pb::Calibration {
                cameras: rig
                    .cameras()
                    .iter()
                    .map(|c| camera_to_pb(c, true))
                    .collect(),
            }),
            reports: fits
                .iter()
                .zip(&observed)
                .map(|(fit, o)| pb::CameraReport {
                    camera: fit.camera.name().to_string(),
                    rms_px: fit.rms_px,
                    max_px: fit.max_px,
                    points: fit.points as u32,
                    boards_found: o.boards_found,
                })
                .collect(),
            total_ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// The camera mapping rig-frame points: P_rig = P_pattern · (rig_from_pattern)⁻¹.
    fn in_rig_frame(&self, camera: &Camera) -> Result<Camera, InputError> {
        let Some(rig_from_pattern) = &self.rig_from_pattern else {
            return Ok(camera.clone());
        };
        let pattern_from_rig = rig_from_pattern.inverse().to_homogeneous();
        let p = camera.projection() * pattern_from_rig;
        Camera::from_projection(
            camera.name().to_string(),
            camera.width(),
            camera.height(),
            p,
            camera.distortion().cloned(),
        )
        .map_err(|e| InputError::new("rig_from_pattern", e.to_string()))
    }
}
