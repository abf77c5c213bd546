//! `[http]` checked: where the dashboard listens, over TLS or not, and which tokens it takes.
//!
//! The rules that keep a plant from exposing the fleet by accident: beyond loopback the
//! dashboard needs tokens (or says `anonymous = true`), and tokens beyond loopback need TLS (a
//! token sent in clear is anyone's on the network). On loopback, the embedded default, nothing
//! is asked.

use std::collections::HashSet;
use std::net::SocketAddr;
use std::path::Path;

use super::ConfigError;
use super::file::HttpSection;
use armtwin_access::http_access::{HttpAccess, Role, Token, server_config};

/// The dashboard's address (`--http` replaces `listen`) and access, or why they cannot be.
pub(super) fn load_http(
    section: &HttpSection,
    http_override: Option<SocketAddr>,
    (source_name, base_dir): (&str, &Path),
) -> Result<(Option<SocketAddr>, HttpAccess), ConfigError> {
    let invalid = |field: &str, problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: format!("http.{field}"),
        problem,
    };
    let listen = match (http_override, &section.listen) {
        (Some(address), _) => Some(address),
        (None, None) => None,
        (None, Some(text)) => Some(text.parse().map_err(|e| {
            invalid(
                "listen",
                format!("'{text}' is not an IP address and port: {e}"),
            )
        })?),
    };
    let tls = match (&section.tls_certificate, &section.tls_private_key) {
        (Some(certificate), Some(key)) => Some(
            server_config(&base_dir.join(certificate), &base_dir.join(key))
                .map_err(|problem| invalid("tls_certificate", problem))?,
        ),
        (None, None) => None,
        _ => {
            return Err(invalid(
                "tls_certificate",
                "tls_certificate and tls_private_key go together".to_owned(),
            ));
        }
    };
    let mut names = HashSet::new();
    let mut tokens = Vec::with_capacity(section.tokens.len());
    for entry in &section.tokens {
        let role = Role::parse(&entry.role).ok_or_else(|| {
            invalid(
                "tokens.role",
                format!("'{}' is not a role (viewer, metrics)", entry.role),
            )
        })?;
        if entry.name.trim().is_empty() || entry.name.contains(':') {
            return Err(invalid(
                "tokens.name",
                format!(
                    "'{}' cannot be a user name (empty, or holds ':')",
                    entry.name
                ),
            ));
        }
        if !names.insert(entry.name.as_str()) {
            return Err(invalid(
                "tokens.name",
                format!("'{}' is named twice", entry.name),
            ));
        }
        tokens.push(
            Token::new(&entry.name, role, &entry.hash)
                .map_err(|e| invalid("tokens.hash", e.to_string()))?,
        );
    }
    if let Some(address) = listen.filter(|address| !address.ip().is_loopback()) {
        if tokens.is_empty() && !section.anonymous {
            return Err(invalid(
                "listen",
                format!(
                    "{address} serves the fleet to anyone who reaches it: add [[http.tokens]] \
                     (armtwin http-token NAME makes one) with TLS, or say anonymous = true"
                ),
            ));
        }
        if !tokens.is_empty() && tls.is_none() {
            return Err(invalid(
                "listen",
                format!(
                    "tokens sent to {address} over plain HTTP are anyone's on the network: set \
                     tls_certificate and tls_private_key"
                ),
            ));
        }
    }
    if section.anonymous && !tokens.is_empty() {
        return Err(invalid(
            "anonymous",
            "anonymous = true beside [[http.tokens]]: which one is meant?".to_owned(),
        ));
    }
    Ok((listen, HttpAccess { tls, tokens }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use armtwin_access::http_access::new_token;

    fn section(text: &str) -> HttpSection {
        toml::from_str(text).expect("an [http] section")
    }

    fn load(text: &str) -> Result<(Option<SocketAddr>, HttpAccess), String> {
        load_http(&section(text), None, ("test", Path::new(""))).map_err(|e| e.to_string())
    }

    #[test]
    fn loopback_needs_nothing_and_beyond_it_tokens_need_tls() {
        let (listen, access) = load("listen = \"127.0.0.1:8080\"").expect("the default way");
        assert_eq!(listen, Some("127.0.0.1:8080".parse().expect("an address")));
        assert!(access.tls.is_none() && access.tokens.is_empty());
        assert_eq!(load("").expect("no HTTP").0, None);

        let hash = new_token().expect("randomness").hash;
        let token = format!("[[tokens]]\nname = \"alice\"\nrole = \"viewer\"\nhash = \"{hash}\"\n");
        let (_, access) = load(&format!("listen = \"127.0.0.1:8080\"\n{token}")).expect("tokens");
        assert_eq!(access.tokens.len(), 1);
        assert!(
            load("listen = \"0.0.0.0:8080\"")
                .expect_err("open")
                .contains("anonymous = true")
        );
        assert!(load("listen = \"0.0.0.0:8080\"\nanonymous = true").is_ok());
        let clear = load(&format!("listen = \"0.0.0.0:8080\"\n{token}")).expect_err("in clear");
        assert!(clear.contains("tls_certificate"), "{clear}");
        // `--http` replaces `listen` and meets the same rules.
        let over = load_http(
            &section(""),
            Some("0.0.0.0:8080".parse().expect("an address")),
            ("test", Path::new("")),
        );
        assert!(over.is_err());
    }

    #[test]
    fn malformed_tokens_and_half_tls_are_refused() {
        let hash = new_token().expect("randomness").hash;
        let entry = |name: &str, role: &str, hash: &str| {
            format!("[[tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nhash = \"{hash}\"\n")
        };
        for (text, reason) in [
            (entry("alice", "admin", &hash), "not a role"),
            (entry("a:b", "viewer", &hash), "user name"),
            (entry("alice", "viewer", "sha256:00:00"), "sha256:"),
            (
                entry("alice", "viewer", &hash) + &entry("alice", "metrics", &hash),
                "named twice",
            ),
            ("tls_private_key = \"k.pem\"".to_owned(), "go together"),
            (
                "tls_certificate = \"/nonexistent.pem\"\ntls_private_key = \"/nonexistent.key\""
                    .to_owned(),
                "cannot read the certificate",
            ),
        ] {
            let problem = load(&text).expect_err(&text);
            assert!(problem.contains(reason), "{problem}");
        }
    }
}
