//! The load generator against a real server on ephemeral ports: both transports, both loops,
//! and refusals counted by code when the server is saturated.

use std::sync::Arc;

use trinocular_server::server;
use trinocular_server::service::store::MemoryStore;
use trinocular_server::service::{Limits, Service};

fn loadgen(args: &[&str]) -> serde_json::Value {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_trinocular-loadgen"))
        .args(args)
        .arg("--json")
        .output()
        .expect("the binary runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

#[test]
fn measures_both_transports_and_counts_refusals() {
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let request = concat!(env!("CARGO_MANIFEST_DIR"), "/../../examples/request.json");
    let (grpc, http, running) = runtime.block_on(async {
        let limits = Limits {
            threads: 1,
            max_jobs: 1,
            ..Limits::default()
        };
        let ttl = std::time::Duration::from_secs(60);
        let store = Arc::new(MemoryStore::new(ttl));
        let service = Arc::new(Service::new(limits, store, ttl).unwrap());
        let any = "127.0.0.1:0".parse().unwrap();
        let running = server::start(service, any, any).await.unwrap();
        (running.grpc_addr, running.http_addr, running)
    });
    let grpc = format!("grpc://{grpc}");
    let http = format!("http://{http}");

    let closed = loadgen(&[
        "--target",
        &grpc,
        "--request",
        request,
        "--concurrency",
        "1",
        "--duration-s",
        "0.5",
    ]);
    assert!(closed["ok"].as_u64().unwrap() > 10, "{closed}");
    assert_eq!(closed["ok"], closed["requests"]);
    assert!(closed["latency_ms"]["p50"].as_f64().unwrap() > 0.0);

    let open = loadgen(&[
        "--target",
        &http,
        "--request",
        request,
        "--rate",
        "50",
        "--duration-s",
        "0.5",
    ]);
    assert_eq!(open["requests"], 25, "{open}");

    // Eight clients against one compute slot: some are refused at once, with 429.
    let busy = loadgen(&[
        "--target",
        &http,
        "--request",
        request,
        "--concurrency",
        "8",
        "--duration-s",
        "0.5",
    ]);
    assert!(
        busy["by_code"]["HTTP 429"].as_u64().unwrap_or(0) > 0,
        "{busy}"
    );
    assert!(busy["ok"].as_u64().unwrap() > 0, "{busy}");

    runtime.block_on(running.shutdown());
}
