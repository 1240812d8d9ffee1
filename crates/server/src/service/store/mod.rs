//! Where sessions live. A robot creates a session (its rig calibration and match options, stored
//! once), then appends captures (a pose and that capture's 3D segments, encoded by the caller)
//! and later asks for all of them to fuse a map. The service itself keeps no state, so several
//! replicas can share one store: one [`SessionStore`] trait, two back ends chosen by URL.
//!
//! ```text
//! open("embedded", data_dir, ttl)     ─▶ EmbeddedStore: one redb file, data_dir/trinocular.redb
//! open("redis://host:port/db", _, ttl) ─▶ RedisStore: keys under `trinocular:`, shared by replicas
//! ```
//!
//! A session not used (get, append, captures) for longer than the idle TTL disappears with its
//! captures. The memory and embedded stores measure that idleness by an injected
//! [`Clock`](super::clock::Clock) (the system clock unless a test sets another with
//! `with_clock`); Redis by its server's clock. Records and captures are opaque bytes here: the
//! store never decodes them.

pub mod embedded;
pub mod memory;
pub mod redis;

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

pub use self::redis::RedisStore;
pub use embedded::EmbeddedStore;
pub use memory::MemoryStore;

/// What a session was created with. `calibration` and `options` are encoded protobuf messages,
/// the caller's business.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionRecord {
    pub id: String,
    pub name: String,
    pub created_unix_ms: u64,
    pub calibration: Vec<u8>,
    pub options: Vec<u8>,
}

/// A live session: its record, how many captures it holds and when it was last used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionInfo {
    pub record: SessionRecord,
    pub captures: u64,
    pub last_used_unix_ms: u64,
}

/// The storage layer's one error type.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StoreError {
    /// No such session (never created, deleted, or expired).
    #[error("no session {id:?}")]
    NotFound { id: String },
    /// The store cannot be reached or failed (server down, I/O error, file locked); the message
    /// names the store and what failed. Retrying later may work.
    #[error("{message}")]
    Unavailable { message: String },
    /// What the store holds cannot be read back: a bug or a damaged file.
    #[error("corrupt data: {message}")]
    Corrupt { message: String },
    /// `create` with an id that a live session already has.
    #[error("session {id:?} already exists")]
    AlreadyExists { id: String },
}

/// What [`SessionStore::append_named`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Appended {
    /// Stored, at this index.
    New(u64),
    /// The session held a capture of that name already: this one, at that index.
    Existing { index: u64, capture: Vec<u8> },
}

/// Session storage, shared by the service as `Arc<dyn SessionStore>`.
#[async_trait::async_trait]
pub trait SessionStore: Send + Sync {
    /// Stores a new session; [`StoreError::AlreadyExists`] if the id is taken by a live one.
    async fn create(&self, record: &SessionRecord) -> Result<(), StoreError>;
    /// The session; refreshes its idle TTL.
    async fn get(&self, id: &str) -> Result<SessionInfo, StoreError>;
    /// The session as [`SessionStore::get`] reads it, without refreshing its idle TTL: what a
    /// live view's periodic look reads, so that a watched session still expires when nobody
    /// uses it (a forgotten browser tab kept its session, and its place in the key's quota,
    /// alive for ever).
    async fn peek(&self, id: &str) -> Result<SessionInfo, StoreError>;
    /// The live sessions, sorted by id (does not refresh their TTL).
    async fn list(&self) -> Result<Vec<SessionInfo>, StoreError>;
    /// Removes the session and its captures.
    async fn delete(&self, id: &str) -> Result<(), StoreError>;
    /// Appends a capture to the session as it is now (its record read first), in one atomic
    /// step, and returns its index (0, 1, 2, ...); refreshes the TTL. Concurrent appends (from
    /// any replica) each get their own index. The stores' tests use it; the service appends
    /// with [`SessionStore::append_named`] against the record it matched, with no second read.
    #[cfg(test)]
    async fn append_capture(&self, id: &str, capture: &[u8]) -> Result<u64, StoreError> {
        let record = self.get(id).await?.record;
        match self.append_named(id, capture, None, &record).await? {
            Appended::New(index) | Appended::Existing { index, .. } => Ok(index),
        }
    }
    /// Appends a capture under the client's `name` for it, in one atomic step, to the session
    /// whose record is `matched` — the one the capture was matched and placed against. A
    /// session deleted meanwhile and created again under the same id with another record
    /// (other options, another calibration) is another session: [`StoreError::NotFound`],
    /// nothing written. When the session already holds a capture of that name (a retry, or
    /// the same capture sent twice at once to two replicas), nothing is written and that
    /// capture comes back. Names are the session's: they go with it.
    async fn append_named(
        &self,
        id: &str,
        capture: &[u8],
        name: Option<&str>,
        matched: &SessionRecord,
    ) -> Result<Appended, StoreError>;
    /// The capture the session holds under `name`, with its index; refreshes the TTL.
    async fn named_capture(
        &self,
        id: &str,
        name: &str,
    ) -> Result<Option<(u64, Vec<u8>)>, StoreError>;
    /// Every capture, in append order; refreshes the TTL.
    async fn captures(&self, id: &str) -> Result<Vec<Vec<u8>>, StoreError>;
    /// What this store is, for logs: "embedded redb at /path", "redis at redis://host:6379".
    fn describe(&self) -> String;
}

/// The store `url` names: `embedded` (or empty) for a redb file under `data_dir`, or
/// `redis://host:port[/db]` (`rediss://` too).
pub async fn open(
    url: &str,
    data_dir: &Path,
    ttl: Duration,
) -> Result<Arc<dyn SessionStore>, StoreError> {
    check_url(url).map_err(|message| StoreError::Unavailable { message })?;
    if is_redis(url) {
        Ok(Arc::new(
            RedisStore::open(url, self::redis::DEFAULT_PREFIX, ttl).await?,
        ))
    } else if url == "memory" {
        Ok(Arc::new(MemoryStore::new(ttl)))
    } else {
        Ok(Arc::new(EmbeddedStore::open(data_dir, ttl).await?))
    }
}

/// Whether `url` names a store [`open`] knows; the problem names `store.url`. Configuration
/// validation calls this, so the two cannot disagree.
pub fn check_url(url: &str) -> Result<(), String> {
    if url.is_empty() || url == "embedded" || url == "memory" || is_redis(url) {
        Ok(())
    } else {
        Err(format!(
            "store.url: {url:?} is none of \"embedded\", \"memory\" and redis://host:port[/db]"
        ))
    }
}

/// `url` with its password, if any, replaced by `***`: what may be logged of it.
pub fn redacted(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    let Some((credentials, host)) = rest.rsplit_once('@') else {
        return url.to_string();
    };
    match credentials.split_once(':') {
        Some((user, _password)) => format!("{scheme}://{user}:***@{host}"),
        None => format!("{scheme}://***@{host}"),
    }
}

fn is_redis(url: &str) -> bool {
    url.starts_with("redis://") || url.starts_with("rediss://")
}

#[cfg(test)]
#[test]
fn a_password_is_never_shown() {
    assert_eq!(
        redacted("redis://:s3cret@10.0.0.1:6379/2"),
        "redis://:***@10.0.0.1:6379/2"
    );
    assert_eq!(
        redacted("rediss://app:s3cret@cache:6380"),
        "rediss://app:***@cache:6380"
    );
    assert_eq!(redacted("redis://token@cache"), "redis://***@cache");
    assert_eq!(redacted("redis://cache:6379"), "redis://cache:6379");
    assert_eq!(redacted("embedded"), "embedded");
}

/// The TTL in milliseconds, at least 1 (a zero TTL would expire sessions as they are created).
pub(crate) fn ttl_ms(ttl: Duration) -> u64 {
    (ttl.as_millis() as u64).max(1)
}

/// A record without its id (the id is the key), as both back ends store it: a version byte,
/// `created_unix_ms` (u64 LE), then name, calibration and options, each a u32 LE length and
/// the bytes. A hand-written format keeps the store free of the protobuf schema.
pub(crate) fn encode_record(record: &SessionRecord) -> Vec<u8> {
    let mut out = Vec::with_capacity(
        21 + record.name.len() + record.calibration.len() + record.options.len(),
    );
    out.push(RECORD_VERSION);
    out.extend_from_slice(&record.created_unix_ms.to_le_bytes());
    for field in [record.name.as_bytes(), &record.calibration, &record.options] {
        out.extend_from_slice(&(field.len() as u32).to_le_bytes());
        out.extend_from_slice(field);
    }
    out
}

const RECORD_VERSION: u8 = 1;

/// The record [`encode_record`] wrote for session `id`; any inconsistency is
/// [`StoreError::Corrupt`], never a panic.
pub(crate) fn decode_record(id: &str, bytes: &[u8]) -> Result<SessionRecord, StoreError> {
    let corrupt = |what: &str| StoreError::Corrupt {
        message: format!("session {id:?}: record {what}"),
    };
    let (&version, mut rest) = bytes.split_first().ok_or_else(|| corrupt("is empty"))?;
    if version != RECORD_VERSION {
        return Err(corrupt(&format!("has unknown version {version}")));
    }
    let mut take = |n: usize| -> Result<&[u8], StoreError> {
        if rest.len() < n {
            return Err(corrupt("is truncated"));
        }
        let (head, tail) = rest.split_at(n);
        rest = tail;
        Ok(head)
    };
    let created = u64::from_le_bytes(take(8)?.try_into().map_err(|_| corrupt("is truncated"))?);
    let mut field = || -> Result<Vec<u8>, StoreError> {
        let len = u32::from_le_bytes(take(4)?.try_into().map_err(|_| corrupt("is truncated"))?);
        Ok(take(len as usize)?.to_vec())
    };
    let name = String::from_utf8(field()?).map_err(|_| corrupt("has a name not in UTF-8"))?;
    let calibration = field()?;
    let options = field()?;
    if !rest.is_empty() {
        return Err(corrupt("has trailing bytes"));
    }
    Ok(SessionRecord {
        id: id.to_string(),
        name,
        created_unix_ms: created,
        calibration,
        options,
    })
}

/// Tests both back ends run: the same behaviour whatever the store.
#[cfg(test)]
pub(crate) mod contract {
    use super::*;

    pub fn record(id: &str) -> SessionRecord {
        SessionRecord {
            id: id.to_string(),
            name: format!("rig {id}"),
            created_unix_ms: 1_700_000_000_000,
            calibration: vec![1, 2, 3, 0, 255],
            options: b"opts".to_vec(),
        }
    }

    /// create/get/list/delete, AlreadyExists and NotFound.
    pub async fn crud(store: &dyn SessionStore) {
        let a = record("a");
        let b = record("b");
        store.create(&b).await.unwrap();
        store.create(&a).await.unwrap();
        assert_eq!(
            store.create(&a).await,
            Err(StoreError::AlreadyExists { id: "a".into() })
        );
        let info = store.get("a").await.unwrap();
        assert_eq!(info.record, a);
        assert_eq!(info.captures, 0);
        assert!(info.last_used_unix_ms > 0);
        let listed = store.list().await.unwrap();
        let ids: Vec<&str> = listed.iter().map(|s| s.record.id.as_str()).collect();
        assert_eq!(ids, ["a", "b"], "sorted by id");
        assert_eq!(listed[1].record, b);
        store.delete("a").await.unwrap();
        assert_eq!(
            store.get("a").await,
            Err(StoreError::NotFound { id: "a".into() })
        );
        assert_eq!(
            store.delete("a").await,
            Err(StoreError::NotFound { id: "a".into() })
        );
        let ids: Vec<String> = store
            .list()
            .await
            .unwrap()
            .into_iter()
            .map(|s| s.record.id)
            .collect();
        assert_eq!(ids, ["b"]);
        store.delete("b").await.unwrap();
        assert!(store.list().await.unwrap().is_empty());
    }

    /// Indices 0..n in order; unknown session; delete removes captures.
    pub async fn captures(store: &dyn SessionStore) {
        let missing = StoreError::NotFound { id: "nope".into() };
        assert_eq!(
            store.append_capture("nope", b"x").await,
            Err(missing.clone())
        );
        assert_eq!(store.captures("nope").await, Err(missing));
        store.create(&record("c")).await.unwrap();
        assert!(store.captures("c").await.unwrap().is_empty());
        for i in 0..10u64 {
            let payload = format!("capture {i}").into_bytes();
            assert_eq!(store.append_capture("c", &payload).await.unwrap(), i);
        }
        let all = store.captures("c").await.unwrap();
        let expected: Vec<Vec<u8>> = (0..10)
            .map(|i| format!("capture {i}").into_bytes())
            .collect();
        assert_eq!(all, expected);
        assert_eq!(store.get("c").await.unwrap().captures, 10);
        store.delete("c").await.unwrap();
        // Re-created under the same id, the session starts empty: the old captures are gone.
        store.create(&record("c")).await.unwrap();
        assert!(store.captures("c").await.unwrap().is_empty());
        assert_eq!(store.append_capture("c", b"new").await.unwrap(), 0);
        store.delete("c").await.unwrap();
        // Nothing was stored for the unknown session either.
        assert_eq!(
            store.captures("nope").await,
            Err(StoreError::NotFound { id: "nope".into() })
        );
    }

    /// Named captures: a name stores once, a second append under it answers the first;
    /// names are per session, unnamed appends are unaffected, and delete forgets them.
    pub async fn named_captures(store: &dyn SessionStore) {
        let missing = StoreError::NotFound { id: "nope".into() };
        assert_eq!(
            store
                .append_named("nope", b"x", Some("n"), &record("nope"))
                .await,
            Err(missing.clone())
        );
        assert_eq!(store.named_capture("nope", "n").await, Err(missing));
        store.create(&record("n1")).await.unwrap();
        store.create(&record("n2")).await.unwrap();
        assert_eq!(store.named_capture("n1", "first").await, Ok(None));
        assert_eq!(
            store
                .append_named("n1", b"one", Some("first"), &record("n1"))
                .await,
            Ok(Appended::New(0))
        );
        assert_eq!(store.append_capture("n1", b"unnamed").await, Ok(1));
        assert_eq!(
            store
                .append_named("n1", b"two", Some("second"), &record("n1"))
                .await,
            Ok(Appended::New(2))
        );
        // Sent again under a name the session holds: nothing written, the first comes back
        // (whatever the bytes: comparing them is the caller's business).
        assert_eq!(
            store
                .append_named("n1", b"one again", Some("first"), &record("n1"))
                .await,
            Ok(Appended::Existing {
                index: 0,
                capture: b"one".to_vec()
            })
        );
        assert_eq!(
            store.named_capture("n1", "second").await,
            Ok(Some((2, b"two".to_vec())))
        );
        assert_eq!(store.captures("n1").await.unwrap().len(), 3);
        // Another session's names are its own.
        assert_eq!(store.named_capture("n2", "first").await, Ok(None));
        assert_eq!(
            store
                .append_named("n2", b"other", Some("first"), &record("n2"))
                .await,
            Ok(Appended::New(0))
        );
        // A session created again under the same id starts without names.
        store.delete("n1").await.unwrap();
        store.create(&record("n1")).await.unwrap();
        assert_eq!(store.named_capture("n1", "first").await, Ok(None));
        assert_eq!(
            store
                .append_named("n1", b"fresh", Some("first"), &record("n1"))
                .await,
            Ok(Appended::New(0))
        );
        // A capture matched against a session that was deleted and created again under its id
        // with other options is refused as for a session that is gone: it was placed with the
        // old options, and would put their 3D segments in the new session's map.
        store.delete("n2").await.unwrap();
        let other = SessionRecord {
            options: b"other options".to_vec(),
            ..record("n2")
        };
        store.create(&other).await.unwrap();
        assert_eq!(
            store
                .append_named("n2", b"late", Some("late"), &record("n2"))
                .await,
            Err(StoreError::NotFound { id: "n2".into() })
        );
        assert_eq!(store.captures("n2").await.unwrap().len(), 0);
        assert_eq!(
            store.append_named("n2", b"new", None, &other).await,
            Ok(Appended::New(0))
        );
        store.delete("n1").await.unwrap();
        store.delete("n2").await.unwrap();
    }

    /// With a store whose idle TTL is `ttl`: use keeps a session alive, idleness ends it.
    /// `pass(d)` lets `d` go by on the store's clock: a manual clock's advance, or a real
    /// sleep for a store that keeps time itself.
    pub async fn expiry<F, Fut>(store: &dyn SessionStore, ttl: Duration, mut pass: F)
    where
        F: FnMut(Duration) -> Fut,
        Fut: std::future::Future<Output = ()>,
    {
        store.create(&record("idle")).await.unwrap();
        store.create(&record("busy")).await.unwrap();
        store
            .append_named("idle", b"x", Some("k"), &record("idle"))
            .await
            .unwrap();
        let step = ttl / 3;
        for i in 0..5 {
            // Watched but not used: a peek reads it and does not keep it alive.
            let peeked = store.peek("idle").await;
            assert!(i > 2 || peeked.is_ok(), "{peeked:?}");
            pass(step).await;
            let name = format!("b{i}");
            store
                .append_named("busy", b"y", Some(&name), &record("busy"))
                .await
                .unwrap();
        }
        // More than the TTL has passed since "idle" was last used; "busy" was used throughout.
        let gone = StoreError::NotFound { id: "idle".into() };
        assert_eq!(store.get("idle").await, Err(gone.clone()));
        assert_eq!(store.captures("idle").await, Err(gone.clone()));
        assert_eq!(store.append_capture("idle", b"z").await, Err(gone));
        let ids: Vec<String> = store
            .list()
            .await
            .unwrap()
            .into_iter()
            .map(|s| s.record.id)
            .collect();
        assert_eq!(ids, ["busy"]);
        assert_eq!(store.captures("busy").await.unwrap().len(), 5);
        // The names live as long as the captures: the first one's is still known.
        assert_eq!(
            store.named_capture("busy", "b0").await,
            Ok(Some((0, b"y".to_vec())))
        );
        // An expired id can be created again, empty, without its names.
        store.create(&record("idle")).await.unwrap();
        assert!(store.captures("idle").await.unwrap().is_empty());
        assert_eq!(store.named_capture("idle", "k").await, Ok(None));
        store.delete("idle").await.unwrap();
        store.delete("busy").await.unwrap();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_bad_bytes_are_corrupt() {
        let r = contract::record("x");
        assert_eq!(decode_record("x", &encode_record(&r)).unwrap(), r);
        let bytes = encode_record(&r);
        for cut in 0..bytes.len() {
            assert!(matches!(
                decode_record("x", &bytes[..cut]),
                Err(StoreError::Corrupt { .. })
            ));
        }
        let mut long = bytes.clone();
        long.push(0);
        assert!(matches!(
            decode_record("x", &long),
            Err(StoreError::Corrupt { .. })
        ));
    }

    #[test]
    fn urls_are_checked() {
        assert!(check_url("embedded").is_ok());
        assert!(check_url("memory").is_ok());
        assert!(check_url("").is_ok());
        assert!(check_url("redis://127.0.0.1:6379/2").is_ok());
        let e = check_url("postgres://x").unwrap_err();
        assert!(e.contains("store.url"), "{e}");
    }

    #[tokio::test]
    async fn open_chooses_by_url() {
        let dir = embedded::tests::temp_dir("open");
        let store = open("embedded", &dir, Duration::from_secs(60))
            .await
            .unwrap();
        assert!(
            store.describe().starts_with("embedded redb at "),
            "{}",
            store.describe()
        );
        assert!(store.describe().ends_with("trinocular.redb"));
        drop(store);
        let e = open("ftp://x", &dir, Duration::from_secs(60)).await.err();
        assert!(
            matches!(&e, Some(StoreError::Unavailable { message }) if message.contains("store.url")),
            "{e:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
