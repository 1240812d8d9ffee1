//! Trinocular as a library, a CLI and a service: the `trinocular` binary and its demo, over
//! the workspace's crates, re-exported here so that code written against the single crate
//! keeps its paths.
//!
//! ```text
//! trinocular (CLI, demo) ─▶ trinocular-server (use cases, transports)
//!                                 ─▶ trinocular-schema (messages, conversions)
//!                                       ─▶ trinocular-core (vision)
//!                        ─▶ trinocular-synth (synthetic rooms, scorer) ─▶ trinocular-core
//! ```
//!
//! `trinocular::pipeline` and the core's other modules are [`trinocular_core`]'s;
//! `trinocular::synth` is [`trinocular_synth`];
//! `trinocular::api` is [`trinocular_schema`] with the server's transports and the running of
//! a checked request; `trinocular::service` is the server's use cases with its servers and
//! configuration. The layering itself is the crates' (docs/ARCHITECTURE.md), not these
//! re-exports'.

pub use trinocular_core::{
    angle, calibrate, checkpoint, extract, geometry, map, matching, overlay, pipeline, plot,
    reconstruct, segment,
};
/// The synthetic rooms and the scorer ([`trinocular_synth`]), for the demo, tests, benches,
/// examples and fuzz seeds.
pub use trinocular_synth as synth;

/// The schema and its conversions ([`trinocular_schema`]), the transports, and the running of
/// a checked request (its traits, [`RunMatch`] and [`RunCalibration`], must be in scope for
/// `input.run()`).
pub mod api {
    pub use trinocular_schema::*;
    pub use trinocular_server::service::calibration::RunCalibration;
    pub use trinocular_server::service::matching::{Executed, RunError, RunMatch};
    pub use trinocular_server::{grpc, grpc_body, http};
}

/// The use cases, pool, stores and errors ([`trinocular_server::service`]), with the servers,
/// request ids, TLS and configuration.
pub mod service {
    pub use trinocular_server::service::*;
    pub use trinocular_server::{config, http_server, observe, serve, server, tls};
}

pub mod demo;
