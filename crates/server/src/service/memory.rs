//! The compute jobs' working memory, reserved from a budget before the work that needs it.
//!
//! Admission counts jobs, but jobs are not alike: three 3-megapixel photographs of brick
//! need a thousand times the memory of three lists of 600 segments. So each Match (and
//! Calibrate) reserves an estimate of its peak from `limits.max_working_mib` before it decodes
//! or extracts anything, and returns it when it ends. RSS is then bounded by the budget, the
//! body budget and the process's base, whatever the mix of requests and however many cores.
//!
//! The estimates come from measured peaks (worst content we could make): 3 × 2000² pixels
//! of per-pixel random noise sent over HTTP to a server with four compute threads (the three
//! images extracted at once) peaked 34 B per pixel over the base and the body, the decoded
//! request included (ordinary scenes: 9 B; one such image alone, `trinocular extract`:
//! 36 B/pixel with the decoder's own buffers, a third of them its 1.4 M edge points and
//! 300,000 chains); 3 × 100,000 random segments at 150 MB, 445 B per segment — once the matcher's
//! buckets register a segment in at most eight windows on average (before, a crowd of long
//! segments across the image registered each in 35 or more: 3 × 100,000 of them peaked at
//! 394 MiB in the service, 776 MiB for two at once; now 156 and 299 MiB). A request whose
//! estimate exceeds the whole budget can never
//! run: INVALID_ARGUMENT naming its input. One that would exceed what is free now is
//! refused like a full compute pool: RESOURCE_EXHAUSTED, retry later.
//!
//! A budget bounds the memory in use, not what the allocator keeps: glibc raises its mmap
//! threshold after each large free, so image buffers came from the heap and stayed there
//! (six 3 × 1 Mpx noise requests one after the other: RSS 83 → 130 MB). After a job that
//! reserved 32 MiB or more, the allocator's free memory is handed back (`malloc_trim`): the
//! same six leave 30–40 MB, at no measurable cost to 512² image requests. What the allocator
//! still holds while jobs run grows with the compute threads (each its own arena, and a
//! refused request decoded on each): eight 88 MB jobs in a 100 MiB budget with 32 MiB of
//! bodies peaked 10 MiB over base + bodies + budget on 2 threads, 39–59 MiB on 4. A request
//! body is held twice while it is decoded (the bytes and the message). So the bound is
//! base + 2 × `max_bodies_mib` + `max_working_mib` + 24 MiB per compute thread. Also tried: a fixed 4 MiB
//! mmap threshold (flat RSS, but 1 Mpx noise triplets lost a quarter of their throughput, and
//! the same peak), a single arena (a third of segment requests' throughput).

use std::sync::{Arc, Mutex};

/// Bytes reserved per image pixel (measured worst 34 B).
pub const BYTES_PER_PIXEL: u64 = 36;
/// Bytes reserved per input segment (measured 445 B).
pub const BYTES_PER_SEGMENT: u64 = 512;
/// Bytes reserved per request whatever its size (its own structures, the response).
pub const BYTES_PER_REQUEST: u64 = 4 << 20;

/// From this reservation up, a job's freed memory is handed back to the system when it ends.
const TRIM_AFTER_BYTES: u64 = 32 << 20;

/// A job's estimate: `pixels` of images and `segments` of lists.
pub fn estimate(pixels: u64, segments: u64) -> u64 {
    BYTES_PER_REQUEST
        .saturating_add(pixels.saturating_mul(BYTES_PER_PIXEL))
        .saturating_add(segments.saturating_mul(BYTES_PER_SEGMENT))
}

/// The budget: bytes reserved now, out of a total.
#[derive(Debug)]
pub struct WorkingMemory {
    total: u64,
    reserved: Mutex<u64>,
}

/// Why a reservation was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// More than the whole budget: this request can never run here.
    Never { needed: u64, total: u64 },
    /// More than is free now: retry when other jobs end.
    NotNow { needed: u64, total: u64 },
}

/// Reserved bytes, returned when dropped.
#[derive(Debug)]
pub struct Reservation {
    budget: Arc<WorkingMemory>,
    bytes: u64,
}

impl WorkingMemory {
    pub fn new(total: u64) -> Arc<WorkingMemory> {
        Arc::new(WorkingMemory {
            total,
            reserved: Mutex::new(0),
        })
    }

    pub fn total(&self) -> u64 {
        self.total
    }

    /// Bytes reserved now.
    pub fn reserved(&self) -> u64 {
        *self.reserved.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Reserves `bytes` at once, or says why not; never waits.
    pub fn try_reserve(self: &Arc<Self>, bytes: u64) -> Result<Reservation, Refused> {
        if bytes > self.total {
            return Err(Refused::Never {
                needed: bytes,
                total: self.total,
            });
        }
        let mut reserved = self.reserved.lock().unwrap_or_else(|e| e.into_inner());
        if *reserved + bytes > self.total {
            return Err(Refused::NotNow {
                needed: bytes,
                total: self.total,
            });
        }
        *reserved += bytes;
        Ok(Reservation {
            budget: Arc::clone(self),
            bytes,
        })
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        if self.bytes >= TRIM_AFTER_BYTES {
            release_free_memory();
        }
        let mut reserved = self
            .budget
            .reserved
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        *reserved -= self.bytes;
    }
}

/// Hands the allocator's free memory back to the system (glibc: every arena's).
fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages; it touches no live allocation.
    unsafe {
        libc::malloc_trim(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reservations_add_up_to_the_total_and_return_when_dropped() {
        let budget = WorkingMemory::new(100);
        let a = budget.try_reserve(60).unwrap();
        assert_eq!(
            budget.try_reserve(50).unwrap_err(),
            Refused::NotNow {
                needed: 50,
                total: 100
            }
        );
        let b = budget.try_reserve(40).unwrap();
        assert_eq!(budget.reserved(), 100);
        drop(a);
        assert_eq!(budget.reserved(), 40);
        assert!(budget.try_reserve(60).is_ok());
        drop(b);
        assert_eq!(budget.reserved(), 0);
        assert_eq!(
            budget.try_reserve(101).unwrap_err(),
            Refused::Never {
                needed: 101,
                total: 100
            }
        );
    }

    #[test]
    fn estimates_saturate_instead_of_wrapping() {
        assert_eq!(estimate(0, 0), BYTES_PER_REQUEST);
        assert_eq!(estimate(u64::MAX, 1), u64::MAX);
        assert_eq!(
            estimate(1000, 10),
            BYTES_PER_REQUEST + 1000 * BYTES_PER_PIXEL + 10 * BYTES_PER_SEGMENT
        );
    }
}
