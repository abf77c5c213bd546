//! Intake: the subscribers and queryables that feed the fleet, and each sample's way from its
//! key to its robot's twin (decoded before the robot's lock, stepped under it).
//!
//! Must not block in a callback beyond the robot's own lock and its outputs' `put`: queries go to
//! the query threads ([`QueryPool`]).

use std::sync::Arc;

use tracing::{debug, info, warn};
use zenoh::sample::Sample;
use zenoh::session::Session;

use super::controller::take_facts;
use super::description::take_description;
use super::error::ServiceError;
use super::fleet::{Fleet, Lookup, RobotCell, Stepping};
use super::queries::{Queries, QueryPool};
use super::shard::claim_shard;
use crate::config::{ServiceConfig, SourceConfig, SourceRobot, SourceStream};
use armtwin_codec::decoded::{self, Arrival, Decoded, Decoder};
use armtwin_codec::gateway::{self, Codec, SourceCodec};
use armtwin_codec::{cdr, zser};
use armtwin_core::model::urdf::MAX_URDF_BYTES;
use armtwin_core::pipeline::{MeasuredStream, Robot, Untracked};
use armtwin_mesh::ingest;
use armtwin_mesh::keys::{KeySpace, Stream};
use armtwin_mesh::ros2::{Attachment, KeyScheme, PublisherSeq};
use armtwin_mesh::{TEARDOWN_STEP, bounded, transport_stamp_s};

/// The subscribers and queryables that feed the twin.
pub(super) struct Intake {
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    /// The description sources' subscribers, which read transient-local history.
    history_subscribers: Vec<zenoh_ext::AdvancedSubscriber<()>>,
    queryables: Vec<zenoh::query::Queryable<()>>,
}

impl Intake {
    /// Undeclares every subscriber and queryable, each within [`TEARDOWN_STEP`].
    pub(super) async fn undeclare(self) {
        for subscriber in self.subscribers {
            let step = format!("undeclaring the subscriber on {}", subscriber.key_expr());
            if let Some(Err(e)) = bounded(&step, TEARDOWN_STEP, subscriber.undeclare()).await {
                warn!(error = %e, step, "undeclaring failed");
            }
        }
        for subscriber in self.history_subscribers {
            let step = format!("undeclaring the subscriber on {}", subscriber.key_expr());
            if let Some(Err(e)) = bounded(&step, TEARDOWN_STEP, subscriber.undeclare()).await {
                warn!(error = %e, step, "undeclaring failed");
            }
        }
        for queryable in self.queryables {
            let step = format!("undeclaring the queryable on {}", queryable.key_expr());
            if let Some(Err(e)) = bounded(&step, TEARDOWN_STEP, queryable.undeclare()).await {
                warn!(error = %e, step, "undeclaring failed");
            }
        }
    }
}

/// The totals a shard claim answers with: robots tracked and the bound, refused, retired, and
/// failed snapshot writes, as on `/metrics`.
fn service_totals(fleet: &Arc<Fleet>) -> impl Fn() -> serde_json::Value + Send + Sync + 'static {
    let fleet = Arc::clone(fleet);
    move || {
        let (robots, max_robots) = fleet.occupancy();
        serde_json::json!({
            "robots": robots,
            "max_robots": max_robots,
            "robots_refused": fleet.robots_refused(),
            "robots_retired": fleet.robots_retired(),
            "snapshot_failures": fleet.snapshot_failures(),
            "descriptions_refused": fleet.descriptions_refused(),
            "recorder": fleet.recorder().totals(),
        })
    }
}

pub(super) async fn declare_intake(
    session: &Session,
    config: &ServiceConfig,
    fleet: &Arc<Fleet>,
    admin_refusal: Option<String>,
) -> Result<Intake, ServiceError> {
    let keys = &config.keys;
    let mut subscribers = Vec::new();
    let mut queryables =
        vec![claim_shard(session, keys, &config.shard, service_totals(fleet)).await?];
    let shard = config.shard.as_str();
    let router = Arc::new(Router {
        fleet: Arc::clone(fleet),
        keys: keys.clone(),
    });
    let joints = Arc::clone(&router);
    subscribers.push(
        session
            .declare_subscriber(keys.key(Stream::Joints, shard))
            .callback(move |sample| joints.joints(&sample))
            .await?,
    );
    let measured = Arc::clone(&router);
    subscribers.push(
        session
            .declare_subscriber(keys.key(Stream::Measured, shard))
            .callback(move |sample| measured.measured(&sample))
            .await?,
    );
    let controller = Arc::clone(&router);
    subscribers.push(
        session
            .declare_subscriber(keys.key(Stream::Controller, shard))
            .callback(move |sample| controller.controller(&sample))
            .await?,
    );
    let description = Arc::clone(&router);
    subscribers.push(
        session
            .declare_subscriber(keys.key(Stream::Description, shard))
            .callback(move |sample| description.description(&sample))
            .await?,
    );
    ask_gateways(
        session,
        keys.key(Stream::Controller, shard),
        &router,
        Router::controller,
    );
    ask_gateways(
        session,
        keys.key(Stream::Description, shard),
        &router,
        Router::description,
    );
    for (robot, settings) in &config.robots {
        // A configured robot is in the directory from the start: its sensors' samples need no
        // look-up at all.
        let Some(handle) = fleet.find(robot) else {
            continue;
        };
        for (index, sensor) in settings.sensors.iter().enumerate() {
            let sensor_router = Arc::clone(&router);
            let robot = handle.clone();
            subscribers.push(
                session
                    .declare_subscriber(sensor.key_expr.clone())
                    .callback(move |sample| sensor_router.sensor(&robot, index, &sample))
                    .await?,
            );
        }
    }
    let history_subscribers = declare_sources(session, config, &router, &mut subscribers).await?;
    if let Some(why) = &admin_refusal {
        info!("{why}");
    }
    let queries = Queries::new(Arc::clone(fleet), keys.clone(), admin_refusal);
    let pool = QueryPool::start(queries)
        .map_err(|e| ServiceError::Worker(format!("the query threads: {e}")))?;
    for (stream, handler) in Queries::HANDLERS {
        let pool = pool.clone();
        queryables.push(
            session
                .declare_queryable(keys.key(stream, shard))
                .callback(move |query| pool.submit(query, stream, handler))
                .await?,
        );
    }
    Ok(Intake {
        subscribers,
        history_subscribers,
        queryables,
    })
}

/// Asks the gateways already streaming what they read of their controllers, or the robots'
/// descriptions (`stream`): a gateway puts them when they change, so one that started first
/// would otherwise stay unheard until then. The answers are taken as the puts are, off the
/// start's path.
fn ask_gateways(session: &Session, key: String, router: &Arc<Router>, take: fn(&Router, &Sample)) {
    let session = session.clone();
    let router = Arc::clone(router);
    tokio::spawn(async move {
        let replies = match session
            .get(key.as_str())
            .timeout(GATEWAY_QUERY_TIMEOUT)
            .await
        {
            Ok(replies) => replies,
            Err(error) => {
                warn!(%key, %error, "cannot ask the gateways for what they keep");
                return;
            }
        };
        while let Ok(reply) = replies.recv_async().await {
            if let Ok(sample) = reply.result() {
                take(&router, sample);
            }
        }
    });
}

/// How long the gateways have to answer the start's queries for what they keep.
const GATEWAY_QUERY_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);

/// One subscriber per `[[sources]]` entry (their keys were checked when the configuration
/// loaded: outside armtwin's own keys and twin pose outputs, disjoint from each other).
/// The description sources' subscribers come back: they also read the history their
/// publishers keep (a ROS 2 `/robot_description` is transient local), and ask again for it
/// from a publisher that appears later.
async fn declare_sources(
    session: &Session,
    config: &ServiceConfig,
    router: &Arc<Router>,
    subscribers: &mut Vec<zenoh::pubsub::Subscriber<()>>,
) -> Result<Vec<zenoh_ext::AdvancedSubscriber<()>>, ServiceError> {
    use zenoh_ext::{AdvancedSubscriberBuilderExt as _, HistoryConfig};
    let mut history_subscribers = Vec::new();
    for (index, source) in config.sources.iter().enumerate() {
        let intake = Arc::new(SourceIntake {
            index,
            config: source.clone(),
        });
        let source_router = Arc::clone(router);
        let builder = session
            .declare_subscriber(source.key_expr.clone())
            .callback(move |sample| source_router.source(&intake, &sample));
        if source.stream == SourceStream::Description {
            history_subscribers.push(
                builder
                    .history(HistoryConfig::default().detect_late_publishers())
                    .await?,
            );
        } else {
            subscribers.push(builder.await?);
        }
        info!(
            key = %source.key_expr,
            codec = source.codec.as_str(),
            stream = source.stream.as_str(),
            "source subscribed"
        );
    }
    Ok(history_subscribers)
}

/// A `[[sources]]` entry as the service runs it.
struct SourceIntake {
    /// Its place in `[[sources]]`: what a robot's entry keys the source's sequence numbers by.
    index: usize,
    config: SourceConfig,
}

impl SourceIntake {
    /// The robot of a sample on `key`, or `None` (said in the log) when its key names none.
    fn robot_of<'k>(&'k self, key: &'k str) -> Option<&'k str> {
        match &self.config.robot {
            SourceRobot::Fixed(id) => Some(id.as_str()),
            SourceRobot::FromKey(rule) => {
                let id = rule.robot_of(key);
                if id.is_none() {
                    warn!(
                        %key,
                        source = %self.config.key_expr,
                        topic = rule.topic(),
                        "sample whose key names no robot (no ROS namespace before the topic, or \
                         another type): ignored"
                    );
                }
                id
            }
        }
    }

    /// The gateway `seq` of a joint sample of `robot` with `attachment`; `by_source` is the
    /// robot's [`Stepping::publisher_seqs`], so only the robot's own lock is held.
    fn gateway_seq(
        &self,
        robot: &Robot,
        attachment: &Attachment,
        by_source: &mut Vec<(usize, PublisherSeq)>,
    ) -> u64 {
        let known = by_source
            .iter()
            .position(|(source, _)| *source == self.index);
        let position = known.unwrap_or_else(|| {
            by_source.push((self.index, PublisherSeq::default()));
            by_source.len() - 1
        });
        let (seq, changed) = by_source[position].1.gateway_seq(attachment);
        if changed {
            info!(
                robot = robot.id(),
                key = %self.config.key_expr,
                sequence_number = attachment.sequence_number,
                "another ROS publisher (gid): its sequence numbers carry on from the previous one's"
            );
        }
        seq
    }
}

/// Each sample's way from its key to its robot's twin, in Zenoh's callbacks.
pub(super) struct Router {
    fleet: Arc<Fleet>,
    keys: KeySpace,
}

impl Router {
    /// One input of robot `id`, arrived on `key`, decoded with `decoder` and stepped into the
    /// robot's twin: the one intake path of every sample (armtwin's own keys, sensors' and
    /// `[[sources]]`', whatever the codec). The robot is found under the read locks or, on its
    /// first input, admitted under the default settings ([`Fleet::lookup`]); the input of a robot
    /// that may not be tracked is rejected as such, at the stamp the decoder finds in it, instead.
    ///
    /// `fallback_s` gives the stamp of a message without one (read only then). `transport` sees
    /// the decoded message under the robot's lock before it is stepped: what the transport adds
    /// to it (`rmw_zenoh`'s attachment).
    #[allow(
        clippy::too_many_arguments,
        reason = "one input: who, where, how, and its bytes"
    )]
    fn intake<D: Decoder, T>(
        &self,
        id: &str,
        key: &str,
        stream: MeasuredStream,
        decoder: &D,
        payload: &[u8],
        fallback_s: impl Fn() -> f64,
        mut transport: T,
    ) where
        T: FnOnce(&mut Stepping<'_>, &mut Decoded<D::Message, D::Error>),
    {
        // A robot retired between its look-up and its lock is looked up again, which admits it
        // afresh (a retired robot was idle for `forget_after`: the new one cannot be, so this
        // goes round once at most).
        loop {
            match self.fleet.lookup(id) {
                Lookup::Found(cell) => {
                    let arrival = Arrival { key, stream };
                    match self.decode_and_step(
                        &cell,
                        arrival,
                        decoder,
                        payload,
                        &fallback_s,
                        transport,
                    ) {
                        Some(unused) => transport = unused,
                        None => return,
                    }
                }
                Lookup::Foreign => {
                    debug!(robot = id, %key, "robot of another instance: ignored");
                    return;
                }
                Lookup::Refused(why) => {
                    if self.fleet.count_input() {
                        let limit = match why {
                            Untracked::Full { max_robots } => {
                                Some((max_robots, "the fleet is full (service.max_robots)"))
                            }
                            Untracked::GroupFull { max_robots, .. } => Some((
                                max_robots,
                                "a gateway's prefix grant is full (its max_robots)",
                            )),
                            Untracked::Unknown => None,
                        };
                        if let Some((max_robots, full)) = limit
                            && self.fleet.refuse_full()
                        {
                            warn!(
                                robot = id,
                                max_robots,
                                refused = self.fleet.robots_refused(),
                                "{full}: samples of new robots are refused (logged at most once a \
                                 minute; counted in armtwin_robots_refused_total)"
                            );
                        }
                        let mut sink = self.fleet.untracked_sink();
                        gateway::untracked_robot(
                            id,
                            why,
                            key,
                            decoder,
                            payload,
                            &fallback_s,
                            &mut sink,
                        );
                    }
                    return;
                }
            }
        }
    }

    /// Decodes an input against `cell`'s robot before taking its lock, then steps the twin with
    /// it under that lock alone; hands `transport` back if the robot was retired meanwhile.
    fn decode_and_step<D: Decoder, T>(
        &self,
        cell: &RobotCell,
        arrival: Arrival<'_>,
        decoder: &D,
        payload: &[u8],
        fallback_s: impl FnOnce() -> f64,
        transport: T,
    ) -> Option<T>
    where
        T: FnOnce(&mut Stepping<'_>, &mut Decoded<D::Message, D::Error>),
    {
        let mut message = Decoded::decode(decoder, cell.robot(), payload, fallback_s);
        let mut transport = Some(transport);
        let stepped = self.fleet.step(cell, |mut locked| {
            if let Some(transport) = transport.take() {
                transport(&mut locked, &mut message);
            }
            message.step(locked.twin, arrival, &mut locked.sink);
        });
        if stepped { None } else { transport }
    }

    fn joints(&self, sample: &Sample) {
        let decoder = gateway::Joints(ingest::codec_of(sample.encoding()));
        self.gateway_sample(sample, Stream::Joints, &decoder);
    }

    fn measured(&self, sample: &Sample) {
        let decoder = gateway::Pose(ingest::codec_of(sample.encoding()));
        self.gateway_sample(sample, Stream::Measured, &decoder);
    }

    /// A gateway's sample on `<prefix>/<stream>/<robot>`: its robot from the key, decoded with
    /// `decoder` (the sample's encoding chose it).
    fn gateway_sample<D: Decoder>(&self, sample: &Sample, stream: Stream, decoder: &D) {
        let key = sample.key_expr().as_str();
        let id = match self.keys.robot_of(stream, key) {
            Ok(id) => id,
            Err(error) => {
                warn!(%key, %error, "sample without a robot id in its key: ignored");
                return;
            }
        };
        let payload = sample.payload().to_bytes();
        let fallback_s = || transport_stamp_s(sample);
        let measured = MeasuredStream::Robot;
        self.intake(id, key, measured, decoder, &payload, fallback_s, |_, _| {});
    }

    /// A gateway's facts of a controller, on `<prefix>/controller/<robot>`.
    fn controller(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        match self.keys.robot_of(Stream::Controller, key) {
            Ok(id) => take_facts(&self.fleet, id, &sample.payload().to_bytes()),
            Err(error) => {
                warn!(%key, %error, "controller facts without a robot id in their key: ignored");
            }
        }
    }

    /// A robot's description, on `<prefix>/description/<robot>`: the URDF's text.
    fn description(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        match self.keys.robot_of(Stream::Description, key) {
            // Refused before the payload is copied, if it is too large.
            Ok(id) if sample.payload().len() > MAX_URDF_BYTES => {
                let why = format!("{} bytes, over {MAX_URDF_BYTES}", sample.payload().len());
                take_description(&self.fleet, id, key, &Err(why));
            }
            Ok(id) => {
                let payload = sample.payload().to_bytes();
                take_description(&self.fleet, id, key, &Ok(&payload[..]));
            }
            Err(error) => {
                warn!(%key, %error, "description without a robot id in its key: ignored");
            }
        }
    }

    /// A pose of one of `robot`'s sensors: the robot is the sensor's, resolved when its key was
    /// declared.
    fn sensor(&self, robot: &Robot, index: usize, sample: &Sample) {
        let arrival = Arrival {
            key: sample.key_expr().as_str(),
            stream: MeasuredStream::Sensor(index),
        };
        let decoder = gateway::Pose(ingest::codec_of(sample.encoding()));
        let payload = sample.payload().to_bytes();
        let fallback_s = || transport_stamp_s(sample);
        // A configured robot: never retired, so its cell is always the fleet's.
        let Some(cell) = self.fleet.live_cell(robot) else {
            return;
        };
        let _ = self.decode_and_step(&cell, arrival, &decoder, &payload, fallback_s, |_, _| {});
    }

    /// A sample of a `[[sources]]` entry: its robot from the source (fixed, or the key's ROS
    /// namespace), decoded with the source's codec, stepped like the built-in inputs.
    fn source(&self, source: &SourceIntake, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let Some(id) = source.robot_of(key) else {
            return;
        };
        let payload = sample.payload().to_bytes();
        if source.config.stream == SourceStream::Description {
            // A ROS 2 robot's is a std_msgs/String; any other's, the URDF's text.
            let text = match &source.config.ros2 {
                Some(_) => cdr::decode_string(&payload, MAX_URDF_BYTES)
                    .map(str::as_bytes)
                    .map_err(|error| format!("not a std_msgs/String: {error}")),
                None => Ok(&payload[..]),
            };
            take_description(&self.fleet, id, key, &text);
            return;
        }
        let stream = MeasuredStream::Robot;
        let Some(ros2) = &source.config.ros2 else {
            let fallback_s = || transport_stamp_s(sample);
            let codec = match (source.config.codec, source.config.stream) {
                (SourceCodec::ZenohSerialized, SourceStream::Joints) => {
                    Codec::ZenohSerialized(Some(zser::Schema::Joints))
                }
                (SourceCodec::ZenohSerialized, SourceStream::Measured) => {
                    Codec::ZenohSerialized(Some(zser::Schema::Pose))
                }
                _ => ingest::codec_of(sample.encoding()),
            };
            match source.config.stream {
                // Taken above.
                SourceStream::Description => {}
                SourceStream::Joints => {
                    let decoder = gateway::Joints(codec);
                    self.intake(id, key, stream, &decoder, &payload, fallback_s, |_, _| {});
                }
                SourceStream::Measured => {
                    let decoder = gateway::Pose(codec);
                    self.intake(id, key, stream, &decoder, &payload, fallback_s, |_, _| {});
                }
            }
            return;
        };
        // ROS 2: `header.stamp` is the source time (else the attachment's source timestamp,
        // else the transport's); the `rmw_zenoh` attachment's sequence number is the gateway
        // `seq` of joint samples, and an attachment that does not parse is rejected on its own
        // while the message still goes in.
        let attachment = match (ros2.scheme, sample.attachment()) {
            (KeyScheme::RmwZenoh, Some(bytes)) => Some(Attachment::parse(&bytes.to_bytes())),
            _ => None,
        };
        let source_stamp_s = attachment
            .as_ref()
            .and_then(|parsed| parsed.as_ref().ok())
            .and_then(Attachment::source_timestamp_s);
        let fallback_s = || source_stamp_s.unwrap_or_else(|| transport_stamp_s(sample));
        let reject_attachment = |locked: &mut Stepping<'_>, stamp_s: f64| {
            if let Some(Err(error)) = &attachment {
                decoded::reject(locked.twin, key, stamp_s, error, &mut locked.sink);
            }
        };
        match source.config.stream {
            SourceStream::Joints => {
                let decoder = cdr::JointStates {
                    names: &ros2.joint_names,
                    effort: ros2.effort,
                };
                self.intake(
                    id,
                    key,
                    stream,
                    &decoder,
                    &payload,
                    fallback_s,
                    |locked, message| {
                        reject_attachment(locked, message.stamp_s());
                        if let (Some(Ok(attachment)), Some(sample)) =
                            (&attachment, message.message_mut())
                        {
                            let by_source = &mut *locked.publisher_seqs;
                            let robot = locked.twin.robot();
                            sample.seq = Some(source.gateway_seq(robot, attachment, by_source));
                        }
                    },
                );
            }
            SourceStream::Measured => {
                let decoder = cdr::PosesStamped {
                    expected_frame: &ros2.base_frame,
                };
                self.intake(
                    id,
                    key,
                    stream,
                    &decoder,
                    &payload,
                    fallback_s,
                    |locked, message| {
                        reject_attachment(locked, message.stamp_s());
                    },
                );
            }
            // Taken above.
            SourceStream::Description => {}
        }
    }
}
