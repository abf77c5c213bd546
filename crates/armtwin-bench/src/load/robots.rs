//! The robots' side of the wire: each robot's publishers and the reply keys declared for it,
//! on its gateway's session, and one sample put in the chosen format.

use std::thread;
use std::time::{Duration, Instant};

use armtwin_codec::zser;
use armtwin_mesh::keys::Stream;
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;

use super::{Load, LoadError, Target, WireEncoding};
use crate::net;
use crate::workload::Workload;

/// How long to wait for the system under test to subscribe.
const MATCH_TIMEOUT: Duration = Duration::from_secs(30);

/// One robot's publishers and the reply keys it declared.
pub(super) struct RobotKeys {
    pub(super) joints: Publisher<'static>,
    pub(super) measured: Publisher<'static>,
    /// Undeclared when the robot leaves a soak (churn).
    pub(super) replies: Vec<KeyExpr<'static>>,
    /// Samples sent so far (which joint configuration comes next).
    pub(super) next_seq: u64,
    /// The next gateway `seq` of a binary message.
    pub(super) gateway_seq: u64,
    /// The last stamp sent (stamps increase strictly per robot).
    pub(super) last_t_s: f64,
}

/// How a sample goes out: its payloads and their format.
pub(super) struct Outgoing<'a> {
    pub(super) workload: &'a Workload,
    pub(super) encoding: WireEncoding,
    pub(super) embedded: bool,
}

impl Outgoing<'_> {
    /// Puts one sample of the robot of `keys`, stamped `now_s` (or just after its last stamp).
    pub(super) fn put(&self, keys: &mut RobotKeys, now_s: f64) -> Result<(), LoadError> {
        let stamp_s = if now_s > keys.last_t_s {
            now_s
        } else {
            keys.last_t_s + 1e-9
        };
        keys.last_t_s = stamp_s;
        let seq = keys.next_seq;
        keys.next_seq += 1;
        if self.encoding == WireEncoding::ZenohSerialized {
            let gateway_seq = keys.gateway_seq;
            keys.gateway_seq += 1;
            keys.joints
                .put(
                    self.workload
                        .joints_zser(seq, stamp_s, gateway_seq, self.embedded),
                )
                .wait()?;
            if !self.embedded {
                keys.measured
                    .put(self.workload.measured_zser(seq, stamp_s))
                    .wait()?;
            }
        } else if self.embedded {
            keys.joints
                .put(self.workload.joints_with_measured(seq, stamp_s))
                .wait()?;
        } else {
            keys.joints.put(self.workload.joints(seq, stamp_s)).wait()?;
            keys.measured
                .put(self.workload.measured(seq, stamp_s))
                .wait()?;
        }
        Ok(())
    }
}

impl Load {
    /// Declares publishers and reply keys of robots up to (not including) `count`. The memory
    /// measurement declares no reply keys: it receives a few replies per robot, and the system
    /// under test should not hold our declarations for it.
    pub(super) fn declare_robots(&mut self, count: usize) -> Result<(), LoadError> {
        for index in self.robots.len()..count {
            let keys = self.declare_robot(index)?;
            self.robots.push(keys);
        }
        Ok(())
    }

    /// The publishers and reply keys of robot `index`, on gateway session `index % gateways`.
    pub(super) fn declare_robot(&self, index: usize) -> Result<RobotKeys, LoadError> {
        let paired = self.args.paired;
        let reply_streams: &[Stream] = match (self.args.target, self.args.memory_base_robots) {
            (_, Some(_)) => &[],
            (Target::Echo, None) if paired => &[net::PAIRED],
            (Target::Echo, None) => &[net::POSE, net::DEVIATION],
            (Target::Armtwin, None) if paired => &[net::PAIRED, net::METRICS, net::EVENTS],
            (Target::Armtwin, None) => &[net::POSE, net::DEVIATION, net::METRICS, net::EVENTS],
        };
        let robot = net::robot_id(index);
        let gateway = index % (self.senders.len() + 1);
        let sender = match gateway {
            0 => &self.session,
            n => &self.senders[n - 1],
        };
        let binary = self.args.encoding == WireEncoding::ZenohSerialized;
        let publisher = |stream: Stream, schema: &str| {
            let encoding = if binary {
                Encoding::ZENOH_SERIALIZED.with_schema(schema)
            } else {
                Encoding::APPLICATION_JSON
            };
            sender
                .declare_publisher(net::key(stream, &robot))
                .congestion_control(CongestionControl::Block)
                .encoding(encoding)
                .wait()
        };
        let joints = publisher(net::JOINTS, zser::JOINTS_SCHEMA)?;
        let measured = publisher(net::MEASURED, zser::POSE_SCHEMA)?;
        let replies = reply_streams
            .iter()
            .map(|&stream| {
                self.session
                    .declare_keyexpr(net::key(stream, &robot))
                    .wait()
            })
            .collect::<Result<_, _>>()?;
        Ok(RobotKeys {
            joints,
            measured,
            replies,
            next_seq: 0,
            gateway_seq: self.seq_start.get(index).copied().unwrap_or(0),
            last_t_s: f64::NEG_INFINITY,
        })
    }

    /// Waits until the system under test subscribes to both input streams, on every gateway's
    /// session (each one's first robot).
    pub(super) fn wait_for_subscriber(&self) -> Result<(), LoadError> {
        let deadline = Instant::now() + MATCH_TIMEOUT;
        if self.robots.is_empty() {
            return Err(LoadError::NoAnswer("no robots".to_owned()));
        }
        let firsts = &self.robots[..self.robots.len().min(self.senders.len() + 1)];
        for publisher in firsts
            .iter()
            .flat_map(|keys| [&keys.joints, &keys.measured])
        {
            while !publisher.matching_status().wait()?.matching() {
                if Instant::now() >= deadline {
                    return Err(LoadError::NoAnswer(format!(
                        "nobody subscribes to {} after {} s",
                        publisher.key_expr(),
                        MATCH_TIMEOUT.as_secs()
                    )));
                }
                thread::sleep(Duration::from_millis(20));
            }
        }
        // The subscriber's declaration and ours cross on the link; let ours land too.
        thread::sleep(Duration::from_millis(200));
        Ok(())
    }

    /// Sends one sample of `robot`: a joint and a measured message with the same stamp, or one
    /// joint message with the measured pose embedded.
    pub(super) fn send(&mut self, robot: usize) -> Result<(), LoadError> {
        self.send_stamped(robot, self.replies.now_s())
    }

    /// [`Load::send`] stamped `stamp_s` (or just after the robot's last stamp).
    pub(super) fn send_stamped(&mut self, robot: usize, stamp_s: f64) -> Result<(), LoadError> {
        let outgoing = Outgoing {
            workload: &self.workload,
            encoding: self.args.encoding,
            embedded: self.embedded,
        };
        outgoing.put(&mut self.robots[robot], stamp_s)
    }

    /// Deviations expected per sample: one, except from the echo when the measured pose is
    /// embedded in the joint message (it returns that one message on `pose`); a paired reply
    /// stands for both.
    pub(super) fn deviations_per_sample(&self) -> u64 {
        u64::from(self.args.paired || !(self.embedded && self.args.target == Target::Echo))
    }
}
