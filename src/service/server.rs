//! Both servers on their listeners, stopped together: gRPC (tonic) and HTTP (axum) over the
//! same [`Service`].

use std::net::SocketAddr;
use std::sync::Arc;

use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tonic::transport::server::TcpIncoming;

use super::Service;
use crate::api::{grpc, http, pb};

/// HTTP/2 flow-control windows of the gRPC server, bytes.
const H2_STREAM_WINDOW: u32 = 4 << 20;
const H2_CONNECTION_WINDOW: u32 = 16 << 20;

/// Two running servers.
pub struct Running {
    pub grpc_addr: SocketAddr,
    pub http_addr: SocketAddr,
    health: tonic_health::server::HealthReporter,
    stop: watch::Sender<bool>,
    grpc: JoinHandle<Result<(), tonic::transport::Error>>,
    http: JoinHandle<std::io::Result<()>>,
}

/// Binds both addresses (port 0: any free port) and starts serving.
pub async fn start(
    service: Arc<Service>,
    grpc_addr: SocketAddr,
    http_addr: SocketAddr,
) -> std::io::Result<Running> {
    let grpc_listener = TcpListener::bind(grpc_addr).await?;
    let http_listener = TcpListener::bind(http_addr).await?;
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
            .register_encoded_file_descriptor_set(crate::api::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection().build_v1().map_err(std::io::Error::other)?;
    let reflection_v1alpha = reflection()
        .build_v1alpha()
        .map_err(std::io::Error::other)?;
    let mut grpc_stop = stop.subscribe();
    let grpc = tokio::spawn(
        tonic::transport::Server::builder()
            // HTTP/2's default 64 KiB windows make a client stop mid-request and wait a round
            // trip for WINDOW_UPDATE whenever a request is larger (600 segments per list are
            // 80 KiB, an image triplet megabytes): open them wide.
            .initial_stream_window_size(Some(H2_STREAM_WINDOW))
            .initial_connection_window_size(Some(H2_CONNECTION_WINDOW))
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
    let mut http_stop = stop.subscribe();
    let app = http::router(Arc::clone(&service));
    let http = tokio::spawn(async move {
        axum::serve(http_listener, app)
            .with_graceful_shutdown(async move {
                let _ = http_stop.wait_for(|&s| s).await;
            })
            .await
    });
    Ok(Running {
        grpc_addr,
        http_addr,
        health,
        stop,
        grpc,
        http,
    })
}

impl Running {
    /// Reports NOT_SERVING, stops accepting connections, lets in-flight requests finish, and
    /// returns.
    pub async fn shutdown(self) {
        self.health
            .set_not_serving::<pb::trinocular_server::TrinocularServer<grpc::GrpcApi>>()
            .await;
        self.health
            .set_service_status("", tonic_health::ServingStatus::NotServing)
            .await;
        let _ = self.stop.send(true);
        let (g, h) = tokio::join!(self.grpc, self.http);
        if let Ok(Err(e)) = g {
            tracing::error!(error = %e, "gRPC server");
        }
        if let Ok(Err(e)) = h {
            tracing::error!(error = %e, "HTTP server");
        }
    }
}
