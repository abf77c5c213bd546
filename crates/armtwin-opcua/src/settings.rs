//! `[opcua]` as written (serde) and checked: where the server listens, who may connect, with
//! which certificate, and how often it samples the twins.
//!
//! The rules that keep a plant from exposing its arms by accident: anonymous access is off
//! unless `anonymous = true`; security policy None is offered only on a loopback endpoint or
//! with `security_none = true`, and then to anonymous clients alone, so a password never
//! travels on an unencrypted channel. Must not open a socket or read a certificate: the server
//! does that when it starts.

use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use crate::password::PasswordHash;

/// `[opcua]` as written: off unless `endpoint` (or `--opcua`) is given.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpcUaSection {
    /// `opc.tcp://HOST:PORT`: where the server listens.
    pub endpoint: Option<String>,
    /// `opc.tcp://HOST:PORT`: the URL clients are told, when it is not `endpoint` (a server
    /// listening on every interface, or behind a name or a port mapping).
    pub advertise: Option<String>,
    /// How often the server copies every twin's state into its nodes (ms).
    pub sampling_interval_ms: Option<u64>,
    /// Anonymous clients are let in.
    #[serde(default)]
    pub anonymous: bool,
    /// Security policy None is offered beyond loopback too (to anonymous clients).
    #[serde(default)]
    pub security_none: bool,
    /// The server's certificate and private key are kept (and, unless both `certificate` and
    /// `private_key` are given, created on the first start) here, beside `trusted/` and
    /// `rejected/` client certificates.
    pub pki_dir: Option<PathBuf>,
    /// The server's own certificate (DER), with `private_key`.
    pub certificate: Option<PathBuf>,
    /// The server's private key (PEM), with `certificate`.
    pub private_key: Option<PathBuf>,
    /// `[[opcua.users]]`.
    #[serde(default)]
    pub users: Vec<UserSection>,
}

/// `[[opcua.users]]`: one user name, its password's digest and its role.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UserSection {
    /// The user name.
    pub name: String,
    /// `pbkdf2-sha256:<iterations>:<salt, hex>:<digest, hex>`.
    pub password_hash: String,
    /// What the user may do beyond reading (`reader` when not given).
    #[serde(default)]
    pub role: Role,
}

/// What a signed-in user may do. Everyone reads; no one writes a variable.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Reads, browses, subscribes and refreshes conditions.
    #[default]
    Reader,
    /// A reader who may also acknowledge and confirm alarm conditions.
    Operator,
}

/// The OPC UA server's checked settings.
#[derive(Debug, Clone)]
pub struct OpcUaSettings {
    /// The endpoint's URL, as clients are told it (`advertise`, else `endpoint`).
    pub url: String,
    /// The host the server binds.
    pub host: String,
    /// The port it binds.
    pub port: u16,
    /// The host and port of `url`: its endpoints' own.
    pub advertised: (String, u16),
    /// How often the server copies every twin's state into its nodes.
    pub sampling_interval: Duration,
    /// Anonymous clients are let in.
    pub anonymous: bool,
    /// Security policy None is offered (to anonymous clients).
    pub security_none: bool,
    /// The server's PKI directory.
    pub pki_dir: PathBuf,
    /// The configured certificate (DER) and private key (PEM); `None`: created in `pki_dir`.
    pub certificate: Option<(PathBuf, PathBuf)>,
    /// Who may sign in with a user name and password.
    pub users: Vec<User>,
}

/// A user who may sign in with a password.
#[derive(Debug, Clone)]
pub struct User {
    /// The user name.
    pub name: String,
    /// Its password's digest.
    pub password: PasswordHash,
    /// What it may do.
    pub role: Role,
}

/// Why `[opcua]` cannot be used: the field and the problem.
#[derive(Debug, thiserror::Error)]
#[error("opcua.{field}: {problem}")]
pub struct SettingsError {
    /// The field, under `opcua.`.
    pub field: &'static str,
    /// What is wrong with it.
    pub problem: String,
}

/// The sampling interval when none is given (ms).
const DEFAULT_SAMPLING_INTERVAL_MS: u64 = 100;
/// The shortest sampling interval (ms): below it the copy would cost more than clients gain.
const MIN_SAMPLING_INTERVAL_MS: u64 = 10;

impl OpcUaSettings {
    /// `section` checked, with `endpoint_override` (`--opcua`) replacing its `endpoint`; relative
    /// paths are taken from `base_dir`. `None` when no endpoint is given: no server.
    pub fn from_section(
        section: &OpcUaSection,
        endpoint_override: Option<&str>,
        base_dir: &Path,
    ) -> Result<Option<Self>, SettingsError> {
        let Some(url) = endpoint_override.or(section.endpoint.as_deref()) else {
            return Ok(None);
        };
        let (host, port) = parse_endpoint(url).ok_or_else(|| SettingsError {
            field: "endpoint",
            problem: format!("'{url}' is not opc.tcp://HOST:PORT"),
        })?;
        let (url, advertised) = match &section.advertise {
            Some(advertise) => {
                let advertised = parse_endpoint(advertise).ok_or_else(|| SettingsError {
                    field: "advertise",
                    problem: format!("'{advertise}' is not opc.tcp://HOST:PORT"),
                })?;
                (advertise.as_str(), advertised)
            }
            None if host.parse::<IpAddr>().is_ok_and(|ip| ip.is_unspecified()) => {
                return Err(SettingsError {
                    field: "advertise",
                    problem: format!(
                        "'{url}' is where the server listens, not an address a client can \
                         reach: give advertise = \"opc.tcp://<this host's name or address>:{port}\""
                    ),
                });
            }
            None => (url, (host.clone(), port)),
        };
        let sampling_interval_ms = section
            .sampling_interval_ms
            .unwrap_or(DEFAULT_SAMPLING_INTERVAL_MS);
        if sampling_interval_ms < MIN_SAMPLING_INTERVAL_MS {
            return Err(SettingsError {
                field: "sampling_interval_ms",
                problem: format!(
                    "{sampling_interval_ms} is below the shortest, {MIN_SAMPLING_INTERVAL_MS}"
                ),
            });
        }
        let users = users_of(&section.users)?;
        if users.is_empty() && !section.anonymous {
            return Err(SettingsError {
                field: "users",
                problem: "no client could sign in: give [[opcua.users]] or anonymous = true"
                    .to_owned(),
            });
        }
        let certificate = match (&section.certificate, &section.private_key) {
            (Some(certificate), Some(key)) => {
                Some((base_dir.join(certificate), base_dir.join(key)))
            }
            (None, None) => None,
            _ => {
                return Err(SettingsError {
                    field: "certificate",
                    problem: "certificate and private_key go together".to_owned(),
                });
            }
        };
        Ok(Some(Self {
            url: url.to_owned(),
            advertised,
            security_none: section.security_none || is_loopback(&host),
            host,
            port,
            sampling_interval: Duration::from_millis(sampling_interval_ms),
            anonymous: section.anonymous,
            pki_dir: base_dir.join(
                section
                    .pki_dir
                    .clone()
                    .unwrap_or_else(|| PathBuf::from("opcua-pki")),
            ),
            certificate,
            users,
        }))
    }
}

/// The `[[opcua.users]]` entries checked: names given once, none empty or reserved, and digests
/// that parse.
fn users_of(entries: &[UserSection]) -> Result<Vec<User>, SettingsError> {
    let mut users: Vec<User> = Vec::with_capacity(entries.len());
    for entry in entries {
        if entry.name.trim().is_empty() {
            return Err(SettingsError {
                field: "users.name",
                problem: "a user name is empty".to_owned(),
            });
        }
        if entry.name == opcua::server::ANONYMOUS_USER_TOKEN_ID {
            // The stack's name for anonymous clients: such a user would lend them its role.
            return Err(SettingsError {
                field: "users.name",
                problem: format!("'{}' is reserved for anonymous clients", entry.name),
            });
        }
        if users.iter().any(|user| user.name == entry.name) {
            return Err(SettingsError {
                field: "users.name",
                problem: format!("'{}' is named twice", entry.name),
            });
        }
        let password = PasswordHash::parse(&entry.password_hash).map_err(|e| SettingsError {
            field: "users.password_hash",
            problem: e.to_string(),
        })?;
        users.push(User {
            name: entry.name.clone(),
            password,
            role: entry.role,
        });
    }
    Ok(users)
}

/// `opc.tcp://HOST:PORT[/path]`'s host (an IPv6 address without its brackets) and port.
fn parse_endpoint(url: &str) -> Option<(String, u16)> {
    let rest = url.strip_prefix("opc.tcp://")?;
    let authority = rest.split('/').next()?;
    let (host, port) = if let Some(bracketed) = authority.strip_prefix('[') {
        let (host, after) = bracketed.split_once(']')?;
        (host, after.strip_prefix(':')?)
    } else {
        authority.rsplit_once(':')?
    };
    if host.is_empty() {
        return None;
    }
    Some((host.to_owned(), port.parse().ok()?))
}

/// Whether `host` names this machine's loopback interface only.
fn is_loopback(host: &str) -> bool {
    host == "localhost" || host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

#[cfg(test)]
mod tests {
    use super::*;

    const HASH: &str = "pbkdf2-sha256:1000:00112233445566778899aabbccddeeff:\
        0000000000000000000000000000000000000000000000000000000000000000";

    fn section(endpoint: &str, anonymous: bool, users: &[&str]) -> OpcUaSection {
        OpcUaSection {
            endpoint: Some(endpoint.to_owned()),
            // Every interface is no URL for clients.
            advertise: endpoint
                .contains("0.0.0.0")
                .then(|| endpoint.replace("0.0.0.0", "plant-gw")),
            anonymous,
            users: users
                .iter()
                .map(|name| UserSection {
                    name: (*name).to_owned(),
                    password_hash: HASH.to_owned(),
                    role: Role::Reader,
                })
                .collect(),
            ..OpcUaSection::default()
        }
    }

    #[test]
    fn off_without_an_endpoint() {
        let settings =
            OpcUaSettings::from_section(&OpcUaSection::default(), None, Path::new("")).unwrap();
        assert!(settings.is_none());
    }

    #[test]
    fn clients_are_told_the_advertised_url_and_never_every_interface() {
        let told = |endpoint: &str, advertise: Option<&str>| {
            let section = OpcUaSection {
                endpoint: Some(endpoint.to_owned()),
                advertise: advertise.map(str::to_owned),
                anonymous: true,
                ..OpcUaSection::default()
            };
            OpcUaSettings::from_section(&section, None, Path::new(""))
                .map(|settings| settings.map(|s| (s.url, s.advertised, s.host, s.port)))
                .map_err(|e| e.to_string())
        };
        assert_eq!(
            told("opc.tcp://127.0.0.1:4840", None),
            Ok(Some((
                "opc.tcp://127.0.0.1:4840".to_owned(),
                ("127.0.0.1".to_owned(), 4840),
                "127.0.0.1".to_owned(),
                4840
            )))
        );
        assert_eq!(
            told("opc.tcp://0.0.0.0:4840", Some("opc.tcp://plant-gw:48400")),
            Ok(Some((
                "opc.tcp://plant-gw:48400".to_owned(),
                ("plant-gw".to_owned(), 48400),
                "0.0.0.0".to_owned(),
                4840
            )))
        );
        let refused = told("opc.tcp://0.0.0.0:4840", None).unwrap_err();
        assert!(
            refused.starts_with(
                "opcua.advertise: 'opc.tcp://0.0.0.0:4840' is where the server listens"
            ),
            "{refused}"
        );
        let refused = told("opc.tcp://[::]:4840", None).unwrap_err();
        assert!(refused.starts_with("opcua.advertise:"), "{refused}");
        let refused = told("opc.tcp://127.0.0.1:4840", Some("plant-gw:4840")).unwrap_err();
        assert!(refused.contains("is not opc.tcp://HOST:PORT"), "{refused}");
    }

    #[test]
    fn endpoints_parse_with_ipv4_ipv6_and_names() {
        assert_eq!(
            parse_endpoint("opc.tcp://127.0.0.1:4840"),
            Some(("127.0.0.1".to_owned(), 4840))
        );
        assert_eq!(
            parse_endpoint("opc.tcp://[::1]:4841/armtwin"),
            Some(("::1".to_owned(), 4841))
        );
        assert_eq!(
            parse_endpoint("opc.tcp://plant-gw:4840"),
            Some(("plant-gw".to_owned(), 4840))
        );
        assert_eq!(parse_endpoint("http://127.0.0.1:4840"), None);
        assert_eq!(parse_endpoint("opc.tcp://127.0.0.1"), None);
        assert_eq!(parse_endpoint("opc.tcp://:4840"), None);
    }

    #[test]
    fn policy_none_only_on_loopback_unless_configured() {
        let loopback = OpcUaSettings::from_section(
            &section("opc.tcp://127.0.0.1:4840", false, &["mes"]),
            None,
            Path::new(""),
        )
        .unwrap()
        .unwrap();
        assert!(loopback.security_none);
        let plant = OpcUaSettings::from_section(
            &section("opc.tcp://0.0.0.0:4840", false, &["mes"]),
            None,
            Path::new(""),
        )
        .unwrap()
        .unwrap();
        assert!(!plant.security_none);
        let mut configured = section("opc.tcp://0.0.0.0:4840", true, &[]);
        configured.security_none = true;
        let configured = OpcUaSettings::from_section(&configured, None, Path::new(""))
            .unwrap()
            .unwrap();
        assert!(configured.security_none && configured.anonymous);
    }

    #[test]
    fn nobody_let_in_is_refused_and_anonymous_is_off_by_default() {
        let error = OpcUaSettings::from_section(
            &section("opc.tcp://127.0.0.1:4840", false, &[]),
            None,
            Path::new(""),
        )
        .unwrap_err();
        assert_eq!(error.field, "users");
        let settings = OpcUaSettings::from_section(
            &section("opc.tcp://127.0.0.1:4840", false, &["mes"]),
            None,
            Path::new(""),
        )
        .unwrap()
        .unwrap();
        assert!(!settings.anonymous);
    }

    #[test]
    fn a_user_named_twice_or_anonymous_or_a_lone_certificate_is_refused() {
        let twice = section("opc.tcp://127.0.0.1:4840", false, &["mes", "mes"]);
        assert_eq!(
            OpcUaSettings::from_section(&twice, None, Path::new(""))
                .unwrap_err()
                .field,
            "users.name"
        );
        let anonymous = section("opc.tcp://127.0.0.1:4840", false, &["ANONYMOUS"]);
        let error = OpcUaSettings::from_section(&anonymous, None, Path::new("")).unwrap_err();
        assert!(error.problem.contains("reserved"), "{error}");
        let mut lone = section("opc.tcp://127.0.0.1:4840", false, &["mes"]);
        lone.certificate = Some(PathBuf::from("cert.der"));
        assert_eq!(
            OpcUaSettings::from_section(&lone, None, Path::new(""))
                .unwrap_err()
                .field,
            "certificate"
        );
    }

    #[test]
    fn the_command_line_endpoint_wins_and_paths_follow_the_file() {
        let settings = OpcUaSettings::from_section(
            &section("opc.tcp://127.0.0.1:4840", false, &["mes"]),
            Some("opc.tcp://127.0.0.1:4999"),
            Path::new("/etc/armtwin"),
        )
        .unwrap()
        .unwrap();
        assert_eq!(settings.port, 4999);
        assert_eq!(settings.pki_dir, PathBuf::from("/etc/armtwin/opcua-pki"));
        assert_eq!(settings.sampling_interval, Duration::from_millis(100));
    }
}
