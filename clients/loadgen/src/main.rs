//! `trinocular-loadgen`: sends one `MatchRequest` again and again to a Trinocular service and
//! reports throughput, latency percentiles and errors by code.
//!
//! - closed loop (`--concurrency N`): N clients, each sending its next request when the last
//!   one is answered — the service's capacity at that concurrency;
//! - open loop (`--rate R`): requests sent at R per second whatever happens, latency measured
//!   from each request's *intended* send time, so a stalled server cannot hide its queue
//!   (coordinated omission).
//!
//! ```text
//! trinocular-loadgen --target grpc://127.0.0.1:50051 --request examples/request.json \
//!     --concurrency 4 --duration-s 10 [--json]
//! trinocular-loadgen --target http://127.0.0.1:8080 --request examples/request.json \
//!     --rate 200 --duration-s 10
//! trinocular-loadgen --target inproc://2 --request examples/request.json --concurrency 4
//! ```
//!
//! `inproc://THREADS` is the peer the transports are measured against: the library in this
//! process, on a compute pool of THREADS threads behind the same admission limit as the
//! server's (two jobs per thread), with no network, encoding or decoding of messages.

use std::collections::BTreeMap;
use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Parser;
use prost::Message;
use trinocular_schema::{self as api, pb};
use trinocular_server::service::store::MemoryStore;
use trinocular_server::service::{Limits, Service};

#[derive(Parser)]
#[command(
    name = "trinocular-loadgen",
    about = "Load generator for the Trinocular service"
)]
struct Args {
    /// grpc://HOST:PORT, http://HOST:PORT, or inproc://THREADS (the library in this process).
    #[arg(long)]
    target: String,
    /// A MatchRequest in proto3 JSON.
    #[arg(long)]
    request: std::path::PathBuf,
    /// Closed loop: this many clients in parallel.
    #[arg(long, conflicts_with = "rate")]
    concurrency: Option<usize>,
    /// Open loop: requests per second.
    #[arg(long)]
    rate: Option<f64>,
    /// How long to send, seconds.
    #[arg(long, default_value_t = 10.0)]
    duration_s: f64,
    /// HTTP: send JSON instead of protobuf.
    #[arg(long)]
    http_json: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// What one request came to: its latency and its outcome ("OK" or a gRPC code / HTTP status).
type Outcome = (Duration, String);

/// A gRPC codec that sends bytes encoded once up front and counts the answer's bytes without
/// decoding them: the gRPC client then does as little per request as the HTTP client, which
/// posts a prepared body, so the figures compare the server's transports rather than the
/// clients (they share the machine).
#[derive(Clone, Copy, Default)]
struct PreEncoded;
struct PassBytes;
struct CountBytes;

impl tonic::codec::Codec for PreEncoded {
    type Encode = bytes::Bytes;
    type Decode = usize;
    type Encoder = PassBytes;
    type Decoder = CountBytes;
    fn encoder(&mut self) -> PassBytes {
        PassBytes
    }
    fn decoder(&mut self) -> CountBytes {
        CountBytes
    }
}

impl tonic::codec::Encoder for PassBytes {
    type Item = bytes::Bytes;
    type Error = tonic::Status;
    fn encode(
        &mut self,
        item: bytes::Bytes,
        dst: &mut tonic::codec::EncodeBuf<'_>,
    ) -> Result<(), tonic::Status> {
        bytes::BufMut::put_slice(dst, &item);
        Ok(())
    }
}

impl tonic::codec::Decoder for CountBytes {
    type Item = usize;
    type Error = tonic::Status;
    fn decode(
        &mut self,
        src: &mut tonic::codec::DecodeBuf<'_>,
    ) -> Result<Option<usize>, tonic::Status> {
        let n = bytes::Buf::remaining(src);
        bytes::Buf::advance(src, n);
        Ok(Some(n))
    }
}

#[derive(Clone)]
enum Client {
    Grpc {
        grpc: tonic::client::Grpc<tonic::transport::Channel>,
        body: bytes::Bytes,
    },
    Http {
        client: reqwest::Client,
        url: String,
        body: Vec<u8>,
        content_type: &'static str,
    },
    InProcess(Arc<Service>),
}

impl Client {
    async fn send(&mut self, request: &pb::MatchRequest) -> String {
        match self {
            Client::Grpc { grpc, body } => {
                if let Err(e) = grpc.ready().await {
                    return format!("transport: {e}");
                }
                let path = tonic::codegen::http::uri::PathAndQuery::from_static(
                    "/trinocular.v1.Trinocular/Match",
                );
                match grpc
                    .unary(tonic::Request::new(body.clone()), path, PreEncoded)
                    .await
                {
                    Ok(_) => "OK".to_string(),
                    Err(s) => format!("{:?}", s.code()),
                }
            }
            Client::Http {
                client,
                url,
                body,
                content_type,
            } => match client
                .post(url.as_str())
                .header("content-type", *content_type)
                .body(body.clone())
                .send()
                .await
            {
                Ok(r) if r.status().is_success() => match r.bytes().await {
                    Ok(_) => "OK".to_string(),
                    Err(e) => format!("body: {e}"),
                },
                Ok(r) => format!("HTTP {}", r.status().as_u16()),
                Err(e) => format!(
                    "transport: {}",
                    if e.is_connect() { "connect" } else { "error" }
                ),
            },
            Client::InProcess(service) => {
                let request = request.clone();
                match service
                    .match_within(move || Ok(request), |_| (), None)
                    .await
                {
                    Ok(_) => "OK".to_string(),
                    Err(e) => format!("{:?}", e.code()),
                }
            }
        }
    }
}

fn percentile(sorted: &[Duration], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i].as_secs_f64() * 1e3
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let text = std::fs::read_to_string(&args.request)
        .with_context(|| format!("cannot read {}", args.request.display()))?;
    let request: pb::MatchRequest = api::from_json("request", &text)?;
    let client = if let Some(addr) = args.target.strip_prefix("grpc://") {
        let channel = tonic::transport::Channel::from_shared(format!("http://{addr}"))?
            // As the server: wide HTTP/2 windows, so large answers need no WINDOW_UPDATE wait.
            .initial_stream_window_size(Some(4 << 20))
            .initial_connection_window_size(Some(16 << 20))
            .max_frame_size(Some(1 << 20))
            .connect()
            .await
            .context("cannot connect")?;
        Client::Grpc {
            grpc: tonic::client::Grpc::new(channel)
                .max_decoding_message_size(64 << 20)
                .max_encoding_message_size(64 << 20),
            body: request.encode_to_vec().into(),
        }
    } else if args.target.starts_with("http://") {
        let (body, content_type) = if args.http_json {
            (api::to_json(&request).into_bytes(), "application/json")
        } else {
            (request.encode_to_vec(), "application/x-protobuf")
        };
        Client::Http {
            client: reqwest::Client::new(),
            url: format!("{}/v1/match", args.target.trim_end_matches('/')),
            body,
            content_type,
        }
    } else if let Some(threads) = args.target.strip_prefix("inproc://") {
        let threads: usize = threads
            .parse()
            .context("inproc://THREADS needs a number of threads")?;
        let limits = Limits {
            threads,
            max_jobs: trinocular_server::service::JOBS_PER_THREAD * threads,
            ..Limits::default()
        };
        let ttl = Duration::from_secs(60);
        let store = Arc::new(MemoryStore::new(ttl));
        Client::InProcess(Arc::new(Service::new(limits, store, ttl)?))
    } else {
        bail!("--target must start with grpc://, http:// or inproc://");
    };
    let duration = Duration::from_secs_f64(args.duration_s.max(0.1));
    let outcomes: Arc<Mutex<Vec<Outcome>>> = Arc::default();
    let request = Arc::new(request);
    let start = Instant::now();
    let mode;
    match (args.concurrency, args.rate) {
        (_, Some(rate)) if rate > 0.0 => {
            mode = format!("open loop, {rate} requests/s");
            let interval = Duration::from_secs_f64(1.0 / rate);
            let mut tasks = Vec::new();
            let mut k = 0u64;
            loop {
                let intended = start + interval.mul_f64(k as f64);
                if intended - start >= duration {
                    break;
                }
                tokio::time::sleep_until(intended.into()).await;
                let (mut c, r, out) = (client.clone(), Arc::clone(&request), Arc::clone(&outcomes));
                tasks.push(tokio::spawn(async move {
                    let result = c.send(&r).await;
                    out.lock().unwrap().push((intended.elapsed(), result));
                }));
                k += 1;
            }
            for t in tasks {
                t.await?;
            }
        }
        (Some(n), None) if n > 0 => {
            mode = format!("closed loop, concurrency {n}");
            let mut tasks = Vec::new();
            for _ in 0..n {
                let (mut c, r, out) = (client.clone(), Arc::clone(&request), Arc::clone(&outcomes));
                tasks.push(tokio::spawn(async move {
                    while start.elapsed() < duration {
                        let t0 = Instant::now();
                        let result = c.send(&r).await;
                        out.lock().unwrap().push((t0.elapsed(), result));
                    }
                }));
            }
            for t in tasks {
                t.await?;
            }
        }
        _ => bail!("give --concurrency N (> 0) or --rate R (> 0)"),
    }
    let elapsed = start.elapsed().as_secs_f64();
    let outcomes = std::mem::take(&mut *outcomes.lock().unwrap());
    let mut by_code: BTreeMap<String, usize> = BTreeMap::new();
    let mut ok: Vec<Duration> = Vec::new();
    for (latency, code) in &outcomes {
        *by_code.entry(code.clone()).or_default() += 1;
        if code == "OK" {
            ok.push(*latency);
        }
    }
    ok.sort();
    let summary = serde_json::json!({
        "target": args.target,
        "mode": mode,
        "seconds": elapsed,
        "requests": outcomes.len(),
        "ok": ok.len(),
        "throughput_per_s": ok.len() as f64 / elapsed,
        "latency_ms": {
            "p50": percentile(&ok, 0.5), "p90": percentile(&ok, 0.9),
            "p99": percentile(&ok, 0.99), "max": percentile(&ok, 1.0),
        },
        "by_code": by_code,
    });
    let text = if args.json {
        summary.to_string()
    } else {
        format!(
            "{} ({mode}): {} requests in {elapsed:.1} s, {} ok, {:.1}/s\n\
             latency of ok requests, ms: p50 {:.2}  p90 {:.2}  p99 {:.2}  max {:.2}\n\
             by code: {by_code:?}",
            args.target,
            outcomes.len(),
            ok.len(),
            ok.len() as f64 / elapsed,
            percentile(&ok, 0.5),
            percentile(&ok, 0.9),
            percentile(&ok, 0.99),
            percentile(&ok, 1.0),
        )
    };
    // A reader that stopped early (`| head -1`) is not an error of the run.
    let _ = writeln!(std::io::stdout(), "{text}");
    Ok(())
}
