//! The shared store: sessions in Redis, so that any number of replicas behind a load balancer
//! see the same sessions. Each operation that must not interleave with another replica's is one
//! Lua script, which Redis runs atomically; no client-side read-modify-write. Times come from the
//! Redis server's clock (`TIME`), so replicas with skewed clocks agree on `last_used`.
//!
//! ```text
//! {prefix}session:{id}            hash: record (super::encode_record), last_used (ms)  PEXPIRE ttl
//! {prefix}session:{id}:captures   list of capture bytes, in append order            PEXPIRE ttl
//! {prefix}session:{id}:names      hash: a named capture's name → its index          PEXPIRE ttl
//! {prefix}sessions                set of ids, for listing; members whose hash expired are
//!                                 removed when listed
//! ```
//!
//! The connection is a `ConnectionManager`, which reconnects after Redis comes back; connection
//! and response timeouts, few reconnection retries and an overall deadline per call bound how
//! long a call waits while Redis is down.

use std::time::Duration;

use redis::aio::{ConnectionManager, ConnectionManagerConfig};
use redis::{AsyncCommands, RedisError, Script};

use super::{
    decode_record, encode_record, ttl_ms, Appended, SessionInfo, SessionRecord, SessionStore,
    StoreError,
};

/// The key prefix of [`super::open`]; tests use their own.
pub const DEFAULT_PREFIX: &str = "trinocular:";

/// Longest wait for one connection attempt, and for one answer.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
const RESPONSE_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest a call may take, reconnection included: past it, Unavailable.
const CALL_DEADLINE: Duration = Duration::from_secs(5);

/// `KEYS[1]` the session hash, `KEYS[2]` its captures, `KEYS[3]` the set of ids, `KEYS[4]` its
/// names; `ARGV[1]` the id, `ARGV[2]` the encoded record, `ARGV[3]` the TTL in ms. 1 if
/// created, 0 if the id is taken.
const CREATE: &str = r#"
if redis.call('EXISTS', KEYS[1]) == 1 then return 0 end
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
redis.call('DEL', KEYS[2])
redis.call('DEL', KEYS[4])
redis.call('HSET', KEYS[1], 'record', ARGV[2], 'last_used', now)
redis.call('PEXPIRE', KEYS[1], ARGV[3])
redis.call('SADD', KEYS[3], ARGV[1])
return 1
"#;

/// `KEYS[1]` the session hash, `KEYS[2]` its captures, `KEYS[3]` its names; `ARGV[1]` the
/// capture, `ARGV[2]` the TTL in ms, `ARGV[3]` the capture's name ('' for none), `ARGV[4]` the
/// record the capture was matched against. {0, index, false} when appended (the list's new
/// length - 1); {1, index, capture} when the session holds a capture of that name already
/// (then nothing is written); {-1, 0, false} if there is no session with that record — none,
/// or one created again under the id (nothing written either).
const APPEND: &str = r#"
if redis.call('HGET', KEYS[1], 'record') ~= ARGV[4] then return {-1, 0, false} end
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
redis.call('HSET', KEYS[1], 'last_used', now)
redis.call('PEXPIRE', KEYS[1], ARGV[2])
redis.call('PEXPIRE', KEYS[2], ARGV[2])
local answer
if ARGV[3] ~= '' then
  local known = redis.call('HGET', KEYS[3], ARGV[3])
  if known then
    answer = {1, tonumber(known), redis.call('LINDEX', KEYS[2], tonumber(known))}
  end
end
if not answer then
  local n = redis.call('RPUSH', KEYS[2], ARGV[1])
  redis.call('PEXPIRE', KEYS[2], ARGV[2])
  if ARGV[3] ~= '' then redis.call('HSET', KEYS[3], ARGV[3], n - 1) end
  answer = {0, n - 1, false}
end
redis.call('PEXPIRE', KEYS[3], ARGV[2])
return answer
"#;

/// `KEYS[1]` the session hash, `KEYS[2]` its captures, `KEYS[3]` its names; `ARGV[1]` the
/// TTL in ms, `ARGV[2]` a capture's name. Refreshes the TTL and returns as [`APPEND`] does
/// for a name the session holds, {0, 0, false} for one it does not, {-1, 0, false} if there
/// is no session.
const NAMED: &str = r#"
if redis.call('EXISTS', KEYS[1]) == 0 then return {-1, 0, false} end
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
redis.call('HSET', KEYS[1], 'last_used', now)
redis.call('PEXPIRE', KEYS[1], ARGV[1])
redis.call('PEXPIRE', KEYS[2], ARGV[1])
redis.call('PEXPIRE', KEYS[3], ARGV[1])
local known = redis.call('HGET', KEYS[3], ARGV[2])
if not known then return {0, 0, false} end
return {1, tonumber(known), redis.call('LINDEX', KEYS[2], tonumber(known))}
"#;

/// `KEYS[1]` the session hash, `KEYS[2]` its captures, `KEYS[3]` its names; `ARGV[1]` the TTL
/// in ms. Refreshes the TTL and returns {record, last_used, number of captures}, or nil if
/// there is no session.
const GET: &str = r#"
if redis.call('EXISTS', KEYS[1]) == 0 then return false end
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
redis.call('HSET', KEYS[1], 'last_used', now)
redis.call('PEXPIRE', KEYS[1], ARGV[1])
redis.call('PEXPIRE', KEYS[2], ARGV[1])
redis.call('PEXPIRE', KEYS[3], ARGV[1])
return {redis.call('HGET', KEYS[1], 'record'), now, redis.call('LLEN', KEYS[2])}
"#;

/// As [`GET`], but returns the captures, or nil if there is no session.
const CAPTURES: &str = r#"
if redis.call('EXISTS', KEYS[1]) == 0 then return false end
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
redis.call('HSET', KEYS[1], 'last_used', now)
redis.call('PEXPIRE', KEYS[1], ARGV[1])
redis.call('PEXPIRE', KEYS[2], ARGV[1])
redis.call('PEXPIRE', KEYS[3], ARGV[1])
return redis.call('LRANGE', KEYS[2], 0, -1)
"#;

/// `KEYS[1]` the session hash, `KEYS[2]` its captures, `KEYS[3]` the set of ids, `KEYS[4]` its
/// names; `ARGV[1]` the id. 1 if the session existed; its captures, names and set member go
/// either way.
const DELETE: &str = r#"
local existed = redis.call('DEL', KEYS[1])
redis.call('DEL', KEYS[2])
redis.call('DEL', KEYS[4])
redis.call('SREM', KEYS[3], ARGV[1])
return existed
"#;

/// `KEYS[1]` the session hash, `KEYS[2]` the set of ids; `ARGV[1]` the id. Drops the id from
/// the set if its session expired (and not if it was created again meanwhile).
const FORGET_EXPIRED: &str = r#"
if redis.call('EXISTS', KEYS[1]) == 0 then redis.call('SREM', KEYS[2], ARGV[1]) end
return 0
"#;

pub struct RedisStore {
    connection: ConnectionManager,
    /// The URL without credentials, for messages.
    url: String,
    prefix: String,
    ttl_ms: u64,
    scripts: Scripts,
}

struct Scripts {
    create: Script,
    append: Script,
    named: Script,
    get: Script,
    captures: Script,
    delete: Script,
    forget_expired: Script,
}

impl RedisStore {
    /// Connects to `url` (`redis://host:port[/db]`) with keys under `prefix`. Unreachable:
    /// [`StoreError::Unavailable`] within a few seconds.
    pub async fn open(url: &str, prefix: &str, ttl: Duration) -> Result<RedisStore, StoreError> {
        let shown = without_credentials(url);
        let client = redis::Client::open(url).map_err(|e| StoreError::Unavailable {
            message: format!("redis at {shown}: bad URL: {e}"),
        })?;
        let config = ConnectionManagerConfig::new()
            .set_connection_timeout(Some(CONNECT_TIMEOUT))
            .set_response_timeout(Some(RESPONSE_TIMEOUT))
            .set_number_of_retries(1)
            .set_min_delay(Duration::from_millis(50))
            .set_max_delay(Duration::from_millis(500));
        let connect = ConnectionManager::new_with_config(client, config);
        let connection = match tokio::time::timeout(CALL_DEADLINE, connect).await {
            Ok(Ok(c)) => c,
            Ok(Err(e)) => return Err(unavailable(&shown, &e)),
            Err(_) => {
                return Err(StoreError::Unavailable {
                    message: format!(
                        "redis at {shown} unreachable: no connection within {CALL_DEADLINE:?}"
                    ),
                })
            }
        };
        Ok(RedisStore {
            connection,
            url: shown,
            prefix: prefix.to_string(),
            ttl_ms: ttl_ms(ttl),
            scripts: Scripts {
                create: Script::new(CREATE),
                append: Script::new(APPEND),
                named: Script::new(NAMED),
                get: Script::new(GET),
                captures: Script::new(CAPTURES),
                delete: Script::new(DELETE),
                forget_expired: Script::new(FORGET_EXPIRED),
            },
        })
    }

    fn session_key(&self, id: &str) -> String {
        format!("{}session:{id}", self.prefix)
    }

    fn captures_key(&self, id: &str) -> String {
        format!("{}session:{id}:captures", self.prefix)
    }

    fn names_key(&self, id: &str) -> String {
        format!("{}session:{id}:names", self.prefix)
    }

    fn sessions_key(&self) -> String {
        format!("{}sessions", self.prefix)
    }

    /// A name that points past the session's captures: Redis lost a write.
    fn lost(&self, id: &str, index: u64) -> StoreError {
        StoreError::Corrupt {
            message: format!(
                "redis at {}: session {id:?} names capture {index}, which it lacks",
                self.url
            ),
        }
    }

    /// Runs `call` on a handle to the shared connection, within [`CALL_DEADLINE`].
    async fn call<T, F>(&self, call: impl FnOnce(ConnectionManager) -> F) -> Result<T, StoreError>
    where
        F: std::future::Future<Output = Result<T, RedisError>>,
    {
        match tokio::time::timeout(CALL_DEADLINE, call(self.connection.clone())).await {
            Ok(Ok(v)) => Ok(v),
            Ok(Err(e)) => Err(unavailable(&self.url, &e)),
            Err(_) => Err(StoreError::Unavailable {
                message: format!(
                    "redis at {} unreachable: no answer within {CALL_DEADLINE:?}",
                    self.url
                ),
            }),
        }
    }

    fn info(
        &self,
        id: &str,
        record: &[u8],
        last_used: u64,
        captures: u64,
    ) -> Result<SessionInfo, StoreError> {
        Ok(SessionInfo {
            record: decode_record(id, record)?,
            captures,
            last_used_unix_ms: last_used,
        })
    }
}

/// A Redis error as a store error: a reply of the wrong shape is corrupt data, anything else
/// (refused, timed out, dropped, a server error) is the server being unavailable.
fn unavailable(url: &str, e: &RedisError) -> StoreError {
    // These messages reach clients (UNAVAILABLE) and the log: never the password.
    let url = super::redacted(url);
    if matches!(
        e.kind(),
        redis::ErrorKind::Parse | redis::ErrorKind::UnexpectedReturnType
    ) {
        return StoreError::Corrupt {
            message: format!("redis at {url}: unexpected reply: {e}"),
        };
    }
    let what = if e.is_io_error()
        || e.is_connection_refusal()
        || e.is_timeout()
        || e.is_connection_dropped()
    {
        "unreachable"
    } else {
        "failed"
    };
    StoreError::Unavailable {
        message: format!("redis at {url} {what}: {e}"),
    }
}

/// `redis://user:secret@host:6379/0` → `redis://host:6379/0`: passwords stay out of logs.
fn without_credentials(url: &str) -> String {
    match url.split_once("://") {
        Some((scheme, rest)) => {
            let authority_end = rest.find('/').unwrap_or(rest.len());
            match rest[..authority_end].rfind('@') {
                Some(at) => format!("{scheme}://{}", &rest[at + 1..]),
                None => url.to_string(),
            }
        }
        None => url.to_string(),
    }
}

fn not_found(id: &str) -> StoreError {
    StoreError::NotFound { id: id.to_string() }
}

#[async_trait::async_trait]
impl SessionStore for RedisStore {
    async fn create(&self, record: &SessionRecord) -> Result<(), StoreError> {
        let id = record.id.as_str();
        let mut invocation = self.scripts.create.key(self.session_key(id));
        invocation
            .key(self.captures_key(id))
            .key(self.sessions_key())
            .key(self.names_key(id))
            .arg(id)
            .arg(encode_record(record))
            .arg(self.ttl_ms);
        let created: i64 = self
            .call(|mut c| async move { invocation.invoke_async(&mut c).await })
            .await?;
        if created == 1 {
            Ok(())
        } else {
            Err(StoreError::AlreadyExists { id: id.to_string() })
        }
    }

    async fn get(&self, id: &str) -> Result<SessionInfo, StoreError> {
        let mut invocation = self.scripts.get.key(self.session_key(id));
        invocation
            .key(self.captures_key(id))
            .key(self.names_key(id))
            .arg(self.ttl_ms);
        let found: Option<(Vec<u8>, u64, u64)> = self
            .call(|mut c| async move { invocation.invoke_async(&mut c).await })
            .await?;
        let (record, last_used, captures) = found.ok_or_else(|| not_found(id))?;
        self.info(id, &record, last_used, captures)
    }

    async fn peek(&self, id: &str) -> Result<SessionInfo, StoreError> {
        let (session, captures) = (self.session_key(id), self.captures_key(id));
        let ((record, last_used), count): ((Option<Vec<u8>>, Option<u64>), u64) = self
            .call(|mut c| {
                let (session, captures) = (session.clone(), captures.clone());
                async move {
                    redis::pipe()
                        .hmget(&session, &["record", "last_used"])
                        .llen(&captures)
                        .query_async(&mut c)
                        .await
                }
            })
            .await?;
        match (record, last_used) {
            (Some(record), Some(last_used)) => self.info(id, &record, last_used, count),
            _ => Err(not_found(id)),
        }
    }

    async fn list(&self) -> Result<Vec<SessionInfo>, StoreError> {
        let sessions = self.sessions_key();
        let mut ids: Vec<String> = self
            .call(|mut c| {
                let sessions = sessions.clone();
                async move { c.smembers(sessions).await }
            })
            .await?;
        ids.sort();
        if ids.is_empty() {
            return Ok(Vec::new());
        }
        // One round trip for every session's record, last use and number of captures.
        let mut pipe = redis::pipe();
        for id in &ids {
            pipe.hmget(self.session_key(id), &["record", "last_used"])
                .llen(self.captures_key(id));
        }
        type Row = ((Option<Vec<u8>>, Option<u64>), u64);
        let rows: Vec<Row> = self
            .call(|mut c| async move { pipe.query_async(&mut c).await })
            .await?;
        let mut live = Vec::with_capacity(ids.len());
        for (id, ((record, last_used), captures)) in ids.iter().zip(rows) {
            match (record, last_used) {
                (Some(record), Some(last_used)) => {
                    live.push(self.info(id, &record, last_used, captures)?)
                }
                // Expired (or deleted meanwhile): forget the id, unless it was just re-created.
                _ => {
                    let mut invocation = self.scripts.forget_expired.key(self.session_key(id));
                    invocation.key(&sessions).arg(id);
                    let _: i64 = self
                        .call(|mut c| async move { invocation.invoke_async(&mut c).await })
                        .await?;
                }
            }
        }
        Ok(live)
    }

    async fn delete(&self, id: &str) -> Result<(), StoreError> {
        let mut invocation = self.scripts.delete.key(self.session_key(id));
        invocation
            .key(self.captures_key(id))
            .key(self.sessions_key())
            .key(self.names_key(id))
            .arg(id);
        let existed: i64 = self
            .call(|mut c| async move { invocation.invoke_async(&mut c).await })
            .await?;
        if existed == 1 {
            Ok(())
        } else {
            Err(not_found(id))
        }
    }

    async fn append_named(
        &self,
        id: &str,
        capture: &[u8],
        name: Option<&str>,
        matched: &SessionRecord,
    ) -> Result<Appended, StoreError> {
        let mut invocation = self.scripts.append.key(self.session_key(id));
        invocation
            .key(self.captures_key(id))
            .key(self.names_key(id))
            .arg(capture)
            .arg(self.ttl_ms)
            .arg(name.unwrap_or(""))
            .arg(encode_record(matched));
        let answer: (i64, u64, Option<Vec<u8>>) = self
            .call(|mut c| async move { invocation.invoke_async(&mut c).await })
            .await?;
        match answer {
            (0, index, _) => Ok(Appended::New(index)),
            (1, index, capture) => Ok(Appended::Existing {
                index,
                capture: capture.ok_or_else(|| self.lost(id, index))?,
            }),
            _ => Err(not_found(id)),
        }
    }

    async fn named_capture(
        &self,
        id: &str,
        name: &str,
    ) -> Result<Option<(u64, Vec<u8>)>, StoreError> {
        let mut invocation = self.scripts.named.key(self.session_key(id));
        invocation
            .key(self.captures_key(id))
            .key(self.names_key(id))
            .arg(self.ttl_ms)
            .arg(name);
        let answer: (i64, u64, Option<Vec<u8>>) = self
            .call(|mut c| async move { invocation.invoke_async(&mut c).await })
            .await?;
        match answer {
            (0, _, _) => Ok(None),
            (1, index, capture) => Ok(Some((index, capture.ok_or_else(|| self.lost(id, index))?))),
            _ => Err(not_found(id)),
        }
    }

    async fn captures(&self, id: &str) -> Result<Vec<Vec<u8>>, StoreError> {
        let mut invocation = self.scripts.captures.key(self.session_key(id));
        invocation
            .key(self.captures_key(id))
            .key(self.names_key(id))
            .arg(self.ttl_ms);
        let found: Option<Vec<Vec<u8>>> = self
            .call(|mut c| async move { invocation.invoke_async(&mut c).await })
            .await?;
        found.ok_or_else(|| not_found(id))
    }

    fn describe(&self) -> String {
        format!("redis at {}", super::redacted(&self.url))
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;
    use std::sync::Arc;

    use super::super::contract;
    use super::*;

    /// Says why `test` is skipped, or fails it when `TRINOCULAR_REQUIRE_REDIS` is set (CI
    /// sets it: there a missing Redis is a broken set-up, not a reason to skip).
    fn skip(test: &str, why: &str) {
        assert!(
            std::env::var_os("TRINOCULAR_REQUIRE_REDIS").is_none(),
            "{test}: {why}, and TRINOCULAR_REQUIRE_REDIS is set"
        );
        eprintln!("SKIPPED {test}: {why}");
    }

    fn url() -> String {
        std::env::var("TRINOCULAR_TEST_REDIS").unwrap_or_else(|_| "redis://127.0.0.1:6379".into())
    }

    /// A store under a prefix of its own, or None (after saying so) when no Redis answers.
    async fn store(test: &str, ttl: Duration) -> Option<RedisStore> {
        let url = url();
        let prefix = format!("trinocular-test:{test}:{}:", std::process::id());
        match RedisStore::open(&url, &prefix, ttl).await {
            Ok(s) => {
                cleanup(&s).await;
                Some(s)
            }
            Err(e) => {
                skip(test, &format!("no Redis at {url} ({e})"));
                None
            }
        }
    }

    /// Deletes every key under the store's prefix.
    async fn cleanup(s: &RedisStore) {
        let mut c = s.connection.clone();
        let keys: Vec<String> = c.keys(format!("{}*", s.prefix)).await.unwrap();
        if !keys.is_empty() {
            let _: () = c.del(keys).await.unwrap();
        }
    }

    #[tokio::test]
    async fn redis_crud() {
        let Some(s) = store("redis_crud", Duration::from_secs(3600)).await else {
            return;
        };
        contract::crud(&s).await;
        cleanup(&s).await;
    }

    #[tokio::test]
    async fn redis_captures() {
        let Some(s) = store("redis_captures", Duration::from_secs(3600)).await else {
            return;
        };
        contract::captures(&s).await;
        contract::named_captures(&s).await;
        let mut c = s.connection.clone();
        let leftover: Vec<String> = c.keys(format!("{}*", s.prefix)).await.unwrap();
        assert!(
            leftover.is_empty(),
            "no key left for deleted or unknown sessions: {leftover:?}"
        );
    }

    #[tokio::test]
    async fn redis_expiry() {
        let ttl = Duration::from_millis(1500);
        let Some(s) = store("redis_expiry", ttl).await else {
            return;
        };
        // Redis expires keys server-side by its own clock, which no test can move: this one
        // really waits out the TTL.
        contract::expiry(&s, ttl, tokio::time::sleep).await;
        cleanup(&s).await;
    }

    /// Two stores under one test prefix, each with its own connection, as two replicas have,
    /// and a session `id` created through the first; None (after saying so) without Redis.
    async fn two_replicas(test: &str, id: &str) -> Option<(Arc<RedisStore>, Arc<RedisStore>)> {
        let ttl = Duration::from_secs(3600);
        let a = store(test, ttl).await?;
        let b = RedisStore::open(&url(), &a.prefix, ttl).await.unwrap();
        a.create(&contract::record(id)).await.unwrap();
        Some((Arc::new(a), Arc::new(b)))
    }

    #[tokio::test]
    async fn redis_two_replicas_append_concurrently() {
        let Some((a, b)) = two_replicas("redis_two_replicas_append_concurrently", "shared").await
        else {
            return;
        };
        let append_all = |s: Arc<RedisStore>, replica: u8| {
            tokio::spawn(async move {
                let mut got = Vec::new();
                for i in 0..200u16 {
                    let payload = format!("{replica}:{i}").into_bytes();
                    got.push((s.append_capture("shared", &payload).await.unwrap(), payload));
                }
                got
            })
        };
        let (ga, gb) = (append_all(Arc::clone(&a), 0), append_all(Arc::clone(&b), 1));
        let mut got = ga.await.unwrap();
        got.extend(gb.await.unwrap());
        let indices: BTreeSet<u64> = got.iter().map(|(i, _)| *i).collect();
        assert_eq!(indices, (0..400).collect(), "each index returned once");
        let stored = a.captures("shared").await.unwrap();
        assert_eq!(stored.len(), 400);
        for (index, payload) in &got {
            assert_eq!(&stored[*index as usize], payload, "capture {index}");
        }
        assert_eq!(b.get("shared").await.unwrap().captures, 400);
        cleanup(&a).await;
    }

    #[tokio::test]
    async fn redis_two_replicas_store_a_named_capture_once() {
        let test = "redis_two_replicas_store_a_named_capture_once";
        let Some((a, b)) = two_replicas(test, "retried").await else {
            return;
        };
        // Each capture sent to both replicas at once, as a client's retry may race its first
        // attempt: one of the two stores it, the other answers with it.
        let record = a.get("retried").await.unwrap().record;
        let send_all = |s: Arc<RedisStore>, replica: u8| {
            let record = record.clone();
            tokio::spawn(async move {
                let mut got = Vec::new();
                for i in 0..100u16 {
                    let name = format!("capture-{i}");
                    let payload = format!("{replica}:{i}").into_bytes();
                    got.push((
                        i,
                        s.append_named("retried", &payload, Some(&name), &record)
                            .await
                            .unwrap(),
                    ));
                }
                got
            })
        };
        let (ga, gb) = (send_all(Arc::clone(&a), 0), send_all(Arc::clone(&b), 1));
        let (ga, gb) = (ga.await.unwrap(), gb.await.unwrap());
        let stored = a.captures("retried").await.unwrap();
        assert_eq!(stored.len(), 100, "each name stored once");
        for ((i, x), (j, y)) in ga.iter().zip(&gb) {
            assert_eq!(i, j);
            let (index, capture) = match (x, y) {
                (Appended::New(index), Appended::Existing { index: k, capture })
                | (Appended::Existing { index: k, capture }, Appended::New(index)) => {
                    assert_eq!(index, k, "capture {i}: both answers name one index");
                    (*index, capture.clone())
                }
                other => panic!("capture {i}: expected one New and one Existing, got {other:?}"),
            };
            assert_eq!(stored[index as usize], capture, "capture {i}");
        }
        cleanup(&a).await;
    }

    #[tokio::test]
    async fn redis_unreachable_is_unavailable_quickly() {
        let url = "redis://127.0.0.1:1";
        let started = std::time::Instant::now();
        let e = RedisStore::open(url, "trinocular-test:", Duration::from_secs(60))
            .await
            .err();
        match e {
            Some(StoreError::Unavailable { message }) => {
                assert!(
                    message.contains("redis at redis://127.0.0.1:1 unreachable"),
                    "{message}"
                );
            }
            other => panic!("expected Unavailable, got {other:?}"),
        }
        // A bound, not a speed claim: the call must not hang.
        assert!(started.elapsed() < CALL_DEADLINE + Duration::from_secs(1));
    }

    /// A TCP relay to Redis that can be cut and restored on the same port, to stage an outage
    /// without touching the real server.
    struct Relay {
        port: u16,
        target: String,
        tasks: Arc<std::sync::Mutex<Vec<tokio::task::JoinHandle<()>>>>,
    }

    impl Relay {
        async fn start(port: u16, target: &str) -> Relay {
            let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
                .await
                .unwrap();
            let port = listener.local_addr().unwrap().port();
            let tasks = Arc::new(std::sync::Mutex::new(Vec::new()));
            let (target_owned, tasks2) = (target.to_string(), Arc::clone(&tasks));
            let accept = tokio::spawn(async move {
                while let Ok((mut inbound, _)) = listener.accept().await {
                    let target = target_owned.clone();
                    let relay = tokio::spawn(async move {
                        if let Ok(mut outbound) = tokio::net::TcpStream::connect(target).await {
                            let _ =
                                tokio::io::copy_bidirectional(&mut inbound, &mut outbound).await;
                        }
                    });
                    tasks2.lock().unwrap().push(relay);
                }
            });
            tasks.lock().unwrap().push(accept);
            Relay {
                port,
                target: target.to_string(),
                tasks,
            }
        }

        /// Closes the port and every relayed connection.
        fn cut(&self) {
            for t in self.tasks.lock().unwrap().drain(..) {
                t.abort();
            }
        }
    }

    #[tokio::test]
    async fn redis_outage_fails_in_bounded_time_and_recovers() {
        let test = "redis_outage_fails_in_bounded_time_and_recovers";
        let url = url();
        let Some(target) = url
            .strip_prefix("redis://")
            .map(|rest| rest.split('/').next().unwrap_or(rest).to_string())
            .filter(|authority| !authority.contains('@'))
        else {
            skip(test, &format!("{url} is not a plain redis://host:port URL"));
            return;
        };
        if tokio::net::TcpStream::connect(&target).await.is_err() {
            skip(test, &format!("no Redis at {url} (cannot connect)"));
            return;
        }
        let relay = Relay::start(0, &target).await;
        let relayed = format!("redis://127.0.0.1:{}", relay.port);
        let prefix = format!("trinocular-test:{test}:{}:", std::process::id());
        let s = RedisStore::open(&relayed, &prefix, Duration::from_secs(3600))
            .await
            .unwrap();
        s.create(&contract::record("o")).await.unwrap();
        assert_eq!(s.append_capture("o", b"before").await.unwrap(), 0);

        relay.cut();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let started = std::time::Instant::now();
        match s.append_capture("o", b"during").await {
            Err(StoreError::Unavailable { message }) => {
                assert!(
                    message.contains(&format!("redis at {relayed}")),
                    "{message}"
                )
            }
            other => panic!("expected Unavailable during the outage, got {other:?}"),
        }
        assert!(started.elapsed() < CALL_DEADLINE + Duration::from_secs(1));

        // Redis is back on the same address: the connection manager reconnects.
        let relay = Relay::start(relay.port, &relay.target).await;
        let mut recovered = None;
        for _ in 0..50 {
            match s.append_capture("o", b"after").await {
                Ok(index) => {
                    recovered = Some(index);
                    break;
                }
                Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        }
        assert_eq!(recovered, Some(1), "the failed append stored nothing");
        assert_eq!(
            s.captures("o").await.unwrap(),
            [b"before".to_vec(), b"after".to_vec()]
        );
        cleanup(&s).await;
        relay.cut();
    }

    #[test]
    fn credentials_stay_out_of_messages() {
        assert_eq!(
            without_credentials("redis://user:secret@db:6379/2"),
            "redis://db:6379/2"
        );
        assert_eq!(
            without_credentials("redis://127.0.0.1:6379"),
            "redis://127.0.0.1:6379"
        );
    }
}
