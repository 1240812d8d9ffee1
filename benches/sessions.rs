//! Session benchmarks (criterion, release), through the service layer in process (no
//! transport), one compute thread:
//! - `sessions/{match,add_capture}/{segments,images}/{embedded,memory}`: one capture of the
//!   panoramic room — its segment lists (`Defects::noisy`, as these figures were first
//!   measured), or its three rendered 512×512
//!   PNGs — matched (the peer), and added to a session that holds 12 captures (replaced by a
//!   fresh 12-capture session every 4 additions), on the durable embedded store (redb, fsync
//!   per capture) and in memory. The two alternate, each timed in turn;
//! - `sessions/add_capture/segments/memory/100`: a capture's segment lists added to a session
//!   that holds 100 captures (the panorama's twelve, round and round), in memory;
//! - `sessions/get_map/50`: the map of a 50-capture session (read, decode, fuse).
//!
//!     cargo bench --bench sessions

use std::sync::Arc;
use std::time::{Duration, Instant};
use trinocular::service::auth::Caller;

use criterion::{criterion_group, criterion_main, Criterion};
use trinocular::api::session::{pose_to_pb, segment_capture};
use trinocular::api::{self, pb};
use trinocular::service::store::{self, SessionStore};
use trinocular::service::{Limits, Service};
use trinocular::synth::{panoramic_session, render_triplet, Defects, RenderParams, RigSpec};

const TTL: Duration = Duration::from_secs(3600);

struct Fixture {
    calibration: pb::Calibration,
    captures: Vec<pb::AddCaptureRequest>,
    /// Capture 3 as its three rendered images.
    images: pb::AddCaptureRequest,
}

fn fixture() -> Fixture {
    let (scene, rig, captures) = panoramic_session(1, 12, &Defects::noisy());
    let (pose, _) = &captures[3];
    let placed = RigSpec::non_collinear(1).build(pose).expect("preset rig");
    let images = render_triplet(&scene, &placed, &RenderParams::default(), 1)
        .iter()
        .map(|image| pb::Image {
            source: Some(pb::image::Source::Encoded(
                trinocular::overlay::grey_png(image).expect("png"),
            )),
        })
        .collect();
    let images = pb::AddCaptureRequest {
        session_id: String::new(),
        rig_to_world: Some(pose_to_pb(&pose.to_isometry())),
        input: Some(pb::add_capture_request::Input::Images(pb::ImageTriplet {
            images,
        })),
        rig_to_world_covariance: Vec::new(),
        capture_id: String::new(),
    };
    Fixture {
        images,
        calibration: api::calibration_to_pb(&rig),
        captures: captures
            .iter()
            .map(|(pose, obs)| segment_capture(&pose.to_isometry(), &obs.lists))
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
    refined_session(service, f, captures, false).await
}

/// … with the map option `refine_poses` as given.
async fn refined_session(
    service: &Service,
    f: &Fixture,
    captures: usize,
    refine_poses: bool,
) -> String {
    let created = service
        .create_session(
            &Caller::default(),
            pb::CreateSessionRequest {
                name: "bench".into(),
                calibration: Some(f.calibration.clone()),
                options: None,
                map_options: Some(pb::MapOptions {
                    refine_poses: Some(refine_poses),
                    ..Default::default()
                }),
                session_id: String::new(),
            },
        )
        .await
        .expect("session");
    for k in 0..captures {
        let capture = pb::AddCaptureRequest {
            session_id: created.id.clone(),
            ..f.captures[k % f.captures.len()].clone()
        };
        service
            .add_capture(&Caller::default(), capture, None)
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

    let services: Vec<(&str, Service)> = stores
        .into_iter()
        .map(|(name, store)| (name, service(store)))
        .collect();
    for (mode, capture) in [("segments", &f.captures[3]), ("images", &f.images)] {
        let request = pb::MatchRequest {
            calibration: Some(f.calibration.clone()),
            options: None,
            input: capture.input.clone().map(|input| match input {
                pb::add_capture_request::Input::Segments(s) => {
                    pb::match_request::Input::Segments(s)
                }
                pb::add_capture_request::Input::Images(i) => pb::match_request::Input::Images(i),
            }),
        };
        for (name, service) in &services {
            // Match and AddCapture alternate, each timed in turn, so that both run in the same
            // state of caches and allocator (a Match repeated alone reuses warm buffers and
            // looks faster than it is in a service doing other work in between).
            for timed in ["match", "add_capture"] {
                let label = format!("{timed}/{mode}/{name}");
                group.bench_function(label, |b| {
                    b.iter_custom(|iters| {
                        let mut total = Duration::ZERO;
                        let mut id = rt.block_on(session(service, &f, 12));
                        for i in 0..iters {
                            if i % 4 == 3 {
                                id = rt.block_on(session(service, &f, 12));
                            }
                            let r = request.clone();
                            let t = Instant::now();
                            rt.block_on(service.match_within(move || Ok(r), |_| (), None))
                                .expect("match");
                            if timed == "match" {
                                total += t.elapsed();
                            }
                            let capture = pb::AddCaptureRequest {
                                session_id: id.clone(),
                                ..capture.clone()
                            };
                            let t = Instant::now();
                            rt.block_on(service.add_capture(&Caller::default(), capture, None))
                                .expect("capture");
                            if timed == "add_capture" {
                                total += t.elapsed();
                            }
                        }
                        total
                    })
                });
            }
        }
    }

    // A long session: what an AddCapture costs as the captures accumulate (the pose graph,
    // and reading the stored captures). Refreshed every 8 additions, untimed.
    let long = service(Arc::new(store::MemoryStore::new(TTL)));
    group.sample_size(10);
    group.bench_function("add_capture/segments/memory/100", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            let mut id = rt.block_on(session(&long, &f, 100));
            for i in 0..iters {
                if i % 8 == 7 {
                    id = rt.block_on(session(&long, &f, 100));
                }
                let capture = pb::AddCaptureRequest {
                    session_id: id.clone(),
                    ..f.captures[3].clone()
                };
                let t = Instant::now();
                rt.block_on(long.add_capture(&Caller::default(), capture, None))
                    .expect("capture");
                total += t.elapsed();
            }
            total
        })
    });
    group.sample_size(100);

    let service = service(Arc::new(store::MemoryStore::new(TTL)));
    let id = rt.block_on(session(&service, &f, 50));
    group.bench_function("get_map/50", |b| {
        b.iter(|| {
            rt.block_on(service.get_map(&Caller::default(), &id, None))
                .expect("map")
        })
    });
    let refined = rt.block_on(refined_session(&service, &f, 50, true));
    group.bench_function("get_map_refined/50", |b| {
        b.iter(|| {
            rt.block_on(service.get_map(&Caller::default(), &refined, None))
                .expect("map")
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench);
criterion_main!(benches);
