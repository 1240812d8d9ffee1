//! The browser view in a real browser: headless Chromium (Debian's), driven by
//! `tests/browser/pages.mjs` (playwright-core), against a live server holding synthetic
//! sessions. It checks that the session page shows the map the API serves, that a capture
//! added while the page is open appears on it, that the Match page draws an overlay of the
//! uploaded files, and that the screenshots it saves are pictures, not blank pages. It prints
//! the page's load time for a 50-capture session and the live update's delay (measured, not
//! asserted).
//!
//! Skipped, saying why, without Chromium, Node.js or `tests/browser/node_modules` (`npm ci`
//! there); `TRINOCULAR_REQUIRE_BROWSER=1` (CI) makes a missing one a failure.

use std::path::{Path, PathBuf};

use trinocular::api::{self, pb};

use crate::common::{post_protobuf, runtime, scratch_dir};
use crate::sessions::{panorama, start};

fn skip_or_fail(why: &str) {
    assert!(
        std::env::var_os("TRINOCULAR_REQUIRE_BROWSER").is_none(),
        "browser tests: {why}, and TRINOCULAR_REQUIRE_BROWSER is set"
    );
    eprintln!("SKIPPED browser tests: {why}");
}

/// Chromium, Node.js and playwright-core, or why not.
fn tools() -> Result<(PathBuf, PathBuf), String> {
    let chromium = std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    if !chromium.exists() {
        return Err(format!(
            "no Chromium at {} (apt-get install chromium, or set CHROMIUM)",
            chromium.display()
        ));
    }
    let node_ok = std::process::Command::new("node")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !node_ok {
        return Err("no Node.js (`node`) on the PATH".into());
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/browser");
    if !dir.join("node_modules/playwright-core").exists() {
        return Err(format!(
            "playwright-core is not installed (run `npm ci` in {})",
            dir.display()
        ));
    }
    Ok((chromium, dir))
}

/// Adds `captures` to a new session named `name` over HTTP (protobuf); the session's id.
async fn session_with(
    http: &reqwest::Client,
    base: &str,
    name: &str,
    calibration: &pb::Calibration,
    captures: &[pb::AddCaptureRequest],
) -> String {
    let created = http
        .post(format!("{base}/v1/sessions"))
        .body(api::to_json(&pb::CreateSessionRequest {
            name: name.into(),
            calibration: Some(calibration.clone()),
            options: None,
            map_options: None,
            session_id: String::new(),
        }))
        .send()
        .await
        .expect("create");
    assert_eq!(created.status(), 200);
    let session: pb::Session = api::from_json("s", &created.text().await.unwrap()).unwrap();
    for capture in captures {
        let capture = pb::AddCaptureRequest {
            session_id: session.id.clone(),
            ..capture.clone()
        };
        let added = post_protobuf(
            http,
            format!("{base}/v1/sessions/{}/captures", session.id),
            &capture,
        )
        .send()
        .await
        .expect("add capture");
        assert_eq!(added.status(), 200, "{}", added.text().await.unwrap());
    }
    session.id
}

async fn map_segments(http: &reqwest::Client, base: &str, id: &str) -> usize {
    let text = http
        .get(format!("{base}/v1/sessions/{id}/map"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    api::from_json::<pb::Map>("map", &text)
        .unwrap()
        .segments
        .len()
}

/// Spread of a screenshot's grey levels and its count of distinct colours: a blank page has
/// neither.
fn picture_stats(path: &Path) -> (f64, usize) {
    let picture = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8();
    let n = f64::from(picture.width() * picture.height());
    let (mut sum, mut sq) = (0.0, 0.0);
    let mut colours = std::collections::HashSet::new();
    for p in picture.pixels() {
        let y = 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]);
        sum += y;
        sq += y * y;
        colours.insert(p.0);
    }
    let mean = sum / n;
    ((sq / n - mean * mean).max(0.0).sqrt(), colours.len())
}

/// The driver's own waits are 10-30 s each; past this it is stuck.
const DRIVER_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(180);

/// The child's output, or a failure naming the timeout once it has run that long (killed).
fn finish_within(
    mut child: std::process::Child,
    timeout: std::time::Duration,
) -> std::process::Output {
    let until = std::time::Instant::now() + timeout;
    while child.try_wait().expect("wait for node").is_none() {
        if std::time::Instant::now() > until {
            let _ = child.kill();
            panic!("the browser driver did not finish within {timeout:?}");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.wait_with_output().expect("node's output")
}

/// A picture has at least this spread of grey levels: a white page with a few words has
/// about 10, a drawn map or overlay much more.
const NOT_BLANK_SPREAD: f64 = 12.0;
/// …and at least this many colours (a blank page has one or two, text adds its antialiasing).
const NOT_BLANK_COLOURS: usize = 64;

#[test]
fn the_pages_show_sessions_live_and_draw_a_match_overlay_in_chromium() {
    let (chromium, dir) = match tools() {
        Ok(t) => t,
        Err(why) => return skip_or_fail(&why),
    };
    let (calibration, captures) = panorama(12);
    let (_, big_captures) = panorama(50);
    runtime().block_on(async {
        let running = start().await;
        let base = format!("http://{}", running.http_addr);
        let http = reqwest::Client::new();
        // Eleven captures before the page opens; the twelfth while it is open.
        let session =
            session_with(&http, &base, "office tour", &calibration, &captures[..11]).await;
        let before = map_segments(&http, &base, &session).await;
        let big = session_with(&http, &base, "fifty captures", &calibration, &big_captures).await;
        let out = scratch_dir("browser");
        let live_capture = out.join("live-capture.json");
        std::fs::write(
            &live_capture,
            api::to_json(&pb::AddCaptureRequest {
                session_id: session.clone(),
                ..captures[11].clone()
            }),
        )
        .unwrap();
        let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/server/ui/sample");
        let plan = serde_json::json!({
            "base": base,
            "chromium": chromium,
            "screenshots": out,
            "session": session,
            "bigSession": big,
            "liveCapture": live_capture,
            "sample": {
                "image1": sample.join("image1.png"),
                "image2": sample.join("image2.png"),
                "image3": sample.join("image3.png"),
                "calibration": sample.join("calibration.json"),
            },
        });
        let driver = std::process::Command::new("node")
            .arg(dir.join("pages.mjs"))
            .arg(plan.to_string())
            .current_dir(&dir)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("node runs");
        let output = tokio::task::spawn_blocking(move || finish_within(driver, DRIVER_TIMEOUT))
            .await
            .unwrap();
        assert!(
            output.status.success(),
            "the browser driver failed:\n{}\n{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
        let report: serde_json::Value =
            serde_json::from_slice(&output.stdout).expect("the driver's JSON report");
        let after = map_segments(&http, &base, &session).await;

        // The session page shows what the API serves.
        let page = &report["session"];
        assert_eq!(page["title"], "office tour");
        assert_eq!(page["captures"], 11);
        assert_eq!(page["segments"], before, "{page}");
        assert!(
            page["topView"]["spread"].as_f64().unwrap() > NOT_BLANK_SPREAD,
            "{page}"
        );
        assert!(page["webgl"].as_bool().unwrap(), "no 3D view: {page}");
        let formats = page["downloadFormats"].as_array().unwrap();
        assert_eq!(formats.len(), 5, "{page}");

        // The twelfth capture, added while the page was open, is on it.
        let live = &report["live"];
        assert_eq!(live["status"], 200, "{live}");
        assert_eq!(live["captures"], 12, "{live}");
        assert_eq!(live["segments"], after, "{live}");
        assert!(
            live["picked"]
                .as_str()
                .is_some_and(|p| p.starts_with("map segment")),
            "clicking the 3D view picked no segment: {live}"
        );

        // The Match page drew the three overlays of the uploaded files, and says how many 3D
        // segments the service answered.
        let matched = &report["match"];
        assert!(
            matched["sessionRows"]
                .as_array()
                .unwrap()
                .iter()
                .any(|r| r.as_str().unwrap().contains("office tour")),
            "{matched}"
        );
        let answered = matched["answered3d"].as_u64().unwrap();
        assert!(answered > 0, "{matched}");
        assert!(
            matched["facts"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{answered} 3D segments")),
            "{matched}"
        );
        for overlay in matched["overlays"].as_array().unwrap() {
            assert_eq!(overlay["width"], 512, "{overlay}");
            assert!(
                overlay["spread"].as_f64().unwrap() > NOT_BLANK_SPREAD,
                "{overlay}"
            );
            assert!(overlay["colours"].as_u64().unwrap() > 64, "{overlay}");
        }
        assert_eq!(matched["captions"].as_array().unwrap().len(), 3);
        assert!(matched["webgl"].as_bool().unwrap(), "{matched}");
        assert_eq!(report["errors"].as_array().unwrap().len(), 0, "{report}");

        for shot in ["session.png", "session-live.png", "match.png"] {
            let (spread, colours) = picture_stats(&out.join(shot));
            assert!(
                spread > NOT_BLANK_SPREAD && colours > NOT_BLANK_COLOURS,
                "{shot} looks blank: spread {spread:.1}, {colours} colours"
            );
        }
        eprintln!(
            "browser: session page of 50 captures ({} segments) loaded and drawn in {} ms; \
             live update {} ms after AddCapture answered; screenshots in {}",
            report["big"]["segments"],
            report["big"]["loadMs"],
            live["delayMs"],
            out.display()
        );
        // TRINOCULAR_SCREENSHOTS=docs keeps them as the README shows them.
        if let Some(keep) = std::env::var_os("TRINOCULAR_SCREENSHOTS") {
            for shot in ["session.png", "match.png"] {
                let kept = Path::new(&keep).join(format!("browser-{shot}"));
                std::fs::copy(out.join(shot), kept).unwrap();
            }
        } else {
            let _ = std::fs::remove_dir_all(&out);
        }
    });
}

/// Reads the stream until an event named `name` arrives; its data.
async fn next_event(response: &mut reqwest::Response, buffer: &mut String, name: &str) -> String {
    let wait = async {
        loop {
            while let Some(end) = buffer.find("\n\n") {
                let block: String = buffer.drain(..end + 2).collect();
                let mut event = "";
                let mut data = String::new();
                for line in block.lines() {
                    if let Some(e) = line.strip_prefix("event:") {
                        event = e.trim();
                    } else if let Some(d) = line.strip_prefix("data:") {
                        data.push_str(d.trim());
                    }
                }
                if event == name {
                    return data;
                }
            }
            let chunk = response
                .chunk()
                .await
                .expect("the stream")
                .expect("the stream goes on");
            buffer.push_str(std::str::from_utf8(&chunk).unwrap());
        }
    };
    tokio::time::timeout(std::time::Duration::from_secs(10), wait)
        .await
        .unwrap_or_else(|_| panic!("no {name} event within 10 s"))
}

#[test]
fn the_live_feed_announces_each_capture_and_the_end_of_its_session() {
    let (calibration, captures) = panorama(2);
    runtime().block_on(async {
        let running = start().await;
        let base = format!("http://{}", running.http_addr);
        let http = reqwest::Client::new();
        let id = session_with(&http, &base, "live", &calibration, &[]).await;
        let mut events = http
            .get(format!("{base}/v1/sessions/{id}/events"))
            .send()
            .await
            .unwrap();
        assert_eq!(events.status(), 200);
        assert_eq!(events.headers()["content-type"], "text/event-stream");
        let mut buffer = String::new();
        assert_eq!(
            next_event(&mut events, &mut buffer, "captures").await,
            r#"{"captures":0}"#
        );
        for (n, capture) in captures.iter().enumerate() {
            let capture = pb::AddCaptureRequest {
                session_id: id.clone(),
                ..capture.clone()
            };
            let added = post_protobuf(&http, format!("{base}/v1/sessions/{id}/captures"), &capture)
                .send()
                .await
                .unwrap();
            assert_eq!(added.status(), 200);
            assert_eq!(
                next_event(&mut events, &mut buffer, "captures").await,
                format!(r#"{{"captures":{}}}"#, n + 1)
            );
        }
        let deleted = http
            .delete(format!("{base}/v1/sessions/{id}"))
            .send()
            .await
            .unwrap();
        assert_eq!(deleted.status(), 200);
        next_event(&mut events, &mut buffer, "gone").await;

        // A session that does not exist has no feed: NOT_FOUND naming it, before any stream.
        let unknown = http
            .get(format!("{base}/v1/sessions/{id}/events"))
            .send()
            .await
            .unwrap();
        assert_eq!(unknown.status(), 404);
        let body: serde_json::Value = serde_json::from_str(&unknown.text().await.unwrap()).unwrap();
        assert_eq!(body["error"]["field"], "session_id", "{body}");
        // The pages are served without a key and name their type; an unknown file is 404.
        let page = http.get(format!("{base}/")).send().await.unwrap();
        assert_eq!(page.status(), 200);
        assert!(page.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/html"));
        let missing = http.get(format!("{base}/ui/nope.js")).send().await.unwrap();
        assert_eq!(missing.status(), 404);
    });
}

#[test]
fn a_match_answers_as_ply_when_asked_and_refuses_an_unknown_format() {
    runtime().block_on(async {
        let running = start().await;
        let url = format!("http://{}/v1/match", running.http_addr);
        let http = reqwest::Client::new();
        let body = api::to_json(&crate::common::example_request());
        let json = http.post(&url).body(body.clone()).send().await.unwrap();
        let response: pb::MatchResponse =
            api::from_json("response", &json.text().await.unwrap()).unwrap();
        assert!(!response.segments_3d.is_empty());
        let ply = http
            .post(format!("{url}?format=ply"))
            .body(body.clone())
            .send()
            .await
            .unwrap();
        assert_eq!(ply.status(), 200);
        assert_eq!(ply.headers()["content-type"], "application/x-ply");
        let text = ply.text().await.unwrap();
        let vertices = format!("element vertex {}\n", 2 * response.segments_3d.len());
        assert!(
            text.starts_with("ply\n") && text.contains(&vertices),
            "{text}"
        );
        let bad = http
            .post(format!("{url}?format=xml"))
            .body(body)
            .send()
            .await
            .unwrap();
        assert_eq!(bad.status(), 400);
        let error: serde_json::Value = serde_json::from_str(&bad.text().await.unwrap()).unwrap();
        assert_eq!(error["error"]["field"], "format", "{error}");
    });
}
