//! The service: the use cases both transports call, the compute pool they run on, the one
//! error type, and the servers. A thin shell over the core: it decodes, checks, hands the CPU
//! work to the pool and maps errors; the core knows nothing of it.
//!
//! ```text
//! gRPC (tonic) ─┐                     ┌─ rayon compute pool (admission, catch_unwind)
//!               ├─▶ Service::match_request ─▶ api::match_request + pipeline
//! HTTP (axum) ──┘
//! ```

pub mod config;
pub mod error;
pub mod metrics;
pub mod pool;
pub mod request_id;
pub mod server;

use std::sync::atomic::{AtomicBool, Ordering};

use crate::api::{self, pb, InputError};
use crate::extract::DecodeLimits;

pub use error::{http_status, ServiceError};
pub use pool::{ComputePool, PoolError};

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
}

impl Default for Limits {
    fn default() -> Self {
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
        Limits {
            threads,
            max_jobs: 4 * threads,
            max_message_bytes: 32 << 20,
            max_image_pixels: DecodeLimits::default().max_pixels,
        }
    }
}

/// The use cases, shared by both transports.
pub struct Service {
    pool: ComputePool,
    limits: Limits,
    ready: AtomicBool,
    metrics: metrics::Metrics,
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
    pub fn new(limits: Limits) -> Result<Service, StartError> {
        Ok(Service {
            pool: ComputePool::new(limits.threads, limits.max_jobs)?,
            limits,
            ready: AtomicBool::new(true),
            metrics: metrics::Metrics::new()?,
        })
    }

    /// Counts a request refused before it reached [`Service::match_within`] (unreadable body).
    pub fn record_refused(&self, transport: &str, error: &ServiceError, seconds: f64) {
        self.log_refused(transport, error, seconds);
        self.metrics
            .record(transport, "match", error.code(), seconds, None);
    }

    /// The Prometheus text exposition of this service's metrics.
    pub fn metrics_text(&self) -> String {
        self.metrics
            .render(self.pool.in_flight(), self.pool.max_jobs())
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    pub fn pool(&self) -> &ComputePool {
        &self.pool
    }

    /// Ready to take work (false while shutting down).
    pub fn is_ready(&self) -> bool {
        self.ready.load(Ordering::Relaxed)
    }

    pub fn set_ready(&self, ready: bool) {
        self.ready.store(ready, Ordering::Relaxed);
    }

    /// [`Service::match_request`] within `timeout` (none: no deadline). Past it the answer is
    /// DEADLINE_EXCEEDED and the job, if still queued, never runs.
    /// Recorded in the metrics under `transport`.
    pub async fn match_within(
        &self,
        request: pb::MatchRequest,
        timeout: Option<std::time::Duration>,
        transport: &str,
    ) -> Result<pb::MatchResponse, ServiceError> {
        let start = std::time::Instant::now();
        let result = self.match_deadline(request, timeout).await;
        let code = result
            .as_ref()
            .map_or_else(|e| e.code(), |_| tonic::Code::Ok);
        let seconds = start.elapsed().as_secs_f64();
        // One line per request, inside the transport's span (which carries the request id).
        match &result {
            Ok(r) => tracing::info!(
                transport,
                code = ?code,
                ms = seconds * 1e3,
                segments_3d = r.segments_3d.len(),
                "match"
            ),
            Err(e) => {
                tracing::info!(transport, code = ?code, ms = seconds * 1e3, error = %e, "match")
            }
        }
        self.metrics
            .record(transport, "match", code, seconds, result.as_ref().ok());
        result
    }

    /// Logs and counts a request refused before it reached [`Service::match_within`].
    fn log_refused(&self, transport: &str, error: &ServiceError, seconds: f64) {
        tracing::info!(transport, code = ?error.code(), ms = seconds * 1e3, error = %error, "match");
    }

    async fn match_deadline(
        &self,
        request: pb::MatchRequest,
        timeout: Option<std::time::Duration>,
    ) -> Result<pb::MatchResponse, ServiceError> {
        match timeout {
            None => self.match_request(request).await,
            Some(t) => tokio::time::timeout(t, self.match_request(request))
                .await
                .unwrap_or(Err(ServiceError::DeadlineExceeded {
                    timeout_ms: t.as_millis() as u64,
                })),
        }
    }

    /// Match: checks and converts the request (decoding images) and runs the pipeline, all on
    /// the compute pool.
    pub async fn match_request(
        &self,
        request: pb::MatchRequest,
    ) -> Result<pb::MatchResponse, ServiceError> {
        let limits = DecodeLimits {
            max_bytes: self.limits.max_message_bytes,
            max_pixels: self.limits.max_image_pixels,
        };
        let result = self
            .pool
            .run(move || -> Result<pb::MatchResponse, InputError> {
                api::match_request(&request, &limits)?.run()
            })
            .await;
        match result {
            Ok(response) => Ok(response?),
            Err(e) => {
                let e = ServiceError::from(e);
                if let ServiceError::Internal { detail } = &e {
                    tracing::error!(detail = %detail, "match: internal error");
                }
                Err(e)
            }
        }
    }
}
