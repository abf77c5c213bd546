//! Who may use the admin queries (`<prefix>/admin/**`: reset, apply or discard a calibration or
//! a payload, write an incident file): decided once at the start from the session's own Zenoh
//! configuration, since a Zenoh query carries no trustworthy origin (its source id is the
//! querier's to write).
//!
//! - `[service] admin = "loopback"` (the default): answered while nobody off this host can reach
//!   the instance: every `listen` endpoint is a loopback address (or a Unix socket), it connects
//!   nowhere and multicast scouting is off; or its own access control is on, which then judges
//!   each query.
//! - `"mesh"`: answered for whoever reaches the instance: the mesh's router and its ACL decide.
//! - `"off"`: never answered.

use serde_json::Value;

use crate::config::AdminAccess;
use crate::exposure::{endpoints, is_local, json_at};

/// Why the admin queries are refused on a session configured as `zenoh` (its effective Zenoh
/// configuration), or `None` when they are answered.
pub(super) fn refusal(admin: AdminAccess, zenoh: &zenoh::Config) -> Option<String> {
    match admin {
        AdminAccess::Mesh => None,
        AdminAccess::Off => Some("admin queries are off ([service] admin = \"off\")".to_owned()),
        AdminAccess::Loopback => {
            if json_at(zenoh, "access_control/enabled") == Some(Value::Bool(true)) {
                return None;
            }
            let mut open = Vec::new();
            for endpoint in endpoints(json_at(zenoh, "listen/endpoints")) {
                if !is_local(&endpoint) {
                    open.push(format!("listens on {endpoint}"));
                }
            }
            for endpoint in endpoints(json_at(zenoh, "connect/endpoints")) {
                open.push(format!("connects to {endpoint}"));
            }
            if json_at(zenoh, "scouting/multicast/enabled") == Some(Value::Bool(true)) {
                open.push("scouts by multicast".to_owned());
            }
            (!open.is_empty()).then(|| {
                format!(
                    "admin queries are answered only for this host ([service] admin = \
                     \"loopback\"), and this instance {} without access control: give the \
                     session an ACL, or set [service] admin = \"mesh\" where a router's ACL \
                     guards the mesh",
                    open.join(", ")
                )
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(json5: &str) -> zenoh::Config {
        zenoh::Config::from_json5(json5).expect("a valid Zenoh config")
    }

    #[test]
    fn loopback_endpoints_are_local_and_others_are_not() {
        for local in [
            "tcp/127.0.0.1:7447",
            "tcp/127.0.0.2:7447",
            "tls/localhost:7447",
            "udp/[::1]:7447",
            "tcp/127.0.0.1:7447#iface=lo",
            "unixsock-stream//tmp/z.sock",
        ] {
            assert!(is_local(local), "{local}");
        }
        for open in [
            "tcp/0.0.0.0:7447",
            "tcp/[::]:7447",
            "tcp/10.0.0.5:7447",
            "tls/router.plant:7447",
            "quic/192.168.1.2:7447",
            "tcp",
        ] {
            assert!(!is_local(open), "{open}");
        }
    }

    #[test]
    fn loopback_answers_only_an_instance_no_other_host_reaches() {
        let local = config(
            r#"{mode: "peer", listen: {endpoints: ["tcp/127.0.0.1:7447"]}, scouting: {multicast: {enabled: false}}}"#,
        );
        assert_eq!(refusal(AdminAccess::Loopback, &local), None);
        let open = config(
            r#"{mode: "peer", listen: {endpoints: ["tcp/0.0.0.0:7447"]}, scouting: {multicast: {enabled: false}}}"#,
        );
        let why = refusal(AdminAccess::Loopback, &open).expect("refused");
        assert!(why.contains("listens on tcp/0.0.0.0:7447"), "{why}");
        let client = config(
            r#"{mode: "client", connect: {endpoints: ["tcp/10.0.0.5:7447"]}, scouting: {multicast: {enabled: false}}}"#,
        );
        let why = refusal(AdminAccess::Loopback, &client).expect("refused");
        assert!(why.contains("connects to tcp/10.0.0.5:7447"), "{why}");
        let scouting = config(
            r#"{mode: "peer", listen: {endpoints: ["tcp/127.0.0.1:7447"]}, scouting: {multicast: {enabled: true}}}"#,
        );
        assert!(refusal(AdminAccess::Loopback, &scouting).is_some());
        let per_mode = config(
            r#"{mode: "peer", listen: {endpoints: {peer: ["tcp/127.0.0.1:7447"], router: ["tcp/0.0.0.0:7447"]}}, scouting: {multicast: {enabled: false}}}"#,
        );
        assert!(
            refusal(AdminAccess::Loopback, &per_mode).is_some(),
            "every mode's endpoints count"
        );
    }

    #[test]
    fn an_acl_or_the_mesh_answers_and_off_never_does() {
        let guarded = config(
            r#"{mode: "peer", listen: {endpoints: ["tcp/0.0.0.0:7447"]}, access_control: {enabled: true, default_permission: "deny"}}"#,
        );
        assert_eq!(refusal(AdminAccess::Loopback, &guarded), None);
        let open = config(r#"{mode: "peer", listen: {endpoints: ["tcp/0.0.0.0:7447"]}}"#);
        assert_eq!(refusal(AdminAccess::Mesh, &open), None);
        let local = config(r#"{mode: "peer", listen: {endpoints: ["tcp/127.0.0.1:7447"]}}"#);
        assert!(refusal(AdminAccess::Off, &local).is_some());
    }
}
