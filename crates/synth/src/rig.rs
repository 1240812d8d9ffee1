//! Synthetic trinocular rigs and rig poses.
//!
//! A [`RigSpec`] describes three cameras by physically meaningful numbers (optical centre in
//! the rig frame, yaw/pitch/roll, focal lengths, principal point, distortion) and builds a
//! validated [`Rig`] through [`Camera::from_krt`], placed in the world by a [`Pose`]
//! (`rig_to_world`).
//!
//! Orientation convention: with yaw = pitch = roll = 0 a camera looks along rig +y with its
//! image x along rig +x and image y (down) along rig −z. Then, in this order, it rolls about
//! its optical axis, pitches about rig x (positive = looks up) and yaws about rig z (positive
//! = turns left, seen from above).
//!
//! Presets: [`RigSpec::non_collinear`] mimics the rig of the rendered office data set,
//! [`RigSpec::collinear`] a Bumblebee XB3-like bar, [`RigSpec::random`] spans the space that
//! property tests should survive.

use nalgebra::{Matrix3, Matrix4, Point3, Rotation3, Vector3};
use thiserror::Error;

use super::rng::Rng;
use trinocular_core::geometry::{Camera, CameraError, Distortion, Rig, RigError};

/// Why a spec does not make a rig.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SynthError {
    #[error("camera {camera}: {source}")]
    Camera {
        camera: usize,
        #[source]
        source: CameraError,
    },
    #[error(transparent)]
    Rig(#[from] RigError),
}

/// A rigid transform `rig_to_world`: `x_world = rotation · x_rig + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub rotation: Rotation3<f64>,
    pub translation: Vector3<f64>,
}

impl Pose {
    pub fn identity() -> Pose {
        Pose {
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// Rig origin at `position`, turned by `yaw_rad` about world z (0: rig axes = world axes,
    /// the rig looks along world +y; positive turns it left, seen from above).
    pub fn from_position_yaw(position: Point3<f64>, yaw_rad: f64) -> Pose {
        Pose {
            rotation: Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_rad),
            translation: position.coords,
        }
    }

    pub fn transform_point(&self, rig: &Point3<f64>) -> Point3<f64> {
        self.rotation * rig + self.translation
    }

    /// The same transform as an isometry.
    pub fn to_isometry(&self) -> nalgebra::Isometry3<f64> {
        nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::from(self.translation),
            nalgebra::UnitQuaternion::from_rotation_matrix(&self.rotation),
        )
    }

    /// The 4x4 homogeneous matrix (DESIGN §1 `rig_to_world`).
    pub fn to_matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(self.rotation.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }
}

/// One camera of a [`RigSpec`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    /// Optical centre, rig frame, metres.
    pub centre: Point3<f64>,
    pub yaw_rad: f64,
    pub pitch_rad: f64,
    pub roll_rad: f64,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: Option<Distortion>,
}

/// rig_to_cam rotation of a camera with the given yaw, pitch and roll (module doc).
pub fn cam_from_rig_rotation(yaw_rad: f64, pitch_rad: f64, roll_rad: f64) -> Matrix3<f64> {
    // cam_to_rig at rest: columns are the camera axes in the rig frame.
    let rest = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
    let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_rad);
    let pitch = Rotation3::from_axis_angle(&Vector3::x_axis(), pitch_rad);
    let roll = Rotation3::from_axis_angle(&Vector3::y_axis(), roll_rad);
    let cam_to_rig = yaw.matrix() * pitch.matrix() * roll.matrix() * rest;
    cam_to_rig.transpose()
}

impl CameraSpec {
    fn intrinsics(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// The camera mapping world points, for a rig at `rig_to_world`.
    pub fn camera(
        &self,
        name: &str,
        width: u32,
        height: u32,
        rig_to_world: &Pose,
    ) -> Result<Camera, CameraError> {
        let rig_to_cam = cam_from_rig_rotation(self.yaw_rad, self.pitch_rad, self.roll_rad);
        let world_to_cam = rig_to_cam * rig_to_world.rotation.matrix().transpose();
        let centre_world = rig_to_world.transform_point(&self.centre);
        let t = -(world_to_cam * centre_world.coords);
        Camera::from_krt(
            name,
            width,
            height,
            self.intrinsics(),
            world_to_cam,
            t,
            self.distortion,
        )
    }
}

/// Three cameras sharing one image size.
#[derive(Debug, Clone, PartialEq)]
pub struct RigSpec {
    pub width: u32,
    pub height: u32,
    pub cameras: [CameraSpec; 3],
}

fn deg(d: f64) -> f64 {
    d.to_radians()
}

impl RigSpec {
    /// Like the rendered office data: centres at about (0,0,0), (0.30,0.012,−0.004),
    /// (0.15,−0.018,0.25) m, 512x512, f ≈ 560–650 px, pitched down ~5–8°, converging by a
    /// couple of degrees, with a seeded jitter of a fraction of a degree and a few pixels.
    pub fn non_collinear(seed: u64) -> RigSpec {
        let root = Rng::new(seed).fork(0x816_0001);
        // (centre, yaw, pitch, roll in degrees, fx, fy, cx, cy)
        let nominal = [
            ([0.0, 0.0, 0.0], -1.5, -6.0, 0.7, 600.0, 601.2, 257.3, 253.8),
            (
                [0.30, 0.012, -0.004],
                2.5,
                -5.0,
                -1.2,
                640.0,
                640.8,
                252.1,
                258.9,
            ),
            (
                [0.15, -0.018, 0.25],
                0.5,
                -8.0,
                1.9,
                585.0,
                584.3,
                259.6,
                255.0,
            ),
        ];
        let cameras = std::array::from_fn(|i| {
            let (c, yaw, pitch, roll, fx, fy, cx, cy) = nominal[i];
            let mut r = root.fork(i as u64);
            let df = r.symmetric(10.0);
            CameraSpec {
                centre: Point3::new(
                    c[0] + r.symmetric(0.003),
                    c[1] + r.symmetric(0.003),
                    c[2] + r.symmetric(0.003),
                ),
                yaw_rad: deg(yaw + r.symmetric(0.5)),
                pitch_rad: deg(pitch + r.symmetric(0.5)),
                roll_rad: deg(roll + r.symmetric(0.5)),
                fx: fx + df,
                fy: fy + df + r.symmetric(1.0),
                cx: cx + r.symmetric(3.0),
                cy: cy + r.symmetric(3.0),
                distortion: None,
            }
        });
        RigSpec {
            width: 512,
            height: 512,
            cameras,
        }
    }

    /// Three cameras on a horizontal bar at 0, 0.12 and 0.24 m (a Bumblebee XB3), with the
    /// same nominal intrinsics and orientation up to manufacturing tolerances (≤ 0.1°, ≤ 1 px).
    /// The centres are exactly collinear.
    pub fn collinear(seed: u64) -> RigSpec {
        let root = Rng::new(seed).fork(0x816_0002);
        let mut common = root.fork(99);
        let f = 600.0 + common.symmetric(20.0);
        let pitch = -5.0 + common.symmetric(1.0);
        let cameras = std::array::from_fn(|i| {
            let mut r = root.fork(i as u64);
            let df = r.symmetric(1.0);
            CameraSpec {
                centre: Point3::new(0.12 * i as f64, 0.0, 0.0),
                yaw_rad: deg(r.symmetric(0.1)),
                pitch_rad: deg(pitch + r.symmetric(0.1)),
                roll_rad: deg(r.symmetric(0.1)),
                fx: f + df,
                fy: f + df + r.symmetric(0.3),
                cx: 255.5 + r.symmetric(1.0),
                cy: 255.5 + r.symmetric(1.0),
                distortion: None,
            }
        });
        RigSpec {
            width: 512,
            height: 512,
            cameras,
        }
    }

    /// A random rig for property tests: baselines 0.05–0.5 m roughly across the viewing
    /// direction, rotations within ±5° (plus a common pitch within ±10°), f in 300–900 px,
    /// principal points within 10% of the centre, one of a few common image sizes. Collinear
    /// rigs put the third centre on the line of the first two (beyond, before or between).
    pub fn random(seed: u64, collinear: bool) -> RigSpec {
        let mut r = Rng::new(seed).fork(0x816_0003);
        let sizes = [(512u32, 512u32), (640, 480), (320, 240), (800, 600)];
        let (width, height) = sizes[r.index(sizes.len())];
        let heading = deg(r.symmetric(20.0));
        let tilt = deg(r.symmetric(10.0));
        let along = Vector3::new(heading.cos() * tilt.cos(), tilt.sin(), heading.sin());
        let b12 = r.range(0.05, 0.5);
        let c3 = if collinear {
            let b = r.range(0.05, 0.5);
            let at = match r.index(3) {
                0 => b12 + b,
                1 => -b,
                _ if b12 >= 0.1 => b12 * r.range(0.3, 0.7),
                _ => b12 + b,
            };
            along * at
        } else {
            // Off the baseline, in the plane across the view, mostly upwards.
            let side = Vector3::new(0.0, 0.0, 1.0) - along * along.z;
            let side = side.try_normalize(1e-9).unwrap_or_else(Vector3::z);
            let angle = deg(r.symmetric(30.0));
            let off = (side * angle.cos() + along * angle.sin()) * r.range(0.05, 0.5);
            along * (b12 * r.range(0.0, 1.0)) + off
        };
        let centres = [Vector3::zeros(), along * b12, c3];
        let common_pitch = r.symmetric(10.0);
        let cameras = std::array::from_fn(|i| {
            let mut c = r.fork(i as u64);
            let fx = c.range(300.0, 900.0);
            CameraSpec {
                centre: Point3::from(centres[i]),
                yaw_rad: deg(c.symmetric(5.0)),
                pitch_rad: deg(common_pitch + c.symmetric(5.0)),
                roll_rad: deg(c.symmetric(5.0)),
                fx,
                fy: fx * (1.0 + c.symmetric(0.01)),
                cx: width as f64 * (0.5 + c.symmetric(0.1)) - 0.5,
                cy: height as f64 * (0.5 + c.symmetric(0.1)) - 0.5,
                distortion: None,
            }
        });
        RigSpec {
            width,
            height,
            cameras,
        }
    }

    /// A rig of [`RigShape`] `shape`: the optical centres and yaws of the shape, each camera
    /// with the intrinsics, pitch and roll of [`RigSpec::non_collinear`]'s (seeded jitter
    /// included), so that shapes differ by their geometry alone.
    pub fn shaped(shape: RigShape, seed: u64) -> RigSpec {
        let mut spec = RigSpec::non_collinear(seed);
        let Some((centres, yaws_deg)) = shape.geometry() else {
            return spec;
        };
        let root = Rng::new(seed).fork(0x816_0004);
        for (i, camera) in spec.cameras.iter_mut().enumerate() {
            let mut r = root.fork(i as u64);
            let c = centres[i];
            camera.centre = Point3::new(
                c[0] + r.symmetric(0.003),
                c[1] + r.symmetric(0.003),
                c[2] + r.symmetric(0.003),
            );
            camera.yaw_rad = deg(yaws_deg[i] + r.symmetric(0.5));
        }
        spec
    }

    /// The same rig with `distortion` on every camera.
    pub fn with_distortion(mut self, distortion: Distortion) -> RigSpec {
        for c in &mut self.cameras {
            c.distortion = Some(distortion);
        }
        self
    }

    /// The validated rig, with cameras mapping world points, at `rig_to_world`.
    pub fn build(&self, rig_to_world: &Pose) -> Result<Rig, SynthError> {
        let camera = |i: usize| {
            self.cameras[i]
                .camera(
                    &format!("cam{}", i + 1),
                    self.width,
                    self.height,
                    rig_to_world,
                )
                .map_err(|source| SynthError::Camera { camera: i, source })
        };
        Ok(Rig::new([camera(0)?, camera(1)?, camera(2)?])?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_poses_isometry_is_its_matrix() {
        let pose = Pose::from_position_yaw(Point3::new(1.0, -2.0, 0.5), 0.7);
        let diff = pose.to_isometry().to_homogeneous() - pose.to_matrix();
        assert!(diff.abs().max() < 1e-15, "{diff}");
    }

    #[test]
    fn rest_orientation_looks_along_y() {
        let r = cam_from_rig_rotation(0.0, 0.0, 0.0);
        assert!((r * Vector3::y() - Vector3::z()).norm() < 1e-12);
        assert!((r * Vector3::x() - Vector3::x()).norm() < 1e-12);
        assert!((r * Vector3::z() + Vector3::y()).norm() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        // Positive pitch looks up, positive yaw looks left.
        let up = cam_from_rig_rotation(0.0, 0.1, 0.0).transpose() * Vector3::z();
        assert!(up.z > 0.0);
        let left = cam_from_rig_rotation(0.1, 0.0, 0.0).transpose() * Vector3::z();
        assert!(left.x < 0.0);
    }

    #[test]
    fn presets_build_and_match_their_description() {
        for seed in 0..20 {
            let rig = RigSpec::non_collinear(seed)
                .build(&Pose::identity())
                .unwrap();
            let c = rig.cameras();
            assert!((c[1].centre() - Point3::new(0.30, 0.012, -0.004)).norm() < 0.01);
            for cam in c {
                assert!(cam.axis().y > 0.98);
                assert!((560.0..=660.0).contains(&cam.focal_px()));
            }
            let rig = RigSpec::collinear(seed).build(&Pose::identity()).unwrap();
            let c = rig.cameras();
            let d = c[2].centre() - c[0].centre();
            let e = c[1].centre() - c[0].centre();
            assert!(d.cross(&e).norm() < 1e-12);
            for collinear in [false, true] {
                let rig = RigSpec::random(seed, collinear)
                    .build(&Pose::identity())
                    .unwrap();
                let c = rig.cameras();
                let b = (c[1].centre() - c[0].centre()).norm();
                assert!((0.05..=0.5).contains(&b));
                let cross = (c[2].centre() - c[0].centre()).cross(&(c[1].centre() - c[0].centre()));
                assert_eq!(cross.norm() < 1e-9, collinear);
            }
        }
    }

    #[test]
    fn pose_places_cameras_in_the_world() {
        let spec = RigSpec::non_collinear(1);
        let pose = Pose::from_position_yaw(Point3::new(2.0, 3.0, 1.2), std::f64::consts::FRAC_PI_2);
        let rig = spec.build(&pose).unwrap();
        let cam = &rig.cameras()[1];
        let expected = pose.transform_point(&spec.cameras[1].centre);
        assert!((cam.centre() - expected).norm() < 1e-12);
        // Yawed by 90° the rig looks along world −x.
        assert!(cam.axis().x < -0.98);
        let m = pose.to_matrix();
        let p = m * Point3::new(0.3, 0.0, 0.0).to_homogeneous();
        assert!((p.xyz() - Vector3::new(2.0, 3.3, 1.2)).norm() < 1e-12);
    }
}

/// The rig geometries matching must serve ("any three calibrated cameras"): the office-like
/// triangle facing the scene and the shapes that once lost their third camera or a
/// direction. Rig frame: x right, y forward (the viewing direction), z up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RigShape {
    /// [`RigSpec::non_collinear`]: centres in a triangle across the view (the reference).
    FacingTriangle,
    /// Three cameras at one height, the third 25 cm ahead of the middle of the other two.
    ThirdAhead,
    /// The same with the third 25 cm behind.
    ThirdBehind,
    /// An L: the third camera 25 cm above the first.
    LShape,
    /// A triangle only 2 cm off a line: horizontal segments are seen by a 7.6° epipolar angle.
    NearCollinear,
    /// The triangle at twice the size (0.6 m baseline).
    Wide,
    /// The triangle at a third of the size (0.1 m baseline).
    Narrow,
    /// Cameras 1 and 2 turned 15° towards each other.
    Converging,
    /// Cameras 1 and 2 turned 15° away from each other.
    Diverging,
}

impl RigShape {
    pub const ALL: [RigShape; 9] = [
        RigShape::FacingTriangle,
        RigShape::ThirdAhead,
        RigShape::ThirdBehind,
        RigShape::LShape,
        RigShape::NearCollinear,
        RigShape::Wide,
        RigShape::Narrow,
        RigShape::Converging,
        RigShape::Diverging,
    ];

    pub fn name(self) -> &'static str {
        match self {
            RigShape::FacingTriangle => "facing triangle",
            RigShape::ThirdAhead => "third camera ahead",
            RigShape::ThirdBehind => "third camera behind",
            RigShape::LShape => "L-shape",
            RigShape::NearCollinear => "near-collinear",
            RigShape::Wide => "wide (0.6 m)",
            RigShape::Narrow => "narrow (0.1 m)",
            RigShape::Converging => "converging 2 x 15°",
            RigShape::Diverging => "diverging 2 x 15°",
        }
    }

    /// Nominal centres (metres) and yaws (degrees) of the three cameras; `None` for the
    /// reference, which is [`RigSpec::non_collinear`] itself.
    fn geometry(self) -> Option<([[f64; 3]; 3], [f64; 3])> {
        let facing = [[0.0, 0.0, 0.0], [0.30, 0.0, 0.0], [0.15, 0.0, 0.25]];
        let scaled = |k: f64| facing.map(|c| c.map(|x| x * k));
        let level = [0.0; 3];
        Some(match self {
            RigShape::FacingTriangle => return None,
            RigShape::ThirdAhead => ([[0.0; 3], [0.30, 0.0, 0.0], [0.15, 0.25, 0.0]], level),
            RigShape::ThirdBehind => ([[0.0; 3], [0.30, 0.0, 0.0], [0.15, -0.25, 0.0]], level),
            RigShape::LShape => ([[0.0; 3], [0.30, 0.0, 0.0], [0.0, 0.0, 0.25]], level),
            RigShape::NearCollinear => ([[0.0; 3], [0.30, 0.0, 0.0], [0.15, 0.0, 0.02]], level),
            RigShape::Wide => (scaled(2.0), level),
            RigShape::Narrow => (scaled(1.0 / 3.0), level),
            RigShape::Converging => (facing, [-15.0, 15.0, 0.0]),
            RigShape::Diverging => (facing, [15.0, -15.0, 0.0]),
        })
    }
}
