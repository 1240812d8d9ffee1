//! Sessions in this process's memory: lost when it stops. For throwaway runs
//! (`--store memory`), the load generator's in-process peer and tests; the same contract as
//! the durable stores, idle expiry included (by the injected clock, see `with_clock`).

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::super::clock::{self, Clock};
use super::{ttl_ms, Appended, SessionInfo, SessionRecord, SessionStore, StoreError};

struct Session {
    record: SessionRecord,
    captures: Vec<Vec<u8>>,
    /// The named captures' indices, by name.
    names: HashMap<String, u64>,
    last_used_unix_ms: u64,
}

pub struct MemoryStore {
    sessions: Mutex<BTreeMap<String, Session>>,
    ttl_ms: u64,
    clock: Arc<dyn Clock>,
}

impl MemoryStore {
    /// An empty store on the system clock.
    pub fn new(ttl: Duration) -> MemoryStore {
        MemoryStore {
            sessions: Mutex::new(BTreeMap::new()),
            ttl_ms: ttl_ms(ttl),
            clock: clock::system(),
        }
    }

    /// This store, measuring idleness by `clock` (a test's manual one).
    pub fn with_clock(mut self, clock: Arc<dyn Clock>) -> MemoryStore {
        self.clock = clock;
        self
    }

    fn now_unix_ms(&self) -> u64 {
        self.clock.now_unix_ms()
    }

    /// The sessions, expired ones dropped first. A poisoned lock means a panic while holding
    /// it; the map is still consistent (every change is one insert or remove), so carry on.
    fn live(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, Session>> {
        let mut sessions = self.sessions.lock().unwrap_or_else(|p| p.into_inner());
        let now = self.now_unix_ms();
        sessions.retain(|_, s| now.saturating_sub(s.last_used_unix_ms) < self.ttl_ms);
        sessions
    }
}

fn info(s: &Session) -> SessionInfo {
    SessionInfo {
        record: s.record.clone(),
        captures: s.captures.len() as u64,
        last_used_unix_ms: s.last_used_unix_ms,
    }
}

fn not_found(id: &str) -> StoreError {
    StoreError::NotFound { id: id.to_string() }
}

#[async_trait::async_trait]
impl SessionStore for MemoryStore {
    async fn create(&self, record: &SessionRecord) -> Result<(), StoreError> {
        let mut sessions = self.live();
        if sessions.contains_key(&record.id) {
            return Err(StoreError::AlreadyExists {
                id: record.id.clone(),
            });
        }
        sessions.insert(
            record.id.clone(),
            Session {
                record: record.clone(),
                captures: Vec::new(),
                names: HashMap::new(),
                last_used_unix_ms: self.now_unix_ms(),
            },
        );
        Ok(())
    }

    async fn get(&self, id: &str) -> Result<SessionInfo, StoreError> {
        let mut sessions = self.live();
        let s = sessions.get_mut(id).ok_or_else(|| not_found(id))?;
        s.last_used_unix_ms = self.now_unix_ms();
        Ok(info(s))
    }

    async fn peek(&self, id: &str) -> Result<SessionInfo, StoreError> {
        self.live().get(id).map(info).ok_or_else(|| not_found(id))
    }

    async fn list(&self) -> Result<Vec<SessionInfo>, StoreError> {
        Ok(self.live().values().map(info).collect())
    }

    async fn delete(&self, id: &str) -> Result<(), StoreError> {
        self.live()
            .remove(id)
            .map(|_| ())
            .ok_or_else(|| not_found(id))
    }

    async fn append_named(
        &self,
        id: &str,
        capture: &[u8],
        name: Option<&str>,
        matched: &SessionRecord,
    ) -> Result<Appended, StoreError> {
        let mut sessions = self.live();
        let s = sessions
            .get_mut(id)
            .filter(|s| s.record == *matched)
            .ok_or_else(|| not_found(id))?;
        s.last_used_unix_ms = self.now_unix_ms();
        if let Some(&index) = name.and_then(|n| s.names.get(n)) {
            return Ok(Appended::Existing {
                index,
                capture: s.captures[index as usize].clone(),
            });
        }
        let index = s.captures.len() as u64;
        s.captures.push(capture.to_vec());
        if let Some(name) = name {
            s.names.insert(name.to_string(), index);
        }
        Ok(Appended::New(index))
    }

    async fn named_capture(
        &self,
        id: &str,
        name: &str,
    ) -> Result<Option<(u64, Vec<u8>)>, StoreError> {
        let mut sessions = self.live();
        let s = sessions.get_mut(id).ok_or_else(|| not_found(id))?;
        s.last_used_unix_ms = self.now_unix_ms();
        Ok(s.names
            .get(name)
            .map(|&i| (i, s.captures[i as usize].clone())))
    }

    async fn captures(&self, id: &str) -> Result<Vec<Vec<u8>>, StoreError> {
        let mut sessions = self.live();
        let s = sessions.get_mut(id).ok_or_else(|| not_found(id))?;
        s.last_used_unix_ms = self.now_unix_ms();
        Ok(s.captures.clone())
    }

    fn describe(&self) -> String {
        "in memory (lost at exit)".to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::super::contract;
    use super::*;
    use crate::service::clock::ManualClock;

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    }

    #[test]
    fn keeps_the_store_contract() {
        runtime().block_on(async {
            contract::crud(&MemoryStore::new(Duration::from_secs(60))).await;
            contract::captures(&MemoryStore::new(Duration::from_secs(60))).await;
            contract::named_captures(&MemoryStore::new(Duration::from_secs(60))).await;
            // An hour's TTL passes in no time on a manual clock.
            let ttl = Duration::from_secs(3600);
            let clock = Arc::new(ManualClock::new(1_700_000_000_000));
            let store = MemoryStore::new(ttl).with_clock(clock.clone());
            contract::expiry(&store, ttl, |d| {
                clock.advance(d);
                std::future::ready(())
            })
            .await;
        });
    }
}
