//! `trinocular demo`: the whole product on one synthetic capture, for a first look.
//!
//! Renders the standard room (`synth`) from a non-collinear rig — flat shading, varied
//! albedo, light falloff, anti-aliasing, slight blur and sensor noise — extracts the segments
//! of the three images, matches them, reconstructs the 3D segments and scores them against
//! the exact ground truth. Returns the pictures (the three images, the overlay of matched
//! segments, a top view of the 3D segments over the ground truth) and the response.

use crate::api::{self, pb};
use crate::overlay;
use crate::pipeline::{self, Input};
use crate::segment::Segment3;
use crate::synth::{
    render_triplet, rig_centre, score_capture, standard_capture, Defects, RenderParams,
};

/// Top view scale, pixels per metre: the part of the room the rig sees (about 2.5 by 3 m)
/// in about 400 by 480 pixels.
const TOP_VIEW_PX_PER_M: f64 = 160.0;

/// What the demo produced.
#[derive(Debug, Clone)]
pub struct Demo {
    pub images_png: [Vec<u8>; 3],
    pub overlay_png: Vec<u8>,
    pub top_png: Vec<u8>,
    pub response: pb::MatchResponse,
    /// The rig's `Calibration` (projection matrices), to replay the capture through the CLI
    /// or the service.
    pub calibration: pb::Calibration,
    /// A few lines for people: counts, time, accuracy against the ground truth.
    pub summary: String,
    /// Share of wrong 3D segments and of eligible edge length covered (`synth::score`).
    pub error_rate: f64,
    pub completeness: f64,
}

/// Runs the demo on the room of `seed`.
pub fn run(seed: u64) -> Result<Demo, String> {
    let (scene, rig, observation) = standard_capture(seed, Defects::clean(), false);
    let images = render_triplet(&scene, &rig, &RenderParams::default(), seed);
    let png = |i: usize| -> Result<Vec<u8>, String> {
        overlay::grey_png(&images[i]).map_err(|e| format!("cannot encode image {}: {e}", i + 1))
    };
    let result = pipeline::run(
        &rig,
        Input::Images([&images[0], &images[1], &images[2]]),
        &pipeline::Options::default(),
    )
    .map_err(|e| format!("the demo capture did not match: {e}"))?;
    let extracted = result
        .extracted
        .as_ref()
        .ok_or("the demo capture gave no extraction")?;

    let segments = result.output.segments();
    let truth = &observation.ground_truth;
    let s = score_capture(&segments, &observation, &rig);
    let lists = extracted.each_ref().map(|e| &e.segments);
    let labels = overlay::segment3_labels(&result.output, lists.map(|l| l.segments.len()));
    let picture = overlay::triplet_overlay(
        [&images[0], &images[1], &images[2]],
        lists,
        [&labels[0], &labels[1], &labels[2]],
        rig.cameras().each_ref().map(|c| c.name()),
    );
    // The ground truth seen by the rig: the parts of edges visible in all three cameras.
    let visible: Vec<Segment3> = observation
        .visible_all3
        .iter()
        .zip(truth)
        .flat_map(|(intervals, e)| {
            intervals.iter().map(move |&(a, b)| Segment3 {
                start: e.start + (e.end - e.start) * a,
                end: e.start + (e.end - e.start) * b,
            })
        })
        .collect();
    let centres: Vec<_> = rig.cameras().iter().map(|c| c.centre()).collect();
    let top = overlay::top_view(&segments, &visible, &centres, TOP_VIEW_PX_PER_M);
    let stats = &result.output.stats;
    let classes = crate::synth::error_classes(&segments, &s.matches, truth, rig_centre(&rig));
    let error_rate = s.error_rate.unwrap_or(0.0);
    let completeness = s.completeness.unwrap_or(0.0);
    let summary = format!(
        "room {seed}: {} + {} + {} segments extracted, {} triplets, {} 3D segments in {:.1} ms\n\
         against the ground truth: {:.1}% wrong, {:.1}% of the edges seen by all three cameras \
         covered (median endpoint error {:.1} mm)\n\
         wrong: {} off in direction only, {} near an edge, {} near no edge; {} more left out \
         as uncertain (the option includeUncertain returns them, flagged)",
        lists[0].segments.len(),
        lists[1].segments.len(),
        lists[2].segments.len(),
        stats.triplets,
        stats.segments_3d,
        stats.total_ms,
        100.0 * error_rate,
        100.0 * completeness,
        s.acc_median_mm.unwrap_or(f64::NAN),
        classes.direction_only,
        classes.near,
        classes.far,
        stats.uncertain,
    );
    let calibration = api::calibration_to_pb(&rig);
    Ok(Demo {
        calibration,
        images_png: [png(0)?, png(1)?, png(2)?],
        overlay_png: picture.to_png().map_err(|e| e.to_string())?,
        top_png: top.to_png().map_err(|e| e.to_string())?,
        response: api::match_response(&result.output, Some(extracted)),
        summary,
        error_rate,
        completeness,
    })
}
