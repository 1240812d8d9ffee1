pub mod api;
pub mod geometry;
pub mod matching;
pub mod pipeline;
pub mod reconstruct;
pub mod segment;
pub mod synth;
