//! What the unit tests take from `trinocular-synth`, brought across as this crate's types.
//!
//! `trinocular-synth` is built on this crate, so as a dev-dependency it links a second copy of
//! it: the `Rig` it builds is not [`crate::geometry::Rig`] in a unit test. Its seeded `Rng`
//! crosses as it is (it hands out plain numbers); a rig crosses as numbers, each camera's
//! `K`, `R`, `t` and distortion, rebuilt by the constructor that made it, so it is the same
//! rig to the bit. Tests that need whole scenes are integration tests (`tests/synthetic/`),
//! which link the same copy as the synth crate.

use crate::geometry::{Camera, Distortion, Rig};
use trinocular_synth::{Pose, RigSpec};

/// The synth crate's non-collinear preset rig of seed 1 (like the rendered office data), in
/// its own frame: the rig most unit tests of matching and the pipeline run on.
pub(crate) fn preset_rig() -> Rig {
    let theirs = RigSpec::non_collinear(1)
        .build(&Pose::identity())
        .expect("preset rig");
    let cameras = std::array::from_fn(|i| {
        let c = theirs.camera(i);
        let distortion = c.distortion().map(|d| Distortion {
            k1: d.k1,
            k2: d.k2,
            p1: d.p1,
            p2: d.p2,
            k3: d.k3,
        });
        Camera::from_krt(
            c.name(),
            c.width(),
            c.height(),
            *c.intrinsics(),
            *c.rotation(),
            *c.translation(),
            distortion,
        )
        .expect("a valid camera rebuilt from its own numbers")
    });
    Rig::new(cameras).expect("a valid rig rebuilt from its own cameras")
}
