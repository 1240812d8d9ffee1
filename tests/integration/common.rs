//! Shared fixtures: a valid rig in the schema's JSON, built from K, R, t like a user would.

use serde_json::{json, Value};

/// A non-collinear rig looking along rig +y: centres (0,0,0), (0.3,0,0), (0.15,0,0.25) m.
pub fn calibration_json() -> Value {
    let cams: Vec<Value> = [(0.0, 0.0, 0.0), (0.3, 0.0, 0.0), (0.15, 0.0, 0.25)]
        .iter()
        .enumerate()
        .map(|(i, &(x, y, z))| {
            // R maps rig (x right, y forward, z up) to camera (x right, y down, z forward).
            let r = [1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0];
            let c = [x, y, z];
            let t: Vec<f64> = (0..3)
                .map(|row| -(0..3).map(|k| r[row * 3 + k] * c[k]).sum::<f64>())
                .collect();
            json!({
                "name": format!("cam{}", i + 1),
                "width": 512, "height": 512,
                "intrinsics": [600.0, 0.0, 256.0, 0.0, 600.0, 256.0, 0.0, 0.0, 1.0],
                "rotation": r,
                "translation": t,
            })
        })
        .collect();
    json!({ "cameras": cams })
}

pub fn segment(u1: f64, v1: f64, u2: f64, v2: f64) -> Value {
    json!({"u1": u1, "v1": v1, "u2": u2, "v2": v2})
}

/// A request with one plausible segment per list.
pub fn request_json() -> Value {
    let list = json!({"oriented": true, "segments": [segment(100.0, 100.0, 100.0, 200.0)]});
    json!({
        "calibration": calibration_json(),
        "segments": {"lists": [list.clone(), list.clone(), list]},
    })
}

/// The example request of the README (`examples/request.json`): a small scene's three
/// segment lists and their rig.
pub fn example_request() -> trinocular::api::pb::MatchRequest {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/request.json"
    ))
    .expect("example request");
    trinocular::api::from_json("request", &text).expect("valid JSON")
}

/// Runs a JSON request through the API, as the CLI and the service do; returns the failing
/// field, or the response.
pub fn run_json(request: &serde_json::Value) -> Result<trinocular::api::pb::MatchResponse, String> {
    use trinocular::api::{self, RunError, RunMatch};
    let req: api::pb::MatchRequest =
        api::from_json("request", &request.to_string()).map_err(|e| e.field)?;
    let input = api::match_request(&req, &Default::default()).map_err(|e| e.field)?;
    input.run().map_err(|e| match e {
        RunError::Input(e) => e.field,
        stopped => panic!("nothing asked to stop, yet: {stopped}"),
    })
}

/// A fresh directory under the system's temporary directory, for one test.
pub fn scratch_dir(name: &str) -> std::path::PathBuf {
    use std::sync::atomic::{AtomicU32, Ordering};
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let dir = std::env::temp_dir().join(format!(
        "trinocular-test-{name}-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// Idle TTL of the sessions of test services: long enough never to expire during a test.
pub const TEST_SESSION_TTL: std::time::Duration = std::time::Duration::from_secs(3600);

/// A service with `limits` whose sessions live in an embedded store in a scratch directory.
pub async fn embedded_service(
    limits: trinocular::service::Limits,
) -> std::sync::Arc<trinocular::service::Service> {
    let dir = scratch_dir("store");
    let store = trinocular::service::store::open("embedded", &dir, TEST_SESSION_TTL)
        .await
        .expect("embedded store");
    std::sync::Arc::new(
        trinocular::service::Service::new(limits, store, TEST_SESSION_TTL).expect("service"),
    )
}

/// `trinocular serve` as a child process on ephemeral ports, killed when dropped.
pub struct ServerProcess {
    pub child: std::process::Child,
    pub grpc_addr: std::net::SocketAddr,
    pub http_addr: std::net::SocketAddr,
}

impl ServerProcess {
    /// Starts the binary with `args` added to ephemeral addresses, and waits for its
    /// "listening" line (which carries the ports it got).
    pub fn spawn(args: &[&str]) -> ServerProcess {
        Self::spawn_with_env(args, &[])
    }

    /// [`ServerProcess::spawn`] with environment variables set (configuration, as
    /// `TRINOCULAR__SECTION__KEY`).
    pub fn spawn_with_env(args: &[&str], env: &[(&str, &str)]) -> ServerProcess {
        use std::io::BufRead;
        // One thread and room for the tests' concurrent streams (they test stores, not
        // admission), unless the test says otherwise.
        let mut defaults = vec!["--grpc-addr", "127.0.0.1:0", "--http-addr", "127.0.0.1:0"];
        for (flag, value) in [("--threads", "1"), ("--max-jobs", "64")] {
            if !args.contains(&flag) {
                defaults.extend([flag, value]);
            }
        }
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_trinocular"))
            .arg("serve")
            .args(&defaults)
            .args(args)
            .envs(env.iter().copied())
            .env("RUST_LOG", "info")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("the server binary starts");
        let stderr = child.stderr.take().unwrap();
        let mut lines = std::io::BufReader::new(stderr).lines();
        let mut seen = Vec::new();
        let addr_after = |line: &str, key: &str| -> Option<std::net::SocketAddr> {
            let rest = &line[line.find(key)? + key.len()..];
            rest.split_whitespace().next()?.parse().ok()
        };
        for line in lines.by_ref() {
            let line = line.expect("server log");
            if line.contains("listening") {
                let grpc_addr = addr_after(&line, "grpc=").expect("grpc address in the log");
                let http_addr = addr_after(&line, "http=").expect("http address in the log");
                // Keep draining the log so the server never blocks on a full pipe.
                std::thread::spawn(move || for _ in lines {});
                return ServerProcess {
                    child,
                    grpc_addr,
                    http_addr,
                };
            }
            seen.push(line);
        }
        let _ = child.kill();
        let _ = child.wait();
        panic!("the server stopped before listening:\n{}", seen.join("\n"));
    }

    pub fn kill9(&mut self) {
        let _ = self.child.kill(); // SIGKILL on Unix
        let _ = self.child.wait();
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        self.kill9();
    }
}

/// `reqwest` without its `json` feature: parse the body with serde_json.
#[allow(async_fn_in_trait)]
pub trait JsonBody {
    async fn json_body(self) -> serde_json::Value;
}

impl JsonBody for reqwest::Response {
    async fn json_body(self) -> serde_json::Value {
        serde_json::from_str(&self.text().await.expect("body")).expect("JSON body")
    }
}

/// The `/metrics` text of the server whose HTTP port is `http_addr`.
pub async fn metrics_text(http: &reqwest::Client, http_addr: std::net::SocketAddr) -> String {
    http.get(format!("http://{http_addr}/metrics"))
        .send()
        .await
        .expect("metrics")
        .text()
        .await
        .expect("metrics body")
}

/// The runtime of the tests' servers and clients.
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

/// A gRPC client of the server at `url`. The schema's generated client has no `connect` (it
/// would make every user of the schema compile tonic's transport), so the channel is made
/// here, as tonic's `connect` would.
pub async fn grpc_connect(
    url: String,
) -> Result<
    trinocular::api::pb::trinocular_client::TrinocularClient<tonic::transport::Channel>,
    tonic::transport::Error,
> {
    let channel = tonic::transport::Endpoint::new(url)?.connect().await?;
    Ok(trinocular::api::pb::trinocular_client::TrinocularClient::new(channel))
}

/// A plaintext channel to the gRPC listener at `addr`, for the standard services (health,
/// reflection) that have no client of ours.
pub async fn grpc_channel(addr: std::net::SocketAddr) -> tonic::transport::Channel {
    tonic::transport::Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap()
}

/// Asserts that `status` is INVALID_ARGUMENT naming `field`, as every input error is answered
/// over gRPC: the message starts with it, and it is the one `google.rpc.BadRequest` field
/// violation of the status's details (tonic-types reads it).
pub fn assert_invalid_argument_naming(status: &tonic::Status, field: &str) {
    assert_eq!(status.code(), tonic::Code::InvalidArgument, "{status:?}");
    assert!(
        status.message().starts_with(&format!("{field}: ")),
        "{}",
        status.message()
    );
    let violations = tonic_types::StatusExt::get_details_bad_request(status)
        .expect("a BadRequest detail")
        .field_violations;
    assert_eq!(violations.len(), 1, "{violations:?}");
    assert_eq!(violations[0].field, field);
    assert!(!violations[0].description.is_empty());
}

/// A POST of `message` as HTTP/protobuf (`content-type: application/x-protobuf`), to send.
pub fn post_protobuf(
    http: &reqwest::Client,
    url: impl reqwest::IntoUrl,
    message: &impl prost::Message,
) -> reqwest::RequestBuilder {
    http.post(url)
        .header("content-type", "application/x-protobuf")
        .body(message.encode_to_vec())
}
