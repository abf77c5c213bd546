//! Tests of `[zenoh]` read as part of the whole file: the section and the command line's Zenoh
//! flags combined by [`ServiceConfig`], and its errors named. The section's own types are the
//! mesh crate's (`armtwin_mesh::zenoh_section`).
//!
//! Must not hold anything but tests.

use std::path::Path;

use super::ServiceConfig;
use armtwin_mesh::zenoh_section::{Overrides, ZenohMode, ZenohSection};

#[test]
fn zenoh_flags_override_the_file_and_cfg_entries_come_last() {
    let text = "[zenoh]\nmode = \"client\"\nlisten = [\"tcp/127.0.0.1:7000\"]\n\
                connect = [\"tcp/10.0.0.1:7447\"]\ncfg = [\"transport/shared_memory/enabled:false\"]\n";
    let overrides = Overrides {
        mode: Some(ZenohMode::Router),
        listen: vec!["tcp/0.0.0.0:7447".to_owned()],
        connect: Vec::new(),
        cfg: vec![
            "connect/timeout_ms:{router: -1, peer: 2000}"
                .parse()
                .expect("KEY:VALUE"),
        ],
        http_listen: None,
        opcua_endpoint: None,
    };
    let config = ServiceConfig::parse(text, "test", Path::new(""), &overrides).expect("valid");
    let zenoh = &config.zenoh;
    assert_eq!(zenoh.mode, ZenohMode::Router);
    assert_eq!(zenoh.listen, ["tcp/0.0.0.0:7447"]);
    assert_eq!(
        zenoh.connect,
        ["tcp/10.0.0.1:7447"],
        "no -e: the file's list stays"
    );
    let cfg: Vec<String> = zenoh.cfg.iter().map(ToString::to_string).collect();
    assert_eq!(
        cfg,
        [
            "transport/shared_memory/enabled:false",
            "connect/timeout_ms:{router: -1, peer: 2000}"
        ]
    );
    assert_eq!(zenoh.cfg[1].key, "connect/timeout_ms");
    // The default: a peer, multicast scouting off, no extra settings.
    let default = ServiceConfig::load(None, &Overrides::default()).expect("embedded");
    assert_eq!(default.zenoh.mode, ZenohMode::Peer);
    assert!(!default.zenoh.multicast_scouting && default.zenoh.cfg.is_empty());
    assert_eq!(
        ZenohSection::joining_default_service(),
        ZenohSection {
            connect: default.zenoh.listen,
            ..ZenohSection::default()
        }
    );
}

#[test]
fn bad_zenoh_entries_are_named() {
    let error = ServiceConfig::parse(
        "[zenoh]\nmode = \"hub\"\n",
        "test",
        Path::new(""),
        &Overrides::default(),
    )
    .expect_err("unknown mode");
    assert!(error.to_string().contains("hub"), "{error}");
    let error = ServiceConfig::parse(
        "[zenoh]\ncfg = [\"oops\"]\n",
        "test",
        Path::new(""),
        &Overrides::default(),
    )
    .expect_err("not KEY:VALUE");
    assert!(
        error.to_string().contains("'oops' is not KEY:VALUE"),
        "{error}"
    );
}
