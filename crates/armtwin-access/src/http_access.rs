//! Who may reach the service's HTTP side (`[http]`): its TLS identity, and bearer tokens, each
//! with a name and a role, kept in the configuration as salted SHA-256 digests.
//!
//! A token is 256 random bits that `armtwin http-token` makes; a client sends it as
//! `Authorization: Bearer <token>` (Prometheus' `authorization`, scripts) or as the password of
//! HTTP Basic authentication with its name as the user (browsers ask for it once per session).
//! Against a secret of 256 random bits a slow password hash (argon2, bcrypt) adds nothing — no
//! guessing reaches it — while it would cost tens of milliseconds on each request, and a page
//! makes several (assets, streams); the per-token salt keeps two configurations holding the same
//! token from showing the same digest. Tokens are never chosen by people, so none is weak.
//!
//! Roles: `viewer` reads everything the dashboard serves (pages, `/api`, streams, `/metrics`);
//! `metrics` reads `/metrics` only (a Prometheus scraper). The dashboard never changes a twin,
//! so there is no role that may.
//!
//! The TLS identity is read from PEM into a rustls configuration on the ring provider, the one
//! Zenoh's TLS links use, so the process carries one TLS stack.
//!
//! Pure decisions and file reading only: no HTTP server, no twin. The configuration loads an
//! [`HttpAccess`]; the dashboard applies it.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;

use base64::Engine as _;
use base64::engine::general_purpose::{STANDARD, URL_SAFE_NO_PAD};
use ring::digest::{SHA256, digest};
use ring::rand::{SecureRandom, SystemRandom};
use rustls::ServerConfig;
use rustls::pki_types::pem::PemObject as _;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use thiserror::Error;

/// Bytes of randomness in a token.
const TOKEN_BYTES: usize = 32;
/// Bytes of a digest's salt.
const SALT_BYTES: usize = 16;
/// The scheme written before a stored digest.
const HASH_SCHEME: &str = "sha256";

/// What a token may read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Every page, stream, `/api` and `/metrics`.
    Viewer,
    /// `/metrics` only.
    Metrics,
}

impl Role {
    /// The role named `text` (`viewer`, `metrics`).
    #[must_use]
    pub fn parse(text: &str) -> Option<Self> {
        match text {
            "viewer" => Some(Self::Viewer),
            "metrics" => Some(Self::Metrics),
            _ => None,
        }
    }

    /// Its name in the configuration.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Viewer => "viewer",
            Self::Metrics => "metrics",
        }
    }

    fn may_read(self, path: &str) -> bool {
        match self {
            Self::Viewer => true,
            Self::Metrics => path == "/metrics",
        }
    }
}

/// Why a stored token digest cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error(
    "'{0}' is not sha256:<32 hex digits of salt>:<64 hex digits of digest> (armtwin http-token makes one)"
)]
pub struct HashFormatError(String);

/// One token the dashboard accepts.
#[derive(Clone, PartialEq, Eq)]
pub struct Token {
    name: String,
    role: Role,
    salt: [u8; SALT_BYTES],
    digest: [u8; 32],
}

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Token")
            .field("name", &self.name)
            .field("role", &self.role)
            .finish_non_exhaustive()
    }
}

impl Token {
    /// A token from its configuration entry: its name, role and stored digest.
    pub fn new(name: &str, role: Role, hash: &str) -> Result<Self, HashFormatError> {
        let wrong = || HashFormatError(hash.to_owned());
        let mut parts = hash.split(':');
        let (Some(HASH_SCHEME), Some(salt), Some(digest), None) =
            (parts.next(), parts.next(), parts.next(), parts.next())
        else {
            return Err(wrong());
        };
        Ok(Self {
            name: name.to_owned(),
            role,
            salt: from_hex(salt).ok_or_else(wrong)?,
            digest: from_hex(digest).ok_or_else(wrong)?,
        })
    }

    /// Its name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    fn matches(&self, secret: &str) -> bool {
        // Both sides are digests of salted input: a compare that stops at the first differing
        // byte tells an attacker nothing he can steer towards the stored digest.
        salted_digest(&self.salt, secret) == self.digest
    }
}

fn salted_digest(salt: &[u8], secret: &str) -> [u8; 32] {
    let mut input = Vec::with_capacity(salt.len() + secret.len());
    input.extend_from_slice(salt);
    input.extend_from_slice(secret.as_bytes());
    let mut out = [0; 32];
    out.copy_from_slice(digest(&SHA256, &input).as_ref());
    out
}

fn from_hex<const N: usize>(text: &str) -> Option<[u8; N]> {
    if text.len() != 2 * N {
        return None;
    }
    let mut out = [0; N];
    for (byte, pair) in out.iter_mut().zip(text.as_bytes().chunks(2)) {
        *byte = u8::from_str_radix(std::str::from_utf8(pair).ok()?, 16).ok()?;
    }
    Some(out)
}

fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut text, byte| {
        let _ = write!(text, "{byte:02x}");
        text
    })
}

/// A new token and the digest its configuration entry holds.
#[derive(Debug)]
pub struct NewToken {
    /// The secret, for the client only (base64url, 43 characters).
    pub token: String,
    /// `sha256:<salt>:<digest>`, for `[[http.tokens]] hash`.
    pub hash: String,
}

/// Why no token could be made.
#[derive(Debug, Error)]
#[error("the system's random number generator failed")]
pub struct RandomError;

/// Makes a token from the system's random number generator.
pub fn new_token() -> Result<NewToken, RandomError> {
    let random = SystemRandom::new();
    let mut secret = [0; TOKEN_BYTES];
    let mut salt = [0; SALT_BYTES];
    random.fill(&mut secret).map_err(|_| RandomError)?;
    random.fill(&mut salt).map_err(|_| RandomError)?;
    let token = URL_SAFE_NO_PAD.encode(secret);
    let hash = format!(
        "{HASH_SCHEME}:{}:{}",
        to_hex(&salt),
        to_hex(&salted_digest(&salt, &token))
    );
    Ok(NewToken { token, hash })
}

/// What a request may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Served.
    Allow,
    /// No valid credential: 401, with a challenge that makes a browser ask.
    Unauthenticated,
    /// A valid token whose role does not read this path: 403.
    Forbidden,
}

/// Whether a request for `path` with the `Authorization` header `authorization` is served,
/// given the accepted `tokens` (none: everything is open).
#[must_use]
pub fn decide(tokens: &[Token], path: &str, authorization: Option<&str>) -> Decision {
    if tokens.is_empty() || path == "/healthz" {
        return Decision::Allow;
    }
    let found = authorization.and_then(|value| {
        let (scheme, credential) = value.trim().split_once(' ')?;
        let credential = credential.trim();
        if scheme.eq_ignore_ascii_case("bearer") {
            tokens.iter().find(|token| token.matches(credential))
        } else if scheme.eq_ignore_ascii_case("basic") {
            let decoded = STANDARD.decode(credential).ok()?;
            let (user, secret) = std::str::from_utf8(&decoded).ok()?.split_once(':')?;
            tokens
                .iter()
                .find(|token| token.name == user && token.matches(secret))
        } else {
            None
        }
    });
    match found {
        None => Decision::Unauthenticated,
        Some(token) if token.role.may_read(path) => Decision::Allow,
        Some(_) => Decision::Forbidden,
    }
}

/// Who may reach the dashboard, and how (`[http]`): TLS or plain HTTP, tokens or open.
#[derive(Debug, Clone, Default)]
pub struct HttpAccess {
    /// The server's TLS configuration; `None`, plain HTTP.
    pub tls: Option<Arc<ServerConfig>>,
    /// The tokens taken; none, every request is served (the single-machine default).
    pub tokens: Vec<Token>,
}

/// The rustls configuration of a certificate chain and its key, both PEM files; the reason when
/// they cannot be read or do not belong together.
pub fn server_config(certificate: &Path, private_key: &Path) -> Result<Arc<ServerConfig>, String> {
    let chain = CertificateDer::pem_file_iter(certificate)
        .and_then(Iterator::collect::<Result<Vec<_>, _>>)
        .map_err(|e| format!("cannot read the certificate {}: {e}", certificate.display()))?;
    if chain.is_empty() {
        return Err(format!("{} holds no certificate", certificate.display()));
    }
    let key = PrivateKeyDer::from_pem_file(private_key)
        .map_err(|e| format!("cannot read the private key {}: {e}", private_key.display()))?;
    let mut config =
        ServerConfig::builder_with_provider(Arc::new(rustls::crypto::ring::default_provider()))
            .with_safe_default_protocol_versions()
            .map_err(|e| e.to_string())?
            .with_no_client_auth()
            .with_single_cert(chain, key)
            .map_err(|e| {
                format!(
                    "{} and {} do not make a server identity: {e}",
                    certificate.display(),
                    private_key.display()
                )
            })?;
    // The server speaks HTTP/1.1 (axum's `http1`); saying so lets clients skip asking for h2.
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Arc::new(config))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn basic(user: &str, secret: &str) -> String {
        format!("Basic {}", STANDARD.encode(format!("{user}:{secret}")))
    }

    #[test]
    fn a_new_token_matches_its_own_digest_only() {
        let made = new_token().expect("randomness");
        let other = new_token().expect("randomness");
        assert_eq!(made.token.len(), 43);
        assert_ne!(made.token, other.token);
        let token = Token::new("alice", Role::Viewer, &made.hash).expect("a digest");
        assert!(token.matches(&made.token));
        assert!(!token.matches(&other.token));
        assert!(!token.matches(""));
        // Same secret, another salt: another digest.
        let salt = [7; SALT_BYTES];
        assert_ne!(salted_digest(&salt, &made.token), token.digest);
    }

    #[test]
    fn a_malformed_digest_is_refused() {
        let good = new_token().expect("randomness").hash;
        assert!(Token::new("a", Role::Viewer, &good).is_ok());
        for bad in [
            "",
            "sha256",
            &good.replacen("sha256", "md5", 1),
            &good[..good.len() - 1],
            &format!("{good}:00"),
            &good.replacen(':', ":zz", 1)[..good.len()],
        ] {
            assert!(Token::new("a", Role::Viewer, bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn requests_are_served_by_role_and_healthz_is_open() {
        use Decision::{Allow, Forbidden, Unauthenticated};
        let viewer = new_token().expect("randomness");
        let scraper = new_token().expect("randomness");
        let tokens = [
            Token::new("alice", Role::Viewer, &viewer.hash).expect("a digest"),
            Token::new("prometheus", Role::Metrics, &scraper.hash).expect("a digest"),
        ];
        let bearer = |t: &str| format!("Bearer {t}");
        for (path, authorization, expected) in [
            ("/healthz", None, Allow),
            ("/", None, Unauthenticated),
            ("/metrics", None, Unauthenticated),
            ("/", Some(bearer(&viewer.token)), Allow),
            ("/api/robot/stream", Some(bearer(&viewer.token)), Allow),
            ("/metrics", Some(bearer(&viewer.token)), Allow),
            ("/metrics", Some(bearer(&scraper.token)), Allow),
            ("/", Some(bearer(&scraper.token)), Forbidden),
            ("/api/fleet", Some(bearer(&scraper.token)), Forbidden),
            ("/", Some(bearer("not-a-token")), Unauthenticated),
            ("/", Some(format!("bearer  {}", viewer.token)), Allow),
            ("/", Some(basic("alice", &viewer.token)), Allow),
            // Basic needs the token's own name.
            (
                "/",
                Some(basic("prometheus", &viewer.token)),
                Unauthenticated,
            ),
            ("/", Some(basic("alice", "guess")), Unauthenticated),
            ("/", Some("Basic !!!".to_owned()), Unauthenticated),
            ("/", Some(viewer.token.clone()), Unauthenticated),
        ] {
            assert_eq!(
                decide(&tokens, path, authorization.as_deref()),
                expected,
                "{path} {authorization:?}"
            );
        }
        // Without tokens the dashboard is open, as on a single machine.
        assert_eq!(decide(&[], "/", None), Allow);
    }
}
