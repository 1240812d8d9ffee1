//! The browser view, served by the HTTP port: `/` (the sessions and a Match page) and
//! `/sessions/{id}` (a session's map from above and in 3D, live), with their scripts, style
//! and the vendored three.js under `/ui/`. Every file is compiled into the binary, so the view
//! needs no other server and no internet; the pages hold no data (they read it from the API
//! with the visitor's key), so they are served without one.
//!
//! And the live feed the session page listens to: `GET /v1/sessions/{id}/events`, server-sent
//! events — `captures` with the session's capture count when it is opened and whenever it
//! changes, `gone` when the session is deleted or expires. A change made on this replica is
//! sent at once (the service's change broadcast); one made through another replica behind the
//! same store is seen within [`RECHECK`]. A stream lasts at most [`STREAM_LIFETIME`] (the
//! browser reconnects by itself) and a replica holds at most
//! [`crate::service::MAX_EVENT_STREAMS`] of them, one API key at most
//! [`crate::service::MAX_EVENT_STREAMS_PER_KEY`]. Its looks after the first read the session
//! without refreshing its idle TTL: watching a session is not using it.

use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::extract::{Path, State};
use axum::http::{header, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

use crate::http::SessionId;
use crate::service::auth::Caller;
use crate::service::{Service, ServiceError};

/// How often a live stream re-reads its session when told of nothing (changes made through
/// other replicas).
pub const RECHECK: Duration = Duration::from_secs(1);
/// Longest life of one live stream; the browser's `EventSource`-like reader reconnects.
pub const STREAM_LIFETIME: Duration = Duration::from_secs(600);

/// One file of the view.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    bytes: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $type:expr) => {
        Asset {
            path: $path,
            content_type: $type,
            bytes: include_bytes!(concat!("../ui/", $path)),
        }
    };
}

const JS: &str = "text/javascript; charset=utf-8";

/// Every file under `/ui/`.
const ASSETS: &[Asset] = &[
    asset!("index.html", "text/html; charset=utf-8"),
    asset!("session.html", "text/html; charset=utf-8"),
    asset!("style.css", "text/css; charset=utf-8"),
    asset!("common.js", JS),
    asset!("index.js", JS),
    asset!("session.js", JS),
    asset!("view3d.js", JS),
    asset!("topview.js", JS),
    asset!("vendor/three/three.core.js", JS),
    asset!("vendor/three/three.module.js", JS),
    asset!("vendor/three/OrbitControls.js", JS),
    asset!("vendor/three/LICENSE", "text/plain; charset=utf-8"),
    asset!("vendor/three/VERSION", "text/plain; charset=utf-8"),
    asset!("sample/image1.png", "image/png"),
    asset!("sample/image2.png", "image/png"),
    asset!("sample/image3.png", "image/png"),
    asset!("sample/calibration.json", "application/json"),
];

/// The view's routes (pages, files, the live feed), on the HTTP router's state.
pub fn routes() -> Router<Arc<Service>> {
    Router::new()
        .route("/", get(|| async { page("index.html") }))
        .route("/sessions/{id}", get(|| async { page("session.html") }))
        .route("/ui/{*path}", get(file))
        .route("/v1/sessions/{id}/events", get(session_events))
}

/// Paths served without an API key: the pages and their files, which hold no data.
pub fn is_public(path: &str) -> bool {
    path == "/" || path.starts_with("/ui/") || path.starts_with("/sessions/")
}

fn page(name: &str) -> Response {
    serve(name, "no-cache")
}

async fn file(Path(path): Path<String>) -> Response {
    // The files change only with the binary: the pages revalidate, the rest may be kept.
    serve(&path, "public, max-age=300")
}

fn serve(path: &str, cache: &'static str) -> Response {
    match ASSETS.iter().find(|a| a.path == path) {
        Some(a) => (
            [
                (header::CONTENT_TYPE, a.content_type),
                (header::CACHE_CONTROL, cache),
                (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
            ],
            a.bytes,
        )
            .into_response(),
        None => crate::http::error_response(&ServiceError::NotFound {
            field: "path".into(),
            what: format!("file /ui/{}", crate::http::shown_path(path)),
        }),
    }
}

/// `GET /v1/sessions/{id}/events`: see the module's description. A session the caller cannot
/// see is NOT_FOUND before the stream starts.
async fn session_events(
    State(service): State<Arc<Service>>,
    caller: Caller,
    SessionId(id): SessionId,
) -> Response {
    let first = match service.session_captures(&caller, &id).await {
        Ok(captures) => captures,
        Err(e) => return crate::http::error_response(&e),
    };
    let permit = match service.open_event_stream(&caller) {
        Ok(permit) => permit,
        Err(e) => return crate::http::error_response(&e),
    };
    let (send, receive) = tokio::sync::mpsc::channel::<Event>(4);
    let stored_id = crate::service::auth::store_id(&caller, &id);
    let mut changes = service.session_changes();
    tokio::spawn(async move {
        let _permit = permit;
        let captures_event = |n: u64| {
            Event::default()
                .event("captures")
                .data(format!("{{\"captures\":{n}}}"))
        };
        if send.send(captures_event(first)).await.is_err() {
            return;
        }
        let mut known = first;
        let until = tokio::time::Instant::now() + STREAM_LIFETIME;
        let mut recheck = tokio::time::interval(RECHECK);
        recheck.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let woken = tokio::select! {
                () = tokio::time::sleep_until(until) => return,
                () = send.closed() => return,
                change = changes.recv() => match change {
                    Ok(changed) => changed == stored_id,
                    // Fell behind: look again.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => true,
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => return,
                },
                _ = recheck.tick() => true,
            };
            if !woken {
                continue;
            }
            match service.watched_session_captures(&caller, &id).await {
                Ok(captures) if captures != known => {
                    known = captures;
                    if send.send(captures_event(known)).await.is_err() {
                        return;
                    }
                }
                Ok(_) => {}
                Err(ServiceError::NotFound { .. }) => {
                    let _ = send.send(Event::default().event("gone").data("{}")).await;
                    return;
                }
                // The store is unreachable for now: the next look may do better.
                Err(_) => {}
            }
        }
    });
    let mut response = Sse::new(Events(receive))
        .keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
        .into_response();
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, "no-cache".parse().expect("header"));
    *response.status_mut() = StatusCode::OK;
    response
}

/// The events a stream's task sends, as the `Stream` axum's `Sse` reads.
struct Events(tokio::sync::mpsc::Receiver<Event>);

impl futures_core::Stream for Events {
    type Item = Result<Event, Infallible>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        self.0.poll_recv(cx).map(|e| e.map(Ok))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_page_and_file_is_served_with_its_type() {
        for a in ASSETS {
            assert!(!a.bytes.is_empty(), "{} is empty", a.path);
            let response = serve(a.path, "no-cache");
            assert_eq!(response.status(), StatusCode::OK, "{}", a.path);
            assert_eq!(
                response.headers()[header::CONTENT_TYPE],
                a.content_type,
                "{}",
                a.path
            );
        }
        assert_eq!(serve("nope.js", "no-cache").status(), StatusCode::NOT_FOUND);
    }

    #[test]
    fn the_pages_import_only_files_that_are_served() {
        // A page or script that names a file the binary does not hold would fail in the
        // browser only: check every `/ui/...` reference here.
        for a in ASSETS.iter().filter(|a| a.content_type != "image/png") {
            let text = std::str::from_utf8(a.bytes).expect("text asset");
            for (at, _) in text.match_indices("/ui/") {
                let rest = &text[at + 4..];
                let end = rest
                    .find(|c: char| !(c.is_ascii_alphanumeric() || "._-/".contains(c)))
                    .unwrap_or(rest.len());
                let name = &rest[..end];
                if name.is_empty() || name.ends_with('/') {
                    continue;
                }
                assert!(
                    ASSETS.iter().any(|b| b.path == name),
                    "{} refers to /ui/{name}, which is not served",
                    a.path
                );
            }
        }
    }

    #[test]
    fn only_the_view_is_public() {
        assert!(is_public("/"));
        assert!(is_public("/ui/common.js"));
        assert!(is_public("/sessions/abc"));
        assert!(!is_public("/v1/sessions"));
        assert!(!is_public("/v1/sessions/abc/events"));
        assert!(!is_public("/v1/match"));
    }
}
