//! The clock the session stores, the use cases and the transports' observation read, injected
//! so that tests can move time forward instead of sleeping through a TTL or a duration.
//!
//! It has two readings: wall-clock milliseconds since the Unix epoch, which the stores stamp
//! `last_used` and the sessions `created` with and age sessions by, and a monotonic reading,
//! which durations are measured with (a request's latency in the metrics and its log line, a
//! map's `fuse_ms`). Production uses [`SystemClock`] (the default everywhere:
//! `MemoryStore::new`, `EmbeddedStore::open`, `Service::new`); a test builds one
//! [`ManualClock`], hands the same `Arc` to the store and the service with their
//! `with_clock`, and advances it: a TTL passes, or a request lasts exactly 250 ms, at once.
//!
//! Not on it: the deadlines. A request's deadline, a body's timeout and the watchdog's period
//! are tokio timers (`tokio::time::timeout`, `sleep`), which must wake a task when they
//! expire, something a clock read only when asked cannot do; tokio's paused test time
//! (`#[tokio::test(start_paused = true)]`, `tokio::time::advance`) moves those. Nor the
//! computations' own reports (the pipeline's stage times, a calibration's `total_ms`): they
//! are measured by the core and the `Run*` traits, the same for the CLI as for the service.
//! The Redis store does not take a clock, as Redis expires its keys by its own.

use std::fmt::Debug;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::sync::OnceLock;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Wall-clock time for timestamps, monotonic time for durations.
pub trait Clock: Send + Sync + Debug {
    /// Milliseconds since the Unix epoch, as the stores stamp `last_used` and the sessions
    /// `created`.
    fn now_unix_ms(&self) -> u64;

    /// Time since a fixed instant of this clock's (its first reading, for the system's): only
    /// the difference of two readings means anything. Never goes back, unlike the wall clock.
    fn monotonic(&self) -> Duration;

    /// Time since `start`, a [`Clock::monotonic`] reading of this clock.
    fn since(&self, start: Duration) -> Duration {
        self.monotonic().saturating_sub(start)
    }
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

    fn monotonic(&self) -> Duration {
        static ORIGIN: OnceLock<Instant> = OnceLock::new();
        ORIGIN.get_or_init(Instant::now).elapsed()
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
    /// Nanoseconds advanced since it was made: its monotonic reading.
    advanced_ns: AtomicU64,
}

impl ManualClock {
    /// A clock reading `start_unix_ms`.
    pub fn new(start_unix_ms: u64) -> ManualClock {
        ManualClock {
            now_unix_ms: AtomicU64::new(start_unix_ms),
            advanced_ns: AtomicU64::new(0),
        }
    }

    /// Moves the clock forward by `by`: its wall reading by whole milliseconds, its
    /// monotonic one to the nanosecond (both saturating).
    pub fn advance(&self, by: Duration) {
        let ms = u64::try_from(by.as_millis()).unwrap_or(u64::MAX);
        let ns = u64::try_from(by.as_nanos()).unwrap_or(u64::MAX);
        // fetch_update with a closure that always returns Some cannot fail.
        for (reading, by) in [(&self.now_unix_ms, ms), (&self.advanced_ns, ns)] {
            let _ = reading.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |now| {
                Some(now.saturating_add(by))
            });
        }
    }
}

impl Clock for ManualClock {
    fn now_unix_ms(&self) -> u64 {
        self.now_unix_ms.load(Ordering::SeqCst)
    }

    fn monotonic(&self) -> Duration {
        Duration::from_nanos(self.advanced_ns.load(Ordering::SeqCst))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manual_clock_moves_only_when_advanced() {
        let clock = ManualClock::new(1_700_000_000_000);
        assert_eq!(clock.now_unix_ms(), 1_700_000_000_000);
        let start = clock.monotonic();
        assert_eq!(clock.since(start), Duration::ZERO);
        clock.advance(Duration::from_millis(1500));
        assert_eq!(clock.now_unix_ms(), 1_700_000_001_500);
        assert_eq!(clock.since(start), Duration::from_millis(1500));
        clock.advance(Duration::from_micros(250));
        assert_eq!(clock.since(start), Duration::from_micros(1_500_250));
        clock.advance(Duration::MAX);
        assert_eq!(clock.now_unix_ms(), u64::MAX);
    }

    #[test]
    fn the_system_clock_is_after_2020_and_its_monotonic_reading_never_goes_back() {
        assert!(SystemClock.now_unix_ms() > 1_577_836_800_000);
        let start = SystemClock.monotonic();
        assert!(SystemClock.monotonic() >= start);
    }
}
