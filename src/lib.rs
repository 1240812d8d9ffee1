//! Trinocular: passive trinocular stereovision with line segments (N. Ayache and
//! F. Lustman, INRIA 1987), as a library.
//!
//! ```text
//! segment lists ─▶ check + undistort ─▶ rectify ─▶ bucket ─▶ predict ─▶ validate ⇄ reconstruct ─▶ 3D segments
//!                  pipeline             geometry   matching  matching   matching    reconstruct
//! ```
//!
//! [`pipeline::match_segments`] runs the whole chain on a [`geometry::Rig`] and three
//! [`segment::SegmentList`]s. Every stage is a plain function over plain data:
//!
//! | module | what |
//! |---|---|
//! | [`geometry`] | cameras, rig, rectification (one disparity for three views), 3D lines |
//! | [`matching`] | buckets, hypothesis prediction and verification, validation |
//! | [`reconstruct`] | triplets to 3D segments, fragments merged |
//! | [`map`] | session captures fused into a world-frame room map, exports |
//! | [`calibrate`] | projection matrices from images of a known pattern, or from correspondences |
//! | [`pipeline`] | the chain in one call, input checks, statistics |
//! | [`synth`] | synthetic rooms with exact ground truth, and a scorer |
//! | [`api`] | the protobuf schema and its conversion to the types above |
//!
//! The vision core (`geometry`, `matching`, `reconstruct`, `pipeline`) knows nothing of
//! transports; `api` depends on it, never the reverse.

pub mod angle;
pub mod api;
pub mod calibrate;
pub mod checkpoint;
pub mod demo;
pub mod extract;
pub mod geometry;
pub mod map;
pub mod matching;
pub mod overlay;
pub mod pipeline;
pub mod reconstruct;
pub mod segment;
pub mod service;
pub mod synth;
