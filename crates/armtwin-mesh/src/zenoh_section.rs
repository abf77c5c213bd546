//! `[zenoh]` and the command line's Zenoh flags (`-m`, `-l`, `-e`, `--cfg`), zenohd's style.
//!
//! Owns how the file's section and the flags combine. Must not build Zenoh's own configuration
//! or open a session: the service does.

use std::net::SocketAddr;
use std::path::PathBuf;

use serde::Deserialize;
use thiserror::Error;

/// The service's embedded default configuration, read here only for its `[zenoh]` section.
const DEFAULT_CONFIG_TOML: &str = include_str!("../../../config/armtwin.toml");

/// The embedded file's `[zenoh]` section; every other section is the service's to read.
#[derive(Deserialize)]
struct DefaultFile {
    #[serde(default)]
    zenoh: ZenohSection,
}

/// `[zenoh]`: how armtwin joins the mesh.
#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ZenohSection {
    /// The session's role.
    #[serde(default)]
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`.
    #[serde(default)]
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    #[serde(default)]
    pub connect: Vec<String>,
    /// A complete Zenoh JSON5 configuration file; `mode`, `listen`, `connect` and
    /// `multicast_scouting` given here override it.
    pub file: Option<PathBuf>,
    /// Multicast scouting (off by default: peers are found through `listen`/`connect`).
    #[serde(default)]
    pub multicast_scouting: bool,
    /// Values set at a path of the Zenoh configuration (`zenohd --cfg` style), applied last so
    /// that they win over every key above.
    #[serde(default)]
    pub cfg: Vec<ZenohInsert>,
}

/// A Zenoh session's role (`-m/--mode`, `[zenoh] mode`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    /// Talks to every session it reaches, directly.
    #[default]
    Peer,
    /// Talks through one router (or peer) it connects to.
    Client,
    /// Routes for clients and other routers.
    Router,
}

impl ZenohMode {
    /// The name Zenoh's configuration uses.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
            Self::Router => "router",
        }
    }
}

impl std::fmt::Display for ZenohMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One `KEY:VALUE` setting of the Zenoh configuration: a JSON5 `value` at the path `key`, e.g.
/// `transport/shared_memory/enabled:false` (the key holds no `:`, the value may).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct ZenohInsert {
    /// The configuration path, e.g. `transport/shared_memory/enabled`.
    pub key: String,
    /// The JSON5 value, e.g. `false`; Zenoh checks it against the key when the session's
    /// configuration is built.
    pub value: String,
}

/// A `--cfg` (or `[zenoh] cfg`) entry that is not `KEY:VALUE`.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error(
    "'{text}' is not KEY:VALUE (a Zenoh configuration path, a colon, a JSON5 value; e.g. transport/shared_memory/enabled:false)"
)]
pub struct ZenohInsertError {
    /// The entry as given.
    pub text: String,
}

impl std::str::FromStr for ZenohInsert {
    type Err = ZenohInsertError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.split_once(':') {
            Some((key, value)) if !key.trim().is_empty() && !value.trim().is_empty() => Ok(Self {
                key: key.trim().to_owned(),
                value: value.trim().to_owned(),
            }),
            _ => Err(ZenohInsertError {
                text: text.to_owned(),
            }),
        }
    }
}

impl TryFrom<String> for ZenohInsert {
    type Error = ZenohInsertError;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        text.parse()
    }
}

impl std::fmt::Display for ZenohInsert {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}", self.key, self.value)
    }
}

impl ZenohSection {
    /// How a session joins the service running on the embedded default configuration: its
    /// mode and multicast scouting, connecting to the endpoints it listens on
    /// (`tcp/127.0.0.1:7447`). What `armtwin replay` starts from, so that a bare `replay` reaches
    /// a bare `serve`.
    #[must_use]
    pub fn joining_default_service() -> Self {
        // The embedded file is checked by this module's tests; a broken one would fall back to
        // Zenoh's own defaults rather than stop `replay`.
        let service = toml::from_str::<DefaultFile>(DEFAULT_CONFIG_TOML)
            .map(|file| file.zenoh)
            .unwrap_or_default();
        Self {
            mode: service.mode,
            connect: service.listen,
            multicast_scouting: service.multicast_scouting,
            ..Self::default()
        }
    }

    /// Whether a session on this section can meet anyone: it listens, connects, scouts by
    /// multicast, or a `cfg` entry sets any of these (the `[zenoh] file`'s own endpoints are
    /// replaced by `listen` and `connect`). `armtwin serve` warns when it cannot.
    #[must_use]
    pub fn reaches_anyone(&self) -> bool {
        !self.listen.is_empty()
            || !self.connect.is_empty()
            || self.multicast_scouting
            || self.cfg.iter().any(|insert| {
                ["listen", "connect", "scouting"]
                    .iter()
                    .any(|path| insert.key.trim_start_matches('/').starts_with(path))
            })
    }

    /// The section with the command line's flags applied: a mode replaces the section's, an
    /// endpoint list replaces the section's list, `--cfg` entries come after the section's own.
    #[must_use]
    pub fn overridden(mut self, overrides: &Overrides) -> Self {
        if let Some(mode) = overrides.mode {
            self.mode = mode;
        }
        if !overrides.listen.is_empty() {
            self.listen.clone_from(&overrides.listen);
        }
        if !overrides.connect.is_empty() {
            self.connect.clone_from(&overrides.connect);
        }
        self.cfg.extend(overrides.cfg.iter().cloned());
        self
    }
}

/// Command-line overrides, Zenoh style (`-m`, `-l`, `-e`, `--cfg`).
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// `-m/--mode`.
    pub mode: Option<ZenohMode>,
    /// `-l/--listen` (replaces the file's list when given).
    pub listen: Vec<String>,
    /// `-e/--connect` (replaces the file's list when given).
    pub connect: Vec<String>,
    /// `--cfg KEY:VALUE` (applied after the file's `cfg`, so they win).
    pub cfg: Vec<ZenohInsert>,
    /// `--http ADDRESS` (replaces `[http] listen`).
    pub http_listen: Option<SocketAddr>,
    /// `--opcua opc.tcp://HOST:PORT` (replaces `[opcua] endpoint`).
    pub opcua_endpoint: Option<String>,
}

/// Zenoh's error message without the source location it ends with (` at …/file.rs:line.`):
/// not the reader's business. The one scrubber of Zenoh's messages, for every module.
#[must_use]
pub fn without_source_location(message: &str) -> &str {
    message
        .find(" at ")
        .filter(|&at| message[at..].contains(".rs:"))
        .map_or(message, |at| &message[..at])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_zenoh_entries_are_named() {
        for bad in ["novalue", ":false", "key:", ""] {
            let error = bad.parse::<ZenohInsert>().expect_err(bad);
            assert!(
                error
                    .to_string()
                    .contains(&format!("'{bad}' is not KEY:VALUE")),
                "{error}"
            );
        }
    }

    #[test]
    fn source_locations_are_cut_and_other_text_kept() {
        let message = "invalid key expression 'a//b' at /root/.cargo/registry/src/zenoh-1.10.2/src/key_expr.rs:42.";
        assert_eq!(
            without_source_location(message),
            "invalid key expression 'a//b'"
        );
        // " at " in the message itself, with no source file after it, stays.
        let plain = "no value at this key";
        assert_eq!(without_source_location(plain), plain);
    }
}
