//! TLS on both ports, driven as docs/HARDENING.md shows: `trinocular serve --tls-cert
//! --tls-key` with a certificate for `localhost`, and each documented client form (reqwest and
//! tonic here; curl and grpcurl when present; the Python client in its own tests).

use std::io::Write;
use std::path::{Path, PathBuf};

use trinocular::api::{self, pb};

use crate::common::{example_request, runtime, scratch_dir, JsonBody, ServerProcess};

/// A self-signed certificate for `localhost` and 127.0.0.1, written as PEM files; the
/// certificate is also the clients' root.
struct TestCertificate {
    cert_file: PathBuf,
    key_file: PathBuf,
    cert_pem: String,
}

fn certificate(dir: &Path) -> TestCertificate {
    let rcgen::CertifiedKey { cert, signing_key } =
        rcgen::generate_simple_self_signed(vec!["localhost".to_string(), "127.0.0.1".to_string()])
            .expect("a certificate");
    let (cert_file, key_file) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&cert_file, cert.pem()).unwrap();
    std::fs::write(&key_file, signing_key.serialize_pem()).unwrap();
    TestCertificate {
        cert_file,
        key_file,
        cert_pem: cert.pem(),
    }
}

const KEY: &str = "tls-test-key-0123456789abcdef";

fn tls_server(cert: &TestCertificate) -> ServerProcess {
    ServerProcess::spawn_with_env(
        &[
            "--store",
            "memory",
            "--tls-cert",
            cert.cert_file.to_str().unwrap(),
            "--tls-key",
            cert.key_file.to_str().unwrap(),
        ],
        &[("TRINOCULAR_API_KEYS", &format!("robot:{KEY}"))],
    )
}

#[test]
fn both_ports_serve_tls_to_clients_that_trust_the_certificate_and_nothing_in_clear() {
    let dir = scratch_dir("tls");
    let cert = certificate(&dir);
    let server = tls_server(&cert);
    let rt = runtime();
    rt.block_on(async {
        // HTTP: HTTPS with the certificate as root; ALPN picks HTTP/2 or HTTP/1.1.
        for http2 in [false, true] {
            let mut builder = reqwest::Client::builder()
                .add_root_certificate(
                    reqwest::Certificate::from_pem(cert.cert_pem.as_bytes()).unwrap(),
                )
                .resolve("localhost", server.http_addr);
            if !http2 {
                builder = builder.http1_only();
            }
            let https = builder.build().unwrap();
            let url = format!("https://localhost:{}", server.http_addr.port());
            let ready = https
                .get(format!("{url}/readyz"))
                .send()
                .await
                .expect("HTTPS");
            assert_eq!(ready.status(), 200);
            let expected = if http2 {
                reqwest::Version::HTTP_2
            } else {
                reqwest::Version::HTTP_11
            };
            assert_eq!(ready.version(), expected);
            let answer = https
                .post(format!("{url}/v1/match"))
                .bearer_auth(KEY)
                .header("content-type", "application/json")
                .body(api::to_json(&example_request()))
                .send()
                .await
                .unwrap();
            assert_eq!(answer.status(), 200);
            let body = answer.json_body().await;
            assert!(!body["segments3d"].as_array().unwrap().is_empty(), "{body}");
        }
        // A client that does not trust the certificate is refused at the handshake, and
        // plain HTTP on the TLS port gets no answer.
        let untrusting = reqwest::Client::builder()
            .resolve("localhost", server.http_addr)
            .tls_built_in_root_certs(false)
            .build()
            .unwrap();
        let url = format!("https://localhost:{}/readyz", server.http_addr.port());
        assert!(untrusting.get(&url).send().await.is_err());
        let plain = reqwest::Client::new()
            .get(format!("http://{}/readyz", server.http_addr))
            .send()
            .await;
        assert!(
            plain.as_ref().map_or(true, |r| r.status() != 200),
            "{plain:?}"
        );

        // gRPC: tonic over TLS, with the API key.
        let tls = tonic::transport::ClientTlsConfig::new()
            .ca_certificate(tonic::transport::Certificate::from_pem(&cert.cert_pem))
            .domain_name("localhost");
        let channel =
            tonic::transport::Channel::from_shared(format!("https://{}", server.grpc_addr))
                .unwrap()
                .tls_config(tls)
                .unwrap()
                .connect()
                .await
                .expect("gRPC over TLS");
        let mut client = pb::trinocular_client::TrinocularClient::new(channel);
        let mut request = tonic::Request::new(example_request());
        request
            .metadata_mut()
            .insert("authorization", format!("Bearer {KEY}").parse().unwrap());
        let answer = client.r#match(request).await.expect("Match over TLS");
        assert!(!answer.get_ref().segments_3d.is_empty());
        // Without TLS the gRPC port does not answer.
        let plain = crate::common::grpc_connect(format!("http://{}", server.grpc_addr)).await;
        if let Ok(mut plain) = plain {
            let mut request = tonic::Request::new(example_request());
            request.set_timeout(std::time::Duration::from_secs(5));
            assert!(plain.r#match(request).await.is_err());
        }
    });
}

#[test]
fn the_documented_curl_and_grpcurl_forms_work_over_tls() {
    let tools: Vec<(&str, Option<PathBuf>)> = vec![
        ("curl", on_path("curl")),
        (
            "grpcurl",
            std::env::var_os("GRPCURL")
                .map(PathBuf::from)
                .or_else(|| on_path("grpcurl")),
        ),
    ];
    for (name, path) in &tools {
        if path.is_none() {
            eprintln!("SKIPPED the {name} form in the_documented_curl_and_grpcurl_forms_work_over_tls: no {name} on the PATH (.ci/run installs both)");
        }
    }
    if tools.iter().all(|(_, p)| p.is_none()) {
        return;
    }
    let dir = scratch_dir("tls-tools");
    let cert = certificate(&dir);
    let server = tls_server(&cert);
    let request = api::to_json(&example_request());
    let run = |program: &Path, args: &[&str], stdin: &str| -> (bool, String, String) {
        let mut child = std::process::Command::new(program)
            .args(args)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("the tool runs");
        child
            .stdin
            .take()
            .unwrap()
            .write_all(stdin.as_bytes())
            .unwrap();
        let out = child.wait_with_output().unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let ca = cert.cert_file.to_str().unwrap();
    let auth = format!("authorization: Bearer {KEY}");
    if let (_, Some(curl)) = &tools[0] {
        let resolve = format!("localhost:{}:127.0.0.1", server.http_addr.port());
        let url = format!("https://localhost:{}/v1/match", server.http_addr.port());
        let (ok, out, err) = run(
            curl,
            &[
                "-sS",
                "--fail",
                "--cacert",
                ca,
                "--resolve",
                &resolve,
                "-H",
                &auth,
                "-H",
                "content-type: application/json",
                "--data-binary",
                "@-",
                &url,
            ],
            &request,
        );
        assert!(ok, "curl: {err}");
        let reply: pb::MatchResponse = api::from_json("reply", &out).expect("a MatchResponse");
        assert!(!reply.segments_3d.is_empty());
    }
    if let (_, Some(grpcurl)) = &tools[1] {
        let target = format!("localhost:{}", server.grpc_addr.port());
        let (ok, out, err) = run(
            grpcurl,
            &[
                "-cacert",
                ca,
                "-H",
                &auth,
                "-d",
                "@",
                &target,
                "trinocular.v1.Trinocular/Match",
            ],
            &request,
        );
        assert!(ok, "grpcurl: {err}");
        let reply: pb::MatchResponse = api::from_json("reply", &out).expect("a MatchResponse");
        assert!(!reply.segments_3d.is_empty());
        let (ok, _, _) = run(
            grpcurl,
            &["-plaintext", "-max-time", "3", &target, "list"],
            "",
        );
        assert!(!ok, "grpcurl -plaintext must fail against the TLS port");
    }
}

fn on_path(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|dir| dir.join(name))
            .find(|p| p.is_file())
    })
}

/// `trinocular serve` on ephemeral ports, to be given its TLS configuration.
fn serve_on_any_port() -> std::process::Command {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_trinocular"));
    command.args([
        "serve",
        "--store",
        "memory",
        "--grpc-addr",
        "127.0.0.1:0",
        "--http-addr",
        "127.0.0.1:0",
    ]);
    command
}

#[test]
fn a_key_that_is_not_the_certificates_stops_the_server_naming_both_files() {
    let dir = scratch_dir("tls-mismatch");
    let cert = certificate(&dir);
    let other = certificate(&scratch_dir("tls-other"));
    let out = serve_on_any_port()
        .args(["--tls-cert", cert.cert_file.to_str().unwrap()])
        .args(["--tls-key", other.key_file.to_str().unwrap()])
        .output()
        .expect("the binary runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(cert.cert_file.to_str().unwrap())
            && err.contains(other.key_file.to_str().unwrap()),
        "{err}"
    );
    // Half a configuration is refused before anything is read.
    let out = serve_on_any_port()
        .env("TRINOCULAR__TLS__CERT_FILE", &cert.cert_file)
        .output()
        .expect("the binary runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("tls.cert_file and tls.key_file go together"),
        "{err}"
    );
}
