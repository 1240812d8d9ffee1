//! Trinocular's vision core: passive trinocular stereovision with line segments (N. Ayache
//! and F. Lustman, INRIA 1987), as a library a robot can embed — no runtime, transport or
//! store in its dependencies.
//!
//! ```text
//! images ─▶ extract ─▶ segment lists ─▶ check + undistort ─▶ rectify ─▶ bucket ─▶ predict ─▶ validate ⇄ reconstruct ─▶ 3D segments ─▶ map
//!           extract                     pipeline             geometry   matching  matching   matching    reconstruct                    map
//! ```
//!
//! [`pipeline::run`] runs the whole chain on a [`geometry::Rig`] and three images or three
//! [`segment::SegmentList`]s ([`pipeline::Input`]), with [`pipeline::Options`]. Every stage
//! is a plain function over plain data:
//!
//! | module | what |
//! |---|---|
//! | [`extract`] | image decoding, edges, chains, polygonal approximation, oriented segments |
//! | [`segment`] | 2D segments, their line noise, 3D segments |
//! | [`geometry`] | cameras, rig, rectification (one disparity for three views), 3D lines |
//! | [`matching`] | buckets, hypothesis prediction and verification, validation |
//! | [`reconstruct`] | triplets to 3D segments, fragments merged |
//! | [`pipeline`] | the chain in one call, input checks, the accuracy gate, statistics |
//! | [`calibrate`] | projection matrices from images of a known pattern, or from correspondences |
//! | [`map`] | session captures fused into a world-frame room map, exports |
//! | [`overlay`] | pictures of the segments over the images |
//!
//! The synthetic rooms with exact ground truth, and the scorer, that test all of it are a
//! crate of their own, `trinocular-synth`, which a library user never compiles.

pub mod angle;
pub mod calibrate;
pub mod checkpoint;
pub mod extract;
pub mod geometry;
pub mod map;
pub mod matching;
pub mod overlay;
pub mod params;
pub mod pipeline;
pub mod plot;
pub mod reconstruct;
pub mod segment;
#[cfg(test)]
mod testing;
