//! Session use cases: create, add a capture, get the fused map, list, get, delete.
//!
//! A session holds the rig's calibration and options (stored once) and, per capture, its
//! pose and its 3D segments in the rig frame. Matching a capture runs on the compute pool
//! like `Match`; the capture is appended to the store (one atomic, durable step) before the
//! answer, so an acknowledged capture is never lost. The map is fused from the stored
//! captures when asked, on the compute pool: replicas need share nothing but the store.

use std::sync::Arc;
use std::time::Duration;

use prost::Message;

use super::auth::{public_id, store_id, Caller};
use super::clock::Clock;
use super::store::{Appended, SessionInfo, SessionRecord, StoreError};
use super::{Service, ServiceError};
use nalgebra::Matrix6;
use trinocular_core::checkpoint::Checkpoint;
use trinocular_core::map::export::RigMarker;
use trinocular_core::map::images::Views;
use trinocular_core::map::poses::RelativePose;
use trinocular_core::map::session::{Added, Placed, SessionParams};
use trinocular_core::map::{self, FuseParams, MapGate, Measured, PosePrior};
use trinocular_core::segment::Segment3;
use trinocular_schema::session::{
    capture_match_request, capture_pose_from_pb, certain_only, check_session_id, edges_of,
    edges_to_pb, matrix6_to_vec, pose_prior, pose_to_pb, registration_to_pb, status_to_pb,
    stored_capture_segments, stored_header_of, StoredSegments,
};
use trinocular_schema::{match_params, pb, rig_from_calibration, segment_lists, InputError};

// The fused map and its message are the schema's: the transports answer with it.
pub use trinocular_schema::session::{map_to_pb, SessionMap};

/// Captures one session may hold: each is stored and fused into every map asked for, so
/// their number bounds a session's storage and a GetMap's work.
const MAX_CAPTURES_PER_SESSION: u64 = 10_000;

/// Sessions per ListSessions page by default, and at most.
const DEFAULT_PAGE_SIZE: usize = 100;
const MAX_PAGE_SIZE: usize = 1000;

impl From<StoreError> for ServiceError {
    fn from(e: StoreError) -> ServiceError {
        match e {
            StoreError::NotFound { id } => ServiceError::NotFound {
                field: "session_id".to_string(),
                // The public id: a tenant's prefix in the store is not the caller's business.
                what: format!("session {:?}", id.rsplit('~').next().unwrap_or_default()),
            },
            StoreError::AlreadyExists { id } => ServiceError::Internal {
                detail: format!("session id {id} generated twice"),
            },
            StoreError::Unavailable { message } => ServiceError::Unavailable { message },
            StoreError::Corrupt { message } => ServiceError::Internal {
                detail: format!("corrupt session data: {message}"),
            },
        }
    }
}

/// A stored message that no longer decodes: a bug or a damaged store, not the client's fault.
fn corrupt(what: &str, e: prost::DecodeError) -> ServiceError {
    ServiceError::Internal {
        detail: format!("stored {what} does not decode: {e}"),
    }
}

/// A stored capture that decodes but does not hold what it should (a damaged store).
fn damaged(index: usize, e: InputError) -> ServiceError {
    ServiceError::Internal {
        detail: format!("stored capture {index}: {e}"),
    }
}

/// Longest capture name (`AddCaptureRequest.capture_id`), bytes: a UUID is 36.
const MAX_CAPTURE_ID_BYTES: usize = 128;

/// Capture names are store keys and appear in errors: printable ASCII without spaces.
fn check_capture_id(name: &str) -> Result<(), ServiceError> {
    if name.len() > MAX_CAPTURE_ID_BYTES || !name.bytes().all(|b| b.is_ascii_graphic()) {
        let shown: String = name.chars().take(40).collect();
        let more = if shown.len() < name.len() { "..." } else { "" };
        return Err(ServiceError::Input(InputError::new(
            "capture_id",
            format!(
                "{shown:?}{more} is not a capture id (1 to {MAX_CAPTURE_ID_BYTES} printable \
                 ASCII characters, no spaces)"
            ),
        )));
    }
    Ok(())
}

/// SHA-256 of what a named capture was sent with — its pose, the pose's covariance and its
/// input — so that a retry (the same) is told from another capture under the name. Every
/// piece is length-prefixed, so no two requests hash alike by moving bytes between pieces;
/// images, the bulk of a large request, are hashed where they lie.
fn capture_digest(
    pose: &pb::Pose,
    covariance: &[f64],
    input: Option<&pb::add_capture_request::Input>,
) -> Vec<u8> {
    use sha2::{Digest, Sha256};
    let mut hash = Sha256::new();
    let mut piece = |bytes: &[u8]| {
        hash.update((bytes.len() as u64).to_le_bytes());
        hash.update(bytes);
    };
    piece(&pose.encode_to_vec());
    let covariance: Vec<u8> = covariance.iter().flat_map(|c| c.to_le_bytes()).collect();
    piece(&covariance);
    match input {
        None => piece(b"none"),
        Some(pb::add_capture_request::Input::Segments(triplet)) => {
            // One list's encoding at a time: a third of the segments' bytes, transiently.
            piece(b"segments");
            for list in &triplet.lists {
                piece(&list.encode_to_vec());
            }
        }
        Some(pb::add_capture_request::Input::Images(triplet)) => {
            piece(b"images");
            for image in &triplet.images {
                match &image.source {
                    None => piece(b"none"),
                    Some(pb::image::Source::Encoded(bytes)) => {
                        piece(b"encoded");
                        piece(bytes);
                    }
                    Some(pb::image::Source::Raw(raw)) => {
                        piece(b"raw");
                        piece(&raw.width.to_le_bytes());
                        piece(&raw.height.to_le_bytes());
                        piece(&raw.data);
                    }
                }
            }
        }
    }
    hash.finalize().to_vec()
}

/// What became of a capture AddCapture placed or found: stored by this call, or found
/// stored under its name (a retry).
enum Outcome {
    Stored {
        index: u64,
        registration: pb::Registration,
    },
    Found {
        index: u64,
        capture: Vec<u8>,
    },
}

/// The registration a named capture was first answered with, for a retry of it:
/// ALREADY_EXISTS naming `capture_id` if the retry is not the same capture (another digest).
fn answered_registration(
    name: &str,
    digest: &[u8],
    index: u64,
    capture: &[u8],
) -> Result<pb::Registration, ServiceError> {
    let stored = pb::StoredCaptureAnswer::decode(capture).map_err(|e| corrupt("capture", e))?;
    if stored.capture_id != name {
        return Err(ServiceError::Internal {
            detail: format!(
                "the store names capture {index} {name:?}, which holds {:?}",
                stored.capture_id
            ),
        });
    }
    if stored.request_digest != digest {
        return Err(ServiceError::AlreadyExists {
            field: "capture_id".to_string(),
            what: format!(
                "{name:?} names capture {index} of this session, which was sent with another \
                 pose, covariance or input: a retry sends the same capture, and another \
                 capture needs a name of its own"
            ),
        });
    }
    stored.registration.ok_or_else(|| ServiceError::Internal {
        detail: format!("stored capture {index} is named but holds no registration"),
    })
}

/// Session ids are looked up as given; refusing odd ones early keeps them out of store keys
/// and logs.
fn check_id(id: &str) -> Result<(), ServiceError> {
    check_session_id(id).map_err(ServiceError::Input)
}

impl Service {
    fn session_pb(
        &self,
        caller: &Caller,
        info: &SessionInfo,
        full: bool,
    ) -> Result<pb::Session, ServiceError> {
        let r = &info.record;
        let (calibration, stored) = if full {
            let calibration = pb::Calibration::decode(&r.calibration[..])
                .map_err(|e| corrupt("calibration", e))?;
            let stored =
                pb::StoredOptions::decode(&r.options[..]).map_err(|e| corrupt("options", e))?;
            (Some(calibration), stored)
        } else {
            (None, pb::StoredOptions::default())
        };
        Ok(pb::Session {
            id: public_id(caller, &r.id).unwrap_or(&r.id).to_string(),
            name: r.name.clone(),
            created_unix_ms: r.created_unix_ms,
            last_used_unix_ms: info.last_used_unix_ms,
            captures: info.captures,
            calibration,
            options: stored.options,
            map_options: stored.map_options,
            idle_ttl_s: self.store_ttl.as_secs(),
        })
    }

    pub async fn create_session(
        &self,
        caller: &Caller,
        request: pb::CreateSessionRequest,
    ) -> Result<pb::Session, ServiceError> {
        async {
            trinocular_schema::session::check_create_session(&request)?;
            let pb::CreateSessionRequest {
                name,
                calibration,
                options,
                map_options,
                session_id,
            } = request;
            let given = !session_id.is_empty();
            let id = if given {
                session_id
            } else {
                uuid::Uuid::new_v4().simple().to_string()
            };
            let record = SessionRecord {
                id: store_id(caller, &id),
                name,
                created_unix_ms: self.clock.now_unix_ms(),
                calibration: calibration.unwrap_or_default().encode_to_vec(),
                options: pb::StoredOptions {
                    options,
                    map_options,
                }
                .encode_to_vec(),
            };
            // A retry of a create whose answer was lost finds its session: answered as it
            // stands, and not counted against the key's quota a second time.
            if given {
                if let Some(session) = self.created_before(caller, &record).await? {
                    return Ok(session);
                }
            }
            if caller.tenant.is_some() {
                let held = self.own_sessions(caller).await?.len();
                if held >= self.max_sessions_per_key {
                    return Err(ServiceError::QuotaExceeded {
                        limit: self.max_sessions_per_key,
                    });
                }
            }
            match self.store.create(&record).await {
                Ok(()) => {}
                // Created meanwhile by the call this one repeats (or taken by another).
                Err(StoreError::AlreadyExists { .. }) if given => {
                    return self.created_before(caller, &record).await?.ok_or_else(|| {
                        ServiceError::Internal {
                            detail: "a session id both taken and free".to_string(),
                        }
                    });
                }
                Err(e) => return Err(e.into()),
            }
            let info = SessionInfo {
                last_used_unix_ms: record.created_unix_ms,
                captures: 0,
                record,
            };
            self.session_pb(caller, &info, true)
        }
        .await
    }

    /// The live session with `record`'s id, when it was created with the same name,
    /// calibration and options (a retry): `None` when there is none; ALREADY_EXISTS naming
    /// `session_id` when it is another session.
    async fn created_before(
        &self,
        caller: &Caller,
        record: &SessionRecord,
    ) -> Result<Option<pb::Session>, ServiceError> {
        let info = match self.store.get(&record.id).await {
            Ok(info) => info,
            Err(StoreError::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        let held = &info.record;
        if held.name != record.name
            || held.calibration != record.calibration
            || held.options != record.options
        {
            let id = public_id(caller, &record.id).unwrap_or(&record.id);
            return Err(ServiceError::AlreadyExists {
                field: "session_id".to_string(),
                what: format!(
                    "session {id:?} exists with another name, calibration or options: a retry \
                     sends the same session, and another session needs an id of its own"
                ),
            });
        }
        self.session_pb(caller, &info, true).map(Some)
    }

    pub async fn get_session(
        &self,
        caller: &Caller,
        id: &str,
    ) -> Result<pb::Session, ServiceError> {
        async {
            check_id(id)?;
            let info = self.store.get(&store_id(caller, id)).await?;
            self.session_pb(caller, &info, true)
        }
        .await
    }

    /// A session's capture count, from its stored record alone (nothing decoded): what a live
    /// view reads when it opens (a use of the session, which keeps it alive).
    pub async fn session_captures(&self, caller: &Caller, id: &str) -> Result<u64, ServiceError> {
        check_id(id)?;
        Ok(self.store.get(&store_id(caller, id)).await?.captures)
    }

    /// [`Service::session_captures`] for an open live view's later looks: they read the session
    /// without refreshing its idle TTL, so a watched session nobody uses still expires (and
    /// the view is told `gone`).
    pub async fn watched_session_captures(
        &self,
        caller: &Caller,
        id: &str,
    ) -> Result<u64, ServiceError> {
        check_id(id)?;
        Ok(self.store.peek(&store_id(caller, id)).await?.captures)
    }

    /// The caller's sessions, a page at a time: at most `page_size` (0: the default, 100;
    /// at most 1000) of those whose id comes after `page_token` (empty: the first page), by
    /// id; `next_page_token` is empty on the last page.
    pub async fn list_sessions(
        &self,
        caller: &Caller,
        request: pb::ListSessionsRequest,
    ) -> Result<pb::ListSessionsResponse, ServiceError> {
        async {
            let pb::ListSessionsRequest {
                page_size,
                page_token,
            } = request;
            let page_size = match page_size {
                0 => DEFAULT_PAGE_SIZE,
                n if n as usize <= MAX_PAGE_SIZE => n as usize,
                n => {
                    return Err(ServiceError::Input(InputError::new(
                        "page_size",
                        format!(
                        "must be 0 (the default, {DEFAULT_PAGE_SIZE}) to {MAX_PAGE_SIZE}, got {n}"
                    ),
                    )))
                }
            };
            if !page_token.is_empty() {
                check_id(&page_token).map_err(|_| {
                    ServiceError::Input(InputError::new(
                        "page_token",
                        "is not a token this service gave",
                    ))
                })?;
            }
            let mut sessions = self.own_sessions(caller).await?;
            sessions.retain(|(id, _)| page_token.is_empty() || id.as_str() > page_token.as_str());
            let more = sessions.len() > page_size;
            sessions.truncate(page_size);
            let next_page_token = if more {
                sessions
                    .last()
                    .map(|(id, _)| id.clone())
                    .unwrap_or_default()
            } else {
                String::new()
            };
            Ok(pb::ListSessionsResponse {
                sessions: sessions
                    .iter()
                    .map(|(_, info)| self.session_pb(caller, info, false))
                    .collect::<Result<_, _>>()?,
                next_page_token,
            })
        }
        .await
    }

    /// The caller's live sessions with their public ids, sorted by public id.
    async fn own_sessions(
        &self,
        caller: &Caller,
    ) -> Result<Vec<(String, SessionInfo)>, ServiceError> {
        let mut own: Vec<(String, SessionInfo)> = self
            .store
            .list()
            .await?
            .into_iter()
            .filter_map(|info| Some((public_id(caller, &info.record.id)?.to_string(), info)))
            .collect();
        own.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(own)
    }

    pub async fn delete_session(&self, caller: &Caller, id: &str) -> Result<(), ServiceError> {
        async {
            check_id(id)?;
            let stored_id = store_id(caller, id);
            self.store.delete(&stored_id).await?;
            self.session_changed(&stored_id);
            Ok(())
        }
        .await
    }

    /// Matches one capture with the session's rig and options, registers it to the map from
    /// the pose given (`map::register`: the pose is a prior), then stores the refined pose and
    /// the capture's 3D segments. A bad pose or input is refused before anything is stored; a
    /// capture whose match failed is not stored either.
    ///
    /// The match keeps its uncertain segments for registration (each counts by its
    /// covariance) and for later refinements; the answer and the map leave them out unless the
    /// session's options asked for them.
    pub async fn add_capture(
        &self,
        caller: &Caller,
        request: pb::AddCaptureRequest,
        timeout: Option<Duration>,
    ) -> Result<pb::AddCaptureResponse, ServiceError> {
        async {
            let started = self.clock.monotonic();
            let pb::AddCaptureRequest {
                session_id,
                rig_to_world,
                input,
                rig_to_world_covariance,
                capture_id,
            } = request;
            check_id(&session_id)?;
            let name = (!capture_id.is_empty()).then_some(capture_id);
            if let Some(name) = &name {
                check_capture_id(name)?;
            }
            let session_id = store_id(caller, &session_id);
            let Some(rig_to_world) = rig_to_world else {
                return Err(ServiceError::Input(InputError::new(
                    "rig_to_world",
                    "missing: where the robot believes the rig was (a row-major 4x4 rigid \
                     transform), with rig_to_world_covariance saying how sure it is. A capture \
                     is registered to the map from that pose; registration without one \
                     (global) is not supported",
                )));
            };
            let (pose, pose_warning) = capture_pose_from_pb(Some(&rig_to_world), "rig_to_world")?;
            let prior = pose_prior(pose, &rig_to_world_covariance, "rig_to_world_covariance")?;
            let info = self.store.get(&session_id).await?;
            // A retry of a capture the session holds is answered, not stored again (below):
            // the match is run again, placing is not.
            let earlier = match &name {
                Some(name) => self.store.named_capture(&session_id, name).await?,
                None => None,
            };
            if earlier.is_none() && info.captures >= MAX_CAPTURES_PER_SESSION {
                return Err(ServiceError::Input(InputError::new(
                    "session_id",
                    format!(
                        "the session holds {MAX_CAPTURES_PER_SESSION} captures, the most one may; \
                         start another session"
                    ),
                )));
            }
            let calibration = pb::Calibration::decode(&info.record.calibration[..])
                .map_err(|e| corrupt("calibration", e))?;
            let stored = pb::StoredOptions::decode(&info.record.options[..])
                .map_err(|e| corrupt("options", e))?;
            let mut options = stored.options.unwrap_or_default();
            let asked_uncertain = options.include_uncertain == Some(true);
            options.include_uncertain = Some(true);
            // Placing refines the capture's pose in its own images' segments: the match
            // hands back what it extracted, or the lists given are kept.
            let asked_extracted = options.return_extracted == Some(true);
            options.return_extracted = Some(true);
            let list_noise_px = match_params(Some(&options)).line_noise_px;
            let rig_calibration = calibration.clone();
            let given_lists = match &input {
                Some(pb::add_capture_request::Input::Segments(triplet)) => Some(triplet.clone()),
                _ => None,
            };
            // A named capture's digest is taken on the pool, with the match's decoding: an
            // image triplet is megabytes.
            let digest = Arc::new(std::sync::Mutex::new(Vec::new()));
            let digest_of_input = name.as_ref().map(|_| {
                let digest = Arc::clone(&digest);
                let pose = rig_to_world.clone();
                let covariance = rig_to_world_covariance.clone();
                move |input: Option<&pb::add_capture_request::Input>| {
                    *digest.lock().unwrap_or_else(|p| p.into_inner()) =
                        capture_digest(&pose, &covariance, input);
                }
            });
            let read = move || {
                if let Some(digest_of_input) = digest_of_input {
                    digest_of_input(input.as_ref());
                }
                Ok(capture_match_request(calibration, Some(options), input))
            };
            let (everything, ()) = self.run_match(read, |_| (), timeout).await?;
            let digest = std::mem::take(&mut *digest.lock().unwrap_or_else(|p| p.into_inner()));
            let already_placed = earlier.is_some();
            let captures = if already_placed {
                Vec::new()
            } else {
                self.store.captures(&session_id).await?
            };
            // Placing, and the stored record's encoding, on the pool: the tokio worker only
            // hands over and stores.
            let clock = Arc::clone(&self.clock);
            let placed_name = name.clone();
            let placed_digest = digest.clone();
            let job = self.pool.run(move |abandoned| {
                let stop = || abandoned.is_set();
                let checkpoint = Checkpoint::new(&stop);
                let rig =
                    rig_from_calibration(Some(&rig_calibration)).map_err(ServiceError::Input)?;
                let mut everything = everything;
                let seen = given_lists.unwrap_or_else(|| pb::SegmentTriplet {
                    lists: std::mem::take(&mut everything.extracted),
                });
                let added = if already_placed {
                    None
                } else {
                    let lists = segment_lists(&seen, usize::MAX).ok();
                    let views = lists.as_ref().map(|lists| Views {
                        cameras: rig.cameras(),
                        segments: std::array::from_fn(|k| &lists[k].segments[..]),
                        list_noise_px,
                    });
                    Some(place_capture(
                        &captures,
                        &everything.segments_3d,
                        views.as_ref(),
                        &prior,
                        checkpoint,
                    )?)
                };
                if asked_extracted {
                    everything.extracted = seen.lists;
                }
                let placed = added.map(|added| {
                    let mut stored =
                        stored_capture(&everything, &added, &pose, &prior, clock.now_unix_ms());
                    if let Some(name) = placed_name {
                        stored.capture_id = name;
                        stored.request_digest = placed_digest;
                    }
                    (
                        registration_to_pb(&added.registration),
                        stored.encode_to_vec(),
                    )
                });
                let response = if asked_uncertain {
                    everything
                } else {
                    certain_only(&everything)
                };
                Ok::<_, ServiceError>((placed, response))
            });
            let deadline = self.deadline(timeout);
            let left = deadline.saturating_sub(self.clock.since(started));
            let (placed, response) = super::within_what_is_left(job, left, deadline).await?;
            let outcome = match (placed, earlier) {
                (Some((registration, stored)), _) => {
                    match self
                        .store
                        .append_named(&session_id, &stored, name.as_deref(), &info.record)
                        .await?
                    {
                        Appended::New(index) => Outcome::Stored {
                            index,
                            registration,
                        },
                        // The same capture, stored meanwhile by another call (the first
                        // attempt of this retry, still running when it was sent).
                        Appended::Existing { index, capture } => Outcome::Found { index, capture },
                    }
                }
                (None, Some((index, capture))) => Outcome::Found { index, capture },
                (None, None) => {
                    return Err(ServiceError::Internal {
                        detail: "a capture neither placed nor stored before".to_string(),
                    })
                }
            };
            let (capture_index, registration, captures, duplicate) = match outcome {
                Outcome::Stored {
                    index,
                    registration,
                } => {
                    self.session_changed(&session_id);
                    (index, registration, index + 1, false)
                }
                Outcome::Found { index, capture } => {
                    let name = name.as_deref().unwrap_or_default();
                    let registration = answered_registration(name, &digest, index, &capture)?;
                    let captures = self.store.get(&session_id).await?.captures;
                    (index, registration, captures, true)
                }
            };
            self.metrics.record_capture(duplicate);
            Ok(pb::AddCaptureResponse {
                r#match: Some(response),
                capture_index,
                map: Some(pb::MapSummary { captures }),
                registration: Some(registration),
                warnings: pose_warning.into_iter().collect(),
                duplicate,
            })
        }
        .await
    }

    /// The session's map, fused on the compute pool from its stored captures.
    /// `min_observations` overrides the session's map option.
    pub async fn get_map(
        &self,
        caller: &Caller,
        id: &str,
        min_observations: Option<u32>,
    ) -> Result<SessionMap, ServiceError> {
        async {
            check_id(id)?;
            if min_observations == Some(0) {
                return Err(ServiceError::Input(InputError::new(
                    "min_observations",
                    "must be at least 1",
                )));
            }
            let stored_id = store_id(caller, id);
            let info = self.store.get(&stored_id).await?;
            let stored = pb::StoredOptions::decode(&info.record.options[..])
                .map_err(|e| corrupt("options", e))?;
            let calibration = info.record.calibration.clone();
            let captures = self.store.captures(&stored_id).await?;
            let refine_poses = stored
                .map_options
                .as_ref()
                .and_then(|m| m.refine_poses)
                .unwrap_or(true);
            let min_observations = min_observations
                .or(stored.map_options.and_then(|m| m.min_observations))
                .unwrap_or(1);
            let gate = MapGate::of(&match_params(stored.options.as_ref()));
            let (session_id, clock) = (id.to_string(), Arc::clone(&self.clock));
            let job = self.pool.run(move |abandoned| {
                // The rig's cameras, for the top views: its calibration decomposed here, on
                // the pool, with the rest of the work.
                let calibration = pb::Calibration::decode(&calibration[..])
                    .map_err(|e| corrupt("calibration", e))?;
                let cameras = rig_from_calibration(Some(&calibration)).map_err(|e| {
                    ServiceError::Internal {
                        detail: format!("stored calibration is not a rig: {e}"),
                    }
                })?;
                let options = MapBuild {
                    min_observations,
                    refine_poses,
                    // The shift the rig's views share, added once to each map segment (the
                    // captures were fused without it).
                    gate: gate.sharing_shift(&cameras),
                    rig: RigMarker::of(&cameras),
                };
                let stop = || abandoned.is_set();
                let checkpoint = Checkpoint::new(&stop);
                fuse_stored(session_id, &captures, options, clock.as_ref(), checkpoint)
            });
            // Fusing is compute like Match: it keeps to the service's longest request time.
            super::within(job, self.deadline(None)).await
        }
        .await
    }
}

/// Decodes the stored captures and fuses them (on the compute pool), timed on `clock`; stops
/// at `checkpoint` (the caller gone, or its deadline past) rather than solve or fuse for
/// nobody.
fn fuse_stored(
    session_id: String,
    captures: &[Vec<u8>],
    options: MapBuild,
    clock: &dyn Clock,
    checkpoint: Checkpoint,
) -> Result<SessionMap, ServiceError> {
    let start = clock.monotonic();
    let stored = decode_captures(captures)?;
    let priors: Vec<PosePrior> = stored.iter().map(|(s, _)| s.prior).collect();
    // Refined, the poses are the pose graph's solution: every capture's odometry and the
    // edges each capture found when it was added, each pose with its marginal covariance.
    // Nothing is registered again here. Not refined, they are as given, and taken as exact.
    let poses: Vec<PosePrior> = if options.refine_poses {
        let edges: Vec<RelativePose> = stored.iter().flat_map(|(_, e)| e.clone()).collect();
        check_graph(stored.len(), &edges)?;
        map::session::solve_poses_until(&placed(&stored), &edges, checkpoint)?
    } else {
        priors
            .iter()
            .map(|p| PosePrior {
                rig_to_world: p.rig_to_world,
                covariance: Matrix6::zeros(),
            })
            .collect()
    };
    let prior_poses: Vec<_> = priors.iter().map(|p| p.rig_to_world).collect();
    // The map fuses what met the capture's gate, each segment by its covariance.
    let fused: Vec<(Vec<Segment3>, Vec<Matrix6<f64>>)> = stored
        .iter()
        .map(|(s, _)| {
            s.measured
                .iter()
                .filter(|m| !m.uncertain)
                .map(|m| {
                    let segment = Segment3 {
                        start: m.start,
                        end: m.end,
                    };
                    (segment, m.covariance)
                })
                .unzip()
        })
        .collect();
    let inputs: Vec<map::Capture> = fused
        .iter()
        .zip(&poses)
        .enumerate()
        .map(|(i, ((segments, covariances), pose))| map::Capture {
            id: i as u32,
            rig_to_world: pose.rig_to_world,
            segments,
            covariances,
            pose_covariance: pose.covariance,
        })
        .collect();
    let params = FuseParams {
        min_observations: options.min_observations,
        gate: Some(options.gate),
        ..FuseParams::default()
    };
    checkpoint.before("fusion")?;
    let segments = map::fuse(&inputs, &params);
    Ok(SessionMap {
        session_id,
        segments,
        poses: poses.iter().map(|p| p.rig_to_world).collect(),
        prior_poses,
        fuse_ms: clock.since(start).as_secs_f64() * 1e3,
        rig: options.rig,
    })
}

/// How GetMap builds a map, from the session's options and the call.
#[derive(Debug, Clone, Copy)]
struct MapBuild {
    min_observations: u32,
    /// Solve the poses (`map::session::solve_poses`) rather than take them as given.
    refine_poses: bool,
    /// The promise the map keeps: the session's match options' gate.
    gate: MapGate,
    /// Where the rig's cameras are, for the top views.
    rig: RigMarker,
}

/// Each stored capture's segments and poses, with the pose-graph edges it holds.
fn decode_captures(
    captures: &[Vec<u8>],
) -> Result<Vec<(StoredSegments, Vec<RelativePose>)>, ServiceError> {
    captures
        .iter()
        .enumerate()
        .map(|(index, bytes)| {
            let capture =
                pb::StoredCapture::decode(&bytes[..]).map_err(|e| corrupt("capture", e))?;
            let segments = stored_capture_segments(&capture).map_err(|e| damaged(index, e))?;
            let edges = edges_of(&capture.edges, index).map_err(|e| damaged(index, e))?;
            Ok((segments, edges))
        })
        .collect()
}

/// The stored captures as the core's session sees them.
fn placed(stored: &[(StoredSegments, Vec<RelativePose>)]) -> Vec<Placed<'_>> {
    stored
        .iter()
        .map(|(s, _)| Placed {
            prior: s.prior,
            segments: &s.measured,
        })
        .collect()
}

/// Refuses a session whose pose graph would take longer to solve than a request may
/// ([`map::session::MAX_GRAPH_WORK`]), from its edges alone, before anything is allocated
/// for it.
fn check_graph(captures: usize, edges: &[RelativePose]) -> Result<(), ServiceError> {
    let work = map::session::graph_work(captures, edges);
    if work > map::session::MAX_GRAPH_WORK {
        return Err(ServiceError::Input(InputError::new(
            "session_id",
            format!(
                "the session's pose graph is too wide to solve: its captures tie back to so \
                 many others that a solve takes {work} products of 6x6 blocks, the most is {}; \
                 start another session (or read this one's map with the map option \
                 refine_poses false)",
                map::session::MAX_GRAPH_WORK
            ),
        )));
    }
    Ok(())
}

/// The record a capture is stored as: its refined pose and covariance, the pose it was given
/// with its covariance, every 3D segment of its match (uncertain ones too, for registration
/// and later refinement) and the pose-graph edges it found.
fn stored_capture(
    matched: &pb::MatchResponse,
    added: &Added,
    given: &nalgebra::Isometry3<f64>,
    prior: &PosePrior,
    received_unix_ms: u64,
) -> pb::StoredCapture {
    let registration = &added.registration;
    pb::StoredCapture {
        rig_to_world: Some(pose_to_pb(&registration.rig_to_world)),
        segments: matched
            .segments_3d
            .iter()
            .map(|s| pb::Segment3 {
                start: s.start,
                end: s.end,
                covariance: s.covariance.clone(),
                uncertain: s.uncertain,
                shift_sigma_m: s.shift_sigma_m,
                along_dominant_direction: s.along_dominant_direction,
                ..Default::default()
            })
            .collect(),
        received_unix_ms,
        prior_rig_to_world: Some(pose_to_pb(given)),
        prior_covariance: matrix6_to_vec(&prior.covariance),
        pose_covariance: matrix6_to_vec(&registration.covariance),
        status: status_to_pb(registration.status) as i32,
        edges: edges_to_pb(&added.edges),
        registration: Some(registration_to_pb(registration)),
        capture_id: String::new(),
        request_digest: Vec::new(),
    }
}

/// Places a new capture's segments (rig frame, as the match answered them) in the session
/// (on the compute pool): registered to the stored captures as a map, and to each one it
/// overlaps as an edge of the pose graph (`map::session::add_capture`). Every capture's
/// poses and edges are read, but the segments only of the few neighbours placing uses: a
/// session of hundreds of captures is not decoded whole for each one added.
fn place_capture(
    captures: &[Vec<u8>],
    segments: &[pb::Segment3],
    views: Option<&Views>,
    prior: &PosePrior,
    checkpoint: Checkpoint,
) -> Result<Added, ServiceError> {
    let mut priors: Vec<PosePrior> = Vec::with_capacity(captures.len());
    let mut edges: Vec<RelativePose> = Vec::new();
    for (index, bytes) in captures.iter().enumerate() {
        let header =
            pb::StoredCaptureHeader::decode(&bytes[..]).map_err(|e| corrupt("capture", e))?;
        let (given, found) = stored_header_of(&header, index).map_err(|e| damaged(index, e))?;
        priors.push(given);
        edges.extend(found);
    }
    check_graph(priors.len(), &edges)?;
    let params = SessionParams::default();
    let unread: Vec<Placed> = priors
        .iter()
        .map(|&prior| Placed {
            prior,
            segments: &[],
        })
        .collect();
    let neighbours = map::session::neighbours_until(&unread, &edges, prior, &params, checkpoint)?;
    let mut measured: Vec<Vec<Measured>> = vec![Vec::new(); captures.len()];
    for index in neighbours.needed() {
        let capture =
            pb::StoredCapture::decode(&captures[index][..]).map_err(|e| corrupt("capture", e))?;
        measured[index] = StoredSegments::measured_of(&capture.segments);
    }
    let placed: Vec<Placed> = priors
        .iter()
        .zip(&measured)
        .map(|(&prior, segments)| Placed { prior, segments })
        .collect();
    let capture = StoredSegments::measured_of(segments);
    Ok(map::session::place_until(
        &placed,
        &neighbours,
        prior,
        &capture,
        views,
        &params,
        checkpoint,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Isometry3;

    #[test]
    fn a_stored_capture_keeps_the_shift_its_segments_share() {
        // Registration and fusion read a stored capture's covariances without the shift its
        // three views share (`StoredSegments::measured_of`), so the record must keep it.
        let segment = pb::Segment3 {
            start: Some(pb::Point3 {
                x: 0.0,
                y: 0.0,
                z: 2.0,
            }),
            end: Some(pb::Point3 {
                x: 0.0,
                y: 0.5,
                z: 2.0,
            }),
            covariance: vec![1e-6; 36],
            shift_sigma_m: 0.0012,
            ..Default::default()
        };
        let matched = pb::MatchResponse {
            segments_3d: vec![segment],
            ..Default::default()
        };
        let prior = PosePrior::with_default_covariance(Isometry3::identity());
        let added = Added {
            registration: trinocular_core::map::Registration {
                rig_to_world: Isometry3::identity(),
                covariance: prior.covariance,
                status: trinocular_core::map::RegistrationStatus::EmptyMap,
                inliers: 0,
                rotation_change_deg: 0.0,
                translation_change_m: 0.0,
            },
            edges: Vec::new(),
        };
        let stored = stored_capture(&matched, &added, &Isometry3::identity(), &prior, 0);
        assert_eq!(stored.segments.len(), 1);
        assert_eq!(stored.segments[0].shift_sigma_m, 0.0012);
        assert_eq!(stored.segments[0].covariance, vec![1e-6; 36]);
    }

    #[test]
    fn capture_ids_are_short_printable_ascii() {
        for good in [
            "a",
            "robot-7/capture-0001",
            "0f8fad5b-d9cb-469f-a165-70867728950e",
        ] {
            assert!(check_capture_id(good).is_ok(), "{good}");
        }
        assert!(check_capture_id(&"x".repeat(MAX_CAPTURE_ID_BYTES)).is_ok());
        for bad in [
            "two words",
            "tab\there",
            "line\nbreak",
            "caf\u{e9}",
            "\u{0}",
            &"x".repeat(MAX_CAPTURE_ID_BYTES + 1),
        ] {
            match check_capture_id(bad) {
                Err(ServiceError::Input(e)) => {
                    assert_eq!(e.field, "capture_id");
                    assert!(e.to_string().len() < 200, "{e}");
                }
                other => panic!("{bad:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn a_capture_digest_tells_every_part_of_the_capture_apart() {
        let pose = pose_to_pb(&Isometry3::identity());
        let image = |bytes: &[u8]| pb::Image {
            source: Some(pb::image::Source::Encoded(bytes.to_vec())),
        };
        let images = |parts: [&[u8]; 3]| {
            Some(pb::add_capture_request::Input::Images(pb::ImageTriplet {
                images: parts.map(image).to_vec(),
            }))
        };
        let base = capture_digest(&pose, &[], images([b"ab", b"c", b"d"]).as_ref());
        assert_eq!(base.len(), 32);
        assert_eq!(
            base,
            capture_digest(&pose, &[], images([b"ab", b"c", b"d"]).as_ref()),
            "the same capture, the same digest"
        );
        // Bytes moved from one image to the next are another capture.
        assert_ne!(
            base,
            capture_digest(&pose, &[], images([b"a", b"bc", b"d"]).as_ref())
        );
        let mut moved = pose.clone();
        moved.matrix[3] = 0.01;
        assert_ne!(
            base,
            capture_digest(&moved, &[], images([b"ab", b"c", b"d"]).as_ref())
        );
        assert_ne!(
            base,
            capture_digest(&pose, &[1e-4; 36], images([b"ab", b"c", b"d"]).as_ref())
        );
        let raw = Some(pb::add_capture_request::Input::Images(pb::ImageTriplet {
            images: vec![
                pb::Image {
                    source: Some(pb::image::Source::Raw(pb::RawImage {
                        width: 2,
                        height: 1,
                        data: b"ab".to_vec(),
                    })),
                },
                image(b"c"),
                image(b"d"),
            ],
        }));
        assert_ne!(
            base,
            capture_digest(&pose, &[], raw.as_ref()),
            "raw is not encoded"
        );
        let lists = |v: f64| {
            Some(pb::add_capture_request::Input::Segments(
                pb::SegmentTriplet {
                    lists: vec![
                        pb::SegmentList {
                            segments: vec![pb::Segment {
                                u1: v,
                                ..Default::default()
                            }],
                            ..Default::default()
                        };
                        3
                    ],
                },
            ))
        };
        let segments = capture_digest(&pose, &[], lists(1.0).as_ref());
        assert_ne!(segments, base);
        assert_ne!(segments, capture_digest(&pose, &[], lists(1.5).as_ref()));
        assert_ne!(base, capture_digest(&pose, &[], None));
    }

    /// A stored capture with no segments, at the origin, tied by `edges`.
    fn stored(index: usize, edges: &[RelativePose]) -> Vec<u8> {
        let prior = PosePrior::with_default_covariance(Isometry3::identity());
        pb::StoredCapture {
            rig_to_world: Some(pose_to_pb(&prior.rig_to_world)),
            prior_rig_to_world: Some(pose_to_pb(&prior.rig_to_world)),
            prior_covariance: matrix6_to_vec(&prior.covariance),
            pose_covariance: matrix6_to_vec(&prior.covariance),
            edges: edges_to_pb(
                &edges
                    .iter()
                    .filter(|e| e.from == index)
                    .copied()
                    .collect::<Vec<_>>(),
            ),
            ..Default::default()
        }
        .encode_to_vec()
    }

    /// AddCapture's placing on the pool stops, rather than solve and register for nobody,
    /// once its caller has gone or its deadline has passed.
    #[test]
    fn placing_a_capture_stops_once_nobody_waits_for_it() {
        let captures: Vec<Vec<u8>> = (0..3).map(|k| stored(k, &[])).collect();
        let prior = PosePrior::with_default_covariance(Isometry3::identity());
        let gone = || true;
        match place_capture(&captures, &[], None, &prior, Checkpoint::new(&gone)) {
            Err(ServiceError::Stopped { stage }) => assert_eq!(stage, "pose graph"),
            other => panic!("expected the job to stop, got {other:?}"),
        }
        assert!(place_capture(&captures, &[], None, &prior, Checkpoint::NEVER).is_ok());
    }

    #[test]
    fn a_session_whose_pose_graph_is_too_wide_is_refused_naming_it() {
        // A square hall mown in rows of 100, each capture tied to the one before it and to
        // its neighbour in the row before.
        let edge = |from: usize, to: usize| RelativePose {
            from,
            to,
            pose: Isometry3::identity(),
            information: Matrix6::identity(),
            inliers: 10,
        };
        let tied = |n: usize| -> Vec<Vec<u8>> {
            let edges: Vec<RelativePose> = (1..n)
                .flat_map(|k| {
                    let mut e = vec![edge(k, k - 1)];
                    if k >= 100 {
                        e.push(edge(k, k - 100));
                    }
                    e
                })
                .collect();
            (0..n).map(|k| stored(k, &edges)).collect()
        };
        let prior = PosePrior::with_default_covariance(Isometry3::identity());
        let small = tied(300);
        assert!(place_capture(&small, &[], None, &prior, Checkpoint::NEVER).is_ok());
        let wide = tied(10_000);
        match place_capture(&wide, &[], None, &prior, Checkpoint::NEVER) {
            Err(ServiceError::Input(e)) => {
                assert_eq!(e.field, "session_id");
                assert!(e.message.contains("too wide"), "{}", e.message);
            }
            other => panic!("expected a refusal naming session_id, got {other:?}"),
        }
    }
}
