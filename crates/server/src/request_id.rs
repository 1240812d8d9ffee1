//! Request ids: the client's `x-request-id` if it sent one (up to 128 printable characters),
//! otherwise a new one; echoed in the response (HTTP header, gRPC metadata) and in the log
//! line of the request, so a client's report can be found in the logs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{SystemTime, UNIX_EPOCH};

/// The header and metadata key.
pub const HEADER: &str = "x-request-id";
const MAX_LEN: usize = 128;

/// The caller's id when acceptable, else a fresh one: `<process start, hex>-<counter>`.
pub fn request_id(given: Option<&str>) -> String {
    if let Some(id) = given.filter(|id| {
        !id.is_empty() && id.len() <= MAX_LEN && id.bytes().all(|b| b.is_ascii_graphic())
    }) {
        return id.to_string();
    }
    static START: OnceLock<u64> = OnceLock::new();
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let start = START.get_or_init(|| {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64)
    });
    format!("{start:x}-{}", COUNTER.fetch_add(1, Ordering::Relaxed))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_a_sane_client_id_and_makes_unique_ones() {
        assert_eq!(request_id(Some("abc-123")), "abc-123");
        let (a, b) = (request_id(None), request_id(Some("bad id with spaces")));
        assert_ne!(a, b);
        assert!(!b.contains(' '));
        assert_ne!(request_id(Some(&"x".repeat(500))).len(), 500);
    }
}
