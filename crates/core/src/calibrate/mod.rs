//! Calibration: the three projection matrices of a rig from images of a known pattern
//! (Faugeras and Toscani's procedure, as the paper uses it), or from 3D–2D correspondences a
//! user's own detector found.
//!
//! ```text
//! images ─▶ extract ─▶ detect (dark quadrilaterals → boards → ordered grid → refined corners)
//!                                         │ 3D–2D correspondences (or given)
//!                                         ▼
//!                       estimate (normalised DLT → RQ → Levenberg–Marquardt) ─▶ Camera + error report
//! ```

pub mod detect;
pub mod pattern;

pub use detect::{detect, DetectError, Detection};
pub use pattern::{CalibrationPattern, CornerId, GridBoard, PatternError};
pub mod estimate;
pub use estimate::{estimate_camera, CameraFit, EstimateError, EstimateOptions};
