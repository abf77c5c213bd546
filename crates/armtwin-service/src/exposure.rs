//! Who may reach each door of a configured service, read from its configuration alone (what
//! `armtwin doctor` says of the doors): Zenoh's listeners and links, the admin queries, the
//! dashboard and the OPC UA server. Nothing is bound or opened.
//!
//! Must not decide what the service does: it reads the same rules the service applies
//! (`service::admin`'s, `[http]`'s, `[opcua]`'s) and says where they leave a door.

use std::net::SocketAddr;

use serde_json::Value;

use crate::config::{AdminAccess, ServiceConfig};
use armtwin_mesh::{MeshError, zenoh_config_of};

/// How a door stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verdict {
    /// As it should be.
    Ok,
    /// Worth a look: open on purpose, or closed where it may be wanted.
    Warn,
    /// Open to anyone who reaches the host, without a check of who they are.
    Fail,
}

/// One door: its name, how it stands, and who may reach it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Door {
    /// What the door is (`zenoh listen tcp/127.0.0.1:7447`).
    pub name: String,
    /// How it stands.
    pub verdict: Verdict,
    /// Who may reach it, and through what.
    pub who: String,
}

fn door(name: String, verdict: Verdict, who: impl Into<String>) -> Door {
    Door {
        name,
        verdict,
        who: who.into(),
    }
}

/// Every door of `config`, in the order the service opens them.
pub fn doors(config: &ServiceConfig) -> Result<Vec<Door>, MeshError> {
    let zenoh = zenoh_config_of(&config.zenoh)?;
    let guarded = json_at(&zenoh, "access_control/enabled") == Some(Value::Bool(true));
    let mut found = Vec::new();
    for endpoint in endpoints(json_at(&zenoh, "listen/endpoints")) {
        let name = format!("zenoh listen {endpoint}");
        found.push(if is_local(&endpoint) {
            door(name, Verdict::Ok, "this host only")
        } else if guarded {
            door(
                name,
                Verdict::Ok,
                "the network, each peer judged by the session's access control",
            )
        } else {
            door(
                name,
                Verdict::Fail,
                "anyone on the network, unchecked: any peer may put any robot's samples and read \
                 every twin (listen on loopback, give the session an access control, or run \
                 behind a router with one: docs/security.md)",
            )
        });
    }
    for endpoint in endpoints(json_at(&zenoh, "connect/endpoints")) {
        found.push(door(
            format!("zenoh connect {endpoint}"),
            Verdict::Ok,
            "that router's peers, as its access control allows",
        ));
    }
    if json_at(&zenoh, "scouting/multicast/enabled") == Some(Value::Bool(true)) {
        found.push(door(
            "zenoh multicast scouting".to_owned(),
            Verdict::Warn,
            "any peer on the LAN finds and joins this session",
        ));
    }
    found.push(admin_door(config.admin, &found));
    found.push(http_door(config));
    found.push(opcua_door(config));
    Ok(found)
}

/// The admin queries (reset, apply a calibration or payload, write an incident file).
fn admin_door(admin: AdminAccess, zenoh_doors: &[Door]) -> Door {
    let name = "admin queries".to_owned();
    let open = zenoh_doors.iter().any(|d| d.verdict == Verdict::Fail);
    match admin {
        AdminAccess::Off => door(name, Verdict::Ok, "nobody ([service] admin = \"off\")"),
        AdminAccess::Loopback => door(
            name,
            Verdict::Ok,
            "this host's sessions, and only while no other host reaches the instance \
             ([service] admin = \"loopback\")",
        ),
        AdminAccess::Mesh if open => door(
            name,
            Verdict::Fail,
            "whoever reaches the mesh ([service] admin = \"mesh\"), and a listener above is open \
             to the network unchecked",
        ),
        AdminAccess::Mesh => door(
            name,
            Verdict::Ok,
            "whoever the mesh's access control lets query <prefix>/admin/** ([service] admin = \
             \"mesh\")",
        ),
    }
}

/// The dashboard and `/metrics`.
fn http_door(config: &ServiceConfig) -> Door {
    let Some(address) = config.http_listen else {
        return door("http".to_owned(), Verdict::Ok, "off: no [http] listen");
    };
    let name = format!("http {address}");
    let access = &config.http_access;
    let scheme = if access.tls.is_some() {
        "HTTPS"
    } else {
        "plain HTTP"
    };
    match (is_loopback(address), access.tokens.len()) {
        (true, 0) => door(
            name,
            Verdict::Ok,
            format!("this host only, {scheme}, no token"),
        ),
        (_, 0) => door(
            name,
            Verdict::Warn,
            format!("anyone on the network, {scheme}, no token ([http] anonymous = true)"),
        ),
        (_, tokens) => door(
            name,
            Verdict::Ok,
            format!("holders of one of {tokens} tokens, {scheme}"),
        ),
    }
}

/// The OPC UA server.
fn opcua_door(config: &ServiceConfig) -> Door {
    let Some(opcua) = &config.opcua else {
        return door("opcua".to_owned(), Verdict::Ok, "off: no [opcua] endpoint");
    };
    let name = format!("opcua {}", opcua.url);
    let local = opcua.host == "localhost"
        || opcua
            .host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback());
    let users = opcua.users.len();
    let who = match (opcua.anonymous, users) {
        (true, 0) => "anonymous clients".to_owned(),
        (true, _) => format!("anonymous clients and {users} users"),
        (false, _) => format!("{users} users"),
    };
    let channel = if opcua.security_none {
        "unencrypted channels allowed"
    } else {
        "signed and encrypted channels"
    };
    let verdict = if !local && opcua.anonymous {
        Verdict::Fail
    } else if !local && opcua.security_none {
        Verdict::Warn
    } else {
        Verdict::Ok
    };
    let reach = if local {
        "this host only"
    } else {
        "the network"
    };
    door(name, verdict, format!("{reach}: {who}, {channel}"))
}

fn is_loopback(address: SocketAddr) -> bool {
    address.ip().is_loopback()
}

/// The JSON value at `path` of `zenoh`, if it has one.
pub(crate) fn json_at(zenoh: &zenoh::Config, path: &str) -> Option<Value> {
    zenoh
        .get_json(path)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
}

/// Every endpoint an endpoint list names: a list, or a list per mode (all modes counted).
pub(crate) fn endpoints(value: Option<Value>) -> Vec<String> {
    let mut found = Vec::new();
    let mut next: Vec<Value> = value.into_iter().collect();
    while let Some(value) = next.pop() {
        match value {
            Value::String(endpoint) => found.push(endpoint),
            Value::Array(items) => next.extend(items.into_iter().rev()),
            Value::Object(by_mode) => next.extend(by_mode.into_iter().map(|(_, v)| v)),
            _ => {}
        }
    }
    found
}

/// Whether `endpoint` (`proto/address[?config][#metadata]`) is reachable from this host alone.
pub(crate) fn is_local(endpoint: &str) -> bool {
    let locator = endpoint.split(['?', '#']).next().unwrap_or_default();
    let Some((protocol, address)) = locator.split_once('/') else {
        return false;
    };
    if protocol.starts_with("unixsock") || protocol == "unixpipe" {
        return true;
    }
    // `host:port`, `[v6]:port`; the port's absence is the address's problem, not ours.
    let host = match address.strip_prefix('[') {
        Some(rest) => rest.split(']').next().unwrap_or_default(),
        None => address.rsplit_once(':').map_or(address, |(host, _)| host),
    };
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Overrides;

    fn doors_of(text: &str) -> Vec<(String, Verdict)> {
        let config = ServiceConfig::parse(
            text,
            "test",
            std::path::Path::new(""),
            &Overrides::default(),
        )
        .expect("loads");
        doors(&config)
            .expect("doors")
            .into_iter()
            .map(|d| (d.name, d.verdict))
            .collect()
    }

    #[test]
    fn the_built_in_configuration_opens_no_door_to_the_network() {
        let config = ServiceConfig::load(None, &Overrides::default()).expect("loads");
        let found = doors(&config).expect("doors");
        assert!(found.iter().all(|d| d.verdict == Verdict::Ok), "{found:?}");
        assert!(
            found[0].name.starts_with("zenoh listen tcp/127.0.0.1:"),
            "{found:?}"
        );
    }

    #[test]
    fn a_listener_on_every_address_without_access_control_fails() {
        let found =
            doors_of("[zenoh]\nlisten = [\"tcp/0.0.0.0:7447\"]\n[service]\nadmin = \"mesh\"\n");
        assert!(
            found.contains(&("zenoh listen tcp/0.0.0.0:7447".to_owned(), Verdict::Fail)),
            "{found:?}"
        );
        assert!(
            found.contains(&("admin queries".to_owned(), Verdict::Fail)),
            "{found:?}"
        );
    }
}
