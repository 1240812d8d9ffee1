//! The fuzz targets' code: what each does with one input, and what they share (small limits
//! so that one execution stays short, a valid rig, an in-process HTTP service).
//!
//! A plain crate of the workspace, so that `cargo test` replays the checked-in corpus
//! (`fuzz/corpus/`, tests/corpus.rs) through the very functions libFuzzer calls: `fuzz/`
//! holds only the libFuzzer entry points, built with coverage flags by `.ci/fuzz`
//! (docs/FUZZING.md).

pub mod image_decode;
pub mod json_body;
pub mod match_whole;
pub mod multipart_body;
pub mod protobuf_body;
pub mod session_whole;

use std::sync::{Arc, Mutex, OnceLock};

use axum::body::Body;
use axum::http::{Request, StatusCode};
use tower::ServiceExt;
use trinocular::api::{self, pb, RequestLimits};
use trinocular::extract::DecodeLimits;
use trinocular::service::{store::MemoryStore, Limits, Service};

/// Largest encoded image or body: 1 MiB.
pub const MAX_BYTES: usize = 1 << 20;
/// Largest image, pixels.
pub const MAX_PIXELS: u64 = 1_000_000;
/// Most segments per list a conversion accepts.
pub const MAX_SEGMENTS_PER_LIST: usize = 2000;

pub fn decode_limits() -> DecodeLimits {
    DecodeLimits {
        max_bytes: MAX_BYTES,
        max_pixels: MAX_PIXELS,
    }
}

pub fn request_limits() -> RequestLimits {
    RequestLimits {
        decode: decode_limits(),
        max_segments_per_list: MAX_SEGMENTS_PER_LIST,
    }
}

/// A valid non-collinear rig for `width` x `height` images, as the integration tests build it
/// (K, R, t): centres (0,0,0), (0.3,0,0), (0.15,0,0.25) m, looking along rig +y.
pub fn calibration(width: u32, height: u32) -> pb::Calibration {
    let f = 1.2 * f64::from(width.max(height));
    let (cx, cy) = (f64::from(width) / 2.0, f64::from(height) / 2.0);
    let r = [1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0];
    pb::Calibration {
        cameras: [(0.0, 0.0, 0.0), (0.3, 0.0, 0.0), (0.15, 0.0, 0.25)]
            .iter()
            .enumerate()
            .map(|(i, &(x, y, z))| {
                let c = [x, y, z];
                pb::Camera {
                    name: format!("cam{}", i + 1),
                    width,
                    height,
                    intrinsics: vec![f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0],
                    rotation: r.to_vec(),
                    translation: (0..3)
                        .map(|row| -(0..3).map(|k| r[row * 3 + k] * c[k]).sum::<f64>())
                        .collect(),
                    ..Default::default()
                }
            })
            .collect(),
    }
}

/// The rig of the session the HTTP target's captures go to: the synthetic room's preset rig
/// (seed 1) at 1/8 of its resolution, 64 x 64 pixels. fuzz/seedgen renders the seed images of
/// captures with the same rig.
pub fn session_calibration() -> pb::Calibration {
    api::calibration_to_pb(&trinocular::synth::bench_capture(1, 0.125).1)
}

/// The real HTTP router over a service with a memory store, on a current-thread runtime
/// built once per process, and the session that captures are sent to.
pub struct Http {
    runtime: tokio::runtime::Runtime,
    router: axum::Router,
    session: Mutex<String>,
    calibration: pb::Calibration,
}

/// What one request answered.
pub struct Answer {
    pub status: StatusCode,
    pub body: Vec<u8>,
}

impl Http {
    /// The process's one instance.
    pub fn get() -> &'static Http {
        static HTTP: OnceLock<Http> = OnceLock::new();
        HTTP.get_or_init(|| {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .expect("tokio runtime");
            let limits = Limits {
                threads: 1,
                max_jobs: 2,
                max_message_bytes: MAX_BYTES,
                max_image_pixels: MAX_PIXELS,
                max_segments_per_list: MAX_SEGMENTS_PER_LIST,
                // The rest (the request deadline among them) as the server has it: an input
                // that runs long is caught by libFuzzer's -timeout first.
                ..Limits::default()
            };
            let ttl = std::time::Duration::from_secs(24 * 3600);
            let service = Service::new(limits, Arc::new(MemoryStore::new(ttl)), ttl)
                .expect("the service starts");
            let http = Http {
                runtime,
                router: api::http::router(Arc::new(service)),
                session: Mutex::new(String::new()),
                calibration: session_calibration(),
            };
            http.new_session();
            http
        })
    }

    /// Sends one request through the router and reads the whole answer.
    pub fn send(&self, request: Request<Body>) -> Answer {
        self.runtime.block_on(async {
            let response = self
                .router
                .clone()
                .oneshot(request)
                .await
                .expect("the router is infallible");
            let status = response.status();
            let body = axum::body::to_bytes(response.into_body(), usize::MAX)
                .await
                .expect("the answer's body reads")
                .to_vec();
            Answer { status, body }
        })
    }

    /// [`Http::send`], failing on a 5xx answer (what the HTTP targets promise), and with
    /// `FUZZ_DEBUG` set printing the answer's start.
    pub fn send_checked(&self, request: Request<Body>) -> Answer {
        let what = format!("{} {}", request.method(), request.uri());
        let answer = self.send(request);
        assert!(
            !answer.status.is_server_error(),
            "{what} answered {}: {}",
            answer.status,
            String::from_utf8_lossy(&answer.body)
        );
        debug(|| {
            let body: String = String::from_utf8_lossy(&answer.body)
                .chars()
                .take(300)
                .collect();
            format!("{what}: {} {body}", answer.status)
        });
        answer
    }

    /// The session that captures go to now.
    pub fn session(&self) -> String {
        self.session.lock().unwrap().clone()
    }

    /// Replaces the session (deleting the old one): a session that keeps every accepted
    /// capture would grow the memory store for as long as the fuzzer runs.
    pub fn new_session(&self) {
        let old = self.session();
        if !old.is_empty() {
            let answer = self.send(
                Request::delete(format!("/v1/sessions/{old}"))
                    .body(Body::empty())
                    .unwrap(),
            );
            assert_eq!(answer.status, StatusCode::OK, "deleting the session");
        }
        let create = pb::CreateSessionRequest {
            name: "fuzz".into(),
            calibration: Some(self.calibration.clone()),
            options: None,
            map_options: None,
            session_id: String::new(),
        };
        let answer = self.send(
            Request::post("/v1/sessions")
                .header("content-type", "application/json")
                .body(Body::from(api::to_json(&create)))
                .unwrap(),
        );
        assert_eq!(answer.status, StatusCode::OK, "creating the session");
        let session: pb::Session =
            api::from_json("session", std::str::from_utf8(&answer.body).unwrap())
                .expect("a Session");
        *self.session.lock().unwrap() = session.id;
    }
}

/// The operations of a structured input: as many as the bytes give, up to `most` — not
/// arbitrary's `Vec`, whose continue-or-stop bit per element gives two or three on average.
pub(crate) fn ops_until_exhausted<'a, T: arbitrary::Arbitrary<'a>>(
    u: &mut arbitrary::Unstructured<'a>,
    most: usize,
) -> arbitrary::Result<Vec<T>> {
    let mut ops = Vec::new();
    while !u.is_empty() && ops.len() < most {
        ops.push(T::arbitrary(u)?);
    }
    Ok(ops)
}

/// With `FUZZ_DEBUG` set, prints what `what` says (to see where an input gets: replay a file
/// with `FUZZ_DEBUG=1 target FILE`).
pub fn debug(what: impl FnOnce() -> String) {
    static ON: OnceLock<bool> = OnceLock::new();
    if *ON.get_or_init(|| std::env::var_os("FUZZ_DEBUG").is_some()) {
        eprintln!("{}", what());
    }
}
