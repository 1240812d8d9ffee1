//! The service: the use cases both transports call, the compute pool they run on, the
//! session stores and the one error type. A thin shell over the core: it decodes, checks,
//! hands the CPU work to the pool and maps errors; the core knows nothing of it.
//!
//! ```text
//! gRPC (tonic) ─┐                     ┌─ rayon compute pool (admission, catch_unwind)
//!               ├─▶ Service::match_request ─▶ schema::match_request + pipeline
//! HTTP (axum) ──┘
//! ```
//!
//! The transports (the crate's `grpc`, `http` and `server` modules) call this module; it
//! imports none of them.

pub mod auth;
pub mod calibration;
pub mod clock;
pub mod error;
pub mod matching;
pub mod memory;
pub mod metrics;
pub mod pool;
pub mod priority;
pub mod sessions;
pub mod store;

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use matching::{RunError, RunMatch};
use trinocular_core::extract::DecodeLimits;
use trinocular_core::pipeline::Checkpoint;
use trinocular_schema::{self as api, pb, InputError};

pub use error::{http_status, ServiceError};
pub use pool::{ComputePool, PoolError};

/// Jobs queued or running per compute thread by default. Two: under overload an admitted
/// request waits for at most about one job ahead of it per thread, so its latency stays near
/// twice the service time while the excess is refused at once; more would only queue, which
/// lengthens latency without adding throughput.
pub const JOBS_PER_THREAD: usize = 2;

/// How long a job may run on after its caller gave up before the service says it is not
/// ready. Every stage asks its checkpoint within milliseconds, so only a bug gets here.
pub const OVERRUN_GRACE: std::time::Duration = std::time::Duration::from_secs(2);

/// What the service is allowed to do. Units in the names.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// Compute threads.
    pub threads: usize,
    /// Jobs queued or running at once; past it, RESOURCE_EXHAUSTED / 429 at once.
    pub max_jobs: usize,
    /// Largest request message or body, bytes (tonic's default of 4 MiB is too small for an
    /// image triplet).
    pub max_message_bytes: usize,
    /// Largest image, pixels (checked from its header, before decoding).
    pub max_image_pixels: u64,
    /// Most segments in one list of a request.
    pub max_segments_per_list: usize,
    /// Longest a request may run: its deadline when it gives none, and the cap on the one it
    /// gives. Past it the answer is DEADLINE_EXCEEDED and the work stops.
    pub max_request_time: std::time::Duration,
    /// Bytes of request bodies held at once, on both transports, each body's bytes taken as
    /// they arrive and before they are gathered ([`BodyMeter`]); past it,
    /// RESOURCE_EXHAUSTED / 429 at once.
    pub max_body_bytes_in_flight: usize,
    /// Working memory of the compute jobs at once, bytes: each reserves its estimate
    /// ([`memory`]) before it decodes or extracts anything.
    pub max_working_bytes: u64,
    /// Connections, header and body timeouts, and the shutdown grace period.
    pub connections: ConnectionLimits,
}

/// The default of [`Limits::max_image_pixels`]: 3 megapixels (2048 × 1536), more than robot
/// cameras and the real photograph sets we measure (1536 × 1024, 1600 × 1200) need, and what
/// lets a triplet of the largest images fit the default working memory (3 × 3 Mpx × 36 B +
/// 4 MiB = 313 MiB of 320) so that one server stays under 512 MiB (docs/HARDENING.md#memory).
/// The command line, one request on the whole machine, keeps the core's 12 Mpx.
pub const MAX_IMAGE_PIXELS: u64 = 3_000_000;

/// The default of [`Limits::max_request_time`]: a minute, ten times what the largest image
/// triplet within the other limits takes on one core.
pub const MAX_REQUEST_TIME: std::time::Duration = std::time::Duration::from_secs(60);

/// How the HTTP server treats its connections.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectionLimits {
    /// Connections open at once; past it a new one is answered 503 and closed.
    pub max_connections: usize,
    /// Longest wait for a request's headers, from the connection's start or the end of the
    /// previous answer (so also the idle timeout of a kept-alive connection).
    pub header_timeout: std::time::Duration,
    /// Longest wait for a request's whole body, from its headers.
    pub body_timeout: std::time::Duration,
    /// After a stop, how long open connections may finish what they do before being cut.
    pub shutdown_grace: std::time::Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        ConnectionLimits {
            max_connections: 1024,
            header_timeout: std::time::Duration::from_secs(10),
            body_timeout: std::time::Duration::from_secs(30),
            shutdown_grace: std::time::Duration::from_secs(10),
        }
    }
}

impl Default for Limits {
    fn default() -> Self {
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
        Limits {
            threads,
            max_jobs: JOBS_PER_THREAD * threads,
            max_message_bytes: 32 << 20,
            max_image_pixels: MAX_IMAGE_PIXELS,
            max_segments_per_list: api::MAX_SEGMENTS_PER_LIST,
            max_request_time: MAX_REQUEST_TIME,
            max_body_bytes_in_flight: 32 << 20,
            max_working_bytes: 320 << 20,
            connections: ConnectionLimits::default(),
        }
    }
}

/// The use cases, shared by both transports.
pub struct Service {
    pool: ComputePool,
    limits: Limits,
    ready: AtomicBool,
    metrics: Arc<metrics::Metrics>,
    store: Arc<dyn store::SessionStore>,
    store_ttl: std::time::Duration,
    /// What stamps sessions' and captures' creation times and times requests: the store's
    /// clock, in tests.
    clock: Arc<dyn clock::Clock>,
    /// Request-body bytes held now, in KiB permits ([`Limits::max_body_bytes_in_flight`]).
    bodies: Arc<tokio::sync::Semaphore>,
    /// The compute jobs' working memory ([`Limits::max_working_bytes`]).
    working: Arc<memory::WorkingMemory>,
    /// The API keys; none: the service is open.
    keys: auth::ApiKeys,
    /// Sessions one key may hold at once.
    max_sessions_per_key: usize,
    /// The stored id of each session as a capture is added to it or it is deleted, for the
    /// live views on this replica ([`Service::session_changes`]).
    changes: tokio::sync::broadcast::Sender<String>,
    /// Live-view streams open now, at most [`MAX_EVENT_STREAMS`].
    event_streams: Arc<tokio::sync::Semaphore>,
    /// Live-view streams open now by API key, each at most [`MAX_EVENT_STREAMS_PER_KEY`].
    event_streams_by_key: StreamsByKey,
}

/// Session changes a slow live view may fall behind by before it is told to catch up (it then
/// reads the session again, so nothing is lost but the intermediate counts).
const CHANGES_BUFFERED: usize = 256;
/// Live-view streams (`GET /v1/sessions/{id}/events`) open at once on one replica: each holds
/// a task and reads its session's record when told of a change or once a second.
pub const MAX_EVENT_STREAMS: usize = 256;
/// Live-view streams one API key may hold open at once on a replica, when the service has
/// keys: an eighth of [`MAX_EVENT_STREAMS`], so that no key can take them all.
pub const MAX_EVENT_STREAMS_PER_KEY: usize = 32;

/// Live-view streams open by API key.
type StreamsByKey = Arc<Mutex<HashMap<String, usize>>>;

/// One open live-view stream's places (on the replica, and in its key's share), given back
/// when it is dropped.
pub struct EventStream {
    tenant: Option<(StreamsByKey, String)>,
    _replica: tokio::sync::OwnedSemaphorePermit,
}

impl Drop for EventStream {
    fn drop(&mut self) {
        if let Some((open, tenant)) = &self.tenant {
            let mut open = open.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(held) = open.get_mut(tenant) {
                *held -= 1;
                if *held == 0 {
                    open.remove(tenant);
                }
            }
        }
    }
}

/// The default of the sessions one API key may hold at once.
pub const MAX_SESSIONS_PER_KEY: usize = 1000;

/// A request body's share of the body budget ([`Limits::max_body_bytes_in_flight`]), taken
/// as its bytes arrive and given back when dropped (with the answer: the decoded message, about
/// as large, lives until then). A body holds what it has sent, never what it announces: a
/// client that declares 32 MiB, or sends a chunked body, and then stalls holds nothing, where
/// a reservation of the announced size let one idle connection refuse every other upload for
/// the body timeout.
pub struct BodyMeter {
    bodies: Arc<tokio::sync::Semaphore>,
    limit_bytes: usize,
    received: u64,
    /// One KiB per permit, merged.
    held: Option<tokio::sync::OwnedSemaphorePermit>,
}

impl BodyMeter {
    /// Takes the budget for `bytes` more of the body, or refuses when the bodies being
    /// received hold it all (their own bytes, counted exactly: a body sent a byte at a time
    /// holds one KiB per KiB sent, not one per piece).
    pub fn add(&mut self, bytes: usize) -> Result<(), ServiceError> {
        self.received = self.received.saturating_add(bytes as u64);
        let held = self.held.as_ref().map_or(0, |p| p.num_permits()) as u64;
        let needed = self.received.div_ceil(1024).saturating_sub(held);
        if needed == 0 {
            return Ok(());
        }
        let refused = ServiceError::BodiesInFlight {
            limit_bytes: self.limit_bytes,
        };
        let needed = u32::try_from(needed).map_err(|_| refused.clone())?;
        let permit = Arc::clone(&self.bodies)
            .try_acquire_many_owned(needed)
            .map_err(|_| refused)?;
        match &mut self.held {
            Some(held) => held.merge(permit),
            None => self.held = Some(permit),
        }
        Ok(())
    }

    /// Bytes counted so far.
    pub fn received(&self) -> u64 {
        self.received
    }
}

/// Why a service could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("cannot start the compute pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
    #[error("cannot set up the metrics: {0}")]
    Metrics(#[from] prometheus::Error),
}

impl Service {
    /// A service whose sessions live in `store` and expire after `session_ttl` idle.
    pub fn new(
        limits: Limits,
        store: Arc<dyn store::SessionStore>,
        session_ttl: std::time::Duration,
    ) -> Result<Service, StartError> {
        let body_kib = (limits.max_body_bytes_in_flight >> 10).clamp(1, u32::MAX as usize);
        Ok(Service {
            keys: auth::ApiKeys::default(),
            max_sessions_per_key: MAX_SESSIONS_PER_KEY,
            changes: tokio::sync::broadcast::channel(CHANGES_BUFFERED).0,
            event_streams: Arc::new(tokio::sync::Semaphore::new(MAX_EVENT_STREAMS)),
            event_streams_by_key: Arc::default(),
            bodies: Arc::new(tokio::sync::Semaphore::new(body_kib)),
            working: memory::WorkingMemory::new(limits.max_working_bytes),
            pool: ComputePool::new(limits.threads, limits.max_jobs)?,
            limits,
            ready: AtomicBool::new(true),
            metrics: Arc::new(metrics::Metrics::new()?),
            store,
            store_ttl: session_ttl,
            clock: clock::system(),
        })
    }

    /// Stored session ids as they change (a capture added, the session deleted), on this
    /// replica only: a live view also re-reads its session now and then for the changes made
    /// through other replicas.
    pub fn session_changes(&self) -> tokio::sync::broadcast::Receiver<String> {
        self.changes.subscribe()
    }

    /// A place for one more live-view stream of `caller`, held until dropped: refused when
    /// [`MAX_EVENT_STREAMS`] are open on this replica, or, when the service has API keys, when
    /// the caller's key holds [`MAX_EVENT_STREAMS_PER_KEY`] of them (one key opening 256
    /// streams, which reconnect by themselves, locked every other key out of live views).
    pub fn open_event_stream(&self, caller: &auth::Caller) -> Result<EventStream, ServiceError> {
        // Dropped on a refusal of the key below, the replica's place is given back.
        let replica = Arc::clone(&self.event_streams)
            .try_acquire_owned()
            .map_err(|_| ServiceError::TooManyStreams {
                limit: MAX_EVENT_STREAMS,
                per_key: false,
            })?;
        let tenant = match &caller.tenant {
            Some(tenant) => {
                let mut open = self
                    .event_streams_by_key
                    .lock()
                    .unwrap_or_else(|e| e.into_inner());
                let held = open.entry(tenant.clone()).or_insert(0);
                if *held >= MAX_EVENT_STREAMS_PER_KEY {
                    return Err(ServiceError::TooManyStreams {
                        limit: MAX_EVENT_STREAMS_PER_KEY,
                        per_key: true,
                    });
                }
                *held += 1;
                Some((Arc::clone(&self.event_streams_by_key), tenant.clone()))
            }
            None => None,
        };
        Ok(EventStream {
            tenant,
            _replica: replica,
        })
    }

    fn session_changed(&self, stored_id: &str) {
        // No receiver (no live view open) is not a failure.
        let _ = self.changes.send(stored_id.to_string());
    }

    /// This service, stamping sessions and captures and timing requests by `clock` (give the
    /// store the same one).
    pub fn with_clock(mut self, clock: Arc<dyn clock::Clock>) -> Service {
        self.clock = clock;
        self
    }

    /// This service, requiring one of `keys` on every call (none: open), each key holding at
    /// most `max_sessions_per_key` sessions.
    pub fn with_api_keys(mut self, keys: auth::ApiKeys, max_sessions_per_key: usize) -> Service {
        self.keys = keys;
        self.max_sessions_per_key = max_sessions_per_key;
        self
    }

    /// The caller of a request with these credentials (the `authorization` header or
    /// metadata), or UNAUTHENTICATED.
    pub fn caller(&self, authorization: Option<&str>) -> Result<auth::Caller, ServiceError> {
        self.keys.caller(authorization)
    }

    /// A service on a memory store with a minute's session TTL, for unit tests.
    #[cfg(test)]
    pub(crate) fn in_memory(limits: Limits) -> Arc<Service> {
        let ttl = std::time::Duration::from_secs(60);
        let store = Arc::new(store::memory::MemoryStore::new(ttl));
        Arc::new(Service::new(limits, store, ttl).expect("a test service"))
    }

    /// A new body's meter on the request-body budget: it holds nothing until bytes arrive.
    pub fn body_meter(&self) -> BodyMeter {
        BodyMeter {
            bodies: Arc::clone(&self.bodies),
            limit_bytes: self.limits.max_body_bytes_in_flight,
            received: 0,
            held: None,
        }
    }

    /// Whether every compute slot is taken now: a request that would need one is refused
    /// before its body is read.
    pub fn compute_full(&self) -> bool {
        self.pool.in_flight() >= self.pool.max_jobs()
    }

    /// Where sessions are kept, for the log.
    pub fn store_description(&self) -> String {
        self.store.describe()
    }

    /// The metrics, for the transports' observation of each request.
    pub fn metrics(&self) -> &metrics::Metrics {
        &self.metrics
    }

    /// The clock this service reads: timestamps, and the durations of requests.
    pub fn clock(&self) -> &dyn clock::Clock {
        self.clock.as_ref()
    }

    /// The Prometheus text exposition of this service's metrics.
    pub fn metrics_text(&self) -> String {
        self.metrics.render(
            self.pool.in_flight(),
            self.pool.max_jobs(),
            self.pool.overrunning(OVERRUN_GRACE),
        )
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    pub fn pool(&self) -> &ComputePool {
        &self.pool
    }

    /// Ready to take work: false while shutting down, and while a job runs on more than
    /// [`OVERRUN_GRACE`] after its caller gave up (the watchdog: that thread is lost to new
    /// work until the job ends).
    pub fn is_ready(&self) -> bool {
        self.ready.load(Ordering::Relaxed) && self.pool.overrunning(OVERRUN_GRACE) == 0
    }

    pub fn set_ready(&self, ready: bool) {
        self.ready.store(ready, Ordering::Relaxed);
    }

    /// Match: [`Service::run_match`], with its pipeline's stage times recorded in the
    /// metrics. The request itself (its count, latency and log line) is the transport's to
    /// observe, as is every request's.
    pub async fn match_within<T: Send + 'static>(
        &self,
        read: impl FnOnce() -> Result<pb::MatchRequest, InputError> + Send + 'static,
        encode: impl FnOnce(&pb::MatchResponse) -> T + Send + 'static,
        timeout: Option<std::time::Duration>,
    ) -> Result<(pb::MatchResponse, T), ServiceError> {
        let answer = self.run_match(read, encode, timeout).await;
        if let Ok((response, _)) = &answer {
            self.metrics.record_match(response);
        }
        answer
    }

    /// Match on the compute pool, not the async runtime: `read` produces the request (so an
    /// HTTP body is parsed there), the request is checked and converted (images decoded) and
    /// the pipeline run, and `encode` turns the response into what the transport sends. Past
    /// its [`Service::deadline`] the answer is DEADLINE_EXCEEDED and the job, if still
    /// queued, never runs; if running, it stops at its next checkpoint (as it does when the
    /// caller goes away).
    pub async fn run_match<T: Send + 'static>(
        &self,
        read: impl FnOnce() -> Result<pb::MatchRequest, InputError> + Send + 'static,
        encode: impl FnOnce(&pb::MatchResponse) -> T + Send + 'static,
        timeout: Option<std::time::Duration>,
    ) -> Result<(pb::MatchResponse, T), ServiceError> {
        let limits = api::RequestLimits {
            decode: DecodeLimits {
                max_bytes: self.limits.max_message_bytes,
                max_pixels: self.limits.max_image_pixels,
            },
            max_segments_per_list: self.limits.max_segments_per_list,
        };
        let stopped = Arc::clone(&self.metrics);
        let working = Arc::clone(&self.working);
        let job = self.pool.run(move |abandoned| -> Result<_, ServiceError> {
            let request = read()?;
            let (pixels, segments) = api::request_size(&request, &limits.decode);
            let field = if pixels > 0 { "images" } else { "segments" };
            let _reserved = reserve(&working, memory::estimate(pixels, segments), field)?;
            let input = api::match_request(&request, &limits)?;
            let stop = || abandoned.is_set();
            let response = input.run_until(Checkpoint::new(&stop)).inspect_err(|e| {
                if let RunError::Stopped { stage } = e {
                    stopped.record_stopped(stage);
                }
            })?;
            let encoded = encode(&response);
            Ok((response, encoded))
        });
        within(job, self.deadline(timeout)).await
    }

    /// The deadline of a request that asked for `timeout` (none: no deadline of its own):
    /// never longer than [`Limits::max_request_time`].
    pub fn deadline(&self, timeout: Option<std::time::Duration>) -> std::time::Duration {
        let max = self.limits.max_request_time;
        timeout.map_or(max, |t| t.min(max))
    }
}

/// Reserves a job's working memory, or the error to answer: INVALID_ARGUMENT naming `field`
/// when the whole budget is too small, RESOURCE_EXHAUSTED when it is taken now.
pub(crate) fn reserve(
    working: &Arc<memory::WorkingMemory>,
    bytes: u64,
    field: &str,
) -> Result<memory::Reservation, ServiceError> {
    working.try_reserve(bytes).map_err(|refused| match refused {
        memory::Refused::Never { needed, total } => ServiceError::Input(InputError::new(
            field,
            format!(
                "needs about {} MiB of working memory, more than this service's {} MiB \
                 (limits.max_working_mib): send smaller images or fewer segments",
                needed.div_ceil(1 << 20),
                total >> 20
            ),
        )),
        memory::Refused::NotNow { total, .. } => ServiceError::MemoryBusy { limit_bytes: total },
    })
}

/// Awaits a compute-pool job, or answers DEADLINE_EXCEEDED past `timeout` and drops the job:
/// a queued job then never runs, a running one stops at its next checkpoint.
pub(crate) async fn within<T, E: Into<ServiceError>>(
    job: impl std::future::Future<Output = Result<Result<T, E>, PoolError>>,
    timeout: std::time::Duration,
) -> Result<T, ServiceError> {
    within_what_is_left(job, timeout, timeout).await
}

/// [`within`] for the last stage of a request whose `deadline` has partly gone on the stages
/// before: the job gets what is `left` of it, and a timeout names the request's deadline, not
/// the remainder (an AddCapture given 120 ms said "the deadline of 3 ms passed").
pub(crate) async fn within_what_is_left<T, E: Into<ServiceError>>(
    job: impl std::future::Future<Output = Result<Result<T, E>, PoolError>>,
    left: std::time::Duration,
    deadline: std::time::Duration,
) -> Result<T, ServiceError> {
    match tokio::time::timeout(left, job).await {
        Ok(done) => done
            .map_err(ServiceError::from)
            .and_then(|r| r.map_err(Into::into)),
        Err(_) => Err(ServiceError::DeadlineExceeded {
            timeout_ms: deadline.as_millis() as u64,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_api_key_can_take_every_live_view() {
        let service = Service::in_memory(Limits {
            threads: 1,
            ..Limits::default()
        });
        let caller = |tenant: Option<&str>| auth::Caller {
            tenant: tenant.map(str::to_string),
        };
        let alice = caller(Some("alice"));
        let mut held: Vec<EventStream> = (0..MAX_EVENT_STREAMS_PER_KEY)
            .map(|_| service.open_event_stream(&alice).unwrap())
            .collect();
        let refused = service.open_event_stream(&alice).err().unwrap();
        assert_eq!(
            refused,
            ServiceError::TooManyStreams {
                limit: MAX_EVENT_STREAMS_PER_KEY,
                per_key: true
            }
        );
        assert!(
            refused.to_string().contains("for this API key"),
            "{refused}"
        );
        // Another key still gets its own; one of alice's closed gives her a place back.
        held.push(service.open_event_stream(&caller(Some("bob"))).unwrap());
        held.swap_remove(0);
        held.push(service.open_event_stream(&alice).unwrap());
        // Without keys the replica's bound is the only one.
        let anyone = caller(None);
        while held.len() < MAX_EVENT_STREAMS {
            held.push(service.open_event_stream(&anyone).unwrap());
        }
        assert_eq!(
            service.open_event_stream(&anyone).err(),
            Some(ServiceError::TooManyStreams {
                limit: MAX_EVENT_STREAMS,
                per_key: false
            })
        );
        // A key refused by the replica's bound gets back the place in its share it took.
        let bob = caller(Some("bob"));
        let refused = service.open_event_stream(&bob).err().unwrap();
        assert!(matches!(
            refused,
            ServiceError::TooManyStreams { per_key: false, .. }
        ));
        let open = service.event_streams_by_key.lock().unwrap().clone();
        assert_eq!(open.get("bob"), Some(&1));
        drop(held);
        assert!(service.event_streams_by_key.lock().unwrap().is_empty());
    }

    #[tokio::test]
    async fn a_timeout_names_the_requests_deadline_not_what_was_left_of_it() {
        let never = std::future::pending::<Result<Result<(), ServiceError>, PoolError>>();
        let left = std::time::Duration::from_millis(5);
        let deadline = std::time::Duration::from_millis(120);
        let e = within_what_is_left(never, left, deadline)
            .await
            .unwrap_err();
        assert_eq!(e, ServiceError::DeadlineExceeded { timeout_ms: 120 });
        assert!(e.to_string().contains("120 ms"), "{e}");
    }
}
