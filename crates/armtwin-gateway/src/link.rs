//! One controller's link: connect, run the RTDE exchange ([`armtwin_codec::rtde::Handshake`]),
//! publish each data package as a joint message with the measured pose embedded, and after any
//! fault the controller can cause (a refused connection, a dropped link, silence, damaged data)
//! wait and connect again, with a backoff from 0.1 s doubling to 5 s. Says each state change in
//! the log and in the robot's gateway liveliness tokens.
//!
//! Beside the samples, what it reads of the controller ([`ControllerFacts`]: its version, its
//! `tcp_offset`, its model and serial number from the dashboard server, read once per
//! connection while the samples flow) goes on the robot's controller key whenever it changes,
//! before the sample that changed it, and a queryable there answers the latest.
//!
//! Owns the socket, the timeouts, the backoff and the per-robot `seq`; must not parse bytes (the
//! codec's `rtde` module does) nor decide stamps ([`super::clock`]).

use std::io::Write as _;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use nalgebra::Vector3;
use thiserror::Error;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio::time::timeout;
use tracing::{debug, info, warn};
use zenoh::Session;
use zenoh::bytes::Encoding;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Queryable;

use super::ControllerSettings;
use super::clock::{OffsetChange, StampClock};
use super::dashboard::{self, DashboardError, Identity};
use armtwin_codec::rtde::handshake::{Progress, Started, TextMessage};
use armtwin_codec::rtde::{FrameSplitter, Handshake, RtdeError, RtdeSample, record};
use armtwin_codec::zser;
use armtwin_core::orientation;
use armtwin_mesh::controller::ControllerFacts;
use armtwin_mesh::keys::{KeySpace, Stream};

/// The first wait before connecting again, and after a link that streamed.
const FIRST_BACKOFF: Duration = Duration::from_millis(100);
/// The longest wait between attempts.
const MAX_BACKOFF: Duration = Duration::from_secs(5);
/// How long a connection may take to open.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
/// How long the controller may take to answer a request of the exchange.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a streaming controller may stay silent: it sends at 125 or 500 Hz.
const SILENCE_TIMEOUT: Duration = Duration::from_secs(1);

/// Why a link ended, or a probe failed.
#[derive(Debug, Error)]
pub enum LinkError {
    /// The controller's port refused or failed the connection.
    #[error("cannot connect: {0}")]
    Connect(std::io::Error),
    /// No answer (or data package) within the time the exchange allows.
    #[error("no answer within {0:?}")]
    Silent(Duration),
    /// The controller closed the connection.
    #[error("the controller closed the link")]
    Closed,
    /// The connection failed.
    #[error("link: {0}")]
    Io(#[from] std::io::Error),
    /// What the controller sent is not RTDE as armtwin speaks it.
    #[error("RTDE: {0}")]
    Protocol(#[from] RtdeError),
    /// Publishing failed.
    #[error("zenoh: {0}")]
    Zenoh(zenoh::Error),
}

/// The gateway side of one robot, kept across its connections.
struct Robot {
    settings: ControllerSettings,
    publisher: Publisher<'static>,
    session: Session,
    keys: KeySpace,
    /// The joint messages' `seq`, continuous across connections.
    seq: u64,
    clock: StampClock,
    /// The liveliness token of the current state and whether it is the streaming one.
    token: Option<(bool, LivelinessToken)>,
    dropped_said: bool,
    recorder: Option<Recorder>,
    /// Samples of the current connection.
    streamed: u64,
    /// What was read of the controller, across connections.
    facts: ControllerFacts,
    /// The facts last published, which the controller key's queryable answers.
    published: Arc<Mutex<Option<ControllerFacts>>>,
}

/// `--record`: the CSV of every data package, under the first connection's recipe, appended to
/// what an earlier run wrote under the same columns; a file of other columns is left as it is.
struct Recorder {
    file: std::io::BufWriter<std::fs::File>,
    recipe: Option<armtwin_codec::rtde::Recipe>,
    line: String,
    /// The header line the file already had (an earlier run's), if it was not empty.
    earlier_header: Option<String>,
}

/// The longest header line read back from an earlier recording: a recipe's names, never more.
const MAX_HEADER_BYTES: u64 = 64 * 1024;

impl Recorder {
    /// Opens `path` to append to, creating it; reads the header an earlier run wrote.
    fn open(path: &std::path::Path) -> std::io::Result<Self> {
        use std::io::BufRead as _;
        let file = std::fs::OpenOptions::new()
            .create(true)
            .read(true)
            .append(true)
            .open(path)?;
        let mut first = String::new();
        std::io::BufReader::new(std::io::Read::take(&file, MAX_HEADER_BYTES))
            .read_line(&mut first)?;
        let header = first.trim_end_matches(['\n', '\r']);
        Ok(Self {
            file: std::io::BufWriter::new(file),
            recipe: None,
            line: String::new(),
            earlier_header: (!header.is_empty()).then(|| header.to_owned()),
        })
    }
}

/// One connection's RTDE exchange: the socket, the handshake and the frames being read.
struct Exchange {
    socket: TcpStream,
    handshake: Handshake,
    splitter: FrameSplitter,
    buffer: Vec<u8>,
}

impl Exchange {
    /// Connects to `host:port` and sends the exchange's first request, asking for `frequency_hz`.
    async fn open(host: &str, port: u16, frequency_hz: f64) -> Result<Self, LinkError> {
        let mut socket = match timeout(CONNECT_TIMEOUT, TcpStream::connect((host, port))).await {
            Ok(Ok(socket)) => socket,
            Ok(Err(error)) => return Err(LinkError::Connect(error)),
            Err(_) => return Err(LinkError::Silent(CONNECT_TIMEOUT)),
        };
        socket.set_nodelay(true)?;
        let (handshake, first) = Handshake::new(frequency_hz)?;
        socket.write_all(&first).await?;
        Ok(Self {
            socket,
            handshake,
            splitter: FrameSplitter::new(),
            buffer: vec![0_u8; 16 * 1024],
        })
    }

    /// How long the controller may stay silent now: an answer's time during the exchange, a
    /// cycle's once the data packages flow.
    fn limit(&self) -> Duration {
        if self.handshake.is_streaming() {
            SILENCE_TIMEOUT
        } else {
            ANSWER_TIMEOUT
        }
    }

    /// Takes what one read (bounded by `limit`) brought: answers the controller where the
    /// exchange asks to, and puts every other step in `out` (emptied first).
    async fn take(
        &mut self,
        read: Result<std::io::Result<usize>, tokio::time::error::Elapsed>,
        limit: Duration,
        out: &mut Vec<Progress>,
    ) -> Result<(), LinkError> {
        out.clear();
        let read = match read {
            Ok(read) => read?,
            Err(_) => return Err(LinkError::Silent(limit)),
        };
        if read == 0 {
            return Err(LinkError::Closed);
        }
        self.splitter.extend(&self.buffer[..read])?;
        while let Some(frame) = self.splitter.next_frame()? {
            match self.handshake.on_frame(frame)? {
                Progress::Send(bytes) => self.socket.write_all(&bytes).await?,
                progress => out.push(progress),
            }
        }
        Ok(())
    }
}

/// Connects to the controller at `host:port`, runs RTDE's exchange up to its first data package
/// and leaves, streaming nothing (`armtwin doctor`): what the controller says of itself, and the
/// package.
pub async fn probe(host: &str, port: u16) -> Result<(Started, RtdeSample), LinkError> {
    let mut exchange = Exchange::open(host, port, super::DEFAULT_FREQUENCY_HZ).await?;
    let mut steps = Vec::new();
    let mut started = None;
    loop {
        let limit = exchange.limit();
        let read = timeout(limit, exchange.socket.read(&mut exchange.buffer)).await;
        exchange.take(read, limit, &mut steps).await?;
        for step in steps.drain(..) {
            match step {
                Progress::Started(now) => started = Some(now),
                Progress::Sample(sample) => {
                    if let Some(started) = started.take() {
                        return Ok((started, sample));
                    }
                }
                Progress::Send(_) | Progress::Text(_) => {}
            }
        }
    }
}

/// Runs one controller's link until `shutdown` says stop.
pub(super) async fn run(
    session: Session,
    keys: KeySpace,
    settings: ControllerSettings,
    mut shutdown: watch::Receiver<bool>,
) {
    let key = keys.key(Stream::Joints, &settings.robot);
    let publisher = match session
        .declare_publisher(key.clone())
        .encoding(Encoding::ZENOH_SERIALIZED.with_schema(zser::JOINTS_STATE_SCHEMA))
        .congestion_control(CongestionControl::Block)
        .await
    {
        Ok(publisher) => publisher,
        Err(error) => {
            warn!(robot = %settings.robot, %key, %error, "cannot declare the joints publisher: robot not streamed");
            return;
        }
    };
    let recorder = match settings.record.as_deref().map(Recorder::open).transpose() {
        Ok(recorder) => recorder,
        Err(error) => {
            warn!(robot = %settings.robot, %error, "cannot open the recording: not recording");
            None
        }
    };
    let published = Arc::new(Mutex::new(None));
    let facts_key = keys.key(Stream::Controller, &settings.robot);
    let facts_queryable = match session.declare_queryable(facts_key).await {
        Ok(queryable) => Some(tokio::spawn(answer_facts(
            queryable,
            Arc::clone(&published),
        ))),
        Err(error) => {
            warn!(robot = %settings.robot, %error, "cannot declare the controller facts queryable: a service that starts later learns them at the next change");
            None
        }
    };
    let mut robot = Robot {
        clock: StampClock::new(1.0 / settings.frequency_hz),
        settings,
        publisher,
        session,
        keys,
        seq: 0,
        token: None,
        dropped_said: false,
        recorder,
        streamed: 0,
        facts: ControllerFacts::default(),
        published,
    };
    let mut backoff = FIRST_BACKOFF;
    loop {
        robot.say(false).await;
        robot.streamed = 0;
        robot.clock.reconnected();
        info!(robot = %robot.settings.robot, host = %robot.settings.host, port = robot.settings.port, "connecting to the controller");
        let ended = tokio::select! {
            ended = robot.stream() => ended,
            _ = shutdown.changed() => break,
        };
        robot.flush_recording();
        if robot.streamed > 0 {
            backoff = FIRST_BACKOFF;
        }
        warn!(
            robot = %robot.settings.robot,
            error = %ended,
            samples = robot.streamed,
            retry_in_s = backoff.as_secs_f64(),
            "link to the controller ended; reconnecting"
        );
        robot.say(false).await;
        tokio::select! {
            () = tokio::time::sleep(backoff) => {}
            _ = shutdown.changed() => break,
        }
        backoff = (backoff * 2).min(MAX_BACKOFF);
    }
    robot.flush_recording();
    if let Some(task) = facts_queryable {
        // The task owns the queryable: ending it undeclares it.
        task.abort();
    }
    if let Some((_, token)) = robot.token.take() {
        let _ = token.undeclare().await;
    }
    let _ = robot.publisher.undeclare().await;
    info!(robot = %robot.settings.robot, "gateway link stopped");
}

impl Robot {
    /// Declares the token of the state (streaming or waiting), undeclaring the other.
    async fn say(&mut self, streaming: bool) {
        if self.token.as_ref().is_some_and(|(is, _)| *is == streaming) {
            return;
        }
        let stream = if streaming {
            Stream::GatewayStreaming
        } else {
            Stream::GatewayWaiting
        };
        match self
            .session
            .liveliness()
            .declare_token(self.keys.key(stream, &self.settings.robot))
            .await
        {
            Ok(token) => {
                if let Some((_, old)) = self.token.replace((streaming, token)) {
                    let _ = old.undeclare().await;
                }
            }
            Err(error) => {
                warn!(robot = %self.settings.robot, %error, "cannot declare the gateway's liveliness token");
            }
        }
    }

    /// One connection, until it ends: the reason it ended.
    async fn stream(&mut self) -> LinkError {
        match self.stream_inner().await {
            Ok(never) => match never {},
            Err(error) => error,
        }
    }

    async fn stream_inner(&mut self) -> Result<std::convert::Infallible, LinkError> {
        let mut exchange = Exchange::open(
            &self.settings.host,
            self.settings.port,
            self.settings.frequency_hz,
        )
        .await?;
        // Read beside the samples, never before them: a dashboard server out of reach costs
        // the stream nothing.
        let host = self.settings.host.clone();
        let identity = dashboard::read_identity(&host, self.settings.dashboard_port);
        let mut identity = std::pin::pin!(identity);
        let mut identity_pending = true;
        // Kept across reads: a data package's steps allocate nothing once it has grown.
        let mut steps = Vec::new();
        loop {
            let limit = exchange.limit();
            let read = tokio::select! {
                read = timeout(limit, exchange.socket.read(&mut exchange.buffer)) => read,
                identity = &mut identity, if identity_pending => {
                    identity_pending = false;
                    self.identified(identity).await;
                    continue;
                }
            };
            exchange.take(read, limit, &mut steps).await?;
            for step in steps.drain(..) {
                match step {
                    Progress::Started(started) => self.started(started).await,
                    Progress::Sample(sample) => self.publish(&sample).await?,
                    Progress::Text(text) => self.text(&text),
                    Progress::Send(_) => {}
                }
            }
        }
    }

    async fn started(&mut self, started: Started) {
        let controller = started.controller;
        info!(
            robot = %self.settings.robot,
            controller = %format_args!("{}.{}.{}.{}", controller.major, controller.minor, controller.bugfix, controller.build),
            protocol = started.version.number(),
            variables = started.recipe.variables.len(),
            "streaming"
        );
        if !started.dropped.is_empty() && !self.dropped_said {
            self.dropped_said = true;
            warn!(
                robot = %self.settings.robot,
                variables = %started.dropped.join(","),
                "the controller does not have these variables: streaming without them"
            );
        }
        self.facts.version = Some([
            controller.major,
            controller.minor,
            controller.bugfix,
            controller.build,
        ]);
        self.publish_facts().await;
        if let Some(recorder) = &mut self.recorder
            && recorder.recipe.is_none()
        {
            let header = record::header(&started.recipe);
            match recorder.earlier_header.as_deref() {
                None => {
                    if let Err(error) = writeln!(recorder.file, "{header}") {
                        warn!(robot = %self.settings.robot, %error, "cannot write the recording");
                    }
                    recorder.recipe = Some(started.recipe);
                }
                Some(earlier) if earlier == header => {
                    info!(robot = %self.settings.robot, "appending to the recording an earlier run wrote");
                    recorder.recipe = Some(started.recipe);
                }
                Some(_) => {
                    warn!(
                        robot = %self.settings.robot,
                        "the recording holds other columns than this controller's: left as it is, not recording (name another file)"
                    );
                    self.recorder = None;
                }
            }
        }
        self.say(true).await;
    }

    /// The dashboard server's answer, or why there is none: logged, and published if it changed
    /// what is known.
    async fn identified(&mut self, identity: Result<Identity, DashboardError>) {
        let robot = &self.settings.robot;
        match identity {
            Ok(Identity { model, serial }) => {
                info!(
                    %robot,
                    model = model.as_deref().unwrap_or("unknown"),
                    serial = serial.as_deref().unwrap_or("unknown"),
                    "dashboard server read"
                );
                self.facts.model = model;
                self.facts.serial = serial;
                self.facts.dashboard_error = None;
            }
            Err(error) => {
                warn!(
                    %robot,
                    %error,
                    "cannot read the controller's dashboard server: its model and serial number \
                     stay unknown; streaming goes on"
                );
                self.facts.dashboard_error = Some(error.to_string());
            }
        }
        self.publish_facts().await;
    }

    /// A `tcp_offset` new to the gateway: logged and published before the sample of it.
    async fn tcp_offset(&mut self, tcp_offset: [f64; 6]) {
        if !tcp_offset.iter().all(|v| v.is_finite()) || self.facts.tcp_offset == Some(tcp_offset) {
            return;
        }
        info!(
            robot = %self.settings.robot,
            tcp_offset = ?tcp_offset,
            previous = ?self.facts.tcp_offset,
            "the controller's TCP (tcp_offset)"
        );
        self.facts.tcp_offset = Some(tcp_offset);
        self.publish_facts().await;
    }

    /// Puts the facts on the robot's controller key, if they changed since last put.
    async fn publish_facts(&mut self) {
        let mut published = self
            .published
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        if published.as_ref() == Some(&self.facts) {
            return;
        }
        let key = self.keys.key(Stream::Controller, &self.settings.robot);
        match self
            .session
            .put(key, self.facts.to_json())
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(CongestionControl::Block)
            .await
        {
            Ok(()) => published = Some(self.facts.clone()),
            Err(error) => {
                warn!(robot = %self.settings.robot, %error, "cannot publish the controller's facts");
            }
        }
        *self
            .published
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = published;
    }

    async fn publish(&mut self, sample: &RtdeSample) -> Result<(), LinkError> {
        if let Some(tcp_offset) = sample.tcp_offset {
            self.tcp_offset(tcp_offset).await;
        }
        let wall_s = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |since| since.as_secs_f64());
        let (stamp_s, change) = self.clock.stamp(sample.timestamp_s, wall_s);
        match change {
            Some(OffsetChange::Restarted {
                from_s,
                to_s,
                offset_s,
            }) => warn!(
                robot = %self.settings.robot,
                from_s,
                to_s,
                offset_s,
                "the controller's clock went back: it restarted; stamps continue from the last one"
            ),
            Some(OffsetChange::Fixed { offset_s }) => {
                debug!(robot = %self.settings.robot, offset_s, "stamp offset to wall time fixed");
            }
            None => {}
        }
        let measured = sample.actual_tcp_pose.map(|[x, y, z, rx, ry, rz]| {
            let q = orientation::quaternion_from_rotation_vector(&Vector3::new(rx, ry, rz));
            let [qx, qy, qz, qw] = orientation::quaternion_to_xyzw(&q);
            [x, y, z, qx, qy, qz, qw]
        });
        let payload = zser::joints_state_bytes(
            stamp_s,
            &sample.actual_q_rad,
            self.seq,
            measured.as_ref(),
            &sample.joint_state(),
        );
        self.publisher
            .put(payload)
            .await
            .map_err(LinkError::Zenoh)?;
        self.seq += 1;
        self.streamed += 1;
        if let Some(Recorder {
            file,
            recipe: Some(recipe),
            line,
            ..
        }) = &mut self.recorder
        {
            line.clear();
            record::write_row(recipe, sample, line);
            line.push('\n');
            if let Err(error) = file.write_all(line.as_bytes()) {
                warn!(robot = %self.settings.robot, %error, "cannot write the recording: stopped recording");
                self.recorder = None;
            }
        }
        Ok(())
    }

    fn text(&self, text: &TextMessage) {
        let robot = &self.settings.robot;
        let (message, source) = (&text.message, &text.source);
        match text.level {
            0 | 1 => warn!(%robot, %message, %source, "controller error message"),
            2 => warn!(%robot, %message, %source, "controller warning"),
            _ => info!(%robot, %message, %source, "controller message"),
        }
    }

    fn flush_recording(&mut self) {
        if let Some(recorder) = &mut self.recorder
            && let Err(error) = recorder.file.flush()
        {
            warn!(robot = %self.settings.robot, %error, "cannot write the recording");
        }
    }
}

/// Answers each query on the robot's controller key with the facts last published (none before
/// the first), until the link ends and aborts it.
async fn answer_facts(
    queryable: Queryable<zenoh::handlers::FifoChannelHandler<zenoh::query::Query>>,
    published: Arc<Mutex<Option<ControllerFacts>>>,
) {
    while let Ok(query) = queryable.recv_async().await {
        let facts = published
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        if let Some(facts) = facts {
            let key = queryable.key_expr().clone();
            if let Err(error) = query
                .reply(key, facts.to_json())
                .encoding(Encoding::APPLICATION_JSON)
                .await
            {
                debug!(%error, "cannot answer a controller facts query");
            }
        }
    }
}
