//! The HTTP server's connection handling, where `axum::serve` leaves a hostile client too
//! much room: a cap on open connections (past it, a canned 503 and close, costing
//! microseconds), a deadline for each request's headers that is also the idle timeout of a
//! kept-alive connection, a deadline for each request's body, and a shutdown that waits for
//! connections only as long as its grace period, then cuts them.
//!
//! HTTP/1.1 and HTTP/2 (prior knowledge, for h2c clients) on one port, as before; with TLS
//! ([`crate::tls`]) the handshake is done on the connection's own task, within the header
//! timeout, and ALPN picks the protocol.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::Body;
use axum::Router;
use http_body::{Frame, SizeHint};
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto;
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinSet;

// The limits are part of the service's [`Limits`](crate::service::Limits), which the
// configuration builds; they are kept there so that the service never imports this module.
pub use crate::service::ConnectionLimits;

/// The body of the answer to a connection past the cap.
const REFUSAL: &str =
    "{\"error\": {\"code\": \"UNAVAILABLE\", \"message\": \"too many open connections; retry later\"}}\n";

/// Serves `app` on `listener` (over TLS when `tls` is given) until `stop` turns true; then
/// stops accepting, lets open connections finish for `limits.shutdown_grace`, and cuts
/// those still open.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: ConnectionLimits,
    tls: Option<tokio_rustls::TlsAcceptor>,
    mut stop: watch::Receiver<bool>,
) -> io::Result<()> {
    let mut builder = auto::Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout)
        .keep_alive(true);
    builder
        .http2()
        .timer(TokioTimer::new())
        .keep_alive_interval(Some(limits.header_timeout))
        .keep_alive_timeout(limits.header_timeout)
        .max_concurrent_streams(64);
    let body_timeout = limits.body_timeout;
    let app = app.layer(axum::middleware::map_request(
        move |request: axum::extract::Request| {
            let request = request.map(|body| Body::new(TimedBody::new(body, body_timeout)));
            std::future::ready(request)
        },
    ));
    let open = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    let mut connections = JoinSet::new();
    let mut stopped = Box::pin(async move {
        let _ = stop.wait_for(|&s| s).await;
    });
    loop {
        tokio::select! {
            _ = &mut stopped => break,
            Some(_) = connections.join_next(), if !connections.is_empty() => {}
            accepted = listener.accept() => {
                let stream = match accepted {
                    Ok((stream, _)) => stream,
                    Err(e) => {
                        // Out of file descriptors, or a connection reset before it was
                        // accepted: wait a moment rather than spin.
                        tracing::warn!(error = %e, "http accept");
                        tokio::time::sleep(Duration::from_millis(5)).await;
                        continue;
                    }
                };
                let Ok(permit) = Arc::clone(&open).try_acquire_owned() else {
                    if tls.is_some() {
                        // A plain-text 503 means nothing to a TLS client, and a handshake
                        // to send it is the cost the cap is there to avoid: just close.
                        drop(stream);
                    } else {
                        connections.spawn(refuse(stream));
                    }
                    continue;
                };
                let _ = stream.set_nodelay(true);
                let (builder, app, watcher) = (builder.clone(), app.clone(), graceful.watcher());
                match &tls {
                    None => connections.spawn(async move {
                        serve_connection(builder, app, stream, watcher).await;
                        drop(permit);
                    }),
                    Some(acceptor) => {
                        let (acceptor, handshake_timeout) = (acceptor.clone(), limits.header_timeout);
                        connections.spawn(async move {
                            match tokio::time::timeout(handshake_timeout, acceptor.accept(stream)).await {
                                Ok(Ok(stream)) => serve_connection(builder, app, stream, watcher).await,
                                Ok(Err(e)) => tracing::debug!(error = %e, "http: TLS handshake failed"),
                                Err(_) => tracing::debug!("http: TLS handshake timed out"),
                            }
                            drop(permit);
                        })
                    }
                };
            }
        }
    }
    drop(listener);
    if tokio::time::timeout(limits.shutdown_grace, graceful.shutdown())
        .await
        .is_err()
    {
        tracing::warn!(
            open = connections.len(),
            "http: connections still open after the shutdown grace period; cutting them"
        );
    }
    connections.abort_all();
    while connections.join_next().await.is_some() {}
    Ok(())
}

/// Serves one connection's requests until it closes or, once shutdown begins, until its
/// in-flight requests are answered.
async fn serve_connection<I>(
    builder: auto::Builder<TokioExecutor>,
    app: Router,
    io: I,
    watcher: hyper_util::server::graceful::Watcher,
) where
    I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let connection =
        builder.serve_connection_with_upgrades(TokioIo::new(io), TowerToHyperService::new(app));
    let _ = watcher.watch(connection.into_owned()).await;
}

/// Answers a connection past the cap with a whole 503, and closes it.
async fn refuse(mut stream: TcpStream) {
    let answer = format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n\
         retry-after: 1\r\nconnection: close\r\ncontent-length: {}\r\n\r\n{REFUSAL}",
        REFUSAL.len()
    );
    let _ = tokio::time::timeout(Duration::from_secs(1), async {
        let _ = stream.write_all(answer.as_bytes()).await;
        let _ = stream.shutdown().await;
    })
    .await;
}

/// The error a body that did not arrive in time ends with; found again by
/// [`timed_out_body`].
#[derive(Debug, thiserror::Error)]
#[error("the request body did not arrive within {0:?}")]
pub struct BodyTimedOut(pub Duration);

/// Whether an error (from reading a body) comes from a body that did not arrive in time.
pub fn timed_out_body(error: &(dyn std::error::Error + 'static)) -> Option<Duration> {
    let mut e: Option<&(dyn std::error::Error + 'static)> = Some(error);
    while let Some(err) = e {
        if let Some(t) = err.downcast_ref::<BodyTimedOut>() {
            return Some(t.0);
        }
        e = err.source();
    }
    None
}

/// A request body that fails once `timeout` has passed since it was wrapped.
struct TimedBody {
    inner: Body,
    deadline: Pin<Box<tokio::time::Sleep>>,
    timeout: Duration,
}

impl TimedBody {
    fn new(inner: Body, timeout: Duration) -> TimedBody {
        TimedBody {
            inner,
            deadline: Box::pin(tokio::time::sleep(timeout)),
            timeout,
        }
    }
}

impl http_body::Body for TimedBody {
    type Data = axum::body::Bytes;
    type Error = axum::BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        if let Poll::Ready(frame) = Pin::new(&mut self.inner).poll_frame(cx) {
            return Poll::Ready(frame.map(|f| f.map_err(Into::into)));
        }
        if self.deadline.as_mut().poll(cx).is_ready() {
            let timeout = self.timeout;
            return Poll::Ready(Some(Err(Box::new(BodyTimedOut(timeout)))));
        }
        Poll::Pending
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}
