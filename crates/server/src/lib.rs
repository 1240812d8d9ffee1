//! Trinocular as a service: the use cases on a compute pool, the session stores and the
//! configuration, with the gRPC and HTTP transports on top.
//!
//! ```text
//! serve ─▶ server ─▶ grpc, grpc_body, http, http_server, metered_body, observe, tls, ui
//!    │                          │                                          (transports)
//!    │                          ▼
//!    └──── config ─────▶ service: Match, sessions, Calibrate, pool,  (use cases)
//!                        stores, errors, metrics, auth
//!                               │
//!                               ▼
//!            trinocular-schema (messages, conversions) ─▶ trinocular-core (vision)
//! ```
//!
//! Arrows point one way: `service` imports none of the transports, so a use case cannot come
//! to depend on how it is reached, and the schema and the core know nothing of this crate
//! (their crate boundaries enforce it). docs/ARCHITECTURE.md draws the whole workspace.

pub mod config;
pub mod grpc;
pub mod grpc_body;
pub mod http;
pub mod http_server;
pub mod metered_body;
pub mod observe;
pub mod serve;
pub mod server;
pub mod service;
pub mod tls;
pub mod ui;
