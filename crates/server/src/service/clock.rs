//! The wall clock the session stores and the session use cases read, injected so that tests
//! can move time forward instead of sleeping through a TTL.
//!
//! Production uses [`SystemClock`] (the default everywhere: `MemoryStore::new`,
//! `EmbeddedStore::open`, `Service::new`); a test builds one [`ManualClock`], hands the same
//! `Arc` to the store and the service with their `with_clock`, and advances it. Only wall-clock
//! timestamps and idle ages go through it: durations measured for metrics and request deadlines
//! stay on `Instant` and tokio's timers. The Redis store does not take one, as Redis expires its
//! keys by its own clock.

use std::fmt::Debug;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Milliseconds since the Unix epoch, as the stores stamp `last_used` and the sessions
/// `created`.
pub trait Clock: Send + Sync + Debug {
    fn now_unix_ms(&self) -> u64;
}

/// The system's wall clock.
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    /// 0 for a clock before 1970, which cannot happen in practice and must not panic.
    fn now_unix_ms(&self) -> u64 {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64)
    }
}

/// The system clock, shared: what every store and service uses unless told otherwise.
pub fn system() -> Arc<dyn Clock> {
    Arc::new(SystemClock)
}

/// A clock that stands still until [`advance`](ManualClock::advance)d: for tests.
#[derive(Debug)]
pub struct ManualClock {
    now_unix_ms: AtomicU64,
}

impl ManualClock {
    /// A clock reading `start_unix_ms`.
    pub fn new(start_unix_ms: u64) -> ManualClock {
        ManualClock {
            now_unix_ms: AtomicU64::new(start_unix_ms),
        }
    }

    /// Moves the clock forward by `by` (whole milliseconds; saturating).
    pub fn advance(&self, by: Duration) {
        let ms = u64::try_from(by.as_millis()).unwrap_or(u64::MAX);
        // fetch_update with a closure that always returns Some cannot fail.
        let _ = self
            .now_unix_ms
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |now| {
                Some(now.saturating_add(ms))
            });
    }
}

impl Clock for ManualClock {
    fn now_unix_ms(&self) -> u64 {
        self.now_unix_ms.load(Ordering::SeqCst)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manual_clock_moves_only_when_advanced() {
        let clock = ManualClock::new(1_700_000_000_000);
        assert_eq!(clock.now_unix_ms(), 1_700_000_000_000);
        clock.advance(Duration::from_millis(1500));
        assert_eq!(clock.now_unix_ms(), 1_700_000_001_500);
        clock.advance(Duration::MAX);
        assert_eq!(clock.now_unix_ms(), u64::MAX);
    }

    #[test]
    fn the_system_clock_is_after_2020() {
        assert!(SystemClock.now_unix_ms() > 1_577_836_800_000);
    }
}
