//! `armtwin record`'s messages and files: a live message on one of a robot's keys decoded
//! ([`decode`]) into a [`LiveMessage`], and a robot's messages written in arrival order to its
//! MCAP file ([`LiveFile`]), with the channels, schemas and CDR of an incident file.
//!
//! Pure: bytes in, MCAP bytes out through any writer. Must not know the network (the caller reads
//! the keys and the encodings) or where the file goes.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use serde::Deserialize;

use super::mcap_file::{McapFile, PoseTopic, WriteError, joint_names, pose_of};
use armtwin_codec::gateway::Codec;
use armtwin_codec::json::WireError;
use armtwin_codec::zser::{DEVIATION_BYTES, TWIN_POSE_BYTES};
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::sample::{JointQuantity, JointSample};

/// The frame of a robot's joints and measured poses (`…/measured/<robot>` is in the robot's
/// `base` frame), as the UR driver's topics name it.
const BASE_FRAME: &str = "base";

/// The streams `armtwin record` takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum LiveStream {
    /// `<prefix>/joints/<robot>`, with the measured pose a gateway embeds.
    Joints,
    /// `<prefix>/measured/<robot>`.
    Measured,
    /// `<prefix>/pose/<robot>`: the twin pose, when a service publishes it.
    TwinPose,
    /// `<prefix>/deviation/<robot>`: the same.
    Deviation,
}

/// A decoded live message, stamped with its source time.
#[derive(Debug, Clone, PartialEq)]
pub enum LiveMessage {
    /// A joint sample (its `measured` the embedded pose, if valid).
    Joints {
        /// Source time (s).
        stamp_s: f64,
        /// The sample.
        sample: Box<JointSample>,
    },
    /// A measured pose in the robot's `base` frame.
    Measured {
        /// Source time (s).
        stamp_s: f64,
        /// The pose (normalised by the decoder).
        pose: PoseReadout,
    },
    /// A twin pose.
    TwinPose {
        /// Source time (s).
        stamp_s: f64,
        /// Its frame (`base`, `base_link`).
        frame_id: String,
        /// The pose, as published.
        pose: PoseReadout,
    },
    /// A deviation: its nine values in `armtwin_msgs/msg/Deviation`'s order.
    Deviation {
        /// Source time (s).
        stamp_s: f64,
        /// `dx_m, dy_m, dz_m, position_m, quat_distance, angle_rad, droll_rad, dpitch_rad,
        /// dyaw_rad`.
        values: [f64; 9],
    },
}

impl LiveMessage {
    /// Its source time (s).
    #[must_use]
    pub fn stamp_s(&self) -> f64 {
        match self {
            Self::Joints { stamp_s, .. }
            | Self::Measured { stamp_s, .. }
            | Self::TwinPose { stamp_s, .. }
            | Self::Deviation { stamp_s, .. } => *stamp_s,
        }
    }
}

/// Why a live message was not taken.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// A gateway message armtwin's decoder refuses.
    #[error(transparent)]
    Input(#[from] WireError),
    /// A twin pose or deviation that is not armtwin's JSON.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A binary twin pose or deviation of another length than its schema's.
    #[error("{schema}: {got} bytes, expected {expected}")]
    Binary {
        /// The schema the key takes.
        schema: &'static str,
        /// The message's length.
        got: usize,
        /// The schema's.
        expected: usize,
    },
    /// A stamp that is not a finite number.
    #[error("stamp {0} is not finite")]
    Stamp(f64),
}

/// The twin pose's JSON fields that go into the file.
#[derive(Deserialize)]
struct TwinPoseJson {
    t: f64,
    #[serde(default)]
    frame: Option<String>,
    x: f64,
    y: f64,
    z: f64,
    qx: f64,
    qy: f64,
    qz: f64,
    qw: f64,
}

/// The deviation's JSON fields.
#[derive(Deserialize)]
struct DeviationJson {
    t: f64,
    dx: f64,
    dy: f64,
    dz: f64,
    position: f64,
    quat_distance: f64,
    angle: f64,
    droll: f64,
    dpitch: f64,
    dyaw: f64,
}

/// Decodes a message of `stream` in `codec` (its sample's encoding) for an arm of `joint_count`
/// joints. A gateway message without a stamp takes `fallback_s` (the transport's), as the
/// service would.
pub fn decode(
    stream: LiveStream,
    codec: Codec,
    payload: &[u8],
    joint_count: usize,
    fallback_s: f64,
) -> Result<LiveMessage, DecodeError> {
    let message = match stream {
        LiveStream::Joints => {
            let mut sample = codec
                .read_joints(payload, joint_count)
                .map_err(|refused| refused.error)?
                .sample;
            if let Some(pose) = &mut sample.measured {
                keep_as_sent(
                    pose,
                    quaternion_as_sent(stream, codec, payload, joint_count),
                );
            }
            LiveMessage::Joints {
                stamp_s: sample.stamp_s.unwrap_or(fallback_s),
                sample: Box::new(sample),
            }
        }
        LiveStream::Measured => {
            let mut measured = codec
                .read_measured(payload)
                .map_err(|refused| refused.error)?;
            let as_sent = quaternion_as_sent(stream, codec, payload, joint_count);
            keep_as_sent(&mut measured.pose, as_sent);
            LiveMessage::Measured {
                stamp_s: measured.stamp_s.unwrap_or(fallback_s),
                pose: measured.pose,
            }
        }
        LiveStream::TwinPose => twin_pose(codec, payload)?,
        LiveStream::Deviation => deviation(codec, payload)?,
    };
    let stamp_s = message.stamp_s();
    if stamp_s.is_finite() {
        Ok(message)
    } else {
        Err(DecodeError::Stamp(stamp_s))
    }
}

/// A measured quaternion's components as the gateway sent them (JSON).
#[derive(Deserialize)]
struct QuaternionJson {
    qx: f64,
    qy: f64,
    qz: f64,
    qw: f64,
}

/// A joint message's embedded measured pose, its quaternion as sent (JSON).
#[derive(Deserialize)]
struct EmbeddedJson {
    measured: QuaternionJson,
}

/// The quaternion of a decoded measured pose (its own message's, or embedded in a joint
/// message) as the gateway sent it, when it sent one: the decoder normalises it, and a reader of
/// the file (`validate`, `replay`) normalises what it reads, so the file keeps what came in and
/// a reader computes what the twin computed. `None` for another orientation form (the decoded
/// quaternion is then kept).
fn quaternion_as_sent(
    stream: LiveStream,
    codec: Codec,
    payload: &[u8],
    joint_count: usize,
) -> Option<[f64; 4]> {
    let from = |q: QuaternionJson| [q.qx, q.qy, q.qz, q.qw];
    match (codec, stream) {
        (Codec::Json, LiveStream::Joints) => serde_json::from_slice::<EmbeddedJson>(payload)
            .ok()
            .map(|m| from(m.measured)),
        (Codec::Json, _) => serde_json::from_slice::<QuaternionJson>(payload)
            .ok()
            .map(from),
        // `(t, q: seq, seq: u64, measured: seq)` and `(t, pose: seq)`, each sequence's length one
        // byte (LEB128 below 128), the framing already checked by the decoder.
        (Codec::ZenohSerialized(_), stream) => {
            let at = match stream {
                LiveStream::Joints => 8 + 1 + 8 * joint_count + 8 + 1 + 24,
                _ => 8 + 1 + 24,
            };
            let fits = joint_count < 128 && payload.len() >= at + 32;
            fits.then(|| std::array::from_fn(|i| f64_at(payload, at + 8 * i)))
        }
    }
}

/// `pose`'s quaternion replaced by the one sent, if it is the same rotation (a check that the
/// bytes read are the ones the decoder read).
fn keep_as_sent(pose: &mut PoseReadout, as_sent: Option<[f64; 4]>) {
    let Some(xyzw) = as_sent else {
        return;
    };
    let norm = xyzw.iter().map(|c| c * c).sum::<f64>().sqrt();
    let dot: f64 = xyzw
        .iter()
        .zip(&pose.quaternion_xyzw)
        .map(|(a, b)| a * b)
        .sum();
    // Normalised, the two agree to rounding (or one is the other's negation).
    if norm.is_finite() && norm > 0.0 && (dot.abs() / norm - 1.0).abs() < 1e-9 {
        pose.quaternion_xyzw = xyzw;
    }
}

/// The `n`th little-endian `f64` of `bytes` from `at` (the length checked by the caller).
fn f64_at(bytes: &[u8], at: usize) -> f64 {
    let mut word = [0; 8];
    word.copy_from_slice(&bytes[at..at + 8]);
    f64::from_le_bytes(word)
}

/// `armtwin/twin-pose/v1` (`t`, `seq`, then 10 values: `x, y, z, roll, pitch, yaw, qx, qy, qz,
/// qw`) or the JSON twin pose.
fn twin_pose(codec: Codec, payload: &[u8]) -> Result<LiveMessage, DecodeError> {
    if let Codec::ZenohSerialized(_) = codec {
        if payload.len() != TWIN_POSE_BYTES || payload[16] != 10 {
            return Err(DecodeError::Binary {
                schema: armtwin_codec::zser::TWIN_POSE_SCHEMA,
                got: payload.len(),
                expected: TWIN_POSE_BYTES,
            });
        }
        let value = |i: usize| f64_at(payload, 17 + 8 * i);
        return Ok(LiveMessage::TwinPose {
            stamp_s: f64_at(payload, 0),
            frame_id: BASE_FRAME.to_owned(),
            pose: pose_of(&[
                value(0),
                value(1),
                value(2),
                value(6),
                value(7),
                value(8),
                value(9),
            ]),
        });
    }
    let pose: TwinPoseJson = serde_json::from_slice(payload)?;
    Ok(LiveMessage::TwinPose {
        stamp_s: pose.t,
        frame_id: pose.frame.unwrap_or_else(|| BASE_FRAME.to_owned()),
        pose: pose_of(&[pose.x, pose.y, pose.z, pose.qx, pose.qy, pose.qz, pose.qw]),
    })
}

/// `armtwin/deviation/v1` (`t`, then 9 values in the message's order) or the JSON deviation.
fn deviation(codec: Codec, payload: &[u8]) -> Result<LiveMessage, DecodeError> {
    if let Codec::ZenohSerialized(_) = codec {
        if payload.len() != DEVIATION_BYTES || payload[8] != 9 {
            return Err(DecodeError::Binary {
                schema: armtwin_codec::zser::DEVIATION_SCHEMA,
                got: payload.len(),
                expected: DEVIATION_BYTES,
            });
        }
        return Ok(LiveMessage::Deviation {
            stamp_s: f64_at(payload, 0),
            values: std::array::from_fn(|i| f64_at(payload, 9 + 8 * i)),
        });
    }
    let d: DeviationJson = serde_json::from_slice(payload)?;
    Ok(LiveMessage::Deviation {
        stamp_s: d.t,
        values: [
            d.dx,
            d.dy,
            d.dz,
            d.position,
            d.quat_distance,
            d.angle,
            d.droll,
            d.dpitch,
            d.dyaw,
        ],
    })
}

/// Messages of one robot's file, by stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveCounts {
    /// Joint samples (`/joint_states`).
    pub joints: u64,
    /// Measured poses (`/tcp_pose_broadcaster/pose`), embedded ones included.
    pub measured: u64,
    /// Twin poses (`/twin/pose`).
    pub twin_poses: u64,
    /// Deviations (`/twin/deviation`).
    pub deviations: u64,
}

/// One robot's recording being written.
pub struct LiveFile<W: Write + Seek> {
    file: McapFile<W>,
    robot: String,
    joint_count: usize,
    joint_names: Vec<String>,
    /// The twin poses' frame, for the deviations (`base` until a twin pose says otherwise).
    twin_frame: String,
    span_s: Option<(f64, f64)>,
    counts: LiveCounts,
}

impl<W: Write + Seek> LiveFile<W> {
    /// Starts `robot`'s file, of an arm of `joint_count` joints, on `out`.
    pub fn create(out: W, robot: &str, joint_count: usize) -> Result<Self, WriteError> {
        Ok(Self {
            file: McapFile::create(out, false)?,
            robot: robot.to_owned(),
            joint_count,
            joint_names: joint_names(joint_count),
            twin_frame: BASE_FRAME.to_owned(),
            span_s: None,
            counts: LiveCounts::default(),
        })
    }

    /// What was written so far.
    #[must_use]
    pub fn counts(&self) -> LiveCounts {
        self.counts
    }

    /// Writes `message`: a joint sample as a `JointState` (and its embedded measured pose), a
    /// pose as a `PoseStamped`, a deviation as armtwin's message, each stamped with its source
    /// time.
    pub fn write(&mut self, message: &LiveMessage) -> Result<(), WriteError> {
        let stamp_s = message.stamp_s();
        match message {
            LiveMessage::Joints { sample, .. } => {
                let n = self.joint_count;
                let state = sample.state.as_deref();
                let part = |quantity| {
                    state
                        .and_then(|s| s.get(quantity))
                        .filter(|values| values.len() == n)
                        .unwrap_or(&[])
                };
                self.file.joint_state(
                    stamp_s,
                    BASE_FRAME,
                    &self.joint_names,
                    &sample.q_rad[..n],
                    part(JointQuantity::Velocity),
                    part(JointQuantity::Torque),
                )?;
                self.counts.joints += 1;
                if let Some(measured) = &sample.measured {
                    self.file
                        .pose(PoseTopic::Measured, stamp_s, BASE_FRAME, measured)?;
                    self.counts.measured += 1;
                }
            }
            LiveMessage::Measured { pose, .. } => {
                self.file
                    .pose(PoseTopic::Measured, stamp_s, BASE_FRAME, pose)?;
                self.counts.measured += 1;
            }
            LiveMessage::TwinPose { frame_id, pose, .. } => {
                self.file.pose(PoseTopic::Twin, stamp_s, frame_id, pose)?;
                if *frame_id != self.twin_frame {
                    self.twin_frame.clone_from(frame_id);
                }
                self.counts.twin_poses += 1;
            }
            LiveMessage::Deviation { values, .. } => {
                self.file.deviation(stamp_s, &self.twin_frame, values)?;
                self.counts.deviations += 1;
            }
        }
        self.span_s = Some(self.span_s.map_or((stamp_s, stamp_s), |(from_s, until_s)| {
            (from_s.min(stamp_s), until_s.max(stamp_s))
        }));
        Ok(())
    }

    /// Writes the metadata record (robot, version, `trigger` = `record`, the span of source
    /// time) and ends the file; the messages written.
    pub fn finish(self) -> Result<u64, WriteError> {
        let (from_s, until_s) = self.span_s.unwrap_or((f64::NAN, f64::NAN));
        let metadata: BTreeMap<String, String> = [
            ("robot", self.robot),
            ("armtwin_version", env!("CARGO_PKG_VERSION").to_owned()),
            ("trigger", "record".to_owned()),
            ("from_s", from_s.to_string()),
            ("until_s", until_s.to_string()),
            ("frame_id", BASE_FRAME.to_owned()),
            ("joint_count", self.joint_count.to_string()),
        ]
        .into_iter()
        .map(|(key, value)| (key.to_owned(), value))
        .collect();
        self.file.finish(metadata)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::float_cmp, reason = "values are copied, not computed")]
    use std::io::Cursor;

    use super::{DecodeError, LiveFile, LiveStream, decode};
    use crate::mcap_file::{METADATA_NAME, topics};
    use armtwin_codec::cdr::{self, JointNames};
    use armtwin_codec::gateway::Codec;
    use armtwin_codec::zser;

    const STAMP_S: f64 = 1_748_954_669.123_456_7;

    fn joints_json(stamp_s: f64) -> Vec<u8> {
        format!(
            r#"{{"t": {stamp_s}, "q": [-0.693, -0.833, 0.951, 1.149, 1.515, 1e-17],
                 "measured": {{"x": -0.807, "y": 0.436, "z": 0.42,
                               "qx": -0.408, "qy": -0.9, "qz": -0.014, "qw": 0.152}}}}"#
        )
        .into_bytes()
    }

    /// Writes the messages of `inputs` to an MCAP file in memory and reads it back: the file's
    /// bytes and its messages by topic.
    fn round_trip(inputs: &[(LiveStream, Codec, Vec<u8>)]) -> (Vec<u8>, u64) {
        let mut out = Cursor::new(Vec::new());
        let mut file = LiveFile::create(&mut out, "cell-1/r1", 6).expect("starts");
        for (stream, codec, payload) in inputs {
            let message = decode(*stream, *codec, payload, 6, 0.0).expect("decodes");
            file.write(&message).expect("writes");
        }
        let written = file.finish().expect("ends");
        (out.into_inner(), written)
    }

    #[test]
    fn joints_and_their_embedded_pose_read_back_bit_for_bit_with_their_stamps() {
        let (bytes, written) = round_trip(&[
            (LiveStream::Joints, Codec::Json, joints_json(STAMP_S)),
            (
                LiveStream::Joints,
                Codec::Json,
                joints_json(STAMP_S + 0.002),
            ),
        ]);
        assert_eq!(written, 4);
        let names = JointNames::ur("");
        let mut joints = Vec::new();
        let mut poses = Vec::new();
        for message in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
            let message = message.expect("reads");
            assert_eq!(message.channel.message_encoding, "cdr");
            match message.channel.topic.as_str() {
                topics::JOINT_STATES => {
                    let sample =
                        cdr::decode_joint_state(&message.data, &names, None).expect("a JointState");
                    assert_eq!(
                        message.log_time,
                        crate::ros2_messages::stamp_ns(sample.stamp_s.unwrap())
                    );
                    joints.push(sample);
                }
                topics::MEASURED_POSE => {
                    poses.push(
                        cdr::decode_pose_stamped(&message.data)
                            .expect("a PoseStamped")
                            .sample,
                    );
                }
                other => panic!("unexpected topic {other}"),
            }
        }
        assert_eq!(joints.len(), 2);
        assert_eq!(joints[0].stamp_s, Some(STAMP_S));
        assert_eq!(joints[1].stamp_s, Some(STAMP_S + 0.002));
        assert_eq!(
            joints[0].q_rad[..],
            [-0.693, -0.833, 0.951, 1.149, 1.515, 1e-17]
        );
        assert_eq!(poses.len(), 2);
        let summary = mcap::Summary::read(&bytes)
            .expect("reads")
            .expect("has a summary");
        assert_eq!(summary.channels.len(), 6);
        let metadata = mcap::read::metadata(&bytes, &summary.metadata_indexes[0]).expect("reads");
        assert_eq!(metadata.name, METADATA_NAME);
        assert_eq!(metadata.metadata["robot"], "cell-1/r1");
        assert_eq!(metadata.metadata["trigger"], "record");
        assert_eq!(metadata.metadata["from_s"], STAMP_S.to_string());
        assert_eq!(metadata.metadata["until_s"], (STAMP_S + 0.002).to_string());
    }

    #[test]
    fn a_binary_measured_quaternion_is_kept_as_sent() {
        let measured = [0.5, 0.25, 0.125, -0.408, -0.9, -0.014, 0.152];
        let q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6];
        let payload = zser::joints_bytes(STAMP_S, &q, 7, Some(&measured));
        let message = decode(
            LiveStream::Joints,
            Codec::ZenohSerialized(Some(zser::Schema::Joints)),
            &payload,
            6,
            0.0,
        )
        .expect("decodes");
        let super::LiveMessage::Joints { sample, .. } = message else {
            panic!("a joint message");
        };
        let pose = sample.measured.expect("its measured pose");
        assert_eq!(pose.position_m, [0.5, 0.25, 0.125]);
        assert_eq!(pose.quaternion_xyzw, [-0.408, -0.9, -0.014, 0.152]);
    }

    #[test]
    fn twin_poses_and_deviations_in_json_and_binary_read_back_as_published() {
        let pose = armtwin_codec::PoseFields {
            x: 0.1,
            y: 0.2,
            z: 0.3,
            roll: 0.0,
            pitch: 0.0,
            yaw: 0.0,
            qx: 0.0,
            qy: 0.0,
            qz: 0.0,
            qw: 1.0,
        };
        let deviation = armtwin_core::metrics::Deviation {
            dx_m: 1e-3,
            dy_m: -2e-3,
            dz_m: 0.0,
            position_m: 2.2e-3,
            quat_distance: 1e-9,
            angle_rad: 1e-4,
            droll_rad: 0.0,
            dpitch_rad: 0.0,
            dyaw_rad: 1e-4,
        };
        let binary = Codec::ZenohSerialized(None);
        let (bytes, written) = round_trip(&[
            (
                LiveStream::TwinPose,
                binary,
                zser::twin_pose_bytes(STAMP_S, 1, &pose).to_vec(),
            ),
            (
                LiveStream::TwinPose,
                Codec::Json,
                armtwin_codec::json::pose_json_bytes("r1", STAMP_S + 1.0, 2, "base_link", &pose),
            ),
            (
                LiveStream::Deviation,
                binary,
                zser::deviation_bytes(STAMP_S, &deviation).to_vec(),
            ),
            (
                LiveStream::Deviation,
                Codec::Json,
                armtwin_codec::json::deviation_json_bytes("r1", STAMP_S + 1.0, &deviation),
            ),
        ]);
        assert_eq!(written, 4);
        let mut frames = Vec::new();
        for message in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
            let message = message.expect("reads");
            if message.channel.topic == topics::TWIN_POSE {
                let decoded = cdr::decode_pose_stamped(&message.data).expect("a PoseStamped");
                assert_eq!(decoded.sample.pose.position_m, [0.1, 0.2, 0.3]);
                frames.push(decoded.frame_id.to_owned());
            } else {
                assert_eq!(message.channel.topic, topics::DEVIATION);
                // The body: stamp (8), "base_link\0" (4 + 10) padded to 24, then dx_m….
                assert_eq!(message.data.len(), 4 + 24 + 9 * 8);
                let dx_m = f64::from_le_bytes(message.data[28..36].try_into().expect("8 bytes"));
                assert_eq!(dx_m, 1e-3);
            }
        }
        assert_eq!(frames, ["base", "base_link"]);
    }

    #[test]
    fn a_malformed_message_is_an_error_not_a_panic() {
        let short = vec![0_u8; 12];
        for (stream, codec, payload) in [
            (
                LiveStream::Joints,
                Codec::Json,
                b"{\"t\": 1, \"q\": [0]}".to_vec(),
            ),
            (LiveStream::Measured, Codec::Json, b"not json".to_vec()),
            (
                LiveStream::TwinPose,
                Codec::ZenohSerialized(None),
                short.clone(),
            ),
            (LiveStream::Deviation, Codec::ZenohSerialized(None), short),
            (LiveStream::Deviation, Codec::Json, b"{\"t\": 1}".to_vec()),
        ] {
            assert!(
                decode(stream, codec, &payload, 6, 0.0).is_err(),
                "{stream:?}"
            );
        }
        let no_stamp = br#"{"q": [0, 0, 0, 0, 0, 0]}"#;
        let message = decode(LiveStream::Joints, Codec::Json, no_stamp, 6, 42.5).expect("takes");
        assert_eq!(message.stamp_s(), 42.5);
        let infinite = decode(LiveStream::Joints, Codec::Json, no_stamp, 6, f64::INFINITY);
        assert!(matches!(infinite, Err(DecodeError::Stamp(_))));
    }
}
