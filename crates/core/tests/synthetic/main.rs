//! The core's tests that need synthetic scenes: one integration test binary.
//!
//! The scenes come from `trinocular-synth`, which is built on this crate. A unit test would
//! see them through a second copy of the core (a dev-dependency cycle), whose types are not
//! `crate::`'s; an integration test links the same core as the synth crate, so a scene's rig,
//! lists and images are the core's own. What these tests call is the core's public API.

mod detect;
mod pipeline;
