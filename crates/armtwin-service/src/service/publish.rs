//! The session's publishing side: every robot output's key, encoding and congestion control, every
//! `put` (the twin pose for ROS tools among them) and the count of those Zenoh refused, the
//! publishers and input keys that cache a streaming robot's routes, its liveliness token, and
//! their undeclaration.
//!
//! Zenoh I/O only: must not encode a result, decide what is published, or lock a robot's cell
//! (callers publish with the cell they hold, or none).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use tracing::warn;
use zenoh::Wait;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::sample::Locality;
use zenoh::session::Session;

use crate::config::{Congestion, OutputEncoding, OutputShape, ServiceConfig};
use armtwin_codec::zser;
use armtwin_mesh::keys::{KeySpace, Stream};
use armtwin_mesh::ros2::{self, PoseOutput, PoseOutputs};

/// A streaming robot's publishers of its outputs at the sample rate, and its input keys:
/// declared so Zenoh caches their routes, once the robot streams at the rate the sink's route
/// demand sets; then, once every streaming robot has those, its metrics publisher (one message
/// per metrics period: worth a route cache in a large fleet, but never ahead of another robot's
/// poses, which would slow a fleet's first contact: crates/armtwin-bench/README.md, "The
/// per-sample path").
/// Events and calibration go out without a publisher: every declaration costs in proportion to
/// the keys beside it, on this side and on every subscriber's.
pub(super) struct RobotPublishers {
    /// The twin pose and the deviation on their own streams (`[service] outputs = "separate"`),
    /// or both on the paired stream: declared for the streams the robot publishes on alone.
    pose: Option<Publisher<'static>>,
    deviation: Option<Publisher<'static>>,
    paired: Option<Publisher<'static>>,
    /// The twin pose as a ROS 2 `PoseStamped`, if the robot has `ros2_pose`.
    ros2_pose: Option<Publisher<'static>>,
    /// Declared after the others (see above); shared so that the metrics period can publish
    /// through it after releasing the robot's lock.
    metrics: Option<Arc<Publisher<'static>>>,
    inputs: Vec<KeyExpr<'static>>,
}

impl RobotPublishers {
    /// The publisher of `stream`, for the streams at the sample rate.
    fn of(&self, stream: Stream) -> Option<&Publisher<'static>> {
        match stream {
            Stream::Pose => self.pose.as_ref(),
            Stream::Deviation => self.deviation.as_ref(),
            Stream::Paired => self.paired.as_ref(),
            Stream::Metrics => self.metrics.as_deref(),
            _ => None,
        }
    }

    /// The metrics publisher, once declared: shared, to publish through after the robot's lock
    /// is released.
    pub(super) fn metrics(&self) -> Option<Arc<Publisher<'static>>> {
        self.metrics.clone()
    }

    /// Gives these publishers the metrics publisher, declared after them.
    pub(super) fn set_metrics(&mut self, publisher: Publisher<'static>) {
        self.metrics = Some(Arc::new(publisher));
    }
}

/// The session's publishing side, shared by every robot: keys, encodings and congestion control,
/// and the count of outputs Zenoh refused. Per-robot publishers live in each robot's cell.
pub(super) struct Outlet {
    session: Session,
    keys: KeySpace,
    /// The format of poses and deviations.
    encoding: OutputEncoding,
    /// Whether poses and deviations go out on their own streams or paired.
    shape: OutputShape,
    /// Of poses and deviations.
    pose_congestion: CongestionControl,
    pose_encoding: Encoding,
    deviation_encoding: Encoding,
    paired_encoding: Encoding,
    /// Which robots publish their twin pose for ROS tools, and where.
    ros2_pose: PoseOutputs,
    /// Outputs Zenoh refused to send.
    publish_errors: AtomicU64,
}

impl Outlet {
    /// The outputs of `config`'s robots on `session`.
    pub(super) fn new(session: Session, config: &ServiceConfig) -> Self {
        let (pose_encoding, deviation_encoding, paired_encoding) = match config.encoding {
            OutputEncoding::Json => (
                Encoding::APPLICATION_JSON,
                Encoding::APPLICATION_JSON,
                Encoding::APPLICATION_JSON,
            ),
            OutputEncoding::ZenohSerialized => (
                Encoding::ZENOH_SERIALIZED.with_schema(zser::TWIN_POSE_SCHEMA),
                Encoding::ZENOH_SERIALIZED.with_schema(zser::DEVIATION_SCHEMA),
                Encoding::ZENOH_SERIALIZED.with_schema(zser::PAIRED_SCHEMA),
            ),
        };
        Self {
            session,
            keys: config.keys.clone(),
            encoding: config.encoding,
            shape: config.outputs,
            pose_congestion: match config.pose_congestion {
                Congestion::Block => CongestionControl::Block,
                Congestion::Drop => CongestionControl::Drop,
            },
            pose_encoding,
            deviation_encoding,
            paired_encoding,
            ros2_pose: config.ros2_pose.clone(),
            publish_errors: AtomicU64::new(0),
        }
    }

    /// The format poses and deviations are published in.
    pub(super) fn encoding(&self) -> OutputEncoding {
        self.encoding
    }

    /// Whether poses and deviations go out on their own streams or paired.
    pub(super) fn shape(&self) -> OutputShape {
        self.shape
    }

    /// Outputs Zenoh refused to send, so far.
    pub(super) fn publish_errors(&self) -> u64 {
        self.publish_errors.load(Ordering::Relaxed)
    }

    /// Where `robot` publishes its twin pose for ROS tools, if it does.
    pub(super) fn ros2_pose_of(&self, robot: &str) -> Option<&PoseOutput> {
        self.ros2_pose.of(robot)
    }

    /// The publisher gid of `robot`'s twin pose for ROS tools, as `rmw_zenoh` attachments carry
    /// it: the same for the robot from this session, whether declared or not.
    pub(super) fn ros2_publisher_gid(&self, robot: &str) -> [u8; 16] {
        ros2::publisher_gid(&self.session.zid().to_le_bytes(), robot)
    }

    /// The congestion control and encoding of `stream`: poses, deviations and both paired as configured,
    /// effort as poses but always JSON, metrics and events blocking JSON.
    fn qos(&self, stream: Stream) -> (CongestionControl, Encoding) {
        match stream {
            Stream::Pose => (self.pose_congestion, self.pose_encoding.clone()),
            Stream::Deviation => (self.pose_congestion, self.deviation_encoding.clone()),
            Stream::Paired => (self.pose_congestion, self.paired_encoding.clone()),
            Stream::Effort => (self.pose_congestion, Encoding::APPLICATION_JSON),
            _ => (CongestionControl::Block, Encoding::APPLICATION_JSON),
        }
    }

    /// Publishes `payload` on `robot`'s `stream`: through its declared publisher, or, until the
    /// control thread has declared it (and for robots that are not tracked), on the plain key.
    /// Returns whether Zenoh took it; a failure is logged here, and counted by the caller.
    fn put(
        &self,
        outputs: Option<&RobotPublishers>,
        robot: &str,
        stream: Stream,
        payload: ZBytes,
    ) -> bool {
        self.put_through(
            outputs.and_then(|outputs| outputs.of(stream)),
            robot,
            stream,
            payload,
        )
    }

    /// [`put`](Self::put) through `publisher`, or on the plain key when there is none.
    fn put_through(
        &self,
        publisher: Option<&Publisher<'static>>,
        robot: &str,
        stream: Stream,
        payload: ZBytes,
    ) -> bool {
        let result = if let Some(publisher) = publisher {
            publisher.put(payload).wait()
        } else {
            let (congestion, encoding) = self.qos(stream);
            self.session
                .put(self.keys.key(stream, robot), payload)
                .congestion_control(congestion)
                .encoding(encoding)
                .wait()
        };
        if let Err(e) = &result {
            warn!(error = %e, %robot, stream = stream.as_str(), "publish failed");
        }
        result.is_ok()
    }

    fn publisher(&self, stream: Stream, robot: &str) -> zenoh::Result<Publisher<'static>> {
        let (congestion, encoding) = self.qos(stream);
        self.session
            .declare_publisher(self.keys.key(stream, robot))
            .congestion_control(congestion)
            .encoding(encoding)
            .wait()
    }

    pub(super) fn declare(&self, robot: &str) -> zenoh::Result<RobotPublishers> {
        let mut inputs = Vec::new();
        for stream in [Stream::Joints, Stream::Measured] {
            inputs.push(
                self.session
                    .declare_keyexpr(self.keys.key(stream, robot))
                    .wait()?,
            );
        }
        // A paired robot's deviations that pair outside their pose's message (interpolated) are
        // few: they go out on the plain key.
        let (pose, deviation, paired) = match self.shape {
            OutputShape::Separate => (
                Some(self.publisher(Stream::Pose, robot)?),
                Some(self.publisher(Stream::Deviation, robot)?),
                None,
            ),
            OutputShape::Paired => (None, None, Some(self.publisher(Stream::Paired, robot)?)),
        };
        let ros2_pose = match self.ros2_pose.of(robot) {
            Some(output) => Some(
                self.session
                    .declare_publisher(output.key(robot))
                    .congestion_control(self.pose_congestion)
                    // Never delivered back into this session's sources, whatever their keys.
                    .allowed_destination(Locality::Remote)
                    .wait()?,
            ),
            None => None,
        };
        Ok(RobotPublishers {
            pose,
            deviation,
            paired,
            ros2_pose,
            metrics: None,
            inputs,
        })
    }

    /// The publisher of `robot`'s metrics.
    pub(super) fn declare_metrics(&self, robot: &str) -> zenoh::Result<Publisher<'static>> {
        self.publisher(Stream::Metrics, robot)
    }

    pub(super) fn declare_token(&self, robot: &str) -> zenoh::Result<LivelinessToken> {
        self.session
            .liveliness()
            .declare_token(self.keys.key(Stream::Alive, robot))
            .wait()
    }

    pub(super) fn undeclare_all(
        &self,
        outputs: Vec<(Arc<str>, RobotPublishers)>,
        tokens: Vec<(Arc<str>, LivelinessToken)>,
    ) {
        for (robot, outputs) in outputs {
            let RobotPublishers {
                pose,
                deviation,
                paired,
                ros2_pose,
                metrics,
                inputs,
            } = outputs;
            // A metrics publisher still shared by a metrics period in progress is undeclared
            // when that period drops it.
            let metrics = metrics.and_then(|metrics| Arc::try_unwrap(metrics).ok());
            for publisher in [pose, deviation, paired]
                .into_iter()
                .flatten()
                .chain(ros2_pose)
                .chain(metrics)
            {
                if let Err(e) = publisher.undeclare().wait() {
                    warn!(%robot, error = %e, "undeclaring a publisher failed");
                }
            }
            for key in inputs {
                if let Err(e) = self.session.undeclare(key).wait() {
                    warn!(%robot, error = %e, "undeclaring a key expression failed");
                }
            }
        }
        for (robot, token) in tokens {
            if let Err(e) = token.undeclare().wait() {
                warn!(%robot, error = %e, "undeclaring the liveliness token failed");
            }
        }
    }

    /// Publishes `payload` on `robot`'s `stream` ([`put`](Self::put), through `declared`, the
    /// robot's publishers, when they exist), counting a refusal.
    pub(super) fn publish(
        &self,
        declared: Option<&RobotPublishers>,
        robot: &str,
        stream: Stream,
        payload: impl Into<ZBytes>,
    ) {
        if !self.put(declared, robot, stream, payload.into()) {
            self.publish_errors.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Publishes `robot`'s metrics message through `publisher`, its metrics publisher once
    /// declared, else on the plain key; a refusal is logged and counted.
    pub(super) fn publish_metrics(
        &self,
        publisher: Option<&Publisher<'static>>,
        robot: &str,
        payload: impl Into<ZBytes>,
    ) {
        if !self.put_through(publisher, robot, Stream::Metrics, payload.into()) {
            self.publish_errors.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Publishes `robot`'s twin pose for ROS tools (`payload` a CDR `PoseStamped`, with
    /// `rmw_zenoh`'s `attachment` for that scheme) on `key`: through its publisher among
    /// `declared` once declared, else on the plain key, never delivered back into this session's
    /// sources; a refusal is logged and counted.
    pub(super) fn publish_ros2_pose(
        &self,
        declared: Option<&RobotPublishers>,
        robot: &str,
        key: &str,
        payload: Vec<u8>,
        attachment: Option<Vec<u8>>,
    ) {
        let publisher = declared.and_then(|publishers| publishers.ros2_pose.as_ref());
        let result = match publisher {
            Some(publisher) => publisher.put(payload).attachment(attachment).wait(),
            None => self
                .session
                .put(key, payload)
                .attachment(attachment)
                .congestion_control(self.pose_congestion)
                .allowed_destination(Locality::Remote)
                .wait(),
        };
        if let Err(e) = result {
            warn!(error = %e, %robot, %key, "publish failed");
            self.publish_errors.fetch_add(1, Ordering::Relaxed);
        }
    }
}
