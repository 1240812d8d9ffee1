//! Calibrations in the files robotics tools write, to and from our `Calibration`:
//!
//! - **Kalibr** `camchain.yaml` (one file): `cam0`, `cam1`, `cam2`, each `camera_model:
//!   pinhole`, `intrinsics: [fu, fv, pu, pv]`, `distortion_model: radtan` (or `none`) with
//!   `distortion_coeffs: [k1, k2, r1, r2]`, `resolution: [w, h]`; the extrinsics are
//!   `T_cn_cnm1`, the 4x4 taking camera n-1's frame to camera n's.
//! - **OpenCV** `FileStorage`, YAML or XML (one file), as a program writes it after
//!   `stereoCalibrate`: per camera k = 1, 2, 3 `cameraMatrix{k}` (or `M{k}`, `K{k}`) and
//!   `distCoeffs{k}` (or `D{k}`; 4, 5 or more coefficients: k1 k2 p1 p2 [k3]; more are refused),
//!   (a skew term is ignored, as OpenCV's own functions ignore it), the image size as
//!   `imageSize` [w, h] or `image_width`/`image_height` (or per camera
//!   `imageSize{k}`), and the extrinsics of cameras 2 and 3 from camera 1 as `R12`/`T12` and
//!   `R13`/`T13` (x_k = R x_1 + T, OpenCV's `R`, `T` of `stereoCalibrate(cam1, camk)`).
//! - **ROS** `camera_calibration` / `CameraInfo` YAML (one file per camera): `image_width`,
//!   `image_height`, `camera_name`, `camera_matrix`, `distortion_model: plumb_bob` and
//!   `distortion_coefficients`, `rectification_matrix` R and `projection_matrix` P. R is the
//!   rectification (camera frame to rectified frame), not the rig extrinsic: the extrinsics come
//!   from R and P together, as `camera_calibration` writes a stereo pair — the rectified frames
//!   are parallel to one common frame and P's fourth column is the camera's offset in it times
//!   its focal length (Tx = -fx' B). A raw camera k then takes common-frame points x to
//!   `R_k^T (x + b_k)`, b_k = (Tx/fx', Ty/fy', Tz). Three files, one per camera.
//!
//! The rig frame of an imported calibration is camera 1's frame turned to the conventions'
//! axes (x right, y forward, z up; camera 1 at the origin looking along +y). Exports write the
//! extrinsics relative to camera 1 (ROS: the common frame is camera 1's, so R = R_k1^T and P =
//! K [I | b]); a calibration whose rig frame is another is re-expressed in camera 1's (its
//! projections unchanged but for that rigid change of frame). Fisheye and omnidirectional models
//! (Kalibr `equidistant`, `fov`, `omni`, `ds`, `eucm`; ROS `equidistant`; OpenCV's fisheye
//! module) are refused naming the model: Trinocular's cameras are pinhole with plumb_bob
//! distortion.

use nalgebra::{Matrix3, Matrix4, Vector3};
use yaml_rust2::parser::{Event, EventReceiver, Parser};
use yaml_rust2::{Yaml, YamlLoader};

use super::{pb, InputError};
use crate::convert::{camera_to_pb, rig_from_calibration};
use crate::session::{nearest_rotation, NEAR_RIGID};

/// A file format of calibrations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CalibrationFormat {
    Kalibr,
    OpenCvYaml,
    OpenCvXml,
    /// One file per camera.
    Ros,
}

impl CalibrationFormat {
    pub const ALL: [(&'static str, CalibrationFormat); 4] = [
        ("kalibr", CalibrationFormat::Kalibr),
        ("opencv-yaml", CalibrationFormat::OpenCvYaml),
        ("opencv-xml", CalibrationFormat::OpenCvXml),
        ("ros", CalibrationFormat::Ros),
    ];

    pub fn name(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("?", |(n, _)| n)
    }

    /// How many files hold one rig's calibration.
    pub fn files(self) -> usize {
        match self {
            CalibrationFormat::Ros => 3,
            _ => 1,
        }
    }
}

impl std::str::FromStr for CalibrationFormat {
    type Err = InputError;

    fn from_str(s: &str) -> Result<Self, InputError> {
        Self::ALL
            .iter()
            .find(|(n, _)| *n == s)
            .map(|&(_, f)| f)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|(n, _)| *n).collect();
                InputError::new(
                    "format",
                    format!("must be one of {}, got {s:?}", names.join(", ")),
                )
            })
    }
}

/// A camera read from a file: in its own terms, before the rig frame is chosen.
#[derive(Debug, Clone, PartialEq)]
struct FileCamera {
    name: String,
    width: u32,
    height: u32,
    k: Matrix3<f64>,
    /// k1 k2 p1 p2 k3
    distortion: [f64; 5],
    /// Takes camera 1's frame to this camera's (identity for camera 1).
    from_first: Matrix4<f64>,
}

/// Camera 1's frame from the rig's: x right, y forward, z up to x right, y down, z forward.
fn camera1_from_rig() -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0)
}

fn row_major(m: &Matrix3<f64>) -> Vec<f64> {
    (0..9).map(|i| m[(i / 3, i % 3)]).collect()
}

/// Our `Calibration` of three cameras read from files: K, R, t per camera (and distortion).
fn to_calibration(cameras: Vec<FileCamera>) -> pb::Calibration {
    let a = camera1_from_rig();
    pb::Calibration {
        cameras: cameras
            .into_iter()
            .map(|c| {
                let r = c.from_first.fixed_view::<3, 3>(0, 0) * a;
                let t: Vector3<f64> = c.from_first.fixed_view::<3, 1>(0, 3).into();
                pb::Camera {
                    name: c.name,
                    width: c.width,
                    height: c.height,
                    projection: Vec::new(),
                    intrinsics: row_major(&c.k),
                    rotation: row_major(&r),
                    translation: t.as_slice().to_vec(),
                    distortion: (c.distortion != [0.0; 5]).then(|| pb::Distortion {
                        k1: c.distortion[0],
                        k2: c.distortion[1],
                        p1: c.distortion[2],
                        p2: c.distortion[3],
                        k3: c.distortion[4],
                    }),
                }
            })
            .collect(),
    }
}

/// The cameras of a `Calibration` in file terms (checked as a Match would check them).
fn from_calibration(calibration: &pb::Calibration) -> Result<Vec<FileCamera>, InputError> {
    let rig = rig_from_calibration(Some(calibration))?;
    let pose = |c: &trinocular_core::geometry::Camera| {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(c.rotation());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(c.translation());
        m
    };
    let first_inverse = pose(rig.camera(0))
        .try_inverse()
        .ok_or_else(|| InputError::new("calibration.cameras[0]", "its pose is singular"))?;
    Ok(rig
        .cameras()
        .iter()
        .map(|c| {
            let k = c.intrinsics() / c.intrinsics()[(2, 2)];
            let d = c
                .distortion()
                .map_or([0.0; 5], |d| [d.k1, d.k2, d.p1, d.p2, d.k3]);
            FileCamera {
                name: c.name().to_string(),
                width: c.width(),
                height: c.height(),
                k,
                distortion: d,
                from_first: pose(c) * first_inverse,
            }
        })
        .collect())
}

/// Reads a calibration from `files` (one, or three for ROS) in `format`. Errors name the file
/// (`files[i]`, or `file` for one) and the key.
pub fn import(format: CalibrationFormat, files: &[&str]) -> Result<pb::Calibration, InputError> {
    if files.len() != format.files() {
        return Err(InputError::new(
            "files",
            format!(
                "{} takes {} file{}, got {}",
                format.name(),
                format.files(),
                if format.files() == 1 {
                    ""
                } else {
                    "s (one per camera)"
                },
                files.len()
            ),
        ));
    }
    let cameras = match format {
        CalibrationFormat::Kalibr => kalibr::read(files[0])?,
        CalibrationFormat::OpenCvYaml => opencv::read(&opencv::Doc::yaml(files[0])?)?,
        CalibrationFormat::OpenCvXml => opencv::read(&opencv::Doc::xml(files[0])?)?,
        CalibrationFormat::Ros => ros::read(files)?,
    };
    let calibration = to_calibration(cameras);
    // What a Match would refuse is refused here, with the same field names.
    rig_from_calibration(Some(&calibration))?;
    Ok(calibration)
}

/// Writes `calibration` in `format`: one file, or three for ROS.
pub fn export(
    format: CalibrationFormat,
    calibration: &pb::Calibration,
) -> Result<Vec<String>, InputError> {
    let cameras = from_calibration(calibration)?;
    Ok(match format {
        CalibrationFormat::Kalibr => vec![kalibr::write(&cameras)],
        CalibrationFormat::OpenCvYaml => vec![opencv::write_yaml(&cameras)],
        CalibrationFormat::OpenCvXml => vec![opencv::write_xml(&cameras)],
        CalibrationFormat::Ros => ros::write(&cameras),
    })
}

/// The `Calibration` a rig's cameras give as K, R, t (for tests and the CLI's output).
pub fn calibration_krt(calibration: &pb::Calibration) -> Result<pb::Calibration, InputError> {
    let rig = rig_from_calibration(Some(calibration))?;
    Ok(pb::Calibration {
        cameras: rig
            .cameras()
            .iter()
            .map(|c| camera_to_pb(c, true))
            .collect(),
    })
}

fn bad(field: impl Into<String>, message: impl Into<String>) -> InputError {
    InputError::new(field, message)
}

/// Refuses a lens model that is not pinhole with plumb_bob (radtan) distortion.
fn pinhole_only(field: &str, model: &str) -> Result<(), InputError> {
    match model {
        "" | "pinhole" | "plumb_bob" | "radtan" | "rational_polynomial" | "none" => Ok(()),
        other => Err(bad(
            field,
            format!(
                "the {other:?} model is not supported: Trinocular's cameras are pinhole with \
                 plumb_bob (radtan) distortion; recalibrate with that model, or undistort the \
                 images first and give the pinhole model"
            ),
        )),
    }
}

fn yaml_doc(text: &str, file: &str) -> Result<Yaml, InputError> {
    // OpenCV writes "%YAML:1.0", which is not YAML 1.2's directive syntax.
    let cleaned: String = text
        .lines()
        .filter(|l| !l.starts_with("%YAML"))
        .collect::<Vec<_>>()
        .join("\n");
    let nodes = expanded_nodes(&cleaned).map_err(|e| bad(file, format!("not YAML: {e}")))?;
    if nodes > MAX_YAML_NODES {
        return Err(bad(
            file,
            format!(
                "the document expands to more than {MAX_YAML_NODES} nodes (each YAML alias \
                 repeats what its anchor names): not a calibration file"
            ),
        ));
    }
    let mut docs =
        YamlLoader::load_from_str(&cleaned).map_err(|e| bad(file, format!("not YAML: {e}")))?;
    if docs.is_empty() {
        return Err(bad(file, "empty"));
    }
    Ok(docs.swap_remove(0))
}

/// Most nodes a YAML calibration file may expand to. A calibration of three cameras is a few
/// hundred; the loader copies an alias's whole subtree wherever the alias stands, so a few
/// hundred bytes of nested aliases ("billion laughs") expand to billions of nodes — gigabytes
/// built before any field is read.
const MAX_YAML_NODES: u64 = 100_000;

/// The number of nodes `text` holds once every alias is replaced by what its anchor names, in
/// one pass over the parser's events (which build nothing): what the loader would build.
fn expanded_nodes(text: &str) -> Result<u64, yaml_rust2::ScanError> {
    #[derive(Default)]
    struct Count {
        /// The expanded size of each anchor seen, by anchor id.
        anchors: std::collections::HashMap<usize, u64>,
        /// The open collections: their anchor id and their expanded size so far.
        open: Vec<(usize, u64)>,
        total: u64,
    }
    impl Count {
        fn node(&mut self, anchor: usize, size: u64) {
            if anchor > 0 {
                self.anchors.insert(anchor, size);
            }
            match self.open.last_mut() {
                Some((_, parent)) => *parent = parent.saturating_add(size),
                None => self.total = self.total.saturating_add(size),
            }
        }
    }
    impl EventReceiver for Count {
        fn on_event(&mut self, event: Event) {
            match event {
                Event::Scalar(_, _, anchor, _) => self.node(anchor, 1),
                Event::SequenceStart(anchor, _) | Event::MappingStart(anchor, _) => {
                    self.open.push((anchor, 1))
                }
                Event::SequenceEnd | Event::MappingEnd => {
                    if let Some((anchor, size)) = self.open.pop() {
                        self.node(anchor, size);
                    }
                }
                Event::Alias(anchor) => {
                    let size = self.anchors.get(&anchor).copied().unwrap_or(1);
                    self.node(0, size);
                }
                _ => {}
            }
        }
    }
    let mut count = Count::default();
    Parser::new_from_str(text).load(&mut count, true)?;
    Ok(count.total)
}

/// `s` as a YAML double-quoted scalar: a camera's name written as it is, whatever YAML would
/// make of it bare (`a: b`, `# note`, `*alias`, a leading space). Control characters never
/// reach here: a calibration's names are refused with them.
fn yaml_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn number(y: &Yaml) -> Option<f64> {
    match y {
        Yaml::Integer(i) => Some(*i as f64),
        Yaml::Real(_) => y.as_f64(),
        Yaml::String(s) => s.trim().parse().ok(),
        _ => None,
    }
}

fn numbers(y: &Yaml, field: &str) -> Result<Vec<f64>, InputError> {
    let list = y
        .as_vec()
        .ok_or_else(|| bad(field, "missing, or not a list of numbers"))?;
    list.iter()
        .enumerate()
        .map(|(i, v)| {
            number(v)
                .filter(|x| x.is_finite())
                .ok_or_else(|| bad(format!("{field}[{i}]"), "not a finite number"))
        })
        .collect()
}

fn size(v: f64, field: &str) -> Result<u32, InputError> {
    if (1.0..=100_000.0).contains(&v) && v.fract() == 0.0 {
        Ok(v as u32)
    } else {
        Err(bad(
            field,
            format!("must be a whole number of pixels, got {v}"),
        ))
    }
}

/// k1 k2 p1 p2 [k3], refusing higher-order models that would be silently dropped.
fn plumb_bob(d: &[f64], field: &str) -> Result<[f64; 5], InputError> {
    if d.len() > 5 && d[5..].iter().any(|&x| x != 0.0) {
        return Err(bad(
            field,
            format!(
                "{} coefficients: only k1 k2 p1 p2 k3 (plumb_bob) are supported, and the \
                 higher ones are not zero",
                d.len()
            ),
        ));
    }
    if !d.is_empty() && d.len() < 4 {
        return Err(bad(
            field,
            format!("needs 4 or 5 coefficients, got {}", d.len()),
        ));
    }
    let mut out = [0.0; 5];
    for (o, v) in out.iter_mut().zip(d) {
        *o = *v;
    }
    Ok(out)
}

/// Files print rotations to a few digits: the nearest rotation to one within
/// [`NEAR_RIGID`] of orthonormal (as a pose may be); one further off is refused.
fn rotation_of(m: &Matrix3<f64>, field: &str) -> Result<Matrix3<f64>, InputError> {
    let off = (m.transpose() * m - Matrix3::identity()).abs().max();
    if off > NEAR_RIGID || m.determinant() <= 0.0 {
        return Err(bad(
            field,
            format!(
                "not a rotation (max |RᵀR − I| = {off:.2e}, det = {:.4})",
                m.determinant()
            ),
        ));
    }
    Ok(nearest_rotation(m))
}

fn fmt(x: f64) -> String {
    // Shortest text that reads back to the same f64.
    format!("{x:?}")
}

fn list(xs: impl IntoIterator<Item = f64>) -> String {
    let v: Vec<String> = xs.into_iter().map(fmt).collect();
    format!("[{}]", v.join(", "))
}

mod kalibr {
    use super::*;

    pub(super) fn read(text: &str) -> Result<Vec<FileCamera>, InputError> {
        let doc = yaml_doc(text, "file")?;
        // A chain of more cameras is another rig: which three would be meant is not ours to
        // guess.
        if !doc["cam3"].is_badvalue() {
            return Err(bad(
                "cam3",
                "a camchain of more than three cameras: Trinocular's rig is three; keep cam0, \
                 cam1 and cam2 (re-chained if the three are not the first)",
            ));
        }
        let mut cameras = Vec::new();
        let mut from_first = Matrix4::identity();
        for n in 0..3 {
            let key = format!("cam{n}");
            let cam = &doc[key.as_str()];
            if cam.is_badvalue() {
                return Err(bad(key, "missing: a Kalibr camchain of three cameras"));
            }
            let field = |k: &str| format!("{key}.{k}");
            let model = cam["camera_model"].as_str().unwrap_or("pinhole");
            pinhole_only(&field("camera_model"), model)?;
            let dmodel = cam["distortion_model"].as_str().unwrap_or("none");
            pinhole_only(&field("distortion_model"), dmodel)?;
            let i = numbers(&cam["intrinsics"], &field("intrinsics"))?;
            if i.len() != 4 {
                return Err(bad(field("intrinsics"), "needs [fu, fv, pu, pv]"));
            }
            let d = if dmodel == "none" || cam["distortion_coeffs"].is_badvalue() {
                [0.0; 5]
            } else {
                let c = numbers(&cam["distortion_coeffs"], &field("distortion_coeffs"))?;
                if c.len() != 4 {
                    return Err(bad(
                        field("distortion_coeffs"),
                        "radtan needs [k1, k2, r1, r2]",
                    ));
                }
                [c[0], c[1], c[2], c[3], 0.0]
            };
            let r = numbers(&cam["resolution"], &field("resolution"))?;
            if r.len() != 2 {
                return Err(bad(field("resolution"), "needs [width, height]"));
            }
            if n > 0 {
                let rows = cam["T_cn_cnm1"]
                    .as_vec()
                    .ok_or_else(|| bad(field("T_cn_cnm1"), "missing: a 4x4 list of rows"))?;
                let mut t = Matrix4::zeros();
                if rows.len() != 4 {
                    return Err(bad(field("T_cn_cnm1"), "needs 4 rows"));
                }
                for (i, row) in rows.iter().enumerate() {
                    let v = numbers(row, &format!("{}[{i}]", field("T_cn_cnm1")))?;
                    if v.len() != 4 {
                        return Err(bad(field("T_cn_cnm1"), "needs 4 columns"));
                    }
                    for (j, x) in v.into_iter().enumerate() {
                        t[(i, j)] = x;
                    }
                }
                // A rigid transform's last row; its rotation part is checked with the
                // calibration (the nearest rotation, within NEAR_RIGID).
                let last = [t[(3, 0)], t[(3, 1)], t[(3, 2)], t[(3, 3)] - 1.0];
                if last.iter().any(|x| x.abs() > 1e-9) {
                    return Err(bad(
                        format!("{}[3]", field("T_cn_cnm1")),
                        "must be [0, 0, 0, 1]: a rigid transform",
                    ));
                }
                from_first = t * from_first;
            }
            cameras.push(FileCamera {
                name: cam["rostopic"]
                    .as_str()
                    .map_or(key.clone(), |t| t.trim_matches('/').to_string()),
                width: size(r[0], &field("resolution[0]"))?,
                height: size(r[1], &field("resolution[1]"))?,
                k: Matrix3::new(i[0], 0.0, i[2], 0.0, i[1], i[3], 0.0, 0.0, 1.0),
                distortion: d,
                from_first,
            });
        }
        Ok(cameras)
    }

    pub(super) fn write(cameras: &[FileCamera]) -> String {
        let mut out = String::from("# Kalibr camchain, written by trinocular calibration export\n");
        for (n, c) in cameras.iter().enumerate() {
            out.push_str(&format!("cam{n}:\n"));
            if n > 0 {
                let t = c.from_first
                    * cameras[n - 1]
                        .from_first
                        .try_inverse()
                        .unwrap_or_else(Matrix4::identity);
                out.push_str("  T_cn_cnm1:\n");
                for i in 0..4 {
                    out.push_str(&format!("  - {}\n", list((0..4).map(|j| t[(i, j)]))));
                }
            }
            out.push_str("  camera_model: pinhole\n");
            out.push_str(&format!(
                "  intrinsics: {}\n",
                list([c.k[(0, 0)], c.k[(1, 1)], c.k[(0, 2)], c.k[(1, 2)]])
            ));
            out.push_str("  distortion_model: radtan\n");
            out.push_str(&format!(
                "  distortion_coeffs: {}\n",
                list(c.distortion[..4].iter().copied())
            ));
            out.push_str(&format!("  resolution: [{}, {}]\n", c.width, c.height));
            out.push_str(&format!(
                "  rostopic: {}\n",
                yaml_string(&format!("/{}", c.name))
            ));
        }
        out
    }
}

mod opencv {
    use super::*;

    /// An OpenCV FileStorage document: its top-level nodes by name.
    pub(super) enum Doc {
        Yaml(Yaml),
        Xml(Vec<(String, XmlNode)>),
    }

    /// A node's numbers, with its (rows, cols) when it is a matrix.
    type Shaped = (Vec<f64>, Option<(usize, usize)>);

    /// The whitespace-separated values of an XML element's text.
    fn values<T: std::str::FromStr>(text: &str, field: &str) -> Result<Vec<T>, InputError> {
        text.split_whitespace()
            .map(str::parse)
            .collect::<Result<Vec<T>, _>>()
            .map_err(|_| bad(field, "not a list of numbers"))
    }

    pub(super) enum XmlNode {
        Matrix {
            rows: usize,
            cols: usize,
            data: Vec<f64>,
        },
        Text(String),
    }

    impl Doc {
        pub(super) fn yaml(text: &str) -> Result<Doc, InputError> {
            Ok(Doc::Yaml(yaml_doc(text, "file")?))
        }

        pub(super) fn xml(text: &str) -> Result<Doc, InputError> {
            let doc = roxmltree::Document::parse(text)
                .map_err(|e| bad("file", format!("not XML: {e}")))?;
            let root = doc.root_element();
            if root.tag_name().name() != "opencv_storage" {
                return Err(bad(
                    "file",
                    "not an OpenCV FileStorage (no <opencv_storage>)",
                ));
            }
            let mut nodes = Vec::new();
            for node in root.children().filter(|n| n.is_element()) {
                let name = node.tag_name().name().to_string();
                let child = |tag: &str| {
                    node.children()
                        .find(|c| c.tag_name().name() == tag)
                        .and_then(|c| c.text())
                        .map(str::trim)
                };
                let data = || values(child("data").unwrap_or(""), &format!("{name}.data"));
                let value = if node.attribute("type_id") == Some("opencv-nd-matrix") {
                    // A 1-D array: its sizes multiply to its length.
                    let sizes: Vec<usize> =
                        values(child("sizes").unwrap_or(""), &format!("{name}.sizes"))?;
                    XmlNode::Matrix {
                        rows: sizes.iter().product(),
                        cols: 1,
                        data: data()?,
                    }
                } else if node.attribute("type_id") == Some("opencv-matrix") {
                    let count = |tag: &str| -> Result<usize, InputError> {
                        child(tag)
                            .and_then(|t| t.parse().ok())
                            .ok_or_else(|| bad(format!("{name}.{tag}"), "missing or not a count"))
                    };
                    XmlNode::Matrix {
                        rows: count("rows")?,
                        cols: count("cols")?,
                        data: data()?,
                    }
                } else {
                    XmlNode::Text(node.text().unwrap_or("").trim().to_string())
                };
                nodes.push((name, value));
            }
            Ok(Doc::Xml(nodes))
        }

        /// The numbers of the node named `key` (a matrix's data, or a list, or a scalar),
        /// with its shape when it is a matrix; none when absent.
        fn get(&self, key: &str) -> Result<Option<Shaped>, InputError> {
            match self {
                Doc::Yaml(doc) => {
                    let node = &doc[key];
                    if node.is_badvalue() {
                        return Ok(None);
                    }
                    if !node["data"].is_badvalue() {
                        let data = numbers(&node["data"], &format!("{key}.data"))?;
                        // opencv-matrix has rows and cols; opencv-nd-matrix (a 1-D array) sizes.
                        let shape = match (number(&node["rows"]), number(&node["cols"])) {
                            (Some(r), Some(c)) => Some((r as usize, c as usize)),
                            _ => numbers(&node["sizes"], &format!("{key}.sizes"))
                                .ok()
                                .map(|s| (s.iter().product::<f64>() as usize, 1)),
                        };
                        return Ok(Some((data, shape)));
                    }
                    if node.as_vec().is_some() {
                        return Ok(Some((numbers(node, key)?, None)));
                    }
                    let v = number(node).ok_or_else(|| bad(key, "not a number"))?;
                    Ok(Some((vec![v], None)))
                }
                Doc::Xml(nodes) => {
                    let Some((_, node)) = nodes.iter().find(|(n, _)| n == key) else {
                        return Ok(None);
                    };
                    Ok(Some(match node {
                        XmlNode::Matrix { rows, cols, data } => {
                            (data.clone(), Some((*rows, *cols)))
                        }
                        XmlNode::Text(t) => (values(t, key)?, None),
                    }))
                }
            }
        }

        /// The first of `keys` present, with `n` numbers (a matrix's shape must agree).
        fn numbers(
            &self,
            keys: &[&str],
            n: Option<usize>,
        ) -> Result<(String, Vec<f64>), InputError> {
            for key in keys {
                if let Some((data, shape)) = self.get(key)? {
                    if let Some((r, c)) = shape {
                        if r * c != data.len() {
                            return Err(bad(*key, format!("{r}x{c} but {} numbers", data.len())));
                        }
                    }
                    if let Some(n) = n {
                        if data.len() != n {
                            return Err(bad(
                                *key,
                                format!("needs {n} numbers, got {}", data.len()),
                            ));
                        }
                    }
                    if let Some(i) = data.iter().position(|x| !x.is_finite()) {
                        return Err(bad(format!("{key}[{i}]"), "not a finite number"));
                    }
                    return Ok((key.to_string(), data));
                }
            }
            Err(bad(
                keys[0],
                format!("missing (looked for {})", keys.join(", ")),
            ))
        }

        fn has(&self, key: &str) -> Result<bool, InputError> {
            Ok(self.get(key)?.is_some())
        }
    }

    pub(super) fn read(doc: &Doc) -> Result<Vec<FileCamera>, InputError> {
        for fisheye in ["fisheye", "fisheyeK1", "D1_fisheye"] {
            if doc.has(fisheye)? {
                return Err(bad(fisheye, "OpenCV's fisheye model is not supported: Trinocular's cameras are pinhole with plumb_bob distortion"));
            }
        }
        let mut cameras = Vec::new();
        for k in 1..=3 {
            let (_, kk) = doc.numbers(
                &[
                    &format!("cameraMatrix{k}"),
                    &format!("M{k}"),
                    &format!("K{k}"),
                ],
                Some(9),
            )?;
            let d = match doc.numbers(&[&format!("distCoeffs{k}"), &format!("D{k}")], None) {
                Ok((key, d)) => plumb_bob(&d, &key)?,
                Err(_) => [0.0; 5],
            };
            let size_keys = [format!("imageSize{k}"), "imageSize".to_string()];
            let given = doc.has(&size_keys[0])? || doc.has(&size_keys[1])?;
            let (width, height) = match given {
                true => {
                    let (key, s) = doc.numbers(&[&size_keys[0], &size_keys[1]], Some(2))?;
                    (size(s[0], &key)?, size(s[1], &key)?)
                }
                false => {
                    let (_, w) = doc.numbers(&["image_width"], Some(1))?;
                    let (_, h) = doc.numbers(&["image_height"], Some(1))?;
                    (size(w[0], "image_width")?, size(h[0], "image_height")?)
                }
            };
            let mut from_first = Matrix4::identity();
            if k > 1 {
                let (_, r) = doc.numbers(&[&format!("R1{k}")], Some(9))?;
                let (_, t) = doc.numbers(&[&format!("T1{k}")], Some(3))?;
                for i in 0..3 {
                    for j in 0..3 {
                        from_first[(i, j)] = r[3 * i + j];
                    }
                    from_first[(i, 3)] = t[i];
                }
            }
            // OpenCV's pinhole model reads fx, fy, cx, cy only: a skew term in the file is
            // ignored by every OpenCV function, so it is here too.
            let mut kk = Matrix3::from_row_slice(&kk);
            kk[(0, 1)] = 0.0;
            cameras.push(FileCamera {
                name: format!("cam{k}"),
                width,
                height,
                k: kk,
                distortion: d,
                from_first,
            });
        }
        Ok(cameras)
    }

    fn matrix_yaml(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
        format!(
            "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: {}\n",
            list(data.iter().copied())
        )
    }

    fn matrix_xml(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
        let v: Vec<String> = data.iter().map(|&x| fmt(x)).collect();
        format!(
            "<{name} type_id=\"opencv-matrix\">\n  <rows>{rows}</rows>\n  <cols>{cols}</cols>\n  \
             <dt>d</dt>\n  <data>\n    {}</data></{name}>\n",
            v.join(" ")
        )
    }

    fn nodes(cameras: &[FileCamera]) -> Vec<(String, usize, usize, Vec<f64>)> {
        let mut out = Vec::new();
        for (i, c) in cameras.iter().enumerate() {
            let k = i + 1;
            out.push((format!("cameraMatrix{k}"), 3, 3, row_major(&c.k)));
            out.push((format!("distCoeffs{k}"), 1, 5, c.distortion.to_vec()));
            out.push((
                format!("imageSize{k}"),
                1,
                2,
                vec![f64::from(c.width), f64::from(c.height)],
            ));
            if k > 1 {
                let r: Matrix3<f64> = c.from_first.fixed_view::<3, 3>(0, 0).into();
                out.push((format!("R1{k}"), 3, 3, row_major(&r)));
                out.push((
                    format!("T1{k}"),
                    3,
                    1,
                    (0..3).map(|j| c.from_first[(j, 3)]).collect(),
                ));
            }
        }
        out
    }

    pub(super) fn write_yaml(cameras: &[FileCamera]) -> String {
        let mut out = String::from("%YAML:1.0\n---\n");
        for (name, r, c, data) in nodes(cameras) {
            out.push_str(&matrix_yaml(&name, r, c, &data));
        }
        out
    }

    pub(super) fn write_xml(cameras: &[FileCamera]) -> String {
        let mut out = String::from("<?xml version=\"1.0\"?>\n<opencv_storage>\n");
        for (name, r, c, data) in nodes(cameras) {
            out.push_str(&matrix_xml(&name, r, c, &data));
        }
        out.push_str("</opencv_storage>\n");
        out
    }
}

mod ros {
    use super::*;

    fn matrix(doc: &Yaml, key: &str, file: &str, n: usize) -> Result<Vec<f64>, InputError> {
        let field = format!("{file}.{key}");
        let node = &doc[key];
        if node.is_badvalue() {
            return Err(bad(&field, "missing"));
        }
        let data = numbers(&node["data"], &format!("{field}.data"))?;
        if data.len() != n {
            return Err(bad(
                format!("{field}.data"),
                format!("needs {n} numbers, got {}", data.len()),
            ));
        }
        Ok(data)
    }

    pub(super) fn read(files: &[&str]) -> Result<Vec<FileCamera>, InputError> {
        // Per camera: K, distortion, size, R (raw to rectified) and b (offset in the common
        // rectified frame).
        let mut parsed = Vec::new();
        for (i, text) in files.iter().enumerate() {
            let file = format!("files[{i}]");
            let doc = yaml_doc(text, &file)?;
            let model = doc["distortion_model"].as_str().unwrap_or("plumb_bob");
            pinhole_only(&format!("{file}.distortion_model"), model)?;
            let k = matrix(&doc, "camera_matrix", &file, 9)?;
            let d = if doc["distortion_coefficients"].is_badvalue() {
                [0.0; 5]
            } else {
                let field = format!("{file}.distortion_coefficients");
                plumb_bob(
                    &numbers(&doc["distortion_coefficients"]["data"], &field)?,
                    &field,
                )?
            };
            let r = if doc["rectification_matrix"].is_badvalue() {
                Matrix3::identity()
            } else {
                let field = format!("{file}.rectification_matrix");
                rotation_of(
                    &Matrix3::from_row_slice(&matrix(&doc, "rectification_matrix", &file, 9)?),
                    &field,
                )?
            };
            let b = if doc["projection_matrix"].is_badvalue() {
                Vector3::zeros()
            } else {
                let p = matrix(&doc, "projection_matrix", &file, 12)?;
                let (fx, fy) = (p[0], p[5]);
                if fx == 0.0 || fy == 0.0 {
                    return Err(bad(
                        format!("{file}.projection_matrix"),
                        "fx' or fy' is zero",
                    ));
                }
                Vector3::new(p[3] / fx, p[7] / fy, p[11])
            };
            let w = number(&doc["image_width"])
                .ok_or_else(|| bad(format!("{file}.image_width"), "missing"))?;
            let h = number(&doc["image_height"])
                .ok_or_else(|| bad(format!("{file}.image_height"), "missing"))?;
            let name = doc["camera_name"]
                .as_str()
                .map_or(format!("cam{}", i + 1), str::to_string);
            parsed.push((
                name,
                size(w, &format!("{file}.image_width"))?,
                size(h, &format!("{file}.image_height"))?,
                Matrix3::from_row_slice(&k),
                d,
                r,
                b,
            ));
        }
        let (r1, b1) = (parsed[0].5, parsed[0].6);
        Ok(parsed
            .into_iter()
            .map(|(name, width, height, k, distortion, r, b)| {
                // x_k = R_k^T (x_common + b_k), x_common = R_1 x_1 - b_1.
                let rotation = r.transpose() * r1;
                let translation = r.transpose() * (b - b1);
                let mut from_first = Matrix4::identity();
                from_first.fixed_view_mut::<3, 3>(0, 0).copy_from(&rotation);
                from_first
                    .fixed_view_mut::<3, 1>(0, 3)
                    .copy_from(&translation);
                FileCamera {
                    name,
                    width,
                    height,
                    k,
                    distortion,
                    from_first,
                }
            })
            .collect())
    }

    pub(super) fn write(cameras: &[FileCamera]) -> Vec<String> {
        cameras
            .iter()
            .map(|c| {
                let rotation: Matrix3<f64> = c.from_first.fixed_view::<3, 3>(0, 0).into();
                let t: Vector3<f64> = c.from_first.fixed_view::<3, 1>(0, 3).into();
                // The common frame is camera 1's: R = R_k1^T, b = R_k1^T t_k1, P = K [I | b].
                let r = rotation.transpose();
                let b = r * t;
                let k = &c.k;
                // The reader takes b back as (Tx/fx', Ty/fy', Tz): P's left block is K
                // without its skew (P has none in ROS), its fourth column fx' b_x, fy' b_y, b_z.
                let p = [
                    k[(0, 0)],
                    0.0,
                    k[(0, 2)],
                    k[(0, 0)] * b.x,
                    0.0,
                    k[(1, 1)],
                    k[(1, 2)],
                    k[(1, 1)] * b.y,
                    0.0,
                    0.0,
                    1.0,
                    b.z,
                ];
                format!(
                    "# ROS CameraInfo, written by trinocular calibration export; the rectified\n\
                     # frames are parallel to camera 1's, P's fourth column is the offset in it.\n\
                     image_width: {}\nimage_height: {}\ncamera_name: {}\n\
                     camera_matrix:\n  rows: 3\n  cols: 3\n  data: {}\n\
                     distortion_model: plumb_bob\n\
                     distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {}\n\
                     rectification_matrix:\n  rows: 3\n  cols: 3\n  data: {}\n\
                     projection_matrix:\n  rows: 3\n  cols: 4\n  data: {}\n",
                    c.width,
                    c.height,
                    yaml_string(&c.name),
                    list(row_major(k)),
                    list(c.distortion),
                    list(row_major(&r)),
                    list(p),
                )
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Point3};

    /// A three-camera Kalibr chain in the documented format (values of the Kalibr wiki's
    /// camchain example for cam0 and cam1; cam2 a third camera further along).
    const KALIBR: &str = "\
cam0:
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.294719, 0.08601, -0.0003228, -0.0000501]
  distortion_model: radtan
  intrinsics: [461.14152593, 459.85600558, 363.00002051, 248.10086571]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [0.9999741703, 0.0001225282, 0.0071861893, -0.1100612398]
  - [-0.0001525345, 0.9999871553, 0.0050663471, 0.0003861546]
  - [-0.0071856167, -0.0050671573, 0.9999613519, -0.0001513299]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.2905, 0.0839, 0.00007, 0.00012]
  distortion_model: radtan
  intrinsics: [460.74072, 459.31648, 367.42339, 245.98535]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
cam2:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, 0.0551]
  - [0.0, 1.0, 0.0, -0.0905]
  - [0.0, 0.0, 1.0, 0.0012]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [-0.28, 0.079, 0.0001, -0.0002]
  distortion_model: radtan
  intrinsics: [462.0, 460.5, 370.1, 240.2]
  resolution: [752, 480]
  rostopic: /cam2/image_raw
";

    /// camera_calibration's stereo output, as the ROS tutorial shows it (left and right),
    /// and a third camera rectified to the same frame above them.
    const ROS_LEFT: &str = "\
image_width: 640
image_height: 480
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [429.15, 0, 306.17, 0, 429.07, 237.49, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.0060, 0.0022, 0.0012, 0.0015, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [0.9999, 0.0077, -0.0091, -0.0078, 0.9999, -0.0121, 0.0090, 0.0122, 0.9998]
projection_matrix:
  rows: 3
  cols: 4
  data: [295.53, 0, 285.55, 0, 0, 295.53, 223.29, 0, 0, 0, 1, 0]
";
    const ROS_RIGHT: &str = "\
image_width: 640
image_height: 480
camera_name: narrow_stereo/right
camera_matrix:
  rows: 3
  cols: 3
  data: [430.23, 0, 311.72, 0, 430.98, 221.18, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.0073, 0.0072, 0.0001, 0.0029, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [0.9999, 0.0046, -0.0119, -0.0044, 0.9999, 0.0121, 0.0120, -0.0120, 0.9998]
projection_matrix:
  rows: 3
  cols: 4
  data: [295.53, 0, 285.55, -26.51, 0, 295.53, 223.29, 0, 0, 0, 1, 0]
";
    const ROS_THIRD: &str = "\
image_width: 640
image_height: 480
camera_name: narrow_stereo/top
camera_matrix:
  rows: 3
  cols: 3
  data: [428.9, 0, 309.2, 0, 428.7, 230.1, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.0051, 0.0031, 0.0002, 0.0011, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [295.53, 0, 285.55, -13.25, 0, 295.53, 223.29, 17.73, 0, 0, 1, 0]
";

    fn project(k: &Matrix3<f64>, d: [f64; 5], cam: Vector3<f64>) -> Point2<f64> {
        let (x, y) = (cam.x / cam.z, cam.y / cam.z);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
        let xd = x * radial + 2.0 * d[2] * x * y + d[3] * (r2 + 2.0 * x * x);
        let yd = y * radial + d[2] * (r2 + 2.0 * y * y) + 2.0 * d[3] * x * y;
        let p = k * Vector3::new(xd, yd, 1.0);
        Point2::new(p.x, p.y)
    }

    /// Points 2-6 m in front of camera 1, spread across its view (in camera 1's frame).
    fn scene() -> Vec<Vector3<f64>> {
        let mut out = Vec::new();
        for z in [2.0, 3.5, 6.0] {
            for x in [-0.6, 0.0, 0.7] {
                for y in [-0.4, 0.1, 0.5] {
                    out.push(Vector3::new(x * z / 3.0, y * z / 3.0, z));
                }
            }
        }
        out
    }

    /// Largest pixel difference between `calibration`'s projections of the scene and
    /// `truth(k, point in camera 1's frame)`.
    fn worst(
        calibration: &pb::Calibration,
        truth: impl Fn(usize, Vector3<f64>) -> Point2<f64>,
    ) -> f64 {
        let rig = rig_from_calibration(Some(calibration)).unwrap();
        let a = camera1_from_rig();
        let mut worst: f64 = 0.0;
        for x1 in scene() {
            let rig_point = Point3::from(a.transpose() * x1);
            for k in 0..3 {
                let ours = rig.camera(k).project(&rig_point).unwrap();
                worst = worst.max((ours - truth(k, x1)).norm());
            }
        }
        worst
    }

    /// The same text but for numbers, which agree to 1e-9 (the last bits of a decomposition).
    fn same_file(a: &str, b: &str) {
        let split = |t: &str| -> Vec<String> {
            t.split(|c: char| c.is_whitespace() || ",[]<>".contains(c))
                .filter(|w| !w.is_empty())
                .map(str::to_string)
                .collect()
        };
        let (wa, wb) = (split(a), split(b));
        assert_eq!(wa.len(), wb.len(), "{a}\n{b}");
        for (x, y) in wa.iter().zip(&wb) {
            match (x.parse::<f64>(), y.parse::<f64>()) {
                (Ok(x), Ok(y)) => assert!((x - y).abs() <= 1e-9 * x.abs().max(1.0), "{x} {y}"),
                _ => assert_eq!(x, y),
            }
        }
    }

    fn same_projections(a: &pb::Calibration, b: &pb::Calibration) -> f64 {
        let rb = rig_from_calibration(Some(b)).unwrap();
        worst(a, |k, x1| {
            let p = Point3::from(camera1_from_rig().transpose() * x1);
            rb.camera(k).project(&p).unwrap()
        })
    }

    #[test]
    fn kalibr_imports_with_the_chain_composed_and_round_trips() {
        let calibration = import(CalibrationFormat::Kalibr, &[KALIBR]).unwrap();
        assert_eq!(calibration.cameras[0].name, "cam0/image_raw");
        assert_eq!(
            (calibration.cameras[1].width, calibration.cameras[1].height),
            (752, 480)
        );
        let doc = yaml_doc(KALIBR, "file").unwrap();
        let chain = |n: usize| -> Matrix4<f64> {
            let mut m = Matrix4::identity();
            for i in 1..=n {
                let rows = numbers(&doc[format!("cam{i}").as_str()]["T_cn_cnm1"][0], "r").unwrap();
                let _ = rows;
                let mut t = Matrix4::zeros();
                for r in 0..4 {
                    let v = numbers(&doc[format!("cam{i}").as_str()]["T_cn_cnm1"][r], "r").unwrap();
                    for c in 0..4 {
                        t[(r, c)] = v[c];
                    }
                }
                m = t * m;
            }
            m
        };
        let truth = |k: usize, x1: Vector3<f64>| {
            let cam = &doc[format!("cam{k}").as_str()];
            let i = numbers(&cam["intrinsics"], "i").unwrap();
            let d = numbers(&cam["distortion_coeffs"], "d").unwrap();
            let kk = Matrix3::new(i[0], 0.0, i[2], 0.0, i[1], i[3], 0.0, 0.0, 1.0);
            let xk = chain(k) * x1.push(1.0);
            project(&kk, [d[0], d[1], d[2], d[3], 0.0], xk.xyz())
        };
        let error = worst(&calibration, truth);
        assert!(error < 1e-9, "{error} px from the file's own projection");
        let again = import(
            CalibrationFormat::Kalibr,
            &[&export(CalibrationFormat::Kalibr, &calibration).unwrap()[0]],
        )
        .unwrap();
        assert!(same_projections(&calibration, &again) < 1e-9);
    }

    /// The documented files print R to four digits; the same rectifications to full precision
    /// (exact rotations), for a comparison to 1e-9 px.
    fn exact(text: &str, euler: (f64, f64, f64)) -> String {
        let r = nalgebra::Rotation3::from_euler_angles(euler.0, euler.1, euler.2);
        let start = text.find("rectification_matrix:").unwrap();
        let data = start + text[start..].find("data: ").unwrap() + 6;
        let end = data + text[data..].find('\n').unwrap();
        format!(
            "{}{}{}",
            &text[..data],
            list(row_major(r.matrix())),
            &text[end..]
        )
    }

    #[test]
    fn ros_files_printed_to_four_digits_import_their_nearest_rotations() {
        let calibration =
            import(CalibrationFormat::Ros, &[ROS_LEFT, ROS_RIGHT, ROS_THIRD]).unwrap();
        let rotated = ROS_LEFT.replace("0.9999, 0.0077", "0.9, 0.0077");
        let e = import(CalibrationFormat::Ros, &[&rotated, ROS_RIGHT, ROS_THIRD]).unwrap_err();
        assert_eq!(e.field, "files[0].rectification_matrix");
        assert_eq!(calibration.cameras.len(), 3);
    }

    #[test]
    fn ros_imports_a_rectified_stereo_set_and_round_trips() {
        let left = exact(ROS_LEFT, (0.0122, -0.0091, -0.0078));
        let right = exact(ROS_RIGHT, (-0.0120, -0.0119, -0.0044));
        let files = [left.as_str(), right.as_str(), ROS_THIRD];
        let calibration = import(CalibrationFormat::Ros, &files).unwrap();
        assert_eq!(calibration.cameras[1].name, "narrow_stereo/right");
        // The files' own model: a common rectified frame c; camera k sees R_k^T (x_c + b_k).
        type FileModel = (Matrix3<f64>, [f64; 5], Matrix3<f64>, Vector3<f64>);
        let parsed: Vec<FileModel> = files
            .iter()
            .map(|t| {
                let doc = yaml_doc(t, "f").unwrap();
                let k =
                    Matrix3::from_row_slice(&numbers(&doc["camera_matrix"]["data"], "k").unwrap());
                let d = numbers(&doc["distortion_coefficients"]["data"], "d").unwrap();
                let r = Matrix3::from_row_slice(
                    &numbers(&doc["rectification_matrix"]["data"], "r").unwrap(),
                );
                let p = numbers(&doc["projection_matrix"]["data"], "p").unwrap();
                (
                    k,
                    [d[0], d[1], d[2], d[3], d[4]],
                    r,
                    Vector3::new(p[3] / p[0], p[7] / p[5], p[11]),
                )
            })
            .collect();
        let truth = |k: usize, x1: Vector3<f64>| {
            let xc = parsed[0].2 * x1 - parsed[0].3;
            let (kk, d, r, b) = &parsed[k];
            project(kk, *d, r.transpose() * (xc + b))
        };
        let error = worst(&calibration, truth);
        assert!(error < 1e-9, "{error} px from the files' own projection");
        let written = export(CalibrationFormat::Ros, &calibration).unwrap();
        assert_eq!(written.len(), 3);
        let refs: Vec<&str> = written.iter().map(String::as_str).collect();
        let again = import(CalibrationFormat::Ros, &refs).unwrap();
        assert!(same_projections(&calibration, &again) < 1e-9);
        // A rig exported again is the same file (to rounding): export after import is the
        // identity.
        for (a, b) in export(CalibrationFormat::Ros, &again)
            .unwrap()
            .iter()
            .zip(&written)
        {
            same_file(a, b);
        }
    }

    /// A camera's name is written as a quoted string: names YAML would read as structure come
    /// back as they were, and a name of more than one line is refused before anything is
    /// written (an exported file held `image_width: 9999` as a key of its own).
    #[test]
    fn names_round_trip_whatever_yaml_would_make_of_them_and_lines_are_refused() {
        let mut calibration = import(CalibrationFormat::Kalibr, &[KALIBR]).unwrap();
        let names = [
            "cam: [evil] # not a comment",
            "*alias \"quoted\" \\ back",
            " lead",
        ];
        for (camera, name) in calibration.cameras.iter_mut().zip(names) {
            camera.name = name.to_string();
        }
        for format in [CalibrationFormat::Kalibr, CalibrationFormat::Ros] {
            let written = export(format, &calibration).unwrap();
            let files: Vec<&str> = written.iter().map(String::as_str).collect();
            let again = import(format, &files).unwrap();
            let names_again: Vec<&str> = again.cameras.iter().map(|c| c.name.as_str()).collect();
            assert_eq!(names_again, names, "{format:?}");
        }
        calibration.cameras[1].name = "cam2\nimage_width: 9999".to_string();
        let e = export(CalibrationFormat::Ros, &calibration).unwrap_err();
        assert_eq!(e.field, "calibration.cameras[1].name");
        assert!(e.message.contains("U+000A"), "{}", e.message);
    }

    #[test]
    fn opencv_yaml_and_xml_round_trip_through_each_other() {
        let calibration = import(CalibrationFormat::Kalibr, &[KALIBR]).unwrap();
        for format in [CalibrationFormat::OpenCvYaml, CalibrationFormat::OpenCvXml] {
            let text = export(format, &calibration).unwrap();
            let again = import(format, &[&text[0]]).unwrap();
            assert!(same_projections(&calibration, &again) < 1e-9, "{format:?}");
            same_file(&export(format, &again).unwrap()[0], &text[0]);
        }
    }

    #[test]
    fn fisheye_and_broken_files_are_refused_naming_what() {
        let fisheye = KALIBR.replacen(
            "distortion_model: radtan",
            "distortion_model: equidistant",
            1,
        );
        let e = import(CalibrationFormat::Kalibr, &[&fisheye]).unwrap_err();
        assert_eq!(e.field, "cam0.distortion_model");
        assert!(e.message.contains("equidistant"), "{}", e.message);
        let e = import(CalibrationFormat::Kalibr, &["cam0: {}"]).unwrap_err();
        assert!(e.field.starts_with("cam0."), "{}", e.field);
        let four = format!("{KALIBR}cam3:\n  camera_model: pinhole\n");
        let e = import(CalibrationFormat::Kalibr, &[&four]).unwrap_err();
        assert_eq!(e.field, "cam3");
        let skewed = KALIBR.replacen("  - [0.0, 0.0, 0.0, 1.0]", "  - [0.0, 0.0, 0.0, 0.999]", 1);
        let e = import(CalibrationFormat::Kalibr, &[&skewed]).unwrap_err();
        assert_eq!(e.field, "cam1.T_cn_cnm1[3]");
        let e = import(CalibrationFormat::Ros, &[ROS_LEFT]).unwrap_err();
        assert_eq!(e.field, "files");
        let e = import(CalibrationFormat::OpenCvXml, &["<a/>"]).unwrap_err();
        assert_eq!(e.field, "file");
        let e = import(
            CalibrationFormat::OpenCvYaml,
            &["%YAML:1.0\n---\nM1: [1, 2]\n"],
        )
        .unwrap_err();
        assert_eq!(e.field, "M1");
        assert!(e.message.contains("needs 9"), "{}", e.message);
        let bad_number = ROS_LEFT.replace("429.15", "nan");
        let e = import(CalibrationFormat::Ros, &[&bad_number, ROS_RIGHT, ROS_THIRD]).unwrap_err();
        assert_eq!(e.field, "files[0].camera_matrix.data[0]");
        assert_eq!(
            "kalibr".parse::<CalibrationFormat>().unwrap(),
            CalibrationFormat::Kalibr
        );
        assert_eq!(
            "matlab".parse::<CalibrationFormat>().unwrap_err().field,
            "format"
        );
    }

    /// "Billion laughs": nine levels of ten aliases each, 400 bytes that the loader would
    /// expand to a billion nodes (gigabytes, for many seconds) — refused from the parser's
    /// events, before anything is built; a file whose aliases stay small still imports.
    #[test]
    fn aliases_that_expand_past_the_bound_are_refused_before_loading() {
        let letters = "abcdefghij";
        let mut bomb = String::from("a: &a [x, x, x, x, x, x, x, x, x, x]\n");
        for (i, name) in letters.chars().enumerate().skip(1) {
            let previous = &letters[i - 1..i];
            let items = vec![format!("*{previous}"); 10].join(", ");
            bomb.push_str(&format!("{name}: &{name} [{items}]\n"));
        }
        bomb.push_str("cam0: *j\n");
        assert!(bomb.len() < 500);
        let started = std::time::Instant::now();
        for format in [CalibrationFormat::Kalibr, CalibrationFormat::OpenCvYaml] {
            let e = import(format, &[&bomb]).unwrap_err();
            assert_eq!(e.field, "file");
            assert!(e.message.contains("alias"), "{}", e.message);
        }
        let e = import(CalibrationFormat::Ros, &[&bomb, ROS_RIGHT, ROS_THIRD]).unwrap_err();
        assert!(e.message.contains("alias"), "{}", e.message);
        // A bound on the work, not a speed measurement: the loader would take minutes.
        assert!(started.elapsed() < std::time::Duration::from_secs(10));
        // Level k (a = 1) is a list of ten of level k - 1: (10^(k+1) - 1) / 9 nodes. The
        // document: its mapping, eleven keys, the ten levels and cam0's copy of the last.
        let level = |k: u32| (10u64.pow(k + 1) - 1) / 9;
        let expected = 1 + 11 + (1..=10).map(level).sum::<u64>() + level(10);
        assert_eq!(expanded_nodes(&bomb).unwrap(), expected);
        assert!(expected > 10_000_000_000);

        // The same chain with its distortion written once and named twice.
        let shared = KALIBR
            .replacen(
                "distortion_coeffs: [-0.294719, 0.08601, -0.0003228, -0.0000501]",
                "distortion_coeffs: &d [-0.294719, 0.08601, -0.0003228, -0.0000501]",
                1,
            )
            .replacen(
                "distortion_coeffs: [-0.28, 0.079, 0.0001, -0.0002]",
                "distortion_coeffs: *d",
                1,
            );
        let calibration = import(CalibrationFormat::Kalibr, &[&shared]).unwrap();
        assert_eq!(
            calibration.cameras[2].distortion,
            calibration.cameras[0].distortion
        );
        assert_eq!(
            expanded_nodes(KALIBR).unwrap(),
            expanded_nodes(&shared).unwrap()
        );
    }
}
