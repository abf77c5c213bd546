//! Tests of `[zenoh]` read as part of the whole file: the section and the command line's Zenoh
//! flags combined by [`ServiceConfig`], and its errors named. The section's own types are the
//! mesh crate's (`armtwin_mesh::zenoh_section`).
//!
//! Must not hold anything but tests.

use std::path::Path;

use super::{Origin, ServiceConfig};
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

/// The configuration `text` over the built-in one, with `zenoh.json5` holding `zenoh_file`
/// beside it, and the Zenoh configuration the service would open its session with.
fn with_zenoh_file(
    text: &str,
    zenoh_file: &str,
    overrides: &Overrides,
) -> (ServiceConfig, zenoh::Config) {
    let dir = tempfile::tempdir().expect("a temporary folder");
    std::fs::write(dir.path().join("zenoh.json5"), zenoh_file).expect("written");
    let config = ServiceConfig::parse(text, "test", dir.path(), overrides).expect("valid");
    let zenoh = armtwin_mesh::zenoh_config_of(&config.zenoh).expect("a Zenoh configuration");
    (config, zenoh)
}

#[test]
fn a_zenoh_files_own_mode_and_endpoints_stand_over_the_built_in_ones() {
    let client_file = "{ mode: \"client\", connect: { endpoints: [\"tls/localhost:7447\"] } }";
    let uses_file = "[zenoh]\nfile = \"zenoh.json5\"\n";
    let (config, zenoh) = with_zenoh_file(uses_file, client_file, &Overrides::default());
    assert_eq!(config.zenoh.mode, ZenohMode::Client);
    assert_eq!(zenoh.get_json("mode").expect("mode"), "\"client\"");
    // The file's connect stands; the built-in peer's listen is not a client's.
    assert_eq!(
        zenoh.get_json("connect/endpoints").expect("connect"),
        "[\"tls/localhost:7447\"]"
    );
    assert_eq!(zenoh.get_json("listen/endpoints").expect("listen"), "[]");
    assert_eq!(
        config.zenoh.origins.listen,
        Origin::ClientListensNowhere,
        "{:?}",
        config.zenoh.origins
    );
    assert!(matches!(
        config.zenoh.origins.mode,
        Origin::ZenohFile { .. }
    ));
    assert!(
        config.zenoh.reaches_anyone(),
        "it connects, through its file"
    );

    // The configuration's own [zenoh] keys and the flags win over the file's.
    let (config, zenoh) = with_zenoh_file(
        "[zenoh]\nfile = \"zenoh.json5\"\nmode = \"peer\"\n",
        client_file,
        &Overrides {
            connect: vec!["tcp/127.0.0.1:7000".to_owned()],
            ..Overrides::default()
        },
    );
    assert_eq!(
        (config.zenoh.origins.mode, config.zenoh.origins.connect),
        (Origin::Configuration, Origin::CommandLine)
    );
    assert_eq!(zenoh.get_json("mode").expect("mode"), "\"peer\"");
    assert_eq!(
        zenoh.get_json("connect/endpoints").expect("connect"),
        "[\"tcp/127.0.0.1:7000\"]"
    );
    // A peer that the file does not tell where to listen listens where the built-in one does.
    assert_eq!(
        zenoh.get_json("listen/endpoints").expect("listen"),
        "[\"tcp/127.0.0.1:7447\"]"
    );

    // A client told by its file to listen listens there; a file's list per mode is kept whole.
    let (config, zenoh) = with_zenoh_file(
        uses_file,
        "{ mode: \"client\", listen: { endpoints: { client: [\"tcp/127.0.0.1:7001\"] } } }",
        &Overrides::default(),
    );
    assert!(matches!(
        config.zenoh.origins.listen,
        Origin::ZenohFile { .. }
    ));
    assert!(
        zenoh
            .get_json("listen/endpoints")
            .expect("listen")
            .contains("tcp/127.0.0.1:7001")
    );
    assert!(config.zenoh.reaches_anyone());
}

#[test]
fn a_client_by_flag_alone_listens_nowhere() {
    let client = |listen: &[&str]| {
        ServiceConfig::load(
            None,
            &Overrides {
                mode: Some(ZenohMode::Client),
                listen: listen.iter().map(|&l| l.to_owned()).collect(),
                connect: vec!["tcp/127.0.0.1:7000".to_owned()],
                ..Overrides::default()
            },
        )
        .expect("embedded")
        .zenoh
    };
    let nowhere = client(&[]);
    assert!(nowhere.listen.is_empty(), "{:?}", nowhere.listen);
    assert_eq!(nowhere.origins.listen, Origin::ClientListensNowhere);
    let told = client(&["tcp/127.0.0.1:7001"]);
    assert_eq!(told.listen, ["tcp/127.0.0.1:7001"]);
    assert_eq!(told.origins.listen, Origin::CommandLine);
}

#[test]
fn a_bad_zenoh_file_is_refused_when_the_configuration_loads() {
    let dir = tempfile::tempdir().expect("a temporary folder");
    std::fs::write(dir.path().join("zenoh.json5"), "{ mode: \"hub\" }").expect("written");
    for text in [
        "[zenoh]\nfile = \"zenoh.json5\"\n",
        "[zenoh]\nfile = \"missing.json5\"\n",
    ] {
        let error = ServiceConfig::parse(text, "test", dir.path(), &Overrides::default())
            .expect_err(text)
            .to_string();
        assert!(error.starts_with("test: zenoh.file: "), "{error}");
        assert!(!error.contains(".rs:"), "{error}");
    }
}
