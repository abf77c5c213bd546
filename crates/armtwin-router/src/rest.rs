//! Where the REST API runs, and as whom: the decision, from the router's configuration and the
//! `--rest-*` flags, and the configuration of the Zenoh client that carries REST as an identity.
//!
//! REST answers HTTP with a Zenoh session ([`crate::rest_http`]). The router's own session has
//! no link, so no certificate, and the router's access control never sees its puts and queries.
//! A Zenoh client of the router instead, over mutual TLS with a certificate of its own, reaches
//! the router as that certificate's subject, and every HTTP request is allowed or dropped by the
//! same rules as any other session's. Hence, with access control on, REST runs as an identity,
//! or on the router's session only when the operator says it may (`--rest-trusted`) and only on
//! loopback.
//!
//! Owns no HTTP: [`crate::rest_http`] serves it either way.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use serde_json::Value;
use zenoh::Config;

/// Where REST runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RestDoor {
    /// No REST.
    Off,
    /// Inside the router, past its access control (`zenohd`'s way): the router has no access
    /// control, or `--rest-trusted` on a loopback address.
    Inside {
        /// The address REST listens on.
        address: SocketAddr,
    },
    /// In a Zenoh client of the router with a certificate of its own: the router's access
    /// control rules every request as that certificate's subject.
    Identity {
        /// The address REST listens on.
        address: SocketAddr,
        /// The client's certificate (PEM).
        certificate: PathBuf,
        /// Its private key (PEM).
        private_key: PathBuf,
    },
}

/// What the command line says about REST.
#[derive(Debug, Clone, Default)]
pub struct RestFlags {
    /// `--rest-http-port`: `PORT` (loopback), `ADDRESS:PORT`, or `none`.
    pub http_port: Option<String>,
    /// `--rest-trusted`.
    pub trusted: bool,
    /// `--rest-certificate`.
    pub certificate: Option<PathBuf>,
    /// `--rest-private-key`.
    pub private_key: Option<PathBuf>,
}

/// The address of `--rest-http-port`: a bare port binds loopback, `ADDRESS:PORT` that address.
pub fn flag_address(value: &str) -> Result<SocketAddr> {
    if let Ok(port) = value.parse::<u16>() {
        return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
    }
    value
        .parse()
        .with_context(|| format!("--rest-http-port '{value}' is not a port nor ADDRESS:PORT"))
}

/// The address of a configuration file's `plugins/rest/http_port`, read as `zenohd`'s REST plugin
/// reads it: a number or a string without an address listens on every interface.
fn file_address(value: &Value) -> Result<SocketAddr> {
    let every = |port: u16| SocketAddr::new(IpAddr::V6(Ipv6Addr::UNSPECIFIED), port);
    match value {
        Value::Number(number) => number
            .as_u64()
            .and_then(|port| u16::try_from(port).ok())
            .map(every)
            .with_context(|| format!("plugins/rest/http_port {number} is not a port")),
        Value::String(text) => {
            let address = match text.split_once(':') {
                None => text.parse().ok().map(every),
                Some((ip, port)) => ip
                    .parse()
                    .ok()
                    .zip(port.parse().ok())
                    .map(|(ip, port)| SocketAddr::new(ip, port)),
            };
            address.with_context(|| {
                format!("plugins/rest/http_port '{text}' is not a port nor IP:PORT")
            })
        }
        other => bail!("plugins/rest/http_port {other} is not a port nor IP:PORT"),
    }
}

/// Where REST runs, given whether the router's access control is on, the file's
/// `plugins/rest/http_port` (if any) and the flags.
pub fn door(
    access_control: bool,
    file_port: Option<&Value>,
    flags: &RestFlags,
) -> Result<RestDoor> {
    let address = match flags.http_port.as_deref() {
        Some("none") => None,
        Some(value) => Some(flag_address(value)?),
        None => file_port.map(file_address).transpose()?,
    };
    let identity = match (&flags.certificate, &flags.private_key) {
        (Some(certificate), Some(private_key)) => Some((certificate.clone(), private_key.clone())),
        (None, None) => None,
        _ => bail!("--rest-certificate and --rest-private-key go together"),
    };
    let Some(address) = address else {
        if identity.is_some() || flags.trusted {
            bail!("--rest-certificate or --rest-trusted without REST: add --rest-http-port PORT");
        }
        return Ok(RestDoor::Off);
    };
    match identity {
        Some(_) if flags.trusted => bail!(
            "--rest-trusted and --rest-certificate contradict each other: REST either runs as the \
             certificate's subject or past the access control"
        ),
        Some((certificate, private_key)) => Ok(RestDoor::Identity {
            address,
            certificate,
            private_key,
        }),
        None if !access_control => Ok(RestDoor::Inside { address }),
        None if flags.trusted && address.ip().is_loopback() => Ok(RestDoor::Inside { address }),
        None if flags.trusted => bail!(
            "REST on {address} would let anyone who reaches it past the router's access control \
             (put any input, reset any twin): --rest-trusted is for a loopback address only; \
             give REST an identity instead (--rest-certificate, --rest-private-key)"
        ),
        None => bail!(
            "the router has access control, which REST inside the router bypasses (its requests \
             reach the mesh as the router itself): give REST an identity the rules name \
             (--rest-certificate FILE --rest-private-key FILE), or, for a loopback address only, \
             say REST is trusted (--rest-trusted)"
        ),
    }
}

/// The origins whose web pages may call REST: `--rest-allow-origin` (each `scheme://host[:port]`,
/// as a browser writes `Origin`), else the file's `plugins/rest/allowed_origins`; none by default.
/// No wildcard: any page a plant's browser opens could then drive the mesh.
pub fn allowed_origins(file: Option<&Value>, flags: &[String]) -> Result<Vec<String>> {
    let origins: Vec<String> = if flags.is_empty() {
        match file {
            None => Vec::new(),
            Some(Value::Array(list)) => list
                .iter()
                .map(|o| {
                    o.as_str().map(str::to_owned).with_context(|| {
                        format!("plugins/rest/allowed_origins: {o} is not a string")
                    })
                })
                .collect::<Result<_>>()?,
            Some(other) => bail!("plugins/rest/allowed_origins {other} is not a list of origins"),
        }
    } else {
        flags.to_vec()
    };
    for origin in &origins {
        let well_formed = origin.split_once("://").is_some_and(|(scheme, authority)| {
            matches!(scheme, "http" | "https")
                && !authority.is_empty()
                && !authority.contains(['/', '*', ' '])
        });
        if !well_formed {
            bail!(
                "REST's allowed origin '{origin}' is not scheme://host[:port] (no path, no \
                 wildcard)"
            );
        }
    }
    Ok(origins)
}

/// Whether the configuration turns the router's access control on.
pub fn access_control_enabled(config: &Config) -> bool {
    config
        .get_json("access_control/enabled")
        .is_ok_and(|json| json.trim() == "true")
}

/// The endpoint a client in this process reaches the router on: its first TLS listen endpoint,
/// a wildcard address replaced by `localhost` (the name the router's certificate carries).
fn own_tls_endpoint(listen: &Value) -> Result<String> {
    let endpoints = match listen {
        Value::Array(list) => list.clone(),
        Value::Object(by_mode) => by_mode
            .get("router")
            .and_then(Value::as_array)
            .cloned()
            .unwrap_or_default(),
        _ => Vec::new(),
    };
    let endpoint = endpoints
        .iter()
        .filter_map(Value::as_str)
        .find(|e| e.starts_with("tls/"))
        .context(
            "REST with an identity reaches the router over TLS, but the router listens on no \
             tls/ endpoint",
        )?;
    // Drop the endpoint's metadata and configuration (`?…`, `#…`): they are the listener's.
    let address = endpoint
        .trim_start_matches("tls/")
        .split(['?', '#'])
        .next()
        .unwrap_or_default();
    let (host, port) = address
        .rsplit_once(':')
        .with_context(|| format!("listen endpoint {endpoint} has no port"))?;
    let host = match host {
        "0.0.0.0" | "[::]" | "::" => "localhost",
        host => host,
    };
    Ok(format!("tls/{host}:{port}"))
}

/// The configuration of the Zenoh client that serves REST as an identity: the router's TLS
/// settings (its CA) with the identity's certificate, connected to the router's own TLS
/// endpoint, nothing else (no scouting, no admin space).
pub fn identity_client_config(
    router: &Config,
    certificate: &std::path::Path,
    private_key: &std::path::Path,
) -> Result<Config> {
    let listen: Value = serde_json::from_str(
        &router
            .get_json("listen/endpoints")
            .map_err(|e| anyhow::anyhow!("{e}"))?,
    )?;
    let endpoint = own_tls_endpoint(&listen)?;
    let mut tls: Value = serde_json::from_str(
        &router
            .get_json("transport/link/tls")
            .map_err(|e| anyhow::anyhow!("{e}"))?,
    )?;
    let Some(settings) = tls.as_object_mut() else {
        bail!("the router's transport/link/tls is not an object");
    };
    let has_ca = ["root_ca_certificate", "root_ca_certificate_base64"]
        .iter()
        .any(|key| settings.get(*key).is_some_and(|v| !v.is_null()));
    if !has_ca {
        bail!(
            "REST with an identity needs the router's CA: transport/link/tls/root_ca_certificate"
        );
    }
    settings.retain(|key, _| !key.starts_with("listen_"));
    settings.insert("connect_certificate".to_owned(), path_value(certificate)?);
    settings.insert("connect_private_key".to_owned(), path_value(private_key)?);
    settings.insert("enable_mtls".to_owned(), Value::Bool(true));
    let mut client = Config::default();
    let inserts = [
        ("mode", "\"client\"".to_owned()),
        ("connect/endpoints", serde_json::to_string(&[endpoint])?),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("transport/link/protocols", "[\"tls\"]".to_owned()),
        ("transport/link/tls", tls.to_string()),
        ("adminspace/enabled", "false".to_owned()),
    ];
    for (key, value) in inserts {
        client
            .insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("cannot set the REST client's {key} to {value}"))?;
    }
    Ok(client)
}

fn path_value(path: &std::path::Path) -> Result<Value> {
    path.to_str()
        .map(|p| Value::String(p.to_owned()))
        .with_context(|| format!("{} is not UTF-8", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flags(port: Option<&str>, trusted: bool, identity: bool) -> RestFlags {
        RestFlags {
            http_port: port.map(str::to_owned),
            trusted,
            certificate: identity.then(|| "rest.pem".into()),
            private_key: identity.then(|| "rest.key".into()),
        }
    }

    fn at(text: &str) -> SocketAddr {
        text.parse().expect("an address")
    }

    #[test]
    fn a_bare_port_binds_loopback_and_an_address_binds_itself() {
        assert_eq!(flag_address("8000").expect("a port"), at("127.0.0.1:8000"));
        assert_eq!(
            flag_address("0.0.0.0:8000").expect("an address"),
            at("0.0.0.0:8000")
        );
        assert_eq!(
            flag_address("[::1]:8000").expect("an address"),
            at("[::1]:8000")
        );
        assert!(flag_address("localhost:8000").is_err());
        assert!(flag_address("80000").is_err());
        // The file keeps zenohd's meaning: a port alone is every interface.
        assert_eq!(
            file_address(&serde_json::json!(8000)).expect("a port"),
            at("[::]:8000")
        );
        assert_eq!(
            file_address(&serde_json::json!("8000")).expect("a port"),
            at("[::]:8000")
        );
        assert_eq!(
            file_address(&serde_json::json!("127.0.0.1:8000")).expect("an address"),
            at("127.0.0.1:8000")
        );
        assert!(file_address(&serde_json::json!(true)).is_err());
    }

    #[test]
    fn without_access_control_rest_runs_inside_the_router() {
        let door_of = |port| door(false, None, &flags(port, false, false)).expect("a door");
        assert_eq!(door_of(None), RestDoor::Off);
        assert_eq!(door_of(Some("none")), RestDoor::Off);
        assert_eq!(
            door_of(Some("8000")),
            RestDoor::Inside {
                address: at("127.0.0.1:8000")
            }
        );
        assert_eq!(
            door_of(Some("0.0.0.0:8000")),
            RestDoor::Inside {
                address: at("0.0.0.0:8000")
            }
        );
        let from_file = door(false, Some(&serde_json::json!(8000)), &RestFlags::default());
        assert_eq!(
            from_file.expect("a door"),
            RestDoor::Inside {
                address: at("[::]:8000")
            }
        );
        // The flag replaces the file's port.
        let flag_wins = door(
            false,
            Some(&serde_json::json!(8000)),
            &flags(Some("none"), false, false),
        );
        assert_eq!(flag_wins.expect("a door"), RestDoor::Off);
    }

    #[test]
    fn with_access_control_rest_needs_an_identity_or_trust_on_loopback() {
        let refused = |flags: RestFlags| door(true, None, &flags).expect_err("refused").to_string();
        // Loopback alone is not enough: any process of the host would reach every twin.
        assert!(refused(flags(Some("8000"), false, false)).contains("--rest-certificate"));
        assert!(refused(flags(Some("0.0.0.0:8000"), false, false)).contains("--rest-trusted"));
        assert!(
            refused(flags(Some("0.0.0.0:8000"), true, false)).contains("loopback address only")
        );
        let file = serde_json::json!(8000);
        assert!(
            door(true, Some(&file), &flags(None, true, false)).is_err(),
            "every interface"
        );
        assert_eq!(
            door(true, None, &flags(Some("8000"), true, false)).expect("trusted"),
            RestDoor::Inside {
                address: at("127.0.0.1:8000")
            }
        );
        assert_eq!(
            door(true, None, &flags(Some("0.0.0.0:8000"), false, true)).expect("an identity"),
            RestDoor::Identity {
                address: at("0.0.0.0:8000"),
                certificate: "rest.pem".into(),
                private_key: "rest.key".into(),
            }
        );
        assert!(refused(flags(Some("8000"), true, true)).contains("contradict"));
        let mut half = flags(Some("8000"), false, true);
        half.private_key = None;
        assert!(refused(half).contains("go together"));
        assert!(refused(flags(None, false, true)).contains("without REST"));
    }

    #[test]
    fn allowed_origins_are_exact_origins_and_none_by_default() {
        let file = serde_json::json!(["http://hmi.plant:8080"]);
        assert!(allowed_origins(None, &[]).expect("none").is_empty());
        assert_eq!(
            allowed_origins(Some(&file), &[]).expect("the file's"),
            ["http://hmi.plant:8080"]
        );
        let flag = ["https://scada.plant".to_owned()];
        assert_eq!(
            allowed_origins(Some(&file), &flag).expect("the flag's"),
            ["https://scada.plant"]
        );
        for bad in [
            "*",
            "http://*",
            "hmi.plant",
            "http://hmi.plant/",
            "ftp://hmi.plant",
        ] {
            assert!(allowed_origins(None, &[bad.to_owned()]).is_err(), "{bad}");
        }
        assert!(allowed_origins(Some(&serde_json::json!("http://a")), &[]).is_err());
    }

    #[test]
    fn the_identity_client_reaches_the_router_over_its_own_tls_endpoint() {
        let endpoint = |listen: Value| own_tls_endpoint(&listen).map_err(|e| e.to_string());
        assert_eq!(
            endpoint(serde_json::json!(["tcp/0.0.0.0:7448", "tls/0.0.0.0:7447"])).as_deref(),
            Ok("tls/localhost:7447")
        );
        assert_eq!(
            endpoint(serde_json::json!({"router": ["tls/localhost:7447#iface=lo"]})).as_deref(),
            Ok("tls/localhost:7447")
        );
        assert_eq!(
            endpoint(serde_json::json!(["tls/[::]:7447"])).as_deref(),
            Ok("tls/localhost:7447")
        );
        assert!(endpoint(serde_json::json!(["tcp/localhost:7447"])).is_err());

        let mut router = Config::default();
        for (key, value) in [
            ("listen/endpoints", r#"["tls/localhost:7447"]"#),
            (
                "transport/link/tls/root_ca_certificate",
                r#""certs/ca.pem""#,
            ),
            (
                "transport/link/tls/listen_certificate",
                r#""certs/router.pem""#,
            ),
            (
                "transport/link/tls/listen_private_key",
                r#""certs/router.key""#,
            ),
        ] {
            router.insert_json5(key, value).expect("a setting");
        }
        let client = identity_client_config(
            &router,
            "certs/rest.pem".as_ref(),
            "certs/rest.key".as_ref(),
        )
        .expect("a client");
        let get = |key: &str| client.get_json(key).expect(key);
        assert_eq!(get("mode"), "\"client\"");
        assert_eq!(get("connect/endpoints"), r#"["tls/localhost:7447"]"#);
        assert_eq!(
            get("transport/link/tls/root_ca_certificate"),
            "\"certs/ca.pem\""
        );
        assert_eq!(
            get("transport/link/tls/connect_certificate"),
            "\"certs/rest.pem\""
        );
        assert_eq!(get("transport/link/tls/listen_certificate"), "null");

        let mut without_ca = router.clone();
        without_ca
            .insert_json5("transport/link/tls/root_ca_certificate", "null")
            .expect("a setting");
        let refused = identity_client_config(&without_ca, "a".as_ref(), "b".as_ref());
        assert!(refused.is_err());
    }
}
