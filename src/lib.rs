//! Trinocular as a service: the protobuf schema and its conversions (`api`), the use cases,
//! stores and transports (`service`), and the demo, over the vision core of
//! [`trinocular_core`] (re-exported here, module by module, so that `trinocular::pipeline`
//! and the rest keep their paths).
//!
//! ```text
//! service (gRPC, HTTP, sessions, stores) ─▶ api (schema, conversions) ─▶ trinocular-core (vision)
//! ```
//!
//! The core knows nothing of the service; `api` depends on it, never the reverse (the
//! crate boundary enforces it). docs/ARCHITECTURE.md draws the whole tree.

pub use trinocular_core::{
    angle, calibrate, checkpoint, extract, geometry, map, matching, overlay, pipeline, reconstruct,
    segment, synth,
};

pub mod api;
pub mod demo;
pub mod service;
