//! Where long work asks whether its result is still wanted. A service's caller may have gone
//! or its deadline passed; every stage of matching, extraction and calibration asks between
//! its steps and inside its long loops, so that stopped work ends within milliseconds instead
//! of running on and holding a compute thread. An explicit argument rather than a global flag,
//! so each call says who may stop it; a load of one flag, so asking is cheap enough for inner
//! loops.

use thiserror::Error;

/// The answer of a [`Checkpoint`] that said stop: the stage that was not run (or not
/// finished).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
#[error("stopped in {stage}: the result is no longer wanted")]
pub struct Stopped {
    pub stage: &'static str,
}

/// Asked whether to stop (see the module doc).
#[derive(Clone, Copy)]
pub struct Checkpoint<'a>(Option<&'a (dyn Fn() -> bool + Sync)>);

impl<'a> Checkpoint<'a> {
    /// Never stops.
    pub const NEVER: Checkpoint<'static> = Checkpoint(None);

    /// Stops once `stop` returns true.
    pub fn new(stop: &'a (dyn Fn() -> bool + Sync)) -> Checkpoint<'a> {
        Checkpoint(Some(stop))
    }

    /// Whether the result is no longer wanted.
    #[inline]
    pub fn stopped(&self) -> bool {
        self.0.is_some_and(|stop| stop())
    }

    /// `Err(Stopped)` in or before `stage` when the result is no longer wanted.
    #[inline]
    pub fn before(&self, stage: &'static str) -> Result<(), Stopped> {
        if self.stopped() {
            Err(Stopped { stage })
        } else {
            Ok(())
        }
    }
}

/// The result of work asked of [`Checkpoint::NEVER`], which cannot have stopped: how each
/// `*_until` function's plain form unwraps it.
pub fn never_stopped<T>(result: Result<T, Stopped>) -> T {
    match result {
        Ok(value) => value,
        Err(_) => unreachable!("a checkpoint that never stops stopped"),
    }
}

impl std::fmt::Debug for Checkpoint<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Checkpoint(..)"
        } else {
            "Checkpoint::NEVER"
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};

    #[test]
    fn a_checkpoint_stops_once_asked_to() {
        assert_eq!(Checkpoint::NEVER.before("predict"), Ok(()));
        let flag = AtomicBool::new(false);
        let stop = || flag.load(Ordering::Relaxed);
        let checkpoint = Checkpoint::new(&stop);
        assert!(!checkpoint.stopped());
        flag.store(true, Ordering::Relaxed);
        assert_eq!(
            checkpoint.before("predict"),
            Err(Stopped { stage: "predict" })
        );
    }
}
