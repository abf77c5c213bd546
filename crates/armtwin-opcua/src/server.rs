//! The OPC UA server: its endpoints, certificate and users, and the sampler thread.
//!
//! The robots' nodes are made from the fleet when a request names them ([`crate::robots`]).
//! Once per sampling interval the sampler reads the robots whose variables clients monitor and
//! notifies those items, reads every robot's alarm flags and turns their changes into condition
//! events ([`crate::conditions`]), and prunes the refused client certificates. Nothing here runs
//! on the twins' sample path.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use opcua::crypto::SecurityPolicy;
use opcua::nodes::Event;
use opcua::server::diagnostics::DiagnosticsNodeManagerBuilder;
use opcua::server::node_manager::memory::{CoreNodeManagerBuilder, InMemoryNodeManagerBuilder};
use opcua::server::{
    ANONYMOUS_USER_TOKEN_ID, Server, ServerBuilder, ServerEndpoint, ServerHandle, ServerUserToken,
    SubscriptionCache,
};
use opcua::types::{DateTime, MessageSecurityMode};
use ring::rand::SystemRandom;
use tracing::{debug, info, warn};

use crate::access::{Access, USERS_TOKEN_ID};
use crate::alarms::{Alarm, AlarmStates};
use crate::condition_event::ConditionEvent;
use crate::conditions::{ConditionSnapshot, Conditions};
use crate::manager::{self, NodeSetError};
use crate::methods::{self, ConditionMethods};
use crate::reading::TwinSource;
use crate::rejected;
use crate::robots::RobotNodeManager;
use crate::settings::OpcUaSettings;

/// Why the OPC UA server could not start.
#[derive(Debug, thiserror::Error)]
pub enum OpcUaError {
    /// The endpoint's address could not be bound.
    #[error("OPC UA: cannot listen on {address}: {source}")]
    Listen {
        /// `HOST:PORT`.
        address: String,
        /// Why.
        source: std::io::Error,
    },
    /// The information models could not be read.
    #[error("OPC UA: {0}")]
    NodeSet(#[from] NodeSetError),
    /// The server's configuration was refused by the OPC UA stack.
    #[error("OPC UA: {0}")]
    Server(String),
}

/// How long stopping may wait for the server's sessions to close.
const STOP_TIMEOUT: Duration = Duration::from_secs(2);
/// How often the refused client certificates are pruned, and retired robots' conditions
/// forgotten (which needs every robot's id: not each sampling interval).
const PRUNE_PERIOD: Duration = Duration::from_secs(1);

/// A running OPC UA server.
pub struct OpcUaServer {
    handle: ServerHandle,
    server: tokio::task::JoinHandle<Result<(), String>>,
    stop_sampler: mpsc::Sender<()>,
    sampler: JoinHandle<()>,
}

/// The endpoints: the encrypted ones for users (and anonymous clients, when let in); policy None
/// for anonymous clients alone, when offered.
fn endpoints(settings: &OpcUaSettings) -> Vec<(String, ServerEndpoint)> {
    let mut secure_tokens = vec![USERS_TOKEN_ID.to_owned()];
    if settings.anonymous {
        secure_tokens.push(ANONYMOUS_USER_TOKEN_ID.to_owned());
    }
    let mut endpoints: Vec<(String, ServerEndpoint)> = [
        (SecurityPolicy::Basic256Sha256, "basic256sha256"),
        (SecurityPolicy::Aes128Sha256RsaOaep, "aes128sha256rsaoaep"),
        (SecurityPolicy::Aes256Sha256RsaPss, "aes256sha256rsapss"),
    ]
    .into_iter()
    .map(|(policy, name)| {
        (
            format!("{name}_sign_encrypt"),
            ServerEndpoint::new(
                "/",
                policy,
                MessageSecurityMode::SignAndEncrypt,
                &secure_tokens,
            ),
        )
    })
    .collect();
    if settings.security_none && settings.anonymous {
        endpoints.push((
            "none".to_owned(),
            ServerEndpoint::new_none("/", &[ANONYMOUS_USER_TOKEN_ID.to_owned()]),
        ));
    }
    endpoints
}

/// A server built and bound, not yet serving: what can fail at start has failed here, before
/// the service takes any input.
pub struct BoundServer {
    server: Server,
    handle: ServerHandle,
    listener: tokio::net::TcpListener,
    robots: Arc<RobotNodeManager>,
    conditions: Arc<Mutex<Conditions>>,
    period: Duration,
    /// Where the stack stores the client certificates it refused, kept within bounds.
    rejected_dir: PathBuf,
}

impl OpcUaServer {
    /// Binds the endpoint and builds the server with the DI and Robotics models. Call from
    /// within a Tokio runtime.
    pub async fn bind(settings: &OpcUaSettings) -> Result<BoundServer, OpcUaError> {
        let nodesets = manager::parse_nodesets()?;
        let address = format!("{}:{}", settings.host, settings.port);
        let listener = tokio::net::TcpListener::bind(&address)
            .await
            .map_err(|source| OpcUaError::Listen {
                address: address.clone(),
                source,
            })?;
        let conditions = Arc::new(Mutex::new(Conditions::default()));
        let for_methods = Arc::clone(&conditions);
        // The condition methods first, ahead of the core node manager that owns their ids
        // ([`crate::methods`]); then the stack's own two, as `ServerBuilder::new` adds them.
        let mut builder = ServerBuilder::new()
            .without_node_managers()
            .with_node_manager(move |context: opcua::server::node_manager::ServerContext| {
                ConditionMethods::new(&context, for_methods)
            })
            .with_node_manager(InMemoryNodeManagerBuilder::new(CoreNodeManagerBuilder))
            .with_node_manager(DiagnosticsNodeManagerBuilder)
            .application_name("armtwin")
            .application_uri("urn:armtwin:server")
            .product_uri("urn:armtwin")
            // The endpoints' URLs are the advertised ones; the listener above is the bound one.
            .host(settings.advertised.0.clone())
            .port(settings.advertised.1)
            .discovery_urls(vec![settings.url.clone()])
            .pki_dir(settings.pki_dir.clone())
            .trust_client_certs(false)
            .with_authenticator(Arc::new(Access::new(&settings.users, settings.anonymous)))
            .with_node_manager(manager::builder(nodesets))
            .with_node_manager(|context: opcua::server::node_manager::ServerContext| {
                RobotNodeManager::new(&context)
            });
        builder = match &settings.certificate {
            Some((certificate, key)) => builder
                .certificate_path(certificate.clone())
                .private_key_path(key.clone()),
            None => builder
                .create_sample_keypair(true)
                .certificate_path("own/cert.der")
                .private_key_path("private/private.pem"),
        };
        // The stack checks every endpoint's token ids against its user table; the passwords
        // themselves are checked by `Access`, against their digests.
        builder = builder.add_user_token(
            USERS_TOKEN_ID,
            ServerUserToken {
                user: USERS_TOKEN_ID.to_owned(),
                pass: Some(String::new()),
                ..ServerUserToken::default()
            },
        );
        for (id, endpoint) in endpoints(settings) {
            builder = builder.add_endpoint(id, endpoint);
        }
        let (server, handle) = builder.build().map_err(OpcUaError::Server)?;
        let robots = handle
            .node_managers()
            .get_of_type::<RobotNodeManager>()
            .ok_or_else(|| OpcUaError::Server("the robots' node manager is missing".to_owned()))?;
        info!(
            endpoint = %settings.url,
            sampling_interval_ms = settings.sampling_interval.as_millis(),
            anonymous = settings.anonymous,
            security_none = settings.security_none && settings.anonymous,
            users = settings.users.len(),
            "OPC UA server bound"
        );
        Ok(BoundServer {
            server,
            handle,
            listener,
            robots,
            conditions,
            period: settings.sampling_interval,
            rejected_dir: settings.pki_dir.join("rejected"),
        })
    }

    /// Stops the sampler, then the server, bounded in time.
    pub async fn stop(self) {
        // The sampler wakes on the message (or on the channel's close) at once.
        let _ = self.stop_sampler.send(());
        let sampler = self.sampler;
        let _ = tokio::task::spawn_blocking(move || sampler.join()).await;
        self.handle.cancel();
        match tokio::time::timeout(STOP_TIMEOUT, self.server).await {
            Ok(Ok(Ok(()))) => info!("OPC UA server stopped"),
            Ok(Ok(Err(e))) => warn!(error = %e, "OPC UA server stopped with an error"),
            Ok(Err(e)) => warn!(error = %e, "OPC UA server task failed"),
            Err(_) => warn!("OPC UA server did not stop in time"),
        }
    }
}

impl BoundServer {
    /// Starts serving, and the sampler, which reads `source` every sampling interval.
    pub fn start(self, source: Arc<dyn TwinSource>) -> Result<OpcUaServer, OpcUaError> {
        let (stop_sampler, stopped) = mpsc::channel();
        self.robots.serve(Arc::clone(&source));
        let sampler = Sampler {
            source,
            robots: self.robots,
            conditions: self.conditions,
            subscriptions: Arc::clone(self.handle.subscriptions()),
            alarmed: HashMap::new(),
            random: SystemRandom::new(),
            rejected_dir: self.rejected_dir,
        };
        let period = self.period;
        let sampler = std::thread::Builder::new()
            .name("armtwin-opcua".to_owned())
            .spawn(move || sampler.run(period, &stopped))
            .map_err(|e| OpcUaError::Server(format!("the sampler thread: {e}")))?;
        let server = tokio::spawn(self.server.run_with(self.listener));
        info!("OPC UA server serving");
        Ok(OpcUaServer {
            handle: self.handle,
            server,
            stop_sampler,
            sampler,
        })
    }
}

/// The sampler thread's state.
struct Sampler {
    source: Arc<dyn TwinSource>,
    robots: Arc<RobotNodeManager>,
    /// Every condition that needs attention, shared with the condition methods.
    conditions: Arc<Mutex<Conditions>>,
    subscriptions: Arc<SubscriptionCache>,
    /// The robots with an alarm on, as last published, and the turn that last saw each: a robot
    /// without one is kept nowhere.
    alarmed: HashMap<Arc<str>, (AlarmStates, u64)>,
    random: SystemRandom,
    rejected_dir: PathBuf,
}

impl Sampler {
    fn run(mut self, period: Duration, stop: &mpsc::Receiver<()>) {
        let mut turn = 0_u64;
        let mut next = Instant::now();
        let mut pruned = Instant::now();
        loop {
            turn += 1;
            let started = Instant::now();
            let prune = pruned.elapsed() >= PRUNE_PERIOD;
            self.sample(turn, prune);
            if prune {
                pruned = Instant::now();
                self.prune_rejected();
            }
            let (variables, robots) = self.robots.watched();
            debug!(
                variables,
                robots,
                alarmed = self.alarmed.len(),
                took_us = started.elapsed().as_micros(),
                "OPC UA monitored variables sampled"
            );
            next += period;
            let now = Instant::now();
            if next < now {
                // Behind (a long turn): skip the turns missed rather than run them back to back.
                next = now + period;
            }
            match stop.recv_timeout(next - now) {
                Err(RecvTimeoutError::Timeout) => {}
                Ok(()) | Err(RecvTimeoutError::Disconnected) => break,
            }
        }
    }

    /// Keeps the refused client certificates within [`rejected::MAX_REJECTED_FILES`] and
    /// [`rejected::MAX_REJECTED_BYTES`].
    fn prune_rejected(&self) {
        match rejected::prune(
            &self.rejected_dir,
            rejected::MAX_REJECTED_FILES,
            rejected::MAX_REJECTED_BYTES,
        ) {
            Ok(0) => {}
            Ok(removed) => warn!(
                removed,
                dir = %self.rejected_dir.display(),
                "OPC UA: refused client certificates removed, the oldest first (a client is \
                 presenting new ones)"
            ),
            Err(e) => warn!(
                error = %e,
                dir = %self.rejected_dir.display(),
                "OPC UA: cannot prune refused client certificates"
            ),
        }
    }

    /// One turn: the monitored variables sampled, and the alarms' changes notified as condition
    /// events.
    fn sample(&mut self, turn: u64, prune: bool) {
        self.robots.sample(&self.subscriptions);
        let mut changes: Vec<(Arc<str>, Alarm, bool)> = Vec::new();
        let alarmed = &mut self.alarmed;
        // The robots still here, gathered only on a pruning turn while a condition is retained.
        let gather = prune
            && self
                .conditions
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .len()
                > 0;
        let mut present: HashSet<Arc<str>> = HashSet::new();
        self.source.read_alarms(&mut |robot, reading| {
            if gather {
                present.insert(Arc::clone(robot));
            }
            let now = AlarmStates::from_alarms(reading);
            let before = alarmed
                .get(robot)
                .map_or_else(AlarmStates::default, |(states, _)| *states);
            changes.extend(
                before
                    .changes(now)
                    .map(|change| (Arc::clone(robot), change.alarm, change.raised)),
            );
            if now.any() {
                alarmed.insert(Arc::clone(robot), (now, turn));
            } else if before.any() {
                alarmed.remove(robot);
            }
        });
        let snapshots: Vec<ConditionSnapshot> = {
            let mut conditions = self
                .conditions
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            // A robot retired with an alarm on is forgotten without an event, as its node is
            // gone; so are its conditions, cleared or not.
            alarmed.retain(|_, (_, seen)| *seen == turn);
            if gather {
                conditions.retain_robots(|robot| present.contains(robot));
            }
            changes
                .iter()
                .filter_map(|(robot, alarm, raised)| {
                    let id = methods::event_id(&self.random);
                    conditions.set_active(robot, *alarm, *raised, DateTime::now(), id)
                })
                .collect()
        };
        self.notify(snapshots);
    }

    /// Each condition's new state as an event from the robot's node: a client watching the
    /// node, or the Server object (which every event reaches), receives it.
    fn notify(&self, snapshots: Vec<ConditionSnapshot>) {
        let armtwin = self.robots.namespace();
        for snapshot in snapshots {
            info!(
                robot = %snapshot.robot,
                alarm = snapshot.alarm.name(),
                active = snapshot.active,
                severity = snapshot.severity,
                message = %snapshot.message,
                "OPC UA condition"
            );
            let event = ConditionEvent::new(armtwin, snapshot);
            let source = event.source().clone();
            self.subscriptions
                .notify_events([(&event as &dyn Event, &source)].into_iter());
        }
    }
}
