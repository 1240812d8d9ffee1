//! The service over real sockets: a server on ephemeral ports, a tonic client and an HTTP
//! client, the same requests through both.

use std::sync::Arc;

use prost::Message;
use trinocular::api::{self, pb, RunMatch};
use trinocular::service::{server, Limits};

use crate::common::{example_request, metrics_text, post_protobuf, runtime, JsonBody};

async fn start(limits: Limits) -> server::Running {
    let any = "127.0.0.1:0".parse().unwrap();
    server::start(crate::common::embedded_service(limits).await, any, any)
        .await
        .expect("listen")
}

async fn grpc_client(
    running: &server::Running,
) -> pb::trinocular_client::TrinocularClient<tonic::transport::Channel> {
    crate::common::grpc_connect(format!("http://{}", running.grpc_addr))
        .await
        .expect("connect")
}

fn small_limits() -> Limits {
    Limits {
        threads: 2,
        max_jobs: 8,
        ..Limits::default()
    }
}

/// What must agree between transports: everything but the timings.
fn essence(r: &pb::MatchResponse) -> (Vec<pb::Triplet>, Vec<pb::Segment3>, u32) {
    (
        r.triplets.clone(),
        r.segments_3d.clone(),
        r.stats.as_ref().map_or(0, |s| s.hypotheses),
    )
}

#[test]
fn grpc_json_and_protobuf_over_http_give_the_same_match() {
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let request = example_request();

        let mut grpc = grpc_client(&running).await;
        let by_grpc = grpc
            .r#match(request.clone())
            .await
            .expect("ok")
            .into_inner();
        assert!(by_grpc.segments_3d.len() > 10);

        let http = reqwest::Client::new();
        let url = format!("http://{}/v1/match", running.http_addr);
        let json = http
            .post(&url)
            .header("content-type", "application/json")
            .body(api::to_json(&request))
            .send()
            .await
            .expect("sent");
        assert_eq!(json.status(), 200);
        let by_json: pb::MatchResponse =
            serde_json::from_str(&json.text().await.unwrap()).expect("a MatchResponse");

        let proto = post_protobuf(&http, &url, &request)
            .send()
            .await
            .expect("sent");
        assert_eq!(proto.status(), 200);
        assert_eq!(
            proto.headers()["content-type"].to_str().unwrap(),
            "application/x-protobuf"
        );
        let by_proto = pb::MatchResponse::decode(proto.bytes().await.unwrap()).expect("protobuf");

        // The library itself, for reference.
        let direct = api::match_request(&request, &Default::default())
            .unwrap()
            .run()
            .unwrap();
        assert_eq!(essence(&by_grpc), essence(&direct));
        assert_eq!(essence(&by_json), essence(&direct));
        assert_eq!(essence(&by_proto), essence(&direct));
        running.shutdown().await;
    });
}

/// `text` with the value of every `"…Ms": number` (timings, which differ from run to run)
/// replaced by 0; everything else kept byte for byte.
fn without_timings(text: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let is_timing = line
            .trim_start()
            .split_once("Ms\": ")
            .is_some_and(|(key, _)| key.starts_with('"') && !key.contains(' '));
        if is_timing {
            let (key, value) = line.split_once(": ").unwrap();
            let comma = if value.ends_with(',') { "," } else { "" };
            out.push_str(&format!("{key}: 0{comma}"));
        } else {
            out.push_str(line);
        }
        out.push('\n');
    }
    out
}

#[test]
fn http_json_is_the_clis_json_byte_for_byte_but_for_timings() {
    let dir = std::env::temp_dir().join(format!("trinocular-cli-json-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("request.json");
    let request = api::to_json(&example_request());
    std::fs::write(&path, &request).unwrap();
    let cli = std::process::Command::new(env!("CARGO_BIN_EXE_trinocular"))
        .arg("match")
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        cli.status.success(),
        "{}",
        String::from_utf8_lossy(&cli.stderr)
    );
    let cli = String::from_utf8(cli.stdout).unwrap();
    let _ = std::fs::remove_dir_all(&dir);

    let http = runtime().block_on(async {
        let running = start(small_limits()).await;
        let text = reqwest::Client::new()
            .post(format!("http://{}/v1/match", running.http_addr))
            .header("content-type", "application/json")
            .body(request)
            .send()
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        running.shutdown().await;
        text
    });
    assert!(
        cli.contains("\"totalMs\": "),
        "the comparison must see the timings to blank them"
    );
    assert_eq!(without_timings(&http), without_timings(&cli));
}

#[test]
fn bad_input_is_invalid_argument_naming_the_field_on_both_transports() {
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let mut request = example_request();
        request.calibration.as_mut().unwrap().cameras[2].projection[0] = f64::NAN;

        let mut grpc = grpc_client(&running).await;
        let status = grpc.r#match(request.clone()).await.unwrap_err();
        crate::common::assert_invalid_argument_naming(&status, "calibration.cameras[2].projection");

        let http = reqwest::Client::new();
        let url = format!("http://{}/v1/match", running.http_addr);
        // proto3 JSON spells NaN "NaN" (pbjson writes repeated NaNs as null: set it by hand).
        let mut json: serde_json::Value = serde_json::from_str(&api::to_json(&request)).unwrap();
        json["calibration"]["cameras"][2]["projection"][0] = "NaN".into();
        let reply = http
            .post(&url)
            .header("content-type", "application/json")
            .body(json.to_string())
            .send()
            .await
            .unwrap();
        assert_eq!(reply.status(), 400);
        let body: serde_json::Value = reply.json_body().await;
        assert_eq!(body["error"]["code"], "INVALID_ARGUMENT");
        assert_eq!(body["error"]["field"], "calibration.cameras[2].projection");

        // A body that does not parse: the field where it stops, or the request when it
        // stops nowhere in particular.
        for (content_type, bytes, field) in [
            (
                "application/json",
                b"{\"calibration\": [1, 2".to_vec(),
                "calibration",
            ),
            (
                "application/json",
                b"{\"calibration\": {\"cameras\": [{\"width\": -1}]}}".to_vec(),
                "calibration.cameras[0].width",
            ),
            (
                "application/json",
                b"{\"options\": {\"maxDirectionSigmaDeg\": \"x\"}}".to_vec(),
                "options.max_direction_sigma_deg",
            ),
            (
                "application/json",
                b"{\"calibration\": ".to_vec(),
                "calibration",
            ),
            ("application/json", b"[".to_vec(), "request"),
            (
                "application/x-protobuf",
                vec![0x0a, 0xff, 0xff, 0xff],
                "calibration",
            ),
            ("application/x-protobuf", vec![0x00], "request"),
            ("application/json", vec![0xff, 0xfe], "request"),
        ] {
            let reply = http
                .post(&url)
                .header("content-type", content_type)
                .body(bytes)
                .send()
                .await
                .unwrap();
            assert_eq!(reply.status(), 400, "{content_type}");
            let body: serde_json::Value = reply.json_body().await;
            assert_eq!(body["error"]["field"], field, "{body}");
        }
        running.shutdown().await;
    });
}

#[test]
fn oversized_requests_are_refused() {
    runtime().block_on(async {
        let running = start(Limits {
            max_message_bytes: 4096,
            ..small_limits()
        })
        .await;
        let request = example_request();
        assert!(request.encoded_len() > 4096);
        let reply = post_protobuf(
            &reqwest::Client::new(),
            format!("http://{}/v1/match", running.http_addr),
            &request,
        )
        .send()
        .await
        .unwrap();
        assert_eq!(reply.status(), 413);
        let body = reply.json_body().await;
        assert_eq!(body["error"]["code"], "OUT_OF_RANGE");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(
            message.contains("4096 bytes (limits.max_message_mib)"),
            "{message}"
        );

        // The same through a curl-style upload.
        let form = reqwest::multipart::Form::new()
            .text("calibration", "{}")
            .part("image1", reqwest::multipart::Part::bytes(vec![0u8; 8000]));
        let reply = reqwest::Client::new()
            .post(format!("http://{}/v1/match", running.http_addr))
            .multipart(form)
            .send()
            .await
            .unwrap();
        assert_eq!(reply.status(), 413);

        let mut grpc = grpc_client(&running).await;
        let status = grpc.r#match(request).await.unwrap_err();
        assert_eq!(status.code(), tonic::Code::OutOfRange, "{status:?}");
        assert!(status.message().contains("4096"), "{status:?}");
        running.shutdown().await;
    });
}

#[test]
fn too_many_segments_in_a_list_is_refused_naming_the_list_and_the_limit() {
    runtime().block_on(async {
        let running = start(Limits {
            max_segments_per_list: 10,
            ..small_limits()
        })
        .await;
        let request = example_request();
        let mut grpc = grpc_client(&running).await;
        let status = grpc.r#match(request.clone()).await.unwrap_err();
        assert_eq!(status.code(), tonic::Code::InvalidArgument, "{status:?}");
        assert!(
            status.message().starts_with("segments.lists[0].segments: ")
                && status
                    .message()
                    .contains("limit of 10 per list (limits.max_segments_per_list)"),
            "{status:?}"
        );
        let reply = post_protobuf(
            &reqwest::Client::new(),
            format!("http://{}/v1/match", running.http_addr),
            &request,
        )
        .send()
        .await
        .unwrap();
        assert_eq!(reply.status(), 400);
        assert_eq!(
            reply.json_body().await["error"]["field"],
            "segments.lists[0].segments"
        );
        running.shutdown().await;
    });
}

#[test]
fn health_and_readiness() {
    runtime().block_on(async {
        let service = crate::common::embedded_service(small_limits()).await;
        let any = "127.0.0.1:0".parse().unwrap();
        let running = server::start(Arc::clone(&service), any, any).await.unwrap();
        let http = reqwest::Client::new();
        let get = |path: &str| {
            http.get(format!("http://{}{path}", running.http_addr))
                .send()
        };
        // What the Kubernetes gRPC readiness probe asks: grpc.health.v1 for the service "".
        let channel = crate::common::grpc_channel(running.grpc_addr).await;
        let health = tonic_health::pb::health_client::HealthClient::new(channel);
        let grpc_ready_becomes = |want: tonic_health::pb::health_check_response::ServingStatus| {
            let mut health = health.clone();
            async move {
                // The watchdog passes readiness on every 500 ms.
                for _ in 0..40 {
                    let status = health
                        .check(tonic_health::pb::HealthCheckRequest {
                            service: String::new(),
                        })
                        .await
                        .unwrap()
                        .into_inner()
                        .status();
                    if status == want {
                        return true;
                    }
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
                false
            }
        };
        use tonic_health::pb::health_check_response::ServingStatus;
        assert_eq!(get("/healthz").await.unwrap().status(), 200);
        assert_eq!(get("/readyz").await.unwrap().status(), 200);
        assert!(grpc_ready_becomes(ServingStatus::Serving).await);
        service.set_ready(false);
        assert_eq!(get("/readyz").await.unwrap().status(), 503);
        assert_eq!(get("/healthz").await.unwrap().status(), 200);
        assert!(
            grpc_ready_becomes(ServingStatus::NotServing).await,
            "gRPC health \"\" must follow /readyz"
        );
        service.set_ready(true);
        assert_eq!(get("/readyz").await.unwrap().status(), 200);
        assert!(grpc_ready_becomes(ServingStatus::Serving).await);
        running.shutdown().await;
    });
}

/// The grpcurl binary: `$GRPCURL`, or `grpcurl` on the PATH (`.ci/run` installs one).
fn grpcurl() -> Option<std::path::PathBuf> {
    if let Some(path) = std::env::var_os("GRPCURL") {
        return Some(path.into());
    }
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|dir| dir.join("grpcurl"))
            .find(|p| p.is_file())
    })
}

#[test]
fn the_readmes_grpcurl_commands_work() {
    let Some(grpcurl) = grpcurl() else {
        eprintln!("SKIPPED the_readmes_grpcurl_commands_work: no grpcurl (set GRPCURL or put it on the PATH; .ci/run installs one)");
        return;
    };
    let rt = runtime();
    let running = rt.block_on(start(small_limits()));
    let addr = running.grpc_addr.to_string();
    let run = |args: &[&str], stdin: Option<&str>| -> String {
        use std::io::Write;
        let mut child = std::process::Command::new(&grpcurl)
            .arg("-plaintext")
            .args(args)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("grpcurl runs");
        let mut input = child.stdin.take().unwrap();
        input.write_all(stdin.unwrap_or("").as_bytes()).unwrap();
        drop(input);
        let out = child.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "grpcurl {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    let list = run(&[&addr, "list"], None);
    assert!(
        list.lines().any(|l| l == "trinocular.v1.Trinocular"),
        "{list}"
    );
    assert!(list.lines().any(|l| l == "grpc.health.v1.Health"), "{list}");
    let describe = run(&[&addr, "describe", "trinocular.v1.Trinocular"], None);
    assert!(
        describe.contains(
            "rpc Match ( .trinocular.v1.MatchRequest ) returns ( .trinocular.v1.MatchResponse )"
        ),
        "{describe}"
    );
    let request = api::to_json(&example_request());
    let reply = run(
        &["-d", "@", &addr, "trinocular.v1.Trinocular/Match"],
        Some(&request),
    );
    let reply: pb::MatchResponse =
        api::from_json("reply", &reply).expect("a MatchResponse in JSON");
    let direct = api::match_request(&example_request(), &Default::default())
        .unwrap()
        .run()
        .unwrap();
    assert_eq!(essence(&reply), essence(&direct));
    let health = run(&[&addr, "grpc.health.v1.Health/Check"], None);
    assert!(health.contains("SERVING"), "{health}");
    rt.block_on(running.shutdown());
}

#[test]
fn grpc_health_and_reflection_work_like_grpcurl_expects() {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::{health_check_response::ServingStatus, health_client::HealthClient};
    use tonic_reflection::pb::v1::{
        server_reflection_client::ServerReflectionClient,
        server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
        ServerReflectionRequest,
    };
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let channel = crate::common::grpc_channel(running.grpc_addr).await;
        let mut health = HealthClient::new(channel.clone());
        for service in ["", "trinocular.v1.Trinocular"] {
            let reply = health
                .check(HealthCheckRequest {
                    service: service.to_string(),
                })
                .await
                .unwrap()
                .into_inner();
            assert_eq!(reply.status(), ServingStatus::Serving, "{service:?}");
        }

        let mut reflection = ServerReflectionClient::new(channel);
        let request = ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let mut replies = reflection
            .server_reflection_info(tokio_stream_once(request))
            .await
            .unwrap()
            .into_inner();
        let reply = replies.message().await.unwrap().expect("a reply");
        let Some(MessageResponse::ListServicesResponse(list)) = reply.message_response else {
            panic!("not a service list: {reply:?}");
        };
        let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
        assert!(
            names.contains(&"trinocular.v1.Trinocular".to_string()),
            "{names:?}"
        );
        running.shutdown().await;
    });
}

/// A one-message request stream.
fn tokio_stream_once<T: Send + 'static>(item: T) -> impl tonic::IntoStreamingRequest<Message = T> {
    futures_once(item)
}

fn futures_once<T>(item: T) -> impl futures_core::Stream<Item = T> {
    struct Once<T>(Option<T>);
    impl<T> Unpin for Once<T> {}
    impl<T> futures_core::Stream for Once<T> {
        type Item = T;
        fn poll_next(
            mut self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<Option<T>> {
            std::task::Poll::Ready(self.0.take())
        }
    }
    Once(Some(item))
}

/// A request that takes a while (about 100 ms): 10,000 segments per image to match.
fn slow_request() -> pb::MatchRequest {
    let (rig, lists) = trinocular::synth::scattered_capture(10_000, 0.3, 0.2, 1);
    pb::MatchRequest {
        calibration: Some(api::calibration_to_pb(&rig)),
        options: None,
        input: Some(pb::match_request::Input::Segments(pb::SegmentTriplet {
            lists: lists.iter().map(api::segment_list_to_pb).collect(),
        })),
    }
}

#[test]
fn deadlines_are_honoured_on_both_transports() {
    runtime().block_on(async {
        // One compute thread, kept busy by a slow request: small requests with a deadline
        // wait in the queue, and the deadline passes there, whatever the machine's speed.
        let running = start(Limits {
            threads: 1,
            ..small_limits()
        })
        .await;
        let http = reqwest::Client::new();
        let url = format!("http://{}/v1/match", running.http_addr);
        let slow = tokio::spawn(post_protobuf(&http, url.clone(), &slow_request()).send());
        tokio::time::sleep(std::time::Duration::from_millis(30)).await;
        let small = example_request();

        let reply = post_protobuf(&http, format!("{url}?timeout_ms=10"), &small)
            .send()
            .await
            .unwrap();
        assert_eq!(reply.status(), 504);
        let body: serde_json::Value = reply.json_body().await;
        assert_eq!(body["error"]["code"], "DEADLINE_EXCEEDED");

        let mut grpc = grpc_client(&running).await;
        let mut call = tonic::Request::new(small.clone());
        call.set_timeout(std::time::Duration::from_millis(40));
        let t0 = std::time::Instant::now();
        let status = grpc.r#match(call).await.unwrap_err();
        // The server answers DEADLINE_EXCEEDED just before the deadline; a tonic client,
        // though, reports a call whose deadline it set as CANCELLED "Timeout expired" (its own
        // timeout layer), where other gRPC clients report DEADLINE_EXCEEDED. Either way the call
        // ends at its deadline, long before the queue ahead of it drains.
        assert!(
            status.code() == tonic::Code::DeadlineExceeded
                || (status.code() == tonic::Code::Cancelled
                    && status.message() == "Timeout expired"),
            "{status:?}"
        );
        assert!(
            t0.elapsed() < std::time::Duration::from_millis(60),
            "{:?}",
            t0.elapsed()
        );

        // A deadline that does not parse, or one misspelt (not silently dropped), is named.
        for (query, field) in [
            ("timeout_ms=soon", "timeout_ms"),
            ("timout_ms=10", "timout_ms"),
        ] {
            let bad = post_protobuf(&http, format!("{url}?{query}"), &small)
                .send()
                .await
                .unwrap();
            assert_eq!(bad.status(), 400, "{query}");
            assert_eq!(bad.json_body().await["error"]["field"], field);
        }

        // The slow one completes, and the service is fine afterwards.
        assert_eq!(slow.await.unwrap().unwrap().status(), 200);
        let ok = grpc.r#match(small).await.unwrap().into_inner();
        assert!(!ok.segments_3d.is_empty());
        running.shutdown().await;
    });
}

/// Polls `/metrics` until the count of jobs stopped early reaches `n` (or five seconds pass).
async fn stopped_jobs(http: &reqwest::Client, running: &server::Running, n: u64) -> u64 {
    let mut seen = 0;
    for _ in 0..500 {
        let text = metrics_text(http, running.http_addr).await;
        seen = text
            .lines()
            .filter(|l| l.starts_with("trinocular_jobs_stopped_total{"))
            .filter_map(|l| l.rsplit(' ').next()?.parse::<u64>().ok())
            .sum();
        if seen >= n {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    seen
}

#[test]
fn a_running_job_stops_between_stages_once_nobody_waits() {
    runtime().block_on(async {
        let running = start(Limits {
            threads: 1,
            ..small_limits()
        })
        .await;
        let http = reqwest::Client::new();
        let url = format!("http://{}/v1/match", running.http_addr);
        let slow = slow_request().encode_to_vec();

        // Its deadline passes while it runs: 504, and the job stops at its next checkpoint.
        // (50 ms: long enough for the job to have started on a loaded machine, far shorter
        // than it runs.)
        let reply = http
            .post(format!("{url}?timeout_ms=50"))
            .header("content-type", "application/x-protobuf")
            .body(slow.clone())
            .send()
            .await
            .unwrap();
        assert_eq!(reply.status(), 504);
        assert_eq!(stopped_jobs(&http, &running, 1).await, 1);

        // The client hangs up while it runs: the same.
        let gone = http
            .post(url.clone())
            .header("content-type", "application/x-protobuf")
            .body(slow)
            .timeout(std::time::Duration::from_millis(20))
            .send()
            .await;
        assert!(gone.unwrap_err().is_timeout());
        assert_eq!(stopped_jobs(&http, &running, 2).await, 2);

        // Nothing else noticed: the next request is answered.
        let mut grpc = grpc_client(&running).await;
        let ok = grpc.r#match(example_request()).await.unwrap().into_inner();
        assert!(!ok.segments_3d.is_empty());
        running.shutdown().await;
    });
}

#[test]
fn curl_style_multipart_uploads_match_images() {
    use reqwest::multipart::{Form, Part};
    use trinocular::synth::{render_triplet, standard_capture, Defects, RenderParams};
    let (scene, rig, _) = standard_capture(1, Defects::clean(), false);
    let images = render_triplet(&scene, &rig, &RenderParams::default(), 1);
    let png = |i: usize| trinocular::overlay::grey_png(&images[i]).unwrap();
    let calibration = api::to_json(&api::calibration_to_pb(&rig));
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let url = format!("http://{}/v1/match", running.http_addr);
        let http = reqwest::Client::new();
        let form = |parts: &[usize], extra: Option<(&str, String)>| {
            let mut f = Form::new().text("calibration", calibration.clone());
            for &i in parts {
                let name = format!("image{}", i + 1);
                f = f.part(
                    name.clone(),
                    Part::bytes(png(i)).file_name(format!("{name}.png")),
                );
            }
            if let Some((name, value)) = extra {
                f = f.text(name.to_string(), value);
            }
            f
        };
        let reply = http
            .post(&url)
            .multipart(form(
                &[0, 1, 2],
                Some((
                    "options",
                    "{\"returnExtracted\": true, \"includeUncertain\": true}".into(),
                )),
            ))
            .send()
            .await
            .unwrap();
        assert_eq!(reply.status(), 200);
        let response: pb::MatchResponse =
            serde_json::from_str(&reply.text().await.unwrap()).unwrap();
        assert!(response.segments_3d.len() > 100);
        assert_eq!(response.extracted.len(), 3);

        let missing = http
            .post(&url)
            .multipart(form(&[0, 1], None))
            .send()
            .await
            .unwrap();
        assert_eq!(missing.status(), 400);
        assert_eq!(missing.json_body().await["error"]["field"], "images");
        let unknown = http
            .post(&url)
            .multipart(form(&[0, 1, 2], Some(("picture", "x".into()))))
            .send()
            .await
            .unwrap();
        assert_eq!(unknown.status(), 400);
        assert_eq!(unknown.json_body().await["error"]["field"], "picture");
        // A part sent twice is refused, not silently replaced by the second.
        let twice = http
            .post(&url)
            .multipart(form(&[0, 1, 2, 1], None))
            .send()
            .await
            .unwrap();
        assert_eq!(twice.status(), 400);
        let body = twice.json_body().await;
        assert_eq!(body["error"]["field"], "image2");
        assert!(
            body["error"]["message"].as_str().unwrap().contains("twice"),
            "{body}"
        );
        running.shutdown().await;
    });
}

#[test]
fn metrics_count_requests_by_transport_and_code() {
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let mut grpc = grpc_client(&running).await;
        grpc.r#match(example_request()).await.unwrap();
        let http = reqwest::Client::new();
        let reply = http
            .post(format!("http://{}/v1/match", running.http_addr))
            .body("{not json")
            .send()
            .await
            .unwrap();
        assert_eq!(reply.status(), 400);
        let text = metrics_text(&http, running.http_addr).await;
        let has = |line: &str| text.lines().any(|l| l == line);
        assert!(
            has(r#"trinocular_requests_total{code="OK",route="match",transport="grpc"} 1"#),
            "{text}"
        );
        assert!(
            has(r#"trinocular_requests_total{code="INVALID_ARGUMENT",route="match",transport="http"} 1"#),
            "{text}"
        );
        assert!(has(r#"trinocular_request_duration_seconds_count{route="match",transport="grpc"} 1"#));
        assert!(text.contains(r#"trinocular_stage_duration_seconds_count{stage="predict"} 1"#));
        assert!(has("trinocular_jobs_in_flight 0"));
        // What is running and what it costs the machine.
        assert!(has(&format!(
            r#"trinocular_build_info{{version="{}"}} 1"#,
            env!("CARGO_PKG_VERSION")
        )));
        for process in ["process_resident_memory_bytes", "process_cpu_seconds_total", "process_open_fds"] {
            assert!(text.lines().any(|l| l.starts_with(process)), "{process} missing");
        }
        assert!(has("trinocular_jobs_max 8"));
        assert!(has("trinocular_rejections_total 0"));
        running.shutdown().await;
    });
}

#[test]
fn each_request_is_counted_once_under_its_transport_route_and_code() {
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let mut grpc = grpc_client(&running).await;
        grpc.create_session(pb::CreateSessionRequest {
            name: "room".into(),
            calibration: example_request().calibration,
            options: None,
            map_options: None, session_id: String::new(), })
        .await
        .unwrap();
        let bad_id = pb::GetSessionRequest {
            session_id: "not an id!".into(),
        };
        assert_eq!(
            grpc.get_session(bad_id).await.unwrap_err().code(),
            tonic::Code::InvalidArgument
        );
        let http = reqwest::Client::new();
        let url = |path: &str| format!("http://{}{path}", running.http_addr);
        let status = |r: reqwest::Response| r.status().as_u16();
        assert_eq!(status(http.get(url("/v1/sessions")).send().await.unwrap()), 200);
        let missing = http.get(url("/v1/sessions/nope")).send().await.unwrap();
        assert_eq!(status(missing), 404);
        let unread = http.post(url("/v1/calibrate")).body("{").send().await.unwrap();
        assert_eq!(status(unread), 400);
        // Off the API: the probes, and paths the router does not serve, are not counted.
        assert_eq!(status(http.get(url("/healthz")).send().await.unwrap()), 200);
        let nowhere = http.get(url("/v2/nothing")).send().await.unwrap();
        assert_eq!(status(nowhere), 404);
        // …and answer in the API's error format, as a wrong method does.
        let nowhere: serde_json::Value =
            serde_json::from_str(&http.get(url("/v2/nothing")).send().await.unwrap().text().await.unwrap())
                .unwrap();
        assert_eq!(nowhere["error"]["code"], "NOT_FOUND", "{nowhere}");
        // A long path is not repeated whole (it was, into the answer and every log line).
        let long = format!("/v2/{}", "a".repeat(20_000));
        let answer = http.get(url(&long)).send().await.unwrap().text().await.unwrap();
        assert!(answer.len() < 1000 && answer.contains('…'), "{} bytes", answer.len());
        let wrong = http.delete(url("/v1/match")).send().await.unwrap();
        assert_eq!(status(wrong), 405);
        let wrong: serde_json::Value =
            serde_json::from_str(&http.delete(url("/v1/match")).send().await.unwrap().text().await.unwrap())
                .unwrap();
        assert_eq!(wrong["error"]["field"], "method", "{wrong}");

        let text = http.get(url("/metrics")).send().await.unwrap().text().await.unwrap();
        let counted: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with("trinocular_requests_total{"))
            .collect();
        let mut expected = [
            r#"trinocular_requests_total{code="OK",route="create_session",transport="grpc"} 1"#,
            r#"trinocular_requests_total{code="INVALID_ARGUMENT",route="get_session",transport="grpc"} 1"#,
            r#"trinocular_requests_total{code="OK",route="list_sessions",transport="http"} 1"#,
            r#"trinocular_requests_total{code="NOT_FOUND",route="get_session",transport="http"} 1"#,
            r#"trinocular_requests_total{code="INVALID_ARGUMENT",route="calibrate",transport="http"} 1"#,
        ];
        let mut counted_sorted = counted.clone();
        counted_sorted.sort_unstable();
        expected.sort_unstable();
        assert_eq!(counted_sorted, expected, "{text}");
        assert!(
            text.contains(r#"trinocular_request_duration_seconds_count{route="get_session",transport="http"} 1"#),
            "{text}"
        );
        running.shutdown().await;
    });
}

#[test]
fn request_ids_are_echoed_on_both_transports() {
    runtime().block_on(async {
        let running = start(small_limits()).await;
        let http = reqwest::Client::new();
        let url = format!("http://{}/v1/match", running.http_addr);
        let given = http
            .post(&url)
            .header("x-request-id", "robot-42")
            .body(api::to_json(&example_request()))
            .send()
            .await
            .unwrap();
        assert_eq!(given.headers()["x-request-id"], "robot-42");
        let made = http.post(&url).body("{").send().await.unwrap();
        assert_eq!(made.status(), 400);
        let id = made.headers()["x-request-id"].to_str().unwrap().to_string();
        assert!(!id.is_empty() && id != "robot-42");

        let mut grpc = grpc_client(&running).await;
        let mut call = tonic::Request::new(example_request());
        call.metadata_mut()
            .insert("x-request-id", "robot-43".parse().unwrap());
        let reply = grpc.r#match(call).await.unwrap();
        assert_eq!(reply.metadata().get("x-request-id").unwrap(), "robot-43");
        let mut bad = example_request();
        bad.calibration = None;
        let status = grpc.r#match(bad).await.unwrap_err();
        assert!(status.metadata().get("x-request-id").is_some());

        // An id that is not 1 to 128 printable characters is replaced by a new one, on both
        // transports; a call without one gets one too.
        for unacceptable in ["has spaces", &"x".repeat(129)] {
            let replaced = http
                .post(&url)
                .header("x-request-id", unacceptable)
                .body("{")
                .send()
                .await
                .unwrap();
            let id = replaced.headers()["x-request-id"].to_str().unwrap();
            assert!(
                !id.is_empty() && id != unacceptable && !id.contains(' '),
                "{id}"
            );
            let mut call = tonic::Request::new(example_request());
            call.metadata_mut()
                .insert("x-request-id", unacceptable.parse().unwrap());
            let reply = grpc.r#match(call).await.unwrap();
            let id = reply
                .metadata()
                .get("x-request-id")
                .unwrap()
                .to_str()
                .unwrap();
            assert!(!id.is_empty() && id != unacceptable, "{id}");
        }
        let reply = grpc.r#match(example_request()).await.unwrap();
        let made = reply
            .metadata()
            .get("x-request-id")
            .unwrap()
            .to_str()
            .unwrap();
        assert!(!made.is_empty() && made != "robot-43");
        running.shutdown().await;
    });
}
