//! `[zenoh]` and the command line's Zenoh flags (`-m`, `-l`, `-e`, `--cfg`), zenohd's style.
//!
//! Owns how the built-in section, the configuration file's, a `[zenoh] file`'s own `mode`,
//! `listen` and `connect`, and the flags combine, and where each of those three came from. Must
//! not build Zenoh's own configuration or open a session: the service does.

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
    /// A complete Zenoh JSON5 configuration file. Its own `mode`, `listen` and `connect` stand
    /// unless the configuration file's `[zenoh]` or the command line sets them; the built-in
    /// values fill only what it leaves out. `multicast_scouting` and `cfg` always apply over it.
    pub file: Option<PathBuf>,
    /// Multicast scouting (off by default: peers are found through `listen`/`connect`).
    #[serde(default)]
    pub multicast_scouting: bool,
    /// Values set at a path of the Zenoh configuration (`zenohd --cfg` style), applied last so
    /// that they win over every key above.
    #[serde(default)]
    pub cfg: Vec<ZenohInsert>,
    /// Where `mode`, `listen` and `connect` came from ([`ZenohSection::layered`] sets it).
    #[serde(skip)]
    pub origins: ZenohOrigins,
}

/// Where one of `[zenoh]`'s `mode`, `listen` and `connect` came from.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum Origin {
    /// The built-in configuration.
    #[default]
    BuiltIn,
    /// The configuration file's own `[zenoh]` section.
    Configuration,
    /// The `[zenoh] file` itself, which armtwin then leaves as the file has it: `value` is the
    /// file's, as Zenoh's JSON (an endpoint list may hold a list per mode, or strategies).
    ZenohFile {
        /// The file's value, as Zenoh's JSON.
        value: String,
    },
    /// `-m`, `-l` or `-e`.
    CommandLine,
    /// Nowhere: the built-in `listen` is a peer's, and a client listens only where it is told
    /// to (the configuration, its `[zenoh] file` or `-l`).
    ClientListensNowhere,
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::BuiltIn => "the built-in configuration",
            Self::Configuration => "the configuration file's [zenoh]",
            Self::ZenohFile { .. } => "the [zenoh] file",
            Self::CommandLine => "the command line",
            Self::ClientListensNowhere => {
                "a client's: it listens only where its configuration, its [zenoh] file or -l says"
            }
        })
    }
}

/// Where `[zenoh]`'s `mode`, `listen` and `connect` came from, each.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ZenohOrigins {
    /// `mode`'s.
    pub mode: Origin,
    /// `listen`'s.
    pub listen: Origin,
    /// `connect`'s.
    pub connect: Origin,
}

/// Which of `mode`, `listen` and `connect` a configuration file's `[zenoh]` writes itself (the
/// built-in configuration's values fill the others).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WrittenKeys {
    /// `mode` is written.
    pub mode: bool,
    /// `listen` is written.
    pub listen: bool,
    /// `connect` is written.
    pub connect: bool,
}

/// What a `[zenoh] file` sets itself of `mode`, `listen` and `connect`: `None` where it leaves
/// Zenoh's own default (`crate::zenoh_file` reads it).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ZenohFileKeys {
    /// The file's `mode`.
    pub mode: Option<ZenohMode>,
    /// The file's `listen/endpoints`, as Zenoh's JSON.
    pub listen: Option<String>,
    /// The file's `connect/endpoints`, as Zenoh's JSON.
    pub connect: Option<String>,
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

    /// Whether a session on this section can meet anyone: it listens, connects (here or in its
    /// `[zenoh] file`), scouts by multicast, or a `cfg` entry sets any of these. `armtwin serve`
    /// warns when it cannot.
    #[must_use]
    pub fn reaches_anyone(&self) -> bool {
        !self.listen.is_empty()
            || !self.connect.is_empty()
            || lists_an_endpoint(&self.origins.listen, self.mode)
            || lists_an_endpoint(&self.origins.connect, self.mode)
            || self.multicast_scouting
            || self.cfg.iter().any(|insert| {
                ["listen", "connect", "scouting"]
                    .iter()
                    .any(|path| insert.key.trim_start_matches('/').starts_with(path))
            })
    }

    /// The section the service runs on. `self` is the configuration file's `[zenoh]` layered
    /// over the built-in one, of which the file wrote `written` itself; what it did not write,
    /// the `[zenoh] file` sets if it does (`file_keys`), else the built-in value stands. The
    /// command line's flags come next ([`Self::overridden`]). Last, a client whose `listen` is
    /// still the built-in one listens nowhere: that list is a peer's, and a client listens only
    /// where it is told to.
    #[must_use]
    pub fn layered(
        mut self,
        written: WrittenKeys,
        file_keys: Option<&ZenohFileKeys>,
        overrides: &Overrides,
    ) -> Self {
        let origin = |written: bool| {
            if written {
                Origin::Configuration
            } else {
                Origin::BuiltIn
            }
        };
        self.origins = ZenohOrigins {
            mode: origin(written.mode),
            listen: origin(written.listen),
            connect: origin(written.connect),
        };
        if let Some(keys) = file_keys {
            if let (false, Some(mode)) = (written.mode, keys.mode) {
                self.mode = mode;
                self.origins.mode = Origin::ZenohFile {
                    value: format!("\"{mode}\""),
                };
            }
            // The file's lists are left in the file, untranslated: they may hold a list per
            // mode, or endpoints with strategies, that `listen` and `connect` cannot write.
            if let (false, Some(value)) = (written.listen, &keys.listen) {
                self.listen.clear();
                self.origins.listen = Origin::ZenohFile {
                    value: value.clone(),
                };
            }
            if let (false, Some(value)) = (written.connect, &keys.connect) {
                self.connect.clear();
                self.origins.connect = Origin::ZenohFile {
                    value: value.clone(),
                };
            }
        }
        let mut section = self.overridden(overrides);
        if section.mode == ZenohMode::Client && section.origins.listen == Origin::BuiltIn {
            section.listen.clear();
            section.origins.listen = Origin::ClientListensNowhere;
        }
        section
    }

    /// The section with the command line's flags applied: a mode replaces the section's, an
    /// endpoint list replaces the section's list (or its `[zenoh] file`'s), `--cfg` entries come
    /// after the section's own.
    #[must_use]
    pub fn overridden(mut self, overrides: &Overrides) -> Self {
        if let Some(mode) = overrides.mode {
            self.mode = mode;
            self.origins.mode = Origin::CommandLine;
        }
        if !overrides.listen.is_empty() {
            self.listen.clone_from(&overrides.listen);
            self.origins.listen = Origin::CommandLine;
        }
        if !overrides.connect.is_empty() {
            self.connect.clone_from(&overrides.connect);
            self.origins.connect = Origin::CommandLine;
        }
        self.cfg.extend(overrides.cfg.iter().cloned());
        self
    }

    /// `mode`, `listen` and `connect` as the session gets them, each as JSON with where it came
    /// from: what `armtwin config show` and the service's start log print.
    #[must_use]
    pub fn with_origins(&self) -> [(&'static str, String, &Origin); 3] {
        let list = |own: &[String], origin: &Origin| match origin {
            Origin::ZenohFile { value } => value.clone(),
            _ => serde_json::to_string(own).unwrap_or_default(),
        };
        [
            ("mode", format!("\"{}\"", self.mode), &self.origins.mode),
            (
                "listen",
                list(&self.listen, &self.origins.listen),
                &self.origins.listen,
            ),
            (
                "connect",
                list(&self.connect, &self.origins.connect),
                &self.origins.connect,
            ),
        ]
    }
}

/// Whether `origin` is a `[zenoh] file`'s endpoint list naming at least one endpoint for `mode`:
/// one list for every mode, or a list per mode.
fn lists_an_endpoint(origin: &Origin, mode: ZenohMode) -> bool {
    let Origin::ZenohFile { value } = origin else {
        return false;
    };
    let not_empty = |list: &serde_json::Value| list.as_array().is_some_and(|a| !a.is_empty());
    match serde_json::from_str::<serde_json::Value>(value) {
        Ok(serde_json::Value::Object(per_mode)) => {
            per_mode.get(mode.as_str()).is_some_and(not_empty)
        }
        Ok(list) => not_empty(&list),
        Err(_) => false,
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
