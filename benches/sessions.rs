//! Session benchmarks (criterion, release), through the service layer in process (no
//! transport), one compute thread:
//! - `sessions/match`: a plain Match of one capture of the panoramic room (realistic
//!   defects) — the peer;
//! - `sessions/add_capture/{embedded,memory}`: the same capture added to a session that
//!   holds 12 captures (the session is replaced by a fresh 12-capture one every 4 additions),
//!   on the durable embedded store (redb, fsync per capture) and in memory;
//! - `sessions/get_map/50`: the map of a 50-capture session (read, decode, fuse).
//!
//!     cargo bench --bench sessions

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use trinocular::api::{self, pb};
use trinocular::service::store::{self, SessionStore};
use trinocular::service::{Limits, Service};
use trinocular::synth::{panoramic_session, Defects};

const TTL: Duration = Duration::from_secs(3600);

struct Fixture {
    calibration: pb::Calibration,
    captures: Vec<pb::AddCaptureRequest>,
}

fn fixture() -> Fixture {
    let (_, rig, captures) = panoramic_session(1, 12, &Defects::realistic());
    Fixture {
        calibration: api::calibration_to_pb(&rig),
        captures: captures
            .iter()
            .map(|(pose, obs)| {
                let m = pose.to_matrix();
                pb::AddCaptureRequest {
                    session_id: String::new(),
                    rig_to_world: Some(pb::Pose {
                        matrix: (0..16).map(|i| m[(i / 4, i % 4)]).collect(),
                    }),
                    input: Some(pb::add_capture_request::Input::Segments(
                        pb::SegmentTriplet {
                            lists: obs.lists.iter().map(api::segment_list_to_pb).collect(),
                        },
                    )),
                }
            })
            .collect(),
    }
}

fn service(store: Arc<dyn SessionStore>) -> Service {
    let limits = Limits {
        threads: 1,
        max_jobs: 64,
        ..Limits::default()
    };
    Service::new(limits, store, TTL).expect("service")
}

/// A session holding `captures` of the fixture's captures (cycling through them).
async fn session(service: &Service, f: &Fixture, captures: usize) -> String {
    let created = service
        .create_session(
            pb::CreateSessionRequest {
                name: "bench".into(),
                calibration: Some(f.calibration.clone()),
                options: None,
                map_options: None,
            },
            "bench",
        )
        .await
        .expect("session");
    for k in 0..captures {
        let capture = pb::AddCaptureRequest {
            session_id: created.id.clone(),
            ..f.captures[k % f.captures.len()].clone()
        };
        service
            .add_capture(capture, None, "bench")
            .await
            .expect("capture");
    }
    created.id
}

fn bench(c: &mut Criterion) {
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let f = fixture();
    let dir = std::env::temp_dir().join(format!("trinocular-bench-{}", std::process::id()));
    let embedded = rt
        .block_on(store::open("embedded", &dir, TTL))
        .expect("embedded store");
    let stores: [(&str, Arc<dyn SessionStore>); 2] = [
        ("embedded", embedded),
        ("memory", Arc::new(store::MemoryStore::new(TTL))),
    ];
    let mut group = c.benchmark_group("sessions");
    group.measurement_time(Duration::from_secs(8));

    let plain = service(Arc::new(store::MemoryStore::new(TTL)));
    let request = match f.captures[3].input.clone() {
        Some(pb::add_capture_request::Input::Segments(s)) => pb::MatchRequest {
            calibration: Some(f.calibration.clone()),
            options: None,
            input: Some(pb::match_request::Input::Segments(s)),
        },
        _ => unreachable!("segment captures"),
    };
    group.bench_function("match", |b| {
        b.iter(|| {
            let r = request.clone();
            rt.block_on(plain.match_within(move || Ok(r), |_| (), None, "bench"))
                .expect("match")
        })
    });

    for (name, store) in stores {
        let service = service(store);
        group.bench_function(format!("add_capture/{name}"), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                let mut id = rt.block_on(session(&service, &f, 12));
                for i in 0..iters {
                    if i % 4 == 3 {
                        id = rt.block_on(session(&service, &f, 12));
                    }
                    let capture = pb::AddCaptureRequest {
                        session_id: id.clone(),
                        ..f.captures[3].clone()
                    };
                    let t = Instant::now();
                    rt.block_on(service.add_capture(capture, None, "bench"))
                        .expect("capture");
                    total += t.elapsed();
                }
                total
            })
        });
    }

    let service = service(Arc::new(store::MemoryStore::new(TTL)));
    let id = rt.block_on(session(&service, &f, 50));
    group.bench_function("get_map/50", |b| {
        b.iter(|| {
            rt.block_on(service.get_map(&id, None, "bench"))
                .expect("map")
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench);
criterion_main!(benches);
