//! `trinocular serve`: a checked [`Config`] becomes a running service — logging, the async
//! runtime (its network threads below the compute threads in priority), the session store,
//! the API keys, TLS, both listeners — until SIGTERM or SIGINT, then a graceful stop
//! (readiness false, in-flight requests finished). The CLI only parses its flags and loads
//! the configuration's layers.

use std::sync::Arc;

use thiserror::Error;

use crate::config::Config;
use crate::service::auth::{ApiKeys, KEYS_ENV};
use crate::service::{priority, store, Service};
use crate::tls::ServerTls;

/// Why the service could not start, or stopped other than by a signal.
#[derive(Debug, Error)]
pub enum ServeError {
    #[error("log.level: {0}")]
    LogLevel(String),
    #[error("cannot start the async runtime: {0}")]
    Runtime(std::io::Error),
    #[error("cannot open the session store: {0}")]
    Store(String),
    #[error("cannot read auth.keys_file {path}: {source}")]
    KeysFile {
        path: String,
        source: std::io::Error,
    },
    #[error("API keys: {0}")]
    Keys(String),
    #[error("cannot start the service: {0}")]
    Service(String),
    #[error("TLS: {0}")]
    Tls(String),
    #[error("cannot listen: {0}")]
    Listen(std::io::Error),
    #[error("cannot handle SIGTERM: {0}")]
    Signal(std::io::Error),
}

/// Starts the logs: human-readable to a terminal, one JSON object per line if `log.json`.
fn start_logging(config: &Config) -> Result<(), ServeError> {
    let filter = tracing_subscriber::EnvFilter::try_new(&config.log.level)
        .map_err(|e| ServeError::LogLevel(e.to_string()))?;
    let logs = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr);
    if config.log.json {
        logs.json().init();
    } else {
        logs.init();
    }
    Ok(())
}

/// The API keys of `auth.keys_file` and the environment's [`KEYS_ENV`].
fn api_keys(config: &Config) -> Result<ApiKeys, ServeError> {
    let file = if config.auth.keys_file.as_os_str().is_empty() {
        None
    } else {
        Some(
            std::fs::read_to_string(&config.auth.keys_file).map_err(|source| {
                ServeError::KeysFile {
                    path: config.auth.keys_file.display().to_string(),
                    source,
                }
            })?,
        )
    };
    ApiKeys::parse(file.as_deref(), std::env::var(KEYS_ENV).ok().as_deref())
        .map_err(ServeError::Keys)
}

/// Runs the service `config` describes until SIGTERM or SIGINT.
pub fn serve(config: Config) -> Result<(), ServeError> {
    start_logging(&config)?;
    let limits = config.limits();
    let shown = Config {
        store: crate::config::StoreConfig {
            url: store::redacted(&config.store.url),
            ..config.store.clone()
        },
        ..config.clone()
    };
    tracing::info!(
        config = %toml::to_string(&shown).unwrap_or_default(),
        limits = ?limits,
        "effective configuration"
    );
    let network_nice = config.compute.network_nice;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .on_thread_start(move || {
            if let Err(e) = priority::lower_this_thread(network_nice) {
                tracing::warn!(error = %e, "cannot lower the network threads' priority");
            }
        })
        .build()
        .map_err(ServeError::Runtime)?;
    runtime.block_on(async {
        let ttl = config.store.session_ttl();
        let store = store::open(&config.store.url, &config.store.data_dir, ttl)
            .await
            .map_err(|e| ServeError::Store(e.to_string()))?;
        tracing::info!(store = %store.describe(), "sessions");
        let keys = api_keys(&config)?;
        if keys.is_empty() {
            tracing::warn!("auth: no API keys configured; the service is open to every caller");
        } else {
            tracing::info!(keys = keys.len(), "auth: an API key is required");
        }
        let service = Arc::new(
            Service::new(limits, store, ttl)
                .map_err(|e| ServeError::Service(e.to_string()))?
                .with_api_keys(keys, config.auth.max_sessions_per_key),
        );
        let tls = ServerTls::from_config(&config.tls.cert_file, &config.tls.key_file)
            .map_err(|e| ServeError::Tls(e.to_string()))?;
        let scheme = if tls.is_some() { "TLS" } else { "plain TCP" };
        let running = crate::server::start_with_tls(
            Arc::clone(&service),
            config.server.grpc_addr,
            config.server.http_addr,
            tls,
        )
        .await
        .map_err(ServeError::Listen)?;
        tracing::info!(grpc = %running.grpc_addr, http = %running.http_addr, transport = scheme, "listening");
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .map_err(ServeError::Signal)?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        tracing::info!("stopping: readiness false, finishing in-flight requests");
        service.set_ready(false);
        running.shutdown().await;
        tracing::info!("stopped");
        Ok(())
    })
}
