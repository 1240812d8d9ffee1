//! Service configuration, in layers (figment): defaults → an optional TOML file → environment
//! variables `TRINOCULAR__SECTION__KEY` → command-line flags (merged by the caller). Unknown
//! keys are errors wherever they come from; [`Config::validate`] reports every problem at once.
//!
//! ```toml
//! [server]
//! grpc_addr = "0.0.0.0:50051"
//! http_addr = "0.0.0.0:8080"
//! max_connections = 1024     # HTTP; past it, 503 and close
//! header_timeout_ms = 10000  # a request's headers, and a kept-alive connection's idle time
//! body_timeout_ms = 30000    # a request's body, once its headers arrived
//! shutdown_grace_ms = 10000  # after SIGTERM, then open connections are cut
//! [compute]
//! threads = 2          # 0: one per core
//! max_jobs = 4         # 0: two per thread
//! network_nice = 10    # the network threads this many nice levels below the compute threads
//! [limits]
//! max_message_mib = 32
//! max_image_pixels = 3000000
//! max_segments_per_list = 100000
//! max_request_ms = 60000   # a request's deadline when it gives none, and the cap on its own
//! max_bodies_mib = 32      # request bodies held at once, taken as their bytes arrive
//! max_working_mib = 320    # the compute jobs' working memory, reserved from an estimate
//! [log]
//! json = false
//! level = "info"
//! [auth]
//! keys_file = ""       # `name key` lines; with TRINOCULAR_API_KEYS=name:key,...; none: open
//! max_sessions_per_key = 1000
//! [store]
//! url = "embedded"     # or redis://host:port[/db], shared by replicas
//! data_dir = "data"    # the embedded store's directory, relative to the working directory
//! session_ttl_s = 86400
//! ```

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use figment::providers::{Env, Format, Serialized, Toml};
use figment::Figment;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::service::Limits;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub server: ServerConfig,
    pub compute: ComputeConfig,
    pub limits: LimitsConfig,
    pub log: LogConfig,
    pub store: StoreConfig,
    pub auth: AuthConfig,
    pub tls: TlsConfig,
}

/// TLS on both ports ([`crate::tls`]): a PEM certificate chain and its private key; neither
/// leaves both ports plain TCP.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct TlsConfig {
    /// The server's certificate chain, PEM (leaf first); empty: no TLS.
    pub cert_file: PathBuf,
    /// Its private key, PEM (PKCS#8, PKCS#1 or SEC1); never logged.
    pub key_file: PathBuf,
}

/// API keys ([`crate::service::auth`]): from `keys_file` and the `TRINOCULAR_API_KEYS`
/// variable; none at all leaves the service open.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AuthConfig {
    /// A file of `name key` lines; empty: none.
    pub keys_file: PathBuf,
    /// Sessions one key may hold at once.
    pub max_sessions_per_key: usize,
}

impl Default for AuthConfig {
    fn default() -> Self {
        AuthConfig {
            keys_file: PathBuf::new(),
            max_sessions_per_key: crate::service::MAX_SESSIONS_PER_KEY,
        }
    }
}

/// Where sessions live (see [`crate::service::store::open`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StoreConfig {
    /// `embedded` (a redb file under `data_dir`, one replica) or `redis://host:port[/db]`.
    pub url: String,
    /// The embedded store's directory, relative to the working directory; created if missing.
    pub data_dir: PathBuf,
    /// A session not used for this long disappears with its captures, seconds.
    pub session_ttl_s: u64,
}

impl Default for StoreConfig {
    fn default() -> Self {
        StoreConfig {
            url: "embedded".to_string(),
            data_dir: PathBuf::from("data"),
            session_ttl_s: 24 * 3600,
        }
    }
}

impl StoreConfig {
    /// The idle TTL.
    pub fn session_ttl(&self) -> Duration {
        Duration::from_secs(self.session_ttl_s)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogConfig {
    /// One JSON object per line instead of text.
    pub json: bool,
    /// A `tracing` filter: `info`, `debug`, `trinocular=debug,info`, ...
    pub level: String,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            json: false,
            level: "info".to_string(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    pub grpc_addr: SocketAddr,
    pub http_addr: SocketAddr,
    /// HTTP connections open at once; past it, 503 and close.
    pub max_connections: usize,
    /// Longest wait for a request's headers (and idle time of a kept-alive connection), ms.
    pub header_timeout_ms: u64,
    /// Longest wait for a request's body once its headers arrived, ms.
    pub body_timeout_ms: u64,
    /// After SIGTERM, how long open connections may finish before they are cut, ms.
    pub shutdown_grace_ms: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ComputeConfig {
    /// Compute threads; 0: one per core.
    pub threads: usize,
    /// Jobs queued or running at once; 0: two per thread.
    pub max_jobs: usize,
    /// How many nice levels below the compute threads the network threads run (0 to 19; 0:
    /// the same), so that under overload the CPU goes to admitted work
    /// ([`crate::service::priority`]).
    pub network_nice: i32,
}

impl Default for ComputeConfig {
    fn default() -> Self {
        ComputeConfig {
            threads: 0,
            max_jobs: 0,
            network_nice: crate::service::priority::DEFAULT_NETWORK_NICE,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsConfig {
    pub max_message_mib: usize,
    pub max_image_pixels: u64,
    pub max_segments_per_list: usize,
    /// Longest a request may run, milliseconds (its deadline when it gives none).
    pub max_request_ms: u64,
    /// Request bodies held at once, MiB (each body's bytes taken as they arrive, before they
    /// are gathered).
    pub max_bodies_mib: usize,
    /// The compute jobs' working memory at once, MiB (each reserves its estimate first).
    pub max_working_mib: u64,
}

impl Default for ServerConfig {
    fn default() -> Self {
        let connections = crate::http_server::ConnectionLimits::default();
        ServerConfig {
            grpc_addr: SocketAddr::from(([0, 0, 0, 0], 50051)),
            http_addr: SocketAddr::from(([0, 0, 0, 0], 8080)),
            max_connections: connections.max_connections,
            header_timeout_ms: connections.header_timeout.as_millis() as u64,
            body_timeout_ms: connections.body_timeout.as_millis() as u64,
            shutdown_grace_ms: connections.shutdown_grace.as_millis() as u64,
        }
    }
}

impl Default for LimitsConfig {
    fn default() -> Self {
        LimitsConfig {
            max_message_mib: 32,
            max_image_pixels: crate::service::Limits::default().max_image_pixels,
            max_segments_per_list: trinocular_schema::MAX_SEGMENTS_PER_LIST,
            max_request_ms: crate::service::MAX_REQUEST_TIME.as_millis() as u64,
            max_bodies_mib: crate::service::Limits::default().max_body_bytes_in_flight >> 20,
            max_working_mib: crate::service::Limits::default().max_working_bytes >> 20,
        }
    }
}

/// Longest request time accepted by configuration: an hour, as for `timeout_ms`.
const MAX_REQUEST_MS: u64 = 3_600_000;

/// The working-memory budget accepted by configuration, MiB: at least one small request's,
/// at most a terabyte.
const MIN_WORKING_MIB: u64 = 16;
const MAX_WORKING_MIB: u64 = 1 << 20;

/// Largest request accepted by configuration, MiB.
const MAX_MESSAGE_MIB: usize = 1024;

/// Environment variables read, with this prefix and `__` between section and key.
pub const ENV_PREFIX: &str = "TRINOCULAR__";

/// Why a configuration cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// A layer could not be read: TOML that does not parse, an unknown key, a value of the
    /// wrong type. Names the key and the layer it came from (file, environment variable, flag).
    #[error("configuration: {0}")]
    Layer(Box<figment::Error>),
    /// Values that read well but do not make a service: every problem, one per line.
    #[error("invalid configuration:\n{0}")]
    Invalid(String),
}

impl From<figment::Error> for ConfigError {
    fn from(e: figment::Error) -> ConfigError {
        ConfigError::Layer(Box::new(e))
    }
}

impl Config {
    /// The layers, each over the one before: the defaults, `file` (TOML text), then the
    /// environment's `TRINOCULAR__SECTION__KEY` variables (values read as TOML: `8`,
    /// `"0.0.0.0:1"`, or bare strings). A caller merges its command-line flags on top (as
    /// `("section.key", value)` pairs) and reads the result with [`Config::from_layers`].
    pub fn layers(file: Option<&str>) -> Figment {
        let mut layers = Figment::from(Serialized::defaults(Config::default()));
        if let Some(text) = file {
            layers = layers.merge(Toml::string(text));
        }
        layers.merge(Env::prefixed(ENV_PREFIX).split("__"))
    }

    /// `layers` with command-line `flags` over them: `flags` serialises to a map keyed by
    /// dotted paths (`"server.grpc_addr"`), absent flags skipped — so each flag's declaration
    /// says which key it sets, and no code copies flags into the configuration one by one.
    pub fn with_flags(layers: Figment, flags: &impl Serialize) -> Result<Figment, ConfigError> {
        let not_a_map = || figment::Error::from("the flags are not a map of keys".to_string());
        let flags = serde_json::to_value(flags).map_err(|_| not_a_map())?;
        let serde_json::Value::Object(map) = flags else {
            return Err(not_a_map().into());
        };
        Ok(map
            .into_iter()
            .fold(layers, |layers, (key, value)| layers.merge((key, value))))
    }

    /// The configuration the layers give, checked ([`Config::validate`]).
    pub fn from_layers(layers: &Figment) -> Result<Config, ConfigError> {
        let config: Config = layers.extract()?;
        config.validate().map_err(ConfigError::Invalid)?;
        Ok(config)
    }

    /// Every problem, one per line.
    pub fn validate(&self) -> Result<(), String> {
        let mut problems = Vec::new();
        if self.server.grpc_addr == self.server.http_addr && self.server.grpc_addr.port() != 0 {
            problems.push("server.grpc_addr and server.http_addr must differ".to_string());
        }
        if !(1..=MAX_MESSAGE_MIB).contains(&self.limits.max_message_mib) {
            problems.push(format!(
                "limits.max_message_mib must be 1 to {MAX_MESSAGE_MIB}, got {}",
                self.limits.max_message_mib
            ));
        }
        if tracing_subscriber::EnvFilter::try_new(&self.log.level).is_err() {
            problems.push(format!(
                "log.level: {:?} is not a log filter",
                self.log.level
            ));
        }
        if !(MIN_WORKING_MIB..=MAX_WORKING_MIB).contains(&self.limits.max_working_mib) {
            problems.push(format!(
                "limits.max_working_mib must be {MIN_WORKING_MIB} to {MAX_WORKING_MIB}, got {}",
                self.limits.max_working_mib
            ));
        }
        if self.limits.max_image_pixels == 0 {
            problems.push("limits.max_image_pixels must be at least 1".to_string());
        }
        if !(1..=MAX_REQUEST_MS).contains(&self.limits.max_request_ms) {
            problems.push(format!(
                "limits.max_request_ms must be 1 to {MAX_REQUEST_MS}, got {}",
                self.limits.max_request_ms
            ));
        }
        if self.limits.max_bodies_mib < self.limits.max_message_mib {
            problems.push(format!(
                "limits.max_bodies_mib must be at least limits.max_message_mib ({}), got {}",
                self.limits.max_message_mib, self.limits.max_bodies_mib
            ));
        }
        if !(0..=19).contains(&self.compute.network_nice) {
            problems.push(format!(
                "compute.network_nice must be 0 to 19, got {}",
                self.compute.network_nice
            ));
        }
        if self.server.max_connections == 0 {
            problems.push("server.max_connections must be at least 1".to_string());
        }
        for (name, ms) in [
            ("server.header_timeout_ms", self.server.header_timeout_ms),
            ("server.body_timeout_ms", self.server.body_timeout_ms),
            ("server.shutdown_grace_ms", self.server.shutdown_grace_ms),
        ] {
            if !(1..=MAX_REQUEST_MS).contains(&ms) {
                problems.push(format!("{name} must be 1 to {MAX_REQUEST_MS}, got {ms}"));
            }
        }
        if self.limits.max_segments_per_list == 0 {
            problems.push("limits.max_segments_per_list must be at least 1".to_string());
        }
        if let Err(problem) = crate::service::store::check_url(&self.store.url) {
            problems.push(problem);
        }
        if self.auth.max_sessions_per_key == 0 {
            problems.push("auth.max_sessions_per_key must be at least 1".to_string());
        }
        if self.tls.cert_file.as_os_str().is_empty() != self.tls.key_file.as_os_str().is_empty() {
            problems.push(
                "tls.cert_file and tls.key_file go together: give both or neither".to_string(),
            );
        }
        if self.store.session_ttl_s == 0 {
            problems.push("store.session_ttl_s must be at least 1".to_string());
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(problems.join("\n"))
        }
    }

    /// The service limits this configuration gives on this machine.
    pub fn limits(&self) -> Limits {
        let defaults = Limits::default();
        let threads = if self.compute.threads == 0 {
            defaults.threads
        } else {
            self.compute.threads
        };
        Limits {
            threads,
            max_jobs: if self.compute.max_jobs == 0 {
                crate::service::JOBS_PER_THREAD * threads
            } else {
                self.compute.max_jobs
            },
            max_message_bytes: self.limits.max_message_mib << 20,
            max_image_pixels: self.limits.max_image_pixels,
            max_segments_per_list: self.limits.max_segments_per_list,
            max_request_time: Duration::from_millis(self.limits.max_request_ms),
            max_body_bytes_in_flight: self.limits.max_bodies_mib << 20,
            max_working_bytes: self.limits.max_working_mib << 20,
            connections: crate::http_server::ConnectionLimits {
                max_connections: self.server.max_connections,
                header_timeout: Duration::from_millis(self.server.header_timeout_ms),
                body_timeout: Duration::from_millis(self.server.body_timeout_ms),
                shutdown_grace: Duration::from_millis(self.server.shutdown_grace_ms),
            },
        }
    }
}

#[cfg(test)]
// figment's `Jail` closures return its `Error`, large by figment's design.
#[allow(clippy::result_large_err)]
mod tests {
    use super::*;

    use figment::Jail;

    /// The configuration of `file` under the environment `jail` set.
    fn load(file: Option<&str>) -> Result<Config, ConfigError> {
        Config::from_layers(&Config::layers(file))
    }

    #[test]
    fn layers_apply_in_order() {
        Jail::expect_with(|jail| {
            let file =
                "[compute]\nthreads = 3\nmax_jobs = 5\n[server]\nhttp_addr = \"127.0.0.1:9000\"\n";
            jail.set_env("TRINOCULAR__COMPUTE__MAX_JOBS", "7");
            jail.set_env("HOME", "/root");
            let c = load(Some(file)).unwrap();
            assert_eq!(c.compute.threads, 3, "from the file");
            assert_eq!(c.compute.max_jobs, 7, "the environment beats the file");
            assert_eq!(c.server.http_addr, "127.0.0.1:9000".parse().unwrap());
            assert_eq!(
                c.server.grpc_addr,
                ServerConfig::default().grpc_addr,
                "default"
            );
            assert_eq!(c.limits().max_jobs, 7);
            // A flag, merged last, beats them all.
            let flagged =
                Config::from_layers(&Config::layers(Some(file)).merge(("compute.max_jobs", 9)))
                    .unwrap();
            assert_eq!(flagged.compute.max_jobs, 9);
            jail.set_env("TRINOCULAR__SERVER__GRPC_ADDR", "127.0.0.1:1");
            assert_eq!(
                load(None).unwrap().server.grpc_addr,
                "127.0.0.1:1".parse().unwrap()
            );
            Ok(())
        });
        assert_eq!(
            Config::default().limits().max_jobs,
            crate::service::JOBS_PER_THREAD * Limits::default().threads
        );
    }

    #[test]
    fn unknown_keys_and_bad_values_are_refused_naming_them() {
        Jail::expect_with(|jail| {
            let e = load(Some("[compute]\nthread = 3\n"))
                .unwrap_err()
                .to_string();
            assert!(e.contains("thread"), "{e}");
            jail.set_env("TRINOCULAR__COMPUTE__SPEED", "9");
            let e = load(None).unwrap_err().to_string();
            assert!(e.contains("speed"), "{e}");
            jail.clear_env();
            jail.set_env("TRINOCULAR__THREADS", "9");
            let e = load(None).unwrap_err().to_string();
            assert!(e.contains("threads"), "{e}");
            jail.clear_env();
            let e = load(Some("[limits]\nmax_message_mib = \"big\"\n")).unwrap_err();
            assert!(e.to_string().contains("max_message_mib"), "{e}");
            Ok(())
        });
        let mut c = Config::default();
        c.limits.max_message_mib = 0;
        c.limits.max_image_pixels = 0;
        c.limits.max_segments_per_list = 0;
        let problems = c.validate().unwrap_err();
        assert_eq!(problems.lines().count(), 3, "{problems}");
    }

    #[test]
    fn store_section() {
        let c = Config::default();
        assert_eq!(c.store.url, "embedded");
        assert_eq!(c.store.data_dir, PathBuf::from("data"));
        assert_eq!(c.store.session_ttl(), Duration::from_secs(86400));
        assert!(c.validate().is_ok());
        Jail::expect_with(|jail| {
            let file = "[store]\nurl = \"redis://127.0.0.1:6379/1\"\ndata_dir = \"/var/lib/t\"\n";
            jail.set_env("TRINOCULAR__STORE__SESSION_TTL_S", "60");
            let c = load(Some(file)).unwrap();
            assert_eq!(c.store.url, "redis://127.0.0.1:6379/1");
            assert_eq!(c.store.data_dir, PathBuf::from("/var/lib/t"));
            assert_eq!(c.store.session_ttl_s, 60);
            let e = load(Some("[store]\nttl = 5\n")).unwrap_err().to_string();
            assert!(e.contains("ttl"), "{e}");
            Ok(())
        });
        let mut c = Config::default();
        c.store.url = "mysql://db".to_string();
        c.store.session_ttl_s = 0;
        let problems = c.validate().unwrap_err();
        assert_eq!(problems.lines().count(), 2, "{problems}");
        assert!(problems.contains("store.url"), "{problems}");
        assert!(problems.contains("store.session_ttl_s"), "{problems}");
    }
}
