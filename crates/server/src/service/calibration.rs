//! The Calibrate use case: the rig's cameras from images of a pattern or from
//! correspondences, on the compute pool like Match.
//!
//! The calibration of a rig in one call ([`RunCalibration`]): detect the pattern in the three
//! images (or take the caller's correspondences), estimate each camera, express them in the
//! rig frame if asked, and answer with both camera models and the error report.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use nalgebra::{Point2, Point3};
use rayon::prelude::*;

use super::matching::RunError;
use super::{Service, ServiceError};
use trinocular_core::calibrate::detect::{detect_with, DetectError};
use trinocular_core::calibrate::estimate::{estimate_camera, CameraFit};
use trinocular_core::checkpoint::{Checkpoint, Stopped};
use trinocular_core::extract::DecodeLimits;
use trinocular_core::geometry::{Camera, Rig, RigError};
use trinocular_schema::calibrate::{CalibrateInput, CalibrateSource};
use trinocular_schema::{self as api, camera_to_pb, pb, InputError};

impl Service {
    /// Calibrate. `read` produces the request on the compute pool (so an HTTP body is parsed
    /// there); past `timeout` the answer is DEADLINE_EXCEEDED and a queued job never runs.
    pub async fn calibrate(
        &self,
        read: impl FnOnce() -> Result<pb::CalibrateRequest, InputError> + Send + 'static,
        timeout: Option<Duration>,
    ) -> Result<pb::CalibrateResponse, ServiceError> {
        let limits = DecodeLimits {
            max_bytes: self.limits.max_message_bytes,
            max_pixels: self.limits.max_image_pixels,
        };
        let working = std::sync::Arc::clone(&self.working);
        let job = self.pool.run(move |abandoned| -> Result<_, ServiceError> {
            let stop = || abandoned.is_set();
            let request = read()?;
            let pixels = match &request.input {
                Some(pb::calibrate_request::Input::Images(triplet)) => {
                    api::triplet_pixels(triplet, &limits, |_| None)
                }
                _ => 0,
            };
            let _reserved = super::reserve(&working, super::memory::estimate(pixels, 0), "images")?;
            Ok(api::calibrate::calibrate_request(&request, &limits)?
                .run_until(Checkpoint::new(&stop))?)
        });
        super::within(job, self.deadline(timeout)).await
    }
}

/// One camera's correspondences, and how many boards its image showed.
struct Observed {
    points_3d: Vec<Point3<f64>>,
    points_2d: Vec<Point2<f64>>,
    size: (u32, u32),
    boards_found: u32,
}

/// Running a checked `CalibrateRequest` on the calling thread (the CLI's way; the service
/// runs it on the compute pool through [`Service::calibrate`]).
pub trait RunCalibration {
    /// Calibrates the rig: see the module doc. Errors name the image or list at fault.
    fn run(&self) -> Result<pb::CalibrateResponse, InputError>;

    /// [`RunCalibration::run`], asking `checkpoint` as it detects the pattern and before it
    /// estimates the cameras.
    fn run_until(&self, checkpoint: Checkpoint) -> Result<pb::CalibrateResponse, RunError>;
}

impl RunCalibration for CalibrateInput {
    fn run(&self) -> Result<pb::CalibrateResponse, InputError> {
        self.run_until(Checkpoint::NEVER).map_err(|e| match e {
            RunError::Input(e) => e,
            RunError::Stopped { stage } => InputError::new("input", format!("stopped in {stage}")),
        })
    }

    fn run_until(&self, checkpoint: Checkpoint) -> Result<pb::CalibrateResponse, RunError> {
        let start = Instant::now();
        let observed: Vec<Observed> = match &self.source {
            CalibrateSource::Images(images) => {
                let reference: HashMap<_, _> =
                    self.pattern.reference_points().into_iter().collect();
                images
                    .par_iter()
                    .enumerate()
                    .map(|(i, image)| {
                        let found = detect_with(image, &self.pattern, &self.extract, checkpoint)
                            .map_err(|e| match e {
                                DetectError::Stopped(Stopped { stage }) => {
                                    RunError::Stopped { stage }
                                }
                                e => InputError::new(format!("images.images[{i}]"), e.to_string())
                                    .into(),
                            })?;
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
            .map(|fit| in_rig_frame(self, &fit.camera))
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
}

/// The camera mapping rig-frame points: P_rig = P_pattern · (pattern_to_rig)⁻¹.
fn in_rig_frame(input: &CalibrateInput, camera: &Camera) -> Result<Camera, InputError> {
    let Some(pattern_to_rig) = &input.pattern_to_rig else {
        return Ok(camera.clone());
    };
    let rig_to_pattern = pattern_to_rig.inverse().to_homogeneous();
    let p = camera.projection() * rig_to_pattern;
    Camera::from_projection(
        camera.name().to_string(),
        camera.width(),
        camera.height(),
        p,
        camera.distortion().cloned(),
    )
    .map_err(|e| InputError::new("pattern_to_rig", e.to_string()))
}

/// Longest calibration file ImportCalibration reads, bytes.
pub const MAX_CALIBRATION_FILE_BYTES: usize = 1 << 20;

impl Service {
    /// ImportCalibration: a `Calibration` from other tools' files
    /// (`trinocular_schema::calibration_files`). `read` produces the request on the compute
    /// pool (so an HTTP body is parsed there), within the service's longest request time.
    pub async fn import_calibration(
        &self,
        read: impl FnOnce() -> Result<pb::ImportCalibrationRequest, InputError> + Send + 'static,
    ) -> Result<pb::Calibration, ServiceError> {
        use trinocular_schema::calibration_files::{import, CalibrationFormat};
        let job = self.pool.run(move |_| {
            let request = read()?;
            let format: CalibrationFormat = request.format.parse()?;
            if let Some(i) = request
                .files
                .iter()
                .position(|f| f.len() > MAX_CALIBRATION_FILE_BYTES)
            {
                return Err(InputError::new(
                    format!("files[{i}]"),
                    format!("longer than {MAX_CALIBRATION_FILE_BYTES} bytes"),
                ));
            }
            let files: Vec<&str> = request.files.iter().map(String::as_str).collect();
            import(format, &files)
        });
        super::within(job, self.deadline(None)).await
    }

    /// ExportCalibration: a `Calibration` written as other tools' files; `read` as for
    /// [`Service::import_calibration`].
    pub async fn export_calibration(
        &self,
        read: impl FnOnce() -> Result<pb::ExportCalibrationRequest, InputError> + Send + 'static,
    ) -> Result<pb::ExportCalibrationResponse, ServiceError> {
        use trinocular_schema::calibration_files::{export, CalibrationFormat};
        let job = self.pool.run(move |_| {
            let request = read()?;
            let format: CalibrationFormat = request.format.parse()?;
            let calibration = request.calibration.ok_or_else(|| {
                InputError::new("calibration", "missing: the calibration to write")
            })?;
            Ok::<_, InputError>(pb::ExportCalibrationResponse {
                files: export(format, &calibration)?,
            })
        });
        super::within(job, self.deadline(None)).await
    }
}
