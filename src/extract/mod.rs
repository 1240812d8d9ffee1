//! Segments from images (DESIGN §2.1, the paper's preprocessing): edge points, chains of
//! connected edge points, and their polygonal approximation into line segments oriented by
//! contrast, with the graph of segments that share a chain vertex or a junction.
//!
//! ```text
//! GreyImage ─▶ gradient ─▶ nms (sub-pixel) ─▶ hysteresis ─▶ chain ─▶ undistort ─▶ polygon ─▶ segments + graph
//! ```
//!
//! Each stage is a plain function over plain data and can be tested alone. Pure and
//! synchronous: one image per call (the pipeline runs the three images in parallel).

pub mod decode;
pub mod image;

pub use decode::{check_size, decode, from_raw, DecodeError, DecodeLimits};
pub use image::GreyImage;
