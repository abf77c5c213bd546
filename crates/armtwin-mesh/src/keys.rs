//! armtwin's key space on Zenoh (docs/protocol/keys.md): every key armtwin declares, puts,
//! queries or reads a robot from is built and parsed here, and nowhere else.
//!
//! Owns the grammar of a robot id and of the key prefix, the one list of armtwin's own per-robot
//! subtrees ([`Stream::ALL`]), building `<prefix>/<stream>/<robot>` and `<prefix>/shards/<zid>`,
//! reading the robot id back out of a key, and telling whether a key expression configured for
//! something else would reach into armtwin's own subtrees.
//!
//! Must not open a session, declare anything or know a payload: the service, replay, validate
//! and the benchmark decide what travels on these keys.
//!
//! **The robot-id grammar.** A robot id is a plain key of Zenoh's canonical key-expression
//! grammar: one or more non-empty chunks separated by `/`, none holding `*` or `$` (wildcards and
//! their DSL) nor `#` or `?` (forbidden in every key expression), at most
//! [`MAX_ROBOT_ID_BYTES`] bytes. That is exactly the set of wildcard-free strings
//! `zenoh::key_expr::KeyExpr` accepts, cut at the length bound, so every id a sample's key can
//! carry is one (ids with `/`, e.g. `demo/ur10e`, and ROS namespaces included). Chunks starting
//! with `@` are Zenoh's verbatim chunks: valid ids, but `**` never matches them, so such a robot
//! is reached only by a shard or query naming it.

use thiserror::Error;
use zenoh::key_expr::KeyExpr;

/// Longest robot id, in bytes (UTF-8). A robot id arrives in every sample's key, which nothing
/// else bounds: without a bound, one put could make the service keep, log and publish an id of
/// any length. 256 bytes is several times any site/cell/robot path or ROS namespace seen.
pub const MAX_ROBOT_ID_BYTES: usize = 256;

/// The key prefix unless `[service] key_prefix` sets another.
pub const DEFAULT_PREFIX: &str = "twin";

/// One of armtwin's own per-robot subtrees, `<prefix>/<stream>/<robot>`: its inputs, outputs,
/// queryables and liveliness tokens (docs/protocol/keys.md's key table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stream {
    /// Twin poses, one per valid joint sample (out).
    Pose,
    /// Deviations, one per paired measured pose (out).
    Deviation,
    /// Twin poses each with the deviation paired at its stamp, in one message, instead of
    /// [`Stream::Pose`] and [`Stream::Deviation`] (out; `[service] outputs = "paired"`).
    Paired,
    /// Running metrics (out).
    Metrics,
    /// Rejections, alarms, recoveries, gaps, unpaired measurements (out).
    Events,
    /// Self-calibration estimates (out).
    Calibration,
    /// Joint torques, model and measured, per joint sample of a robot whose effort is watched
    /// (out).
    Effort,
    /// The identified payload, each metrics period of a robot whose effort is watched (out).
    Payload,
    /// Joint samples (in).
    Joints,
    /// Measured TCP poses in the robot's `base` frame (in).
    Measured,
    /// What a gateway read of the robot's controller: its TCP, model and serial number (in;
    /// also the gateway's queryable of the latest).
    Controller,
    /// The robot's own description, a URDF (in; also a gateway's queryable of the latest).
    Description,
    /// The robot's state (queryable).
    State,
    /// The robot's per-second window statistics over the last `[recorder] history_s`
    /// (queryable, read-only).
    History,
    /// FK under the robot's model (queryable).
    Fk,
    /// Resets the robot's metrics (queryable, a change: under `admin/`, which an ACL keeps
    /// from those who only watch).
    Reset,
    /// IK under the robot's current model (queryable).
    Ik,
    /// Reports the robot's self-calibration (queryable, read-only).
    Calibrate,
    /// Applies or discards the robot's self-calibration estimate (queryable, a change: under
    /// `admin/`).
    ApplyCalibration,
    /// Applies or discards the robot's identified payload (queryable, a change: under `admin/`).
    ApplyPayload,
    /// Writes the robot's recent streams to a file (queryable, under `admin/`: it writes to the
    /// service's disk).
    Record,
    /// Present while armtwin tracks the robot (liveliness token).
    Alive,
    /// Present while a gateway (`armtwin gateway rtde`) streams the robot from its controller
    /// (liveliness token).
    GatewayStreaming,
    /// Present while a gateway for the robot is connecting or waiting to reconnect (liveliness
    /// token).
    GatewayWaiting,
}

impl Stream {
    /// Every subtree, outputs first: a key expression reaching into several is named by the
    /// first it meets here, and feeding armtwin its own outputs is the worse mistake.
    pub const ALL: [Self; 24] = [
        Self::Pose,
        Self::Deviation,
        Self::Paired,
        Self::Metrics,
        Self::Events,
        Self::Calibration,
        Self::Effort,
        Self::Payload,
        Self::Joints,
        Self::Measured,
        Self::Controller,
        Self::Description,
        Self::State,
        Self::History,
        Self::Fk,
        Self::Reset,
        Self::Ik,
        Self::Calibrate,
        Self::ApplyCalibration,
        Self::ApplyPayload,
        Self::Record,
        Self::Alive,
        Self::GatewayStreaming,
        Self::GatewayWaiting,
    ];

    /// The chunk after the prefix (`pose`, `joints`, …).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Pose => "pose",
            Self::Deviation => "deviation",
            Self::Paired => "paired",
            Self::Metrics => "metrics",
            Self::Events => "events",
            Self::Calibration => "calibration",
            Self::Effort => "effort",
            Self::Payload => "payload",
            Self::Joints => "joints",
            Self::Measured => "measured",
            Self::Controller => "controller",
            Self::Description => "description",
            Self::State => "state",
            Self::History => "history",
            Self::Fk => "fk",
            Self::Reset => "admin/reset",
            Self::Ik => "ik",
            Self::Calibrate => "calibrate",
            Self::ApplyCalibration => "admin/calibrate",
            Self::ApplyPayload => "admin/payload",
            Self::Record => "admin/record",
            Self::Alive => "alive",
            Self::GatewayStreaming => "gateway/streaming",
            Self::GatewayWaiting => "gateway/waiting",
        }
    }
}

impl Stream {
    /// Whether queries on this stream change a twin or write files (`admin/…`), rather than read.
    #[must_use]
    pub fn is_admin(self) -> bool {
        self.as_str().starts_with("admin/")
    }
}

impl std::fmt::Display for Stream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The chunk of the shard claims, `<prefix>/shards/<zenoh id>` (not per robot).
const SHARDS: &str = "shards";

/// Why a string is not a plain key (a robot id or the key prefix).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum PlainKeyError {
    /// The string is empty.
    #[error("is empty")]
    Empty,
    /// A robot id longer than [`MAX_ROBOT_ID_BYTES`].
    #[error("is {bytes} bytes long, over the {MAX_ROBOT_ID_BYTES} bytes a robot id may have")]
    TooLong {
        /// Its length in bytes.
        bytes: usize,
    },
    /// A leading, trailing or doubled `/`.
    #[error("has an empty chunk (a leading, trailing or doubled '/')")]
    EmptyChunk,
    /// A wildcard (`*`, `$`) or a character key expressions forbid (`#`, `?`).
    #[error("holds '{character}' (wildcards and '#', '?' are not part of a plain key)")]
    Reserved {
        /// The first such character.
        character: char,
    },
}

/// A key prefix given to a command that is no plain key.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("key prefix '{prefix}' {problem}")]
pub struct KeyPrefixError {
    /// The prefix given.
    pub prefix: String,
    /// What is wrong with it.
    pub problem: PlainKeyError,
}

/// Why a key names no robot of a stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum RobotKeyError {
    /// The key is not under `<prefix>/<stream>/`.
    #[error("not a <prefix>/{stream}/<robot id> key")]
    OtherStream {
        /// The stream expected.
        stream: Stream,
    },
    /// What follows `<prefix>/<stream>/` is not a robot id.
    #[error("no robot id: what follows <prefix>/{stream}/ {problem}")]
    RobotId {
        /// The stream.
        stream: Stream,
        /// What is wrong with the id.
        problem: PlainKeyError,
    },
}

/// `text` if it is a plain key: non-empty chunks separated by `/`, none holding `* $ # ?`.
/// Walks `text` once and allocates nothing.
fn plain_key(text: &str) -> Result<&str, PlainKeyError> {
    if text.is_empty() {
        return Err(PlainKeyError::Empty);
    }
    let mut previous = b'/';
    for &byte in text.as_bytes() {
        match byte {
            b'/' if previous == b'/' => return Err(PlainKeyError::EmptyChunk),
            b'*' | b'$' | b'#' | b'?' => {
                return Err(PlainKeyError::Reserved {
                    character: char::from(byte),
                });
            }
            _ => {}
        }
        previous = byte;
    }
    if previous == b'/' {
        return Err(PlainKeyError::EmptyChunk);
    }
    Ok(text)
}

/// `text` if it is a robot id (the module's grammar); the length is checked before anything
/// else is read, so an id of any length costs at most [`MAX_ROBOT_ID_BYTES`] steps.
pub fn robot_id(text: &str) -> Result<&str, PlainKeyError> {
    if text.len() > MAX_ROBOT_ID_BYTES {
        return Err(PlainKeyError::TooLong { bytes: text.len() });
    }
    plain_key(text)
}

/// armtwin's keys under one prefix. Cheap to clone.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KeySpace {
    prefix: std::sync::Arc<str>,
}

impl Default for KeySpace {
    /// The keys under [`DEFAULT_PREFIX`].
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.into(),
        }
    }
}

impl KeySpace {
    /// The keys under `prefix`, if it is a plain key (as a robot id, without the length bound:
    /// the prefix is the operator's, not a sample's).
    pub fn new(prefix: &str) -> Result<Self, PlainKeyError> {
        Ok(Self {
            prefix: plain_key(prefix)?.into(),
        })
    }

    /// [`Self::new`] for a command's `--prefix`, the error naming it.
    pub fn of_prefix(prefix: &str) -> Result<Self, KeyPrefixError> {
        Self::new(prefix).map_err(|problem| KeyPrefixError {
            prefix: prefix.to_owned(),
            problem,
        })
    }

    /// The prefix (`twin`).
    #[must_use]
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// `<prefix>/<stream>/<robots>`: one robot's key when `robots` is a robot id, or a key
    /// expression over robot ids (`**`, a shard's `site-a/**`).
    #[must_use]
    pub fn key(&self, stream: Stream, robots: &str) -> String {
        format!("{}/{stream}/{robots}", self.prefix)
    }

    /// `<prefix>/<stream>/**`: every robot's key of `stream`.
    #[must_use]
    pub fn every_robot(&self, stream: Stream) -> String {
        self.key(stream, "**")
    }

    /// `<prefix>/shards/<zid>`: the queryable an instance answers with its shard.
    #[must_use]
    pub fn shard_claim(&self, zid: &str) -> String {
        format!("{}/{SHARDS}/{zid}", self.prefix)
    }

    /// `<prefix>/**`: every key of this key space.
    #[must_use]
    pub fn everything(&self) -> String {
        format!("{}/**", self.prefix)
    }

    /// `<prefix>/shards/**`: every instance's shard claim.
    #[must_use]
    pub fn every_shard_claim(&self) -> String {
        self.shard_claim("**")
    }

    /// The robot id in `key` after `<prefix>/<stream>/`: a put or query on a key expression
    /// names no robot (it must not become one), nor does an over-long id. Borrows from `key`.
    pub fn robot_of<'k>(&self, stream: Stream, key: &'k str) -> Result<&'k str, RobotKeyError> {
        let id = key
            .strip_prefix(&*self.prefix)
            .and_then(|rest| rest.strip_prefix('/'))
            .and_then(|rest| rest.strip_prefix(stream.as_str()))
            .and_then(|rest| rest.strip_prefix('/'))
            .ok_or(RobotKeyError::OtherStream { stream })?;
        robot_id(id).map_err(|problem| RobotKeyError::RobotId { stream, problem })
    }

    /// Every subtree armtwin declares, puts, queries or reads on: each [`Stream`]'s
    /// `<prefix>/<stream>/**`, then `<prefix>/shards/**`.
    pub fn own_subtrees(&self) -> impl Iterator<Item = String> + '_ {
        Stream::ALL
            .into_iter()
            .map(|stream| self.every_robot(stream))
            .chain(std::iter::once(self.every_shard_claim()))
    }

    /// The first of armtwin's own subtrees `key` intersects, if any: a subscriber there would
    /// take armtwin's inputs twice or feed its outputs back into it (a local put is delivered in
    /// the publishing thread, which holds the robot's lock), a publisher there would speak for
    /// armtwin.
    #[must_use]
    pub fn own_subtree_of(&self, key: &KeyExpr<'_>) -> Option<String> {
        self.own_subtrees().find(|own| {
            KeyExpr::try_from(own.as_str()).is_ok_and(|own_key| key.intersects(&own_key))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn keys_are_built_under_the_prefix() {
        let keys = KeySpace::new("site/twin").expect("a plain key");
        assert_eq!(
            keys.key(Stream::Joints, "demo/ur10e"),
            "site/twin/joints/demo/ur10e"
        );
        assert_eq!(keys.every_robot(Stream::Pose), "site/twin/pose/**");
        assert_eq!(keys.shard_claim("a1b2"), "site/twin/shards/a1b2");
        assert_eq!(keys.every_shard_claim(), "site/twin/shards/**");
        assert_eq!(KeySpace::default().prefix(), "twin");
        let streams: Vec<&str> = Stream::ALL.iter().map(|s| s.as_str()).collect();
        assert_eq!(
            streams,
            [
                "pose",
                "deviation",
                "paired",
                "metrics",
                "events",
                "calibration",
                "effort",
                "payload",
                "joints",
                "measured",
                "controller",
                "description",
                "state",
                "history",
                "fk",
                "admin/reset",
                "ik",
                "calibrate",
                "admin/calibrate",
                "admin/payload",
                "admin/record",
                "alive",
                "gateway/streaming",
                "gateway/waiting"
            ]
        );
    }

    #[test]
    fn the_robot_id_is_read_back_from_its_key_only() {
        let keys = KeySpace::default();
        for id in [
            "r1",
            "demo/ur10e",
            "plant-a/cell-3/ur10e-07",
            "ur_ns/arm_1",
            "@verbatim/r",
        ] {
            assert_eq!(
                keys.robot_of(Stream::Joints, &keys.key(Stream::Joints, id)),
                Ok(id)
            );
        }
        let other = Err(RobotKeyError::OtherStream {
            stream: Stream::Joints,
        });
        for key in [
            "twin/pose/r1",
            "twin/joints",
            "twins/joints/r1",
            "other/joints/r1",
        ] {
            assert_eq!(keys.robot_of(Stream::Joints, key), other, "{key}");
        }
        assert_eq!(
            keys.robot_of(Stream::Joints, "twin/joints/"),
            Err(RobotKeyError::RobotId {
                stream: Stream::Joints,
                problem: PlainKeyError::Empty
            })
        );
        assert!(matches!(
            keys.robot_of(Stream::State, "twin/state/**"),
            Err(RobotKeyError::RobotId {
                problem: PlainKeyError::Reserved { character: '*' },
                ..
            })
        ));
        let long = format!("twin/joints/{}", "r".repeat(MAX_ROBOT_ID_BYTES + 1));
        let error = keys.robot_of(Stream::Joints, &long).expect_err("too long");
        assert_eq!(
            error.to_string(),
            "no robot id: what follows <prefix>/joints/ is 257 bytes long, over the 256 bytes a \
             robot id may have"
        );
    }

    #[test]
    fn the_grammar_refuses_wildcards_reserved_characters_empty_chunks_and_length() {
        for (id, problem) in [
            ("", PlainKeyError::Empty),
            ("/r1", PlainKeyError::EmptyChunk),
            ("r1/", PlainKeyError::EmptyChunk),
            ("a//b", PlainKeyError::EmptyChunk),
            ("/", PlainKeyError::EmptyChunk),
            ("a/*", PlainKeyError::Reserved { character: '*' }),
            ("a/$*b", PlainKeyError::Reserved { character: '$' }),
            ("a#1", PlainKeyError::Reserved { character: '#' }),
            ("a?x=1", PlainKeyError::Reserved { character: '?' }),
        ] {
            assert_eq!(robot_id(id), Err(problem), "{id:?}");
        }
        assert_eq!(
            robot_id(&"r".repeat(MAX_ROBOT_ID_BYTES)).map(str::len),
            Ok(MAX_ROBOT_ID_BYTES)
        );
        assert_eq!(
            robot_id(&"r".repeat(MAX_ROBOT_ID_BYTES + 1)),
            Err(PlainKeyError::TooLong {
                bytes: MAX_ROBOT_ID_BYTES + 1
            })
        );
        // The prefix follows the grammar without the bound.
        assert!(KeySpace::new(&"p".repeat(2 * MAX_ROBOT_ID_BYTES)).is_ok());
        assert_eq!(KeySpace::new("twin/"), Err(PlainKeyError::EmptyChunk));
    }

    #[test]
    fn a_key_expression_reaching_into_armtwins_subtrees_is_named() {
        let keys = KeySpace::default();
        let own = |text: &str| keys.own_subtree_of(&KeyExpr::try_from(text).expect("valid"));
        assert_eq!(own("twin/**").as_deref(), Some("twin/pose/**"));
        assert_eq!(own("twin/joints/**").as_deref(), Some("twin/joints/**"));
        assert_eq!(
            own("twin/calibration/r1").as_deref(),
            Some("twin/calibration/**")
        );
        assert_eq!(own("*/shards/z1").as_deref(), Some("twin/shards/**"));
        assert_eq!(own("lab/r7/pose"), None);
        assert_eq!(own("twin"), None);
    }

    /// One chunk of a robot id: any characters but `/` and the four the grammar refuses.
    fn chunk() -> impl Strategy<Value = String> {
        "[^/*$#?]{1,12}"
    }

    proptest! {
        /// Exactly the wildcard-free keys Zenoh accepts, up to the bound, are robot ids.
        #[test]
        fn robot_ids_are_zenohs_plain_keys(text in "[a-z/*$#?@ é-]{0,24}") {
            let zenoh_plain = KeyExpr::try_from(text.as_str()).is_ok() && !text.contains(['*', '$']);
            prop_assert_eq!(robot_id(&text).is_ok(), zenoh_plain, "{:?}", text);
        }

        /// Every id of valid chunks within the bound is accepted, round-trips through its key
        /// and is refused beyond the bound.
        #[test]
        fn ids_of_chunks_round_trip(chunks in prop::collection::vec(chunk(), 1..40)) {
            let id = chunks.join("/");
            let keys = KeySpace::default();
            let key = keys.key(Stream::Measured, &id);
            if id.len() <= MAX_ROBOT_ID_BYTES {
                prop_assert_eq!(keys.robot_of(Stream::Measured, &key), Ok(id.as_str()));
                prop_assert!(KeyExpr::try_from(key.as_str()).is_ok());
            } else {
                prop_assert_eq!(
                    robot_id(&id),
                    Err(PlainKeyError::TooLong { bytes: id.len() })
                );
            }
        }
    }
}
