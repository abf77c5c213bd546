//! A fleet's access control on its Zenoh router (`armtwin acl`): a small fleet description —
//! which certificate common name (CN) speaks for which robots, which names are armtwin
//! instances, dashboards and operators — becomes the `access_control` section of the router's
//! configuration (Zenoh 1.10's keys: `rules`, `subjects`, `policies`), every key built by
//! [`KeySpace`] under the fleet's key prefix.
//!
//! What each role may do (docs/security.md has the whole table):
//! - a **gateway** puts joints and measured poses, and holds its streaming/waiting tokens, for
//!   its own robots only (robot ids or key expressions over them, `site-a/**`); it asks its own
//!   robots' state (`armtwin replay` waits on it) and sees who subscribes to inputs (its
//!   publisher sends nothing while it knows of no subscriber);
//! - **armtwin** takes inputs and publishes every output, token and queryable under the prefix;
//!   it reads the other instances' robots' state and hears the gateways' tokens;
//! - a **dashboard** subscribes and reads (`state`, `fk`, `ik`, `calibrate`), never changes;
//! - an **operator** reads and also changes a twin (`<prefix>/admin/**`).
//!
//! Pure: takes the description's text, returns the section as JSON (also JSON5); must not read
//! files nor know the router that loads it.

use std::collections::{BTreeMap, BTreeSet};

use serde::Deserialize;
use serde_json::{Value, json};
use thiserror::Error;
use zenoh::key_expr::KeyExpr;

use armtwin_mesh::keys::{self, KeySpace, Stream};

/// Outputs, tokens and queryables armtwin declares per robot: every stream but the inputs and
/// the gateways' own tokens.
const ARMTWIN_DECLARES: [Stream; 18] = [
    Stream::Pose,
    Stream::Deviation,
    Stream::Paired,
    Stream::Metrics,
    Stream::Events,
    Stream::Calibration,
    Stream::Effort,
    Stream::Payload,
    Stream::Alive,
    Stream::State,
    Stream::History,
    Stream::Fk,
    Stream::Ik,
    Stream::Calibrate,
    Stream::Reset,
    Stream::ApplyCalibration,
    Stream::ApplyPayload,
    Stream::Record,
];
/// What a gateway sends for a robot.
const INPUTS: [Stream; 4] = [
    Stream::Joints,
    Stream::Measured,
    Stream::Controller,
    Stream::Description,
];
/// What a gateway keeps the latest of, for an armtwin instance that starts after it.
const LATEST: [Stream; 2] = [Stream::Controller, Stream::Description];
/// The tokens a gateway holds for a robot.
const GATEWAY_TOKENS: [Stream; 2] = [Stream::GatewayStreaming, Stream::GatewayWaiting];
/// Queryables that only read: the ACL sees a query's key, never its parameters, so every change
/// lives under `<prefix>/admin/`, which these leave out.
const READS: [Stream; 5] = [
    Stream::State,
    Stream::History,
    Stream::Fk,
    Stream::Ik,
    Stream::Calibrate,
];
/// Queryables that change a twin.
const CHANGES: [Stream; 4] = [
    Stream::Reset,
    Stream::ApplyCalibration,
    Stream::ApplyPayload,
    Stream::Record,
];

/// The fleet description's TOML (config/fleet.toml is a commented one).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FleetFile {
    #[serde(default = "default_prefix")]
    key_prefix: String,
    #[serde(default)]
    armtwin: Vec<String>,
    #[serde(default)]
    dashboards: Vec<String>,
    #[serde(default)]
    operators: Vec<String>,
    /// Gateway CN → the robots it speaks for.
    #[serde(default)]
    gateways: BTreeMap<String, Grant>,
}

/// A gateway's robots: a list, or a table with the most robots of its prefixes it may bring.
#[derive(Debug, Deserialize)]
#[serde(untagged, deny_unknown_fields)]
enum Grant {
    Robots(Vec<String>),
    Limited {
        robots: Vec<String>,
        max_robots: usize,
    },
}

/// The most robots one gateway's prefix grant (`site-a/**`) brings to armtwin unless its
/// `max_robots` says otherwise.
pub const DEFAULT_GRANT_MAX_ROBOTS: usize = 1000;

/// `site-a/` of a grant `site-a/**` whose head has no wildcard (a key expression of another
/// shape names no prefix).
fn granted_prefix(entry: &str) -> Option<&str> {
    let head = entry.strip_suffix("**")?;
    (head.ends_with('/') && !head.contains('*') && !head.contains('$')).then_some(head)
}

fn default_prefix() -> String {
    keys::DEFAULT_PREFIX.to_owned()
}

/// Why a fleet description cannot become an access control.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum AclError {
    /// Not TOML, or not the description's fields.
    #[error("{0}")]
    Syntax(String),
    /// `key_prefix` is not a plain key.
    #[error("key_prefix '{prefix}' {problem}")]
    Prefix {
        /// The prefix given.
        prefix: String,
        /// What is wrong with it.
        problem: keys::PlainKeyError,
    },
    /// A name that is empty or blank.
    #[error("an empty certificate name among the {role}")]
    EmptyName {
        /// The role's field.
        role: &'static str,
    },
    /// A name given two roles (or twice in one): each name has one role, so that what it may
    /// do is read in one place.
    #[error("'{name}' is named twice ({first} and {second}): give each certificate name one role")]
    NameTwice {
        /// The name.
        name: String,
        /// Its first role's field.
        first: &'static str,
        /// Its second role's field.
        second: &'static str,
    },
    /// A gateway without robots.
    #[error("gateway '{gateway}' speaks for no robot: list its robot ids (or `site/**`)")]
    NoRobots {
        /// The gateway's name.
        gateway: String,
    },
    /// A gateway's robot that is neither a robot id nor a key expression over ids.
    #[error("gateway '{gateway}': '{robots}' is not a robot id nor a key expression ({problem})")]
    Robots {
        /// The gateway's name.
        gateway: String,
        /// The entry given.
        robots: String,
        /// Zenoh's reason.
        problem: String,
    },
    /// Nobody is named at all.
    #[error("the fleet names nobody: list its armtwin, dashboards, operators or gateways")]
    Empty,
}

/// A checked fleet description.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fleet {
    keys: KeySpace,
    armtwin: Vec<String>,
    dashboards: Vec<String>,
    operators: Vec<String>,
    /// Each gateway's name and robots (id or key expression over ids), by name.
    gateways: Vec<(String, Vec<String>)>,
    /// Each prefix granted to a gateway (`site-a/` of `site-a/**`) and the most robots of it.
    groups: Vec<(String, usize)>,
}

impl Fleet {
    /// Reads and checks a fleet description (TOML).
    pub fn parse(text: &str) -> Result<Self, AclError> {
        let file: FleetFile = toml::from_str(text).map_err(|e| AclError::Syntax(e.to_string()))?;
        let keys = KeySpace::new(&file.key_prefix).map_err(|problem| AclError::Prefix {
            prefix: file.key_prefix.clone(),
            problem,
        })?;
        let mut roles: BTreeMap<&str, &'static str> = BTreeMap::new();
        let named = [
            ("armtwin", &file.armtwin),
            ("dashboards", &file.dashboards),
            ("operators", &file.operators),
        ];
        let gateway_names: Vec<String> = file.gateways.keys().cloned().collect();
        for (role, names) in named
            .into_iter()
            .chain(std::iter::once(("gateways", &gateway_names)))
        {
            for name in names {
                if name.trim().is_empty() {
                    return Err(AclError::EmptyName { role });
                }
                if let Some(first) = roles.insert(name, role) {
                    return Err(AclError::NameTwice {
                        name: name.clone(),
                        first,
                        second: role,
                    });
                }
            }
        }
        if roles.is_empty() {
            return Err(AclError::Empty);
        }
        let mut gateways = Vec::with_capacity(file.gateways.len());
        let mut groups = Vec::new();
        for (gateway, grant) in file.gateways {
            let (robots, max_robots) = match grant {
                Grant::Robots(robots) => (robots, DEFAULT_GRANT_MAX_ROBOTS),
                Grant::Limited { robots, max_robots } => (robots, max_robots),
            };
            groups.extend(
                robots
                    .iter()
                    .filter_map(|entry| granted_prefix(entry))
                    .map(|prefix| (prefix.to_owned(), max_robots)),
            );
            gateways.push((gateway, robots));
        }
        for (gateway, robots) in &gateways {
            if robots.is_empty() {
                return Err(AclError::NoRobots {
                    gateway: gateway.clone(),
                });
            }
            for entry in robots {
                check_robots(entry).map_err(|problem| AclError::Robots {
                    gateway: gateway.clone(),
                    robots: entry.clone(),
                    problem,
                })?;
            }
        }
        Ok(Self {
            keys,
            armtwin: file.armtwin,
            dashboards: file.dashboards,
            operators: file.operators,
            gateways,
            groups,
        })
    }

    /// Each robot-id prefix granted to a gateway (`site-a/` of `site-a/**`), with the most robots
    /// of it the gateway may bring (`max_robots` of its grant, else
    /// [`DEFAULT_GRANT_MAX_ROBOTS`]).
    #[must_use]
    pub fn robot_groups(&self) -> &[(String, usize)] {
        &self.groups
    }

    /// The router's `access_control` section: default deny, one rule per thing a role may do,
    /// one subject per role (one per gateway), and the policies joining them.
    #[must_use]
    pub fn access_control(&self) -> Value {
        let mut section = Section::default();
        self.armtwin_rules(&mut section);
        self.watcher_rules(&mut section);
        self.gateway_rules(&mut section);
        json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": section.rules,
            "subjects": section.subjects,
            "policies": section.policies,
        })
    }

    /// `<prefix>/<stream>/**` of each of `streams`.
    fn every(&self, streams: &[Stream]) -> Vec<String> {
        streams.iter().map(|s| self.keys.every_robot(*s)).collect()
    }

    /// What armtwin instances may do.
    fn armtwin_rules(&self, section: &mut Section) {
        if !self.armtwin.is_empty() {
            let mut declared = self.every(&ARMTWIN_DECLARES);
            declared.push(self.keys.every_shard_claim());
            section.rules.extend([
                rule(
                    "armtwin-publish",
                    &["ingress"],
                    &["put", "liveliness_token", "declare_queryable", "reply"],
                    &declared,
                ),
                rule(
                    "armtwin-take-inputs",
                    &["ingress"],
                    &["declare_subscriber"],
                    &self.every(&INPUTS),
                ),
                rule(
                    "armtwin-receive-inputs",
                    &["egress"],
                    &["put"],
                    &self.every(&INPUTS),
                ),
                // Each instance asks the gateways what they read of the controllers when it
                // starts (their TCP, model and serial number), and the robots' descriptions.
                rule(
                    "armtwin-ask-controllers",
                    &["ingress", "egress"],
                    &["query", "reply"],
                    &self.every(&LATEST),
                ),
                // Each instance asks the others which robots they own (`[service] robots`).
                rule(
                    "armtwin-shard-claims",
                    &["ingress", "egress"],
                    &["query", "reply"],
                    &[self.keys.every_shard_claim()],
                ),
                // The fleet page of each instance lists the other instances' robots.
                rule(
                    "armtwin-read-other-shards",
                    &["ingress", "egress"],
                    &["query", "reply"],
                    &self.every(&[Stream::State]),
                ),
                // `/metrics` says whether each robot's gateway streams.
                rule(
                    "armtwin-watch-gateways",
                    &["ingress"],
                    &["declare_liveliness_subscriber", "liveliness_query"],
                    &self.every(&GATEWAY_TOKENS),
                ),
                rule(
                    "armtwin-hear-gateways",
                    &["egress"],
                    &["liveliness_token"],
                    &self.every(&GATEWAY_TOKENS),
                ),
                // Queries reach armtwin's queryables, and its publishers learn who subscribes
                // (a publisher that knows of no subscriber sends nothing).
                rule(
                    "armtwin-be-queried-and-subscribed",
                    &["egress"],
                    &["query", "declare_subscriber"],
                    &[self.keys.everything()],
                ),
            ]);
            section.subjects.push(subject("armtwin", &self.armtwin));
            section.policies.push(policy(
                &[
                    "armtwin-publish",
                    "armtwin-take-inputs",
                    "armtwin-receive-inputs",
                    "armtwin-ask-controllers",
                    "armtwin-shard-claims",
                    "armtwin-read-other-shards",
                    "armtwin-watch-gateways",
                    "armtwin-hear-gateways",
                    "armtwin-be-queried-and-subscribed",
                ],
                "armtwin",
            ));
        }
    }

    /// What dashboards and operators may do.
    fn watcher_rules(&self, section: &mut Section) {
        if !self.dashboards.is_empty() || !self.operators.is_empty() {
            section.rules.extend([
                rule(
                    "watch",
                    &["ingress"],
                    &[
                        "declare_subscriber",
                        "declare_liveliness_subscriber",
                        "liveliness_query",
                    ],
                    &[self.keys.everything()],
                ),
                rule("read", &["ingress"], &["query"], &self.every(&READS)),
                // Outputs, replies and tokens reach watchers, and so do queryables'
                // declarations (a querier sees that something answers).
                rule(
                    "receive",
                    &["egress"],
                    &["put", "reply", "liveliness_token", "declare_queryable"],
                    &[self.keys.everything()],
                ),
            ]);
        }
        if !self.dashboards.is_empty() {
            section
                .subjects
                .push(subject("dashboards", &self.dashboards));
            section
                .policies
                .push(policy(&["watch", "read", "receive"], "dashboards"));
        }
        if !self.operators.is_empty() {
            section.rules.push(rule(
                "operate",
                &["ingress"],
                &["query"],
                &self.every(&CHANGES),
            ));
            section.subjects.push(subject("operators", &self.operators));
            section.policies.push(policy(
                &["watch", "read", "operate", "receive"],
                "operators",
            ));
        }
    }

    /// What each gateway may do, for its own robots.
    fn gateway_rules(&self, section: &mut Section) {
        if !self.gateways.is_empty() {
            // Declarations only, no data: a gateway's publisher sends nothing until it knows of
            // a subscriber, and the subscriber it must see (`<prefix>/joints/**`, a shard's
            // `<prefix>/joints/site-a/**`) is wider than any one gateway's robots.
            section.rules.push(rule(
                "gateway-see-subscribers",
                &["egress"],
                &["declare_subscriber"],
                &self.every(&INPUTS),
            ));
        }
        for (gateway, robots) in &self.gateways {
            let of = |streams: &[Stream]| -> Vec<String> {
                robots
                    .iter()
                    .flat_map(|robot| streams.iter().map(move |s| self.keys.key(*s, robot)))
                    .collect()
            };
            let id = format!("gateway:{gateway}");
            let inputs = format!("{id}:inputs");
            let tokens = format!("{id}:tokens");
            let ask = format!("{id}:ask-state");
            let hear = format!("{id}:hear-state");
            let facts = format!("{id}:controller-facts");
            let asked = format!("{id}:asked-controller-facts");
            section.rules.extend([
                rule(&inputs, &["ingress"], &["put"], &of(&INPUTS)),
                rule(
                    &tokens,
                    &["ingress"],
                    &["liveliness_token"],
                    &of(&GATEWAY_TOKENS),
                ),
                // `armtwin replay` asks its robot's state once the recording is sent: the
                // answer comes after every put it made, a barrier before it closes.
                rule(&ask, &["ingress"], &["query"], &of(&[Stream::State])),
                rule(&hear, &["egress"], &["reply"], &of(&[Stream::State])),
                // The latest of what it read of each controller, for a service that starts
                // after it.
                rule(
                    &facts,
                    &["ingress"],
                    &["declare_queryable", "reply"],
                    &of(&LATEST),
                ),
                // Asked by every armtwin instance at its start, on its whole shard
                // (`<prefix>/controller/**`, `…/site-a/**`), wider than this gateway's robots:
                // a rule on its own keys would never cover the query, and the service would
                // run without the controller's TCP until the facts changed. Only armtwin may
                // ask there, and the gateway answers for its own robots only (above).
                rule(&asked, &["egress"], &["query"], &self.every(&LATEST)),
            ]);
            section
                .subjects
                .push(subject(&id, std::slice::from_ref(gateway)));
            section.policies.push(policy(
                &[
                    &inputs,
                    &tokens,
                    &ask,
                    &hear,
                    &facts,
                    &asked,
                    "gateway-see-subscribers",
                ],
                &id,
            ));
        }
    }

    /// Every certificate name the description gives a role, each with its role's field.
    #[must_use]
    pub fn names(&self) -> BTreeSet<(&str, &'static str)> {
        let lists = [
            ("armtwin", &self.armtwin),
            ("dashboards", &self.dashboards),
            ("operators", &self.operators),
        ];
        lists
            .into_iter()
            .flat_map(|(role, names)| names.iter().map(move |n| (n.as_str(), role)))
            .chain(self.gateways.iter().map(|(n, _)| (n.as_str(), "gateways")))
            .collect()
    }
}

/// `entry` if it is a robot id or a canonical key expression over ids (`site-a/**`).
fn check_robots(entry: &str) -> Result<(), String> {
    if keys::robot_id(entry).is_ok() {
        return Ok(());
    }
    let key = KeyExpr::try_from(entry).map_err(|e| e.to_string())?;
    if key.as_str() == entry {
        Ok(())
    } else {
        Err(format!("its canonical form is '{key}'"))
    }
}

/// The parts of an `access_control` section, as the roles add them.
#[derive(Default)]
struct Section {
    rules: Vec<Value>,
    subjects: Vec<Value>,
    policies: Vec<Value>,
}

fn rule(id: &str, flows: &[&str], messages: &[&str], key_exprs: &[String]) -> Value {
    json!({
        "id": id,
        "permission": "allow",
        "flows": flows,
        "messages": messages,
        "key_exprs": key_exprs,
    })
}

fn subject(id: &str, names: &[String]) -> Value {
    json!({ "id": id, "cert_common_names": names })
}

fn policy(rules: &[&str], subject: &str) -> Value {
    json!({ "rules": rules, "subjects": [subject] })
}

/// The section as a router configuration holds it: JSON (which JSON5 reads), one rule, subject
/// or policy a line, each with its fields in the order Zenoh's documentation writes them.
#[must_use]
pub fn to_json5_text(section: &Value) -> String {
    const FIELDS: [&str; 8] = [
        "id",
        "permission",
        "flows",
        "messages",
        "key_exprs",
        "cert_common_names",
        "rules",
        "subjects",
    ];
    let json = |value: &Value| serde_json::to_string(value).unwrap_or_default();
    let line = |item: &Value| {
        let fields: Vec<String> = FIELDS
            .iter()
            .filter_map(|field| Some(format!("\"{field}\": {}", json(item.get(*field)?))))
            .collect();
        format!("{{ {} }}", fields.join(", "))
    };
    let mut members: Vec<String> = ["enabled", "default_permission"]
        .iter()
        .map(|key| format!("  \"{key}\": {}", json(&section[*key])))
        .collect();
    for key in ["rules", "subjects", "policies"] {
        let items: Vec<String> = section[key]
            .as_array()
            .into_iter()
            .flatten()
            .map(|item| format!("    {}", line(item)))
            .collect();
        members.push(format!("  \"{key}\": [\n{}\n  ]", items.join(",\n")));
    }
    format!("{{\n{}\n}}", members.join(",\n"))
}

/// The comment lines that enclose a generated section in a router configuration.
pub const BEGIN_MARK: &str = "// BEGIN access_control generated by `armtwin acl`";
/// See [`BEGIN_MARK`].
pub const END_MARK: &str = "// END access_control";

/// `config` (a router's JSON5 configuration) with the text between [`BEGIN_MARK`] and
/// [`END_MARK`] replaced by `access_control: <section>,`, indented as the begin mark is; `None`
/// when the marks are missing or out of order.
#[must_use]
pub fn replace_section(config: &str, section: &Value) -> Option<String> {
    let begin = config.find(BEGIN_MARK)?;
    let line_start = config[..begin].rfind('\n').map_or(0, |at| at + 1);
    let indent = &config[line_start..begin];
    let body_start = begin + config[begin..].find('\n')? + 1;
    let end = body_start + config[body_start..].find(END_MARK)?;
    let end_line_start = config[..end].rfind('\n').map_or(0, |at| at + 1);
    let mut text = String::new();
    for (n, line) in to_json5_text(section).lines().enumerate() {
        text.push_str(indent);
        if n == 0 {
            text.push_str("access_control: ");
        }
        text.push_str(line);
        text.push('\n');
    }
    // The closing brace takes the comma that separates the section from what follows.
    text.insert(text.len() - 1, ',');
    Some(format!(
        "{}{text}{}",
        &config[..body_start],
        &config[end_line_start..]
    ))
}

#[cfg(test)]
mod tests {
    use std::collections::HashSet;

    use super::*;

    fn rules_of(section: &Value) -> BTreeMap<String, Value> {
        section["rules"]
            .as_array()
            .expect("rules")
            .iter()
            .map(|rule| (rule["id"].as_str().expect("id").to_owned(), rule.clone()))
            .collect()
    }

    fn policy_of<'v>(section: &'v Value, subject: &str) -> Vec<&'v str> {
        section["policies"]
            .as_array()
            .expect("policies")
            .iter()
            .find(|p| p["subjects"][0] == subject)
            .expect("a policy")["rules"]
            .as_array()
            .expect("rules")
            .iter()
            .map(|r| r.as_str().expect("id"))
            .collect()
    }

    /// Whether `subject` may send (`flow`, `message`) on `key`, read the way Zenoh 1.10's
    /// access control reads a section: default deny, allowed when a rule of one of the
    /// subject's policies has the flow and message and a key expression that includes `key`.
    fn allows(section: &Value, subject: &str, flow: &str, message: &str, key: &str) -> bool {
        let rules = rules_of(section);
        let key = KeyExpr::try_from(key).expect("a key");
        policy_of(section, subject).iter().any(|id| {
            let rule = &rules[*id];
            let has = |field: &str, value: &str| {
                rule[field]
                    .as_array()
                    .expect("list")
                    .iter()
                    .any(|v| v == value)
            };
            has("flows", flow)
                && has("messages", message)
                && rule["key_exprs"].as_array().expect("keys").iter().any(|k| {
                    KeyExpr::try_from(k.as_str().expect("key"))
                        .expect("valid")
                        .includes(&key)
                })
        })
    }

    const FLEET: &str = r#"
        key_prefix = "plant/twin"
        armtwin = ["armtwin"]
        dashboards = ["dashboard", "rest"]
        operators = ["operator"]
        [gateways]
        g1 = ["r1"]
        cell-b = ["site-b/**", "r9"]
    "#;

    #[test]
    fn a_gateway_speaks_for_its_own_robots_only() {
        let section = Fleet::parse(FLEET).expect("a fleet").access_control();
        assert!(allows(
            &section,
            "gateway:g1",
            "ingress",
            "put",
            "plant/twin/joints/r1"
        ));
        assert!(allows(
            &section,
            "gateway:g1",
            "ingress",
            "put",
            "plant/twin/measured/r1"
        ));
        assert!(!allows(
            &section,
            "gateway:g1",
            "ingress",
            "put",
            "plant/twin/joints/r2"
        ));
        assert!(!allows(
            &section,
            "gateway:g1",
            "ingress",
            "put",
            "plant/twin/joints/r1/x"
        ));
        assert!(!allows(
            &section,
            "gateway:g1",
            "ingress",
            "put",
            "plant/twin/pose/r1"
        ));
        assert!(allows(
            &section,
            "gateway:g1",
            "ingress",
            "liveliness_token",
            "plant/twin/gateway/streaming/r1"
        ));
        assert!(!allows(
            &section,
            "gateway:g1",
            "ingress",
            "liveliness_token",
            "plant/twin/gateway/streaming/r2"
        ));
        assert!(allows(
            &section,
            "gateway:g1",
            "ingress",
            "query",
            "plant/twin/state/r1"
        ));
        assert!(!allows(
            &section,
            "gateway:g1",
            "ingress",
            "query",
            "plant/twin/admin/reset/r1"
        ));
        assert!(allows(
            &section,
            "gateway:g1",
            "egress",
            "declare_subscriber",
            "plant/twin/joints/**"
        ));
        // A prefix gateway: every robot under it, nothing beside it.
        assert!(allows(
            &section,
            "gateway:cell-b",
            "ingress",
            "put",
            "plant/twin/joints/site-b/ur10e"
        ));
        assert!(allows(
            &section,
            "gateway:cell-b",
            "ingress",
            "put",
            "plant/twin/joints/r9"
        ));
        assert!(!allows(
            &section,
            "gateway:cell-b",
            "ingress",
            "put",
            "plant/twin/joints/site-a/ur10e"
        ));
        assert!(!allows(
            &section,
            "gateway:cell-b",
            "ingress",
            "put",
            "plant/twin/joints/r1"
        ));
    }

    #[test]
    fn dashboards_read_operators_change_and_armtwin_publishes() {
        let section = Fleet::parse(FLEET).expect("a fleet").access_control();
        for reader in ["dashboards", "operators"] {
            assert!(allows(
                &section,
                reader,
                "ingress",
                "query",
                "plant/twin/state/r1"
            ));
            assert!(allows(
                &section,
                reader,
                "ingress",
                "declare_subscriber",
                "plant/twin/pose/**"
            ));
            assert!(allows(
                &section,
                reader,
                "egress",
                "put",
                "plant/twin/pose/r1"
            ));
            assert!(!allows(
                &section,
                reader,
                "ingress",
                "put",
                "plant/twin/joints/r1"
            ));
        }
        assert!(!allows(
            &section,
            "dashboards",
            "ingress",
            "query",
            "plant/twin/admin/reset/r1"
        ));
        assert!(!allows(
            &section,
            "dashboards",
            "ingress",
            "query",
            "plant/twin/**"
        ));
        assert!(allows(
            &section,
            "operators",
            "ingress",
            "query",
            "plant/twin/admin/reset/r1"
        ));
        assert!(allows(
            &section,
            "operators",
            "ingress",
            "query",
            "plant/twin/admin/calibrate/r1"
        ));
        assert!(allows(
            &section,
            "operators",
            "ingress",
            "query",
            "plant/twin/admin/payload/r1"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "ingress",
            "put",
            "plant/twin/pose/r1"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "ingress",
            "declare_queryable",
            "plant/twin/admin/reset/**"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "ingress",
            "liveliness_token",
            "plant/twin/alive/r1"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "ingress",
            "query",
            "plant/twin/shards/**"
        ));
        assert!(!allows(
            &section,
            "armtwin",
            "ingress",
            "put",
            "plant/twin/joints/r1"
        ));
        // Each instance reads the others' robots and hears the gateways' tokens.
        assert!(allows(
            &section,
            "armtwin",
            "ingress",
            "query",
            "plant/twin/state/**"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "egress",
            "reply",
            "plant/twin/state/site-b/r1"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "ingress",
            "declare_liveliness_subscriber",
            "plant/twin/gateway/streaming/**"
        ));
        assert!(allows(
            &section,
            "armtwin",
            "egress",
            "liveliness_token",
            "plant/twin/gateway/waiting/r1"
        ));
        assert!(!allows(
            &section,
            "armtwin",
            "ingress",
            "query",
            "plant/twin/admin/reset/r1"
        ));
        // Nothing outside the prefix.
        assert!(!allows(
            &section,
            "armtwin",
            "ingress",
            "put",
            "twin/pose/r1"
        ));
        let names: Vec<_> = section["subjects"]
            .as_array()
            .expect("subjects")
            .iter()
            .map(|s| {
                (
                    s["id"].as_str().expect("id"),
                    s["cert_common_names"].clone(),
                )
            })
            .collect();
        assert_eq!(
            names,
            [
                ("armtwin", json!(["armtwin"])),
                ("dashboards", json!(["dashboard", "rest"])),
                ("operators", json!(["operator"])),
                ("gateway:cell-b", json!(["cell-b"])),
                ("gateway:g1", json!(["g1"])),
            ]
        );
        assert_eq!(section["default_permission"], "deny");
        assert_eq!(section["enabled"], true);
    }

    #[test]
    fn every_armtwin_stream_has_a_role() {
        let covered: HashSet<Stream> = ARMTWIN_DECLARES
            .iter()
            .chain(&INPUTS)
            .chain(&GATEWAY_TOKENS)
            .copied()
            .collect();
        let all: HashSet<Stream> = Stream::ALL.into_iter().collect();
        assert_eq!(covered, all, "a new stream needs a line in this module");
        let reads: HashSet<_> = READS.iter().chain(&CHANGES).collect();
        let queryables: HashSet<_> = ARMTWIN_DECLARES[9..].iter().collect();
        assert_eq!(reads, queryables);
        assert!(CHANGES.iter().all(|s| s.as_str().starts_with("admin/")));
        assert!(READS.iter().all(|s| !s.as_str().starts_with("admin/")));
    }

    #[test]
    fn a_description_that_cannot_be_a_policy_is_refused() {
        let refused = |text: &str| Fleet::parse(text).expect_err(text);
        assert!(matches!(refused("armtwin = 1"), AclError::Syntax(_)));
        assert!(matches!(refused("visitors = [\"x\"]"), AclError::Syntax(_)));
        assert!(matches!(
            refused("key_prefix = \"a/*\"\narmtwin = [\"a\"]"),
            AclError::Prefix { .. }
        ));
        assert_eq!(refused(""), AclError::Empty);
        assert_eq!(
            refused("dashboards = [\" \"]"),
            AclError::EmptyName { role: "dashboards" }
        );
        assert_eq!(
            refused("operators = [\"x\"]\n[gateways]\nx = [\"r1\"]"),
            AclError::NameTwice {
                name: "x".to_owned(),
                first: "operators",
                second: "gateways"
            }
        );
        assert_eq!(
            refused("[gateways]\ng = []"),
            AclError::NoRobots {
                gateway: "g".to_owned()
            }
        );
        assert!(matches!(
            refused("[gateways]\ng = [\"a//b\"]"),
            AclError::Robots { .. }
        ));
        assert!(matches!(
            refused("[gateways]\ng = [\"**/**\"]"),
            AclError::Robots { .. }
        ));
        assert!(matches!(
            refused("[gateways]\ng = [\"a?b\"]"),
            AclError::Robots { .. }
        ));
    }

    #[test]
    fn prefix_grants_carry_their_robot_limits() {
        let fleet = Fleet::parse(
            "[gateways]\ng1 = [\"r1\", \"site-b/**\"]\n\
             cell-a = { robots = [\"site-a/**\", \"*/r9\"], max_robots = 20 }\n",
        )
        .expect("a fleet");
        assert_eq!(
            fleet.robot_groups(),
            [
                ("site-a/".to_owned(), 20),
                ("site-b/".to_owned(), DEFAULT_GRANT_MAX_ROBOTS)
            ]
        );
        // The table form writes the same rules as the list.
        let listed = Fleet::parse("[gateways]\ncell-a = [\"site-a/**\"]\n").expect("a fleet");
        let limited =
            Fleet::parse("[gateways]\ncell-a = { robots = [\"site-a/**\"], max_robots = 5 }\n")
                .expect("a fleet");
        assert_eq!(listed.access_control(), limited.access_control());
        assert!(
            Fleet::parse("[gateways]\ncell-a = { robots = [\"site-a/**\"], most = 5 }\n").is_err()
        );
    }

    #[test]
    fn the_shipped_router_configuration_holds_the_shipped_fleet() {
        let fleet = Fleet::parse(include_str!("../../../config/fleet.toml")).expect("a fleet");
        let shipped = include_str!("../../../config/router-tls-acl.json5");
        assert_eq!(
            replace_section(shipped, &fleet.access_control()).as_deref(),
            Some(shipped),
            "armtwin acl config/fleet.toml --update config/router-tls-acl.json5"
        );
    }

    #[test]
    fn a_section_replaces_the_one_between_its_marks() {
        let section = Fleet::parse("dashboards = [\"d\"]")
            .expect("a fleet")
            .access_control();
        let config =
            format!("{{\n  mode: \"router\",\n  {BEGIN_MARK}\n  old: 1,\n  {END_MARK}\n}}\n");
        let updated = replace_section(&config, &section).expect("marks");
        assert!(updated.starts_with(&format!(
            "{{\n  mode: \"router\",\n  {BEGIN_MARK}\n  access_control: {{\n    \"enabled\": true,"
        )));
        assert!(
            updated.ends_with(&format!("\n  }},\n  {END_MARK}\n}}\n")),
            "{updated}"
        );
        assert_eq!(
            replace_section(&updated, &section).as_deref(),
            Some(&*updated)
        );
        assert!(replace_section("{}", &section).is_none());
        assert!(replace_section(&format!("{END_MARK}\n{BEGIN_MARK}\n"), &section).is_none());
    }
}
