//! Optional API keys and the tenancy they give. With no keys configured the service is open,
//! as a service on a robot's own network usually is; with keys, every call but the probes and
//! the metrics must carry one (`Authorization: Bearer <key>` on HTTP, `authorization`
//! metadata on gRPC), and a session belongs to the key that created it: another key gets
//! NOT_FOUND for it, as for a session that never existed, and lists only its own.
//!
//! Keys come from a file (`name key` per line, `#` comments) or the environment
//! (`TRINOCULAR_API_KEYS=name:key,name:key`). They are never logged: only their names and
//! count are.

use std::collections::HashMap;

use super::ServiceError;

/// Who is calling: the name of its key, or nobody in particular when the service is open.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Caller {
    pub tenant: Option<String>,
}

/// The environment variable that may hold keys.
pub const KEYS_ENV: &str = "TRINOCULAR_API_KEYS";
/// Shortest key accepted: a guessable key is no key.
const MIN_KEY_CHARS: usize = 16;
/// Longest key name (it prefixes the tenant's session ids in the store).
const MAX_NAME_CHARS: usize = 32;

/// The keys, by key.
#[derive(Clone, Default)]
pub struct ApiKeys {
    by_key: HashMap<String, String>,
}

impl std::fmt::Debug for ApiKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut names: Vec<&String> = self.by_key.values().collect();
        names.sort();
        f.debug_struct("ApiKeys").field("names", &names).finish()
    }
}

impl ApiKeys {
    /// Keys from `name key` lines (the file format) and `name:key` items separated by commas
    /// (the environment's). Errors name the line or item, never the key.
    pub fn parse(file: Option<&str>, env: Option<&str>) -> Result<ApiKeys, String> {
        let mut keys = ApiKeys::default();
        let lines = file
            .into_iter()
            .flat_map(str::lines)
            .enumerate()
            .filter_map(|(n, l)| {
                let l = l.trim();
                (!l.is_empty() && !l.starts_with('#')).then(|| {
                    let mut parts = l.split_whitespace();
                    (
                        format!("keys file line {}", n + 1),
                        parts.next(),
                        parts.next(),
                        parts.next(),
                    )
                })
            });
        let items = env
            .into_iter()
            .flat_map(|e| e.split(','))
            .enumerate()
            .filter_map(|(n, item)| {
                let item = item.trim();
                (!item.is_empty()).then(|| {
                    let (name, key) = item
                        .split_once(':')
                        .map_or((Some(item), None), |(n, k)| (Some(n), Some(k)));
                    (format!("{KEYS_ENV} item {}", n + 1), name, key, None)
                })
            });
        for (place, name, key, extra) in lines.chain(items) {
            let (Some(name), Some(key), None) = (name, key, extra) else {
                return Err(format!("{place}: expected a name and a key"));
            };
            let name_ok = !name.is_empty()
                && name.chars().count() <= MAX_NAME_CHARS
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
            if !name_ok {
                return Err(format!(
                    "{place}: the name must be 1 to {MAX_NAME_CHARS} letters, digits, '-' or '_'"
                ));
            }
            if key.chars().count() < MIN_KEY_CHARS || !key.chars().all(|c| c.is_ascii_graphic()) {
                return Err(format!(
                    "{place}: the key of {name:?} must be at least {MIN_KEY_CHARS} printable characters"
                ));
            }
            if keys
                .by_key
                .insert(key.to_string(), name.to_string())
                .is_some()
            {
                return Err(format!("{place}: the key of {name:?} is given twice"));
            }
        }
        Ok(keys)
    }

    pub fn is_empty(&self) -> bool {
        self.by_key.is_empty()
    }

    pub fn len(&self) -> usize {
        self.by_key.len()
    }

    /// The caller of a request whose credentials are `authorization` (the header's or the
    /// metadata's value). Open when there are no keys.
    pub fn caller(&self, authorization: Option<&str>) -> Result<Caller, ServiceError> {
        if self.is_empty() {
            return Ok(Caller::default());
        }
        let Some(value) = authorization else {
            return Err(ServiceError::Unauthenticated {
                message: "an API key is required: send 'authorization: Bearer <key>'".into(),
            });
        };
        let key = value
            .strip_prefix("Bearer ")
            .or_else(|| value.strip_prefix("bearer "))
            .unwrap_or(value)
            .trim();
        match self.by_key.get(key) {
            Some(name) => Ok(Caller {
                tenant: Some(name.clone()),
            }),
            None => Err(ServiceError::Unauthenticated {
                message: "the API key is not valid".into(),
            }),
        }
    }
}

/// The id a session of `caller` has in the store: its public id, prefixed by its tenant's
/// name, so that one tenant's lookup cannot reach another's session.
pub fn store_id(caller: &Caller, id: &str) -> String {
    match &caller.tenant {
        Some(tenant) => format!("{tenant}~{id}"),
        None => id.to_string(),
    }
}

/// The public id of a stored session id, if it belongs to `caller`.
pub fn public_id<'a>(caller: &Caller, stored: &'a str) -> Option<&'a str> {
    match &caller.tenant {
        Some(tenant) => stored.strip_prefix(tenant.as_str())?.strip_prefix('~'),
        None => (!stored.contains('~')).then_some(stored),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_from_a_file_and_the_environment_name_their_caller() {
        let keys = ApiKeys::parse(
            Some("# robots\nrobot-1  0123456789abcdef0123\n\n"),
            Some("ops:fedcba9876543210fedc"),
        )
        .unwrap();
        assert_eq!(keys.len(), 2);
        let robot = keys.caller(Some("Bearer 0123456789abcdef0123")).unwrap();
        assert_eq!(robot.tenant.as_deref(), Some("robot-1"));
        assert_eq!(
            keys.caller(Some("fedcba9876543210fedc"))
                .unwrap()
                .tenant
                .as_deref(),
            Some("ops")
        );
        for bad in [None, Some("Bearer nope"), Some("")] {
            assert!(matches!(
                keys.caller(bad),
                Err(ServiceError::Unauthenticated { .. })
            ));
        }
        assert!(
            !format!("{keys:?}").contains("0123456789abcdef"),
            "never shown"
        );
        assert_eq!(ApiKeys::default().caller(None), Ok(Caller::default()));
    }

    #[test]
    fn bad_key_lines_are_named_without_the_key() {
        let e = ApiKeys::parse(Some("robot short"), None).unwrap_err();
        assert!(e.contains("line 1") && !e.contains("short"), "{e}");
        let e = ApiKeys::parse(None, Some("a:0123456789abcdef0123,b")).unwrap_err();
        assert!(e.contains("item 2"), "{e}");
        let e = ApiKeys::parse(Some("r/1 0123456789abcdef0123"), None).unwrap_err();
        assert!(e.contains("name"), "{e}");
    }

    #[test]
    fn a_session_id_is_reachable_by_its_tenant_only() {
        let a = Caller {
            tenant: Some("a".into()),
        };
        let b = Caller {
            tenant: Some("b".into()),
        };
        let stored = store_id(&a, "123");
        assert_eq!(public_id(&a, &stored), Some("123"));
        assert_eq!(public_id(&b, &stored), None);
        assert_eq!(public_id(&Caller::default(), &stored), None);
        assert_eq!(public_id(&Caller::default(), "123"), Some("123"));
    }
}
