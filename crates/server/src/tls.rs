//! TLS for both ports, from a PEM certificate chain and its private key (rustls with the
//! `ring` provider: no system OpenSSL, no C toolchain beyond what `ring` builds itself).
//!
//! Both files are read and checked once, at start-up, so a wrong path, an empty file or a
//! key that does not belong to the certificate stops the server with a message naming the
//! file, instead of failing every handshake later. The HTTP port offers ALPN `h2` and
//! `http/1.1`; the gRPC port is tonic's own TLS (ALPN `h2`) over the same identity.
//! Client certificates are not asked for: callers authenticate with API keys
//! ([`crate::service::auth`]), which TLS keeps secret on the wire.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::rustls;

/// Why the certificate or key could not be used; each names its file.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error("tls.cert_file and tls.key_file go together: give both or neither")]
    HalfConfigured,
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: no PEM certificate (-----BEGIN CERTIFICATE-----) in it: {detail}")]
    NoCertificate { path: PathBuf, detail: String },
    #[error("{path}: no PEM private key (PKCS#8, PKCS#1 or SEC1) in it: {detail}")]
    NoKey { path: PathBuf, detail: String },
    #[error("{cert} with {key}: {detail}")]
    Unusable {
        cert: PathBuf,
        key: PathBuf,
        detail: String,
    },
}

/// A checked certificate and key, ready for both servers.
#[derive(Clone)]
pub struct ServerTls {
    http: Arc<rustls::ServerConfig>,
    cert_pem: Vec<u8>,
    key_pem: Vec<u8>,
}

impl std::fmt::Debug for ServerTls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never the key.
        f.write_str("ServerTls { .. }")
    }
}

impl ServerTls {
    /// `None` when neither file is given (plain TCP); an error when only one is, or when
    /// they cannot serve.
    pub fn from_config(cert: &Path, key: &Path) -> Result<Option<ServerTls>, TlsError> {
        match (cert.as_os_str().is_empty(), key.as_os_str().is_empty()) {
            (true, true) => Ok(None),
            (false, false) => ServerTls::load(cert, key).map(Some),
            _ => Err(TlsError::HalfConfigured),
        }
    }

    /// Reads both PEM files and checks that the key belongs to the certificate.
    pub fn load(cert: &Path, key: &Path) -> Result<ServerTls, TlsError> {
        let read = |path: &Path| {
            std::fs::read(path).map_err(|source| TlsError::Read {
                path: path.to_path_buf(),
                source,
            })
        };
        let (cert_pem, key_pem) = (read(cert)?, read(key)?);
        ServerTls::from_pem(cert, &cert_pem, key, &key_pem)
    }

    /// As [`ServerTls::load`], from the files' contents (the paths only name them in errors).
    pub fn from_pem(
        cert_path: &Path,
        cert_pem: &[u8],
        key_path: &Path,
        key_pem: &[u8],
    ) -> Result<ServerTls, TlsError> {
        let chain = CertificateDer::pem_slice_iter(cert_pem)
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| TlsError::NoCertificate {
                path: cert_path.to_path_buf(),
                detail: e.to_string(),
            })?;
        if chain.is_empty() {
            return Err(TlsError::NoCertificate {
                path: cert_path.to_path_buf(),
                detail: "the file holds none".to_string(),
            });
        }
        let key = PrivateKeyDer::from_pem_slice(key_pem).map_err(|e| TlsError::NoKey {
            path: key_path.to_path_buf(),
            detail: e.to_string(),
        })?;
        let unusable = |detail: String| TlsError::Unusable {
            cert: cert_path.to_path_buf(),
            key: key_path.to_path_buf(),
            detail,
        };
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let mut http = rustls::ServerConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .map_err(|e| unusable(e.to_string()))?
            .with_no_client_auth()
            .with_single_cert(chain, key)
            .map_err(|e| unusable(e.to_string()))?;
        http.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
        Ok(ServerTls {
            http: Arc::new(http),
            cert_pem: cert_pem.to_vec(),
            key_pem: key_pem.to_vec(),
        })
    }

    /// The HTTP server's handshake.
    pub fn acceptor(&self) -> tokio_rustls::TlsAcceptor {
        tokio_rustls::TlsAcceptor::from(Arc::clone(&self.http))
    }

    /// The gRPC server's TLS; a handshake that takes longer than `handshake_timeout` is
    /// dropped, so a silent client holds nothing.
    pub fn grpc(&self, handshake_timeout: Duration) -> tonic::transport::ServerTlsConfig {
        tonic::transport::ServerTlsConfig::new()
            .identity(tonic::transport::Identity::from_pem(
                &self.cert_pem,
                &self.key_pem,
            ))
            .timeout(handshake_timeout)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn self_signed() -> (String, String) {
        let rcgen::CertifiedKey { cert, signing_key } =
            rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
        (cert.pem(), signing_key.serialize_pem())
    }

    fn load(cert: &str, key: &str) -> Result<ServerTls, TlsError> {
        ServerTls::from_pem(
            Path::new("cert.pem"),
            cert.as_bytes(),
            Path::new("key.pem"),
            key.as_bytes(),
        )
    }

    #[test]
    fn a_matching_certificate_and_key_load_with_both_alpn_protocols() {
        let (cert, key) = self_signed();
        let tls = load(&cert, &key).expect("loads");
        assert_eq!(
            tls.http.alpn_protocols,
            vec![b"h2".to_vec(), b"http/1.1".to_vec()]
        );
        assert_eq!(format!("{tls:?}"), "ServerTls { .. }");
    }

    #[test]
    fn a_key_of_another_certificate_is_refused_naming_both_files() {
        let (cert, _) = self_signed();
        let (_, other_key) = self_signed();
        let e = load(&cert, &other_key).unwrap_err().to_string();
        assert!(e.contains("cert.pem") && e.contains("key.pem"), "{e}");
    }

    #[test]
    fn swapped_or_empty_files_are_refused_naming_the_file() {
        let (cert, key) = self_signed();
        let e = load(&key, &cert).unwrap_err().to_string();
        assert!(e.starts_with("cert.pem: no PEM certificate"), "{e}");
        let e = load(&cert, "").unwrap_err().to_string();
        assert!(e.starts_with("key.pem: no PEM private key"), "{e}");
    }

    #[test]
    fn only_one_file_is_a_configuration_error_and_none_is_plain_tcp() {
        assert!(ServerTls::from_config(Path::new(""), Path::new(""))
            .unwrap()
            .is_none());
        assert!(matches!(
            ServerTls::from_config(Path::new("cert.pem"), Path::new("")),
            Err(TlsError::HalfConfigured)
        ));
        let e = ServerTls::from_config(Path::new("/nonexistent/cert.pem"), Path::new("k.pem"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("/nonexistent/cert.pem: cannot read"), "{e}");
    }
}
