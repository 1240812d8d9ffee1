//! Both servers on their listeners, stopped together: gRPC (tonic) and HTTP (axum) over the
//! same [`Service`].

use std::net::SocketAddr;
use std::sync::Arc;

use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tonic::transport::server::TcpIncoming;

use crate::service::Service;
use crate::tls::ServerTls;
use crate::{grpc, http};
use trinocular_schema::pb;

/// HTTP/2 flow-control windows of the gRPC server, bytes.
const H2_STREAM_WINDOW: u32 = 4 << 20;
const H2_CONNECTION_WINDOW: u32 = 16 << 20;
/// Largest HTTP/2 frame the gRPC server accepts, bytes: at the protocol's default 16 KiB a
/// 600-segment request arrives in six DATA frames and an image triplet in hundreds, each
/// framed and handled on its own.
const H2_MAX_FRAME: u32 = 1 << 20;

/// Concurrent calls on one gRPC connection.
const GRPC_MAX_STREAMS: u32 = 64;
/// How often the watchdog looks at the compute pool.
const WATCHDOG_PERIOD: std::time::Duration = std::time::Duration::from_millis(500);
/// The gRPC health name of the Trinocular service.
const TRINOCULAR_SERVICE: &str = "trinocular.v1.Trinocular";

/// Two running servers.
pub struct Running {
    pub grpc_addr: SocketAddr,
    pub http_addr: SocketAddr,
    health: tonic_health::server::HealthReporter,
    stop: watch::Sender<bool>,
    grpc: JoinHandle<Result<(), tonic::transport::Error>>,
    http: JoinHandle<std::io::Result<()>>,
    shutdown_grace: std::time::Duration,
}

/// Binds both addresses (port 0: any free port) and starts serving plain TCP.
pub async fn start(
    service: Arc<Service>,
    grpc_addr: SocketAddr,
    http_addr: SocketAddr,
) -> std::io::Result<Running> {
    start_with_tls(service, grpc_addr, http_addr, None).await
}

/// [`start`], with TLS on both ports when `tls` is given.
pub async fn start_with_tls(
    service: Arc<Service>,
    grpc_addr: SocketAddr,
    http_addr: SocketAddr,
    tls: Option<ServerTls>,
) -> std::io::Result<Running> {
    // A bind error names the address and its setting ("address already in use" alone does
    // not say which of the two ports is taken).
    let bind = |setting: &'static str, addr: SocketAddr| async move {
        TcpListener::bind(addr)
            .await
            .map_err(|e| std::io::Error::new(e.kind(), format!("{setting} {addr}: {e}")))
    };
    let grpc_listener = bind("grpc_addr", grpc_addr).await?;
    let http_listener = bind("http_addr", http_addr).await?;
    let (grpc_addr, http_addr) = (grpc_listener.local_addr()?, http_listener.local_addr()?);
    let (stop, _) = watch::channel(false);

    let max = service.limits().max_message_bytes;
    let grpc_service =
        pb::trinocular_server::TrinocularServer::new(grpc::GrpcApi::new(Arc::clone(&service)))
            .max_decoding_message_size(max)
            .max_encoding_message_size(max);
    // Standard health checking (overall "" and the service) and reflection, so grpcurl and
    // load balancers work without the .proto.
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_serving::<pb::trinocular_server::TrinocularServer<grpc::GrpcApi>>()
        .await;
    // Both reflection versions: grpcurl before 1.9 and many other tools only ask v1alpha.
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(trinocular_schema::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection().build_v1().map_err(std::io::Error::other)?;
    let reflection_v1alpha = reflection()
        .build_v1alpha()
        .map_err(std::io::Error::other)?;
    let mut grpc_stop = stop.subscribe();
    let connections = service.limits().connections;
    // A stalled or half-sent call ends with the longest a body may take plus the longest a
    // request may run (the compute deadline answers before that).
    let call_timeout = connections.body_timeout + service.limits().max_request_time;
    let mut grpc_server = tonic::transport::Server::builder();
    if let Some(tls) = &tls {
        grpc_server = grpc_server
            .tls_config(tls.grpc(connections.header_timeout))
            .map_err(std::io::Error::other)?;
    }
    let grpc = tokio::spawn(
        grpc_server
            .timeout(call_timeout)
            // Outermost: every call, refused ones too, has its id and span.
            .layer(crate::observe::grpc(Arc::clone(&service), grpc::route))
            // Each message's bytes come out of the same budget as HTTP bodies.
            .layer(crate::grpc_body::BodyBudgetLayer::new(Arc::clone(&service)))
            .http2_keepalive_interval(Some(connections.header_timeout))
            .http2_keepalive_timeout(Some(connections.header_timeout))
            .max_concurrent_streams(Some(GRPC_MAX_STREAMS))
            // HTTP/2's default 64 KiB windows make a client stop mid-request and wait a round
            // trip for WINDOW_UPDATE whenever a request is larger (600 segments per list are
            // 80 KiB, an image triplet megabytes): open them wide.
            .initial_stream_window_size(Some(H2_STREAM_WINDOW))
            .initial_connection_window_size(Some(H2_CONNECTION_WINDOW))
            .max_frame_size(Some(H2_MAX_FRAME))
            .add_service(health_service)
            .add_service(reflection_v1)
            .add_service(reflection_v1alpha)
            .add_service(grpc_service)
            .serve_with_incoming_shutdown(
                // Nagle and delayed ACKs would hold small answers for 40 ms.
                TcpIncoming::from(grpc_listener).with_nodelay(Some(true)),
                async move {
                    let _ = grpc_stop.wait_for(|&s| s).await;
                },
            ),
    );
    // The watchdog's verdict (Service::is_ready) on the gRPC health service too, so a load
    // balancer checking either transport stops sending work while a job overruns.
    let mut watch_stop = stop.subscribe();
    let (watch_health, watched) = (health.clone(), Arc::clone(&service));
    tokio::spawn(async move {
        let mut serving = true;
        loop {
            tokio::select! {
                _ = watch_stop.wait_for(|&s| s) => return,
                _ = tokio::time::sleep(WATCHDOG_PERIOD) => {}
            }
            let ready = watched.is_ready();
            if ready != serving {
                serving = ready;
                let status = if ready {
                    tonic_health::ServingStatus::Serving
                } else {
                    tracing::error!("a compute job runs on long after its deadline: not ready");
                    tonic_health::ServingStatus::NotServing
                };
                watch_health.set_service_status("", status).await;
                watch_health
                    .set_service_status(TRINOCULAR_SERVICE, status)
                    .await;
            }
        }
    });
    let http_stop = stop.subscribe();
    let app = http::router(Arc::clone(&service));
    let http = tokio::spawn(crate::http_server::serve(
        http_listener,
        app,
        connections,
        tls.as_ref().map(ServerTls::acceptor),
        http_stop,
    ));
    Ok(Running {
        grpc_addr,
        http_addr,
        health,
        stop,
        grpc,
        http,
        shutdown_grace: connections.shutdown_grace,
    })
}

impl Running {
    /// Reports NOT_SERVING, stops accepting connections, lets in-flight requests finish for
    /// the shutdown grace period, cuts the connections still open, and returns.
    pub async fn shutdown(mut self) {
        self.health
            .set_not_serving::<pb::trinocular_server::TrinocularServer<grpc::GrpcApi>>()
            .await;
        self.health
            .set_service_status("", tonic_health::ServingStatus::NotServing)
            .await;
        let _ = self.stop.send(true);
        // The HTTP server keeps to the grace period itself; tonic waits for every connection,
        // so it is cut a moment after.
        let grace = self.shutdown_grace + std::time::Duration::from_millis(500);
        let (g, h) = tokio::join!(
            tokio::time::timeout(grace, &mut self.grpc),
            tokio::time::timeout(grace, &mut self.http)
        );
        let (g, h) = (
            g.unwrap_or_else(|_| {
                tracing::warn!("gRPC: calls still open after the shutdown grace period; cut");
                self.grpc.abort();
                Ok(Ok(()))
            }),
            h.unwrap_or_else(|_| {
                self.http.abort();
                Ok(Ok(()))
            }),
        );
        if let Ok(Err(e)) = g {
            tracing::error!(error = %e, "gRPC server");
        }
        if let Ok(Err(e)) = h {
            tracing::error!(error = %e, "HTTP server");
        }
    }
}
