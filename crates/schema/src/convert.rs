//! Schema ⇄ domain conversions, with exhaustive destructuring so that a field added to the
//! schema cannot be silently ignored here.

use nalgebra::{Matrix3, Matrix3x4, Point2, Vector3};

use super::{pb, InputError};
use trinocular_core::extract::decode::{self, DecodeError, DecodeLimits};
use trinocular_core::extract::{self, Extraction, GreyImage};
use trinocular_core::geometry::{Camera, CameraError, Distortion, Rig, RigError};
use trinocular_core::matching::MatchParams;
use trinocular_core::pipeline::{MatchError, MatchOutput};
use trinocular_core::segment::{LineNoise, Segment2, SegmentList};

fn exactly<const N: usize>(field: String, values: &[f64]) -> Result<[f64; N], InputError> {
    <[f64; N]>::try_from(values).map_err(|_| {
        InputError::new(
            field,
            format!("needs exactly {N} numbers, got {}", values.len()),
        )
    })
}

/// How closely a projection given with K, R, t must agree with K [R | t], relative.
const PROJECTION_AGREEMENT: f64 = 1e-6;

/// The largest difference between two projection matrices, each scaled to unit Frobenius
/// norm (a projection matrix is defined up to a positive scale: a negative one would put the
/// scene behind the camera).
fn projection_difference(a: &Matrix3x4<f64>, b: &Matrix3x4<f64>) -> f64 {
    let (na, nb) = (a.norm(), b.norm());
    if !(na > 0.0 && nb > 0.0) {
        return f64::INFINITY;
    }
    (a / na - b / nb).abs().max()
}

/// Longest camera name, characters: it is stored with every session and echoed in answers.
pub const MAX_CAMERA_NAME_CHARS: usize = 64;
/// Largest radial (k1, k2, k3) and tangential (p1, p2) distortion coefficients accepted: real
/// lenses, fisheyes included, stay well within them in normalised coordinates, and beyond
/// them undistortion has no meaningful solution.
const MAX_RADIAL: f64 = 100.0;
const MAX_TANGENTIAL: f64 = 1.0;
/// Largest camera translation accepted, metres: far beyond any rig, far below where squaring
/// it overflows.
const MAX_TRANSLATION_M: f64 = 1e6;

/// Refuses a name (`field`) holding a control character: names are written into exported
/// calibration files and logs, a line each.
pub(crate) fn one_line(field: &str, name: &str) -> Result<(), InputError> {
    match name.chars().find(|c| c.is_control()) {
        Some(c) => Err(InputError::new(
            field,
            format!(
                "holds the control character U+{:04X}; a name is one line of text",
                c as u32
            ),
        )),
        None => Ok(()),
    }
}

/// A camera's name, distortion and translation within bounds (see the constants above).
fn check_camera_fields(i: usize, cam: &pb::Camera) -> Result<(), InputError> {
    let at = |field: &str| format!("calibration.cameras[{i}].{field}");
    let chars = cam.name.chars().count();
    if chars > MAX_CAMERA_NAME_CHARS {
        return Err(InputError::new(
            at("name"),
            format!("{chars} characters; at most {MAX_CAMERA_NAME_CHARS}"),
        ));
    }
    one_line(&at("name"), &cam.name)?;
    if let Some(d) = &cam.distortion {
        for (field, value, max) in [
            ("k1", d.k1, MAX_RADIAL),
            ("k2", d.k2, MAX_RADIAL),
            ("k3", d.k3, MAX_RADIAL),
            ("p1", d.p1, MAX_TANGENTIAL),
            ("p2", d.p2, MAX_TANGENTIAL),
        ] {
            if !(value.is_finite() && value.abs() <= max) {
                return Err(InputError::new(
                    at(&format!("distortion.{field}")),
                    format!("must be a finite number from -{max} to {max}, got {value}"),
                ));
            }
        }
    }
    if let Some(t) = cam
        .translation
        .iter()
        .find(|t| t.is_finite() && t.abs() > MAX_TRANSLATION_M)
    {
        return Err(InputError::new(
            at("translation"),
            format!("{t} m is beyond the {MAX_TRANSLATION_M} m accepted"),
        ));
    }
    Ok(())
}

/// P scaled so that its largest entry is 1: the same camera (P is defined up to scale), and
/// no overflow in what is computed from it (P × 1e300 gave "fx = NaN").
fn unit_scaled(p: Matrix3x4<f64>) -> Matrix3x4<f64> {
    let largest = p.amax();
    if largest.is_finite() && largest > 0.0 {
        p / largest
    } else {
        p
    }
}

fn camera_from_pb(i: usize, cam: &pb::Camera) -> Result<Camera, InputError> {
    check_camera_fields(i, cam)?;
    let pb::Camera {
        name,
        width,
        height,
        projection,
        intrinsics,
        rotation,
        translation,
        distortion,
    } = cam;
    let at = |field: &str| format!("calibration.cameras[{i}].{field}");
    let name = if name.is_empty() {
        format!("cam{}", i + 1)
    } else {
        name.clone()
    };
    let distortion = distortion.as_ref().map(|d| {
        let pb::Distortion { k1, k2, p1, p2, k3 } = *d;
        Distortion { k1, k2, p1, p2, k3 }
    });
    let pinhole_given = !(intrinsics.is_empty() && rotation.is_empty() && translation.is_empty());
    let camera = match (projection.is_empty(), pinhole_given) {
        // Both, as `Calibrate` answers: K, R, t make the camera, and P must agree with them.
        (false, true) => {
            let p = exactly::<12>(at("projection"), projection)?;
            let k = exactly::<9>(at("intrinsics"), intrinsics)?;
            let r = exactly::<9>(at("rotation"), rotation)?;
            let t = exactly::<3>(at("translation"), translation)?;
            let camera = Camera::from_krt(
                name,
                *width,
                *height,
                Matrix3::from_row_slice(&k),
                Matrix3::from_row_slice(&r),
                Vector3::from_row_slice(&t),
                distortion,
            )
            .map_err(|e: CameraError| InputError::new(at(e.field()), e.to_string()))?;
            let difference =
                projection_difference(&unit_scaled(Matrix3x4::from_row_slice(&p)), camera.projection());
            if difference.is_nan() || difference > PROJECTION_AGREEMENT {
                return Err(InputError::new(
                    at("projection"),
                    format!(
                        "disagrees with intrinsics, rotation and translation (relative difference \
                         {difference:.2e} after scaling): give one model, or both consistent"
                    ),
                ));
            }
            Ok(camera)
        }
        (true, false) => {
            return Err(InputError::new(
                at("projection"),
                "missing: give projection (12 numbers) or intrinsics (9) + rotation (9) + translation (3)",
            ))
        }
        (false, false) => {
            let p = exactly::<12>(at("projection"), projection)?;
            Camera::from_projection(
                name,
                *width,
                *height,
                unit_scaled(Matrix3x4::from_row_slice(&p)),
                distortion,
            )
        }
        (true, true) => {
            let k = exactly::<9>(at("intrinsics"), intrinsics)?;
            let r = exactly::<9>(at("rotation"), rotation)?;
            let t = exactly::<3>(at("translation"), translation)?;
            Camera::from_krt(
                name,
                *width,
                *height,
                Matrix3::from_row_slice(&k),
                Matrix3::from_row_slice(&r),
                Vector3::from_row_slice(&t),
                distortion,
            )
        }
    };
    camera.map_err(|e: CameraError| InputError::new(at(e.field()), e.to_string()))
}

/// The rig of a `Calibration`: exactly three valid cameras with distinct optical centres.
pub fn rig_from_calibration(calibration: Option<&pb::Calibration>) -> Result<Rig, InputError> {
    let calibration = calibration
        .ok_or_else(|| InputError::new("calibration", "missing: three cameras are needed"))?;
    let pb::Calibration { cameras } = calibration;
    if cameras.len() != 3 {
        return Err(InputError::new(
            "calibration.cameras",
            format!("needs exactly 3 cameras, got {}", cameras.len()),
        ));
    }
    let built = [
        camera_from_pb(0, &cameras[0])?,
        camera_from_pb(1, &cameras[1])?,
        camera_from_pb(2, &cameras[2])?,
    ];
    Rig::new(built).map_err(|e| match e {
        RigError::CoincidentCentres { second, .. } => {
            InputError::new(format!("calibration.cameras[{second}]"), e.to_string())
        }
    })
}

/// The `Calibration` of a rig, as projection matrices (what a user replays through the CLI or
/// the service).
pub fn calibration_to_pb(rig: &Rig) -> pb::Calibration {
    pb::Calibration {
        cameras: rig
            .cameras()
            .iter()
            .map(|c| camera_to_pb(c, false))
            .collect(),
    }
}

/// A `Camera` message: its projection and distortion, and with `krt` also K, R and t (as
/// `Calibrate` answers: both models, consistent, which every call accepts).
pub fn camera_to_pb(c: &Camera, krt: bool) -> pb::Camera {
    let rows = |m: &[f64], n: usize| -> Vec<f64> { m.iter().take(n).copied().collect() };
    let p = c.projection();
    let (k, r, t) = (c.intrinsics(), c.rotation(), c.translation());
    let row_major3 = |m: &Matrix3<f64>| (0..9).map(|i| m[(i / 3, i % 3)]).collect::<Vec<f64>>();
    pb::Camera {
        name: c.name().to_string(),
        width: c.width(),
        height: c.height(),
        projection: (0..12).map(|i| p[(i / 4, i % 4)]).collect(),
        intrinsics: if krt { row_major3(k) } else { Vec::new() },
        rotation: if krt { row_major3(r) } else { Vec::new() },
        translation: if krt {
            rows(t.as_slice(), 3)
        } else {
            Vec::new()
        },
        distortion: c.distortion().map(|d| pb::Distortion {
            k1: d.k1,
            k2: d.k2,
            p1: d.p1,
            p2: d.p2,
            k3: d.k3,
        }),
    }
}

/// Matching parameters: each absent option takes its default.
pub fn match_params(options: Option<&pb::MatchOptions>) -> MatchParams {
    let d = MatchParams::default();
    let Some(o) = options else {
        return d;
    };
    let pb::MatchOptions {
        depth_min_m,
        depth_max_m,
        tolerance_px,
        angle_tolerance_deg,
        verify_angle_tolerance_deg,
        min_length_px,
        gradient_ratio_max,
        depth_blind_gradient_ratio_max,
        min_gradient,
        min_gradient_to_background,
        validate,
        neighbour_radius_px,
        max_residual_px,
        line_noise_px,
        list_push_px,
        list_shift_px,
        max_direction_sigma_deg,
        vertex_reach_px,
        dominant_directions,
        gate_direction_deg,
        gate_position_m,
        gate_position_rel,
        gate_confidence,
        include_uncertain,
        // Read by `extract_params` and `match_request`.
        extract: _,
        return_extracted: _,
    } = o;
    MatchParams {
        depth_min_m: depth_min_m.unwrap_or(d.depth_min_m),
        depth_max_m: depth_max_m.unwrap_or(d.depth_max_m),
        tolerance_px: tolerance_px.unwrap_or(d.tolerance_px),
        angle_tolerance_deg: angle_tolerance_deg.unwrap_or(d.angle_tolerance_deg),
        verify_angle_tolerance_deg: verify_angle_tolerance_deg
            .unwrap_or(d.verify_angle_tolerance_deg),
        min_length_px: min_length_px.unwrap_or(d.min_length_px),
        gradient_ratio_max: gradient_ratio_max.unwrap_or(d.gradient_ratio_max),
        depth_blind_gradient_ratio_max: depth_blind_gradient_ratio_max
            .unwrap_or(d.depth_blind_gradient_ratio_max),
        min_gradient: min_gradient.unwrap_or(d.min_gradient),
        min_gradient_to_background: min_gradient_to_background
            .unwrap_or(d.min_gradient_to_background),
        validate: validate.unwrap_or(d.validate),
        neighbour_radius_px: neighbour_radius_px.unwrap_or(d.neighbour_radius_px),
        max_residual_px: max_residual_px.unwrap_or(d.max_residual_px),
        line_noise_px: line_noise_px.unwrap_or(d.line_noise_px),
        list_push_px: list_push_px.unwrap_or(d.list_push_px),
        list_shift_px: list_shift_px.unwrap_or(d.list_shift_px),
        max_direction_sigma_deg: max_direction_sigma_deg.unwrap_or(d.max_direction_sigma_deg),
        vertex_reach_px: vertex_reach_px.unwrap_or(d.vertex_reach_px),
        dominant_directions: dominant_directions.unwrap_or(d.dominant_directions),
        gate_direction_deg: gate_direction_deg.unwrap_or(d.gate_direction_deg),
        gate_position_m: gate_position_m.unwrap_or(d.gate_position_m),
        gate_position_rel: gate_position_rel.unwrap_or(d.gate_position_rel),
        gate_confidence: gate_confidence.unwrap_or(d.gate_confidence),
        include_uncertain: include_uncertain.unwrap_or(d.include_uncertain),
    }
}

/// Extraction parameters: each absent option takes its default.
pub fn extract_params(options: Option<&pb::ExtractOptions>) -> extract::Params {
    let d = extract::Params::default();
    let Some(o) = options else {
        return d;
    };
    let pb::ExtractOptions {
        smoothing_sigma_px,
        gradient_low,
        gradient_high,
        max_deviation_px,
        min_segment_px,
    } = o;
    extract::Params {
        smoothing_sigma_px: smoothing_sigma_px.or(d.smoothing_sigma_px),
        gradient_low: gradient_low.unwrap_or(d.gradient_low),
        gradient_high: gradient_high.unwrap_or(d.gradient_high),
        max_deviation_px: max_deviation_px.unwrap_or(d.max_deviation_px),
        min_segment_px: min_segment_px.unwrap_or(d.min_segment_px),
    }
}

/// The three images of an `ImageTriplet`, decoded within `limits`.
pub fn images(
    triplet: &pb::ImageTriplet,
    limits: &DecodeLimits,
) -> Result<[GreyImage; 3], InputError> {
    images_sized(triplet, limits, None)
}

/// [`images`], each refused from its header unless it has its camera's size (`sizes`, width
/// and height per camera): a wrong image costs no decoding.
pub fn images_sized(
    triplet: &pb::ImageTriplet,
    limits: &DecodeLimits,
    sizes: Option<[(u32, u32); 3]>,
) -> Result<[GreyImage; 3], InputError> {
    let pb::ImageTriplet { images } = triplet;
    if images.len() != 3 {
        return Err(InputError::new(
            "images.images",
            format!("needs exactly 3 images, got {}", images.len()),
        ));
    }
    let one = |i: usize| -> Result<GreyImage, InputError> {
        let pb::Image { source } = &images[i];
        match source {
            Some(pb::image::Source::Encoded(bytes)) => {
                decode::decode_sized(bytes, limits, sizes.map(|s| s[i])).map_err(|e| {
                    InputError::new(format!("images.images[{i}].encoded"), e.to_string())
                })
            }
            Some(pb::image::Source::Raw(raw)) => {
                let pb::RawImage {
                    width,
                    height,
                    data,
                } = raw;
                let raw_error = |e: DecodeError| {
                    InputError::new(format!("images.images[{i}].raw"), e.to_string())
                };
                if let Some((expected_width, expected_height)) = sizes.map(|s| s[i]) {
                    if (*width, *height) != (expected_width, expected_height) {
                        return Err(raw_error(DecodeError::SizeMismatch {
                            width: *width,
                            height: *height,
                            expected_width,
                            expected_height,
                        }));
                    }
                }
                decode::from_raw(*width, *height, data, limits).map_err(raw_error)
            }
            None => Err(InputError::new(
                format!("images.images[{i}]"),
                "missing: give encoded bytes or a raw image",
            )),
        }
    };
    Ok([one(0)?, one(1)?, one(2)?])
}

/// How much one request may ask of the service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RequestLimits {
    /// Bytes and pixels of each image.
    pub decode: DecodeLimits,
    /// Segments in each list.
    pub max_segments_per_list: usize,
}

/// What a Match request brings, counted without decoding anything: pixels from the images'
/// headers (a raw image: its bytes), segments from the lists' lengths. The service estimates
/// a job's working memory from these before it runs. An image that decoding will refuse
/// from its header anyway (not its camera's size, or over the pixel limit) counts nothing,
/// so that its answer names it rather than the memory it would have needed.
pub fn request_size(request: &pb::MatchRequest, limits: &DecodeLimits) -> (u64, u64) {
    match &request.input {
        Some(pb::match_request::Input::Images(triplet)) => {
            let cameras = request.calibration.as_ref().map(|c| c.cameras.as_slice());
            let size_of = |i: usize| cameras.and_then(|c| c.get(i)).map(|c| (c.width, c.height));
            (triplet_pixels(triplet, limits, size_of), 0)
        }
        Some(pb::match_request::Input::Segments(pb::SegmentTriplet { lists })) => {
            (0, lists.iter().map(|l| l.segments.len() as u64).sum())
        }
        None => (0, 0),
    }
}

/// The pixels of a triplet's images (at most its first three) that will be decoded, from
/// their headers: an image over the pixel limit, or not of the size `expected(i)` gives,
/// counts nothing.
pub fn triplet_pixels(
    triplet: &pb::ImageTriplet,
    limits: &DecodeLimits,
    expected: impl Fn(usize) -> Option<(u32, u32)>,
) -> u64 {
    triplet
        .images
        .iter()
        .take(3)
        .enumerate()
        .map(|(i, image)| {
            let size = match &image.source {
                Some(pb::image::Source::Encoded(bytes)) => decode::dimensions(bytes, limits),
                Some(pb::image::Source::Raw(raw)) => Some((raw.width, raw.height)),
                None => None,
            };
            match size {
                Some((w, h)) if expected(i).is_none_or(|e| e == (w, h)) => {
                    let pixels = u64::from(w) * u64::from(h);
                    let raw_bytes = match &image.source {
                        Some(pb::image::Source::Raw(raw)) => raw.data.len() as u64,
                        _ => pixels,
                    };
                    if pixels <= limits.max_pixels && raw_bytes == pixels {
                        pixels
                    } else {
                        0
                    }
                }
                _ => 0,
            }
        })
        .sum()
}

/// Segments per list accepted by default: ten times the densest real scene we have seen.
pub const MAX_SEGMENTS_PER_LIST: usize = 100_000;

impl Default for RequestLimits {
    fn default() -> Self {
        RequestLimits {
            decode: DecodeLimits::default(),
            max_segments_per_list: MAX_SEGMENTS_PER_LIST,
        }
    }
}

/// The three segment lists of a `SegmentTriplet`, each within `max_segments`.
pub fn segment_lists(
    triplet: &pb::SegmentTriplet,
    max_segments: usize,
) -> Result<[SegmentList; 3], InputError> {
    let pb::SegmentTriplet { lists } = triplet;
    if lists.len() != 3 {
        return Err(InputError::new(
            "segments.lists",
            format!("needs exactly 3 segment lists, got {}", lists.len()),
        ));
    }
    if let Some((i, list)) = lists
        .iter()
        .enumerate()
        .find(|(_, l)| l.segments.len() > max_segments)
    {
        return Err(InputError::new(
            format!("segments.lists[{i}].segments"),
            format!(
                "{} segments, more than the limit of {max_segments} per list \
                 (limits.max_segments_per_list)",
                list.segments.len()
            ),
        ));
    }
    for (i, list) in lists.iter().enumerate() {
        if let Some(g) = list.background_gradient {
            if !(g.is_finite() && g >= 0.0) {
                return Err(InputError::new(
                    format!("segments.lists[{i}].background_gradient"),
                    format!("must be a finite number at least 0, got {g}"),
                ));
            }
        }
    }
    // A segment's noise is two numbers or none: one alone would be silently ignored.
    for (i, list) in lists.iter().enumerate() {
        for (j, s) in list.segments.iter().enumerate() {
            let missing = match (s.offset_sigma_px, s.angle_sigma_deg) {
                (Some(_), None) => Some(("angle_sigma_deg", "offset_sigma_px")),
                (None, Some(_)) => Some(("offset_sigma_px", "angle_sigma_deg")),
                _ => None,
            };
            if let Some((absent, given)) = missing {
                return Err(InputError::new(
                    format!("segments.lists[{i}].segments[{j}].{absent}"),
                    format!("missing: {given} is given, and the two go together"),
                ));
            }
            // A shift is part of a stated noise: alone it would be silently ignored.
            if s.shift_sigma_px.is_some() && s.offset_sigma_px.is_none() {
                return Err(InputError::new(
                    format!("segments.lists[{i}].segments[{j}].offset_sigma_px"),
                    "missing: shift_sigma_px is given, and it goes with offset_sigma_px and \
                     angle_sigma_deg",
                ));
            }
        }
    }
    Ok(std::array::from_fn(|i| {
        let pb::SegmentList {
            segments,
            oriented,
            background_gradient,
        } = &lists[i];
        SegmentList {
            oriented: *oriented,
            background_gradient: *background_gradient,
            segments: segments
                .iter()
                .map(|s| {
                    let pb::Segment {
                        u1,
                        v1,
                        u2,
                        v2,
                        gradient,
                        offset_sigma_px,
                        angle_sigma_deg,
                        shift_sigma_px,
                    } = *s;
                    Segment2 {
                        start: Point2::new(u1, v1),
                        end: Point2::new(u2, v2),
                        gradient,
                        noise: match (offset_sigma_px, angle_sigma_deg) {
                            (Some(offset_px), Some(angle)) => Some(LineNoise {
                                offset_px,
                                angle_rad: angle.to_radians(),
                                shift_px: shift_sigma_px.unwrap_or(0.0),
                            }),
                            _ => None,
                        },
                    }
                })
                .collect(),
        }
    }))
}

/// What a request matches: three segment lists, or three images to extract them from.
#[derive(Debug, Clone)]
pub enum MatchSource {
    Segments([SegmentList; 3]),
    Images([GreyImage; 3]),
}

/// A checked `MatchRequest`, ready for the pipeline.
#[derive(Debug, Clone)]
pub struct MatchInput {
    pub rig: Rig,
    pub params: MatchParams,
    pub extract: extract::Params,
    pub return_extracted: bool,
    pub source: MatchSource,
}

/// Converts a `MatchRequest`, checking what the schema cannot express, within `limits`.
pub fn match_request(
    request: &pb::MatchRequest,
    limits: &RequestLimits,
) -> Result<MatchInput, InputError> {
    let pb::MatchRequest {
        calibration,
        options,
        input,
    } = request;
    let rig = rig_from_calibration(calibration.as_ref())?;
    let params = match_params(options.as_ref());
    params
        .check()
        .map_err(|e| InputError::new(format!("options.{}", e.field()), e.to_string()))?;
    let extract = extract_params(options.as_ref().and_then(|o| o.extract.as_ref()));
    extract
        .check()
        .map_err(|e| InputError::new(format!("options.extract.{}", e.field()), e.to_string()))?;
    let return_extracted = options
        .as_ref()
        .and_then(|o| o.return_extracted)
        .unwrap_or(false);
    let source = match input {
        Some(pb::match_request::Input::Segments(triplet)) => {
            MatchSource::Segments(segment_lists(triplet, limits.max_segments_per_list)?)
        }
        Some(pb::match_request::Input::Images(triplet)) => {
            let sizes = std::array::from_fn(|v| {
                let camera = rig.camera(v);
                (camera.width(), camera.height())
            });
            MatchSource::Images(images_sized(triplet, &limits.decode, Some(sizes))?)
        }
        None => return Err(InputError::new("input", "missing: give segments or images")),
    };
    Ok(MatchInput {
        rig,
        params,
        extract,
        return_extracted,
        source,
    })
}

/// A `SegmentList` message.
pub fn segment_list_to_pb(list: &SegmentList) -> pb::SegmentList {
    pb::SegmentList {
        oriented: list.oriented,
        background_gradient: list.background_gradient,
        segments: list
            .segments
            .iter()
            .map(|s| pb::Segment {
                u1: s.start.x,
                v1: s.start.y,
                u2: s.end.x,
                v2: s.end.y,
                gradient: s.gradient,
                offset_sigma_px: s.noise.map(|n| n.offset_px),
                angle_sigma_deg: s.noise.map(|n| n.angle_rad.to_degrees()),
                shift_sigma_px: s.noise.map(|n| n.shift_px).filter(|&shift| shift > 0.0),
            })
            .collect(),
    }
}

/// A pipeline error as the request's fault, naming the field at fault; or, when the
/// pipeline's checkpoint stopped it (nobody wants the answer any more), the stage it stopped
/// before.
pub fn match_error(e: MatchError) -> Result<InputError, &'static str> {
    let field = match &e {
        MatchError::Stopped { stage } => return Err(stage),
        MatchError::Params(p) => format!("options.{}", p.field()),
        MatchError::Rectify(_) => "calibration".to_string(),
        MatchError::NonFiniteCoordinate {
            list,
            index,
            coordinate,
        }
        | MatchError::OutOfImage {
            list,
            index,
            coordinate,
            ..
        } => format!(
            "segments.lists[{list}].segments[{index}].{}",
            coordinate.name()
        ),
        MatchError::NegativeGradient { list, index, .. } => {
            format!("segments.lists[{list}].segments[{index}].gradient")
        }
        MatchError::NonPositiveSigma { list, index, field } => {
            format!("segments.lists[{list}].segments[{index}].{field}")
        }
        MatchError::ShiftOutOfRange { list, index, .. } => {
            format!("segments.lists[{list}].segments[{index}].shift_sigma_px")
        }
        MatchError::Extract(p) => format!("options.extract.{}", p.field()),
        MatchError::ImageSize { view, .. } => format!("images.images[{view}]"),
        MatchError::TooManyHypotheses { .. } => "segments".to_string(),
    };
    Ok(InputError {
        field,
        message: e.to_string(),
    })
}

fn point3(p: &nalgebra::Point3<f64>) -> pb::Point3 {
    pb::Point3 {
        x: p.x,
        y: p.y,
        z: p.z,
    }
}

/// The 3D segments of a `MatchResponse` (absent endpoints read as the origin), for exports.
pub fn segments_3d_of(response: &pb::MatchResponse) -> Vec<trinocular_core::segment::Segment3> {
    let point = |p: &Option<pb::Point3>| {
        p.as_ref().map_or(nalgebra::Point3::origin(), |p| {
            nalgebra::Point3::new(p.x, p.y, p.z)
        })
    };
    response
        .segments_3d
        .iter()
        .map(|s| trinocular_core::segment::Segment3 {
            start: point(&s.start),
            end: point(&s.end),
        })
        .collect()
}

/// The `MatchResponse` of a pipeline output, with the extracted lists if given.
pub fn match_response(
    output: &MatchOutput,
    extracted: Option<&[Extraction; 3]>,
) -> pb::MatchResponse {
    let s = &output.stats;
    pb::MatchResponse {
        triplets: output
            .triplets
            .iter()
            .map(|t| pb::Triplet {
                s1: t.segments[0],
                s2: t.segments[1],
                s3: t.segments[2],
                residual_px: t.residual_px,
            })
            .collect(),
        segments_3d: output
            .segments_3d
            .iter()
            .map(|r| pb::Segment3 {
                start: Some(point3(&r.segment.start)),
                end: Some(point3(&r.segment.end)),
                triplet: r.triplet,
                triplets: r.triplets.clone(),
                residual_px: r.residual_px,
                direction_sigma_deg: r.direction_sigma_deg,
                covariance: r.covariance.transpose().as_slice().to_vec(),
                position_sigma_m: r.position_sigma_m,
                uncertain: r.uncertain,
                shift_sigma_m: r.shift_sigma_m,
                along_dominant_direction: r.aligned,
            })
            .collect(),
        stats: Some(pb::MatchStats {
            segments_in: s.segments_in.to_vec(),
            segments_used: s.segments_used.to_vec(),
            zero_length_dropped: s.zero_length_dropped.to_vec(),
            duplicates_dropped: s.duplicates_dropped.to_vec(),
            hypotheses: s.hypotheses,
            triplets: s.triplets,
            segments_3d: s.segments_3d,
            rectify_ms: s.rectify_ms,
            predict_ms: s.predict_ms,
            validate_ms: s.validate_ms,
            reconstruct_ms: s.reconstruct_ms,
            total_ms: s.total_ms,
            collinear_rig: s.collinear_rig,
            per_pair_rectification: s.per_pair_rectification,
            low_contrast_dropped: s.low_contrast_dropped.to_vec(),
            epipolar_angle_deg: s.epipolar_angle_deg,
            extract_ms: s.extract_ms.map_or_else(Vec::new, |m| m.to_vec()),
            smoothing_sigma_px: s.smoothing_sigma_px.map_or_else(Vec::new, |m| m.to_vec()),
            uncertain: s.uncertain,
            inconsistent: s.inconsistent,
            noise_scale: s.noise_scale,
            ambiguous: s.ambiguous,
            gradient_gains: s.gradient_gains.to_vec(),
            depth_blind_refused: s.depth_blind_refused,
            joined_at_vertices: s.joined_at_vertices,
            along_dominant_directions: s.along_dominant_directions,
        }),
        extracted: extracted
            .map(|e| e.iter().map(|x| segment_list_to_pb(&x.segments)).collect())
            .unwrap_or_default(),
    }
}
