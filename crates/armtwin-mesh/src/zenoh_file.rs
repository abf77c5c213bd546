//! What a `[zenoh] file` (a Zenoh configuration of its own) sets itself of the session's `mode`,
//! `listen` and `connect`, so that the configuration's layering keeps them over the built-in
//! values ([`crate::zenoh_section::ZenohSection::layered`]).
//!
//! Reads the file with Zenoh's own parser, every format it takes (JSON5, YAML). Must not open a
//! session or change the file's configuration: the session's is built by `session`.

use std::path::Path;

use crate::session::MeshError;
use crate::zenoh_section::{ZenohFileKeys, ZenohMode, without_source_location};

/// The `mode`, `listen/endpoints` and `connect/endpoints` that the Zenoh configuration file at
/// `path` sets: each where it differs from Zenoh's own default, which is what a file that leaves
/// the key out gets. (A file that writes Zenoh's default value out in full counts as leaving it
/// out: the built-in value then stands, which only a list equal to Zenoh's per-mode default
/// could tell apart.)
///
/// # Errors
/// The file cannot be read, is not a Zenoh configuration, or names an unknown mode.
pub fn zenoh_file_keys(path: &Path) -> Result<ZenohFileKeys, MeshError> {
    let named = |problem: &str| MeshError::Config(format!("{}: {problem}", path.display()));
    let file = zenoh::Config::from_file(path)
        .map_err(|e| named(without_source_location(&e.to_string())))?;
    let zenoh_default = zenoh::Config::default();
    let own = |key: &str| -> Result<Option<String>, MeshError> {
        let value = file
            .get_json(key)
            .map_err(|e| named(&format!("{key}: {e}")))?;
        let default = zenoh_default.get_json(key).unwrap_or_default();
        Ok((value != default).then_some(value))
    };
    let mode = own("mode")?
        .map(|value| {
            serde_json::from_str::<ZenohMode>(&value)
                .map_err(|_| named(&format!("mode {value} is not peer, client or router")))
        })
        .transpose()?;
    Ok(ZenohFileKeys {
        mode,
        listen: own("listen/endpoints")?,
        connect: own("connect/endpoints")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys_of(name: &str, text: &str) -> Result<ZenohFileKeys, MeshError> {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let path = dir.path().join(name);
        std::fs::write(&path, text).expect("written");
        zenoh_file_keys(&path)
    }

    #[test]
    fn a_file_sets_only_what_it_writes() {
        let client = keys_of(
            "client.json5",
            "{ mode: \"client\", connect: { endpoints: [\"tls/localhost:7447\"] } }",
        )
        .expect("valid");
        assert_eq!(
            client,
            ZenohFileKeys {
                mode: Some(ZenohMode::Client),
                listen: None,
                connect: Some("[\"tls/localhost:7447\"]".to_owned()),
            }
        );
        let nothing = keys_of(
            "empty.json5",
            "{ scouting: { multicast: { enabled: false } } }",
        )
        .expect("valid");
        assert_eq!(nothing, ZenohFileKeys::default());
        let yaml = keys_of("peer.yaml", "mode: peer\nlisten:\n  endpoints: []\n").expect("valid");
        assert_eq!(yaml.mode, Some(ZenohMode::Peer));
        assert_eq!(yaml.listen.as_deref(), Some("[]"));
    }

    #[test]
    fn a_bad_file_is_named_without_source_locations() {
        for (name, text) in [
            ("bad.json5", "{ mode: \"hub\" }"),
            ("bad.json5", "{ nonsense: 1 }"),
            ("bad.txt", "{}"),
        ] {
            let error = keys_of(name, text).expect_err(text).to_string();
            assert!(error.contains(name), "{error}");
            assert!(!error.contains(".rs:"), "{error}");
        }
    }
}
