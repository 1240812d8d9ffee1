//! Prometheus metrics: requests by transport, route and code; latency histograms; per-stage
//! durations of the pipeline; jobs in flight and rejections. One registry per [`Service`],
//! so servers in one process (tests) do not mix their counts.
//!
//! Two writers: each transport's observation layer records every request (count and latency,
//! by transport, route and code: `crate::observe`), and the Match use case records its
//! pipeline's stage times, which only it has.
//!
//! [`Service`]: super::Service

use prometheus::{
    Encoder, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge, IntGaugeVec, Opts,
    Registry, TextEncoder,
};

use trinocular_schema::pb;

/// Latency buckets, seconds: 1 ms to 10 s.
const LATENCY_BUCKETS: &[f64] = &[
    0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0,
];

/// A code's name as gRPC spells it (`OK`, `INVALID_ARGUMENT`, …): the `code` label.
pub fn grpc_code_name(code: tonic::Code) -> &'static str {
    use tonic::Code;
    match code {
        Code::Ok => "OK",
        Code::Cancelled => "CANCELLED",
        Code::Unknown => "UNKNOWN",
        Code::InvalidArgument => "INVALID_ARGUMENT",
        Code::DeadlineExceeded => "DEADLINE_EXCEEDED",
        Code::NotFound => "NOT_FOUND",
        Code::AlreadyExists => "ALREADY_EXISTS",
        Code::PermissionDenied => "PERMISSION_DENIED",
        Code::ResourceExhausted => "RESOURCE_EXHAUSTED",
        Code::FailedPrecondition => "FAILED_PRECONDITION",
        Code::Aborted => "ABORTED",
        Code::OutOfRange => "OUT_OF_RANGE",
        Code::Unimplemented => "UNIMPLEMENTED",
        Code::Internal => "INTERNAL",
        Code::Unavailable => "UNAVAILABLE",
        Code::DataLoss => "DATA_LOSS",
        Code::Unauthenticated => "UNAUTHENTICATED",
    }
}

pub struct Metrics {
    registry: Registry,
    requests: IntCounterVec,
    latency: HistogramVec,
    stages: HistogramVec,
    in_flight: IntGauge,
    max_jobs: IntGauge,
    overrunning: IntGauge,
    malformed: IntGauge,
    rejections: IntCounter,
    stopped: IntCounterVec,
    captures: IntCounterVec,
}

impl Metrics {
    pub fn new() -> Result<Metrics, prometheus::Error> {
        let registry = Registry::new();
        let requests = IntCounterVec::new(
            Opts::new(
                "trinocular_requests_total",
                "Requests by transport, route and gRPC code",
            ),
            &["transport", "route", "code"],
        )?;
        let latency = HistogramVec::new(
            HistogramOpts::new(
                "trinocular_request_duration_seconds",
                "Time from request to answer, by transport and route",
            )
            .buckets(LATENCY_BUCKETS.to_vec()),
            &["transport", "route"],
        )?;
        let stages = HistogramVec::new(
            HistogramOpts::new(
                "trinocular_stage_duration_seconds",
                "Pipeline stage wall time per request (extract: per image)",
            )
            .buckets(LATENCY_BUCKETS.to_vec()),
            &["stage"],
        )?;
        let in_flight = IntGauge::new(
            "trinocular_jobs_in_flight",
            "Compute jobs queued or running",
        )?;
        let overrunning = IntGauge::new(
            "trinocular_jobs_overrunning",
            "Compute jobs still running long after their caller went away (not ready while > 0)",
        )?;
        let malformed = IntGauge::new(
            "trinocular_grpc_malformed_messages",
            "gRPC messages that did not decode (answered INVALID_ARGUMENT), since the start",
        )?;
        let max_jobs = IntGauge::new(
            "trinocular_jobs_max",
            "Compute jobs allowed queued or running at once",
        )?;
        let rejections = IntCounter::new(
            "trinocular_rejections_total",
            "Requests refused at once because every compute slot was taken",
        )?;
        let stopped = IntCounterVec::new(
            Opts::new(
                "trinocular_jobs_stopped_total",
                "Running jobs stopped early (caller gone or deadline passed), by the stage they stopped before",
            ),
            &["stage"],
        )?;
        let captures = IntCounterVec::new(
            Opts::new(
                "trinocular_captures_total",
                "AddCapture calls answered, by outcome: stored, or retried (a capture the \
                 session held under its capture_id, answered without storing it again)",
            ),
            &["outcome"],
        )?;
        // What is running: the crate's version, as the usual `build_info` gauge (value 1).
        let build_info = IntGaugeVec::new(
            Opts::new(
                "trinocular_build_info",
                "The running build (value 1), by version",
            ),
            &["version"],
        )?;
        build_info
            .with_label_values(&[env!("CARGO_PKG_VERSION")])
            .set(1);
        registry.register(Box::new(build_info))?;
        // The process's CPU, memory, open files and start time (`process_*`), from /proc.
        #[cfg(target_os = "linux")]
        registry.register(Box::new(
            prometheus::process_collector::ProcessCollector::for_self(),
        ))?;
        registry.register(Box::new(stopped.clone()))?;
        registry.register(Box::new(captures.clone()))?;
        registry.register(Box::new(requests.clone()))?;
        registry.register(Box::new(latency.clone()))?;
        registry.register(Box::new(stages.clone()))?;
        registry.register(Box::new(in_flight.clone()))?;
        registry.register(Box::new(max_jobs.clone()))?;
        registry.register(Box::new(overrunning.clone()))?;
        registry.register(Box::new(malformed.clone()))?;
        registry.register(Box::new(rejections.clone()))?;
        Ok(Metrics {
            registry,
            requests,
            latency,
            stages,
            in_flight,
            max_jobs,
            overrunning,
            malformed,
            rejections,
            stopped,
            captures,
        })
    }

    /// An AddCapture answered: its capture stored now, or a retry of one already stored.
    pub fn record_capture(&self, retried: bool) {
        let outcome = if retried { "retried" } else { "stored" };
        self.captures.with_label_values(&[outcome]).inc();
    }

    /// A running job stopped before `stage` because nobody wanted its answer any more.
    pub fn record_stopped(&self, stage: &str) {
        self.stopped.with_label_values(&[stage]).inc();
    }

    /// One answered request, by the transport that answered it, its route and its code:
    /// recorded by the transport's observation layer, which times the request.
    pub fn record_request(&self, transport: &str, route: &str, code: tonic::Code, seconds: f64) {
        self.requests
            .with_label_values(&[transport, route, grpc_code_name(code)])
            .inc();
        self.latency
            .with_label_values(&[transport, route])
            .observe(seconds);
        if code == tonic::Code::ResourceExhausted {
            self.rejections.inc();
        }
    }

    /// The stage times of one Match's pipeline, from its answer's statistics: recorded by the
    /// Match use case, which has them (a layer would have to decode the answer to read them).
    pub fn record_match(&self, response: &pb::MatchResponse) {
        let Some(stats) = &response.stats else {
            return;
        };
        for (stage, ms) in [
            ("rectify", stats.rectify_ms),
            ("predict", stats.predict_ms),
            ("validate", stats.validate_ms),
            ("reconstruct", stats.reconstruct_ms),
        ] {
            self.stages.with_label_values(&[stage]).observe(ms / 1e3);
        }
        for ms in &stats.extract_ms {
            self.stages
                .with_label_values(&["extract"])
                .observe(ms / 1e3);
        }
    }

    /// The text exposition format, with the pool's current load.
    pub fn render(&self, in_flight: usize, max_jobs: usize, overrunning: usize) -> String {
        self.in_flight.set(in_flight as i64);
        self.overrunning.set(overrunning as i64);
        self.malformed
            .set(trinocular_schema::codec::malformed_messages() as i64);
        self.max_jobs.set(max_jobs as i64);
        let mut out = Vec::new();
        // Encoding into a Vec cannot fail for well-formed metrics; an error gives what we have.
        let _ = TextEncoder::new().encode(&self.registry.gather(), &mut out);
        String::from_utf8_lossy(&out).into_owned()
    }
}
