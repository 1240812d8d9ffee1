//! The default store: one redb file, `trinocular.redb` under the data directory, for a single
//! replica. Every operation is one redb write transaction, so concurrent calls are serialised
//! and nothing is ever half-written; every acknowledged change is committed with redb's default
//! (immediate) durability before the call returns, so it survives `kill -9`. redb blocks, so
//! transactions run on tokio's blocking pool.
//!
//! ```text
//! sessions  id          → encoded record (see super::encode_record)
//! meta      id          → (last_used_unix_ms, captures)
//! captures  (id, index) → capture bytes
//! names     id ␁ name   → index of the capture the client named so (see `name_key`)
//! ```
//!
//! Expired sessions are swept lazily, when touched or listed: deterministic, no background task.
//! Ages are measured by the store's injected clock (the system clock unless `with_clock`).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use redb::{Database, ReadableTable, Table, TableDefinition, WriteTransaction};

use super::super::clock::{self, Clock};
use super::{
    decode_record, encode_record, ttl_ms, Appended, SessionInfo, SessionRecord, SessionStore,
    StoreError,
};

const SESSIONS: TableDefinition<&str, &[u8]> = TableDefinition::new("sessions");
const META: TableDefinition<&str, (u64, u64)> = TableDefinition::new("meta");
const CAPTURES: TableDefinition<(&str, u64), &[u8]> = TableDefinition::new("captures");
const NAMES: TableDefinition<&str, u64> = TableDefinition::new("names");

/// A named capture's key in [`NAMES`]: the session id, U+0001, the name. Session ids hold
/// letters, digits, '-' and '~' only, all above U+0002, so a session's names are exactly the
/// keys from `id␁` up to `id␂` ([`names_of`]), whatever other ids begin with this one.
fn name_key(id: &str, name: &str) -> String {
    format!("{id}\u{1}{name}")
}

fn names_of(id: &str) -> std::ops::Range<String> {
    format!("{id}\u{1}")..format!("{id}\u{2}")
}

/// The file's name under the data directory.
pub const FILE_NAME: &str = "trinocular.redb";

pub struct EmbeddedStore {
    inner: Arc<Inner>,
    clock: Arc<dyn Clock>,
}

struct Inner {
    db: Database,
    path: PathBuf,
    ttl_ms: u64,
    /// A read refreshes `last_used` only when it is at least this old, so that reading a busy
    /// session does not cost a disk sync each time; expiry is late by at most this much.
    touch_every_ms: u64,
}

/// The three tables, open in one write transaction.
struct Tables<'t> {
    sessions: Table<'t, &'static str, &'static [u8]>,
    meta: Table<'t, &'static str, (u64, u64)>,
    captures: Table<'t, (&'static str, u64), &'static [u8]>,
    names: Table<'t, &'static str, u64>,
}

impl EmbeddedStore {
    /// A live session, its idle TTL refreshed when `touch` ([`SessionStore::get`]) and not
    /// otherwise ([`SessionStore::peek`]).
    async fn read(&self, id: &str, touch: bool) -> Result<SessionInfo, StoreError> {
        let id = id.to_string();
        self.write(move |inner, t, now, changed| {
            let meta = inner
                .live(t, &id, now, changed)?
                .ok_or_else(|| not_found(&id))?;
            let last_used = if touch {
                inner.touch(t, &id, meta, now, changed)?
            } else {
                meta.0
            };
            Ok(SessionInfo {
                record: inner.record(t, &id)?,
                captures: meta.1,
                last_used_unix_ms: last_used,
            })
        })
        .await
    }

    /// Opens (creating if needed) `data_dir/trinocular.redb`. A file another process holds is
    /// [`StoreError::Unavailable`] naming the path.
    pub async fn open(data_dir: &Path, ttl: Duration) -> Result<EmbeddedStore, StoreError> {
        let dir = data_dir.to_path_buf();
        let ttl_ms = ttl_ms(ttl);
        let inner = tokio::task::spawn_blocking(move || -> Result<Inner, StoreError> {
            let path = dir.join(FILE_NAME);
            std::fs::create_dir_all(&dir).map_err(|e| StoreError::Unavailable {
                message: format!(
                    "embedded redb at {}: cannot create the data directory: {e}",
                    path.display()
                ),
            })?;
            let db = Database::create(&path).map_err(|e| match e {
                redb::DatabaseError::DatabaseAlreadyOpen => StoreError::Unavailable {
                    message: format!(
                        "embedded redb at {}: the file is held by another process \
                         (or already open in this one)",
                        path.display()
                    ),
                },
                other => fail(&path, "cannot open", other),
            })?;
            let inner = Inner {
                db,
                path,
                ttl_ms,
                touch_every_ms: ttl_ms / 64,
            };
            // Create the tables once, so that later transactions find them.
            let txn = inner.db.begin_write().map_err(|e| inner.fail("begin", e))?;
            Tables::open(&inner, &txn)?;
            txn.commit().map_err(|e| inner.fail("commit", e))?;
            Ok(inner)
        })
        .await
        .map_err(|e| StoreError::Unavailable {
            message: format!(
                "embedded redb under {}: open failed: {e}",
                data_dir.display()
            ),
        })??;
        Ok(EmbeddedStore {
            inner: Arc::new(inner),
            clock: clock::system(),
        })
    }

    /// This store, measuring idleness by `clock` (a test's manual one).
    pub fn with_clock(mut self, clock: Arc<dyn Clock>) -> EmbeddedStore {
        self.clock = clock;
        self
    }

    /// Runs `f` in one write transaction on the blocking pool, with the time now. The
    /// transaction is committed (durably) if `f` marked it changed and ended in success or a
    /// caller's error (NotFound, AlreadyExists: an expired session may have been swept); on a
    /// storage error it is dropped, so nothing is half-written.
    async fn write<T: Send + 'static>(
        &self,
        f: impl FnOnce(&Inner, &mut Tables, u64, &mut bool) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, StoreError> {
        let inner = Arc::clone(&self.inner);
        let clock = Arc::clone(&self.clock);
        tokio::task::spawn_blocking(move || {
            let txn = inner.db.begin_write().map_err(|e| inner.fail("begin", e))?;
            // Read once the transaction is ours, so that `last_used` never goes backwards.
            let now = clock.now_unix_ms();
            let mut changed = false;
            let result = {
                let mut tables = Tables::open(&inner, &txn)?;
                f(&inner, &mut tables, now, &mut changed)
            };
            let keep = matches!(
                result,
                Ok(_) | Err(StoreError::NotFound { .. } | StoreError::AlreadyExists { .. })
            );
            if changed && keep {
                txn.commit().map_err(|e| inner.fail("commit", e))?;
            } else {
                txn.abort().map_err(|e| inner.fail("abort", e))?;
            }
            result
        })
        .await
        .map_err(|e| StoreError::Unavailable {
            message: format!(
                "embedded redb at {}: transaction task failed: {e}",
                self.inner.path.display()
            ),
        })?
    }
}

fn fail(path: &Path, what: &str, e: impl Into<redb::Error>) -> StoreError {
    match e.into() {
        redb::Error::Corrupted(message) => StoreError::Corrupt {
            message: format!("embedded redb at {}: {message}", path.display()),
        },
        e => StoreError::Unavailable {
            message: format!("embedded redb at {}: {what}: {e}", path.display()),
        },
    }
}

impl Inner {
    fn fail(&self, what: &str, e: impl Into<redb::Error>) -> StoreError {
        fail(&self.path, what, e)
    }

    fn expired(&self, last_used: u64, now: u64) -> bool {
        now.saturating_sub(last_used) > self.ttl_ms
    }

    /// `(last_used, captures)` of a live session; an expired one is removed (and `changed`
    /// set) and reads as absent.
    fn live(
        &self,
        t: &mut Tables,
        id: &str,
        now: u64,
        changed: &mut bool,
    ) -> Result<Option<(u64, u64)>, StoreError> {
        let meta = t
            .meta
            .get(id)
            .map_err(|e| self.fail("read", e))?
            .map(|g| g.value());
        match meta {
            Some((last_used, _)) if self.expired(last_used, now) => {
                self.remove(t, id)?;
                *changed = true;
                Ok(None)
            }
            other => Ok(other),
        }
    }

    fn remove(&self, t: &mut Tables, id: &str) -> Result<(), StoreError> {
        t.sessions.remove(id).map_err(|e| self.fail("remove", e))?;
        t.meta.remove(id).map_err(|e| self.fail("remove", e))?;
        t.captures
            .retain_in((id, 0u64)..=(id, u64::MAX), |_, _| false)
            .map_err(|e| self.fail("remove", e))?;
        let names = names_of(id);
        t.names
            .retain_in(names.start.as_str()..names.end.as_str(), |_, _| false)
            .map_err(|e| self.fail("remove", e))?;
        Ok(())
    }

    fn record(&self, t: &Tables, id: &str) -> Result<SessionRecord, StoreError> {
        let bytes = t
            .sessions
            .get(id)
            .map_err(|e| self.fail("read", e))?
            .ok_or_else(|| StoreError::Corrupt {
                message: format!(
                    "embedded redb at {}: session {id:?} has metadata but no record",
                    self.path.display()
                ),
            })?;
        decode_record(id, bytes.value())
    }

    /// The capture stored under `name` (a [`name_key`]) and its index.
    fn named(
        &self,
        t: &Tables,
        id: &str,
        name: &str,
    ) -> Result<Option<(u64, Vec<u8>)>, StoreError> {
        let Some(index) = t
            .names
            .get(name)
            .map_err(|e| self.fail("read", e))?
            .map(|g| g.value())
        else {
            return Ok(None);
        };
        let capture = t
            .captures
            .get((id, index))
            .map_err(|e| self.fail("read", e))?
            .ok_or_else(|| StoreError::Corrupt {
                message: format!(
                    "embedded redb at {}: session {id:?} names capture {index}, which it lacks",
                    self.path.display()
                ),
            })?;
        Ok(Some((index, capture.value().to_vec())))
    }

    /// Marks the session used now, unless it was so recently that the write is not worth it.
    fn touch(
        &self,
        t: &mut Tables,
        id: &str,
        (last_used, captures): (u64, u64),
        now: u64,
        changed: &mut bool,
    ) -> Result<u64, StoreError> {
        if now.saturating_sub(last_used) < self.touch_every_ms {
            return Ok(last_used);
        }
        t.meta
            .insert(id, (now, captures))
            .map_err(|e| self.fail("write", e))?;
        *changed = true;
        Ok(now)
    }
}

impl<'t> Tables<'t> {
    fn open(inner: &Inner, txn: &'t WriteTransaction) -> Result<Tables<'t>, StoreError> {
        let open = |e| inner.fail("open table", e);
        Ok(Tables {
            sessions: txn.open_table(SESSIONS).map_err(open)?,
            meta: txn.open_table(META).map_err(open)?,
            captures: txn.open_table(CAPTURES).map_err(open)?,
            names: txn.open_table(NAMES).map_err(open)?,
        })
    }
}

fn not_found(id: &str) -> StoreError {
    StoreError::NotFound { id: id.to_string() }
}

#[async_trait::async_trait]
impl SessionStore for EmbeddedStore {
    async fn create(&self, record: &SessionRecord) -> Result<(), StoreError> {
        let id = record.id.clone();
        let encoded = encode_record(record);
        self.write(move |inner, t, now, changed| {
            if inner.live(t, &id, now, changed)?.is_some() {
                return Err(StoreError::AlreadyExists { id });
            }
            t.sessions
                .insert(id.as_str(), encoded.as_slice())
                .map_err(|e| inner.fail("write", e))?;
            t.meta
                .insert(id.as_str(), (now, 0))
                .map_err(|e| inner.fail("write", e))?;
            *changed = true;
            Ok(())
        })
        .await
    }

    async fn get(&self, id: &str) -> Result<SessionInfo, StoreError> {
        self.read(id, true).await
    }

    async fn peek(&self, id: &str) -> Result<SessionInfo, StoreError> {
        self.read(id, false).await
    }

    async fn list(&self) -> Result<Vec<SessionInfo>, StoreError> {
        self.write(move |inner, t, now, changed| {
            let mut live = Vec::new();
            let mut expired = Vec::new();
            for entry in t.meta.iter().map_err(|e| inner.fail("read", e))? {
                let (id, meta) = entry.map_err(|e| inner.fail("read", e))?;
                let (id, (last_used, captures)) = (id.value().to_string(), meta.value());
                if inner.expired(last_used, now) {
                    expired.push(id);
                } else {
                    live.push((id, last_used, captures));
                }
            }
            for id in &expired {
                inner.remove(t, id)?;
                *changed = true;
            }
            // redb iterates keys in byte order, which is `String`'s order: sorted by id.
            live.into_iter()
                .map(|(id, last_used, captures)| {
                    Ok(SessionInfo {
                        record: inner.record(t, &id)?,
                        captures,
                        last_used_unix_ms: last_used,
                    })
                })
                .collect()
        })
        .await
    }

    async fn delete(&self, id: &str) -> Result<(), StoreError> {
        let id = id.to_string();
        self.write(move |inner, t, now, changed| {
            inner
                .live(t, &id, now, changed)?
                .ok_or_else(|| not_found(&id))?;
            inner.remove(t, &id)?;
            *changed = true;
            Ok(())
        })
        .await
    }

    async fn append_named(
        &self,
        id: &str,
        capture: &[u8],
        name: Option<&str>,
        matched: &SessionRecord,
    ) -> Result<Appended, StoreError> {
        let id = id.to_string();
        let capture = capture.to_vec();
        let name = name.map(|n| name_key(&id, n));
        let matched = encode_record(matched);
        self.write(move |inner, t, now, changed| {
            let meta = inner
                .live(t, &id, now, changed)?
                .ok_or_else(|| not_found(&id))?;
            let same = t
                .sessions
                .get(id.as_str())
                .map_err(|e| inner.fail("read", e))?
                .is_some_and(|record| record.value() == matched.as_slice());
            if !same {
                return Err(not_found(&id));
            }
            if let Some(name) = &name {
                if let Some(found) = inner.named(t, &id, name)? {
                    inner.touch(t, &id, meta, now, changed)?;
                    return Ok(Appended::Existing {
                        index: found.0,
                        capture: found.1,
                    });
                }
            }
            let index = meta.1;
            t.captures
                .insert((id.as_str(), index), capture.as_slice())
                .map_err(|e| inner.fail("write", e))?;
            t.meta
                .insert(id.as_str(), (now, index + 1))
                .map_err(|e| inner.fail("write", e))?;
            if let Some(name) = &name {
                t.names
                    .insert(name.as_str(), index)
                    .map_err(|e| inner.fail("write", e))?;
            }
            *changed = true;
            Ok(Appended::New(index))
        })
        .await
    }

    async fn named_capture(
        &self,
        id: &str,
        name: &str,
    ) -> Result<Option<(u64, Vec<u8>)>, StoreError> {
        let id = id.to_string();
        let name = name_key(&id, name);
        self.write(move |inner, t, now, changed| {
            let meta = inner
                .live(t, &id, now, changed)?
                .ok_or_else(|| not_found(&id))?;
            inner.touch(t, &id, meta, now, changed)?;
            inner.named(t, &id, &name)
        })
        .await
    }

    async fn captures(&self, id: &str) -> Result<Vec<Vec<u8>>, StoreError> {
        let id = id.to_string();
        self.write(move |inner, t, now, changed| {
            let meta = inner
                .live(t, &id, now, changed)?
                .ok_or_else(|| not_found(&id))?;
            inner.touch(t, &id, meta, now, changed)?;
            let mut out = Vec::with_capacity(meta.1 as usize);
            let range = t
                .captures
                .range((id.as_str(), 0u64)..=(id.as_str(), u64::MAX))
                .map_err(|e| inner.fail("read", e))?;
            for entry in range {
                let (key, value) = entry.map_err(|e| inner.fail("read", e))?;
                // Indices are dense from 0: a gap means the file lost a write.
                if key.value().1 != out.len() as u64 {
                    return Err(StoreError::Corrupt {
                        message: format!(
                            "embedded redb at {}: session {id:?} lacks capture {}",
                            inner.path.display(),
                            out.len()
                        ),
                    });
                }
                out.push(value.value().to_vec());
            }
            Ok(out)
        })
        .await
    }

    fn describe(&self) -> String {
        format!("embedded redb at {}", self.inner.path.display())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::super::contract;
    use super::*;
    use crate::service::clock::ManualClock;

    /// A fresh directory under the system's temporary directory.
    pub fn temp_dir(name: &str) -> PathBuf {
        use std::sync::atomic::{AtomicU64, Ordering};
        static N: AtomicU64 = AtomicU64::new(0);
        let dir = std::env::temp_dir().join(format!(
            "trinocular-store-{name}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    async fn store(name: &str, ttl: Duration) -> (EmbeddedStore, PathBuf) {
        let dir = temp_dir(name);
        (EmbeddedStore::open(&dir, ttl).await.unwrap(), dir)
    }

    #[tokio::test]
    async fn embedded_crud() {
        let (s, dir) = store("crud", Duration::from_secs(3600)).await;
        contract::crud(&s).await;
        drop(s);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[tokio::test]
    async fn embedded_captures() {
        let (s, dir) = store("captures", Duration::from_secs(3600)).await;
        contract::captures(&s).await;
        contract::named_captures(&s).await;
        drop(s);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[tokio::test]
    async fn embedded_expiry() {
        // An hour's TTL passes in no time on a manual clock.
        let ttl = Duration::from_secs(3600);
        let (s, dir) = store("expiry", ttl).await;
        let clock = Arc::new(ManualClock::new(1_700_000_000_000));
        let s = s.with_clock(clock.clone());
        contract::expiry(&s, ttl, |d| {
            clock.advance(d);
            std::future::ready(())
        })
        .await;
        drop(s);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[tokio::test]
    async fn embedded_survives_reopening() {
        let ttl = Duration::from_secs(3600);
        let (s, dir) = store("durable", ttl).await;
        s.create(&contract::record("kept")).await.unwrap();
        for i in 0..5u8 {
            s.append_capture("kept", &[i; 3]).await.unwrap();
        }
        s.create(&contract::record("gone")).await.unwrap();
        s.delete("gone").await.unwrap();
        drop(s);
        let s = EmbeddedStore::open(&dir, ttl).await.unwrap();
        let info = s.get("kept").await.unwrap();
        assert_eq!(info.record, contract::record("kept"));
        assert_eq!(info.captures, 5);
        let expected: Vec<Vec<u8>> = (0..5u8).map(|i| vec![i; 3]).collect();
        assert_eq!(s.captures("kept").await.unwrap(), expected);
        assert_eq!(s.append_capture("kept", b"more").await.unwrap(), 5);
        assert_eq!(s.list().await.unwrap().len(), 1);
        drop(s);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[tokio::test]
    async fn embedded_concurrent_appends_get_distinct_indices() {
        let (s, dir) = store("concurrent", Duration::from_secs(3600)).await;
        let s = Arc::new(s);
        s.create(&contract::record("c")).await.unwrap();
        let tasks: Vec<_> = (0..4u8)
            .map(|task| {
                let s = Arc::clone(&s);
                tokio::spawn(async move {
                    let mut indices = Vec::new();
                    for i in 0..25u8 {
                        indices.push(s.append_capture("c", &[task, i]).await.unwrap());
                    }
                    indices
                })
            })
            .collect();
        let mut indices = Vec::new();
        for t in tasks {
            indices.extend(t.await.unwrap());
        }
        indices.sort_unstable();
        assert_eq!(indices, (0..100).collect::<Vec<u64>>());
        assert_eq!(s.captures("c").await.unwrap().len(), 100);
        drop(s);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[tokio::test]
    async fn a_file_already_held_is_unavailable_naming_the_path() {
        let (s, dir) = store("held", Duration::from_secs(60)).await;
        let second = EmbeddedStore::open(&dir, Duration::from_secs(60)).await;
        match second {
            Err(StoreError::Unavailable { message }) => {
                assert!(message.contains(FILE_NAME), "{message}");
                assert!(message.contains("held"), "{message}");
            }
            Err(e) => panic!("expected Unavailable, got {e:?}"),
            Ok(_) => panic!("expected Unavailable, opened twice"),
        }
        drop(s);
        let _ = std::fs::remove_dir_all(dir);
    }
}
